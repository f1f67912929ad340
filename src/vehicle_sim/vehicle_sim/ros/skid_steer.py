"""Six-wheel skid-steer simulator: parameters and messages.

Turns :class:`vehicle_sim.plants.skid_steer.SkidSteerSample` into the
contract's topics (CONTRACT.md, skid-steer section):

* ``imu`` — sensor_msgs/Imu at the geometric centre: specific force x, y, z
  (REP 145: +g on z at rest), angular velocity x, y, z; orientation not
  measured (covariance[0] = -1).
* ``joint_states`` — joints ``left_motor``, ``right_motor``: motor-side
  position (rad, quantised), velocity (rad/s), effort (N·m).
* ``gnss/odom`` — nav_msgs/Odometry at the GNSS rate (10 Hz): noisy
  body-frame twist and pose, as an RTK-GNSS with two antennas gives them.
* ``ground_truth/skid_steer/state`` — terrain_msgs/SkidSteerState of the truth;
  ``ground_truth/odom`` — nav_msgs/Odometry of the true twist and pose.

The vehicle's nominal physics comes from the same ``vehicle.*`` parameters as
the estimator's (one config file serves both); ``plant.*`` holds what only the
truth plant has, ``effects.*`` the switchable unmodelled effects. The defaults
are the truth of the estimator tests: the plant's own magic-formula tire
(``plant.tire_law``; ``brush`` is the paper's idealised law) and the two
effects the [SS] issue asks for (roll/pitch load-transfer dynamics and tire
relaxation); everything else is off. ``ground.*`` inclines the ground plane and
lays terrain patches on it (:mod:`vehicle_sim.plants.skid_steer_ground`; level
and uniform by default).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, JointState

from terrain_estimation.params import ParamSpec, ParamValue
from terrain_estimation.ros.adapters import TopicSpec
from terrain_estimation.ros.parameters import check_kind, field_specs, float_fields, kind_specs, namespaced_frame
from terrain_estimation.ros.skid_steer_params import VEHICLE_SPECS_SKID_STEER, vehicle_params
from terrain_estimation.ros.time import sec_to_stamp
from terrain_msgs.msg import SkidSteerState
from vehicle_sim.plants.skid_steer import SkidSteerSample, SkidSteerSimulator
from vehicle_sim.plants.skid_steer_ground import SURFACES, SkidSteerGround, Surface, TerrainPatch
from vehicle_sim.plants.skid_steer_manoeuvres import MANOEUVRES, SkidSteerScenario
from vehicle_sim.plants.skid_steer_vehicle import SkidSteerEffects, SkidSteerSensors, SkidSteerVehicle
from vehicle_sim.plants.tire_laws import TIRE_LAWS, MagicFormulaTire
from vehicle_sim.ros.adapter import SimAdapter

__all__ = ["SCENARIO_SPECS", "PARAMETERS", "SkidSteerSimAdapter", "make_adapter", "make_scenario", "specs_for"]

_V = SkidSteerVehicle.truth_default()
_S = SkidSteerSensors()
_TRUTH = SkidSteerEffects.truth_default()
_MF = MagicFormulaTire()
_G = SkidSteerGround()

#: Truth-only plant parameters: (field of SkidSteerVehicle, unit, description, min, max).
_PLANT_FIELDS: tuple[tuple[str, str, str, float, float], ...] = (
    ("wheel_inertia", "kg m^2", "rotational inertia of one wheel with tire and hub", 1e-3, 1e4),
    ("motor_inertia", "kg m^2", "rotor inertia of one side motor (motor side; reflected by i_g^2)", 0.0, 1e3),
    ("transmission_efficiency", "-", "drive-line efficiency eta: wheel torque = eta i_g T_m", 0.05, 1.0),
    ("motor_torque_limit", "N m", "motor torque limit (motor side)", 1e-3, 1e5),
    ("rolling_resistance", "-", "motion-resistance coefficient (force per unit normal load)", 0.0, 1.0),
    ("unsprung_mass_per_wheel", "kg", "wheel, hub and arm mass below the springs", 0.0, 1e4),
    ("roll_inertia", "kg m^2", "sprung-mass roll inertia about its centre of mass", 1e-3, 1e7),
    ("pitch_inertia", "kg m^2", "sprung-mass pitch inertia about its centre of mass", 1e-3, 1e7),
    ("roll_centre_height", "m", "height of the roll axis above the ground", 0.0, 10.0),
    ("pitch_centre_height", "m", "height of the pitch axis above the ground", 0.0, 10.0),
    ("roll_stiffness", "N m/rad", "suspension roll stiffness", 1.0, 1e9),
    ("roll_damping", "N m s/rad", "suspension roll damping", 0.0, 1e9),
    ("pitch_stiffness", "N m/rad", "suspension pitch stiffness", 1.0, 1e9),
    ("pitch_damping", "N m s/rad", "suspension pitch damping", 0.0, 1e9),
    ("longitudinal_relaxation_length", "m", "tire relaxation length L_x of the longitudinal force lag", 1e-3, 10.0),
    ("lateral_relaxation_length", "m", "tire relaxation length L_y of the lateral force lag", 1e-3, 10.0),
)

#: Magic-formula tire parameters: (field of MagicFormulaTire, unit, description, min, max).
_MAGIC_FORMULA_FIELDS: tuple[tuple[str, str, str, float, float], ...] = (
    ("shape_longitudinal", "-", "shape factor C_x of the pure longitudinal curve", 1.0001, 1.9999),
    ("curvature_longitudinal", "-", "curvature factor E_x of the pure longitudinal curve", -9.9999, 0.9999),
    ("shape_lateral", "-", "shape factor C_y of the pure lateral curve", 1.0001, 1.9999),
    ("curvature_lateral", "-", "curvature factor E_y of the pure lateral curve", -9.9999, 0.9999),
    (
        "cornering_stiffness_peak_load",
        "-",
        "load, in units of m g/6, at which the cornering stiffness c1 sin(2 atan(Fz/(p Fz0))) is largest",
        0.01,
        100.0,
    ),
    (
        "longitudinal_stiffness_load_exponent",
        "-",
        "p of the longitudinal slip stiffness Kx0 (Fz/Fz0) exp(p dfz)",
        -5.0,
        5.0,
    ),
    ("friction_load_sensitivity", "-", "p of the friction mu (1 + p dfz), dfz = Fz/Fz0 - 1", -0.9999, 0.9999),
    ("low_speed", "m/s", "floor of the slip denominator max(|v_x|, V_low)", 1e-3, 10.0),
    (
        "slip_range",
        "-",
        "largest combined slip read from the curves, in units of the peak slip; the force is held beyond it",
        1.0001,
        1e3,
    ),
)

#: Patch parameters: (suffix, field of TerrainPatch / Surface, unit, description, min, max).
_PATCH_FIELDS: tuple[tuple[str, str, str, str, float, float], ...] = (
    ("friction", "friction", "-", "peak friction coefficient mu of each patch", 1e-3, 10.0),
    ("stiffness_scale", "stiffness_scale", "-", "factor on the tire slip stiffnesses on each patch", 1e-3, 10.0),
    ("rolling_resistance", "rolling_resistance", "-", "rolling-resistance coefficient of each patch", 0.0, 1.0),
    ("x_min", "x_min", "m", "lower x edge of each patch (plane coordinates; -1e9: open)", -1e9, 1e9),
    ("x_max", "x_max", "m", "upper x edge of each patch (1e9: open)", -1e9, 1e9),
    ("y_min", "y_min", "m", "lower y edge of each patch (-1e9: open)", -1e9, 1e9),
    ("y_max", "y_max", "m", "upper y edge of each patch (1e9: open)", -1e9, 1e9),
)

_PRESETS = "; ".join(
    f"{name}: mu {s.friction:g}, stiffness x{s.stiffness_scale:g}, f_rr {s.rolling_resistance:g}"
    for name, s in SURFACES.items()
)

SCENARIO_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "scenario.manoeuvre",
        "small_radius_turn",
        "manoeuvre of [SS] (B.11): straight 0-30 km/h, 7 m turn at 5 km/h, S-shape at 30 km/h",
        choices=tuple(MANOEUVRES),
        read_only=True,
    ),
    ParamSpec("scenario.duration", 0.0, "[s] simulated time; 0: the manoeuvre's own", 0.0, 1e5, read_only=True),
    *field_specs("plant", _V, _PLANT_FIELDS),
    ParamSpec(
        "plant.tire_law",
        _V.tire_law,
        "tire force law of the plant: magic_formula (its own, the truth) or brush (the observer's idealised law)",
        choices=TIRE_LAWS,
        read_only=True,
    ),
    *field_specs("plant.magic_formula", _MF, _MAGIC_FORMULA_FIELDS, "magic-formula tire: "),
    ParamSpec(
        "ground.grade",
        _G.grade,
        "[rad] inclination of the ground plane along its x axis (> 0: rises along +x)",
        -0.78,
        0.78,
        read_only=True,
    ),
    ParamSpec(
        "ground.cross_slope",
        _G.cross_slope,
        "[rad] inclination of the ground plane along its y axis (> 0: rises along +y; a bank at the start heading)",
        -0.78,
        0.78,
        read_only=True,
    ),
    ParamSpec(
        "ground.transition",
        _G.transition,
        "[m] width over which a wheel's surface blends across a patch edge",
        1e-3,
        100.0,
        read_only=True,
    ),
    *(
        ParamSpec(
            f"ground.patch_{suffix}",
            [],
            (
                f"[{unit}] {text}; one entry per terrain patch: rectangles of the ground plane laid over the "
                f"vehicle's own surface, later over earlier, each wheel on the one under its contact point; all "
                f"ground.patch_* lists equally long (none: no patch). Surface presets: {_PRESETS}"
            )
            if suffix == "friction"
            else f"[{unit}] {text}; one entry per terrain patch (as ground.patch_friction)",
            lo,
            hi,
            read_only=True,
        )
        for suffix, _, unit, text, lo, hi in _PATCH_FIELDS
    ),
    ParamSpec(
        "effects.load_transfer_dynamics",
        _TRUTH.load_transfer_dynamics,
        "sprung-mass roll/pitch dynamics: loads lag the accelerations, the IMU tilts (off: quasi-static loads)",
        read_only=True,
    ),
    ParamSpec(
        "effects.tire_relaxation",
        _TRUTH.tire_relaxation,
        "first-order tire force lag with the relaxation lengths (off: instantaneous tire-law forces)",
        read_only=True,
    ),
    ParamSpec("effects.gyro_bias", 0.0, "[rad/s] constant yaw-gyro bias", -1.0, 1.0, read_only=True),
    ParamSpec("effects.accel_bias", [0.0, 0.0, 0.0], "[m/s^2] accelerometer bias x, y, z", -10.0, 10.0, read_only=True),
    ParamSpec("effects.sensor_delay", 0.0, "[s] IMU latency", 0.0, 1.0, read_only=True),
    ParamSpec(
        "effects.wheel_radius_error", 0.0, "[-] true rolling radius = nominal (1 + e)", -0.49, 0.49, read_only=True
    ),
    ParamSpec("effects.friction_change", 1.0, "[-] true mu = nominal mu x factor", 0.01, 10.0, read_only=True),
    ParamSpec(
        "effects.cornering_stiffness_change",
        1.0,
        "[-] true cornering stiffness = nominal x factor",
        0.01,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.terrain_grade", 0.0, "[rad] road grade along the path (> 0 uphill)", -0.78, 0.78, read_only=True
    ),
    ParamSpec("sensors.rate", 100.0, "[Hz] IMU and joint-state rate", 1.0, 10000.0, read_only=True),
    ParamSpec(
        "sensors.accel_noise_std", _S.accel_noise_std, "[m/s^2] accelerometer noise per axis", 0.0, 10.0, read_only=True
    ),
    ParamSpec(
        "sensors.gyro_noise_std", _S.gyro_noise_std, "[rad/s] gyroscope noise per axis", 0.0, 1.0, read_only=True
    ),
    ParamSpec(
        "sensors.encoder_counts_per_revolution",
        _S.encoder_counts_per_revolution,
        "[-] motor encoder counts per motor revolution",
        1,
        10**9,
        read_only=True,
    ),
    ParamSpec(
        "sensors.motor_velocity_noise_std",
        _S.motor_velocity_noise_std,
        "[rad/s] noise on the reported motor speed (motor side)",
        0.0,
        100.0,
        read_only=True,
    ),
    ParamSpec(
        "sensors.motor_effort_noise_std",
        _S.motor_effort_noise_std,
        "[N m] noise on the reported motor torque (motor side)",
        0.0,
        1e3,
        read_only=True,
    ),
    ParamSpec(
        "sensors.gnss_rate",
        _S.gnss_rate,
        "[Hz] RTK-GNSS reference rate; 0 disables gnss/odom",
        0.0,
        1000.0,
        read_only=True,
    ),
    ParamSpec(
        "sensors.gnss_velocity_noise_std",
        _S.gnss_velocity_noise_std,
        "[m/s] GNSS velocity noise",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "sensors.gnss_position_noise_std",
        _S.gnss_position_noise_std,
        "[m] GNSS position noise",
        0.0,
        100.0,
        read_only=True,
    ),
    ParamSpec(
        "sensors.gnss_yaw_noise_std", _S.gnss_yaw_noise_std, "[rad] GNSS heading noise", 0.0, 1.0, read_only=True
    ),
    ParamSpec("seed", 0, "seed of the sensor noise", 0, 2**31 - 1, read_only=True),
    ParamSpec("joints.left_motor", "left_motor", "joint_states name of the left motor", read_only=True),
    ParamSpec("joints.right_motor", "right_motor", "joint_states name of the right motor", read_only=True),
    ParamSpec("frames.imu", "imu_link", "frame of imu (prefixed with the namespace)", read_only=True),
    ParamSpec("frames.odom", "odom", "frame of gnss/odom and ground_truth/odom (prefixed)", read_only=True),
    ParamSpec("frames.base_link", "base_link", "body frame (prefixed with the namespace)", read_only=True),
)


def _ground(values: Mapping[str, ParamValue]) -> SkidSteerGround:
    """The ground from ``ground.*``: slope, transition and the patch lists (equally long)."""
    columns = {suffix: [float(v) for v in values[f"ground.patch_{suffix}"]] for suffix, *_ in _PATCH_FIELDS}
    lengths = {len(c) for c in columns.values()}
    if len(lengths) > 1:
        sizes = ", ".join(f"ground.patch_{suffix} {len(c)}" for suffix, c in columns.items())
        raise ValueError(f"the ground.patch_* lists must be equally long (one entry per patch), got {sizes}")
    patches = []
    for i in range(lengths.pop() if lengths else 0):
        surface = Surface(
            name=f"patch {i}",
            friction=columns["friction"][i],
            stiffness_scale=columns["stiffness_scale"][i],
            rolling_resistance=columns["rolling_resistance"][i],
        )
        edges = {
            name: columns[name][i] if abs(columns[name][i]) < 1e9 else math.copysign(math.inf, columns[name][i])
            for name in ("x_min", "x_max", "y_min", "y_max")
        }
        patches.append(TerrainPatch(surface=surface, **edges))
    return SkidSteerGround(
        grade=float(values["ground.grade"]),
        cross_slope=float(values["ground.cross_slope"]),
        patches=tuple(patches),
        transition=float(values["ground.transition"]),
    )


#: Numeric fields of SkidSteerEffects / SkidSteerSensors set from ``effects.<field>`` / ``sensors.<field>``.
_EFFECT_FLOATS = (
    "gyro_bias",
    "sensor_delay",
    "wheel_radius_error",
    "friction_change",
    "cornering_stiffness_change",
    "terrain_grade",
)
_SENSOR_FLOATS = tuple(
    name for name in SkidSteerSensors.__dataclass_fields__ if name != "encoder_counts_per_revolution"
)


def make_scenario(values: Mapping[str, ParamValue]) -> SkidSteerScenario:
    """The plant's scenario from validated parameter values."""
    vehicle = SkidSteerVehicle(
        nominal=vehicle_params(values),
        tire_law=str(values["plant.tire_law"]),
        magic_formula=MagicFormulaTire(
            **float_fields(values, "plant.magic_formula", (n for n, *_ in _MAGIC_FORMULA_FIELDS))
        ),
        **float_fields(values, "plant", (name for name, *_ in _PLANT_FIELDS)),
    )
    bias = [float(b) for b in values["effects.accel_bias"]]
    if len(bias) != 3:
        raise ValueError(f"effects.accel_bias must hold 3 values (x, y, z), got {len(bias)}: {bias}")
    effects = SkidSteerEffects(
        load_transfer_dynamics=bool(values["effects.load_transfer_dynamics"]),
        tire_relaxation=bool(values["effects.tire_relaxation"]),
        accel_bias=(bias[0], bias[1], bias[2]),
        **float_fields(values, "effects", _EFFECT_FLOATS),
    )
    sensors = SkidSteerSensors(
        encoder_counts_per_revolution=int(values["sensors.encoder_counts_per_revolution"]),
        **float_fields(values, "sensors", _SENSOR_FLOATS),
    )
    base = MANOEUVRES[str(values["scenario.manoeuvre"])](vehicle=vehicle, effects=effects, sensors=sensors)
    duration = float(values["scenario.duration"])
    return dataclasses.replace(
        base,
        duration=duration if duration > 0.0 else None,
        sensor_rate=float(values["sensors.rate"]),
        ground=_ground(values),
    )


