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

Effects
    :class:`QuarterCarEffects` (``Scenario.effects``) switches on the
    unmodelled effects of the sim-to-real catalogue (CONTRACT.md "Nominal
    model and effects"; :data:`QUARTER_CAR_EFFECTS`): accelerometer bias,
    scale and delay, Bekker-type nonlinear soil, wheel lift-off, Coulomb
    suspension friction, tire damping, tire enveloping and a sprung-mass
    change. All off (the default) is the linear model above, bit for bit:
    the nominal path runs the same arithmetic as before the effects existed.

Soil changes
    The soil under the tire is looked up at every RK4 stage from the distance
    travelled. Coordinates stay deviations from the *current* soil's static
    equilibrium, as in the paper: a change of soil changes k_tot, not the
    equilibrium height (the extra static sinkage of a softer soil is not
    modelled).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vehicle_sim.terrain.profiles import FlatProfile, HarmonicProfile, RoadProfile
from vehicle_sim.terrain.soils import GRANEVILLE_LOAM, SoilPath, k_tot

__all__ = [
    "FRICTION_VELOCITY_SCALE",
    "LRV_IGNORED_EFFECTS",
    "QUARTER_CAR_EFFECTS",
    "STANDARD_GRAVITY",
    "QuarterCarEffects",
    "LRVVehicle",
    "ProfileReadings",
    "QuarterCarSample",
    "QuarterCarSimulator",
    "QuarterCarTruth",
    "QuarterCarVehicle",
    "Scenario",
    "SimulationResult",
    "SpeedProfile",
    "enveloped_profile",
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
# Effects (CONTRACT.md "Nominal model and effects")
# ---------------------------------------------------------------------------

FRICTION_VELOCITY_SCALE = 0.02
"""Velocity scale v_f (m/s) of the smoothed Coulomb suspension friction
F_f = F_c · tanh(Δv / v_f): 96 % of F_c at |Δv| = 2 v_f = 4 cm/s. Its slope
F_c / v_f acts as a viscous damper near Δv = 0; the simulator checks that
RK4 resolves it (see :class:`QuarterCarEffects`)."""

ENVELOPING_QUADRATURE_POINTS = 16
"""Gauss–Legendre points of the contact-patch average for profiles that are
not sums of harmonics (a :class:`HarmonicProfile` is averaged exactly)."""

QUARTER_CAR_EFFECTS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        "accel_bias": ("accel_bias_body", "accel_bias_wheel"),
        "accel_scale": ("accel_scale_body", "accel_scale_wheel"),
        "sensor_delay": ("sensor_delay", "sensor_delay_body", "sensor_delay_wheel", "sensor_delay_profile"),
        "nonlinear_soil": ("soil_exponent", "soil_origin_ratio"),
        "wheel_liftoff": ("wheel_liftoff",),
        "suspension_friction": ("suspension_friction",),
        "tire_damping": ("tire_damping",),
        "tire_enveloping": ("tire_contact_length",),
        "sprung_mass_change": ("sprung_mass_change",),
    }
)
"""Catalogue effect name (issue 6, quarter car / LRV) → :class:`QuarterCarEffects` fields."""

LRV_IGNORED_EFFECTS: tuple[str, ...] = (
    "accel_bias_wheel",
    "accel_scale_wheel",
    "sensor_delay_wheel",
    "suspension_friction",
    "tire_damping",
)
"""Fields that have no meaning for the 1-DOF LRV (no wheel accelerometer, no
separate suspension or tire): a simulator of the LRV rejects them when set."""


