"""Rocker-bogie terrain-response estimator (Estimators 1 + 2|3, online terrain model): parameters and adapter.

Topics (CONTRACT.md, "Rocker-bogie rover"), relative to the vehicle namespace:

* in: ``imu`` (sensor_msgs/Imu: ``linear_acceleration.x``, ``.z`` = specific
  force along the body axes, gravity included, REP 145; ``angular_velocity.y``
  = pitch rate), ``joint_states`` (sensor_msgs/JointState: ``position`` of the
  joints ``bogie`` (q1) and ``rear_wheel``, ``middle_wheel``,
  ``front_wheel`` (q2..q4, relative to their carrier link), ``effort`` of
  the three wheels = applied wheel torque τ_W; ``velocity`` is not used: the
  rates are encoder differences over each step, eq. 63), ``velocimeter``
  (geometry_msgs/TwistStamped: ``twist.linear.x``), ``wheel/front/load``,
  ``wheel/middle/load``, ``wheel/rear/load`` (geometry_msgs/WrenchStamped in
  the cell's frame: ``force.z`` = F_L along the sensing axis, ``force.x`` =
  F_⊥ along the carrier's forward axis, read only with
  ``estimator.load_cell_axes: 2``). Joint names are parameters.
* out: ``wheel_terrain`` (terrain_msgs/WheelTerrainArray) — one message per
  estimator step (5 Hz), ``wheels`` in the order **rear, middle, front**
  ([RB] wheels 1, 2, 3; :data:`~terrain_estimation.models.rover.WHEELS`),
  each named in its ``wheel`` field. ``contact_angle`` is γ, the angle of the
  terrain tangent under the wheel below the world horizontal (rad, positive
  where the terrain descends forward; eqs. 79–82), not the Wong–Reece entry
  angle θ0. Variances are the filters' posterior variances.
  ``terrain_model`` (terrain_msgs/TerrainResponseModel) — the 2nd-order
  DP(W, i) and τ_R(W, i) fitted online (C.7); coefficients in the order of
  :func:`~terrain_estimation.models.terrain_response.polynomial_exponents`
  (for total degree d = 0..order, for k = d..0: the term i^k W^(d−k); order 2:
  ``[1, i, W, i², i·W, W²]``), validity region = the fitted samples' (i, W)
  range. Its error: ``dp_covariance``/``tau_covariance`` (n × n, row-major) of
  the coefficients, ``*_holdout_rms`` on samples the fit did not see,
  ``*_estimate_rms`` the estimates' own stated error, and
  ``*_prediction_rms`` over the validity region
  (:mod:`~terrain_estimation.models.terrain_response_error`); a new model
  moves the last by at most ``terrain_model.max_jump`` of its stated σ.

**When terrain_model is published.** Every estimate (after
``terrain_model.settle_time`` from a filter (re)initialisation) goes into a
:class:`~terrain_estimation.estimators.rover.TerrainResponseAccumulator`,
which averages it into one sample per wheel per ``terrain_model.sample_period``
(2 s) and gates the sample on terrain curvature (κ < 1/``vehicle.wheelbase``)
and speed. Each time ``terrain_model.fit_every`` new averaged samples have
been kept and at least ``terrain_model.min_samples`` are held, the models are
refitted and one message is published (none when the fit is rank deficient).
A sample period closes when the first estimate of the next one arrives, so
with the defaults (2 s periods, 12 samples = 4 periods × 3 wheels, 2 s
settle) the first model is published about 10 s into a run. A model is
stamped with the mean time of its newest sample period (≈ 9 s for that
first one), so its stamp says how recent the data are.

**Never NaN.** Every numeric input field is checked before it reaches the
core; a non-finite value, a missing joint, a wrong array length or a stamp
out of order is rejected and counted in the diagnostics as
``"<topic>: <field> = <value> …"``. The core keeps every published float
finite. Before the adapter, the node checks every message too (frames
``frames.<key>``, stamps, finite fields, IMU covariances and gravity:
:mod:`terrain_estimation.ros.validation`); while a stream is silent for
longer than ``timeouts.<key>`` the diagnostics WARN and the estimate holds
(:data:`ON_TIMEOUT`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, get_args, get_type_hints

from geometry_msgs.msg import TwistStamped, WrenchStamped
from sensor_msgs.msg import Imu, JointState

from terrain_estimation.estimators.rover import (
    RoverEstimate,
    RoverEstimatorConfig,
    RoverTerrainEstimator,
    TerrainResponseAccumulator,
    TerrainResponseConfig,
    TerrainResponseFit,
)
from terrain_estimation.estimators.rover_diagnostics import FaultCheck, consistency_channels
from terrain_estimation.estimators.rover_noise import ContactAngleBias, NoiseMatchingConfig
from terrain_estimation.models.rover import WHEELS, RoverParams
from terrain_estimation.models.rover_estimators import (
    GeneralProcessNoise,
    MeasurementErrorFloors,
    SensorNoise,
    WheelForceProcessNoise,
)
from terrain_estimation.models.rover_sinkage import SinkageSoil
from terrain_estimation.params import ParamSpec, ParamValue
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
from terrain_msgs.msg import TerrainResponseModel, WheelTerrain, WheelTerrainArray

__all__ = [
    "VEHICLE_SPECS_ROVER",
    "PARAMETERS",
    "CONFIG_PARAMETERS",
    "NOT_GIVEN",
    "WHEEL_ORDER",
    "RoverAdapter",
    "estimator_config",
    "terrain_response_config",
    "vehicle_params",
    "estimate_to_msg",
    "fit_to_msg",
    "make_adapter",
    "specs_for",
]

#: Order of ``WheelTerrainArray.wheels`` (published and ground truth): [RB] wheels 1, 2, 3.
WHEEL_ORDER: tuple[str, str, str] = WHEELS

_R = RoverParams()

#: Kapvik ([RB] Tables I, III; geometry [recon], MODELS.md C.3); shared with the simulator ("/**").
#: (field of RoverParams, unit, description, min, max).
_VEHICLE_FIELDS: tuple[tuple[str, str, str, float, float], ...] = (
    ("body_mass", "kg", "mass of body + rocker m0 (Table III)", 1e-3, 1e4),
    ("bogie_mass", "kg", "mass of the bogie link m1 (Table III)", 1e-3, 1e4),
    ("wheel_mass", "kg", "mass of one wheel m2 = m3 = m4 (Table III)", 1e-3, 1e3),
    ("body_inertia", "kg m^2", "pitch inertia of body + rocker about O, I0 (Table III)", 1e-6, 1e4),
    ("bogie_inertia", "kg m^2", "inertia of the bogie about its centre of mass, I1 (Table III)", 1e-6, 1e4),
    ("wheel_inertia", "kg m^2", "inertia of one wheel about its axle, I_w (Table III)", 1e-6, 1e3),
    (
        "wheel_gear_inertia",
        "kg m^2",
        "wheel + gear train referred to the wheel, I_wg (Table III; >= wheel_inertia)",
        1e-6,
        1e4,
    ),
    ("wheel_damping", "N m s/rad", "viscous damping of a wheel joint b_d (Table III, eq. 40)", 0.0, 1e4),
    ("wheel_radius", "m", "wheel radius r_w (Table I)", 1e-3, 5.0),
    ("wheel_width", "m", "wheel width b_w (Table I)", 1e-3, 5.0),
    (
        "wheelbase",
        "m",
        "rear to front wheel centre l_w (Table I); also sets the terrain-model curvature gate 1/l_w",
        1e-2,
        50.0,
    ),
    (
        "bogie_half_length",
        "m",
        "bogie joint to each bogie wheel along the bogie, b (Fig. 9; [recon], < wheelbase/2)",
        1e-3,
        25.0,
    ),
    ("bogie_joint_height", "m", "bogie joint above the bogie wheel centres, a (Fig. 9; [recon])", 0.0, 10.0),
    ("body_cm_height", "m", "combined centre of mass O above the wheel centres on level ground [recon]", 0.0, 10.0),
)


VEHICLE_SPECS_ROVER: tuple[ParamSpec, ...] = (
    ParamSpec("vehicle.kind", "rover", "vehicle model (one side, planar)", choices=("rover",), read_only=True),
    *(
        ParamSpec(f"vehicle.{name}", float(getattr(_R, name)), f"[{unit}] {text}", lo, hi)
        for name, unit, text, lo, hi in _VEHICLE_FIELDS
    ),
    ParamSpec(
        "vehicle.bogie_cm_offset",
        [float(v) for v in _R.bogie_cm_offset],
        "[m] bogie joint to bogie centre of mass c11, (x, z) in the bogie frame (Table III)",
        -10.0,
        10.0,
    ),
    ParamSpec("vehicle.gravity", _R.gravity, "[m/s^2] gravity", 0.1, 30.0),
)

_SN = SensorNoise()
_FL = MeasurementErrorFloors()
_GQ = GeneralProcessNoise()
_WQ = WheelForceProcessNoise()
_EC = RoverEstimatorConfig()
_TC = TerrainResponseConfig()

#: Sensor noise σ of one 50 Hz sample, [RB] Table IV: (field of SensorNoise, unit, description).
_NOISE_FIELDS: tuple[tuple[str, str, str], ...] = (
    ("bogie_angle", "rad", "bogie encoder (Table IV: 9.155e-4 deg)"),
    ("pitch_rate", "rad/s", "IMU pitch rate (Table IV: 0.56 deg/s)"),
    ("forward_speed", "m/s", "velocimeter (Table IV: 1 mm/s)"),
    ("acceleration", "m/s^2", "IMU specific force per axis (Table IV: 1.245e-3)"),
    ("wheel_angle", "rad", "wheel encoders (Table IV: 2.143e-5 deg)"),
    ("load_cell", "N", "load cells, each axis (Table IV: 3.255e-2 N)"),
)

#: Model-error σ added in quadrature to R: (field of MeasurementErrorFloors, unit, description).
_FLOOR_FIELDS: tuple[tuple[str, str, str], ...] = (
    ("wheel_rate", "rad/s", "wheel rates of eq. 63"),
    ("pitch", "rad", "pitch of eq. 64 (ignores the body acceleration, about x_acc/g)"),
    ("bogie_angle", "rad", "bogie angle"),
    ("specific_force", "m/s^2", "eqs. 72-73 (IMU offset from O, centripetal terms)"),
    ("forward_speed", "m/s", "velocimeter"),
    ("slip", "-", "slip of eq. 68 (assumes zero body z velocity)"),
    ("contact_angle", "rad", "contact angle of eq. 79 (assumes zero body z velocity, eqs. 90-91)"),
    ("load_cell", "N", "load cells"),
    ("synthesised_force", "N", "F_perp synthesised by eqs. 86-88 (Estimator 3: load-proportional split)"),
)

#: Random-walk σ per 0.2 s step: (field, unit, which estimator's state).
_PROCESS_FIELDS: tuple[tuple[str, str, str], ...] = (
    ("wheel_rate", "rad/s", "Estimator 1: wheel rates, on top of eq. 49"),
    ("resistive_torque", "N m", "Estimator 1: resistive torques tau_R (eq. 50)"),
    ("pitch", "rad", "Estimator 1: pitch (eq. 51)"),
    ("bogie_angle", "rad", "Estimator 1: bogie angle (eq. 52)"),
    ("pitch_rate", "rad/s", "Estimator 1: pitch rate (eq. 53)"),
    ("bogie_rate", "rad/s", "Estimator 1: bogie rate (eq. 54)"),
    ("pitch_acceleration", "rad/s^2", "Estimator 1: pitch acceleration, on top of eq. 55"),
    ("bogie_acceleration", "rad/s^2", "Estimator 1: bogie acceleration, on top of eq. 56"),
    ("x_acceleration", "m/s^2", "Estimator 1: x acceleration of O, on top of eq. 57"),
    ("z_acceleration", "m/s^2", "Estimator 1: z acceleration of O, on top of eq. 58"),
    ("body_moment", "N m", "Estimator 1: M_0fw (eq. 59)"),
    ("bogie_moment", "N m", "Estimator 1: M_1fw (eq. 59)"),
    ("wheel_force_x", "N", "Estimator 1: F_xfw (eq. 59)"),
    ("wheel_force_z", "N", "Estimator 1: F_zfw (eq. 59)"),
    ("forward_speed", "m/s", "Estimator 1: forward speed, on top of eq. 60"),
    ("slip", "-", "Estimator 1: slips (eq. 61)"),
    ("contact_angle", "rad", "Estimators 2/3: contact angles gamma"),
    ("normal_load", "N", "Estimators 2/3: normal loads W"),
    ("drawbar_pull", "N", "Estimators 2/3: drawbar pulls DP"),
)
_GENERAL_PROCESS = set(GeneralProcessNoise.__dataclass_fields__)


def _choices(field: str) -> tuple[str, ...]:
    """The values a Literal field of RoverEstimatorConfig allows, default first."""
    allowed = tuple(str(v) for v in get_args(get_type_hints(RoverEstimatorConfig)[field]))
    default = str(getattr(_EC, field))
    return (default, *(v for v in allowed if v != default))


#: The value of an optional list parameter that is not given: a ROS 2 parameter file cannot hold an
#: empty list (rcl reads ``[]`` as no value), and a one-element list cannot be mistaken for the 9-22 values.
NOT_GIVEN: list[float] = [-1.0]


_ESTIMATOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "estimator.load_cell_axes",
        _EC.load_cell_axes,
        "[-] axes of the wheel load cells: 2 = Estimator 2 (F_perp measured, force.x read); 1 = Estimator 3 "
        "(single-axis cells as on Kapvik: F_perp synthesised by eqs. 86-88, force.x ignored)",
        1,
        2,
    ),
    ParamSpec("estimator.sensor_rate", _EC.sensor_rate_hz, "[Hz] nominal rate of every sensor stream", 1.0, 10000.0),
    ParamSpec(
        "estimator.rate",
        _EC.estimator_rate_hz,
        "[Hz] estimator rate 1/T_e: sensors are averaged over windows of T_e ([RB]: 5 Hz); <= sensor_rate",
        0.01,
        1000.0,
    ),
    ParamSpec(
        "estimator.min_window_fraction",
        _EC.min_window_fraction,
        "[-] a window runs a step only with this fraction of the expected samples of every stream",
        0.0,
        1.0,
    ),
    ParamSpec(
        "estimator.max_latency",
        _EC.max_latency_s,
        "[s] how long a window waits for a lagging stream before it is closed",
        1e-3,
        60.0,
    ),
    ParamSpec(
        "estimator.max_gap",
        _EC.max_gap_s,
        "[s] a longer time without a step re-initialises the filters (> 1/estimator.rate)",
        1e-3,
        3600.0,
    ),
    ParamSpec(
        "estimator.max_consecutive_failures",
        _EC.max_consecutive_failures,
        "[-] failed filter steps in a row before the filters re-initialise",
        1,
        1000,
    ),
    ParamSpec(
        "estimator.slip_rate_source",
        _EC.slip_rate_source,
        "pitch and bogie rates in the slip measurement (eq. 66): 'imu' = window mean of the gyro and the "
        "bogie encoder difference ([RB]); 'estimate' = Estimator 1's predicted rates (smoother)",
        choices=_choices("slip_rate_source"),
    ),
    ParamSpec(
        "estimator.vertical_velocity",
        _EC.vertical_velocity,
        "body-z velocity of O in the contact angles (eq. 79): 'zero' as [RB] assumes (eq. 45; error about "
        "z0dot/x0dot in every gamma, eqs. 90-91), or estimated ('geometric')",
        choices=_choices("vertical_velocity"),
    ),
    ParamSpec(
        "estimator.perpendicular_split",
        _EC.perpendicular_split,
        "how Estimator 3 splits F_perp12 between the bogie wheels: 'load_cell' = eq. 88 (same F_perp/F_L), "
        "'terrain' = same DP/W in the frames of the measured contact angles",
        choices=_choices("perpendicular_split"),
    ),
    ParamSpec(
        "estimator.quasi_static_forces",
        _EC.quasi_static_forces,
        "Estimator 1's net wheel forces follow the equilibrium (false: pure random walks, eq. 59)",
    ),
    ParamSpec(
        "estimator.absolute_spin",
        _EC.absolute_spin,
        "slip from the wheel's absolute spin (carrier rate added) instead of the joint rate eq. 68 prints",
    ),
    ParamSpec(
        "estimator.settle_steps",
        _EC.settle_steps,
        "[-] filter updates after a (re)initialisation before wheel_terrain is flagged settled "
        "(WheelTerrainArray.settled; 10 = 2 s at 5 Hz)",
        0,
        10000,
    ),
    ParamSpec(
        "estimator.sinkage",
        _EC.sinkage.enabled,
        "model each wheel's sinkage (Bekker's pressure-sinkage law with the soil.* parameters, the loads of "
        "Estimators 2/3): lifts the wheel centres back onto one path and takes the sinking rate out of the contact "
        "angles (vertical_velocity 'geometric' only); false: rigid ground",
    ),
    ParamSpec(
        "soil.sinkage_exponent",
        _EC.sinkage.sinkage_exponent,
        "[-] nominal pressure-sinkage exponent n of the sinkage model ([RB] Table II)",
        0.01,
        2.99,
    ),
    ParamSpec(
        "soil.cohesive_modulus",
        _EC.sinkage.cohesive_modulus,
        "[Pa] nominal k_c b^(n-1) (k1 of [RB] Table II) of the sinkage model",
        0.0,
        1e9,
    ),
    ParamSpec(
        "soil.frictional_modulus",
        _EC.sinkage.frictional_modulus,
        "[Pa/m] nominal k_phi b^(n-1) (k2 of [RB] Table II) of the sinkage model",
        0.0,
        1e12,
    ),
    ParamSpec(
        "filter.noise_matching",
        _EC.noise_matching.enabled,
        "match noise scales to the innovations: Estimator 1's wheel-rate Q and slip R, Estimators 2/3's Q of W "
        "and DP (their noise rotated with gamma); false: the fixed process_noise.* and R from noise.* and floors.*",
    ),
    ParamSpec(
        "filter.noise_matching_forgetting",
        _EC.noise_matching.forgetting,
        "[-] forgetting b of the noise matching's process-noise scales: memory 1/(1 - b) filter steps",
        0.0,
        0.999,
    ),
    ParamSpec(
        "filter.noise_matching_r_forgetting",
        _EC.noise_matching.r_forgetting,
        "[-] forgetting b of the noise matching's measurement-noise scale (slip R): memory 1/(1 - b) steps",
        0.0,
        0.999,
    ),
    ParamSpec(
        "filter.noise_matching_floor",
        _EC.noise_matching.floor,
        "[-] smallest noise scale relative to its base",
        1e-6,
        1.0,
    ),
    ParamSpec(
        "filter.noise_matching_ceiling",
        _EC.noise_matching.ceiling,
        "[-] largest noise scale relative to its base",
        1.0,
        1e6,
    ),
    ParamSpec(
        "filter.contact_angle_bias",
        _EC.contact_angle_bias.sigma,
        "[rad] sigma of the slowly varying error of the measured contact angles (path beyond the parabola through "
        "the wheel centres, differential sinkage), added to the published variances of gamma, W, DP; 0 disables",
        0.0,
        0.5,
    ),
    ParamSpec("filter.ukf_alpha", _EC.ukf_alpha, "[-] UKF sigma-point spread alpha", 1e-3, 10.0),
    ParamSpec("filter.ukf_beta", _EC.ukf_beta, "[-] UKF beta (2: Gaussian prior)", 0.0, 10.0),
    ParamSpec(
        "filter.ukf_kappa", _EC.ukf_kappa, "[-] UKF kappa (> -9: the wheel-force filter has 9 states)", -8.9, 100.0
    ),
    ParamSpec("filter.gate_threshold", 0.0, "[-] NIS gate on both filters' updates; 0 disables", 0.0, 1e9),
    *divergence_specs(
        "false: on the simulated terrain 1 the mean NIS is about 4.3 against 11 (Estimator 1) and 1.0 against 9 "
        "(Estimators 2/3: their W, DP random walks also carry the cells' rotation with the contact angle), which "
        "would trip it on healthy data"
    ),
    ParamSpec(
        "filter.divergence_reinit_inflation",
        100.0,
        "[-] factor on the initial covariance the filters restart with from their last good estimate after a "
        "divergence: that estimate is seconds old (persistence updates at 5 Hz) and the initial covariance, "
        "pinned by the measurements of a fresh start, would hold the filter there (measured after a 2 s IMU "
        "fault: 1 diverges again and again, 100 recovers)",
        1.0,
        1e6,
    ),
    ParamSpec(
        "filter.divergence_max_variance_growth",
        1e8,
        "[-] divergence monitor: a variance above this multiple of its initial one is a covariance blow-up; "
        "Estimator 1's bogie acceleration, a random walk from a measurement-pinned start, reaches 1.4e5 times "
        "its initial variance on the shipped bags",
        10.0,
        1e15,
    ),
    ParamSpec(
        "filter.general_q_diag",
        list(NOT_GIVEN),
        "[SI^2] Estimator 1 process-noise variances per step, 22 values in state order (eq. 43); "
        "[-1]: the squares of process_noise.*",
        -1.0,
        1e9,
    ),
    ParamSpec(
        "filter.wheel_force_q_diag",
        list(NOT_GIVEN),
        "[SI^2] Estimator 2/3 process-noise variances per step, 9 values [gamma x3, W x3, DP x3] "
        "(rear, middle, front); [-1]: the squares of process_noise.*",
        -1.0,
        1e9,
    ),
    ParamSpec(
        "filter.general_r_diag",
        list(NOT_GIVEN),
        "[SI^2] fixed Estimator 1 measurement variances, 11 values in y1 order (eq. 62); [-1]: propagated "
        "each step from noise.* and floors.*",
        -1.0,
        1e9,
    ),
    ParamSpec(
        "filter.wheel_force_r_diag",
        list(NOT_GIVEN),
        "[SI^2] fixed Estimator 2/3 measurement variances, 9 values [gamma x3, F_L x3, F_perp x3]; [-1]: "
        "propagated each step",
        -1.0,
        1e9,
    ),
    ParamSpec(
        "filter.initial_general_state",
        list(NOT_GIVEN),
        "[SI] Estimator 1 initial mean, 22 values in state order; [-1]: from the first window's measurements "
        "(a rover in equilibrium)",
        -1e6,
        1e6,
    ),
    ParamSpec(
        "filter.initial_wheel_force_state",
        list(NOT_GIVEN),
        "[SI] Estimator 2/3 initial mean [gamma x3, W x3, DP x3]; [-1]: from the first window's measurements",
        -1e6,
        1e6,
    ),
    ParamSpec(
        "filter.general_p0_sigma",
        list(_EC.general_p0_sigma),
        "[SI] Estimator 1 initial standard deviations, 22 values in state order (eq. 43)",
        1e-15,
        1e6,
    ),
    ParamSpec(
        "filter.wheel_force_p0_sigma",
        list(_EC.wheel_force_p0_sigma),
        "[rad, N, N] Estimator 2/3 initial standard deviations [gamma x3, W x3, DP x3]",
        1e-15,
        1e6,
    ),
    *(
        ParamSpec(
            f"noise.{name}", float(getattr(_SN, name)), f"[{unit}] sensor noise sigma per sample: {text}", 1e-15, 1e6
        )
        for name, unit, text in _NOISE_FIELDS
    ),
    *(
        ParamSpec(
            f"floors.{name}", float(getattr(_FL, name)), f"[{unit}] model-error sigma added to R: {text}", 0.0, 1e6
        )
        for name, unit, text in _FLOOR_FIELDS
    ),
    *(
        ParamSpec(
            f"process_noise.{name}",
            float(getattr(_GQ if name in _GENERAL_PROCESS else _WQ, name)),
            f"[{unit}] random-walk sigma per step of 1/estimator.rate: {text}",
            0.0,
            1e6,
        )
        for name, unit, text in _PROCESS_FIELDS
    ),
    ParamSpec(
        "terrain_model.enabled", True, "fit DP(W, i) and tau_R(W, i) online and publish terrain_model ([RB] C.7)"
    ),
    ParamSpec(
        "terrain_model.sample_period",
        _TC.sample_period_s,
        "[s] estimates are averaged to one sample per wheel per period ([RB]: 2 s)",
        0.01,
        3600.0,
    ),
    ParamSpec("terrain_model.order", _TC.order, "[-] polynomial order of the fits ([RB]: 2)", 0, 6),
    ParamSpec(
        "terrain_model.max_samples",
        _TC.max_samples,
        "[-] bounded window of averaged samples kept for the fit, all wheels together (oldest dropped)",
        1,
        10**6,
    ),
    ParamSpec(
        "terrain_model.min_samples",
        0,
        "[-] kept samples needed for a fit (>= (order+1)(order+2)/2); 0: twice the number of coefficients",
        0,
        10**6,
    ),
    ParamSpec(
        "terrain_model.fit_every",
        1,
        "[-] refit and publish after this many new kept samples-periods (1: every sample_period)",
        1,
        10**6,
    ),
    ParamSpec(
        "terrain_model.settle_time",
        2.0,
        "[s] estimates this soon after a filter (re)initialisation are not fed to the model (filter transient)",
        0.0,
        3600.0,
    ),
    ParamSpec(
        "terrain_model.curvature_gate",
        _TC.curvature_gate,
        "reject sample periods over terrain curvature >= 1/vehicle.wheelbase ([RB] V-B), estimated from the "
        "contact angles against distance",
    ),
    ParamSpec(
        "terrain_model.min_curvature_distance",
        _TC.min_curvature_distance,
        "[m] the curvature of a sample period is estimated only over at least this much travel",
        1e-6,
        100.0,
    ),
    ParamSpec(
        "terrain_model.min_bucket_estimates",
        _TC.min_bucket_estimates,
        "[-] estimates a sample period needs (5 Hz x 2 s = 10 at most)",
        1,
        10**6,
    ),
    ParamSpec(
        "terrain_model.min_forward_speed",
        _TC.min_forward_speed,
        "[m/s] sample periods slower than this are rejected (slip undefined at rest)",
        0.0,
        100.0,
    ),
    ParamSpec(
        "terrain_model.wheels",
        list(_TC.wheels),
        "wheels whose samples feed the fit (rear, middle, front); e.g. [front] as a 'sensing wheel' with "
        "single-axis cells ([RB] IV-E)",
    ),
    ParamSpec(
        "terrain_model.weighted",
        _TC.weighted,
        "weight samples by 1/variance of the averaged estimate (false: equal weights, as [RB])",
    ),
    ParamSpec(
        "terrain_model.history_length",
        _TC.history_length,
        "[-] past fits kept (a history of coefficients, [RB] IV-F)",
        1,
        10**6,
    ),
    ParamSpec(
        "terrain_model.validation_blocks",
        _TC.validation_blocks,
        "[-] contiguous blocks of sample periods, each left out in turn: held-out error and jackknife "
        "covariance of the coefficients",
        2,
        1000,
    ),
    ParamSpec(
        "terrain_model.max_jump",
        _TC.max_jump,
        "[-] a new fit moves the published model by at most this many of its stated sigma (Mahalanobis "
        "distance in the previous covariance); 0: no bound",
        0.0,
        1e6,
    ),
    ParamSpec("joints.bogie", "bogie", "joint_states name of the bogie joint (q1)"),
    ParamSpec("joints.rear_wheel", "rear_wheel", "joint_states name of the rear wheel ([RB] wheel 1, q2)"),
    ParamSpec("joints.middle_wheel", "middle_wheel", "joint_states name of the middle wheel ([RB] wheel 2, q3)"),
    ParamSpec("joints.front_wheel", "front_wheel", "joint_states name of the front wheel ([RB] wheel 3, q4)"),
    ParamSpec("frames.base_link", "base_link", "frame of the estimates (prefixed with the namespace)"),
)


_ON_TIMEOUT = (
    "windows lacking its samples are skipped (estimator.min_window_fraction): the estimate holds; a gap "
    "longer than estimator.max_gap re-initialises the filters"
)
#: What the estimator does while an input is silent (shown in the timeout warning): the same for every stream.
ON_TIMEOUT: dict[str, str] = dict.fromkeys(
    ("imu", "joint_states", "velocimeter", "load_front", "load_middle", "load_rear"), _ON_TIMEOUT
)

_INPUT_SPECS: tuple[ParamSpec, ...] = (
    *input_specs("imu", "imu", "imu_link", 0.5, _ON_TIMEOUT),
    *input_specs("joint_states", "joint_states", "", 0.5, _ON_TIMEOUT),
    *input_specs("velocimeter", "velocimeter", "base_link", 0.5, _ON_TIMEOUT),
    *(
        spec
        for w in ("front", "middle", "rear")
        for spec in input_specs(f"load_{w}", f"wheel/{w}/load", f"{w}_load_cell", 0.5, _ON_TIMEOUT)
    ),
)


def specs_for(kind: str = "rover") -> tuple[ParamSpec, ...]:
    """The estimator's parameter specs (one vehicle kind)."""
    if kind != "rover":
        raise ValueError(f"unknown rover vehicle kind {kind!r}")
    return VEHICLE_SPECS_ROVER + _ESTIMATOR_SPECS + _INPUT_SPECS


