"""Skid-steer motion-state estimator (UKF / STUKF / AN-STUKF): parameters and adapter.

Topics (CONTRACT.md, skid-steer section), relative to the vehicle namespace:

* in: ``imu`` (sensor_msgs/Imu: ``linear_acceleration`` x, y, ``angular_velocity.z``),
  ``joint_states`` (joints ``left_motor``, ``right_motor``: motor-side velocity)
* out: ``odom`` (nav_msgs/Odometry: body-frame twist with covariance, pose by
  dead reckoning), ``skid_steer/state`` (terrain_msgs/SkidSteerState)

Each IMU message is one filter step with the latest wheel speeds (zero-order
hold, :class:`~terrain_estimation.estimators.skid_steer.SkidSteerEstimator`).
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
from pathlib import Path
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseWithCovariance, Quaternion, Twist, TwistWithCovariance, Vector3
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Header

from terrain_estimation.estimators.skid_steer import (
    SkidSteerEstimate,
    SkidSteerEstimator,
    SkidSteerEstimatorConfig,
)
from terrain_estimation.filters.adaptive import StrongTrackingConfig
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.params import ParamSpec, ParamValue, default_config_path, load_parameter_file
from terrain_estimation.ros.framework import (
    AdapterHealth,
    TopicSpec,
    divergence_config,
    divergence_errors,
    divergence_specs,
    input_frame,
    input_specs,
)
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_ns
from terrain_msgs.msg import SkidSteerState

__all__ = [
    "VEHICLE_SPECS_SKID_STEER",
    "PARAMETERS",
    "SkidSteerAdapter",
    "estimator_config",
    "vehicle_params",
    "estimate_to_state_msg",
    "estimate_to_odom_msg",
    "make_adapter",
    "specs_for",
    "husky_overrides",
]

_D = SkidSteerParams()
_EC = SkidSteerEstimatorConfig()

#: The vehicle's nominal physics ([SS] Table 1, MODELS.md B.2) and its limits; shared with the simulator
#: (which declares the limits but has no use for them: ``/**`` is read by both nodes).
VEHICLE_SPECS_SKID_STEER: tuple[ParamSpec, ...] = (
    ParamSpec("vehicle.kind", "skid_steer", "vehicle model", choices=("skid_steer",), read_only=True),
    ParamSpec("vehicle.mass", _D.mass, "[kg] vehicle mass m (Table 1)", 1.0, 1e6),
    ParamSpec("vehicle.yaw_inertia", _D.yaw_inertia, "[kg m^2] yaw inertia I_z (Table 1)", 1e-3, 1e8),
    ParamSpec("vehicle.axle_spacing_front", _D.axle_spacing_front, "[m] axle 1 to axle 2, a (Table 1)", 1e-3, 50.0),
    ParamSpec("vehicle.axle_spacing_rear", _D.axle_spacing_rear, "[m] axle 2 to axle 3, b (Table 1)", 1e-3, 50.0),
    ParamSpec(
        "vehicle.cm_ahead_of_middle_axle",
        _D.cm_ahead_of_middle_axle,
        "[m] centre of mass ahead of axle 2, x (Table 1; negative: behind)",
        -50.0,
        50.0,
    ),
    ParamSpec("vehicle.track", _D.track, "[m] lateral distance between the wheel contact lines, B", 1e-2, 20.0),
    ParamSpec("vehicle.cg_height", _D.cg_height, "[m] height of the centre of mass H (Table 1)", 1e-3, 20.0),
    ParamSpec("vehicle.wheel_radius", _D.wheel_radius, "[m] rolling radius R (Table 1)", 1e-3, 5.0),
    ParamSpec("vehicle.transmission_ratio", _D.transmission_ratio, "[-] motor to wheel ratio i_g (Table 1)", 1e-3, 1e4),
    ParamSpec(
        "vehicle.longitudinal_stiffness",
        _D.longitudinal_stiffness,
        "[N] brush longitudinal slip stiffness C_x per wheel (Table 1)",
        1.0,
        1e8,
    ),
    ParamSpec(
        "vehicle.cornering_stiffness", _D.cornering_stiffness, "[N/rad] cornering stiffness C_a per wheel", 1.0, 1e8
    ),
    ParamSpec("vehicle.friction", _D.friction, "[-] tire-ground friction coefficient mu", 1e-3, 5.0),
    ParamSpec("vehicle.gravity", _D.gravity, "[m/s^2] gravity", 0.1, 30.0),
    ParamSpec(
        "vehicle.max_speed",
        _EC.max_speed,
        "[m/s] planar speed the vehicle cannot exceed: an estimate beyond it is a divergence (diagnostic ERROR, "
        "filter restarted from wheel odometry and gyro). [SS]'s vehicle: "
        "30 km/h manoeuvres, 20 m/s with margin",
        0.01,
        1000.0,
    ),
    ParamSpec(
        "vehicle.max_yaw_rate",
        _EC.max_yaw_rate,
        "[rad/s] yaw rate the vehicle cannot exceed: an estimate beyond it is a divergence, as vehicle.max_speed",
        0.01,
        100.0,
    ),
)

_ST = StrongTrackingConfig()


_ESTIMATOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "filter.type",
        "an_stukf",
        "filter: plain UKF (B.8), strong-tracking UKF (B.9) or adaptive-noise strong-tracking UKF (B.10, the paper's)",
        choices=("an_stukf", "stukf", "ukf"),
    ),
    ParamSpec(
        "filter.ukf_alpha", 1.0, "[-] sigma-point spread alpha (small values give negative weights, n = 3)", 1e-3, 10.0
    ),
    ParamSpec("filter.ukf_beta", 2.0, "[-] UKF beta (2: Gaussian prior)", 0.0, 10.0),
    ParamSpec("filter.ukf_kappa", 0.0, "[-] UKF kappa (3 - n = 0)", -2.9, 10.0),
    ParamSpec("filter.gate_threshold", 0.0, "[-] NIS gate on updates (chi^2_3 quantile); 0 disables", 0.0, 1e6),
    *divergence_specs(
        "false: with the default filter.r0_diag (4x the accelerometer noise) the mean NIS is about 0.2 against 3 "
        "on healthy data, every variant (refused for an_stukf, whose adaptive noise rescales the innovations)"
    ),
    ParamSpec(
        "filter.q0_diag",
        list(_EC.q0_diag),
        "[(m/s)^2, (m/s)^2, (rad/s)^2] base process noise of [vx, vy, r] per 10 ms step (B.10)",
        0.0,
        1e6,
    ),
    ParamSpec(
        "filter.r0_diag",
        list(_EC.r0_diag),
        "[(m/s^2)^2, (m/s^2)^2, (rad/s)^2] base measurement noise of [a_x, a_y, r]: accelerometer noise plus "
        "vibration and gravity leakage through roll and pitch (B.10)",
        1e-12,
        1e6,
    ),
    ParamSpec(
        "filter.p0_diag",
        list(_EC.p0_diag),
        "[(m/s)^2, (m/s)^2, (rad/s)^2] initial covariance of [vx, vy, r]",
        1e-12,
        1e6,
    ),
    ParamSpec("strong_tracking.rho", _ST.rho, "[-] forgetting factor of the innovation covariance (B.9)", 1e-3, 1.0),
    ParamSpec("strong_tracking.beta_w", _ST.beta_w, "[-] weakening factor (>= 1; larger: less eager)", 1.0, 100.0),
    ParamSpec(
        "strong_tracking.gamma_th",
        3.0,
        "[-] activation threshold: fading only when e'e > gamma_th tr(P_zz); 0 = at every step",
        0.0,
        1e6,
    ),
    ParamSpec("strong_tracking.lambda_max", _ST.lambda_max, "[-] cap on the fading factor", 1.0, 1e6),
    ParamSpec("adaptive_noise.k_q", 5.0, "[1/rad] Q0 grows as (1 + k_q mean|alpha|) (B.10)", 0.0, 1e4),
    ParamSpec("adaptive_noise.k_r", 2.0, "[1/rad] R0 shrinks as 1/(1 + k_r mean|alpha|) (B.10)", 0.0, 1e4),
    ParamSpec(
        "estimator.accel_cutoff",
        2.0,
        "[Hz] low-pass cut-off of the measured a_x, a_y that feed the load-transfer model",
        1e-3,
        1e3,
    ),
    ParamSpec(
        "estimator.min_yaw_rate", 0.02, "[rad/s] the ICR is published (icr_valid) only above this yaw rate", 0.0, 10.0
    ),
    ParamSpec(
        "estimator.min_sideslip_speed",
        0.2,
        "[m/s] below this speed the sideslip angles are undefined: published as 0 with variance pi^2",
        0.0,
        10.0,
    ),
    ParamSpec(
        "estimator.max_wheel_speed_age",
        0.05,
        "[s] wheel speeds further than this from the IMU stamp are stale: the step is skipped",
        1e-4,
        10.0,
    ),
    ParamSpec("estimator.max_step", 0.1, "[s] a longer gap between IMU samples restarts the filter", 1e-3, 1e4),
    ParamSpec("joints.left_motor", "left_motor", "joint_states name of the left motor"),
    ParamSpec("joints.right_motor", "right_motor", "joint_states name of the right motor"),
    ParamSpec("frames.base_link", "base_link", "child frame of odom (prefixed with the namespace)"),
    ParamSpec("frames.odom", "odom", "frame of the dead-reckoned pose (prefixed with the namespace)"),
)


#: What the estimator does while an input is silent (shown in the timeout warning).
ON_TIMEOUT: dict[str, str] = {
    "imu": "no filter steps: odom and skid_steer/state hold (nothing is published); a gap longer than "
    "estimator.max_step restarts the filter",
    "joint_states": "IMU samples whose wheel speeds are older than estimator.max_wheel_speed_age are skipped: "
    "the estimate holds",
}

_INPUT_SPECS: tuple[ParamSpec, ...] = (
    *input_specs("imu", "imu", "imu_link", 0.5, ON_TIMEOUT["imu"]),
    *input_specs("joint_states", "joint_states", "", 0.5, ON_TIMEOUT["joint_states"]),
)


def specs_for(kind: str = "skid_steer") -> tuple[ParamSpec, ...]:
    """The estimator's parameter specs (one vehicle kind)."""
    if kind != "skid_steer":
        raise ValueError(f"unknown skid-steer vehicle kind {kind!r}")
    return VEHICLE_SPECS_SKID_STEER + _ESTIMATOR_SPECS + _INPUT_SPECS


