"""Soil-stiffness estimator (quarter car 2-DOF and LRV 1-DOF): parameters and adapter.

Topics (CONTRACT.md, quarter car section), relative to the vehicle namespace:

* in: ``imu/body``, ``imu/wheel`` (2-DOF), ``terrain/profile``, ``joint_states``
* out: ``soil_stiffness`` (terrain_msgs/SoilStiffness)

The two accelerometers arrive as separate messages; the filter needs both of
one instant, so they are paired by identical header stamps (the
simulator and a hardware-synchronised IMU pair stamp them so). A body sample
whose wheel partner has not arrived within ``estimator.pair_timeout`` of a
newer sample is used alone (a body-only update) and counted in diagnostics.

Before the adapter, the node checks every message (frames ``frames.<key>``,
stamps, finite fields, accelerometer covariances and gravity:
:mod:`terrain_estimation.ros.validation`); while a topic is silent for longer
than ``timeouts.<key>`` the diagnostics WARN and the estimator does what
:data:`ON_TIMEOUT` says.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from operator import attrgetter
from typing import Any

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Header

from terrain_estimation.estimators.soil_select import make_estimator
from terrain_estimation.estimators.soil_stiffness import (
    P0_LOG_KS,
    SoilStiffnessEstimate,
    SoilStiffnessEstimatorConfig,
)
from terrain_estimation.models.quarter_car import LRVParams, QuarterCarParams
from terrain_estimation.models.quarter_car_road import RoadInputParams
from terrain_estimation.params import ParamSpec, ParamValue
from terrain_estimation.ros.adapters import AdapterHealth, TopicSpec
from terrain_estimation.ros.parameters import (
    divergence_config,
    divergence_errors,
    divergence_specs,
    float_fields,
    input_frame,
    input_specs,
    namespaced_frame,
)
from terrain_estimation.ros.parameters import float_value as _f
from terrain_estimation.ros.time import sec_to_stamp, stamp_parts, stamp_to_ns
from terrain_msgs.msg import SoilStiffness

__all__ = [
    "VEHICLE_SPECS_QUARTER_CAR",
    "VEHICLE_SPECS_LRV",
    "PARAMETERS",
    "SoilStiffnessAdapter",
    "estimator_config",
    "estimate_to_msg",
    "make_adapter",
    "specs_for",
]

# Vehicle parameters, shared with the simulator (config/<vehicle>.yaml, "/**").
VEHICLE_SPECS_QUARTER_CAR: tuple[ParamSpec, ...] = (
    ParamSpec("vehicle.kind", "quarter_car", "model: 2-DOF quarter car", choices=("quarter_car",), read_only=True),
    ParamSpec("vehicle.sprung_mass", 455.0, "[kg] sprung mass m_s (Table 2)", 1.0, 1e5),
    ParamSpec("vehicle.unsprung_mass", 45.5, "[kg] unsprung mass m_ns (Table 2)", 0.1, 1e4),
    ParamSpec("vehicle.suspension_stiffness", 25e3, "[N/m] suspension spring k (Table 2)", 1.0, 1e8),
    ParamSpec("vehicle.suspension_damping", 2e3, "[N s/m] suspension damper c (Table 2)", 0.0, 1e7),
    ParamSpec("vehicle.tire_stiffness", 175e3, "[N/m] tire stiffness k_t, in series with the soil (Table 2)", 1.0, 1e9),
    ParamSpec("vehicle.wheel_radius", 0.3885, "[m] rolling radius (joint rate x radius = travel speed)", 0.01, 5.0),
)
VEHICLE_SPECS_LRV: tuple[ParamSpec, ...] = (
    ParamSpec("vehicle.kind", "lrv", "model: 1-DOF Lunar Roving Vehicle", choices=("lrv",), read_only=True),
    ParamSpec("vehicle.sprung_mass", 75.0, "[kg] lumped mass per wheel m_s (Table 5)", 1.0, 1e5),
    ParamSpec(
        "vehicle.suspension_stiffness",
        15e3,
        "[N/m] combined suspension and tire stiffness k, in series with the soil (Table 5)",
        1.0,
        1e8,
    ),
    ParamSpec("vehicle.suspension_damping", 1.5e3, "[N s/m] damper c (Table 5)", 0.0, 1e7),
    ParamSpec("vehicle.wheel_radius", 0.508, "[m] rolling radius (D = 1.016 m)", 0.01, 5.0),
    ParamSpec(
        "vehicle.damper_reference",
        "ground",
        "what the damper acts against: 'ground' c(dy1 - dh), physical; "
        "'inertial' c dy1, the paper's literal reduction of the 2-DOF matrices",
        choices=("ground", "inertial"),
    ),
)


def _filter_specs(kind: str) -> tuple[ParamSpec, ...]:
    lrv = kind == "lrv"
    # Section 4 of the paper; the LRV keeps states 1, 2 and 5 ("noise unchanged").
    q_diag = [1e-5, 1e-3, 1e5] if lrv else [1e-5, 1e-3, 1e-5, 1e-3, 1e5]
    # Not given by the paper; MODELS.md A.5 values for the motion states. The last
    # entry is the stiffness state's: ln(k_s/k_series) with std 1.5 (2-sigma prior
    # 0.05...20 times k_series) for the default log_k_s state.
    p0_diag = [1e-4, 1e-2, P0_LOG_KS] if lrv else [1e-4, 1e-2, 1e-4, 1e-2, P0_LOG_KS]
    state = "[y1-h, dy1, s]" if lrv else "[y1-y2, dy1, y2-h, dy2, s]"
    # Same relative random walk on both vehicles: 1e3 (N/m)^2 per step on the
    # quarter car's k_t = 175 kN/m, scaled by (15/175)^2 for the LRV's k = 15 kN/m.
    q_ktot = 7.35 if lrv else 1e3
    # The same walks expressed in ln k_s at the reference soils (Graneville loam
    # on the quarter car, regolith on the LRV): q_ktot / (dk_tot/ds)^2.
    q_log = 6.4e-7 if lrv else 1e-6
    return _FILTER_SPECS + (
        ParamSpec(
            "filter.q_ktot_per_step",
            q_ktot,
            "[(N/m)^2] k_tot random-walk variance per 10 ms step (stiffness_state k_tot)",
            0.0,
            1e12,
        ),
        ParamSpec(
            "filter.q_log_ks_per_step",
            q_log,
            "[-] random-walk variance of ln k_s per 10 ms step (stiffness_state log_k_s): a relative walk",
            0.0,
            1.0,
        ),
        ParamSpec(
            "filter.q_diag",
            q_diag,
            f"[SI^2] continuous process-noise variances of {state} (paper section 4)",
            0.0,
            1e15,
        ),
        ParamSpec(
            "filter.p0_diag",
            p0_diag,
            f"[SI^2] initial covariance diagonal of {state}; s is the stiffness state: the variance of "
            "ln(k_s/k_series) for log_k_s (at most 25), of k_tot in (N/m)^2 for k_tot (above 25)",
            1e-15,
            1e15,
        ),
    )


_FILTER_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "filter.type",
        "sckf",
        "filter: square-root cubature (paper), cubature, unscented or extended KF",
        choices=("sckf", "ckf", "ukf", "ekf"),
    ),
    ParamSpec("filter.rate", 100.0, "[Hz] filter rate; faster accelerometer samples are decimated", 1.0, 2000.0),
    ParamSpec(
        "filter.substep_rate",
        1000.0,
        "[Hz] rate of the road sub-steps each cubature point is propagated through (MODELS.md A.10)",
        1.0,
        100000.0,
    ),
    ParamSpec(
        "filter.discretisation",
        "taylor4",
        "state transition: 4th-order Taylor series (P-11) or exact expm",
        choices=("taylor4", "expm"),
    ),
    ParamSpec(
        "filter.stiffness_state",
        "log_k_s",
        "augmented stiffness state: 'log_k_s' = ln(k_s/k_series), k_tot stays inside (0, k_series) and k_s "
        "cannot explode (project default); 'k_tot' = the paper's state, clamped (MODELS.md A.10.4)",
        choices=("log_k_s", "k_tot"),
    ),
    ParamSpec(
        "filter.ktot_noise_form",
        "per_step",
        "k_tot random walk: 'per_step' (filter.q_ktot_per_step each step) or 'printed' (Q_k = dt G Q G^T: "
        "almost no random walk, cannot re-adapt after a soil change; MODELS.md A.4)",
        choices=("per_step", "printed"),
    ),
    ParamSpec("filter.accel_noise_variance", 0.5, "[(m/s^2)^2] accelerometer noise variance R (paper: 0.5)", 1e-9, 1e4),
    ParamSpec(
        "filter.k_tot0", 0.0, "[N/m] initial k_tot; 0: half the series stiffness (the paper's start guess)", 0.0, 1e9
    ),
    ParamSpec(
        "filter.ekf_jacobian",
        "exact",
        "EKF Jacobian: 'exact' derivative of the discrete model, or 'paper' (omits d(B u)/dk_tot, A.6)",
        choices=("exact", "paper"),
    ),
    ParamSpec("filter.gate_threshold", 0.0, "[-] Mahalanobis (NIS) gate on updates; 0 disables", 0.0, 1e6),
    *divergence_specs(),
)

_ESTIMATOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("estimator.gravity", 9.80665, "[m/s^2] gravity subtracted from the specific forces (REP 145)", 0.0, 30.0),
    ParamSpec("estimator.convergence_rel_std", 0.05, "[-] 'converged' when std(k_s)/k_s is below this", 1e-6, 10.0),
    ParamSpec(
        "estimator.class_log_std", 0.1, "[-] within-class spread of ln k_s for the terrain classifier", 1e-3, 10.0
    ),
    ParamSpec("estimator.unknown_weight", 0.05, "[-] prior weight of 'none of the known soils'", 0.0, 0.99),
    ParamSpec(
        "estimator.change_drift",
        0.5,
        "[sigma] CUSUM allowance of the soil-change detector (whitened stiffness corrections, armed from the "
        "start): about half the smallest shift per update worth detecting; must be below change_clip",
        0.0,
        50.0,
    ),
    ParamSpec(
        "estimator.change_threshold",
        20.0,
        "[sigma] CUSUM alarm level of the soil-change detector: larger, fewer false alarms and a longer delay",
        1e-3,
        1e6,
    ),
    ParamSpec(
        "estimator.change_clip",
        20.0,
        "[sigma] standardised corrections are clipped to +-clip before the CUSUM; with clip - change_drift below "
        "change_threshold no single outlier raises an alarm; must exceed change_drift",
        0.1,
        1e6,
    ),
    ParamSpec(
        "estimator.change_reopen_scale",
        0.5,
        "[-] on a soil change the stiffness std grows by this multiple of the innovation-implied jump "
        "(bounded below by change_ktot_std_frac / change_log_ks_std, above by the initial std; the motion "
        "states' variances grow by their initial values); 0 with a zero floor: no re-open",
        0.0,
        10.0,
    ),
    ParamSpec(
        "estimator.change_jump_gain",
        1.0,
        "[-] on a soil change the stiffness mean moves by this fraction of the innovation-implied jump "
        "(1: restart at the implied new soil; 0: re-open in place)",
        0.0,
        1.0,
    ),
    ParamSpec(
        "estimator.change_ktot_std_frac",
        0.2,
        "[-] least k_tot std added on a detected soil change, as a fraction of the series stiffness "
        "(stiffness_state k_tot)",
        0.0,
        1.0,
    ),
    ParamSpec(
        "estimator.change_log_ks_std",
        0.3,
        "[-] least std of ln k_s added on a detected soil change (stiffness_state log_k_s; 0.3: a factor 1.35)",
        0.0,
        5.0,
    ),
    ParamSpec(
        "estimator.profile_smoothing",
        0.0,
        "[s] window of the local quadratic fit of the profile (0: linear interpolation); "
        "0.01-0.02 for 0.5-1 mm profile noise",
        0.0,
        1.0,
    ),
    ParamSpec(
        "estimator.profile_max_gap", 0.02, "[s] a larger gap in the profile makes a step predict-only", 1e-4, 10.0
    ),
    ParamSpec("estimator.max_wait", 0.25, "[s] how long a step waits for the profile to cover it", 0.0, 10.0),
    ParamSpec(
        "estimator.max_extrapolation",
        0.005,
        "[s] how far past the last profile sample a late step may extrapolate the road",
        0.0,
        1.0,
    ),
    ParamSpec(
        "estimator.profile_noise_std",
        1e-4,
        "[m] std of the white noise on the profile elevations; inflates R by its effect on the predicted "
        "accelerations (0: noise-free profile)",
        0.0,
        0.1,
    ),
    ParamSpec(
        "estimator.hdot_window",
        0.06,
        "[m] road length of the centred fit giving dh/dt at the measurement time (LRV ground-referenced "
        "damper; 0: extrapolation)",
        0.0,
        1.0,
    ),
    ParamSpec("estimator.max_step", 0.5, "[s] a longer gap between steps restarts the motion states", 1e-3, 1e4),
    ParamSpec(
        "estimator.pair_timeout",
        0.05,
        "[s] how long a body accelerometer sample waits for the wheel sample of the same stamp",
        0.0,
        10.0,
    ),
    ParamSpec(
        "estimator.road_input",
        "profile",
        "what drives the road: 'profile' = the measured terrain/profile (1 kHz, MODELS.md A.10); 'stochastic' = "
        "no profile, the road is ISO 8608 shaped noise of class estimator.road_class at the travel speed "
        "(joint_states), k_s from the accelerometers alone (quarter car only; issue 21)",
        choices=("profile", "stochastic"),
        read_only=True,
    ),
    ParamSpec(
        "estimator.road_class",
        "D",
        "ISO 8608 class of the road assumed by road_input stochastic (its geometric-mean G_d(n0)); the level "
        "matters: a road twice as rough as assumed biases k_tot low",
        choices=tuple("ABCDEFGH"),
        read_only=True,
    ),
    ParamSpec(
        "estimator.road_gd_n0",
        0.0,
        "[m^3] G_d(n0) of the road (n0 = 0.1 cycles/m) for road_input stochastic, overriding road_class; "
        "0: the class mean",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "estimator.road_band_min",
        0.05,
        "[cycles/m] low cut of the stochastic road (keeps the elevation bounded)",
        0.001,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "estimator.road_band_max",
        10.0,
        "[cycles/m] band edge of the stochastic road (Butterworth high cut; tire enveloping limits real roads "
        "to about 10); 0: slope white to infinity",
        0.0,
        100.0,
        read_only=True,
    ),
    ParamSpec(
        "estimator.road_speed",
        0.0,
        "[m/s] travel speed for the stochastic road; 0: measured (joint_states wheel rate x vehicle.wheel_radius)",
        0.0,
        100.0,
        read_only=True,
    ),
    ParamSpec(
        "estimator.road_memory",
        5.0,
        "[s] time constant of the forgetting of the evidence on k_s in road_input stochastic (how long it "
        "remembers a soil; shorter follows a soil change sooner, with a larger variance)",
        0.1,
        1e4,
        read_only=True,
    ),
    ParamSpec(
        "estimator.road_allow_lrv",
        False,
        "run road_input stochastic on the LRV although its one accelerometer identifies k_tot only through "
        "the assumed road level (off: the node refuses, with the reason)",
        read_only=True,
    ),
    ParamSpec("frames.base_link", "base_link", "frame of the estimate (prefixed with the namespace)"),
)


#: What the estimator does while an input is silent (CONTRACT.md topics; shown in the timeout warning).
ON_TIMEOUT: dict[str, str] = {
    "imu_body": "no filter steps, the estimate holds (nothing is published); a gap longer than "
    "estimator.max_step restarts the motion states",
    "imu_wheel": "body-only updates after estimator.pair_timeout (predicting the wheel, correcting with the body)",
    "profile": "steps wait estimator.max_wait for the road, then are dropped: the estimate holds",
    "joint_states": "the reported travel speed holds (the filter does not use it)",
}

#: (key, topic, message type, default frame, default timeout [s], fields read).
_INPUTS: tuple[tuple[str, str, type, str, float, tuple[str, ...]], ...] = (
    ("imu_body", "imu/body", Imu, "body_imu", 0.5, ("linear_acceleration.z",)),
    ("imu_wheel", "imu/wheel", Imu, "wheel_imu", 0.5, ("linear_acceleration.z",)),
    ("profile", "terrain/profile", PointStamped, "odom", 0.5, ("point.x", "point.z")),
    ("joint_states", "joint_states", JointState, "", 0.5, ("velocity[wheel]",)),
)


def _input_keys(kind: str) -> tuple[str, ...]:
    return tuple(key for key, *_ in _INPUTS if kind == "quarter_car" or key != "imu_wheel")


def specs_for(kind: str) -> tuple[ParamSpec, ...]:
    """The estimator's parameter specs for ``kind`` (quarter_car | lrv)."""
    vehicle = VEHICLE_SPECS_LRV if kind == "lrv" else VEHICLE_SPECS_QUARTER_CAR
    inputs = [
        spec
        for key, topic, _type, frame, timeout, _fields in _INPUTS
        if key in _input_keys(kind)
        for spec in input_specs(key, topic, frame, timeout, ON_TIMEOUT[key])
    ]
    return vehicle + _filter_specs(kind) + _ESTIMATOR_SPECS + tuple(sorted(inputs, key=lambda s: s.name))