PARAMETERS = specs_for()


def _f(values: Mapping[str, ParamValue], name: str) -> float:
    return float(values[name])


def _optional(values: Mapping[str, ParamValue], name: str, size: int) -> tuple[float, ...] | None:
    v = tuple(float(x) for x in values[name])
    if not v or list(v) == NOT_GIVEN:
        return None
    if len(v) != size:
        raise ValueError(f"{name} must be [-1] (not given) or hold {size} values, got {len(v)}: {list(v)}")
    return v


def _fixed(values: Mapping[str, ParamValue], name: str, size: int) -> tuple[float, ...]:
    v = tuple(float(x) for x in values[name])
    if len(v) != size:
        raise ValueError(f"{name} must hold {size} values, got {len(v)}: {list(v)}")
    return v


def vehicle_params(values: Mapping[str, ParamValue]) -> RoverParams:
    """The rover of the ``vehicle.*`` parameters.

    Raises:
        ValueError: inconsistent geometry (e.g. a bogie longer than half the wheelbase).
    """
    offset = _fixed(values, "vehicle.bogie_cm_offset", 2)
    return RoverParams(
        **{name: _f(values, f"vehicle.{name}") for name, *_ in _VEHICLE_FIELDS},
        bogie_cm_offset=(offset[0], offset[1]),
        gravity=_f(values, "vehicle.gravity"),
    )