@dataclass(frozen=True, kw_only=True)
class QuarterCarEffects:
    """Unmodelled effects of the sim-to-real catalogue, each switchable, all off by default.

    The default instance (:meth:`nominal`) is the paper's linear model, bit for
    bit. Used by the 2-DOF :class:`QuarterCarVehicle` and the 1-DOF
    :class:`LRVVehicle`; the fields of :data:`LRV_IGNORED_EFFECTS` do not
    apply to the LRV and its simulator raises ValueError when they are set.
    :data:`QUARTER_CAR_EFFECTS` maps the catalogue names to the fields.

    Accelerometer model (body and wheel alike; d_c the stream's own latency)::

        reading(t) = (1 + accel_scale) · (ÿ + g)(t − sensor_delay − d_c) + accel_bias + noise(t)

    Each sensor stream has its own latency (a real latency sits on one
    driver, bus or filter, not on the whole vehicle): ``sensor_delay_body``,
    ``sensor_delay_wheel`` and ``sensor_delay_profile``; ``sensor_delay`` is
    a latency common to both accelerometers (kept for the ROS adapter's
    parameter). Only differences between streams are observable in a bag.

    Attributes:
        accel_bias_body: Constant bias of the body accelerometer (m/s²).
        accel_bias_wheel: Constant bias of the wheel accelerometer (m/s²); 2-DOF only.
        accel_scale_body: Scale-factor error s of the body accelerometer (–):
            the true specific force is multiplied by (1 + s); −1 < s < 1.
        accel_scale_wheel: Same for the wheel accelerometer (–); 2-DOF only.
        sensor_delay: Latency of the accelerometers relative to the profile
            sampler and the joint states (s), 0–1 s: a pure time shift of the
            continuous signal. The delayed value is interpolated linearly on
            the RK4 integration grid (1 ms by default), so a whole number of
            integration steps shifts exactly and any other delay is accurate
            to a fraction of a per cent up to ~50 Hz. Before the run has lasted
            the delay, the t = 0 value is repeated.
        sensor_delay_body: Extra latency of the body accelerometer alone (s),
            0–1 s, added to ``sensor_delay`` (same interpolation).
        sensor_delay_wheel: Extra latency of the wheel accelerometer alone (s),
            0–1 s; 2-DOF only.
        sensor_delay_profile: Latency of the profile sampler (s), 0–1 s: a
            reading taken at time τ (the road under the sensor at s(τ)) is
            held in a buffer and delivered, stamped τ + d, with the sensor
            period in which τ + d falls. The first d seconds of the run
            deliver no profile reading.
        soil_exponent: Bekker-type pressure–sinkage exponent n (–). The soil
            force is F = k_s z₀ (z/z₀)ⁿ, z the total soil sinkage and
            z₀ = W/k_s the static one (W the static load), in series with the
            tire (or the LRV's combined spring): the static equilibrium is
            unchanged and the stiffness at z₀ is n·k_s (n = 1: the linear soil
            exactly). n < 1 softens, n > 1 stiffens under extra load. 0 or 1:
            off (linear soil); otherwise 0.2 ≤ n ≤ 3. For z < 0 the law is
            continued as an odd function (the soil pulls, like the paper's
            linear spring) unless ``wheel_liftoff`` is on.
        soil_origin_ratio: ζ (–), the second shape parameter of the
            nonlinear soil: the power law's origin lies ζ z₀ below the static
            point instead of z₀ (a pre-consolidated or crusted soil, a rut
            reloaded by earlier passes: the pressure–sinkage curve through
            the operating point does not start at the static sinkage).
            With δ the soil's compression beyond static::

                F(δ) = W + W ζ [σ(1 + δ/(ζ z₀))ⁿ − 1]

            so the stiffness at the static point stays n·k_s for every ζ,
            the curvature is n(n − 1) k_s / (ζ z₀): small ζ makes the same
            n strongly nonlinear about the operating point, large ζ nearly
            linear. ζ = 1 is the Bekker-type law above exactly; 0.05 ≤ ζ ≤ 20;
            ignored (and not counted as active) when the soil is linear.
        wheel_liftoff: Unilateral contact: the total ground force
            W + F_d is clipped at 0 (the wheel leaves the ground). Also
            reachable through ``Scenario.wheel_liftoff`` (kept for backward
            compatibility; either switches it on).
        suspension_friction: Coulomb friction force F_c (N) in the suspension
            (2-DOF only), smoothed as F_c · tanh(Δv / v_f) on the relative
            velocity Δv = ẏ2 − ẏ1 with v_f = :data:`FRICTION_VELOCITY_SCALE`.
            The simulator requires F_c·Δt / (v_f·μ) ≤ 1 (μ the reduced mass
            m_s m_ns/(m_s + m_ns), Δt the RK4 step) so that RK4 resolves the
            near-stick slope: F_c ≤ ≈ 830 N at 1 ms.
        tire_damping: Damper c_t (N·s/m) in parallel with the tire stiffness
            (2-DOF only): F_d = k_tot (h − y2) + c_t (ḣ − ẏ2). Like the LRV's
            damper it acts across the whole tire–soil series chain (massless
            simplification, no internal contact state).
        tire_contact_length: Contact-patch length L (m): the road felt by the
            tire is the moving average of h over [s − L/2, s + L/2]
            (wavelengths L, L/2, … are cancelled, short ones attenuated as
            sinc(L/λ)). The profile sampler still measures the true h, and so
            does the truth's ``road_elevation``. 0: off.
        sprung_mass_change: Relative change x of the sprung mass (–): the
            plant runs with m_s (1 + x) (the LRV's lumped mass m (1 + x)); the
            static load changes with it. x > −1.
    """

    accel_bias_body: float = 0.0
    accel_bias_wheel: float = 0.0
    accel_scale_body: float = 0.0
    accel_scale_wheel: float = 0.0
    sensor_delay: float = 0.0
    sensor_delay_body: float = 0.0
    sensor_delay_wheel: float = 0.0
    sensor_delay_profile: float = 0.0
    soil_exponent: float = 0.0
    soil_origin_ratio: float = 1.0
    wheel_liftoff: bool = False
    suspension_friction: float = 0.0
    tire_damping: float = 0.0
    tire_contact_length: float = 0.0
    sprung_mass_change: float = 0.0

    def __post_init__(self) -> None:
        owner = "QuarterCarEffects"

        def number(name: str) -> float:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"{owner}.{name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
            return float(value)

        for name in ("accel_bias_body", "accel_bias_wheel"):
            number(name)
        for name in ("accel_scale_body", "accel_scale_wheel"):
            if not -1.0 < number(name) < 1.0:
                raise ValueError(f"{owner}.{name} must be in (−1, 1), got {getattr(self, name)}")
        for name in ("sensor_delay", "sensor_delay_body", "sensor_delay_wheel", "sensor_delay_profile"):
            if not 0.0 <= number(name) <= 1.0:
                raise ValueError(f"{owner}.{name} must be in [0, 1] s, got {getattr(self, name)}")
        n = number("soil_exponent")
        if not (n == 0.0 or 0.2 <= n <= 3.0):
            raise ValueError(f"{owner}.soil_exponent must be 0 (off) or in [0.2, 3], got {n}")
        if not 0.05 <= number("soil_origin_ratio") <= 20.0:
            raise ValueError(f"{owner}.soil_origin_ratio must be in [0.05, 20], got {self.soil_origin_ratio}")
        if not isinstance(self.wheel_liftoff, bool | np.bool_):
            raise ValueError(f"{owner}.wheel_liftoff must be a bool, got {self.wheel_liftoff!r}")
        object.__setattr__(self, "wheel_liftoff", bool(self.wheel_liftoff))
        if not 0.0 <= number("suspension_friction") <= 1.0e5:
            raise ValueError(f"{owner}.suspension_friction must be in [0, 1e5] N, got {self.suspension_friction}")
        if not 0.0 <= number("tire_damping") <= 1.0e6:
            raise ValueError(f"{owner}.tire_damping must be in [0, 1e6] N·s/m, got {self.tire_damping}")
        if not 0.0 <= number("tire_contact_length") <= 5.0:
            raise ValueError(f"{owner}.tire_contact_length must be in [0, 5] m, got {self.tire_contact_length}")
        if not -1.0 < number("sprung_mass_change") <= 10.0:
            raise ValueError(f"{owner}.sprung_mass_change must be in (−1, 10], got {self.sprung_mass_change}")

    @classmethod
    def nominal(cls) -> QuarterCarEffects:
        """Everything off: the paper's linear quarter car / LRV."""
        return cls()

    @property
    def nonlinear_soil(self) -> bool:
        """True if the soil follows the Bekker-type law (soil_exponent not 0 or 1)."""
        return self.soil_exponent not in (0.0, 1.0)

    @property
    def active(self) -> tuple[str, ...]:
        """Names of the fields that are switched on (soil_exponent = 1 counts as off)."""
        reference = QuarterCarEffects()
        return tuple(
            name
            for name in self.__dataclass_fields__
            if getattr(self, name) != getattr(reference, name)
            and (name not in ("soil_exponent", "soil_origin_ratio") or self.nonlinear_soil)
        )

    def accelerometer_delays(self) -> tuple[float, float]:
        """Total latency (s) of the (body, wheel) accelerometers: the common one plus each stream's own."""
        return self.sensor_delay + self.sensor_delay_body, self.sensor_delay + self.sensor_delay_wheel

    @property
    def active_effects(self) -> tuple[str, ...]:
        """Catalogue names (keys of :data:`QUARTER_CAR_EFFECTS`) of the effects switched on."""
        on = set(self.active)
        return tuple(effect for effect, names in QUARTER_CAR_EFFECTS.items() if on.intersection(names))


