"""Unmodelled effects of the soil-stiffness plant (the sim-to-real catalogue's quarter car and LRV entries).

:class:`QuarterCarEffects` switches them; the road the tire feels with the
enveloping effect is :func:`enveloped_profile`. How each one enters the plant:
:mod:`vehicle_sim.plants.quarter_car`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vehicle_sim.plants.checks import changed_fields
from vehicle_sim.terrain.profiles import FlatProfile, HarmonicProfile, RoadProfile

__all__ = [
    "ENVELOPING_QUADRATURE_POINTS",
    "FRICTION_VELOCITY_SCALE",
    "LRV_IGNORED_EFFECTS",
    "QUARTER_CAR_EFFECTS",
    "QuarterCarEffects",
    "enveloped_profile",
]

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
        return tuple(
            name
            for name in changed_fields(self, QuarterCarEffects())
            if name not in ("soil_exponent", "soil_origin_ratio") or self.nonlinear_soil
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