#: Field of RoverEstimatorConfig → the parameter(s) that set it (a test keeps this complete).
CONFIG_PARAMETERS: dict[str, str] = {
    "rover": "vehicle.*",
    "load_cell_axes": "estimator.load_cell_axes",
    "sensor_rate_hz": "estimator.sensor_rate",
    "estimator_rate_hz": "estimator.rate",
    "sensor_noise": "noise.*",
    "floors": "floors.*",
    "general_process_noise": "process_noise.* (Estimator 1 states)",
    "wheel_force_process_noise": "process_noise.contact_angle, .normal_load, .drawbar_pull",
    "general_q_diag": "filter.general_q_diag",
    "wheel_force_q_diag": "filter.wheel_force_q_diag",
    "general_r_diag": "filter.general_r_diag",
    "wheel_force_r_diag": "filter.wheel_force_r_diag",
    "initial_general_state": "filter.initial_general_state",
    "initial_wheel_force_state": "filter.initial_wheel_force_state",
    "general_p0_sigma": "filter.general_p0_sigma",
    "wheel_force_p0_sigma": "filter.wheel_force_p0_sigma",
    "slip_rate_source": "estimator.slip_rate_source",
    "absolute_spin": "estimator.absolute_spin",
    "quasi_static_forces": "estimator.quasi_static_forces",
    "perpendicular_split": "estimator.perpendicular_split",
    "vertical_velocity": "estimator.vertical_velocity",
    "min_window_fraction": "estimator.min_window_fraction",
    "max_latency_s": "estimator.max_latency",
    "max_gap_s": "estimator.max_gap",
    "max_consecutive_failures": "estimator.max_consecutive_failures",
    "ukf_alpha": "filter.ukf_alpha",
    "ukf_beta": "filter.ukf_beta",
    "ukf_kappa": "filter.ukf_kappa",
    "gate_threshold": "filter.gate_threshold",
    "divergence": "filter.divergence_* (one monitor per filter)",
    "noise_matching": "filter.noise_matching, filter.noise_matching_*",
    "contact_angle_bias": "filter.contact_angle_bias",
    "settle_steps": "estimator.settle_steps",
    "sinkage": "estimator.sinkage, soil.*",
}