class _MovingAverageProfile(RoadProfile):
    """h averaged over a centred window of length L, by Gauss–Legendre quadrature.

    The slope is exact: d/ds of the average is (h(s + L/2) − h(s − L/2)) / L.
    """

    def __init__(self, profile: RoadProfile, length: float) -> None:
        self.profile = profile
        self.length = length
        nodes, weights = np.polynomial.legendre.leggauss(ENVELOPING_QUADRATURE_POINTS)
        self._offsets = 0.5 * length * nodes
        self._weights = 0.5 * weights
        self.name = f"{profile.name}_enveloped"
        self.description = f"{profile.description} (moving average over {length:g} m)"

    def elevation_and_slope(self, distance: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        s = np.asarray(distance, dtype=float)
        samples = self.profile.elevation(np.add.outer(s, self._offsets))
        h = samples @ self._weights
        half = 0.5 * self.length
        slope = (self.profile.elevation(s + half) - self.profile.elevation(s - half)) / self.length
        return np.asarray(h, dtype=float), np.asarray(slope, dtype=float)


def enveloped_profile(profile: RoadProfile, contact_length: float) -> RoadProfile:
    """The road the tire feels: h averaged over the contact patch [s − L/2, s + L/2].

    Args:
        profile: The true road.
        contact_length: L (m); 0 returns ``profile`` itself.

    Returns:
        A :class:`HarmonicProfile` with amplitudes × sinc(n_i L) (exact) for a
        harmonic road, the road itself when flat or L = 0, a quadrature
        average otherwise.
    """
    if contact_length == 0.0 or isinstance(profile, FlatProfile):
        return profile
    if isinstance(profile, HarmonicProfile):
        return HarmonicProfile(
            profile.spatial_frequencies,
            profile.amplitudes * np.sinc(profile.spatial_frequencies * contact_length),
            profile.phases,
            name=f"{profile.name}_enveloped",
            description=f"{profile.description} (moving average over {contact_length:g} m)",
        )
    return _MovingAverageProfile(profile, contact_length)


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


# ---------------------------------------------------------------------------
# Equations of motion (scalar code: a few floats per stage, called ~10⁴ times/s)
# ---------------------------------------------------------------------------


def _rk4_two_dof(
    accelerations: Callable[[float, float, float, float, int], tuple[float, float]],
    state: tuple[float, float, float, float],
    substeps: int,
    dt: float,
    record: list[tuple[float, float]] | None = None,
) -> tuple[float, float, float, float]:
    """Classical RK4 of (y1, v1, y2, v2) over ``substeps`` steps of ``dt``.

    ``accelerations(y1, v1, y2, v2, j)`` gives (ÿ1, ÿ2) with the road and
    stiffness at half-step index ``j`` (2i, 2i + 1, 2i + 2 for step i).
    ``record``, if given, receives (ÿ1, ÿ2) at the start of every step.
    """
    y1, v1, y2, v2 = state
    half, sixth = 0.5 * dt, dt / 6.0
    for i in range(substeps):
        j = 2 * i
        a1, b1 = accelerations(y1, v1, y2, v2, j)
        if record is not None:
            record.append((a1, b1))
        p1, q1 = v1 + half * a1, v2 + half * b1
        a2, b2 = accelerations(y1 + half * v1, p1, y2 + half * v2, q1, j + 1)
        p2, q2 = v1 + half * a2, v2 + half * b2
        a3, b3 = accelerations(y1 + half * p1, p2, y2 + half * q1, q2, j + 1)
        p3, q3 = v1 + dt * a3, v2 + dt * b3
        a4, b4 = accelerations(y1 + dt * p2, p3, y2 + dt * q2, q3, j + 2)
        y1 += sixth * (v1 + 2.0 * p1 + 2.0 * p2 + p3)
        y2 += sixth * (v2 + 2.0 * q1 + 2.0 * q2 + q3)
        v1 += sixth * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        v2 += sixth * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
    return y1, v1, y2, v2


def _rk4_one_dof(
    acceleration: Callable[[float, float, int], float],
    state: tuple[float, float],
    substeps: int,
    dt: float,
    record: list[tuple[float, float]] | None = None,
) -> tuple[float, float]:
    """Classical RK4 of (y1, v1); ``acceleration(y1, v1, j)`` and ``record`` as in :func:`_rk4_two_dof`."""
    y1, v1 = state
    half, sixth = 0.5 * dt, dt / 6.0
    for i in range(substeps):
        j = 2 * i
        a1 = acceleration(y1, v1, j)
        if record is not None:
            record.append((a1, 0.0))
        p1 = v1 + half * a1
        a2 = acceleration(y1 + half * v1, p1, j + 1)
        p2 = v1 + half * a2
        a3 = acceleration(y1 + half * p1, p2, j + 1)
        p3 = v1 + dt * a3
        a4 = acceleration(y1 + dt * p2, p3, j + 2)
        y1 += sixth * (v1 + 2.0 * p1 + 2.0 * p2 + p3)
        v1 += sixth * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return y1, v1


def _advance_two_dof(
    state: tuple[float, float, float, float],
    road: list[float],
    stiffness: list[float],
    substeps: int,
    dt: float,
    vehicle: QuarterCarVehicle,
    static_load: float,
    liftoff: bool,
    record: list[tuple[float, float]] | None = None,
) -> tuple[float, float, float, float]:
    """RK4 over ``substeps`` steps of eq. 2; road and k_tot given at every half step."""
    m1, m2 = vehicle.sprung_mass, vehicle.unsprung_mass
    k, c = vehicle.suspension_stiffness, vehicle.suspension_damping
    floor = -static_load

    def accelerations(y1: float, v1: float, y2: float, v2: float, j: int) -> tuple[float, float]:
        suspension = k * (y2 - y1) + c * (v2 - v1)
        ground = stiffness[j] * (road[j] - y2)
        if liftoff and ground < floor:
            ground = floor
        return suspension / m1, (ground - suspension) / m2

    return _rk4_two_dof(accelerations, state, substeps, dt, record)


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
    record: list[tuple[float, float]] | None = None,
) -> tuple[float, float]:
    """RK4 over ``substeps`` steps of the 1-DOF LRV (MODELS.md A.7)."""
    m = vehicle.sprung_mass
    floor = -static_load

    def acceleration(y1: float, v1: float, j: int) -> float:
        ground, skyhook = _lrv_ground_force(y1, v1, road[j], road_rate[j], stiffness[j], vehicle)
        if liftoff and ground < floor:
            ground = floor
        return (ground + skyhook) / m

    return _rk4_one_dof(acceleration, state, substeps, dt, record)