PARAMETERS = specs_for("quarter_car")

PROFILE_GAP_RATIO_WARN = 3.0
"""A step whose largest profile gap exceeds this multiple of the median spacing lost samples."""
PROFILE_GAP_WINDOW = 200
"""Steps over which lost profile samples are counted for the diagnostic (2 s at 100 Hz)."""
PROFILE_GAPPY_FRACTION_WARN = 0.05
"""Diagnostics turn WARN when more than this fraction of the window's steps lost profile samples."""


#: Float fields of SoilStiffnessEstimatorConfig read from the ``estimator.*`` parameter of the same name.
_ESTIMATOR_FLOATS = (
    "gravity",
    "convergence_rel_std",
    "class_log_std",
    "unknown_weight",
    "change_drift",
    "change_threshold",
    "change_clip",
    "change_reopen_scale",
    "change_jump_gain",
    "change_ktot_std_frac",
    "change_log_ks_std",
    "profile_noise_std",
)


def estimator_config(values: Mapping[str, ParamValue]) -> SoilStiffnessEstimatorConfig:
    """The core estimator's configuration from validated parameter values.

    Raises:
        ValueError: inconsistent values (e.g. a q_diag of the wrong length).
    """
    kind = str(values["vehicle.kind"])
    r = _f(values, "filter.accel_noise_variance")
    q_diag = tuple(float(v) for v in values["filter.q_diag"])
    p0_diag = tuple(float(v) for v in values["filter.p0_diag"])
    common: dict[str, Any] = {
        "q_ktot_per_step": _f(values, "filter.q_ktot_per_step"),
        "ktot_noise_form": str(values["filter.ktot_noise_form"]),
        "discretisation": str(values["filter.discretisation"]),
        "ekf_jacobian": str(values["filter.ekf_jacobian"]),
        "stiffness_state": str(values["filter.stiffness_state"]),
        "q_log_ks_per_step": _f(values, "filter.q_log_ks_per_step"),
    }
    n = 3 if kind == "lrv" else 5
    for name, diag in (("filter.q_diag", q_diag), ("filter.p0_diag", p0_diag)):
        if len(diag) != n:
            raise ValueError(f"{name} must hold {n} variances for {kind}, got {len(diag)}: {list(diag)}")
    common["q_diag"] = q_diag
    # The last P0 entry is in the stiffness state's units: catch a k_tot
    # variance left in place after switching the state (or the reverse).
    last = p0_diag[-1]
    if common["stiffness_state"] == "log_k_s" and last > 25.0:
        raise ValueError(
            f"filter.p0_diag[-1] = {last:g} is the variance of ln(k_s/k_series) with "
            "filter.stiffness_state = log_k_s and must be <= 25 (it looks like a k_tot variance in (N/m)^2)"
        )
    if common["stiffness_state"] == "k_tot" and last <= 25.0:
        raise ValueError(
            f"filter.p0_diag[-1] = {last:g} is a k_tot variance in (N/m)^2 with filter.stiffness_state = k_tot "
            "and must be > 25 (it looks like a variance of ln k_s)"
        )
    vehicle: dict[str, Any] = {}
    if kind == "lrv":
        vehicle["lrv"] = LRVParams(
            m_s=_f(values, "vehicle.sprung_mass"),
            k=_f(values, "vehicle.suspension_stiffness"),
            c=_f(values, "vehicle.suspension_damping"),
            relative_damper=values["vehicle.damper_reference"] == "ground",
            r_diag=(r,),
            **common,
        )
    else:
        vehicle["quarter_car"] = QuarterCarParams(
            m_s=_f(values, "vehicle.sprung_mass"),
            m_ns=_f(values, "vehicle.unsprung_mass"),
            k=_f(values, "vehicle.suspension_stiffness"),
            c=_f(values, "vehicle.suspension_damping"),
            k_t=_f(values, "vehicle.tire_stiffness"),
            r_diag=(r, r),
            **common,
        )
    k_tot0 = _f(values, "filter.k_tot0")
    gate = _f(values, "filter.gate_threshold")
    divergence = divergence_config(values)
    return SoilStiffnessEstimatorConfig(
        vehicle=values["vehicle.kind"],
        filter=values["filter.type"],
        filter_rate_hz=_f(values, "filter.rate"),
        substep_rate_hz=_f(values, "filter.substep_rate"),
        k_tot0=k_tot0 if k_tot0 > 0 else None,
        p0_diag=p0_diag,
        gate_threshold=gate if gate > 0 else None,
        divergence=divergence,
        **float_fields(values, "estimator", _ESTIMATOR_FLOATS),
        profile_smoothing_s=_f(values, "estimator.profile_smoothing"),
        profile_max_gap_s=_f(values, "estimator.profile_max_gap"),
        max_wait_s=_f(values, "estimator.max_wait"),
        max_extrapolation_s=_f(values, "estimator.max_extrapolation"),
        max_step_s=_f(values, "estimator.max_step"),
        hdot_window_m=_f(values, "estimator.hdot_window"),
        road_input=values["estimator.road_input"],
        road=RoadInputParams(
            iso_class=str(values["estimator.road_class"]),
            memory_s=_f(values, "estimator.road_memory"),
            allow_lrv=bool(values["estimator.road_allow_lrv"]),
            **float_fields(values, "estimator.road", ("gd_n0", "band_min", "band_max", "speed"), sep="_"),
        ),
        **vehicle,
    )


