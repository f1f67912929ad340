"""Skid-steer motion-state estimator (UKF / STUKF / AN-STUKF): parameters and adapter.

Topics (CONTRACT.md, skid-steer section), relative to the vehicle namespace:

* in: ``imu`` (sensor_msgs/Imu: ``linear_acceleration`` x, y, ``angular_velocity.z``),
  ``joint_states`` (joints ``left_motor``, ``right_motor``: motor-side velocity)
* out: ``odom`` (nav_msgs/Odometry: body-frame twist with covariance, pose by
  dead reckoning), ``skid_steer/state`` (terrain_msgs/SkidSteerState)

Each IMU message is one filter step with the wheel speeds at its stamp
(interpolated between the joint states that bracket it, the newest held
within an age limit that follows the measured joint-state period:
:class:`~terrain_estimation.estimators.skid_steer.SkidSteerEstimator`).
The vehicle may have any number of axles (``vehicle.axle_x``).

``odom`` carries the full twist covariance (the ``vx, vy, r`` block of the
filter, cross-covariances included; :data:`UNESTIMATED_VARIANCE` on the
diagonal of ``vz`` and the roll and pitch rates, which are not estimated)
and the dead-reckoned pose with a covariance that grows (the ``x, y, yaw``
block; :data:`UNESTIMATED_VARIANCE` for ``z``, roll and pitch). No −1
anywhere: every entry is a variance.

``skid_steer/state``'s ``tire_sideslip`` (``float64[6]``) holds the six
wheels of a three-axle vehicle; for N ≠ 3 axles per side, front axle,
middle (interpolated at the midpoint between front and rear axle) and rear
axle, left then right
(:func:`~terrain_estimation.models.skid_steer.contract_tire_sideslip`).
Input the core rejects (non-finite values, stamps out of order) is counted in
the diagnostics with the topic, field and value, never passed on. Before the
adapter, the node checks every message (frame ``frames.<key>``, stamps,
finite fields, covariances, gravity in ``linear_acceleration``:
:mod:`terrain_estimation.ros.validation`); while a topic is silent for longer
than ``timeouts.<key>`` the diagnostics WARN and the estimator does what
:data:`ON_TIMEOUT` says (it holds).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseWithCovariance, Quaternion, Twist, TwistWithCovariance, Vector3
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Header

from terrain_estimation.estimators.skid_steer import SkidSteerEstimate, SkidSteerEstimator
from terrain_estimation.models.skid_steer import axle_count
from terrain_estimation.params import ParamValue
from terrain_estimation.ros.adapters import AdapterHealth, TopicSpec
from terrain_estimation.ros.parameters import divergence_errors, input_frame, namespaced_frame
from terrain_estimation.ros.skid_steer_params import (
    ON_TIMEOUT,
    PARAMETERS,
    VEHICLE_SPECS_SKID_STEER,
    estimator_config,
    husky_overrides,
    specs_for,
    vehicle_params,
)
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_ns
from terrain_msgs.msg import SkidSteerState

__all__ = [
    "VEHICLE_SPECS_SKID_STEER",
    "PARAMETERS",
    "ON_TIMEOUT",
    "SkidSteerAdapter",
    "estimator_config",
    "vehicle_params",
    "estimate_to_state_msg",
    "estimate_to_odom_msg",
    "make_adapter",
    "specs_for",
    "husky_overrides",
    "UNESTIMATED_VARIANCE",
]

#: Variance published in ``odom`` for what the estimator does not estimate (pose z, roll, pitch; twist
#: vz, roll and pitch rates): "unknown" as a number a consumer can fuse (a 1000 m / 1000 rad standard
#: deviation), never −1.
UNESTIMATED_VARIANCE = 1.0e6


def estimate_to_state_msg(e: SkidSteerEstimate, frame_id: str) -> SkidSteerState:
    """The contract's SkidSteerState of one estimate (every float finite by the core)."""
    stamp = sec_to_stamp(e.t)
    if _FAST_MESSAGES:
        return _state_msg(e, stamp, frame_id)
    msg = SkidSteerState(
        **{name: getattr(e, name) for name in _STATE_FIELDS},
        tire_sideslip=np.array(e.tire_sideslip),  # float64: taken as is, no per-element check
    )
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    return msg