def estimator_config(values: Mapping[str, ParamValue]) -> RoverEstimatorConfig:
    """The core estimator's configuration from validated parameter values.

    Raises:
        ValueError: inconsistent values (a list of the wrong length, a rate above the sensor rate …).
    """
    gate = _f(values, "filter.gate_threshold")
    process = {name: _f(values, f"process_noise.{name}") for name, *_ in _PROCESS_FIELDS}
    return RoverEstimatorConfig(
        rover=vehicle_params(values),
        load_cell_axes=int(values["estimator.load_cell_axes"]),
        sensor_rate_hz=_f(values, "estimator.sensor_rate"),
        estimator_rate_hz=_f(values, "estimator.rate"),
        sensor_noise=SensorNoise(**{name: _f(values, f"noise.{name}") for name, *_ in _NOISE_FIELDS}),
        floors=MeasurementErrorFloors(**{name: _f(values, f"floors.{name}") for name, *_ in _FLOOR_FIELDS}),
        general_process_noise=GeneralProcessNoise(**{k: v for k, v in process.items() if k in _GENERAL_PROCESS}),
        wheel_force_process_noise=WheelForceProcessNoise(
            **{k: v for k, v in process.items() if k not in _GENERAL_PROCESS}
        ),
        general_q_diag=_optional(values, "filter.general_q_diag", 22),
        wheel_force_q_diag=_optional(values, "filter.wheel_force_q_diag", 9),
        general_r_diag=_optional(values, "filter.general_r_diag", 11),
        wheel_force_r_diag=_optional(values, "filter.wheel_force_r_diag", 9),
        initial_general_state=_optional(values, "filter.initial_general_state", 22),
        initial_wheel_force_state=_optional(values, "filter.initial_wheel_force_state", 9),
        general_p0_sigma=_fixed(values, "filter.general_p0_sigma", 22),
        wheel_force_p0_sigma=_fixed(values, "filter.wheel_force_p0_sigma", 9),
        slip_rate_source=values["estimator.slip_rate_source"],
        vertical_velocity=values["estimator.vertical_velocity"],
        perpendicular_split=values["estimator.perpendicular_split"],
        quasi_static_forces=bool(values["estimator.quasi_static_forces"]),
        absolute_spin=bool(values["estimator.absolute_spin"]),
        min_window_fraction=_f(values, "estimator.min_window_fraction"),
        max_latency_s=_f(values, "estimator.max_latency"),
        max_gap_s=_f(values, "estimator.max_gap"),
        max_consecutive_failures=int(values["estimator.max_consecutive_failures"]),
        ukf_alpha=_f(values, "filter.ukf_alpha"),
        ukf_beta=_f(values, "filter.ukf_beta"),
        ukf_kappa=_f(values, "filter.ukf_kappa"),
        gate_threshold=gate if gate > 0.0 else None,
        divergence=divergence_config(values),
        noise_matching=NoiseMatchingConfig(
            enabled=bool(values["filter.noise_matching"]),
            forgetting=_f(values, "filter.noise_matching_forgetting"),
            r_forgetting=_f(values, "filter.noise_matching_r_forgetting"),
            floor=_f(values, "filter.noise_matching_floor"),
            ceiling=_f(values, "filter.noise_matching_ceiling"),
        ),
        contact_angle_bias=ContactAngleBias(
            enabled=_f(values, "filter.contact_angle_bias") > 0.0, sigma=_f(values, "filter.contact_angle_bias")
        ),
        settle_steps=int(values["estimator.settle_steps"]),
        sinkage=SinkageSoil(
            enabled=bool(values["estimator.sinkage"]),
            sinkage_exponent=_f(values, "soil.sinkage_exponent"),
            cohesive_modulus=_f(values, "soil.cohesive_modulus"),
            frictional_modulus=_f(values, "soil.frictional_modulus"),
        ),
    )


