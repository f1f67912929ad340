"""Parameters of the skid-steer estimator node: specs, the vehicle and the estimator configuration they give.

The specs (name, default, description with unit, range) of every parameter the
node declares (:data:`PARAMETERS`; the ``vehicle.*`` ones, :data:`VEHICLE_SPECS_SKID_STEER`,
shared with the simulator node, which reads the same ``/**`` section), and the
conversion of validated values into :class:`~terrain_estimation.models.skid_steer.SkidSteerParams`
(:func:`vehicle_params`) and
:class:`~terrain_estimation.estimators.skid_steer.SkidSteerEstimatorConfig`
(:func:`estimator_config`). Re-exported by :mod:`terrain_estimation.ros.skid_steer`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from terrain_estimation.estimators.skid_steer import MODELS, SkidSteerEstimatorConfig
from terrain_estimation.estimators.skid_steer_consider import CONSIDER_NAMES, ConsiderConfig
from terrain_estimation.estimators.skid_steer_wheels import INTERPOLATIONS
from terrain_estimation.estimators.skid_steer_zupt import ZuptConfig
from terrain_estimation.filters.adaptive import StrongTrackingConfig
from terrain_estimation.filters.an_stukf import VARIANTS
from terrain_estimation.filters.noise_adaptation import InnovationNoiseConfig
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.models.skid_steer_scales import GRAVITY_NAMES, RESISTANCE_NAME, SCALE_NAMES, TireScaleConfig
from terrain_estimation.params import ParamSpec, ParamValue, default_config_path, load_parameter_file
from terrain_estimation.ros.parameters import (
    divergence_config,
    divergence_specs,
    fixed_floats,
    float_fields,
    input_specs,
    kind_specs,
)
from terrain_estimation.ros.parameters import float_value as _f

__all__ = [
    "VEHICLE_SPECS_SKID_STEER",
    "PARAMETERS",
    "ON_TIMEOUT",
    "estimator_config",
    "vehicle_params",
    "specs_for",
    "husky_overrides",
]

_D = SkidSteerParams()
_EC = SkidSteerEstimatorConfig()
_TS = TireScaleConfig()
_CC = SkidSteerEstimatorConfig().consider
_ZU = ZuptConfig()


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
    ParamSpec(
        "vehicle.axle_x",
        [0.0],
        "[m] axle positions relative to the centre of mass, front to rear (at least 2, strictly decreasing): "
        "the geometry of a vehicle with any number of axles per side, e.g. [0.256, -0.256] for a 4-wheel Husky. "
        "A single entry (the default [0.0]): the paper's three axles from vehicle.axle_spacing_front, "
        "vehicle.axle_spacing_rear and vehicle.cm_ahead_of_middle_axle",
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
_NA = SkidSteerEstimatorConfig().noise_adaptation


_ESTIMATOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "filter.type",
        _EC.filter,
        "filter: plain UKF (B.8), strong-tracking UKF (B.9), adaptive-noise strong-tracking UKF (B.10, the paper's), "
        "adaptive (strong tracking on whitened innovations and Q/R scales matched to the innovations, B.12; "
        "adaptive_noise.*) or adaptive_sideslip (adaptive plus the B.10 sideslip law, guarded at low speed)",
        choices=VARIANTS,
    ),
    ParamSpec(
        "filter.model",
        _EC.model,
        "observer model: brush (the paper's 3-state tire-force model), brush_scales (+ tire-parameter scale "
        "states, tire_scales.*), kinematic (IMU-driven kinematics with the tire forces as pseudo-measurements, "
        "kinematic.*), kinematic_scales (both); every model publishes the same vx, vy, r",
        choices=MODELS,
    ),
    ParamSpec(
        "filter.ukf_alpha", 1.0, "[-] sigma-point spread alpha (small values give negative weights, n = 3)", 1e-3, 10.0
    ),
    ParamSpec("filter.ukf_beta", 2.0, "[-] UKF beta (2: Gaussian prior)", 0.0, 10.0),
    ParamSpec("filter.ukf_kappa", 0.0, "[-] UKF kappa (3 - n = 0)", -2.9, 10.0),
    ParamSpec("filter.gate_threshold", 0.0, "[-] NIS gate on updates (chi^2_3 quantile); 0 disables", 0.0, 1e6),
    *divergence_specs(
        "false: with B.10's noise (the paper's filters) the mean NIS is 0.2-0.5 against 3 on healthy data "
        "(refused for an_stukf, whose adaptive noise rescales the innovations)"
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
    ParamSpec(
        "strong_tracking.criterion",
        "auto",
        "when strong tracking acts and how large: paper (B.9: e'e against gamma_th tr(P_zz), which mixes m/s^2 and "
        "rad/s), whitened (B.12: NIS against its chi^2 quantile strong_tracking.probability, fading factor on "
        "whitened innovations), auto (paper for stukf and an_stukf, whitened for the adaptive filters)",
        choices=("auto", "paper", "whitened"),
    ),
    ParamSpec(
        "strong_tracking.probability",
        0.99,
        "[-] criterion whitened: strong tracking acts when the NIS exceeds its chi^2_3 quantile of this probability",
        0.5,
        0.999999,
    ),
    *(
        ParamSpec(
            f"tire_scales.{name}",
            name in _TS.states,
            f"filter.model brush_scales / kinematic_scales: estimate a scale of vehicle.{name} as a state",
        )
        for name in SCALE_NAMES
    ),
    ParamSpec(
        "tire_scales.walk_std",
        _TS.walk_std,
        "[1/sqrt(s)] random walk of each ln(scale): how fast the tire parameters may change (0.02: ~6 % in 10 s)",
        0.0,
        10.0,
    ),
    ParamSpec(
        "tire_scales.initial_std",
        _TS.initial_std,
        "[-] standard deviation of each ln(scale) at (re)initialisation (0.3: nominal within ~35 %)",
        0.0,
        10.0,
    ),
    ParamSpec(
        f"tire_scales.{RESISTANCE_NAME}",
        RESISTANCE_NAME in _TS.states,
        "filter.model brush_scales / kinematic_scales: estimate the motion-resistance coefficient (rolling, "
        "bulldozing; force per unit normal load) as a Gauss-Markov state around tire_scales.resistance_nominal. "
        "It is not observable in a steady run (it trades with the longitudinal slip): prefer "
        "consider.motion_resistance, which widens the variances instead",
    ),
    ParamSpec(
        "tire_scales.resistance_nominal",
        _TS.resistance_nominal,
        "[-] prior mean of the estimated motion-resistance coefficient (0.01-0.03 firm ground, 0.05-0.15 grass, "
        "sand, mud)",
        0.0,
        1.0,
    ),
    ParamSpec(
        "tire_scales.resistance_std",
        _TS.resistance_std,
        "[-] prior and stationary standard deviation of the estimated motion-resistance coefficient",
        0.0,
        1.0,
    ),
    ParamSpec(
        "tire_scales.resistance_time",
        _TS.resistance_time_s,
        "[s] correlation time of the estimated motion-resistance coefficient",
        1e-3,
        1e6,
    ),
    ParamSpec(
        "tire_scales.resistance_max",
        _TS.resistance_max,
        "[-] upper bound of the estimated motion-resistance coefficient (> resistance_nominal)",
        1e-3,
        1.0,
    ),
    ParamSpec(
        "tire_scales.resistance_speed",
        _TS.resistance_speed,
        "[m/s] smoothing speed v0 of the resistance's direction, tanh(v_wheel/v0)",
        1e-3,
        10.0,
    ),
    ParamSpec(
        "tire_scales.ground_slope",
        _TS.slope,
        "filter.model brush_scales / kinematic_scales: estimate the ground slope as gravity's body-frame x, y "
        "components (states gravity_x, gravity_y) in the process model; off by default: it helps on a bank and "
        "costs on level ground (figures: docs/results/skid_steer_fair.md); runs the Python filter step",
    ),
    ParamSpec(
        "tire_scales.slope_std",
        _TS.slope_std,
        "[m/s^2] prior and stationary standard deviation of each gravity component (1: about 6 deg)",
        1e-3,
        10.0,
    ),
    ParamSpec("tire_scales.slope_time", _TS.slope_time_s, "[s] correlation time of the gravity components", 1e-3, 1e9),
    ParamSpec(
        "tire_scales.slope_max", _TS.slope_max, "[m/s^2] bound of each gravity component (5: about 30 deg)", 1e-3, 9.81
    ),
    *(
        ParamSpec(
            f"consider.{name}",
            name in _CC.parameters,
            f"include in the published variances what an unestimated {name.replace('_', ' ')} does to the "
            "estimate (a consider parameter, Schmidt: the estimate is unchanged, its variance widened by the "
            "sensitivity to the parameter's deviation; skipped when tire_scales estimates it)",
        )
        for name in CONSIDER_NAMES
    ),
    ParamSpec(
        "consider.scale_std",
        _CC.scale_std,
        "[-] rms deviation of ln(scale) of each considered tire stiffness (the friction: consider.friction_std; "
        "0.3: nominal within ~35 %)",
        0.0,
        10.0,
    ),
    ParamSpec(
        "consider.friction_std",
        _CC.friction_std,
        "[-] rms deviation of ln(friction scale) when consider.friction is on (0.3: mu of one tire on firm ground "
        "within ~30 %; between asphalt, gravel, grass and mud mu varies by a factor of 3). In a skid-steer turn the "
        "tires of one side slide, so the lateral velocity's sensitivity to mu is large there (about 0.04 m/s per "
        "10 % in a 3 m/s, 0.6 rad/s turn): off by default (figures: estimators/skid_steer_consider.py)",
        0.0,
        10.0,
    ),
    ParamSpec(
        "consider.resistance_rms",
        _CC.resistance_rms,
        "[-] rms motion-resistance coefficient the observer's model leaves out (0.02: tires on firm ground; "
        "0.05-0.1 on soft soil)",
        0.0,
        1.0,
    ),
    ParamSpec("tire_scales.min", _TS.min_scale, "[-] lower bound of every scale (< 1)", 1e-3, 0.999),
    ParamSpec("tire_scales.max", _TS.max_scale, "[-] upper bound of every scale (> 1)", 1.001, 1e3),
    ParamSpec(
        "tire_scales.reversion_time",
        _TS.reversion_time_s,
        "[s] time constant of the return of each ln(scale) to 0 (scale 1) where nothing is learned (a Gauss-Markov "
        "scale instead of a random walk); 0: none",
        0.0,
        1e6,
    ),
    ParamSpec(
        "kinematic.process_accel_std",
        _EC.process_accel_std,
        "[m/s^2] filter.model kinematic*: accelerometer noise, vibration and gravity leakage integrated by the process",
        1e-4,
        100.0,
    ),
    ParamSpec(
        "kinematic.tire_model_std",
        _EC.tire_model_std,
        "[m/s^2] filter.model kinematic*: error of the brush model's force per unit mass (the tire "
        "pseudo-measurement's trust), added to the accelerometer noise of filter.r0_diag",
        0.0,
        100.0,
    ),
    ParamSpec(
        "kinematic.tire_moment_std",
        _EC.tire_moment_std,
        "[rad/s^2] filter.model kinematic*: error of the brush model's yaw moment per unit yaw inertia (the trust "
        "of the yaw-moment pseudo-measurement against the differenced gyro)",
        0.0,
        1000.0,
    ),
    ParamSpec("adaptive_noise.k_q", 5.0, "[1/rad] Q0 grows as (1 + k_q mean|alpha|) (B.10)", 0.0, 1e4),
    ParamSpec("adaptive_noise.k_r", 2.0, "[1/rad] R0 shrinks as 1/(1 + k_r mean|alpha|) (B.10)", 0.0, 1e4),
    ParamSpec(
        "adaptive_noise.adapt_r",
        _NA.adapt_r,
        "filter.type adaptive*: scale each channel of R0 by what its innovations show (covariance matching); off by "
        "default: R0 is the IMU's noise, and one-step innovations cannot separate Q from R",
    ),
    ParamSpec("adaptive_noise.adapt_q", _NA.adapt_q, "filter.type adaptive*: scale Q0 by what the innovations show"),
    ParamSpec(
        "adaptive_noise.r_forgetting",
        _NA.r_forgetting,
        "[-] filter.type adaptive*: forgetting of the R scales; memory 1/(1 - b) steps (0.98: 50 steps, 0.5 s)",
        0.0,
        0.9999,
    ),
    ParamSpec(
        "adaptive_noise.q_forgetting",
        _NA.q_forgetting,
        "[-] filter.type adaptive*: forgetting of the Q scale, as adaptive_noise.r_forgetting",
        0.0,
        0.9999,
    ),
    ParamSpec("adaptive_noise.r_floor", _NA.r_floor, "[-] lowest R scale (R_k,ii / R0_ii)", 1e-6, 1.0),
    ParamSpec("adaptive_noise.r_ceiling", _NA.r_ceiling, "[-] highest R scale", 1.0, 1e6),
    ParamSpec("adaptive_noise.q_floor", _NA.q_floor, "[-] lowest Q scale (Q_k / Q0)", 1e-6, 1.0),
    ParamSpec("adaptive_noise.q_ceiling", _NA.q_ceiling, "[-] highest Q scale", 1.0, 1e6),
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
        0.0,
        "[s] wheel speeds further than this from the IMU stamp are stale: the step is skipped; 0: "
        "estimator.wheel_speed_age_periods measured joint-state periods, at least estimator.min_wheel_speed_age",
        0.0,
        10.0,
    ),
    ParamSpec(
        "estimator.wheel_speed_age_periods",
        _EC.wheel_speed_age_periods,
        "[-] age limit of the wheel speeds in periods of the joint states (running median of the measured "
        "periods) when estimator.max_wheel_speed_age is 0",
        0.5,
        100.0,
    ),
    ParamSpec(
        "estimator.min_wheel_speed_age",
        _EC.min_wheel_speed_age_s,
        "[s] floor of the age limit derived from the measured joint-state period",
        1e-4,
        10.0,
    ),
    ParamSpec(
        "estimator.wheel_speed_interpolation",
        _EC.wheel_speed_interpolation,
        "wheel speeds at the IMU stamp: linear between the joint states that bracket it (the newest held beyond "
        "it), or hold (the newest joint state not after the stamp)",
        choices=INTERPOLATIONS,
    ),
    ParamSpec(
        "estimator.wheel_speed_wait",
        _EC.wheel_speed_wait_s,
        "[s] an IMU sample newer than the newest joint state waits up to this long for the next one, to be "
        "interpolated instead of held (latency of the estimates); 0: never wait",
        0.0,
        10.0,
    ),
    ParamSpec("estimator.max_step", 0.1, "[s] a longer gap between IMU samples restarts the filter", 1e-3, 1e4),
    ParamSpec(
        "zupt.enabled",
        _ZU.enabled,
        "zero-velocity update (vx = vy = 0, r = mean gyro) while the wheels are stopped and the IMU is quiet",
    ),
    ParamSpec(
        "zupt.wheel_speed", _ZU.wheel_speed, "[m/s] rim speed below which a side's wheels are stopped", 1e-5, 10.0
    ),
    ParamSpec("zupt.window", _ZU.window_s, "[s] IMU window of the stationary test", 0.02, 60.0),
    ParamSpec("zupt.min_samples", _ZU.min_samples, "[samples] fewest IMU samples in the window", 2, 100000),
    ParamSpec(
        "zupt.accel_std",
        _ZU.accel_std,
        "[m/s^2] largest standard deviation of a_x and a_y over the window (IMU quiet)",
        1e-4,
        100.0,
    ),
    ParamSpec(
        "zupt.gyro_std",
        _ZU.gyro_std,
        "[rad/s] largest standard deviation of the yaw rate over the window (IMU quiet)",
        1e-5,
        10.0,
    ),
    ParamSpec("zupt.velocity_std", _ZU.velocity_std, "[m/s] standard deviation of the vx = vy = 0 update", 1e-5, 10.0),
    ParamSpec(
        "zupt.yaw_rate_std",
        _ZU.yaw_rate_std,
        "[rad/s] standard deviation of the r = mean gyro update",
        1e-6,
        10.0,
    ),
    ParamSpec(
        "odom.twist_correlation_time",
        _EC.odom_correlation_time_s,
        "[s] correlation time of the twist error in the dead-reckoned pose covariance (the filter's error is a "
        "slowly varying bias, not white: its integral grows by 2 tau var per second); 0: white",
        0.0,
        1e4,
    ),
    ParamSpec("joints.left_motor", "left_motor", "joint_states name of the left motor"),
    ParamSpec("joints.right_motor", "right_motor", "joint_states name of the right motor"),
    ParamSpec("frames.base_link", "base_link", "child frame of odom (prefixed with the namespace)"),
    ParamSpec("frames.odom", "odom", "frame of the dead-reckoned pose (prefixed with the namespace)"),
)


#: What the estimator does while an input is silent (shown in the timeout warning).
ON_TIMEOUT: dict[str, str] = {
    "imu": "no filter steps: odom and skid_steer/state hold (nothing is published); a gap longer than "
    "estimator.max_step restarts the filter",
    "joint_states": "IMU samples whose wheel speeds are older than the age limit (estimator.max_wheel_speed_age, "
    "or estimator.wheel_speed_age_periods measured periods) are skipped: the estimate holds",
}

_INPUT_SPECS: tuple[ParamSpec, ...] = (
    *input_specs("imu", "imu", "imu_link", 0.5, ON_TIMEOUT["imu"]),
    *input_specs("joint_states", "joint_states", "", 0.5, ON_TIMEOUT["joint_states"]),
)


def specs_for(kind: str = "skid_steer") -> tuple[ParamSpec, ...]:
    """The estimator's parameter specs (one vehicle kind)."""
    return kind_specs(kind, "skid_steer", "skid-steer", VEHICLE_SPECS_SKID_STEER, _ESTIMATOR_SPECS, _INPUT_SPECS)