PARAMETERS = specs_for()


def _f(values: Mapping[str, ParamValue], name: str) -> float:
    return float(values[name])


def _triple(values: Mapping[str, ParamValue], name: str) -> tuple[float, float, float]:
    v = [float(x) for x in values[name]]
    if len(v) != 3:
        raise ValueError(f"{name} must hold 3 values ([vx, vy, r] order), got {len(v)}: {v}")
    return v[0], v[1], v[2]


def vehicle_params(values: Mapping[str, ParamValue]) -> SkidSteerParams:
    """The nominal vehicle of the ``vehicle.*`` parameters."""
    return SkidSteerParams(
        mass=_f(values, "vehicle.mass"),
        yaw_inertia=_f(values, "vehicle.yaw_inertia"),
        axle_spacing_front=_f(values, "vehicle.axle_spacing_front"),
        axle_spacing_rear=_f(values, "vehicle.axle_spacing_rear"),
        cm_ahead_of_middle_axle=_f(values, "vehicle.cm_ahead_of_middle_axle"),
        track=_f(values, "vehicle.track"),
        cg_height=_f(values, "vehicle.cg_height"),
        wheel_radius=_f(values, "vehicle.wheel_radius"),
        transmission_ratio=_f(values, "vehicle.transmission_ratio"),
        longitudinal_stiffness=_f(values, "vehicle.longitudinal_stiffness"),
        cornering_stiffness=_f(values, "vehicle.cornering_stiffness"),
        friction=_f(values, "vehicle.friction"),
        gravity=_f(values, "vehicle.gravity"),
    )