def _bekker_chain_force(
    deflection: float, series_stiffness: float, k_s: float, load: float, n: float, origin: float = 1.0
) -> float:
    """Dynamic force F_d (N) of a linear spring in series with the Bekker-type soil.

    The chain carries the total force F = W + F_d; the spring deflects by F/k.
    The soil (:class:`QuarterCarEffects` ``soil_exponent`` n, ``soil_origin_ratio`` ζ)
    compresses beyond static by δ = ζ z₀ (σ(1 + (F/W − 1)/ζ)^(1/n) − 1)
    (σ: odd continuation), z₀ = W/k_s; ζ = 1: z = z₀ σ(F/W)^(1/n).
    Solves (F − W)/k + δ = deflection, deflection the chain's compression
    beyond static (h − y), by safeguarded Newton in x = F/W (the left side
    increases strictly with x).
    """
    if load <= 0.0:
        # No static sinkage to scale the law around: fall back to the linear chain.
        return float(k_tot(k_s, series_stiffness)) * deflection
    ratio = k_s / series_stiffness  # (k_s/k): the spring's share in units of z₀
    target = deflection * k_s / load  # deflection / z₀
    inv_n = 1.0 / n
    zeta = origin

    def residual(x: float) -> float:
        if zeta == 1.0:
            root = abs(x) ** inv_n
            return ratio * (x - 1.0) + math.copysign(root, x) - 1.0 - target
        u = 1.0 + (x - 1.0) / zeta
        return ratio * (x - 1.0) + zeta * (math.copysign(abs(u) ** inv_n, u) - 1.0) - target

    x = 1.0 + target / (1.0 + ratio)  # the linear chain's answer
    f = residual(x)
    if f == 0.0:
        return load * (x - 1.0)
    # Bracket the root by doubling steps away from the linear guess.
    step = max(1.0, abs(x))
    lo, hi = (x, x + step) if f < 0.0 else (x - step, x)
    while residual(lo) > 0.0:
        step *= 2.0
        lo -= step
    while residual(hi) < 0.0:
        step *= 2.0
        hi += step
    for _ in range(100):
        f = residual(x)
        if f == 0.0:
            break
        if f < 0.0:
            lo = x
        else:
            hi = x
        ax = abs(1.0 + (x - 1.0) / zeta) if zeta != 1.0 else abs(x)
        slope = ratio + inv_n * ax ** (inv_n - 1.0) if ax > 0.0 else math.inf
        x_new = x - f / slope if math.isfinite(slope) else 0.5 * (lo + hi)
        if not lo < x_new < hi:
            x_new = 0.5 * (lo + hi)
        if abs(x_new - x) <= 1e-13 * max(1.0, abs(x)):
            x = x_new
            break
        x = x_new
    return load * (x - 1.0)