def estimate_to_odom_msg(e: SkidSteerEstimate, odom_frame: str, base_frame: str) -> Odometry:
    """nav_msgs/Odometry: body-frame twist [vx, vy, r] with covariance, dead-reckoned planar pose with covariance.

    The pose is an integral of the estimated twist with no absolute correction:
    its ``x, y, yaw`` covariance grows with the twist's (module docstring);
    ``z``, roll and pitch, and in the twist ``vz`` and the roll and pitch rates,
    are not estimated and get :data:`UNESTIMATED_VARIANCE`.
    """
    stamp = sec_to_stamp(e.t)
    if _FAST_MESSAGES:
        return _odom_msg(e, stamp, odom_frame, base_frame)
    msg = Odometry()
    msg.header.stamp = stamp
    msg.header.frame_id = odom_frame
    msg.child_frame_id = base_frame
    msg.pose.pose.position.x = e.x
    msg.pose.pose.position.y = e.y
    msg.pose.pose.orientation.z = math.sin(0.5 * e.yaw)
    msg.pose.pose.orientation.w = math.cos(0.5 * e.yaw)
    msg.pose.covariance = _pose_covariance(e)
    msg.twist.twist.linear.x = e.vx
    msg.twist.twist.linear.y = e.vy
    msg.twist.twist.angular.z = e.yaw_rate
    msg.twist.covariance = _twist_covariance(e)
    return msg


def _twist_covariance(e: SkidSteerEstimate) -> np.ndarray:
    """The 6×6 twist covariance (row-major, 36): [vx, vy, r] → rows/columns 0, 1, 5 (x, y, z, rx, ry, rz);
    vz, roll and pitch rate :data:`UNESTIMATED_VARIANCE`."""
    cov = _UNESTIMATED.copy()
    cov[_PLANAR_COV_INDEX] = e.twist_covariance
    return cov


def _pose_covariance(e: SkidSteerEstimate) -> np.ndarray:
    """The 6×6 pose covariance (row-major, 36): [x, y, yaw] → rows/columns 0, 1, 5; z, roll, pitch
    :data:`UNESTIMATED_VARIANCE`."""
    cov = _UNESTIMATED.copy()
    cov[_PLANAR_COV_INDEX] = e.pose_covariance
    return cov


_PLANAR_COV_INDEX = np.array([6 * row + col for row in (0, 1, 5) for col in (0, 1, 5)])
"""Where a planar 3×3 covariance ([vx, vy, r] or [x, y, yaw], row-major) goes in a 6×6 one."""
_UNESTIMATED = np.zeros(36)
_UNESTIMATED[[14, 21, 28]] = UNESTIMATED_VARIANCE  # z (vz), roll (rate), pitch (rate)

# -- message construction without the generated constructors ----------------------------------
#
# A generated rclpy message's __init__ builds every field's default (nested messages, 36-element
# arrays) before the caller overwrites it, and each nested setter runs again on assignment: about
# 8 µs for an Odometry and 3 µs for a SkidSteerState, twice per IMU sample. The builders below
# create the same objects (the same slots, the same values and types, ``_check_fields`` False as
# the constructors set it by default) by filling the slots directly. Only when rclpy does not
# check fields (ROS_PYTHON_CHECK_FIELDS unset, as the constructors see it) and every class has
# exactly the slots written here; otherwise the constructors above run. A test compares the two.

_SLOTS: dict[type, tuple[str, ...]] = {
    Time: ("_sec", "_nanosec"),
    Header: ("_stamp", "_frame_id"),
    Point: ("_x", "_y", "_z"),
    Quaternion: ("_x", "_y", "_z", "_w"),
    Pose: ("_position", "_orientation"),
    PoseWithCovariance: ("_pose", "_covariance"),
    Vector3: ("_x", "_y", "_z"),
    Twist: ("_linear", "_angular"),
    TwistWithCovariance: ("_twist", "_covariance"),
    Odometry: ("_header", "_child_frame_id", "_pose", "_twist"),
    SkidSteerState: (
        "_header",
        "_vx",
        "_vx_variance",
        "_vy",
        "_vy_variance",
        "_yaw_rate",
        "_yaw_rate_variance",
        "_body_sideslip",
        "_body_sideslip_variance",
        "_slip_left",
        "_slip_right",
        "_tire_sideslip",
        "_icr_x",
        "_icr_y",
        "_icr_valid",
        "_fading_factor",
        "_noise_scale",
    ),
}