def estimator_config(values: Mapping[str, ParamValue]) -> SkidSteerEstimatorConfig:
    """The core estimator's configuration from validated parameter values.

    Raises:
        ValueError: inconsistent values (e.g. a noise diagonal of the wrong length).
    """
    gate = _f(values, "filter.gate_threshold")
    gamma_th = _f(values, "strong_tracking.gamma_th")
    strong = StrongTrackingConfig(
        rho=_f(values, "strong_tracking.rho"),
        beta_w=_f(values, "strong_tracking.beta_w"),
        gamma_th=gamma_th if gamma_th > 0.0 else None,
        lambda_max=_f(values, "strong_tracking.lambda_max"),
    )
    return SkidSteerEstimatorConfig(
        vehicle=vehicle_params(values),
        filter=values["filter.type"],
        ukf_alpha=_f(values, "filter.ukf_alpha"),
        ukf_beta=_f(values, "filter.ukf_beta"),
        ukf_kappa=_f(values, "filter.ukf_kappa"),
        gate_threshold=gate if gate > 0.0 else None,
        strong_tracking=strong,
        k_q=_f(values, "adaptive_noise.k_q"),
        k_r=_f(values, "adaptive_noise.k_r"),
        q0_diag=_triple(values, "filter.q0_diag"),
        r0_diag=_triple(values, "filter.r0_diag"),
        p0_diag=_triple(values, "filter.p0_diag"),
        accel_cutoff_hz=_f(values, "estimator.accel_cutoff"),
        min_yaw_rate=_f(values, "estimator.min_yaw_rate"),
        min_sideslip_speed=_f(values, "estimator.min_sideslip_speed"),
        max_wheel_speed_age_s=_f(values, "estimator.max_wheel_speed_age"),
        max_step_s=_f(values, "estimator.max_step"),
        divergence=divergence_config(values),
        max_speed=_f(values, "vehicle.max_speed"),
        max_yaw_rate=_f(values, "vehicle.max_yaw_rate"),
    )


