"""Parameters of the rocker-bogie terrain-response estimator and the core configuration they make.

The specs (``vehicle.*`` shared with the simulator, ``estimator.*``,
``filter.*``, ``noise.*``, ``floors.*``, ``process_noise.*``, ``soil.*``,
``terrain_model.*``, ``joints.*``, ``frames.*``, ``timeouts.*``) and the
functions that read the validated values back into
:class:`~terrain_estimation.estimators.rover.RoverEstimatorConfig` and
:class:`~terrain_estimation.estimators.rover.TerrainResponseConfig`. The
topics and the adapter are in :mod:`terrain_estimation.ros.rover`, which
imports these names too.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import get_args, get_type_hints

from terrain_estimation.estimators.rover import RoverEstimatorConfig, TerrainResponseConfig
from terrain_estimation.estimators.rover_noise import ContactAngleBias, NoiseMatchingConfig
from terrain_estimation.models.rover import RoverParams
from terrain_estimation.models.rover_estimators import (
    GeneralProcessNoise,
    MeasurementErrorFloors,
    SensorNoise,
    WheelForceProcessNoise,
)
from terrain_estimation.models.rover_sinkage import SinkageSoil
from terrain_estimation.params import ParamSpec, ParamValue
from terrain_estimation.ros.parameters import (
    divergence_config,
    divergence_specs,
    field_specs,
    fixed_floats,
    float_fields,
    input_specs,
    kind_specs,
)
from terrain_estimation.ros.parameters import float_value as _f

__all__ = [
    "VEHICLE_SPECS_ROVER",
    "PARAMETERS",
    "CONFIG_PARAMETERS",
    "NOT_GIVEN",
    "ON_TIMEOUT",
    "estimator_config",
    "terrain_response_config",
    "vehicle_params",
    "specs_for",
]

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
    *field_specs("vehicle", _R, _VEHICLE_FIELDS, read_only=False),
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
        "[rad] sigma of a slowly varying error of the measured contact angles that neither the path nor the "
        "sinkage law below sees, in quadrature with them; added (through sigma_b) to the published variances of "
        "gamma, W, DP",
        0.0,
        0.5,
    ),
    ParamSpec(
        "filter.contact_angle_path_error",
        _EC.contact_angle_bias.path_error,
        "consider the contact angles' error from the path beyond the parabola through the wheel centres, evaluated "
        "on the slope profile the wheels' own estimates traced (Simpson's rule's error over the wheelbase; at a "
        "curvature >= 1/vehicle.wheelbase at least a kink of the span's slope change); false: not considered",
    ),
    ParamSpec(
        "filter.contact_angle_sinkage_error",
        _EC.contact_angle_bias.sinkage_relative_error,
        "[-] relative error of the sinkage model's wheel sinkages (nominal soil; a soil 2x stiffer: -35 %): their "
        "tilt of the fitted path times it is considered; 0: none",
        0.0,
        10.0,
    ),
    ParamSpec(
        "filter.contact_angle_bias_from_repeat_pass",
        _EC.contact_angle_bias.from_repeat_pass,
        "raise the contact-angle error's sigma to what the wheels' repeat passes show (a trailing wheel meets the "
        "ground its leader met 0.35 m earlier: half the mean square difference of their contact-angle estimates, "
        "less their variances, a lower bound); false: not raised",
    ),
    ParamSpec(
        "filter.contact_angle_bias_memory",
        _EC.contact_angle_bias.memory_steps,
        "[steps] the path-error and repeat-pass variances are averaged over this many estimator steps (5 = 1 s at "
        "5 Hz)",
        1.0,
        1000.0,
    ),
    ParamSpec(
        "filter.split_traction_slope",
        _EC.split_traction_slope,
        "[-] Estimator 3: slope of DP/W against slip of the soil (nominal [RB] Table II soil: 0.55); the bogie "
        "wheels' slip difference times it sizes the error of splitting F_perp12 at one DP/W; 0 disables",
        0.0,
        100.0,
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
    return kind_specs(kind, "rover", "rover", VEHICLE_SPECS_ROVER, _ESTIMATOR_SPECS, _INPUT_SPECS)


PARAMETERS = specs_for()


def _optional(values: Mapping[str, ParamValue], name: str, size: int) -> tuple[float, ...] | None:
    v = tuple(float(x) for x in values[name])
    if not v or list(v) == NOT_GIVEN:
        return None
    if len(v) != size:
        raise ValueError(f"{name} must be [-1] (not given) or hold {size} values, got {len(v)}: {list(v)}")
    return v


def vehicle_params(values: Mapping[str, ParamValue]) -> RoverParams:
    """The rover of the ``vehicle.*`` parameters.

    Raises:
        ValueError: inconsistent geometry (e.g. a bogie longer than half the wheelbase).
    """
    offset = fixed_floats(values, "vehicle.bogie_cm_offset", 2)
    return RoverParams(
        **float_fields(values, "vehicle", (name for name, *_ in _VEHICLE_FIELDS)),
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
    "contact_angle_bias": "filter.contact_angle_bias, filter.contact_angle_path_error, "
    "filter.contact_angle_sinkage_error, filter.contact_angle_bias_from_repeat_pass, "
    "filter.contact_angle_bias_memory",
    "split_traction_slope": "filter.split_traction_slope",
    "settle_steps": "estimator.settle_steps",
    "sinkage": "estimator.sinkage, soil.*",
}


def estimator_config(values: Mapping[str, ParamValue]) -> RoverEstimatorConfig:
    """The core estimator's configuration from validated parameter values.

    Raises:
        ValueError: inconsistent values (a list of the wrong length, a rate above the sensor rate …).
    """
    gate = _f(values, "filter.gate_threshold")
    process = float_fields(values, "process_noise", (name for name, *_ in _PROCESS_FIELDS))
    return RoverEstimatorConfig(
        rover=vehicle_params(values),
        load_cell_axes=int(values["estimator.load_cell_axes"]),
        sensor_rate_hz=_f(values, "estimator.sensor_rate"),
        estimator_rate_hz=_f(values, "estimator.rate"),
        sensor_noise=SensorNoise(**float_fields(values, "noise", (name for name, *_ in _NOISE_FIELDS))),
        floors=MeasurementErrorFloors(**float_fields(values, "floors", (name for name, *_ in _FLOOR_FIELDS))),
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
        general_p0_sigma=fixed_floats(values, "filter.general_p0_sigma", 22),
        wheel_force_p0_sigma=fixed_floats(values, "filter.wheel_force_p0_sigma", 9),
        slip_rate_source=values["estimator.slip_rate_source"],
        vertical_velocity=values["estimator.vertical_velocity"],
        perpendicular_split=values["estimator.perpendicular_split"],
        quasi_static_forces=bool(values["estimator.quasi_static_forces"]),
        absolute_spin=bool(values["estimator.absolute_spin"]),
        min_window_fraction=_f(values, "estimator.min_window_fraction"),
        max_latency_s=_f(values, "estimator.max_latency"),
        max_gap_s=_f(values, "estimator.max_gap"),
        max_consecutive_failures=int(values["estimator.max_consecutive_failures"]),
        **float_fields(values, "filter", ("ukf_alpha", "ukf_beta", "ukf_kappa", "split_traction_slope")),
        gate_threshold=gate if gate > 0.0 else None,
        divergence=divergence_config(values),
        noise_matching=NoiseMatchingConfig(
            enabled=bool(values["filter.noise_matching"]),
            **float_fields(
                values, "filter.noise_matching", ("forgetting", "r_forgetting", "floor", "ceiling"), sep="_"
            ),
        ),
        contact_angle_bias=ContactAngleBias(
            enabled=_f(values, "filter.contact_angle_bias") > 0.0
            or bool(values["filter.contact_angle_path_error"])
            or _f(values, "filter.contact_angle_sinkage_error") > 0.0,
            sigma=_f(values, "filter.contact_angle_bias"),
            from_repeat_pass=bool(values["filter.contact_angle_bias_from_repeat_pass"]),
            memory_steps=_f(values, "filter.contact_angle_bias_memory"),
            path_error=bool(values["filter.contact_angle_path_error"]),
            sinkage_relative_error=_f(values, "filter.contact_angle_sinkage_error"),
        ),
        settle_steps=int(values["estimator.settle_steps"]),
        sinkage=SinkageSoil(
            enabled=bool(values["estimator.sinkage"]),
            **float_fields(values, "soil", ("sinkage_exponent", "cohesive_modulus", "frictional_modulus")),
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
