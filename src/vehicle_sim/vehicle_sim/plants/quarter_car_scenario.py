"""What the soil-stiffness plant drives over and how it is sensed (:class:`Scenario`), and what a run reports.

The plant: :mod:`vehicle_sim.plants.quarter_car`.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from terrain_estimation.checks import check_fields
from vehicle_sim.plants.quarter_car_effects import QuarterCarEffects
from vehicle_sim.plants.quarter_car_vehicles import STANDARD_GRAVITY, Vehicle
from vehicle_sim.plants.stepping import SensorTiming
from vehicle_sim.terrain.profiles import FlatProfile, RoadProfile
from vehicle_sim.terrain.soils import GRANEVILLE_LOAM, SoilPath

__all__ = [
    "ProfileReadings",
    "QuarterCarSample",
    "QuarterCarTruth",
    "Scenario",
    "SimulationResult",
    "SpeedProfile",
]

# ---------------------------------------------------------------------------
# Scenario
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class SpeedProfile:
    """Travel speed v(t) ≥ 0, piecewise linear in time, held after the last knot.

    Attributes:
        times: Knot times (s), strictly increasing, starting at 0.
        speeds: Speeds at the knots (m/s), ≥ 0.
    """

    times: tuple[float, ...] = (0.0,)
    speeds: tuple[float, ...] = (10.0,)
    _accel: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _cumulative: tuple[float, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        times = tuple(float(t) for t in self.times)
        speeds = tuple(float(v) for v in self.speeds)
        if len(times) != len(speeds) or not times:
            raise ValueError("a speed profile needs equally many (≥ 1) times and speeds")
        if times[0] != 0.0:
            raise ValueError(f"the first knot must be at t = 0 s, got {times[0]}")
        if any(b <= a for a, b in zip(times, times[1:], strict=False)):
            raise ValueError(f"knot times must increase strictly, got {times}")
        if any(not (v >= 0.0 and math.isfinite(v)) for v in speeds):
            raise ValueError(f"speeds must be finite and ≥ 0 m/s, got {speeds}")
        accel = [(speeds[i + 1] - speeds[i]) / (times[i + 1] - times[i]) for i in range(len(times) - 1)] + [0.0]
        cumulative = [0.0]
        for i in range(len(times) - 1):
            dt = times[i + 1] - times[i]
            cumulative.append(cumulative[-1] + 0.5 * (speeds[i] + speeds[i + 1]) * dt)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "speeds", speeds)
        object.__setattr__(self, "_accel", tuple(accel))
        object.__setattr__(self, "_cumulative", tuple(cumulative))

    @classmethod
    def constant(cls, speed: float) -> SpeedProfile:
        """Constant speed (m/s)."""
        return cls((0.0,), (float(speed),))

    @classmethod
    def piecewise_linear(cls, times: Sequence[float], speeds: Sequence[float]) -> SpeedProfile:
        """Linear interpolation between (time (s), speed (m/s)) knots."""
        return cls(tuple(times), tuple(speeds))

    def _segment(self, t: NDArray[np.float64]) -> NDArray[np.intp]:
        idx = np.searchsorted(self.times, t, side="right") - 1
        return np.clip(idx, 0, len(self.times) - 1)

    def _scalar_segment(self, t: float) -> int:
        """:meth:`_segment` of one time: the same knot (NaN, like numpy's sort order, after the last)."""
        return max(bisect.bisect_right(self.times, t) - 1, 0)

    def speed(self, t: ArrayLike) -> NDArray[np.float64]:
        """v(t) (m/s); shape of ``t`` (s)."""
        if isinstance(t, (float, int)) and not isinstance(t, bool):
            # One time (the plant asks three times a step): the array form's arithmetic on floats, without its
            # per-call conversions; a numpy float64 as the array form returns for a scalar.
            i = self._scalar_segment(float(t))
            return np.float64(self.speeds[i] + self._accel[i] * (float(t) - self.times[i]))
        t_arr = np.asarray(t, dtype=float)
        idx = self._segment(t_arr)
        dt = t_arr - np.asarray(self.times)[idx]
        return np.asarray(self.speeds)[idx] + np.asarray(self._accel)[idx] * dt

    def distance(self, t: ArrayLike) -> NDArray[np.float64]:
        """Distance travelled s(t) = ∫0^t v dt' (m), exact; shape of ``t`` (s)."""
        if isinstance(t, (float, int)) and not isinstance(t, bool):
            i = self._scalar_segment(float(t))
            dt = float(t) - self.times[i]
            return np.float64(self._cumulative[i] + self.speeds[i] * dt + 0.5 * self._accel[i] * dt * dt)
        t_arr = np.asarray(t, dtype=float)
        idx = self._segment(t_arr)
        dt = t_arr - np.asarray(self.times)[idx]
        return (
            np.asarray(self._cumulative)[idx]
            + np.asarray(self.speeds)[idx] * dt
            + 0.5 * np.asarray(self._accel)[idx] * dt * dt
        )

    def is_constant_on(self, t0: float, t1: float) -> bool:
        """True if v is constant on [t0, t1] (s)."""
        if len(self.times) == 1:
            return True
        inside = [v for t, v in zip(self.times, self.speeds, strict=True) if t0 < t < t1]
        v0, v1 = float(self.speed(t0)), float(self.speed(t1))
        return v0 == v1 and all(v == v0 for v in inside)


@dataclass(frozen=True)
class Scenario(SensorTiming):
    """What the vehicle drives over and how it is sensed.

    ``soil_path`` accepts a :class:`Soil`, a list of (start distance (m), Soil)
    or a :class:`SoilPath`; ``speed`` a number (m/s) or a :class:`SpeedProfile`.
    Both are normalised on construction.

    Attributes:
        profile: Road elevation h(s) (default: flat).
        soil_path: Soil along the distance travelled (default: Graneville loam).
        speed: Travel speed profile (default 10 m/s).
        sensor_rate: Accelerometer and joint-state rate (Hz); one
            :meth:`QuarterCarSimulator.step` per period.
        profile_rate: Profile sampler rate (Hz).
        integration_step: Largest RK4 step (s); the step used is the sensor
            period divided by the smallest integer that makes it ≤ this.
        accel_noise_variance: Accelerometer white-noise variance ((m/s²)²),
            0.5 as the paper's R.
        profile_noise_std: Profile sampler elevation noise σ_h (m).
        gravity: g (m/s²); sets the static load and the accelerometer offset.
        wheel_liftoff: Unilateral contact (the wheel may leave the ground);
            kept for backward compatibility, the same switch as
            ``effects.wheel_liftoff``: either one on switches both on.
        effects: Unmodelled effects switched on (default: none, the nominal
            plant; CONTRACT.md "Nominal model and effects").
    """

    profile: RoadProfile = field(default_factory=FlatProfile)
    soil_path: SoilPath = field(default_factory=lambda: SoilPath(GRANEVILLE_LOAM))
    speed: SpeedProfile = field(default_factory=lambda: SpeedProfile.constant(10.0))
    sensor_rate: float = 100.0
    profile_rate: float = 1000.0
    integration_step: float = 1.0e-3
    accel_noise_variance: float = 0.5
    profile_noise_std: float = 1.0e-4
    gravity: float = STANDARD_GRAVITY
    wheel_liftoff: bool = False
    effects: QuarterCarEffects = field(default_factory=QuarterCarEffects)

    def __post_init__(self) -> None:
        if not isinstance(self.effects, QuarterCarEffects):
            raise ValueError(f"effects must be a QuarterCarEffects, got {self.effects!r}")
        # One switch, two spellings: Scenario.wheel_liftoff predates the effects.
        if self.wheel_liftoff and not self.effects.wheel_liftoff:
            object.__setattr__(self, "effects", replace(self.effects, wheel_liftoff=True))
        object.__setattr__(self, "wheel_liftoff", bool(self.effects.wheel_liftoff))
        if not isinstance(self.soil_path, SoilPath):
            object.__setattr__(self, "soil_path", SoilPath(self.soil_path))
        if not isinstance(self.speed, SpeedProfile):
            object.__setattr__(self, "speed", SpeedProfile.constant(float(self.speed)))
        check_fields(self, ("sensor_rate", "profile_rate", "integration_step"))
        check_fields(self, ("accel_noise_variance", "profile_noise_std", "gravity"), rule="non_negative")


# ---------------------------------------------------------------------------
# Samples and results
# ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ProfileReadings:
    """Profile sampler readings: the elevation under the tire at its own rate.

    Attributes:
        t: Reading times (s), shape (M,).
        distance: Distance travelled at each reading (m), shape (M,).
        elevation: Measured elevation h + noise (m), shape (M,).
    """

    t: NDArray[np.float64]
    distance: NDArray[np.float64]
    elevation: NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class QuarterCarTruth:
    """What only the simulator knows. Scalars in a sample, arrays (N,) in a result.

    Attributes:
        soil_name: Soil under the tire (:attr:`Soil.name`).
        k_s: Soil stiffness (N/m).
        k_tot: Soil in series with the tire / combined spring (N/m).
        body_displacement: y1 (m).
        body_velocity: ẏ1 (m/s).
        body_acceleration: ÿ1 (m/s²), kinematic (no gravity, no noise).
        wheel_displacement: y2 (m); None for the LRV.
        wheel_velocity: ẏ2 (m/s); None for the LRV.
        wheel_acceleration: ÿ2 (m/s²); None for the LRV.
        road_elevation: h at the tire (m), noise-free; the true road, also
            with ``tire_contact_length`` (the tire then feels its average).
        road_rate: ḣ = v dh/ds (m/s).
        contact_force: Total normal ground force W + F_d (N); clipped at 0
            when lift-off is enabled, possibly negative otherwise.
        in_contact: W + F_d > 0 (the tire would push on the ground).
    """

    soil_name: str | NDArray[np.str_]
    k_s: float | NDArray[np.float64]
    k_tot: float | NDArray[np.float64]
    body_displacement: float | NDArray[np.float64]
    body_velocity: float | NDArray[np.float64]
    body_acceleration: float | NDArray[np.float64]
    wheel_displacement: float | NDArray[np.float64] | None
    wheel_velocity: float | NDArray[np.float64] | None
    wheel_acceleration: float | NDArray[np.float64] | None
    road_elevation: float | NDArray[np.float64]
    road_rate: float | NDArray[np.float64]
    contact_force: float | NDArray[np.float64]
    in_contact: bool | NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class QuarterCarSample:
    """Everything the sensors report for one sensor period, plus the truth.

    Attributes:
        t: Time at the end of the period (s).
        body_accel_z: Body accelerometer specific force along +z (m/s²),
            ÿ1 + g + noise (REP 145: +g at rest).
        wheel_accel_z: Wheel accelerometer, ÿ2 + g + noise (m/s²); None for
            the LRV.
        distance: Distance travelled s (m).
        wheel_angle: s / wheel radius (rad), unwrapped.
        wheel_rate: v / wheel radius (rad/s).
        speed: Travel speed v (m/s).
        profile: Profile readings taken in (t − period, t] (the first period
            also includes t = 0).
        truth: Plant state and soil at t.
    """

    t: float
    body_accel_z: float
    wheel_accel_z: float | None
    distance: float
    wheel_angle: float
    wheel_rate: float
    speed: float
    profile: ProfileReadings
    truth: QuarterCarTruth


@dataclass(frozen=True)
class SimulationResult:
    """Stacked samples of one run: arrays (N,) at the sensor rate, (M,) for the profile.

    Attributes:
        vehicle: The vehicle simulated.
        scenario: The scenario.
        seed: Sensor-noise seed.
        t: Sample times (s), (N,): period, 2·period, …, duration.
        body_accel_z: (N,) m/s², specific force (REP 145).
        wheel_accel_z: (N,) m/s², or None for the LRV.
        distance: (N,) m.
        wheel_angle: (N,) rad.
        wheel_rate: (N,) rad/s.
        speed: (N,) m/s.
        profile: Profile readings over [0, duration], arrays (M,).
        truth: Truth with arrays (N,).
    """

    vehicle: Vehicle
    scenario: Scenario
    seed: int
    t: NDArray[np.float64]
    body_accel_z: NDArray[np.float64]
    wheel_accel_z: NDArray[np.float64] | None
    distance: NDArray[np.float64]
    wheel_angle: NDArray[np.float64]
    wheel_rate: NDArray[np.float64]
    speed: NDArray[np.float64]
    profile: ProfileReadings
    truth: QuarterCarTruth