def terrain_response_config(values: Mapping[str, ParamValue]) -> TerrainResponseConfig:
    """The online terrain-model accumulator's configuration (curvature gate 1/``vehicle.wheelbase``).

    Raises:
        ValueError: unknown wheel names, min_samples below the number of coefficients, ….
    """
    min_samples = int(values["terrain_model.min_samples"])
    max_jump = _f(values, "terrain_model.max_jump")
    return TerrainResponseConfig(
        sample_period_s=_f(values, "terrain_model.sample_period"),
        order=int(values["terrain_model.order"]),
        max_samples=int(values["terrain_model.max_samples"]),
        min_samples=min_samples if min_samples > 0 else None,
        wheelbase=_f(values, "vehicle.wheelbase"),
        curvature_gate=bool(values["terrain_model.curvature_gate"]),
        min_curvature_distance=_f(values, "terrain_model.min_curvature_distance"),
        min_bucket_estimates=int(values["terrain_model.min_bucket_estimates"]),
        min_forward_speed=_f(values, "terrain_model.min_forward_speed"),
        wheels=tuple(str(w) for w in values["terrain_model.wheels"]),
        weighted=bool(values["terrain_model.weighted"]),
        history_length=int(values["terrain_model.history_length"]),
        validation_blocks=int(values["terrain_model.validation_blocks"]),
        max_jump=max_jump if max_jump > 0.0 else math.inf,
    )


