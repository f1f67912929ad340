"""The fast paths of :mod:`terrain_estimation.ros.validation` decide as the plain checks do.

``first_nonfinite`` checks a message through a plan cached per message class
and falls back to the field-by-field walk when it is not sure: the field path,
the value and the first-in-field-order rule are the walk's. ``InputGuard``
parses its field paths once and skips the covariance checks when a topic sends
the covariance it last found usable, byte for byte: any other covariance is
checked again.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Vector3
from nav_msgs.msg import Odometry
from robustness_harness import float_paths
from sensor_msgs.msg import Imu, JointState

from terrain_estimation.ros import validation
from terrain_estimation.ros.validation import InputGuard, Rejection, field_value, first_nonfinite
from terrain_estimation.vehicles import VEHICLES, estimator_parameters
from terrain_msgs.msg import SkidSteerState, TerrainResponseModel, WheelTerrain, WheelTerrainArray

G = 9.80665


def _odometry() -> Odometry:
    msg = Odometry()
    msg.header.stamp = Time(sec=12, nanosec=345)
    msg.header.frame_id = "veh/odom"
    msg.child_frame_id = "veh/base_link"
    msg.pose.pose.position.x = 1.5
    msg.pose.pose.orientation.w = 1.0
    msg.pose.covariance = np.linspace(0.01, 0.36, 36)
    msg.twist.twist.linear.x = 2.0
    msg.twist.twist.angular.z = -0.1
    msg.twist.covariance = np.linspace(0.02, 0.72, 36)
    return msg


def _wheels() -> WheelTerrainArray:
    msg = WheelTerrainArray()
    msg.wheels = [WheelTerrain(wheel=w, slip=0.1 * i, normal_load=100.0) for i, w in enumerate(("a", "b", "c"))]
    return msg


def _model() -> TerrainResponseModel:
    return TerrainResponseModel(order=2, dp_coefficients=[1.0, 2.0, 3.0], tau_coefficients=[0.5] * 300)


def _joints() -> JointState:
    return JointState(name=["left_motor", "right_motor"], velocity=[1.0, 2.0], position=[0.0, 0.0])


def _set(msg: Any, path: str, value: float) -> None:
    *parents, last = path.split(".")
    obj = msg
    for part in parents:
        if part.endswith("]"):
            attr, index = part[:-1].split("[")
            obj = getattr(obj, attr)[int(index)]
        else:
            obj = getattr(obj, part)
    if last.endswith("]"):
        attr, index = last[:-1].split("[")
        getattr(obj, attr)[int(index)] = value  # in place: the array object stays the same
    else:
        setattr(obj, last, value)


def _found(msg: Any, prefix: str = "") -> tuple[str, float]:
    found = first_nonfinite(msg, prefix)
    assert found is not None
    return found


MESSAGES = {
    "odometry": _odometry,
    "skid_steer_state": lambda: SkidSteerState(vx=1.0, tire_sideslip=[0.01] * 6),
    "wheels": _wheels,
    "model": _model,
    "joints": _joints,
    "imu": lambda: Imu(
        linear_acceleration=Vector3(z=G), linear_acceleration_covariance=[0.1, 0, 0, 0, 0.1, 0, 0, 0, 0.1]
    ),
}


@pytest.mark.parametrize("make", MESSAGES.values(), ids=MESSAGES.keys())
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_every_float_of_a_cached_type_is_found_with_its_path(make, bad) -> None:
    assert first_nonfinite(make()) is None  # the plan of the type is cached from here on
    paths = float_paths(make())
    assert paths
    for path in paths:
        msg = make()
        _set(msg, path, bad)
        found = first_nonfinite(msg)
        assert found is not None and found[0] == path, (path, found)
        assert math.isnan(found[1]) if math.isnan(bad) else found[1] == bad
        assert found == validation._first_nonfinite_walk(msg) or math.isnan(bad)
        assert first_nonfinite(make()) is None  # a clean message of the type still passes


def test_nan_in_a_nested_array_of_a_cached_type() -> None:
    assert first_nonfinite(_odometry()) is None
    msg = _odometry()
    msg.twist.covariance[35] = math.nan
    path, value = _found(msg)
    assert path == "twist.covariance[35]" and math.isnan(value)
    wheels = _wheels()
    wheels.wheels[2].contact_angle_variance = math.inf
    assert first_nonfinite(wheels) == ("wheels[2].contact_angle_variance", math.inf)
    model = _model()
    model.tau_coefficients[299] = -math.inf  # array.array('d') of 300
    assert first_nonfinite(model) == ("tau_coefficients[299]", -math.inf)


def test_the_first_non_finite_in_field_order_is_reported() -> None:
    msg = _odometry()
    msg.twist.twist.linear.y = math.inf
    msg.pose.covariance[3] = math.nan
    msg.pose.pose.orientation.z = -math.inf
    assert first_nonfinite(msg) == ("pose.pose.orientation.z", -math.inf)
    assert first_nonfinite(msg, "odom.") == ("odom.pose.pose.orientation.z", -math.inf)


def test_finite_values_whose_sum_overflows_are_finite() -> None:
    msg = _odometry()
    msg.pose.pose.position.x = 1.7e308
    msg.pose.pose.position.y = 1.7e308
    msg.pose.covariance[:] = 1.7e308
    assert first_nonfinite(msg) is None


def test_fields_holding_unexpected_types_are_judged_as_by_the_walk() -> None:
    # rclpy does not check field types unless ROS_PYTHON_CHECK_FIELDS=1
    msg = _odometry()
    msg.pose.pose.position = Vector3(x=math.nan)  # another class in a nested field
    assert _found(msg)[0] == "pose.pose.position.x"
    msg = _odometry()
    msg.header.stamp.sec = math.nan  # a float in an integer field
    assert _found(msg)[0] == "header.stamp.sec"
    msg = _odometry()
    msg.child_frame_id = math.inf  # a float in a string field
    assert first_nonfinite(msg) == ("child_frame_id", math.inf)
    msg = _odometry()
    msg.pose.pose.position.x = 3  # an int: finite
    msg.pose.pose.position.y = np.float64(2.0)
    assert first_nonfinite(msg) is None
    msg.pose.pose.position.z = np.float32("nan")  # not a float: the walk skips it, and so does the check
    assert first_nonfinite(msg) is validation._first_nonfinite_walk(msg) is None
    msg = _odometry()
    msg.pose.pose = None  # nothing to look into
    assert first_nonfinite(msg) is None
    msg.twist.covariance = [1.0, math.nan]  # a list
    assert _found(msg)[0] == "twist.covariance[1]"


class _Plain:
    """Not a rosidl message: no slots, a large array, a nested message list."""

    def __init__(self) -> None:
        self.big = np.zeros(1000)
        self.matrix = np.eye(3)
        self.items = [Vector3(), 1.0]
        self.label = "x"

    @classmethod
    def get_fields_and_field_types(cls) -> dict[str, str]:
        return {"big": "double[1000]", "matrix": "double[9]", "items": "sequence", "label": "string"}


def test_other_message_like_classes() -> None:
    assert first_nonfinite(_Plain()) is None
    msg = _Plain()
    msg.big[777] = math.nan
    path, value = _found(msg)
    assert path == "big[777]" and math.isnan(value)
    msg = _Plain()
    msg.matrix[1, 1] = math.inf  # 2-D: the walk decides (and fails as it always did)
    with pytest.raises(IndexError):
        first_nonfinite(msg)
    msg = _Plain()
    msg.items[0].y = math.inf
    assert first_nonfinite(msg) == ("items[0].y", math.inf)
    msg = _Plain()
    msg.items[1] = -math.inf
    assert first_nonfinite(msg) == ("items[1]", -math.inf)
    with pytest.raises(AttributeError):
        first_nonfinite(3.0)


# -- InputGuard ---------------------------------------------------------------------------------


def _rejected(guard: InputGuard, key: str, msg: Any) -> Rejection:
    rejection = guard.check(key, msg, None)
    assert rejection is not None
    return rejection


def _guard() -> tuple[InputGuard, Any]:
    entry = VEHICLES["skid_steer"]
    values = estimator_parameters(entry, None)
    adapter = entry.make_adapter(values, entry.namespace)
    return InputGuard(adapter.inputs, values), {s.key: s for s in adapter.inputs}


GOOD_COV = [0.0025, 0.0, 0.0, 0.0, 0.0025, 0.0, 0.0, 0.0, 0.0025]


def _imu(spec: Any, k: int, cov: list[float] | None = None) -> Imu:
    msg = Imu()
    msg.header.frame_id = spec.frame_id
    msg.header.stamp = Time(sec=k // 100, nanosec=(k % 100) * 10_000_000)
    msg.linear_acceleration = Vector3(x=0.1, y=0.0, z=G)
    msg.linear_acceleration_covariance = GOOD_COV if cov is None else cov
    msg.angular_velocity_covariance = GOOD_COV
    return msg


def test_a_changed_covariance_after_a_cached_one_is_checked_again() -> None:
    guard, specs = _guard()
    spec = specs["imu"]
    assert "linear_acceleration_covariance" in spec.covariances
    k = 1
    for _ in range(3):
        assert guard.check("imu", _imu(spec, k), None) is None
        k += 1
    not_psd = [1.0, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0]  # eigenvalue -1
    for _ in range(2):  # a rejected covariance is never taken as usable
        rejection = guard.check("imu", _imu(spec, k, not_psd), None)
        k += 1
        assert rejection is not None
        assert rejection.field == "linear_acceleration_covariance"
        assert rejection.value == "[1, 2, 0, 2, 1, 0, 0, 0, 1] (eigenvalue -1)"
        assert rejection.problem == "is not positive semi-definite"
    msg = _imu(spec, k)
    assert guard.check("imu", msg, None) is None
    k += 1
    msg.header.stamp = _imu(spec, k).header.stamp
    msg.linear_acceleration_covariance[1] = 0.001  # the same message sent again, its array changed in place
    rejection = _rejected(guard, "imu", msg)
    k += 1
    assert rejection.problem == "is not symmetric"
    assert rejection.value == "[0.0025, 0.001, 0, 0, 0.0025, 0, 0, 0, 0.0025]"
    msg = _imu(spec, k, [math.nan, *GOOD_COV[1:]])
    rejection = _rejected(guard, "imu", msg)
    k += 1
    assert rejection.problem == "is not finite"
    assert rejection.value == "[nan, 0, 0, 0, 0.0025, 0, 0, 0, 0.0025]"
    msg = _imu(spec, k)
    msg.angular_velocity_covariance = [-1.0, 2.0, 0.0, 5.0, 1.0, 0.0, 0.0, 0.0, 1.0]  # not measured
    assert guard.check("imu", msg, None) is None
    k += 1
    msg = _imu(spec, k)
    msg.angular_velocity_covariance = [1.0, 0.0, 0.0, 5.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    rejection = _rejected(guard, "imu", msg)
    assert rejection.field == "angular_velocity_covariance"
    assert rejection.problem == "is not symmetric"
    assert guard.accepted == 5 and sum(guard.rejected.values()) == 5


def test_fields_are_read_as_field_value_reads_them() -> None:
    guard, specs = _guard()
    spec = specs["joint_states"]
    joints = _joints()
    joints.header.frame_id = spec.frame_id
    joints.header.stamp = Time(sec=1)
    assert guard.check("joint_states", joints, None) is None
    joints = _joints()
    joints.header.frame_id = spec.frame_id
    joints.header.stamp = Time(sec=2)
    joints.velocity = [1.0]
    rejection = _rejected(guard, "joint_states", joints)
    assert (rejection.field, rejection.value, rejection.problem) == (
        "len(velocity)",
        "1",
        "is too short for joint 'right_motor'",
    )
    joints.name = ["left_motor"]
    joints.velocity = [1.0]
    rejection = _rejected(guard, "joint_states", joints)
    assert (rejection.field, rejection.value) == ("name", "['left_motor']")
    assert rejection.problem == "lacks joint 'right_motor' (for velocity)"
    joints.name = ["left_motor", "right_motor"]
    joints.velocity = [1.0, math.inf]
    rejection = _rejected(guard, "joint_states", joints)
    assert (rejection.field, rejection.value, rejection.problem) == ("velocity[right_motor]", "inf", "is not finite")
    assert field_value(_joints(), "velocity[right_motor]") == 2.0
    assert field_value(_odometry(), "pose.pose.position.x") == 1.5
    with pytest.raises(LookupError) as info:
        field_value(_joints(), "velocity[nowhere]")
    assert info.value.args == ("name", "['left_motor', 'right_motor']", "lacks joint 'nowhere' (for velocity)")
    with pytest.raises(AttributeError):
        field_value(_odometry(), "pose.nowhere")


def test_the_gravity_window_sums_as_float64_arrays_do() -> None:
    rng = np.random.default_rng(7)
    window = validation._GravityWindow(0.5)
    samples: deque[tuple[float, np.ndarray]] = deque()
    total: np.ndarray | None = None
    for k in range(400):
        t = 0.01 * k
        vector = rng.normal([0.3, -0.2, G], 0.5)
        window.add(t, tuple(float(v) for v in vector))
        samples.append((t, vector))  # the reference: the float64 arrays of the first version
        total = vector.copy() if total is None else total + vector
        while t - samples[0][0] > 0.5:
            total -= samples.popleft()[1]
        assert window.total == list(total)
        span = samples[-1][0] - samples[0][0]
        expected = float(np.linalg.norm(total / len(samples))) if len(samples) >= 2 and span >= 0.25 else None
        assert window.mean_norm() == expected


def test_the_gravity_window_of_huge_readings_is_infinite_without_an_overflow_warning() -> None:
    import warnings

    window = validation._GravityWindow(0.5)
    for k in range(60):
        window.add(0.01 * k, (1e200, 0.0, 1e200))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert window.mean_norm() == math.inf


def test_accelerations_in_g_are_still_rejected_once_with_a_restart() -> None:
    guard, specs = _guard()
    spec = specs["imu"]
    rejections = []
    for k in range(1, 200):
        msg = _imu(spec, k)
        msg.linear_acceleration.z = 1.0
        rejection = guard.check("imu", msg, None)
        if rejection is not None:
            rejections.append(rejection)
    assert rejections and rejections[0].restart and not any(r.restart for r in rejections[1:])
    assert rejections[0].field == "linear_acceleration (x, y, z)"
    assert rejections[0].problem == "is in g, not m/s^2"


def test_the_fast_paths_are_taken(monkeypatch) -> None:
    """Clean messages never reach the walk; a repeated usable covariance is not checked again."""

    def walk(msg: Any, prefix: str = "") -> None:
        raise AssertionError("walked a clean message")

    monkeypatch.setattr(validation, "_first_nonfinite_walk", walk)
    for make in MESSAGES.values():
        assert first_nonfinite(make()) is None
    monkeypatch.undo()
    checked: list[list[float]] = []
    problem = validation._covariance_problem

    def counted(cov: np.ndarray) -> tuple[str, str] | None:
        checked.append(cov.tolist())
        return problem(cov)

    monkeypatch.setattr(validation, "_covariance_problem", counted)
    guard, specs = _guard()
    for k in range(1, 6):
        assert guard.check("imu", _imu(specs["imu"], k), None) is None
    assert checked == [GOOD_COV, GOOD_COV]  # linear acceleration and angular velocity, once each