#: The fields of SkidSteerState but its header and tire_sideslip: each is the estimate's attribute of that name.
_STATE_FIELDS = tuple(slot[1:] for slot in _SLOTS[SkidSteerState] if slot not in ("_header", "_tire_sideslip"))


def _fast_messages_apply() -> bool:
    """The slot-filling builders make what the constructors make (see above)."""
    for cls, slots in _SLOTS.items():
        module = sys.modules.get(cls.__module__)
        if getattr(module, "ros_python_check_fields", "1") == "1":
            return False
        if tuple(getattr(cls, "__slots__", ())) != (*slots, "_check_fields"):
            return False
    return True


_FAST_MESSAGES = _fast_messages_apply()
_new = object.__new__


def _header(stamp: Time, frame_id: str) -> Header:
    h = _new(Header)
    h._check_fields = False
    h._stamp = stamp
    h._frame_id = frame_id
    return h


def _time(sec: int, nanosec: int) -> Time:
    t = _new(Time)
    t._check_fields = False
    t._sec = sec
    t._nanosec = nanosec
    return t


def _vector3(x: float, y: float, z: float, cls: type[Any] = Vector3) -> Any:
    v = _new(cls)
    v._check_fields = False
    v._x = x
    v._y = y
    v._z = z
    return v


def _state_msg(e: SkidSteerEstimate, stamp: Time, frame_id: str) -> SkidSteerState:
    """:func:`estimate_to_state_msg`'s message, slots filled directly (``stamp`` is used as is)."""
    m = _new(SkidSteerState)
    m._check_fields = False
    m._header = _header(stamp, frame_id)
    m._vx = e.vx
    m._vx_variance = e.vx_variance
    m._vy = e.vy
    m._vy_variance = e.vy_variance
    m._yaw_rate = e.yaw_rate
    m._yaw_rate_variance = e.yaw_rate_variance
    m._body_sideslip = e.body_sideslip
    m._body_sideslip_variance = e.body_sideslip_variance
    m._slip_left = e.slip_left
    m._slip_right = e.slip_right
    m._tire_sideslip = np.array(e.tire_sideslip, dtype=np.float64)
    m._icr_x = e.icr_x
    m._icr_y = e.icr_y
    m._icr_valid = e.icr_valid
    m._fading_factor = e.fading_factor
    m._noise_scale = e.noise_scale
    return m


def _odom_msg(e: SkidSteerEstimate, stamp: Time, odom_frame: str, base_frame: str) -> Odometry:
    """:func:`estimate_to_odom_msg`'s message, slots filled directly (``stamp`` is used as is)."""
    orientation = _new(Quaternion)
    orientation._check_fields = False
    orientation._x = 0.0
    orientation._y = 0.0
    orientation._z = math.sin(0.5 * e.yaw)
    orientation._w = math.cos(0.5 * e.yaw)
    pose = _new(Pose)
    pose._check_fields = False
    pose._position = _vector3(e.x, e.y, 0.0, Point)
    pose._orientation = orientation
    pose_cov = _new(PoseWithCovariance)
    pose_cov._check_fields = False
    pose_cov._pose = pose
    pose_cov._covariance = _pose_covariance(e)
    twist = _new(Twist)
    twist._check_fields = False
    twist._linear = _vector3(e.vx, e.vy, 0.0)
    twist._angular = _vector3(0.0, 0.0, e.yaw_rate)
    twist_cov = _new(TwistWithCovariance)
    twist_cov._check_fields = False
    twist_cov._twist = twist
    twist_cov._covariance = _twist_covariance(e)
    m = _new(Odometry)
    m._check_fields = False
    m._header = _header(stamp, odom_frame)
    m._child_frame_id = base_frame
    m._pose = pose_cov
    m._twist = twist_cov
    return m