PARAMETERS = specs_for()


#: Float fields read from the parameter of the same name: SkidSteerParams (every ``vehicle.*`` parameter that
#: names one of its fields, axle_x aside), TireScaleConfig (``tire_scales.*``) and InnovationNoiseConfig
#: (``adaptive_noise.*``).
_VEHICLE_FLOATS = tuple(
    name
    for spec in VEHICLE_SPECS_SKID_STEER
    if (name := spec.name.removeprefix("vehicle.")) in SkidSteerParams.__dataclass_fields__ and name != "axle_x"
)
_TIRE_SCALE_FLOATS = (
    "walk_std",
    "initial_std",
    "resistance_nominal",
    "resistance_std",
    "resistance_max",
    "resistance_speed",
    "slope_std",
    "slope_max",
)
_NOISE_ADAPTATION_FLOATS = ("r_forgetting", "q_forgetting", "r_floor", "r_ceiling", "q_floor", "q_ceiling")


def _triple(values: Mapping[str, ParamValue], name: str) -> tuple[float, float, float]:
    v = fixed_floats(values, name, 3, "[vx, vy, r] order")
    return v[0], v[1], v[2]


def vehicle_params(values: Mapping[str, ParamValue]) -> SkidSteerParams:
    """The nominal vehicle of the ``vehicle.*`` parameters.

    Raises:
        ValueError: ``vehicle.axle_x`` with two or more entries that do not decrease strictly.
    """
    axles = [float(v) for v in values.get("vehicle.axle_x", [0.0])]
    return SkidSteerParams(
        axle_x=tuple(axles) if len(axles) >= 2 else None,
        **float_fields(values, "vehicle", _VEHICLE_FLOATS),
    )


