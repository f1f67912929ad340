"""Rocker-bogie rover simulator (one side of Kapvik, planar): parameters and messages.

Steps :class:`vehicle_sim.plants.rover.RoverSimulator` at its 50 Hz control
rate and turns each :class:`~vehicle_sim.plants.rover.RoverSample` into the
contract's topics (CONTRACT.md, "Rocker-bogie rover"):

* ``imu`` — sensor_msgs/Imu in ``imu_link``: ``linear_acceleration`` x, z =
  body-frame specific force (eqs. 72–73, REP 145: +g on z at rest),
  ``angular_velocity.y`` = pitch rate. The planar plant has no y
  acceleration and no roll or yaw rate: those fields are 0 with variance 0;
  orientation is not measured (``orientation_covariance[0] = -1``).
* ``joint_states`` — joints ``bogie``, ``rear_wheel``, ``middle_wheel``,
  ``front_wheel`` (names are parameters): ``position`` = encoder angles q1,
  q2..q4 (wheel angles relative to their carrier link), ``velocity`` = the
  backward difference of consecutive published positions over 20 ms, as an
  encoder driver reports it (the first sample: the true rates), ``effort`` =
  applied wheel torque τ_W (N·m; 0 for the passive bogie joint).
* ``velocimeter`` — geometry_msgs/TwistStamped in ``base_link``:
  ``twist.linear.x`` = forward speed along the body x axis.
* ``wheel/front/load``, ``wheel/middle/load``, ``wheel/rear/load`` —
  geometry_msgs/WrenchStamped in ``<wheel>_load_cell``: ``force.z`` = F_L
  along the sensing axis, ``force.x`` = F_⊥ (eqs. 81–82). With
  ``sensors.load_cell_axes: 1`` (single-axis cells, as on Kapvik)
  ``force.x`` is published as 0. WrenchStamped has no covariance field, so
  the contract's "-1 marks a field not measured" cannot be expressed: the
  number of axes is a parameter on both sides (the estimator's
  ``estimator.load_cell_axes``), never guessed from the data.
* ``ground_truth/wheel_terrain`` — terrain_msgs/WheelTerrainArray, the type of
  the estimate, wheels in the estimator's order (rear, middle, front): true
  slip, normal load W, drawbar pull DP, resistive torque τ_R and contact angle
  γ (terrain tangent below the horizontal, positive descending forward — the
  estimator's ``contact_angle``) of every wheel at the sample's time;
  variances 0, ``settled`` true.
* ``/clock`` is published by the framework.

Every message of a step carries the sample's time t = k / 50 Hz (from 0).
The vehicle's nominal physics comes from the same ``vehicle.*`` parameters as
the estimator's (one config file serves both); ``plant.*``, ``controller.*``
and ``soil.*`` hold what only the truth plant has, ``effects.*`` the
switchable unmodelled effects of the sim-to-real catalogue, all off by
default.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import TwistStamped, WrenchStamped
from sensor_msgs.msg import Imu, JointState

from terrain_estimation.models.rover import WHEELS
from terrain_estimation.params import ParamSpec, ParamValue
from terrain_estimation.ros.adapters import TopicSpec
from terrain_estimation.ros.parameters import (
    check_kind,
    field_specs,
    fixed_floats,
    float_fields,
    kind_specs,
    namespaced_frame,
)
from terrain_estimation.ros.parameters import float_value as _f
from terrain_estimation.ros.rover_params import VEHICLE_SPECS_ROVER, vehicle_params
from terrain_estimation.ros.time import sec_to_stamp
from terrain_msgs.msg import WheelTerrain, WheelTerrainArray
from vehicle_sim.plants.rover import RoverSimulator
from vehicle_sim.plants.rover_paths import TERRAIN_NUMBERS, TERRAINS
from vehicle_sim.plants.rover_scenario import (
    CONTROL_RATE,
    RoverController,
    RoverEffects,
    RoverSample,
    RoverScenario,
    RoverSensorNoise,
)
from vehicle_sim.ros.adapter import SimAdapter
from vehicle_sim.terrain.wong_reece import TABLE_II_SOIL, WongReeceSoil

__all__ = ["SCENARIO_SPECS", "PARAMETERS", "RoverSimAdapter", "make_adapter", "make_scenario", "specs_for"]

_SCENARIO = RoverScenario()
_C = RoverController()
_N = RoverSensorNoise()

#: (field of RoverController, unit, description, min, max).
_CONTROLLER_FIELDS: tuple[tuple[str, str, str, float, float], ...] = (
    ("proportional_gain", "N m per m/s", "wheel-speed PID K_p on the rim-speed error (Table III)", 0.0, 1e6),
    ("integral_gain", "N m per m/s", "PID K_i per 50 Hz sample of the running error sum (Table III)", 0.0, 1e6),
    ("derivative_gain", "N m per m/s", "PID K_d per change between samples (Table III)", 0.0, 1e6),
    ("max_torque", "N m", "saturation of the applied wheel torque [recon]", 1e-3, 1e4),
)

#: (field of WongReeceSoil, unit, description, min, max); defaults [RB] Table II.
_SOIL_FIELDS: tuple[tuple[str, str, str, float, float], ...] = (
    ("sinkage_exponent", "-", "sinkage exponent n_s", 1e-3, 10.0),
    ("cohesion", "Pa", "cohesion c", 0.0, 1e7),
    ("friction_angle", "rad", "internal friction angle phi (Table II: 31.9 deg)", 0.0, 1.57),
    ("shear_deformation_modulus", "m", "shear deformation modulus K_s", 1e-6, 1.0),
    ("pressure_sinkage_k1", "Pa", "pressure-sinkage k1 = k_c b^(n-1), eqs. 4-5", 0.0, 1e9),
    ("pressure_sinkage_k2", "Pa/m", "pressure-sinkage k2 = k_phi b^(n-1), eqs. 4-5", 0.0, 1e12),
    ("max_stress_angle_c1", "-", "maximum-stress angle c1, eq. 3", 1e-6, 1.0),
    ("max_stress_angle_c2", "-", "maximum-stress angle c2, eq. 3 (c1 + c2 <= 1)", -1.0, 1.0),
)

#: (field of RoverSensorNoise, unit, description); defaults [RB] Table IV.
_NOISE_FIELDS: tuple[tuple[str, str, str], ...] = (
    ("bogie_angle_std", "rad", "bogie encoder noise sigma (Table IV: 9.155e-4 deg)"),
    ("pitch_rate_std", "rad/s", "pitch-rate gyro noise sigma (Table IV: 0.56 deg/s)"),
    ("forward_velocity_std", "m/s", "velocimeter noise sigma (Table IV: 1 mm/s)"),
    ("acceleration_std", "m/s^2", "accelerometer noise sigma per axis (Table IV: 1.245e-3)"),
    ("wheel_angle_std", "rad", "wheel encoder noise sigma (Table IV: 2.143e-5 deg)"),
    ("load_cell_std", "N", "load-cell noise sigma per axis (Table IV: 3.255e-2 N)"),
)

_TERRAIN_TEXT = ", ".join(f"{n} = {name}" for n, name in TERRAIN_NUMBERS.items())

SCENARIO_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "scenario.terrain",
        _SCENARIO.terrain,
        f"wheel-centre path: [RB] Fig. 10 terrains ({_TERRAIN_TEXT}) or level 'flat'",
        choices=tuple(TERRAINS),
        read_only=True,
    ),
    ParamSpec(
        "scenario.duration",
        0.0,
        "[s] length of the run the terrain is laid out for (0: the terrain's own, 100-200 s); the node itself "
        "runs until its 'duration' parameter, terrain-simulate for --duration",
        0.0,
        1e6,
        read_only=True,
    ),
    ParamSpec(
        "scenario.terramechanics",
        _SCENARIO.terramechanics,
        "wheel-soil model: 'surrogate' = 4th-order polynomial fit of Wong-Reece ([RB]'s simulation, C.2), "
        "'wong_reece' = the full rigid-wheel model (C.1, root finding: slower)",
        choices=("surrogate", "wong_reece"),
        read_only=True,
    ),
    ParamSpec(
        "scenario.desired_speed",
        _SCENARIO.desired_speed,
        "[m/s] wheel rim speed v_d (Table III: 2 cm/s)",
        1e-4,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "scenario.start_x",
        _SCENARIO.start_x,
        "[m] where along the path O starts (the rover starts rolling in steady state)",
        -100.0,
        100.0,
        read_only=True,
    ),
    ParamSpec("seed", 0, "seed of the sensor noise (the truth does not depend on it)", 0, 2**31 - 1, read_only=True),
    *field_specs("controller", _C, _CONTROLLER_FIELDS),
    ParamSpec(
        "plant.baumgarte_alpha",
        _SCENARIO.baumgarte_alpha,
        "[1/s] constraint stabilisation alpha (eq. 31)",
        0.0,
        1e5,
        read_only=True,
    ),
    ParamSpec(
        "plant.baumgarte_beta",
        _SCENARIO.baumgarte_beta,
        "[1/s] constraint stabilisation beta (eq. 31)",
        0.0,
        1e5,
        read_only=True,
    ),
    ParamSpec(
        "plant.integration_step",
        _SCENARIO.integration_step,
        "[s] largest RK4 step (shorter when the slip dynamics are stiffer)",
        1e-6,
        0.02,
        read_only=True,
    ),
    ParamSpec(
        "plant.slip_stencil",
        _SCENARIO.slip_stencil,
        "[-] slip offset of the per-step quadratic model of DP(i), tau_R(i)",
        1e-4,
        0.1,
        read_only=True,
    ),
    ParamSpec(
        "plant.wheel_sinkage",
        _SCENARIO.wheel_sinkage,
        "[-] sink each wheel by its Wong-Reece sinkage r (1 - cos theta0(W, i)) (false: centres on the path)",
        read_only=True,
    ),
    ParamSpec(
        "plant.sinkage_loading_time",
        _SCENARIO.sinkage_loading_time,
        "[s] time constant of the sinkage following a rising load or slip",
        1e-3,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "plant.simpson_points",
        _SCENARIO.simpson_points,
        "[-] rim nodes per flow region of the full Wong-Reece model (odd)",
        3,
        1001,
        read_only=True,
    ),
    *field_specs("soil", TABLE_II_SOIL, _SOIL_FIELDS, "Table II soil: "),
    ParamSpec(
        "sensors.load_cell_axes",
        2,
        "[-] axes the load cells publish: 2 = F_L (force.z) and F_perp (force.x); 1 = F_L only (force.x = 0). "
        "Two-axis bags serve both estimators",
        1,
        2,
        read_only=True,
    ),
    *(
        ParamSpec(f"sensors.{name}", float(getattr(_N, name)), f"[{unit}] {text}", 0.0, 1e3, read_only=True)
        for name, unit, text in _NOISE_FIELDS
    ),
    ParamSpec(
        "sensors.quantise",
        _N.quantise,
        "round encoders and load cells to their least-significant step instead of adding Gaussian noise",
        read_only=True,
    ),
    ParamSpec(
        "effects.load_cell_bias",
        [0.0, 0.0, 0.0],
        "[N] constant offset of each F_L (rear, middle, front)",
        -200.0,
        200.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.load_cell_crosstalk",
        0.0,
        "[-] fraction of each load-cell axis leaking into the other",
        -1.0,
        1.0,
        read_only=True,
    ),
    ParamSpec("effects.imu_accel_bias", [0.0, 0.0], "[m/s^2] accelerometer bias (x, z)", -10.0, 10.0, read_only=True),
    ParamSpec("effects.imu_gyro_bias", 0.0, "[rad/s] pitch-rate gyro bias", -1.0, 1.0, read_only=True),
    ParamSpec(
        "effects.sensor_delay",
        0.0,
        "[s] latency of every measured channel, whole 20 ms samples (the effort is not delayed)",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.soil_change",
        False,
        "wheels beyond effects.soil_change_distance run on a changed soil (Table II with the soil_change_* values)",
        read_only=True,
    ),
    ParamSpec(
        "effects.soil_change_distance",
        1.0,
        "[m] wheel-centre x where the soil changes",
        -100.0,
        100.0,
        read_only=True,
    ),
    ParamSpec("effects.soil_change_cohesion", 100.0, "[Pa] cohesion c of the changed soil", 0.0, 1e7, read_only=True),
    ParamSpec(
        "effects.soil_change_friction_angle",
        math.radians(26.0),
        "[rad] friction angle phi of the changed soil",
        0.0,
        1.57,
        read_only=True,
    ),
    ParamSpec(
        "effects.soil_change_shear_deformation_modulus",
        0.02,
        "[m] shear deformation modulus K_s of the changed soil",
        1e-6,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.slip_sinkage_coefficient",
        0.0,
        "[-] slip-sinkage c: pressure-sinkage moduli k/(1 + c|i|), so a slipping wheel sinks deeper (0: off)",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.grouser_height",
        0.0,
        "[m] grouser height above the rim: the soil is sheared at r_w + h_g (0: off)",
        0.0,
        0.05,
        read_only=True,
    ),
    ParamSpec(
        "effects.path_undulation_amplitude",
        0.0,
        "[m] amplitude A of A(1 - cos(2 pi x / lambda)) added to the wheel-centre path (0: off)",
        0.0,
        0.05,
        read_only=True,
    ),
    ParamSpec(
        "effects.path_undulation_wavelength",
        0.5,
        "[m] wavelength lambda of the path undulation",
        0.05,
        100.0,
        read_only=True,
    ),
    ParamSpec("joints.bogie", "bogie", "joint_states name of the bogie joint (q1)", read_only=True),
    ParamSpec("joints.rear_wheel", "rear_wheel", "joint_states name of the rear wheel (q2)", read_only=True),
    ParamSpec("joints.middle_wheel", "middle_wheel", "joint_states name of the middle wheel (q3)", read_only=True),
    ParamSpec("joints.front_wheel", "front_wheel", "joint_states name of the front wheel (q4)", read_only=True),
    ParamSpec("frames.imu", "imu_link", "frame of imu (prefixed with the namespace)", read_only=True),
    ParamSpec(
        "frames.base_link",
        "base_link",
        "body frame: velocimeter, joint_states, ground truth (prefixed)",
        read_only=True,
    ),
    *(
        ParamSpec(
            f"frames.{w}_load_cell",
            f"{w}_load_cell",
            f"frame of wheel/{w}/load (prefixed with the namespace)",
            read_only=True,
        )
        for w in ("front", "middle", "rear")
    ),
)


#: Numeric fields of RoverEffects / RoverScenario set from ``effects.<field>`` / ``plant.<field>``.
_EFFECT_FLOATS = (
    "load_cell_crosstalk",
    "imu_gyro_bias",
    "sensor_delay",
    "slip_sinkage_coefficient",
    "grouser_height",
    "path_undulation_amplitude",
    "path_undulation_wavelength",
)
_PLANT_FLOATS = ("baumgarte_alpha", "baumgarte_beta", "integration_step", "slip_stencil", "sinkage_loading_time")


def make_scenario(values: Mapping[str, ParamValue]) -> RoverScenario:
    """The plant's scenario from validated parameter values.

    Raises:
        ValueError: inconsistent values (a bias list of the wrong length, an impossible soil …).
    """
    soil = WongReeceSoil(**float_fields(values, "soil", (name for name, *_ in _SOIL_FIELDS)))
    changed: dict[str, Any] = {}
    if values["effects.soil_change"]:
        changed = {
            "soil_change_distance": _f(values, "effects.soil_change_distance"),
            "soil_change_soil": WongReeceSoil(
                **{
                    **float_fields(values, "soil", (name for name, *_ in _SOIL_FIELDS)),
                    "cohesion": _f(values, "effects.soil_change_cohesion"),
                    "friction_angle": _f(values, "effects.soil_change_friction_angle"),
                    "shear_deformation_modulus": _f(values, "effects.soil_change_shear_deformation_modulus"),
                }
            ),
        }
    bias = fixed_floats(values, "effects.load_cell_bias", 3, "rear, middle, front")
    accel = fixed_floats(values, "effects.imu_accel_bias", 2, "x, z")
    effects = RoverEffects(
        load_cell_bias=(bias[0], bias[1], bias[2]),
        imu_accel_bias=(accel[0], accel[1]),
        **float_fields(values, "effects", _EFFECT_FLOATS),
        **changed,
    )
    duration = _f(values, "scenario.duration")
    return RoverScenario(
        terrain=str(values["scenario.terrain"]),
        duration=duration if duration > 0.0 else None,
        seed=int(values["seed"]),
        terramechanics=values["scenario.terramechanics"],
        desired_speed=_f(values, "scenario.desired_speed"),
        params=vehicle_params(values),
        soil=soil,
        controller=RoverController(**float_fields(values, "controller", (name for name, *_ in _CONTROLLER_FIELDS))),
        sensors=RoverSensorNoise(
            **float_fields(values, "sensors", (name for name, *_ in _NOISE_FIELDS)),
            quantise=bool(values["sensors.quantise"]),
        ),
        effects=effects,
        **float_fields(values, "plant", _PLANT_FLOATS),
        start_x=_f(values, "scenario.start_x"),
        simpson_points=int(values["plant.simpson_points"]),
        wheel_sinkage=bool(values["plant.wheel_sinkage"]),
    )


def wheel_terrain_truth(sample: RoverSample, frame_id: str) -> WheelTerrainArray:
    """ground_truth/wheel_terrain of one sample (wheels in :data:`WHEELS` order, variances 0)."""
    tr = sample.truth
    msg = WheelTerrainArray(
        wheels=[
            WheelTerrain(
                wheel=name,
                slip=float(tr.slip[j]),
                normal_load=float(tr.normal_load[j]),
                drawbar_pull=float(tr.drawbar_pull[j]),
                resistive_torque=float(tr.resistive_torque[j]),
                contact_angle=float(tr.contact_angle[j]),
            )
            for j, name in enumerate(WHEELS)
        ],
        settled=True,  # the truth needs no settling
    )
    msg.header.stamp = sec_to_stamp(sample.t)
    msg.header.frame_id = frame_id
    return msg


class RoverSimAdapter(SimAdapter):
    """Steps a :class:`RoverSimulator` and builds the contract's messages."""

    def __init__(self, values: Mapping[str, ParamValue], namespace: str) -> None:
        self.scenario = make_scenario(values)
        self.simulator = RoverSimulator(self.scenario)
        self.period = 1.0 / CONTROL_RATE
        self.two_axis = int(values["sensors.load_cell_axes"]) == 2
        self.frames = {key: namespaced_frame(namespace, str(values[f"frames.{key}"])) for key in ("imu", "base_link")}
        self.cell_frames = {w: namespaced_frame(namespace, str(values[f"frames.{w}_load_cell"])) for w in WHEELS}
        # joint_states order: the bogie, then the wheels in WHEELS order (rear, middle, front).
        self.joints = [str(values["joints.bogie"])] + [str(values[f"joints.{w}_wheel"]) for w in WHEELS]
        noise = self.scenario.sensors
        self.accel_variance = noise.acceleration_std**2
        self.gyro_variance = noise.pitch_rate_std**2
        self._previous_position: np.ndarray | None = None
        self.outputs: Sequence[TopicSpec] = (
            TopicSpec("imu", "imu", Imu, "sensor"),
            TopicSpec("joint_states", "joint_states", JointState, "sensor"),
            TopicSpec("velocimeter", "velocimeter", TwistStamped, "sensor"),
            *(TopicSpec(f"load_{w}", f"wheel/{w}/load", WrenchStamped, "sensor") for w in ("front", "middle", "rear")),
            TopicSpec("truth_wheel_terrain", "ground_truth/wheel_terrain", WheelTerrainArray, "estimate"),
        )

    def messages(self, sample: RoverSample) -> list[tuple[str, Any]]:
        """The messages of one sample, in publication order (sensors, then the ground truth)."""
        t = sample.t
        stamp = sec_to_stamp(t)
        s = sample.sensors
        out: list[tuple[str, Any]] = []

        imu = Imu()
        imu.header.stamp = stamp
        imu.header.frame_id = self.frames["imu"]
        imu.orientation_covariance[0] = -1.0  # not measured
        imu.linear_acceleration.x = float(s.acceleration[0])
        imu.linear_acceleration.z = float(s.acceleration[1])
        imu.linear_acceleration_covariance[0] = imu.linear_acceleration_covariance[8] = self.accel_variance
        imu.angular_velocity.y = float(s.pitch_rate)
        imu.angular_velocity_covariance[4] = self.gyro_variance
        out.append(("imu", imu))

        position = np.concatenate([[float(s.bogie_angle)], np.asarray(s.wheel_angle, dtype=float)])
        if self._previous_position is None:
            velocity = np.asarray(sample.truth.velocity, dtype=float)[3:7]  # q̇1, q̇2..q̇4
        else:
            velocity = (position - self._previous_position) / self.period
        self._previous_position = position
        joints = JointState(
            name=list(self.joints),
            position=[float(v) for v in position],
            velocity=[float(v) for v in velocity],
            effort=[0.0, *(float(v) for v in s.effort)],
        )
        joints.header.stamp = stamp
        joints.header.frame_id = self.frames["base_link"]
        out.append(("joint_states", joints))

        velocimeter = TwistStamped()
        velocimeter.header.stamp = stamp
        velocimeter.header.frame_id = self.frames["base_link"]
        velocimeter.twist.linear.x = float(s.forward_velocity)
        out.append(("velocimeter", velocimeter))

        for wheel in ("front", "middle", "rear"):
            j = WHEELS.index(wheel)
            cell = WrenchStamped()
            cell.header.stamp = stamp
            cell.header.frame_id = self.cell_frames[wheel]
            cell.wrench.force.z = float(s.load_axial[j])
            cell.wrench.force.x = float(s.load_perpendicular[j]) if self.two_axis else 0.0
            out.append((f"load_{wheel}", cell))

        out.append(("truth_wheel_terrain", wheel_terrain_truth(sample, self.frames["base_link"])))
        return out


def specs_for(kind: str = "rover") -> tuple[ParamSpec, ...]:
    """Simulator specs: the estimator's vehicle parameters (one config file serves both) plus the plant's."""
    return kind_specs(kind, "rover", "rover", VEHICLE_SPECS_ROVER, SCENARIO_SPECS)


PARAMETERS = specs_for()


def make_adapter(values: Mapping[str, ParamValue], namespace: str, kind: str = "rover") -> RoverSimAdapter:
    check_kind(kind, "rover", "rover")
    return RoverSimAdapter(values, namespace)