@dataclass(frozen=True)
class _Dynamics:
    """The effects that change the equations of motion, resolved for one simulator."""

    soil_exponent: float  # 0: linear soil
    friction: float  # F_c (N)
    tire_damping: float  # c_t (N·s/m)
    soil_origin: float = 1.0  # ζ of the nonlinear soil

    def ground(self, deflection: float, kt: float, k_s: float, series: float, load: float) -> float:
        """Spring part of the dynamic ground force (N) for chain compression ``deflection`` (m)."""
        if self.soil_exponent:
            return _bekker_chain_force(deflection, series, k_s, load, self.soil_exponent, self.soil_origin)
        return kt * deflection


def _two_dof_forces(
    y1: float,
    v1: float,
    y2: float,
    v2: float,
    h: float,
    h_rate: float,
    kt: float,
    k_s: float,
    vehicle: QuarterCarVehicle,
    load: float,
    dynamics: _Dynamics,
) -> tuple[float, float]:
    """(suspension force on the body, dynamic ground force F_d before lift-off) in N."""
    dv = v2 - v1
    suspension = vehicle.suspension_stiffness * (y2 - y1) + vehicle.suspension_damping * dv
    if dynamics.friction:
        suspension += dynamics.friction * math.tanh(dv / FRICTION_VELOCITY_SCALE)
    ground = dynamics.ground(h - y2, kt, k_s, vehicle.tire_stiffness, load)
    if dynamics.tire_damping:
        ground += dynamics.tire_damping * (h_rate - v2)
    return suspension, ground