def husky_overrides(path: str | Path | None = None) -> dict[str, Any]:
    """The estimator's parameters for the BorealTC Husky: ``config/husky.yaml`` (default) read as this node.

    That file's ``/**`` section describes the 4-wheel Husky for the sim-to-real replay and the importer
    (names this node does not declare, ``vehicle.kind: husky``); its ``/**/skid_steer_estimator`` section
    holds this node's view of it (three-axle equivalent, noise of the BorealTC IMU, 6.5 Hz wheel speeds).
    Returns the names this node declares, the section over ``/**``, for ``overrides=`` of
    :func:`~terrain_estimation.tools.estimate.estimate_bag` (namespace ``/husky``).
    """
    values = load_parameter_file(path if path is not None else default_config_path("husky"), ["skid_steer_estimator"])
    declared = {s.name for s in PARAMETERS}
    return {name: value for name, value in values.items() if name in declared}


def estimate_to_state_msg(e: SkidSteerEstimate, frame_id: str) -> SkidSteerState:
    """The contract's SkidSteerState of one estimate (every float finite by the core)."""
    stamp = sec_to_stamp(e.t)
    if _FAST_MESSAGES:
        return _state_msg(e, stamp, frame_id)
    msg = SkidSteerState(
        vx=e.vx,
        vx_variance=e.vx_variance,
        vy=e.vy,
        vy_variance=e.vy_variance,
        yaw_rate=e.yaw_rate,
        yaw_rate_variance=e.yaw_rate_variance,
        body_sideslip=e.body_sideslip,
        body_sideslip_variance=e.body_sideslip_variance,
        slip_left=e.slip_left,
        slip_right=e.slip_right,
        tire_sideslip=np.array(e.tire_sideslip),  # float64: taken as is, no per-element check
        icr_x=e.icr_x,
        icr_y=e.icr_y,
        icr_valid=e.icr_valid,
        fading_factor=e.fading_factor,
        noise_scale=e.noise_scale,
    )
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    return msg