def _odometry(
    t: float, frame: str, child: str, vx: float, vy: float, r: float, x: float, y: float, yaw: float
) -> Odometry:
    msg = Odometry()
    msg.header.stamp = sec_to_stamp(t)
    msg.header.frame_id = frame
    msg.child_frame_id = child
    msg.pose.pose.position.x = x
    msg.pose.pose.position.y = y
    msg.pose.pose.orientation.z = math.sin(0.5 * yaw)
    msg.pose.pose.orientation.w = math.cos(0.5 * yaw)
    msg.twist.twist.linear.x = vx
    msg.twist.twist.linear.y = vy
    msg.twist.twist.angular.z = r
    return msg


class SkidSteerSimAdapter(SimAdapter):
    """Steps a :class:`SkidSteerSimulator` and builds the contract's messages."""

    def __init__(self, values: Mapping[str, ParamValue], namespace: str) -> None:
        self.scenario = make_scenario(values)
        self.simulator = SkidSteerSimulator(self.scenario, int(values["seed"]))
        self.period = self.scenario.sensor_period
        self.frames = {
            key: namespaced_frame(namespace, str(values[f"frames.{key}"])) for key in ("imu", "odom", "base_link")
        }
        self.joints = [str(values["joints.left_motor"]), str(values["joints.right_motor"])]
        s = self.scenario.sensors
        self.accel_variance = s.accel_noise_std**2
        self.gyro_variance = s.gyro_noise_std**2
        self.gnss_twist_cov = s.gnss_velocity_noise_std**2
        self.gnss_pose_cov = (s.gnss_position_noise_std**2, s.gnss_yaw_noise_std**2)
        self.outputs: Sequence[TopicSpec] = (
            TopicSpec("imu", "imu", Imu, "sensor"),
            TopicSpec("joint_states", "joint_states", JointState, "sensor"),
            TopicSpec("gnss", "gnss/odom", Odometry, "sensor"),
            TopicSpec("truth_state", "ground_truth/skid_steer/state", SkidSteerState, "estimate"),
            TopicSpec("truth_odom", "ground_truth/odom", Odometry, "estimate"),
        )

    def messages(self, sample: SkidSteerSample) -> list[tuple[str, Any]]:
        """The messages of one sample, in publication order (joints before the IMU that steps the filter)."""
        t = sample.t
        out: list[tuple[str, Any]] = []
        joints = JointState(
            name=list(self.joints),
            position=[float(v) for v in sample.motor_position],
            velocity=[float(v) for v in sample.motor_velocity],
            effort=[float(v) for v in sample.motor_effort],
        )
        joints.header.stamp = sec_to_stamp(t)
        joints.header.frame_id = self.frames["base_link"]
        out.append(("joint_states", joints))
        imu = Imu()
        imu.header.stamp = sec_to_stamp(t)
        imu.header.frame_id = self.frames["imu"]
        imu.orientation_covariance[0] = -1.0  # not measured
        a, w = sample.linear_acceleration, sample.angular_velocity
        imu.linear_acceleration.x, imu.linear_acceleration.y, imu.linear_acceleration.z = (float(v) for v in a)
        imu.angular_velocity.x, imu.angular_velocity.y, imu.angular_velocity.z = (float(v) for v in w)
        for i in (0, 4, 8):
            imu.linear_acceleration_covariance[i] = self.accel_variance
            imu.angular_velocity_covariance[i] = self.gyro_variance
        out.append(("imu", imu))
        g = sample.gnss
        if g is not None:
            gnss = _odometry(g.t, self.frames["odom"], self.frames["base_link"], g.vx, g.vy, 0.0, g.x, g.y, g.yaw)
            gnss.twist.covariance[0] = gnss.twist.covariance[7] = self.gnss_twist_cov
            gnss.twist.covariance[35] = -1.0  # yaw rate: not measured by the GNSS
            gnss.pose.covariance[0] = gnss.pose.covariance[7] = self.gnss_pose_cov[0]
            gnss.pose.covariance[35] = self.gnss_pose_cov[1]
            out.append(("gnss", gnss))
        tr = sample.truth
        state = SkidSteerState(
            vx=float(tr.vx),
            vy=float(tr.vy),
            yaw_rate=float(tr.yaw_rate),
            body_sideslip=float(tr.body_sideslip),
            slip_left=float(tr.slip[0]),
            slip_right=float(tr.slip[1]),
            tire_sideslip=[float(v) for v in tr.tire_sideslip],
            icr_x=float(tr.icr_x),
            icr_y=float(tr.icr_y),
            icr_valid=bool(tr.icr_valid),
            fading_factor=1.0,
            noise_scale=1.0,
        )
        state.header.stamp = sec_to_stamp(t)
        state.header.frame_id = self.frames["base_link"]
        out.append(("truth_state", state))
        yaw = math.remainder(float(tr.yaw), 2.0 * math.pi)
        out.append(
            (
                "truth_odom",
                _odometry(
                    t,
                    self.frames["odom"],
                    self.frames["base_link"],
                    float(tr.vx),
                    float(tr.vy),
                    float(tr.yaw_rate),
                    float(tr.x),
                    float(tr.y),
                    yaw,
                ),
            )
        )
        return out


def specs_for(kind: str = "skid_steer") -> tuple[ParamSpec, ...]:
    """Simulator specs: the estimator's vehicle parameters (one config file serves both) plus the plant's."""
    return kind_specs(kind, "skid_steer", "skid-steer", VEHICLE_SPECS_SKID_STEER, SCENARIO_SPECS)


PARAMETERS = specs_for()


def make_adapter(values: Mapping[str, ParamValue], namespace: str, kind: str = "skid_steer") -> SkidSteerSimAdapter:
    check_kind(kind, "skid_steer", "skid-steer")
    return SkidSteerSimAdapter(values, namespace)