class SkidSteerAdapter:
    """Messages ↔ :class:`SkidSteerEstimator` for one skid-steered vehicle."""

    def __init__(self, values: Mapping[str, ParamValue], namespace: str) -> None:
        self.config = estimator_config(values)
        self.estimator = SkidSteerEstimator(self.config)
        self.base_frame = namespaced_frame(namespace, str(values["frames.base_link"]))
        self.odom_frame = namespaced_frame(namespace, str(values["frames.odom"]))
        self.left_joint = str(values["joints.left_motor"])
        self.right_joint = str(values["joints.right_motor"])
        self.inputs: Sequence[TopicSpec] = (
            TopicSpec(
                "imu",
                "imu",
                Imu,
                frame_id=input_frame(values, namespace, "imu"),
                fields=("linear_acceleration.x", "linear_acceleration.y", "angular_velocity.z"),
                covariances=("linear_acceleration_covariance", "angular_velocity_covariance"),
                gravity_fields=("linear_acceleration.x", "linear_acceleration.y", "linear_acceleration.z"),
                gravity=float(values["vehicle.gravity"]),
                timeout=float(values["timeouts.imu"]),
                on_timeout=ON_TIMEOUT["imu"],
            ),
            TopicSpec(
                "joint_states",
                "joint_states",
                JointState,
                frame_id=input_frame(values, namespace, "joint_states"),
                fields=(f"velocity[{self.left_joint}]", f"velocity[{self.right_joint}]"),
                timeout=float(values["timeouts.joint_states"]),
                on_timeout=ON_TIMEOUT["joint_states"],
            ),
        )
        self._waits = self.config.wheel_speed_wait_s > 0.0
        self._scale_keys = tuple(f"tire_scale.{k}" for k in self.config.scale_states)
        self.outputs: Sequence[TopicSpec] = (
            TopicSpec("odom", "odom", Odometry, "estimate"),
            TopicSpec(
                "state",
                "skid_steer/state",
                SkidSteerState,
                "estimate",
                truth_fields=("vx", "vy", "yaw_rate", "body_sideslip", "slip_left", "slip_right"),
            ),
        )
        self.reset()

    def set_compiled(self, enabled: bool) -> None:
        """Run the estimator's compiled filter step (True, where it applies) or the Python reference step.

        The two give the same estimates to rounding (``test/test_skid_steer_compiled.py``); the switch is for
        the benchmark's side-by-side figures (``terrain_analysis.tools.bench --only skid_replay``).
        """
        self.estimator.use_compiled = bool(enabled) and self.estimator.compiled_available

    def reset(self) -> None:
        self.estimator.reset()
        self.health = AdapterHealth(nis_dof=self.estimator.model.measurement_dim)

    def handle(self, key: str, msg: Any) -> list[tuple[str, Any]]:
        t = stamp_to_ns(msg.header.stamp) * 1e-9
        if key == "joint_states":
            self._on_joints(t, msg)
            # A joint state releases the IMU samples waiting for it (estimator.wheel_speed_wait > 0 only).
            return self._outputs() if self._waits else []
        if key != "imu":
            return []
        acc, gyro = msg.linear_acceleration, msg.angular_velocity
        try:
            self.estimator.add_imu(t, acc.x, acc.y, gyro.z)
        except ValueError as exc:
            self.health.reject(f"imu: {exc}")
        return self._outputs()

    def _outputs(self) -> list[tuple[str, Any]]:
        """The messages of the estimates produced since the last call."""
        out: list[tuple[str, Any]] = []
        for e in self._drain():
            if _FAST_MESSAGES:
                # sec_to_stamp's Time (its checks, its rounding), built without the constructor; the state
                # message gets its own copy.
                t = e.t
                if not math.isfinite(t) or t < 0.0:
                    raise ValueError(f"time {t!r} s cannot be a ROS stamp")
                sec, nanosec = divmod(round(t * 1e9), 1_000_000_000)
                out.append(("odom", _odom_msg(e, _time(sec, nanosec), self.odom_frame, self.base_frame)))
                out.append(("state", _state_msg(e, _time(sec, nanosec), self.base_frame)))
            else:
                out.append(("odom", estimate_to_odom_msg(e, self.odom_frame, self.base_frame)))
                out.append(("state", estimate_to_state_msg(e, self.base_frame)))
        return out

    def _on_joints(self, t: float, msg: Any) -> None:
        names = list(msg.name)
        missing = [j for j in (self.left_joint, self.right_joint) if j not in names]
        if missing:
            self.health.reject(f"joint_states: no joint {', '.join(missing)} (names {names})")
            return
        if len(msg.velocity) != len(names):
            self.health.reject(f"joint_states: velocity has {len(msg.velocity)} entries for {len(names)} names")
            return
        left = float(msg.velocity[names.index(self.left_joint)])
        right = float(msg.velocity[names.index(self.right_joint)])
        try:
            self.estimator.add_joint_state(t, left, right)
        except ValueError as exc:
            self.health.reject(f"joint_states: {exc}")

    def _drain(self) -> list[SkidSteerEstimate]:
        estimates = self.estimator.drain_estimates()
        h = self.health
        for e in estimates:
            h.updates += 1
            h.last_update_time = e.t
            if e.accepted:
                h.nis.append(e.nis)
        counts = self.estimator.counter_values()  # the counters' fields, without a snapshot per step
        if estimates:
            last = estimates[-1]
            beta_deg = math.degrees(last.body_sideslip)
            h.status = f"vx {last.vx:.2f} m/s, yaw rate {last.yaw_rate:.3f} rad/s, sideslip {beta_deg:.1f} deg"
            h.values.update(
                fading_factor=last.fading_factor,
                noise_scale=last.noise_scale,
                slip_left=last.slip_left,
                slip_right=last.slip_right,
            )
            h.values.update(counts)
            h.values.update(self._wheel_speed_values())
            # The newest estimate's scales: those of the estimator's current state (estimator.tire_scales).
            h.values.update(zip(self._scale_keys, last.tire_scales, strict=True))
            if last.stationary:
                h.status += ", standing still"
        h.errors = divergence_errors(self.estimator.fault, counts["divergences"])
        return estimates

    def _wheel_speed_values(self) -> dict[str, Any]:
        """The wheel-speed lookup for diagnostics: method, measured joint-state rate, age limit."""
        period = self.estimator.wheel_speed_period_s
        return {
            "wheel_speed_method": self.config.wheel_speed_interpolation,
            "wheel_speed_rate_hz": 1.0 / period if period else 0.0,
            "wheel_speed_max_age_s": self.estimator.wheel_speed_max_age_s,
        }

    def summary_lines(self) -> list[str]:
        """What the offline tool's summary says about this run beyond the messages: the observer model,
        the wheel-speed lookup with the measured rate and the counts of steps interpolated, held and stale,
        the zero-velocity updates and the estimated tire scales."""
        est, cfg = self.estimator, self.config
        c = est.counter_values()
        period = est.wheel_speed_period_s
        rate = f"{1.0 / period:.3g} Hz measured" if period else "rate not measured"
        age = "fixed" if cfg.max_wheel_speed_age_s is not None else f"{cfg.wheel_speed_age_periods:g} periods"
        lines = [
            f"skid-steer: model {cfg.model}, filter {cfg.filter}, {axle_count(cfg.vehicle)} axles per side",
            f"  wheel speeds: {cfg.wheel_speed_interpolation} ({rate}; age limit {est.wheel_speed_max_age_s:.3g} s, "
            f"{age}): steps {c['wheel_speeds_interpolated']} interpolated, {c['wheel_speeds_held']} held, "
            f"{c['stale_wheel_speeds']} IMU samples stale, {c['no_wheel_speeds']} before any wheel speed",
            f"  zero-velocity updates: {c['zero_velocity_updates']} of {c['steps']} steps",
        ]
        scales = est.tire_scales
        if scales:
            lines.append("  tire scales (last): " + ", ".join(f"{k} {v:.3g}" for k, v in scales.items()))
        return lines


def make_adapter(values: Mapping[str, ParamValue], namespace: str) -> SkidSteerAdapter:
    return SkidSteerAdapter(values, namespace)
