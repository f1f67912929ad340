"""Quarter-car (2-DOF) and LRV (1-DOF) simulator: parameters and messages.

Turns :class:`vehicle_sim.plants.quarter_car.QuarterCarSample` into the
contract's topics (CONTRACT.md, quarter car section):

* ``imu/body``, ``imu/wheel`` (2-DOF only) — sensor_msgs/Imu, specific force
  along z (REP 145: +g at rest); orientation and angular velocity marked not
  measured (covariance[0] = -1); x and y are not simulated (zero, with the
  z variance reported for z only).
* ``joint_states`` — joint ``wheel``: angle (rad) and rate (rad/s).
* ``terrain/profile`` — one geometry_msgs/PointStamped per profile reading
  (1 kHz by default): ``point.x`` distance travelled, ``point.z`` elevation.
* ``ground_truth/soil_stiffness`` — terrain_msgs/SoilStiffness with the true
  k_s and k_tot.

``effects.*`` parameters switch on the unmodelled effects of the sim-to-real
catalogue (:class:`QuarterCarEffects`, CONTRACT.md "Nominal model and
effects"); all are off by default (the nominal plant). The LRV declares only
those that apply to a 1-DOF model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import Imu, JointState

from terrain_estimation.params import ParamSpec, ParamValue
from terrain_estimation.ros.adapters import TopicSpec
from terrain_estimation.ros.parameters import float_fields, namespaced_frame
from terrain_estimation.ros.soil_stiffness import VEHICLE_SPECS_LRV, VEHICLE_SPECS_QUARTER_CAR
from terrain_estimation.ros.time import sec_to_stamp
from terrain_msgs.msg import SoilStiffness
from vehicle_sim.plants.quarter_car import QuarterCarSimulator
from vehicle_sim.plants.quarter_car_effects import QuarterCarEffects
from vehicle_sim.plants.quarter_car_scenario import QuarterCarSample, Scenario, SpeedProfile
from vehicle_sim.plants.quarter_car_vehicles import LRVVehicle, QuarterCarVehicle
from vehicle_sim.ros.adapter import SimAdapter
from vehicle_sim.terrain.profiles import ISO8608_CLASSES, RoadProfile, flat_profile, iso8608_profile, meadow_c_standin
from vehicle_sim.terrain.soils import SOILS, SoilPath, soil_by_name

__all__ = [
    "EFFECT_SPECS_COMMON",
    "EFFECT_SPECS_TWO_DOF",
    "SCENARIO_SPECS",
    "PARAMETERS",
    "QuarterCarSimAdapter",
    "make_adapter",
    "make_effects",
    "make_road",
    "make_scenario",
    "make_vehicle",
]

ROAD_CHOICES = tuple(ISO8608_CLASSES) + ("meadow_c", "flat")


def _accelerometer_specs(sensor: str) -> tuple[ParamSpec, ParamSpec]:
    """Bias and scale-factor error of the ``sensor`` ("body" or "wheel") vertical accelerometer."""
    return (
        ParamSpec(
            f"effects.accel_bias_{sensor}",
            0.0,
            f"[m/s^2] constant bias of the {sensor} accelerometer",
            -50.0,
            50.0,
            read_only=True,
        ),
        ParamSpec(
            f"effects.accel_scale_{sensor}",
            0.0,
            f"[-] {sensor} accelerometer scale-factor error s: reading = (1 + s) x true",
            -0.99,
            0.99,
            read_only=True,
        ),
    )


# Unmodelled effects (CONTRACT.md "Nominal model and effects"; QuarterCarEffects): all off by default.
EFFECT_SPECS_COMMON: tuple[ParamSpec, ...] = (
    *_accelerometer_specs("body"),
    ParamSpec(
        "effects.sensor_delay",
        0.0,
        "[s] accelerometer latency vs profile and joint states (fractional periods: linear interpolation)",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.sensor_delay_body", 0.0, "[s] extra latency of the body accelerometer alone", 0.0, 1.0, read_only=True
    ),
    ParamSpec(
        "effects.sensor_delay_profile",
        0.0,
        "[s] latency of the profile sampler (readings buffered, stamped when delivered)",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.soil_origin_ratio",
        1.0,
        "[-] nonlinear soil: origin of the power law zeta z0 below the static point (1: Bekker-type law)",
        0.05,
        20.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.soil_exponent",
        0.0,
        "[-] Bekker-type soil exponent n, F = k_s z0 (z/z0)^n about the static sinkage z0; 0 or 1: linear soil (off)",
        0.0,
        3.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.wheel_liftoff", False, "unilateral tire contact (the wheel may leave the ground)", read_only=True
    ),
    ParamSpec(
        "effects.tire_contact_length",
        0.0,
        "[m] contact-patch length: the tire feels the moving average of the road over it (0: off)",
        0.0,
        5.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.sprung_mass_change",
        0.0,
        "[-] relative sprung-mass change x: the plant runs with m_s (1 + x)",
        -0.99,
        10.0,
        read_only=True,
    ),
)

# Effects of the 2-DOF quarter car only (the LRV has no wheel accelerometer, suspension or tire of its own).
EFFECT_SPECS_TWO_DOF: tuple[ParamSpec, ...] = (
    *_accelerometer_specs("wheel"),
    ParamSpec(
        "effects.sensor_delay_wheel",
        0.0,
        "[s] extra latency of the wheel accelerometer alone",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "effects.suspension_friction",
        0.0,
        "[N] Coulomb suspension friction, smoothed F_c tanh(dv / 0.02 m/s); at most ~830 N with 1 ms RK4 steps",
        0.0,
        1.0e5,
        read_only=True,
    ),
    ParamSpec(
        "effects.tire_damping", 0.0, "[N*s/m] damper in parallel with the tire stiffness", 0.0, 1.0e6, read_only=True
    ),
)


#: Numeric fields of QuarterCarEffects set from ``effects.<field>``, 0 (off) when not declared.
_EFFECT_NUMBERS = (
    "accel_bias_body",
    "accel_bias_wheel",
    "accel_scale_body",
    "accel_scale_wheel",
    "sensor_delay",
    "sensor_delay_body",
    "sensor_delay_wheel",
    "sensor_delay_profile",
    "soil_exponent",
    "suspension_friction",
    "tire_damping",
    "tire_contact_length",
    "sprung_mass_change",
)


def make_effects(values: Mapping[str, ParamValue]) -> QuarterCarEffects:
    """The effects from parameter values; the 2-DOF-only ones default to 0 when absent (LRV)."""

    def number(name: str) -> float:
        return float(values.get(f"effects.{name}", 0.0))

    return QuarterCarEffects(
        soil_origin_ratio=float(values.get("effects.soil_origin_ratio", 1.0)),
        wheel_liftoff=bool(values.get("effects.wheel_liftoff", False)),
        **{name: number(name) for name in _EFFECT_NUMBERS},
    )


_SCENARIO_HEAD: tuple[ParamSpec, ...] = (
    ParamSpec(
        "scenario.road",
        "D",
        "road profile: ISO 8608 class A-H, 'meadow_c' (stand-in) or 'flat'",
        choices=ROAD_CHOICES,
        read_only=True,
    ),
    ParamSpec("scenario.road_seed", 1, "seed of the road realisation", 0, 2**31 - 1, read_only=True),
    ParamSpec(
        "scenario.road_band_min", 0.05, "[cycles/m] lowest spatial frequency of the road", 0.001, 10.0, read_only=True
    ),
    ParamSpec(
        "scenario.road_band_max", 10.0, "[cycles/m] highest spatial frequency of the road", 0.01, 100.0, read_only=True
    ),
    ParamSpec(
        "scenario.soils",
        ["graneville_loam"],
        "soils along the path, in order (" + ", ".join(SOILS) + ")",
        read_only=True,
    ),
    ParamSpec(
        "scenario.soil_starts",
        [0.0],
        "[m] distance at which each soil of scenario.soils starts",
        0.0,
        1e7,
        read_only=True,
    ),
    ParamSpec("scenario.speed", 10.0, "[m/s] constant travel speed", 0.0, 60.0, read_only=True),
    ParamSpec(
        "scenario.wheel_liftoff",
        False,
        "unilateral tire contact; kept for old configs, same switch as effects.wheel_liftoff (either one on)",
        read_only=True,
    ),
)

_SENSOR_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("sensors.rate", 100.0, "[Hz] accelerometer and joint-state rate", 1.0, 10000.0, read_only=True),
    ParamSpec("sensors.profile_rate", 1000.0, "[Hz] terrain profile sampler rate", 1.0, 100000.0, read_only=True),
    ParamSpec(
        "sensors.accel_noise_variance", 0.5, "[(m/s^2)^2] accelerometer white-noise variance", 0.0, 1e3, read_only=True
    ),
    ParamSpec("sensors.profile_noise_std", 1e-4, "[m] profile sampler elevation noise (std)", 0.0, 0.1, read_only=True),
    ParamSpec("seed", 0, "seed of the sensor noise", 0, 2**31 - 1, read_only=True),
    ParamSpec("frames.body_imu", "body_imu", "frame of imu/body (prefixed with the namespace)", read_only=True),
    ParamSpec("frames.wheel_imu", "wheel_imu", "frame of imu/wheel (prefixed with the namespace)", read_only=True),
    ParamSpec("frames.odom", "odom", "frame of terrain/profile (prefixed with the namespace)", read_only=True),
    ParamSpec("frames.base_link", "base_link", "body frame (prefixed with the namespace)", read_only=True),
)

SCENARIO_SPECS: tuple[ParamSpec, ...] = _SCENARIO_HEAD + EFFECT_SPECS_COMMON + _SENSOR_SPECS
"""Scenario, effects (those the LRV has too) and sensor parameters."""


def make_vehicle(kind: str, values: Mapping[str, ParamValue]) -> QuarterCarVehicle | LRVVehicle:
    """The plant's vehicle from parameter values (``kind``: quarter_car | lrv)."""
    if kind == "lrv":
        return LRVVehicle(
            sprung_mass=float(values["vehicle.sprung_mass"]),
            combined_stiffness=float(values["vehicle.suspension_stiffness"]),
            damping=float(values["vehicle.suspension_damping"]),
            wheel_radius=float(values["vehicle.wheel_radius"]),
            damper_reference=values["vehicle.damper_reference"],
        )
    return QuarterCarVehicle(
        **float_fields(
            values,
            "vehicle",
            (
                "sprung_mass",
                "unsprung_mass",
                "suspension_stiffness",
                "suspension_damping",
                "tire_stiffness",
                "wheel_radius",
            ),
        )
    )