def estimate_to_msg(estimate: SoilStiffnessEstimate, frame_id: str) -> SoilStiffness:
    """The contract's SoilStiffness message of one estimate (all floats finite by the core).

    Built as its constructor and setters build it, without them (they cost a tenth of a quarter-car step):
    with rclpy's field checks off (the default), a setter only stores the value in its slot. With the checks
    on (``ROS_PYTHON_CHECK_FIELDS=1``) or another generated layout, through the constructor.
    """
    if not _DIRECT_OUTPUT:
        return _estimate_to_msg_checked(estimate, frame_id)
    sec, nanosec = stamp_parts(estimate.t)
    stamp = _new(Time)
    stamp._check_fields, stamp._sec, stamp._nanosec = False, sec, nanosec
    header = _new(Header)
    header._check_fields, header._stamp, header._frame_id = False, stamp, frame_id
    msg = _new(SoilStiffness)
    msg._check_fields = False
    msg._header = header
    msg._k_s = estimate.k_s
    msg._k_s_variance = estimate.k_s_variance
    msg._k_tot = estimate.k_tot
    msg._k_tot_variance = estimate.k_tot_variance
    msg._terrain_class = estimate.terrain_class
    msg._class_confidence = estimate.class_confidence
    msg._converged = estimate.converged
    msg._soil_change_detected = estimate.soil_change_detected
    msg._nis = estimate.nis
    return msg