def estimator_config(values: Mapping[str, ParamValue]) -> SkidSteerEstimatorConfig:
    """The core estimator's configuration from validated parameter values.

    Raises:
        ValueError: inconsistent values (e.g. a noise diagonal of the wrong length).
    """
    gate = _f(values, "filter.gate_threshold")
    gamma_th = _f(values, "strong_tracking.gamma_th")
    strong = StrongTrackingConfig(
        gamma_th=gamma_th if gamma_th > 0.0 else None,
        criterion=None if values["strong_tracking.criterion"] == "auto" else values["strong_tracking.criterion"],
        **float_fields(values, "strong_tracking", ("rho", "beta_w", "lambda_max", "probability")),
    )
    scales = TireScaleConfig(
        states=tuple(name for name in (*SCALE_NAMES, RESISTANCE_NAME) if bool(values[f"tire_scales.{name}"]))
        + (GRAVITY_NAMES if bool(values["tire_scales.ground_slope"]) else ()),
        min_scale=_f(values, "tire_scales.min"),
        max_scale=_f(values, "tire_scales.max"),
        reversion_time_s=_f(values, "tire_scales.reversion_time"),
        resistance_time_s=_f(values, "tire_scales.resistance_time"),
        slope_time_s=_f(values, "tire_scales.slope_time"),
        **float_fields(values, "tire_scales", _TIRE_SCALE_FLOATS),
    )
    consider = ConsiderConfig(
        parameters=tuple(name for name in CONSIDER_NAMES if bool(values[f"consider.{name}"])),
        **float_fields(values, "consider", ("scale_std", "friction_std", "resistance_rms")),
    )
    zupt = ZuptConfig(
        enabled=bool(values["zupt.enabled"]),
        window_s=_f(values, "zupt.window"),
        min_samples=int(values["zupt.min_samples"]),
        **float_fields(values, "zupt", ("wheel_speed", "accel_std", "gyro_std", "velocity_std", "yaw_rate_std")),
    )
    max_age = _f(values, "estimator.max_wheel_speed_age")
    return SkidSteerEstimatorConfig(
        vehicle=vehicle_params(values),
        filter=values["filter.type"],
        model=values["filter.model"],
        tire_scales=scales,
        consider=consider,
        **float_fields(values, "kinematic", ("process_accel_std", "tire_model_std", "tire_moment_std")),
        **float_fields(values, "filter", ("ukf_alpha", "ukf_beta", "ukf_kappa")),
        gate_threshold=gate if gate > 0.0 else None,
        strong_tracking=strong,
        **float_fields(values, "adaptive_noise", ("k_q", "k_r")),
        noise_adaptation=InnovationNoiseConfig(
            adapt_r=bool(values["adaptive_noise.adapt_r"]),
            adapt_q=bool(values["adaptive_noise.adapt_q"]),
            **float_fields(values, "adaptive_noise", _NOISE_ADAPTATION_FLOATS),
        ),
        q0_diag=_triple(values, "filter.q0_diag"),
        r0_diag=_triple(values, "filter.r0_diag"),
        p0_diag=_triple(values, "filter.p0_diag"),
        accel_cutoff_hz=_f(values, "estimator.accel_cutoff"),
        max_wheel_speed_age_s=max_age if max_age > 0.0 else None,
        min_wheel_speed_age_s=_f(values, "estimator.min_wheel_speed_age"),
        **float_fields(values, "estimator", ("min_yaw_rate", "min_sideslip_speed", "wheel_speed_age_periods")),
        wheel_speed_interpolation=values["estimator.wheel_speed_interpolation"],
        wheel_speed_wait_s=_f(values, "estimator.wheel_speed_wait"),
        max_step_s=_f(values, "estimator.max_step"),
        zupt=zupt,
        odom_correlation_time_s=_f(values, "odom.twist_correlation_time"),
        divergence=divergence_config(values),
        max_speed=_f(values, "vehicle.max_speed"),
        max_yaw_rate=_f(values, "vehicle.max_yaw_rate"),
    )


def husky_overrides(path: str | Path | None = None) -> dict[str, Any]:
    """The estimator's parameters for the BorealTC Husky: ``config/husky.yaml`` (default) read as this node.

    That file's ``/**`` section describes the 4-wheel Husky for the sim-to-real replay and the importer
    (names this node does not declare, ``vehicle.kind: husky``); its ``/**/skid_steer_estimator`` section
    holds this node's view of it (two axles, per-wheel stiffnesses, noise of the BorealTC IMU). Returns the
    names this node declares, the section over ``/**``, for ``overrides=`` of
    :func:`~terrain_estimation.tools.estimate.estimate_bag` (namespace ``/husky``). The offline tool reads
    such a file by itself (``terrain-estimate BAG --vehicle skid_steer --config config/husky.yaml``).
    """
    values = load_parameter_file(path if path is not None else default_config_path("husky"), ["skid_steer_estimator"])
    declared = {s.name for s in PARAMETERS}
    return {name: value for name, value in values.items() if name in declared}