def make_road(name: str, seed: int, band: tuple[float, float]) -> RoadProfile:
    if name == "flat":
        return flat_profile()
    if name == "meadow_c":
        return meadow_c_standin(seed, band=band)
    return iso8608_profile(name, seed, band=band)


def make_scenario(values: Mapping[str, ParamValue]) -> Scenario:
    """The plant's scenario from parameter values (clear errors for bad soil paths)."""
    soils = list(values["scenario.soils"])
    starts = [float(s) for s in values["scenario.soil_starts"]]
    if len(soils) != len(starts) or not soils:
        raise ValueError(
            f"scenario.soils ({len(soils)} entries) and scenario.soil_starts ({len(starts)}) must have the same, "
            "non-zero length"
        )
    try:
        path = SoilPath([(start, soil_by_name(str(name))) for start, name in zip(starts, soils, strict=True)])
    except KeyError as exc:
        raise ValueError(f"scenario.soils: unknown soil {exc}; known: {', '.join(SOILS)}") from None
    band = (float(values["scenario.road_band_min"]), float(values["scenario.road_band_max"]))
    if band[0] >= band[1]:
        raise ValueError(f"scenario.road_band_min {band[0]} must be below scenario.road_band_max {band[1]}")
    return Scenario(
        profile=make_road(str(values["scenario.road"]), int(values["scenario.road_seed"]), band),
        soil_path=path,
        speed=SpeedProfile.constant(float(values["scenario.speed"])),
        sensor_rate=float(values["sensors.rate"]),
        profile_rate=float(values["sensors.profile_rate"]),
        accel_noise_variance=float(values["sensors.accel_noise_variance"]),
        profile_noise_std=float(values["sensors.profile_noise_std"]),
        wheel_liftoff=bool(values["scenario.wheel_liftoff"]),
        effects=make_effects(values),
    )