#: The fields of SoilStiffness after its header, in slot order: each is the estimate's attribute of that name
#: (:func:`estimate_to_msg` writes them one by one: a loop over them would more than double its cost).
_MSG_FIELDS = tuple(
    "k_s k_s_variance k_tot k_tot_variance terrain_class class_confidence converged soil_change_detected nis".split()
)
_MSG_SLOTS = tuple(f"_{name}" for name in _MSG_FIELDS)
_msg_values = attrgetter(*_MSG_FIELDS)

_new = object.__new__
#: :func:`estimate_to_msg` fills the slots itself: rclpy's field checks are off and the classes have the slots it fills.
_DIRECT_OUTPUT = (
    not SoilStiffness()._check_fields
    and tuple(SoilStiffness.__slots__) == ("_header", *_MSG_SLOTS, "_check_fields")
    and list(Header.__slots__) == ["_stamp", "_frame_id", "_check_fields"]
    and list(Time.__slots__) == ["_sec", "_nanosec", "_check_fields"]
)


def _estimate_to_msg_checked(estimate: SoilStiffnessEstimate, frame_id: str) -> SoilStiffness:
    """:func:`estimate_to_msg` through the message's constructor and setters."""
    msg = SoilStiffness(**dict(zip(_MSG_FIELDS, _msg_values(estimate), strict=True)))
    msg.header.stamp = sec_to_stamp(estimate.t)
    msg.header.frame_id = frame_id
    return msg