def _advance_two_dof_effects(
    state: tuple[float, float, float, float],
    road: list[float],
    road_rate: list[float],
    stiffness: list[float],
    soil_stiffness: list[float],
    substeps: int,
    dt: float,
    vehicle: QuarterCarVehicle,
    static_load: float,
    liftoff: bool,
    dynamics: _Dynamics,
    record: list[tuple[float, float]] | None = None,
) -> tuple[float, float, float, float]:
    """RK4 of eq. 2 with nonlinear soil, suspension friction and/or tire damping."""
    m1, m2 = vehicle.sprung_mass, vehicle.unsprung_mass
    floor = -static_load

    def accelerations(y1: float, v1: float, y2: float, v2: float, j: int) -> tuple[float, float]:
        suspension, ground = _two_dof_forces(
            y1, v1, y2, v2, road[j], road_rate[j], stiffness[j], soil_stiffness[j], vehicle, static_load, dynamics
        )
        if liftoff and ground < floor:
            ground = floor
        return suspension / m1, (ground - suspension) / m2

    return _rk4_two_dof(accelerations, state, substeps, dt, record)


def _lrv_forces(
    y1: float,
    v1: float,
    h: float,
    h_rate: float,
    kt: float,
    k_s: float,
    vehicle: LRVVehicle,
    load: float,
    dynamics: _Dynamics,
) -> tuple[float, float]:
    """:func:`_lrv_ground_force` with the nonlinear soil."""
    if not dynamics.soil_exponent:
        return _lrv_ground_force(y1, v1, h, h_rate, kt, vehicle)
    spring = dynamics.ground(h - y1, kt, k_s, vehicle.combined_stiffness, load)
    if vehicle.damper_reference == "ground":
        return spring + vehicle.damping * (h_rate - v1), 0.0
    return spring, -vehicle.damping * v1


def _advance_lrv_effects(
    state: tuple[float, float],
    road: list[float],
    road_rate: list[float],
    stiffness: list[float],
    soil_stiffness: list[float],
    substeps: int,
    dt: float,
    vehicle: LRVVehicle,
    static_load: float,
    liftoff: bool,
    dynamics: _Dynamics,
    record: list[tuple[float, float]] | None = None,
) -> tuple[float, float]:
    """RK4 of the 1-DOF LRV with the nonlinear soil."""
    m = vehicle.sprung_mass
    floor = -static_load

    def acceleration(y1: float, v1: float, j: int) -> float:
        ground, skyhook = _lrv_forces(
            y1, v1, road[j], road_rate[j], stiffness[j], soil_stiffness[j], vehicle, static_load, dynamics
        )
        if liftoff and ground < floor:
            ground = floor
        return (ground + skyhook) / m

    return _rk4_one_dof(acceleration, state, substeps, dt, record)


# ---------------------------------------------------------------------------
# Simulator
# ---------------------------------------------------------------------------