class QuarterCarSimAdapter(SimAdapter):
    """Steps a :class:`QuarterCarSimulator` and builds the contract's messages."""

    def __init__(self, kind: str, values: Mapping[str, ParamValue], namespace: str) -> None:
        self.kind = kind
        self.vehicle = make_vehicle(kind, values)
        self.scenario = make_scenario(values)
        self.simulator = QuarterCarSimulator(self.vehicle, self.scenario, int(values["seed"]))
        self.period = self.scenario.sensor_period
        self.frames = {
            key: namespaced_frame(namespace, str(values[f"frames.{key}"]))
            for key in ("body_imu", "wheel_imu", "odom", "base_link")
        }
        self.accel_variance = float(values["sensors.accel_noise_variance"])
        outputs = [TopicSpec("imu_body", "imu/body", Imu, "sensor")]
        if self.vehicle.has_wheel_accelerometer:
            outputs.append(TopicSpec("imu_wheel", "imu/wheel", Imu, "sensor"))
        outputs += [
            TopicSpec("joint_states", "joint_states", JointState, "sensor"),
            TopicSpec("profile", "terrain/profile", PointStamped, "sensor"),
            TopicSpec("truth", "ground_truth/soil_stiffness", SoilStiffness, "estimate"),
        ]
        self.outputs: Sequence[TopicSpec] = tuple(outputs)

    def _imu(self, t: float, frame: str, specific_force_z: float) -> Imu:
        msg = Imu()
        msg.header.stamp = sec_to_stamp(t)
        msg.header.frame_id = frame
        msg.orientation_covariance[0] = -1.0  # not measured (REP 145 / sensor_msgs/Imu)
        msg.angular_velocity_covariance[0] = -1.0
        msg.linear_acceleration.z = specific_force_z
        msg.linear_acceleration_covariance[8] = self.accel_variance
        return msg

    def messages(self, sample: QuarterCarSample) -> list[tuple[str, Any]]:
        """The messages of one sample, in publication order (profile first)."""
        out: list[tuple[str, Any]] = []
        for t, s, h in zip(sample.profile.t, sample.profile.distance, sample.profile.elevation, strict=True):
            point = PointStamped()
            point.header.stamp = sec_to_stamp(float(t))
            point.header.frame_id = self.frames["odom"]
            point.point.x = float(s)
            point.point.z = float(h)
            out.append(("profile", point))
        out.append(("imu_body", self._imu(sample.t, self.frames["body_imu"], sample.body_accel_z)))
        if sample.wheel_accel_z is not None:
            out.append(("imu_wheel", self._imu(sample.t, self.frames["wheel_imu"], sample.wheel_accel_z)))
        joints = JointState(name=["wheel"], position=[sample.wheel_angle], velocity=[sample.wheel_rate])
        joints.header.stamp = sec_to_stamp(sample.t)
        joints.header.frame_id = self.frames["base_link"]
        out.append(("joint_states", joints))
        truth = SoilStiffness(
            k_s=sample.truth.k_s,
            k_tot=sample.truth.k_tot,
            terrain_class=sample.truth.soil_name,
            class_confidence=1.0,
            converged=True,
        )
        truth.header.stamp = sec_to_stamp(sample.t)
        truth.header.frame_id = self.frames["base_link"]
        out.append(("truth", truth))
        return out


def specs_for(kind: str) -> tuple[ParamSpec, ...]:
    """Simulator specs of ``kind``: the estimator's vehicle parameters (one
    config file serves both) plus the scenario's."""
    if kind == "lrv":
        return VEHICLE_SPECS_LRV + SCENARIO_SPECS
    return VEHICLE_SPECS_QUARTER_CAR + _SCENARIO_HEAD + EFFECT_SPECS_COMMON + EFFECT_SPECS_TWO_DOF + _SENSOR_SPECS


PARAMETERS = specs_for("quarter_car")


def make_adapter(values: Mapping[str, ParamValue], namespace: str, kind: str = "quarter_car") -> QuarterCarSimAdapter:
    return QuarterCarSimAdapter(kind, values, namespace)