class SoilStiffnessAdapter:
    """Messages ↔ :class:`SoilStiffnessEstimator` for one vehicle.

    Attributes:
        inputs_judged: set by the runner before each message (a
            :class:`~terrain_estimation.ros.framework.JudgedInputs`): while the input
            checks have not judged every accelerometer plausible, estimates are published
            with ``converged`` false (their input may still be found bad).
    """

    def __init__(self, values: Mapping[str, ParamValue], namespace: str) -> None:
        self.config = estimator_config(values)
        self.kind = self.config.vehicle
        self.estimator = make_estimator(self.config)
        self._profile_free = self.config.road_input == "stochastic"
        self.frame_id = namespaced_frame(namespace, str(values["frames.base_link"]))
        self.wheel_radius = _f(values, "vehicle.wheel_radius")
        self.pair_timeout_ns = round(_f(values, "estimator.pair_timeout") * 1e9)
        gravity = _f(values, "estimator.gravity")
        # Without a profile (road_input stochastic) the node neither needs nor waits for terrain/profile.
        keys = tuple(k for k in _input_keys(self.kind) if not (self._profile_free and k == "profile"))
        self.inputs: Sequence[TopicSpec] = tuple(
            TopicSpec(
                key,
                topic,
                msg_type,
                frame_id=input_frame(values, namespace, key),
                fields=fields,
                covariances=("linear_acceleration_covariance",) if msg_type is Imu else (),
                gravity_fields=fields if msg_type is Imu else (),
                gravity=gravity,
                timeout=_f(values, f"timeouts.{key}"),
                on_timeout=ON_TIMEOUT[key],
            )
            for key, topic, msg_type, _frame, _timeout, fields in _INPUTS
            if key in keys
        )
        self.outputs: Sequence[TopicSpec] = (
            TopicSpec("soil_stiffness", "soil_stiffness", SoilStiffness, "estimate", truth_fields=("k_s", "k_tot")),
        )
        self.inputs_judged = True
        self.reset()

    def reset(self) -> None:
        self.estimator.reset()
        self.health = AdapterHealth(nis_dof=2 if self.kind == "quarter_car" else 1)
        self._body: dict[int, float] = {}
        self._wheel: dict[int, float] = {}
        self.travel_speed = math.nan
        self._profile_gappy: deque[bool] = deque(maxlen=PROFILE_GAP_WINDOW)
        self._gappy_count = 0  # True entries of _profile_gappy

    # -- accelerometer pairing -------------------------------------------------
    def _flush_before(self, stamp_ns: int) -> None:
        """Use waiting body samples older than ``stamp_ns`` alone; drop older wheel samples."""
        # Runs on every accelerometer message; usually nothing is older.
        if not ((self._body and min(self._body) < stamp_ns) or (self._wheel and min(self._wheel) < stamp_ns)):
            return
        for t in sorted(t for t in self._body if t < stamp_ns):
            self.health.reject("imu/wheel: no sample with the body stamp (body-only update)")
            self.estimator.add_accelerations(t * 1e-9, self._body.pop(t), None)
        for t in [t for t in self._wheel if t < stamp_ns]:
            self.health.reject("imu/wheel: no body sample with its stamp (dropped)")
            del self._wheel[t]

    def _on_body(self, stamp_ns: int, z: float) -> None:
        if self.kind == "lrv":
            self.estimator.add_accelerations(stamp_ns * 1e-9, z, None)
            return
        if stamp_ns in self._wheel:
            self._flush_before(stamp_ns)
            self.estimator.add_accelerations(stamp_ns * 1e-9, z, self._wheel.pop(stamp_ns))
            return
        self._body[stamp_ns] = z
        self._flush_before(stamp_ns - self.pair_timeout_ns)

    def _on_wheel(self, stamp_ns: int, z: float) -> None:
        if stamp_ns in self._body:
            self._flush_before(stamp_ns)
            self.estimator.add_accelerations(stamp_ns * 1e-9, self._body.pop(stamp_ns), z)
            return
        self._wheel[stamp_ns] = z
        self._flush_before(stamp_ns - self.pair_timeout_ns)

    # -- adapter protocol --------------------------------------------------------
    def handle(self, key: str, msg: Any) -> list[tuple[str, Any]]:
        if key == "profile":
            point = msg.point
            return self.handle_profile(stamp_to_ns(msg.header.stamp), (point.x, point.z))
        if key == "imu_body":
            return self.handle_body(stamp_to_ns(msg.header.stamp), (msg.linear_acceleration.z,))
        if key == "imu_wheel":
            return self.handle_wheel(stamp_to_ns(msg.header.stamp), (msg.linear_acceleration.z,))
        if key == "joint_states":
            self._on_joints(msg)  # the stamp is not used
        return self._outputs()

    def handle_profile(self, stamp_ns: int, values: Sequence[float]) -> list[tuple[str, Any]]:
        """:meth:`handle` of a profile sample given by its stamp and checked fields (``point.x``, ``point.z``)
        (:attr:`field_handlers`). Most samples (9 in 10 at 1 kHz against a 100 Hz filter) complete no step: no
        estimate was made (every call drains them all) and the fault, which only a step changes, is unchanged."""
        if self.estimator.add_profile_sample(stamp_ns * 1e-9, values[0], values[1]) is None:
            return []
        return self._outputs()

    def handle_profile_run(self, stamps_ns: Sequence[int], values: Sequence[Sequence[float]]) -> list[tuple[int, Any]]:
        """:meth:`handle_profile` of each sample in turn (:attr:`field_runs`): (index, outputs) of those with
        outputs. The samples that complete no step are appended together (``add_profile_samples``)."""
        out: list[tuple[int, Any]] = []
        i, n, append_run = 0, len(stamps_ns), self.estimator.add_profile_samples
        t = [stamp_ns * 1e-9 for stamp_ns in stamps_ns]  # as handle_profile converts each
        distance, elevation = [v[0] for v in values], [v[1] for v in values]
        while i < n:
            i = append_run(t, distance, elevation, i, n)
            if i < n:
                produced = self.handle_profile(stamps_ns[i], values[i])
                if produced:
                    out.append((i, produced))
                i += 1
        return out

    def handle_body(self, stamp_ns: int, values: Sequence[float]) -> list[tuple[str, Any]]:
        """:meth:`handle` of a body accelerometer sample given by its stamp and ``linear_acceleration.z``."""
        self._on_body(stamp_ns, values[0])
        return self._outputs()

    def handle_wheel(self, stamp_ns: int, values: Sequence[float]) -> list[tuple[str, Any]]:
        """:meth:`handle` of a wheel accelerometer sample given by its stamp and ``linear_acceleration.z``."""
        self._on_wheel(stamp_ns, values[0])
        return self._outputs()

    @property
    def field_handlers(self) -> Mapping[str, Callable[[int, Sequence[float]], list[tuple[str, Any]]]]:
        """Input key -> the handler taking a message's stamp (ns) and its checked fields (the TopicSpec's
        ``fields`` then ``gravity_fields``, in order) in place of the message: :meth:`handle` of that message."""
        return {"profile": self.handle_profile, "imu_body": self.handle_body, "imu_wheel": self.handle_wheel}

    @property
    def field_runs(self) -> Mapping[str, Callable[[Sequence[int], Any], list[tuple[int, Any]]]]:
        """Input key -> the handler of a run of its samples (stamps, fields): the profile, unless profile-free."""
        return {"profile": self.handle_profile_run} if hasattr(self.estimator, "add_profile_samples") else {}

    def _outputs(self) -> list[tuple[str, Any]]:
        estimates = self._drain()
        if not estimates:  # most messages (≈ 12 of 13 on the quarter car) complete no step
            return []
        frame_id = self.frame_id
        return [("soil_stiffness", estimate_to_msg(e, frame_id)) for e in estimates]

    def _on_joints(self, msg: Any) -> None:
        names = list(msg.name)
        if "wheel" in names and len(msg.velocity) == len(names):
            rate = float(msg.velocity[names.index("wheel")])
            if math.isfinite(rate):
                self.travel_speed = rate * self.wheel_radius
                if self._profile_free:
                    self.estimator.add_speed(stamp_to_ns(msg.header.stamp) * 1e-9, abs(self.travel_speed))

    def _drain(self) -> list[SoilStiffnessEstimate]:
        estimates = self.estimator.drain_estimates()
        if not estimates:  # most messages: only the fault is looked at
            self._fault_errors()
            return estimates
        if not self.inputs_judged:
            estimates = [replace(e, converged=False) if e.converged else e for e in estimates]
        h = self.health
        gappy_steps = self._profile_gappy
        for e in estimates:
            h.updates += 1
            h.last_update_time = e.t
            if e.accepted:
                h.nis.append(e.nis)
            lost = e.profile_gap_ratio > PROFILE_GAP_RATIO_WARN
            if len(gappy_steps) == gappy_steps.maxlen:
                self._gappy_count -= gappy_steps[0]  # about to drop out of the window
            gappy_steps.append(lost)
            self._gappy_count += lost
        if estimates:
            last = estimates[-1]
            c = self.estimator.counts
            h.status = f"k_s {last.k_s / 1e3:.1f} kN/m, {last.terrain_class} ({last.class_confidence:.2f})" + (
                ", converged" if last.converged else ", converging"
            )
            gappy = self._gappy_count  # sum(self._profile_gappy), kept as the window moves
            n = len(self._profile_gappy)
            h.warnings = (
                [
                    f"terrain/profile: {gappy} of the last {n} steps lost profile samples (gap > "
                    f"{PROFILE_GAP_RATIO_WARN:g}x the sample spacing): the road between steps is interpolated "
                    "and k_s biased; the node is not keeping up with the profiler, or the sensor drops samples"
                ]
                if gappy > PROFILE_GAPPY_FRACTION_WARN * n
                else []
            )
            h.values.update(
                k_s=last.k_s,
                profile_gappy_steps=gappy,
                k_s_std=math.sqrt(last.k_s_variance),
                terrain_class=last.terrain_class,
                travel_speed=self.travel_speed,
                soil_changes=c["soil_changes"],
                restarts=c["restarts"],
                gated=c["gated"],
                dropped_nonfinite=c["dropped_nonfinite"],
                dropped_out_of_order=c["dropped_out_of_order"],
                dropped_no_profile=c["dropped_no_profile"],
                profile_rejected=c["profile_rejected"],
                divergences=c["divergences"],
            )
        self._fault_errors()
        return estimates

    def _fault_errors(self) -> None:
        """The diagnostics' errors from the estimator's fault."""
        # Runs for most input messages: the counters are read only for a fault, an empty list is left as it is.
        fault = self.estimator.fault
        h = self.health
        if fault:
            h.errors = divergence_errors(fault, self.estimator.counters.divergences)
        elif h.errors:
            h.errors = []


def make_adapter(values: Mapping[str, ParamValue], namespace: str) -> SoilStiffnessAdapter:
    return SoilStiffnessAdapter(values, namespace)
