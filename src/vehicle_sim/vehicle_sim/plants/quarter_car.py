"""Truth plant for soil-stiffness estimation: 2-DOF quarter car and 1-DOF LRV.

Reina, Leanza, Messina, *Terrain estimation via vehicle vibration measurement
and Cubature Kalman Filtering* (MODELS.md A.1, A.7, A.9). The soil is an
equivalent spring k_s in series with the tire (eq. 3); the plant is integrated
in continuous time and sampled by the sensors the estimator uses.

Truth integration
    Classical fixed-step RK4 with step ≤ 1 ms by default (sensor period / an
    integer number of sub-steps). The road h(s(t)) and its rate are evaluated
    exactly at every RK4 stage (t, t + Δt/2, t + Δt); s(t) is the exact
    integral of the speed profile. This is deliberately *not* the filter's own
    10 ms / 4th-order-Taylor discretisation (DESIGN.md: a filter tested against
    its own model proves nothing; MODELS.md A.10: the road between filter steps
    decides the k_s error).

Coordinates
    y1 (body) and y2 (wheel) are vertical displacements (m, up positive) from
    static equilibrium on a level road at h = 0, so gravity cancels in the
    equations of motion (eq. 2). Accelerometers report specific force along
    +z (REP 145): ÿ + g, i.e. +g at rest.

2-DOF quarter car (eq. 2)::

    m_s  ÿ1 = k(y2 − y1) + c(ẏ2 − ẏ1)
    m_ns ÿ2 = −k(y2 − y1) − c(ẏ2 − ẏ1) + F_d,     F_d = k_tot (h − y2)

1-DOF LRV (section 5.3, MODELS.md A.7)::

    m ÿ1 = F_d,   F_d = k_tot (h − y1) + c (ḣ − ẏ1)        (damper_reference="ground")
    m ÿ1 = k_tot (h − y1) − c ẏ1                          (damper_reference="inertial")

  k_tot = k k_s / (k + k_s), k the combined suspension/tire stiffness. The
  physical default puts the damper between body and ground, c(ẏ1 − ḣ); the
  paper's literal reduction of the 2-DOF matrices puts it on the absolute body
  velocity and is kept as an option for comparisons. The damper acts across the
  whole series chain (soil included): a massless simplification that avoids the
  extra internal state a damper across k only would need.

Contact
    The total normal ground force is F = W + F_d, W the static load
    (total mass × g). With ``wheel_liftoff`` the contact is unilateral:
    F = max(0, W + F_d) — the wheel leaves the ground when the dynamic force
    would pull (MODELS.md A.10 item 5: 7–9 % of the time at ISO F, 10 m/s).
    Without it (the paper's linear model) F may go negative.

Soil changes
    The soil under the tire is looked up at every RK4 stage from the distance
    travelled. Coordinates stay deviations from the *current* soil's static
    equilibrium, as in the paper: a change of soil changes k_tot, not the
    equilibrium height (the extra static sinkage of a softer soil is not
    modelled).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vehicle_sim.terrain.profiles import FlatProfile, RoadProfile
from vehicle_sim.terrain.soils import GRANEVILLE_LOAM, SoilPath, k_tot

__all__ = [
    "STANDARD_GRAVITY",
    "LRVVehicle",
    "ProfileReadings",
    "QuarterCarSample",
    "QuarterCarSimulator",
    "QuarterCarTruth",
    "QuarterCarVehicle",
    "Scenario",
    "SimulationResult",
    "SpeedProfile",
    "simulate",
]

STANDARD_GRAVITY = 9.80665
"""Standard gravity (m/s²)."""


# ---------------------------------------------------------------------------
# Vehicles
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class QuarterCarVehicle:
    """2-DOF quarter car of the paper's Table 2 (reference off-road vehicle).

    Attributes:
        sprung_mass: m_s (kg).
        unsprung_mass: m_ns (kg).
        suspension_stiffness: k (N/m).
        suspension_damping: c (N·s/m).
        tire_stiffness: k_t (N/m); the soil is in series with it.
        wheel_radius: Rolling radius (m) converting speed to wheel rate;
            default D/2 of Table 1's wheel (D = 0.777 m).
    """

    sprung_mass: float = 455.0
    unsprung_mass: float = 45.5
    suspension_stiffness: float = 25.0e3
    suspension_damping: float = 2.0e3
    tire_stiffness: float = 175.0e3
    wheel_radius: float = 0.3885

    def __post_init__(self) -> None:
        for name in ("sprung_mass", "unsprung_mass", "suspension_stiffness", "tire_stiffness"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.suspension_damping >= 0.0:
            raise ValueError(f"suspension_damping must be ≥ 0, got {self.suspension_damping}")
        if not self.wheel_radius > 0.0:
            raise ValueError(f"wheel_radius must be > 0 m, got {self.wheel_radius}")

    @property
    def series_stiffness(self) -> float:
        """Stiffness in series with the soil (N/m): the tire stiffness k_t."""
        return self.tire_stiffness

    @property
    def total_mass(self) -> float:
        """m_s + m_ns (kg), carried by the ground at rest."""
        return self.sprung_mass + self.unsprung_mass

    @property
    def has_wheel_accelerometer(self) -> bool:
        """True: the 2-DOF car carries an accelerometer on the unsprung mass."""
        return True

    def k_tot(self, k_s: float) -> float:
        """Soil in series with the tire (eq. 3), N/m."""
        return float(k_tot(k_s, self.tire_stiffness))

    def undamped_natural_frequencies(self, k_s: float) -> tuple[float, float]:
        """Closed-form undamped natural frequencies (Hz), (body, wheel hop).

        Roots of m_s m_ns ω⁴ − (m_s (k + k_tot) + m_ns k) ω² + k k_tot = 0. The
        "body ≈ 1.18 Hz" of MODELS.md A.1 is the uncoupled √(k/m_s)/2π; the
        coupled body mode is 1.05–1.10 Hz on Table 1's soils.

        Args:
            k_s: Soil stiffness (N/m).

        Returns:
            (f_body, f_wheel) in Hz, f_body < f_wheel.
        """
        m1, m2, k = self.sprung_mass, self.unsprung_mass, self.suspension_stiffness
        kt = self.k_tot(k_s)
        a = m1 * m2
        b = m1 * (k + kt) + m2 * k
        disc = math.sqrt(b * b - 4.0 * a * k * kt)
        w_low = math.sqrt((b - disc) / (2.0 * a))
        w_high = math.sqrt((b + disc) / (2.0 * a))
        return w_low / (2.0 * math.pi), w_high / (2.0 * math.pi)

    def state_matrix(self, k_s: float) -> NDArray[np.float64]:
        """Continuous-time state matrix for x = [y1, ẏ1, y2, ẏ2] on a level road (4×4)."""
        m1, m2 = self.sprung_mass, self.unsprung_mass
        k, c, kt = self.suspension_stiffness, self.suspension_damping, self.k_tot(k_s)
        return np.array(
            [
                [0.0, 1.0, 0.0, 0.0],
                [-k / m1, -c / m1, k / m1, c / m1],
                [0.0, 0.0, 0.0, 1.0],
                [k / m2, c / m2, -(k + kt) / m2, -c / m2],
            ]
        )


@dataclass(frozen=True)
class LRVVehicle:
    """1-DOF Lunar Roving Vehicle corner of the paper's Table 5.

    Suspension and tire stiffness are combined in k and sprung and unsprung
    masses lumped in m (section 5.3).

    Attributes:
        sprung_mass: Lumped mass m (kg); 75 kg gives the paper's Earth load
            W = 735 N.
        combined_stiffness: k (N/m), suspension and tire in series; the soil is
            in series with it.
        damping: c (N·s/m).
        wheel_radius: Rolling radius (m); LRV wheel D = 1.016 m.
        damper_reference: ``"ground"`` (physical, default): damper force
            c(ḣ − ẏ1) between body and ground; ``"inertial"``: −c ẏ1, the
            paper's literal reduction of the 2-DOF matrices (MODELS.md A.7).
    """

    sprung_mass: float = 75.0
    combined_stiffness: float = 15.0e3
    damping: float = 1.5e3
    wheel_radius: float = 0.508
    damper_reference: Literal["ground", "inertial"] = "ground"

    def __post_init__(self) -> None:
        for name in ("sprung_mass", "combined_stiffness", "wheel_radius"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.damping >= 0.0:
            raise ValueError(f"damping must be ≥ 0, got {self.damping}")
        if self.damper_reference not in ("ground", "inertial"):
            raise ValueError(f"damper_reference must be 'ground' or 'inertial', got {self.damper_reference!r}")

    @property
    def series_stiffness(self) -> float:
        """Stiffness in series with the soil (N/m): the combined stiffness k."""
        return self.combined_stiffness

    @property
    def total_mass(self) -> float:
        """m (kg), carried by the ground at rest."""
        return self.sprung_mass

    @property
    def has_wheel_accelerometer(self) -> bool:
        """False: the LRV model has no unsprung mass, hence no wheel accelerometer."""
        return False

    def k_tot(self, k_s: float) -> float:
        """Soil in series with the combined stiffness, N/m (9.826 kN/m on regolith)."""
        return float(k_tot(k_s, self.combined_stiffness))

    def undamped_natural_frequency(self, k_s: float) -> float:
        """√(k_tot/m)/2π (Hz): ≈ 1.82 Hz on regolith."""
        return math.sqrt(self.k_tot(k_s) / self.sprung_mass) / (2.0 * math.pi)


Vehicle = QuarterCarVehicle | LRVVehicle


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

    def speed(self, t: ArrayLike) -> NDArray[np.float64]:
        """v(t) (m/s); shape of ``t`` (s)."""
        t_arr = np.asarray(t, dtype=float)
        idx = self._segment(t_arr)
        dt = t_arr - np.asarray(self.times)[idx]
        return np.asarray(self.speeds)[idx] + np.asarray(self._accel)[idx] * dt

    def distance(self, t: ArrayLike) -> NDArray[np.float64]:
        """Distance travelled s(t) = ∫0^t v dt' (m), exact; shape of ``t`` (s)."""
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
class Scenario:
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
        wheel_liftoff: Unilateral contact (the wheel may leave the ground).
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

    def __post_init__(self) -> None:
        if not isinstance(self.soil_path, SoilPath):
            object.__setattr__(self, "soil_path", SoilPath(self.soil_path))
        if not isinstance(self.speed, SpeedProfile):
            object.__setattr__(self, "speed", SpeedProfile.constant(float(self.speed)))
        for name in ("sensor_rate", "profile_rate", "integration_step"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.accel_noise_variance >= 0.0:
            raise ValueError(f"accel_noise_variance must be ≥ 0, got {self.accel_noise_variance}")
        if not self.profile_noise_std >= 0.0:
            raise ValueError(f"profile_noise_std must be ≥ 0, got {self.profile_noise_std}")
        if not self.gravity >= 0.0:
            raise ValueError(f"gravity must be ≥ 0, got {self.gravity}")

    @property
    def sensor_period(self) -> float:
        """1 / sensor_rate (s)."""
        return 1.0 / self.sensor_rate

    @property
    def substeps(self) -> int:
        """RK4 steps per sensor period."""
        return max(1, math.ceil(self.sensor_period / self.integration_step - 1e-9))


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
        road_elevation: h at the tire (m), noise-free.
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


# ---------------------------------------------------------------------------
# Equations of motion (scalar code: a few floats per stage, called ~10⁴ times/s)
# ---------------------------------------------------------------------------


def _advance_two_dof(
    state: tuple[float, float, float, float],
    road: list[float],
    stiffness: list[float],
    substeps: int,
    dt: float,
    vehicle: QuarterCarVehicle,
    static_load: float,
    liftoff: bool,
) -> tuple[float, float, float, float]:
    """RK4 over ``substeps`` steps of eq. 2; road and k_tot given at every half step."""
    m1, m2 = vehicle.sprung_mass, vehicle.unsprung_mass
    k, c = vehicle.suspension_stiffness, vehicle.suspension_damping
    floor = -static_load

    def accelerations(y1: float, v1: float, y2: float, v2: float, h: float, kt: float):
        suspension = k * (y2 - y1) + c * (v2 - v1)
        ground = kt * (h - y2)
        if liftoff and ground < floor:
            ground = floor
        return suspension / m1, (ground - suspension) / m2

    y1, v1, y2, v2 = state
    half, sixth = 0.5 * dt, dt / 6.0
    for i in range(substeps):
        j = 2 * i
        a1, b1 = accelerations(y1, v1, y2, v2, road[j], stiffness[j])
        p1, q1 = v1 + half * a1, v2 + half * b1
        h_mid, kt_mid = road[j + 1], stiffness[j + 1]
        a2, b2 = accelerations(y1 + half * v1, p1, y2 + half * v2, q1, h_mid, kt_mid)
        p2, q2 = v1 + half * a2, v2 + half * b2
        a3, b3 = accelerations(y1 + half * p1, p2, y2 + half * q1, q2, h_mid, kt_mid)
        p3, q3 = v1 + dt * a3, v2 + dt * b3
        a4, b4 = accelerations(y1 + dt * p2, p3, y2 + dt * q2, q3, road[j + 2], stiffness[j + 2])
        y1 += sixth * (v1 + 2.0 * p1 + 2.0 * p2 + p3)
        y2 += sixth * (v2 + 2.0 * q1 + 2.0 * q2 + q3)
        v1 += sixth * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        v2 += sixth * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
    return y1, v1, y2, v2


def _lrv_ground_force(
    y1: float, v1: float, h: float, h_rate: float, kt: float, vehicle: LRVVehicle
) -> tuple[float, float]:
    """(dynamic ground force F_d, damper force acting on the body from outside the contact)."""
    if vehicle.damper_reference == "ground":
        return kt * (h - y1) + vehicle.damping * (h_rate - v1), 0.0
    return kt * (h - y1), -vehicle.damping * v1


def _advance_lrv(
    state: tuple[float, float],
    road: list[float],
    road_rate: list[float],
    stiffness: list[float],
    substeps: int,
    dt: float,
    vehicle: LRVVehicle,
    static_load: float,
    liftoff: bool,
) -> tuple[float, float]:
    """RK4 over ``substeps`` steps of the 1-DOF LRV (MODELS.md A.7)."""
    m = vehicle.sprung_mass
    floor = -static_load

    def acceleration(y1: float, v1: float, j: int) -> float:
        ground, skyhook = _lrv_ground_force(y1, v1, road[j], road_rate[j], stiffness[j], vehicle)
        if liftoff and ground < floor:
            ground = floor
        return (ground + skyhook) / m

    y1, v1 = state
    half, sixth = 0.5 * dt, dt / 6.0
    for i in range(substeps):
        j = 2 * i
        a1 = acceleration(y1, v1, j)
        p1 = v1 + half * a1
        a2 = acceleration(y1 + half * v1, p1, j + 1)
        p2 = v1 + half * a2
        a3 = acceleration(y1 + half * p1, p2, j + 1)
        p3 = v1 + dt * a3
        a4 = acceleration(y1 + dt * p2, p3, j + 2)
        y1 += sixth * (v1 + 2.0 * p1 + 2.0 * p2 + p3)
        v1 += sixth * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return y1, v1


# ---------------------------------------------------------------------------
# Simulator
# ---------------------------------------------------------------------------


class QuarterCarSimulator:
    """Stepping truth simulator for the quarter car or the LRV.

    Each :meth:`step` advances one sensor period (``scenario.sensor_period``,
    10 ms by default) with RK4 sub-steps and returns a :class:`QuarterCarSample`.

    Args:
        vehicle: :class:`QuarterCarVehicle` (2-DOF) or :class:`LRVVehicle` (1-DOF).
        scenario: Road, soil, speed, sensors.
        seed: Seed of the sensor noise (accelerometers and profile sampler use
            independent streams spawned from it).
        initial_state: [y1, ẏ1, y2, ẏ2] (2-DOF) or [y1, ẏ1] (LRV) in m and m/s;
            default: at rest at the road height under the wheel at t = 0.
    """

    def __init__(
        self,
        vehicle: Vehicle,
        scenario: Scenario,
        seed: int,
        initial_state: Sequence[float] | None = None,
    ) -> None:
        if not isinstance(vehicle, QuarterCarVehicle | LRVVehicle):
            raise TypeError(f"vehicle must be QuarterCarVehicle or LRVVehicle, got {vehicle!r}")
        self.vehicle = vehicle
        self.scenario = scenario
        self.seed = seed
        self._two_dof = isinstance(vehicle, QuarterCarVehicle)
        self._period = scenario.sensor_period
        self._substeps = scenario.substeps
        self._dt = self._period / self._substeps
        self._stage_offsets = 0.5 * self._dt * np.arange(2 * self._substeps + 1)
        accel_seed, profile_seed = np.random.SeedSequence(seed).spawn(2)
        self._accel_rng = np.random.default_rng(accel_seed)
        self._profile_rng = np.random.default_rng(profile_seed)
        self._accel_std = math.sqrt(scenario.accel_noise_variance)
        self._static_load = vehicle.total_mass * scenario.gravity
        self._k_tot_by_segment = [vehicle.k_tot(soil.k_s) for soil in scenario.soil_path.soils]
        self._step_index = 0
        self._next_profile_index = 0
        n_states = 4 if self._two_dof else 2
        if initial_state is None:
            h0 = float(scenario.profile.elevation(np.array([0.0]))[0])
            state: tuple[float, ...] = (h0, 0.0, h0, 0.0) if self._two_dof else (h0, 0.0)
        else:
            state = tuple(float(x) for x in initial_state)
            if len(state) != n_states:
                raise ValueError(f"initial_state needs {n_states} values, got {len(state)}")
        self._state: tuple[float, ...] = state

    @property
    def t(self) -> float:
        """Current simulation time (s)."""
        return self._step_index * self._period

    @property
    def step_index(self) -> int:
        """Number of sensor periods simulated so far."""
        return self._step_index

    @property
    def state(self) -> tuple[float, ...]:
        """Current [y1, ẏ1, y2, ẏ2] (2-DOF) or [y1, ẏ1] (LRV), m and m/s."""
        return self._state

    @property
    def integration_step(self) -> float:
        """RK4 step actually used (s)."""
        return self._dt

    def step(self) -> QuarterCarSample:
        """Advance one sensor period and report the sensors and the truth at its end.

        Returns:
            The sample at t = (step_index + 1) · period. Its profile readings are
            those with times in (t − period, t]; the first call also delivers the
            reading at t = 0, so successive calls hand over every reading once.
        """
        scenario = self.scenario
        speed_profile = scenario.speed
        t0 = self._step_index * self._period
        t1 = (self._step_index + 1) * self._period
        constant_speed = speed_profile.is_constant_on(t0, t1)

        if constant_speed:
            v = float(speed_profile.speed(t0))
            s0 = float(speed_profile.distance(t0))
            stage_spacing = v * 0.5 * self._dt
            stage_distance = np.asarray(s0 + stage_spacing * np.arange(self._stage_offsets.size), dtype=np.float64)
            road, slope = scenario.profile.evaluate_uniform(s0, stage_spacing, self._stage_offsets.size)
            road_rate = v * slope
        else:
            stage_times = t0 + self._stage_offsets
            stage_distance = speed_profile.distance(stage_times)
            road, slope = scenario.profile.elevation_and_slope(stage_distance)
            road_rate = speed_profile.speed(stage_times) * slope

        soil_index = scenario.soil_path.index_at(stage_distance)
        stiffness = [self._k_tot_by_segment[i] for i in soil_index.tolist()]
        road_list = road.tolist()
        liftoff = scenario.wheel_liftoff
        if self._two_dof:
            self._state = _advance_two_dof(
                self._state,  # type: ignore[arg-type]
                road_list,
                stiffness,
                self._substeps,
                self._dt,
                self.vehicle,  # type: ignore[arg-type]
                self._static_load,
                liftoff,
            )
        else:
            self._state = _advance_lrv(
                self._state,  # type: ignore[arg-type]
                road_list,
                road_rate.tolist(),
                stiffness,
                self._substeps,
                self._dt,
                self.vehicle,  # type: ignore[arg-type]
                self._static_load,
                liftoff,
            )
        self._step_index += 1

        distance = float(stage_distance[-1])
        speed = float(speed_profile.speed(t1))
        truth = self._truth(float(road[-1]), float(road_rate[-1]), stiffness[-1], int(soil_index[-1]))
        noise = self._accel_rng.standard_normal(2) * self._accel_std
        g = scenario.gravity
        body_accel = float(truth.body_acceleration) + g + float(noise[0])
        wheel_accel = (
            float(truth.wheel_acceleration) + g + float(noise[1])  # type: ignore[arg-type]
            if self._two_dof
            else None
        )
        radius = self.vehicle.wheel_radius
        return QuarterCarSample(
            t=t1,
            body_accel_z=body_accel,
            wheel_accel_z=wheel_accel,
            distance=distance,
            wheel_angle=distance / radius,
            wheel_rate=speed / radius,
            speed=speed,
            profile=self._profile_readings(t0, t1, constant_speed, stage_distance, road),
            truth=truth,
        )

    def _truth(self, h: float, h_rate: float, kt: float, segment: int) -> QuarterCarTruth:
        soil = self.scenario.soil_path.soils[segment]
        load = self._static_load
        liftoff = self.scenario.wheel_liftoff
        if self._two_dof:
            vehicle: QuarterCarVehicle = self.vehicle  # type: ignore[assignment]
            y1, v1, y2, v2 = self._state
            suspension = vehicle.suspension_stiffness * (y2 - y1) + vehicle.suspension_damping * (v2 - v1)
            dynamic = kt * (h - y2)
            in_contact = load + dynamic > 0.0
            if liftoff and not in_contact:
                dynamic = -load
            a1 = suspension / vehicle.sprung_mass
            a2 = (dynamic - suspension) / vehicle.unsprung_mass
            wheel: tuple[float | None, float | None, float | None] = (y2, v2, a2)
        else:
            lrv: LRVVehicle = self.vehicle  # type: ignore[assignment]
            y1, v1 = self._state
            dynamic, skyhook = _lrv_ground_force(y1, v1, h, h_rate, kt, lrv)
            in_contact = load + dynamic > 0.0
            if liftoff and not in_contact:
                dynamic = -load
            a1 = (dynamic + skyhook) / lrv.sprung_mass
            wheel = (None, None, None)
        return QuarterCarTruth(
            soil_name=soil.name,
            k_s=soil.k_s,
            k_tot=kt,
            body_displacement=y1,
            body_velocity=v1,
            body_acceleration=a1,
            wheel_displacement=wheel[0],
            wheel_velocity=wheel[1],
            wheel_acceleration=wheel[2],
            road_elevation=h,
            road_rate=h_rate,
            contact_force=load + dynamic,
            in_contact=bool(in_contact),
        )

    def _profile_readings(
        self,
        t0: float,
        t1: float,
        constant_speed: bool,
        stage_distance: NDArray[np.float64],
        stage_road: NDArray[np.float64],
    ) -> ProfileReadings:
        scenario = self.scenario
        rate = scenario.profile_rate
        first = self._next_profile_index
        last = math.floor(t1 * rate + 1e-9)
        self._next_profile_index = max(first, last + 1)
        indices = np.arange(first, last + 1)
        times = indices / rate
        if indices.size == 0:
            empty = np.empty(0)
            return ProfileReadings(empty, empty.copy(), empty.copy())
        # Readings that fall on RK4 stage times (1 kHz with 1 ms steps) reuse the
        # stage road, which is the same exact h(s) at the same s.
        stage = (times - t0) / (0.5 * self._dt)
        stage_index = np.rint(stage).astype(int)
        if np.all(np.abs(stage - stage_index) < 1e-6):
            distance = stage_distance[stage_index]
            elevation = stage_road[stage_index]
        else:
            distance = scenario.speed.distance(times)
            if constant_speed:
                spacing = float(scenario.speed.speed(t0)) / rate
                elevation, _ = scenario.profile.evaluate_uniform(float(distance[0]), spacing, indices.size)
            else:
                elevation = scenario.profile.elevation(distance)
        if scenario.profile_noise_std > 0.0:
            elevation = elevation + scenario.profile_noise_std * self._profile_rng.standard_normal(indices.size)
        return ProfileReadings(times, distance, elevation)


def simulate(
    vehicle: Vehicle,
    scenario: Scenario,
    duration: float,
    seed: int,
    initial_state: Sequence[float] | None = None,
) -> SimulationResult:
    """Run a :class:`QuarterCarSimulator` for ``duration`` seconds and stack the samples.

    Args:
        vehicle: The vehicle.
        scenario: The scenario.
        duration: Simulated time (s); rounded to a whole number of sensor periods.
        seed: Sensor-noise seed.
        initial_state: As for :class:`QuarterCarSimulator`.

    Returns:
        The stacked result: N = round(duration × sensor_rate) samples at
        t = period … duration, profile readings over [0, duration].
    """
    n_samples = int(round(duration * scenario.sensor_rate))
    if n_samples < 1:
        raise ValueError(f"duration {duration} s is shorter than one sensor period")
    simulator = QuarterCarSimulator(vehicle, scenario, seed, initial_state)
    samples = [simulator.step() for _ in range(n_samples)]

    def stack(getter) -> NDArray:
        return np.array([getter(sample) for sample in samples])

    two_dof = vehicle.has_wheel_accelerometer
    truths = [sample.truth for sample in samples]

    def truth_array(name: str) -> NDArray | None:
        values = [getattr(truth, name) for truth in truths]
        return None if values[0] is None else np.array(values)

    # The per-sample truth fields stacked into arrays (the dataclass allows both).
    truth = QuarterCarTruth(**{name: truth_array(name) for name in QuarterCarTruth.__dataclass_fields__})  # type: ignore[arg-type]
    return SimulationResult(
        vehicle=vehicle,
        scenario=scenario,
        seed=seed,
        t=stack(lambda s: s.t),
        body_accel_z=stack(lambda s: s.body_accel_z),
        wheel_accel_z=stack(lambda s: s.wheel_accel_z) if two_dof else None,
        distance=stack(lambda s: s.distance),
        wheel_angle=stack(lambda s: s.wheel_angle),
        wheel_rate=stack(lambda s: s.wheel_rate),
        speed=stack(lambda s: s.speed),
        profile=ProfileReadings(
            t=np.concatenate([s.profile.t for s in samples]),
            distance=np.concatenate([s.profile.distance for s in samples]),
            elevation=np.concatenate([s.profile.elevation for s in samples]),
        ),
        truth=truth,
    )