def estimate_to_msg(e: RoverEstimate, frame_id: str) -> WheelTerrainArray:
    """The contract's WheelTerrainArray of one estimate, wheels in :data:`WHEEL_ORDER` (floats finite by the core)."""
    msg = WheelTerrainArray(
        wheels=[
            WheelTerrain(
                wheel=w.wheel,
                slip=w.slip,
                slip_variance=w.slip_variance,
                normal_load=w.normal_load,
                normal_load_variance=w.normal_load_variance,
                drawbar_pull=w.drawbar_pull,
                drawbar_pull_variance=w.drawbar_pull_variance,
                resistive_torque=w.resistive_torque,
                resistive_torque_variance=w.resistive_torque_variance,
                contact_angle=w.contact_angle,
                contact_angle_variance=w.contact_angle_variance,
            )
            for w in e.wheels
        ],
        settled=e.settled,
    )
    msg.header.stamp = sec_to_stamp(e.t)
    msg.header.frame_id = frame_id
    return msg


def fit_to_msg(fit: TerrainResponseFit, frame_id: str) -> TerrainResponseModel:
    """terrain_msgs/TerrainResponseModel of one fit, stamped with its newest sample's time."""
    msg = TerrainResponseModel(
        order=fit.order,
        dp_coefficients=[float(c) for c in fit.dp_coefficients],
        tau_coefficients=[float(c) for c in fit.tau_coefficients],
        slip_min=fit.slip_min,
        slip_max=fit.slip_max,
        load_min=fit.load_min,
        load_max=fit.load_max,
        samples=fit.samples,
        dp_rms=fit.dp_rms,
        tau_rms=fit.tau_rms,
        dp_covariance=[float(c) for c in fit.dp_covariance.ravel()],
        tau_covariance=[float(c) for c in fit.tau_covariance.ravel()],
        dp_holdout_rms=fit.dp_holdout_rms,
        tau_holdout_rms=fit.tau_holdout_rms,
        dp_estimate_rms=fit.dp_estimate_rms,
        tau_estimate_rms=fit.tau_estimate_rms,
        dp_prediction_rms=fit.dp_prediction_rms,
        tau_prediction_rms=fit.tau_prediction_rms,
        validation_samples=fit.validation_samples,
    )
    msg.header.stamp = sec_to_stamp(fit.t)
    msg.header.frame_id = frame_id
    return msg