def estimate_to_odom_msg(e: SkidSteerEstimate, odom_frame: str, base_frame: str) -> Odometry:
    """nav_msgs/Odometry: body-frame twist [vx, vy, r] with covariance, dead-reckoned planar pose.

    The pose is an integral of the estimated twist with no absolute correction:
    its covariance is not estimated and is marked unknown (-1 on the diagonal's
    first element, as sensor_msgs does for a field that is not measured).
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
    msg.pose.covariance[0] = -1.0
    msg.twist.twist.linear.x = e.vx
    msg.twist.twist.linear.y = e.vy
    msg.twist.twist.angular.z = e.yaw_rate
    msg.twist.covariance = _twist_covariance(e)
    return msg


def _twist_covariance(e: SkidSteerEstimate) -> np.ndarray:
    """The 6×6 twist covariance (row-major, 36): [vx, vy, r] → rows/columns 0, 1, 5 (x, y, z, rx, ry, rz)."""
    cov = np.zeros(36)
    cov[_TWIST_COV_INDEX] = e.twist_covariance
    return cov


_TWIST_COV_INDEX = np.array([6 * row + col for row in (0, 1, 5) for col in (0, 1, 5)])
"""Where the 3×3 covariance of [vx, vy, r] (row-major) goes in the 6×6 twist covariance."""

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
_POSE_COVARIANCE = np.zeros(36)
_POSE_COVARIANCE[0] = -1.0  # pose covariance unknown (estimate_to_odom_msg)
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
    pose_cov._covariance = _POSE_COVARIANCE.copy()
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


def _frame(namespace: str, frame: str) -> str:
    ns = namespace.strip("/")
    return f"{ns}/{frame}" if ns else frame


class SkidSteerAdapter:
    """Messages ↔ :class:`SkidSteerEstimator` for one skid-steered vehicle."""

    def __init__(self, values: Mapping[str, ParamValue], namespace: str) -> None:
        self.config = estimator_config(values)
        self.estimator = SkidSteerEstimator(self.config)
        self.base_frame = _frame(namespace, str(values["frames.base_link"]))
        self.odom_frame = _frame(namespace, str(values["frames.odom"]))
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
                gravity=_f(values, "vehicle.gravity"),
                timeout=_f(values, "timeouts.imu"),
                on_timeout=ON_TIMEOUT["imu"],
            ),
            TopicSpec(
                "joint_states",
                "joint_states",
                JointState,
                frame_id=input_frame(values, namespace, "joint_states"),
                fields=(f"velocity[{self.left_joint}]", f"velocity[{self.right_joint}]"),
                timeout=_f(values, "timeouts.joint_states"),
                on_timeout=ON_TIMEOUT["joint_states"],
            ),
        )
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

    def reset(self) -> None:
        self.estimator.reset()
        self.health = AdapterHealth(nis_dof=3)

    def handle(self, key: str, msg: Any) -> list[tuple[str, Any]]:
        t = stamp_to_ns(msg.header.stamp) * 1e-9
        if key == "joint_states":
            self._on_joints(t, msg)
            return []
        if key != "imu":
            return []
        acc, gyro = msg.linear_acceleration, msg.angular_velocity
        try:
            self.estimator.add_imu(t, acc.x, acc.y, gyro.z)
        except ValueError as exc:
            self.health.reject(f"imu: {exc}")
        out: list[tuple[str, Any]] = []
        for e in self._drain():
            if _FAST_MESSAGES:
                stamp = sec_to_stamp(e.t)  # one per estimate; the state message gets its own copy
                out.append(("odom", _odom_msg(e, stamp, self.odom_frame, self.base_frame)))
                out.append(("state", _state_msg(e, _time(stamp.sec, stamp.nanosec), self.base_frame)))
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
        h.errors = divergence_errors(self.estimator.fault, counts["divergences"])
        return estimates


def make_adapter(values: Mapping[str, ParamValue], namespace: str) -> SkidSteerAdapter:
    return SkidSteerAdapter(values, namespace)