_ACCEL_FIELDS = frozenset(("accel_bias_body", "accel_bias_wheel", "accel_scale_body", "accel_scale_wheel"))


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
        effects = scenario.effects
        if not self._two_dof:
            for name in LRV_IGNORED_EFFECTS:
                if getattr(effects, name) != 0.0:
                    raise ValueError(
                        f"QuarterCarEffects.{name} = {getattr(effects, name)} does not apply to the 1-DOF LRV "
                        "(no wheel accelerometer, no separate suspension or tire); leave it at 0"
                    )
        self._period = scenario.sensor_period
        self._substeps = scenario.substeps
        self._dt = self._period / self._substeps
        self._stage_offsets = 0.5 * self._dt * np.arange(2 * self._substeps + 1)
        accel_seed, profile_seed = np.random.SeedSequence(seed).spawn(2)
        self._accel_rng = np.random.default_rng(accel_seed)
        self._profile_rng = np.random.default_rng(profile_seed)
        self._accel_std = math.sqrt(scenario.accel_noise_variance)
        # The plant actually integrated: the vehicle with the sprung-mass change.
        self._plant: Vehicle = (
            replace(vehicle, sprung_mass=vehicle.sprung_mass * (1.0 + effects.sprung_mass_change))
            if effects.sprung_mass_change
            else vehicle
        )
        self._static_load = self._plant.total_mass * scenario.gravity
        self._k_tot_by_segment = [vehicle.k_tot(soil.k_s) for soil in scenario.soil_path.soils]
        self._dynamics = _Dynamics(
            soil_exponent=effects.soil_exponent if effects.nonlinear_soil else 0.0,
            friction=effects.suspension_friction,
            tire_damping=effects.tire_damping,
            soil_origin=effects.soil_origin_ratio if effects.nonlinear_soil else 1.0,
        )
        self._nominal_dynamics = self._dynamics == _Dynamics(0.0, 0.0, 0.0)
        if self._dynamics.friction and isinstance(self._plant, QuarterCarVehicle):
            reduced = self._plant.sprung_mass * self._plant.unsprung_mass / self._plant.total_mass
            stiffness = self._dynamics.friction * self._dt / (FRICTION_VELOCITY_SCALE * reduced)
            if stiffness > 1.0:
                raise ValueError(
                    f"QuarterCarEffects.suspension_friction = {effects.suspension_friction} N is too stiff for the "
                    f"RK4 step {self._dt} s (F_c·dt/(v_f·mu) = {stiffness:.3g} > 1); reduce it or integration_step"
                )
        # The road the tire feels (contact-patch average); the profiler measures scenario.profile.
        self._tire_profile = enveloped_profile(scenario.profile, effects.tire_contact_length)
        self._enveloping = self._tire_profile is not scenario.profile
        self._step_index = 0
        self._next_profile_index = 0
        n_states = 4 if self._two_dof else 2
        if initial_state is None:
            h0 = float(self._tire_profile.elevation(np.array([0.0]))[0])
            state: tuple[float, ...] = (h0, 0.0, h0, 0.0) if self._two_dof else (h0, 0.0)
        else:
            state = tuple(float(x) for x in initial_state)
            if len(state) != n_states:
                raise ValueError(f"initial_state needs {n_states} values, got {len(state)}")
        self._state: tuple[float, ...] = state
        # Noise-free true accelerations (body, wheel) at every RK4 step from t = 0, for the delay:
        # the delayed reading is interpolated on the integration grid, not between sensor samples
        # (linear interpolation at the sensor rate would low-pass the signal: −5 % at 10 Hz, 100 Hz).
        # Each accelerometer has its own lag (sensor_delay plus the stream's own latency).
        body_delay, wheel_delay = effects.accelerometer_delays()
        self._delay_lags = (body_delay / self._dt, wheel_delay / self._dt)
        self._delaying = body_delay > 0.0 or wheel_delay > 0.0
        self._accel_history: deque[tuple[float, float]] = deque(maxlen=int(math.ceil(max(self._delay_lags))) + 2)
        self._record: list[tuple[float, float]] | None = [] if self._delaying else None
        # Profile readings taken but not yet delivered (sensor_delay_profile): (taken at, distance, elevation).
        self._profile_buffer: deque[tuple[float, float, float]] = deque()

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

        if self._enveloping:
            # The same stage grid on the road the tire feels.
            if constant_speed:
                tire_road, tire_slope = self._tire_profile.evaluate_uniform(s0, stage_spacing, stage_distance.size)
                tire_rate = v * tire_slope
            else:
                tire_road, tire_slope = self._tire_profile.elevation_and_slope(stage_distance)
                tire_rate = speed_profile.speed(t0 + self._stage_offsets) * tire_slope
        else:
            tire_road, tire_rate = road, road_rate

        soil_index = scenario.soil_path.index_at(stage_distance)
        stiffness = [self._k_tot_by_segment[i] for i in soil_index.tolist()]
        road_list = tire_road.tolist()
        liftoff = scenario.effects.wheel_liftoff
        if self._nominal_dynamics:
            if self._two_dof:
                self._state = _advance_two_dof(
                    self._state,  # type: ignore[arg-type]
                    road_list,
                    stiffness,
                    self._substeps,
                    self._dt,
                    self._plant,  # type: ignore[arg-type]
                    self._static_load,
                    liftoff,
                    self._record,
                )
            else:
                self._state = _advance_lrv(
                    self._state,  # type: ignore[arg-type]
                    road_list,
                    tire_rate.tolist(),
                    stiffness,
                    self._substeps,
                    self._dt,
                    self._plant,  # type: ignore[arg-type]
                    self._static_load,
                    liftoff,
                    self._record,
                )
        else:
            soils = scenario.soil_path.soils
            soil_stiffness = [soils[i].k_s for i in soil_index.tolist()]
            advance = _advance_two_dof_effects if self._two_dof else _advance_lrv_effects
            self._state = advance(
                self._state,  # type: ignore[arg-type]
                road_list,
                tire_rate.tolist(),
                stiffness,
                soil_stiffness,
                self._substeps,
                self._dt,
                self._plant,  # type: ignore[arg-type]
                self._static_load,
                liftoff,
                self._dynamics,
                self._record,
            )
        self._step_index += 1

        distance = float(stage_distance[-1])
        speed = float(speed_profile.speed(t1))
        truth = self._truth(
            float(road[-1]),
            float(road_rate[-1]),
            float(tire_road[-1]),
            float(tire_rate[-1]),
            stiffness[-1],
            int(soil_index[-1]),
        )
        noise = self._accel_rng.standard_normal(2) * self._accel_std
        body_accel, wheel_accel = self._accelerometers(truth, noise)
        radius = self.vehicle.wheel_radius
        return QuarterCarSample(
            t=t1,
            body_accel_z=body_accel,
            wheel_accel_z=wheel_accel,
            distance=distance,
            wheel_angle=distance / radius,
            wheel_rate=speed / radius,
            speed=speed,
            profile=self._deliver_profile(self._profile_readings(t0, t1, constant_speed, stage_distance, road), t1),
            truth=truth,
        )

    def _specific_forces(self, truth: QuarterCarTruth) -> tuple[float, float]:
        """Noise-free true specific forces ÿ + g (body, wheel; 0 for the LRV's wheel), m/s²."""
        g = self.scenario.gravity
        wheel = truth.wheel_acceleration
        return float(truth.body_acceleration) + g, (float(wheel) + g if wheel is not None else 0.0)

    def _accelerometers(self, truth: QuarterCarTruth, noise: NDArray[np.float64]) -> tuple[float, float | None]:
        """The accelerometer readings: true specific force, delayed, scaled, biased, plus noise."""
        effects = self.scenario.effects
        g = self.scenario.gravity
        if not (self._delaying or _ACCEL_FIELDS.intersection(effects.active)):
            # Nominal sensors: the same arithmetic as always (bit-identical output).
            body = float(truth.body_acceleration) + g + float(noise[0])
            wheel = (
                float(truth.wheel_acceleration) + g + float(noise[1])  # type: ignore[arg-type]
                if self._two_dof
                else None
            )
            return body, wheel
        body_sf, wheel_sf = self._delayed(self._specific_forces(truth))
        body = (1.0 + effects.accel_scale_body) * body_sf + effects.accel_bias_body + float(noise[0])
        if not self._two_dof:
            return body, None
        return body, (1.0 + effects.accel_scale_wheel) * wheel_sf + effects.accel_bias_wheel + float(noise[1])

    def _delayed(self, current: tuple[float, float]) -> tuple[float, float]:
        """The (body, wheel) specific forces each its own latency ago, linearly interpolated on the RK4 grid.

        The history holds the accelerations at the start of every RK4 step
        since t = 0 (recorded by the integrator); ``current`` is the value at
        the end of this sensor period. Before the run has lasted a channel's
        delay, its t = 0 value is returned.
        """
        if not self._delaying:
            return current
        g = self.scenario.gravity
        history = self._accel_history
        if self._record:
            two = self._two_dof
            history.extend((a + g, (b + g) if two else 0.0) for a, b in self._record)
            self._record.clear()
        sequence = list(history) + [current]
        out = []
        for channel, lag in enumerate(self._delay_lags):
            whole = int(math.floor(lag + 1e-9))
            frac = max(lag - whole, 0.0)
            if frac <= 1e-9:
                frac = 0.0
            needed = whole + (1 if frac else 0)
            if needed > len(sequence) - 1:
                out.append(sequence[0][channel])
                continue
            newer = sequence[-1 - whole][channel]
            if not frac:
                out.append(newer)
                continue
            older = sequence[-2 - whole][channel]
            out.append((1.0 - frac) * newer + frac * older)
        return out[0], out[1]

    def _deliver_profile(self, readings: ProfileReadings, t1: float) -> ProfileReadings:
        """The profile sampler's latency: buffer the readings taken, deliver those due by ``t1`` (stamped when due)."""
        delay = self.scenario.effects.sensor_delay_profile
        if not delay:
            return readings
        for t, s, h in zip(readings.t.tolist(), readings.distance.tolist(), readings.elevation.tolist(), strict=True):
            self._profile_buffer.append((t, s, h))
        due = []
        while self._profile_buffer and self._profile_buffer[0][0] + delay <= t1 + 1e-9:
            due.append(self._profile_buffer.popleft())
        if not due:
            empty = np.empty(0)
            return ProfileReadings(empty, empty.copy(), empty.copy())
        taken, distance, elevation = (np.array(column, dtype=float) for column in zip(*due, strict=True))
        return ProfileReadings(taken + delay, distance, elevation)

    def _truth(
        self, h: float, h_rate: float, h_tire: float, h_tire_rate: float, kt: float, segment: int
    ) -> QuarterCarTruth:
        """Truth at the current state; ``h``/``h_rate`` the true road, ``h_tire``/``h_tire_rate`` the one felt."""
        soil = self.scenario.soil_path.soils[segment]
        load = self._static_load
        liftoff = self.scenario.effects.wheel_liftoff
        dynamics = self._dynamics
        if self._two_dof:
            vehicle: QuarterCarVehicle = self._plant  # type: ignore[assignment]
            y1, v1, y2, v2 = self._state
            if self._nominal_dynamics:
                suspension = vehicle.suspension_stiffness * (y2 - y1) + vehicle.suspension_damping * (v2 - v1)
                dynamic = kt * (h_tire - y2)
            else:
                suspension, dynamic = _two_dof_forces(
                    y1, v1, y2, v2, h_tire, h_tire_rate, kt, soil.k_s, vehicle, load, dynamics
                )
            in_contact = load + dynamic > 0.0
            if liftoff and not in_contact:
                dynamic = -load
            a1 = suspension / vehicle.sprung_mass
            a2 = (dynamic - suspension) / vehicle.unsprung_mass
            wheel: tuple[float | None, float | None, float | None] = (y2, v2, a2)
        else:
            lrv: LRVVehicle = self._plant  # type: ignore[assignment]
            y1, v1 = self._state
            dynamic, skyhook = _lrv_forces(y1, v1, h_tire, h_tire_rate, kt, soil.k_s, lrv, load, dynamics)
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