def _frame(namespace: str, frame: str) -> str:
    ns = namespace.strip("/")
    return f"{ns}/{frame}" if ns else frame


_MAX_REJECT_REASONS = 64
"""Distinct rejection reasons kept with their value; beyond, the value is dropped from the key (bounded diagnostics)."""

_ZERO_PERPENDICULAR_WARN = 50
#: The innovation fault check (estimators.rover_diagnostics.FaultCheck): window (s of stamps) and the
#: two-sided band probability (upper tail 5e-5 per update: on the simulated terrains 1 and 4 the largest 2-s mean
#: of a nominal run was 1.5-1.8x the dof).
_FAULT_WINDOW_S = 2.0
_FAULT_PROBABILITY = 0.9999
"""Load-cell messages in a row with force.x exactly 0 on every wheel that raise the single-axis warning."""


class RoverAdapter:
    """Messages ↔ :class:`RoverTerrainEstimator` and :class:`TerrainResponseAccumulator` for one rover side."""

    def __init__(self, values: Mapping[str, ParamValue], namespace: str) -> None:
        self.config = estimator_config(values)
        self.model_config = terrain_response_config(values)
        self.model_enabled = bool(values["terrain_model.enabled"])
        self.settle_time = _f(values, "terrain_model.settle_time")
        self.fit_every = int(values["terrain_model.fit_every"])
        self.estimator = RoverTerrainEstimator(self.config)
        self.accumulator = TerrainResponseAccumulator(self.model_config)
        self.frame_id = _frame(namespace, str(values["frames.base_link"]))
        # joint_states names in WHEELS order (rear, middle, front).
        self.bogie_joint = str(values["joints.bogie"])
        self.wheel_joints = tuple(str(values[f"joints.{w}_wheel"]) for w in WHEELS)
        self.two_axis = self.config.load_cell_axes == 2
        joints = (self.bogie_joint, *self.wheel_joints)

        def spec(key: str, topic: str, msg_type: type, **checks: Any) -> TopicSpec:
            return TopicSpec(
                key,
                topic,
                msg_type,
                frame_id=input_frame(values, namespace, key),
                timeout=_f(values, f"timeouts.{key}"),
                on_timeout=ON_TIMEOUT[key],
                **checks,
            )

        self.inputs: Sequence[TopicSpec] = (
            spec(
                "imu",
                "imu",
                Imu,
                fields=("linear_acceleration.x", "linear_acceleration.z", "angular_velocity.y"),
                covariances=("linear_acceleration_covariance", "angular_velocity_covariance"),
                gravity_fields=("linear_acceleration.x", "linear_acceleration.z"),
                gravity=_f(values, "vehicle.gravity"),
            ),
            spec(
                "joint_states",
                "joint_states",
                JointState,
                fields=(*(f"position[{j}]" for j in joints), *(f"effort[{j}]" for j in self.wheel_joints)),
            ),
            spec("velocimeter", "velocimeter", TwistStamped, fields=("twist.linear.x",)),
            *(
                spec(
                    f"load_{w}",
                    f"wheel/{w}/load",
                    WrenchStamped,
                    fields=("wrench.force.z", "wrench.force.x") if self.two_axis else ("wrench.force.z",),
                )
                for w in ("front", "middle", "rear")
            ),
        )
        self.outputs: Sequence[TopicSpec] = (
            TopicSpec(
                "wheel_terrain",
                "wheel_terrain",
                WheelTerrainArray,
                "estimate",
                truth_fields=tuple(
                    f"wheels[{i}].{q}"
                    for i in range(len(WHEELS))
                    for q in ("slip", "normal_load", "drawbar_pull", "resistive_torque")
                ),
            ),
            TopicSpec("terrain_model", "terrain_model", TerrainResponseModel, "estimate"),
        )
        self.reset()

    def reset(self) -> None:
        self.estimator.reset()
        self.accumulator.reset()
        # NIS over the channels whose S is sensor noise plus state uncertainty (velocimeter, slips, load cells;
        # estimators.rover_diagnostics says which are left out and why): chi-square with 10 (two-axis) or 7 dof.
        dof = sum(len(c) for c in consistency_channels(self.estimator.config.load_cell_axes))
        self.health = AdapterHealth(nis_dof=dof)
        self._fault_check = FaultCheck(
            dof, max(1, math.ceil(_FAULT_WINDOW_S * self.estimator.config.estimator_rate_hz - 1e-9)), _FAULT_PROBABILITY
        )
        self._fault_warning: str | None = None
        self._settled_from: float | None = None
        self._buckets_at_fit = 0
        self._zero_perpendicular = dict.fromkeys(WHEELS, 0)
        self._last_stamp: dict[str, float] = {}
        self.fits_published = 0

    # -- rejections ----------------------------------------------------------------
    def _reject(self, topic: str, field: str, value: Any, problem: str) -> None:
        reason = f"{topic}: {field} = {value!r} {problem}"
        if reason not in self.health.rejected and len(self.health.rejected) >= _MAX_REJECT_REASONS:
            reason = f"{topic}: {field} {problem}"
        self.health.reject(reason)

    def _finite(self, topic: str, fields: Sequence[tuple[str, Any]]) -> bool:
        for name, value in fields:
            v = float(value)
            if not math.isfinite(v):
                self._reject(topic, name, v, "is not finite")
                return False
        return True

    def _call(self, topic: str, stamp: float, call: Any, *args: Any) -> None:
        """Pass one sample of ``topic`` to the core if its stamp is after the topic's previous one."""
        previous = self._last_stamp.get(topic)
        if previous is not None and stamp <= previous:
            self._reject(topic, "header.stamp", stamp, "is not after the previous sample's")
            return
        try:
            call(stamp, *args)
        except ValueError as exc:  # anything else the core refuses, in its words
            self.health.reject(f"{topic}: {exc}")
            return
        self._last_stamp[topic] = stamp

    # -- adapter protocol ------------------------------------------------------------
    def handle(self, key: str, msg: Any) -> list[tuple[str, Any]]:
        t = stamp_to_ns(msg.header.stamp) * 1e-9
        if key == "imu":
            self._on_imu(t, msg)
        elif key == "joint_states":
            self._on_joints(t, msg)
        elif key == "velocimeter":
            speed = msg.twist.linear.x
            if self._finite("velocimeter", [("twist.linear.x", speed)]):
                self._call("velocimeter", t, self.estimator.add_velocimeter, float(speed))
        elif key.startswith("load_"):
            self._on_load_cell(t, key[len("load_") :], msg)
        else:
            return []
        return self._drain()

    def _on_imu(self, t: float, msg: Any) -> None:
        acc, gyro = msg.linear_acceleration, msg.angular_velocity
        fields = [("linear_acceleration.x", acc.x), ("linear_acceleration.z", acc.z), ("angular_velocity.y", gyro.y)]
        if self._finite("imu", fields):
            self._call("imu", t, self.estimator.add_imu, float(acc.x), float(acc.z), float(gyro.y))

    def _on_joints(self, t: float, msg: Any) -> None:
        topic = "joint_states"
        names = list(msg.name)
        missing = [j for j in (self.bogie_joint, *self.wheel_joints) if j not in names]
        if missing:
            self._reject(topic, "name", names, f"lacks {', '.join(missing)}")
            return
        for field in ("position", "effort"):
            n = len(getattr(msg, field))
            if n != len(names):
                self._reject(topic, f"len({field})", n, f"differs from len(name) = {len(names)}")
                return
        index = {name: k for k, name in enumerate(names)}
        bogie = float(msg.position[index[self.bogie_joint]])
        angles = [float(msg.position[index[j]]) for j in self.wheel_joints]
        torques = [float(msg.effort[index[j]]) for j in self.wheel_joints]
        fields = [(f"position[{self.bogie_joint}]", bogie)]
        fields += [(f"position[{j}]", a) for j, a in zip(self.wheel_joints, angles, strict=True)]
        fields += [(f"effort[{j}]", e) for j, e in zip(self.wheel_joints, torques, strict=True)]
        if self._finite(topic, fields):
            self._call(topic, t, self.estimator.add_joint_state, bogie, angles, torques)

    def _on_load_cell(self, t: float, wheel: str, msg: Any) -> None:
        topic = f"wheel/{wheel}/load"
        axial, perpendicular = msg.wrench.force.z, msg.wrench.force.x
        fields = [("wrench.force.z", axial)] + ([("wrench.force.x", perpendicular)] if self.two_axis else [])
        if not self._finite(topic, fields):
            return
        if self.two_axis:
            self._zero_perpendicular[wheel] = self._zero_perpendicular[wheel] + 1 if perpendicular == 0.0 else 0
            self._call(topic, t, self.estimator.add_load_cell, wheel, float(axial), float(perpendicular))
        else:
            self._call(topic, t, self.estimator.add_load_cell, wheel, float(axial), None)

    # -- outputs -------------------------------------------------------------------------
    def _drain(self) -> list[tuple[str, Any]]:
        estimates = self.estimator.drain_estimates()
        if not estimates:
            return []
        out: list[tuple[str, Any]] = []
        h = self.health
        for e in estimates:
            h.updates += 1
            h.last_update_time = e.t
            if e.initialised:
                self._fault_check.reset()
                self._fault_warning = None
            elif e.accepted and e.settled:  # the first 2 s after a start describe the start (rover_noise.is_settled)
                h.nis.append(e.consistency_nis)
                # A fault (a load-cell offset) within 2 s of stamp time; the long window's autocorrelation time.
                tau = _nis_autocorrelation_time(h.nis)
                self._fault_warning = self._fault_check.add(e.consistency_nis, tau)
            out.append(("wheel_terrain", estimate_to_msg(e, self.frame_id)))
            fit = self._feed_model(e)
            if fit is not None:
                out.append(("terrain_model", fit_to_msg(fit, self.frame_id)))
        self._update_health(estimates[-1])
        return out

    def _feed_model(self, e: RoverEstimate) -> TerrainResponseFit | None:
        """Add one estimate to the accumulator; refit when ``fit_every`` new sample periods were kept."""
        if not self.model_enabled:
            return None
        if e.initialised:
            self._settled_from = e.t + self.settle_time
            return None
        if self._settled_from is None or e.t < self._settled_from - 1e-9:
            return None
        try:
            self.accumulator.add_estimate(e)
        except ValueError as exc:  # the core keeps estimates finite and ordered; report rather than crash
            self.health.reject(f"terrain_model: {exc}")
            return None
        used = self.accumulator.counters.buckets_used
        if used - self._buckets_at_fit < self.fit_every:
            return None
        if self.accumulator.sample_count < self.model_config.required_samples:
            return None
        self._buckets_at_fit = used
        fit = self.accumulator.fit()
        if fit is not None:
            self.fits_published += 1
        return fit

    def _update_health(self, last: RoverEstimate) -> None:
        h = self.health
        c = self.estimator.counters
        m = self.accumulator.counters
        front, middle, rear = last.wheel("front"), last.wheel("middle"), last.wheel("rear")
        h.status = (
            f"Estimator 1+{last.estimator}: slip {rear.slip:.3f}/{middle.slip:.3f}/{front.slip:.3f}, "
            f"W {rear.normal_load:.1f}/{middle.normal_load:.1f}/{front.normal_load:.1f} N (rear/middle/front)"
        )
        warnings = []
        if self.two_axis and all(n >= _ZERO_PERPENDICULAR_WARN for n in self._zero_perpendicular.values()):
            warnings.append(
                "wheel/*/load: force.x (F_perp) is exactly 0 on every cell: single-axis cells? "
                "set estimator.load_cell_axes: 1"
            )
        if self._fault_warning is not None:
            warnings.append(self._fault_warning)
        h.warnings = warnings
        h.errors = divergence_errors(self.estimator.fault, c.divergences)
        curvature = self.accumulator.last_curvature
        h.values.update(
            estimator=last.estimator,
            distance_m=last.distance,
            forward_speed=last.body.forward_speed,
            pitch=last.body.pitch,
            bogie_angle=last.body.bogie_angle,
            **{name: getattr(c, name) for name in c.__dataclass_fields__},
            model_samples=self.accumulator.sample_count,
            model_samples_required=self.model_config.required_samples,
            model_fits=m.fits,
            model_fits_published=self.fits_published,
            model_buckets=m.buckets,
            model_buckets_used=m.buckets_used,
            model_rejected_curvature=m.rejected_curvature,
            model_rejected_speed=m.rejected_speed,
            model_rejected_sparse=m.rejected_sparse,
            model_samples_dropped=m.samples_dropped,
            model_last_curvature=curvature if curvature is not None else "unknown",
        )
        history = self.accumulator.history
        if history:  # the last model's stated error and how far its fit wanted to move (issue 21)
            h.values.update(
                model_dp_prediction_rms=history[-1].dp_prediction_rms,
                model_tau_prediction_rms=history[-1].tau_prediction_rms,
                model_dp_jump=history[-1].dp_jump,
                model_step_bounded=history[-1].limited,
            )


def _nis_autocorrelation_time(values: Sequence[float]) -> float:
    """τ of the NIS values (≥ 1; 1 below 8 values), imported late as the framework does (scipy, issue 23)."""
    if len(values) < 8:
        return 1.0
    from terrain_estimation.analysis.consistency import integrated_autocorrelation_time

    return float(integrated_autocorrelation_time(list(values)))


def make_adapter(values: Mapping[str, ParamValue], namespace: str) -> RoverAdapter:
    return RoverAdapter(values, namespace)
