"""Rigid wheel on deformable soil: Wong–Reece stresses, contact angle, drawbar pull, resistive torque.

Setterfield & Ellery, *Terrain Response Estimation Using an Instrumented
Rocker-Bogie Mobility System* ([RB], MODELS.md C.1), after Wong & Reece (1967).
This is the truth physics of the rocker-bogie simulator; the simulator itself
uses the polynomial surrogate of
:mod:`vehicle_sim.terrain.terramechanics_surrogate`, fitted to this model.

Angles
    θ is measured at the wheel centre from the bottom dead centre towards the
    entry point: exit angle 0, entry (contact) angle θ0, maximum normal stress
    at θ_m = θ0 (c1 + c2 i) (eq. 3). Only 0 ≤ θ0 ≤ π/2 is considered (the
    wheel sinks at most to its axle).

Equations ([RB] numbering)::

    σ(θ) = (k1 + k2 b) [ (r/b)(cos θ − cos θ0) ]^n                 θ_m ≤ θ ≤ θ0   (4)
    σ(θ) = (k1 + k2 b) [ (r/b)(cos θ* − cos θ0) ]^n,
           θ* = θ0 − (θ/θ_m)(θ0 − θ_m)                             0 ≤ θ < θ_m    (5)
    τ(θ) = (c + σ tan φ)(1 − exp(−j/K_s)),
           j = r [(θ0 − θ) − (1 − i)(sin θ0 − sin θ)]                             (6)
    W    = b r (∫ σ cos θ dθ + ∫ τ sin θ dθ)                                       (7)
    DP   = b r (∫ τ cos θ dθ − ∫ σ sin θ dθ)                                       (8)
    τ_R  = b r² ∫ τ dθ                                                             (9)

  all integrals over [0, θ0]. Eq. 6 is printed with "τ_w/K_s"; the
  dimensionally correct factor r/K_s is used (MODELS.md C.1). With
  k1 = k_c b^(n−1), k2 = k_φ b^(n−1) eq. 4 is Bekker's
  σ = (k_c/b + k_φ)(r(cos θ − cos θ0))^n.

Skid (i < 0) by anti-symmetry about the i = 0 intercept (eqs. 10–11)::

    DP(i) = −DP(−i) + 2 DP(0),    τ_R(i) = −τ_R(−i) + 2 τ_R(0)

Numerics
    The rim integrals use composite Simpson's rule on the rear region
    [0, θ_m] and on the front region [θ_m, θ0] separately, ``simpson_points``
    nodes each (θ_m shared). σ has a kink at θ_m, so splitting there keeps
    Simpson's accuracy. ``simpson_points=3`` uses the paper's 5 rim nodes
    (placed at θ_m rather than uniformly); the default is more accurate.
    Because every node is a fixed fraction of θ0 the discrete W(θ0) is smooth
    in θ0, and the contact angle solves the *same*
    discretised eq. 7 that DP and τ_R are then integrated with.

    The contact angle is the smallest root of eq. 7 on (0, π/2] (Algorithm 1,
    step 3): W(θ0, i) is tabulated on a uniform θ0 scan once per distinct slip,
    the first scan interval where it reaches the load brackets the root, and a
    vectorised Illinois (modified regula falsi) iteration refines every
    (W, i) pair at once.

Behaviour with Table II's soil and the Kapvik wheel (tested)
    τ_R rises with slip at every load. DP rises with slip up to i ≈ 0.4 at
    every load and over the whole 0 ≤ i ≤ 1 only for W ≲ 28 N: heavier
    wheels sink further as slip moves θ_m forward, so DP peaks (≈ 10.3 N at
    W ≈ 120 N, i ≈ 0.6) and falls again (−5.4 N at W = 200 N, i = 1). Over
    0.1 ≤ W ≤ 200 N, 0 ≤ i ≤ 1 DP spans −9.53…10.29 N ([RB]: −9.406…10.195 N).

Units: SI throughout (m, rad, Pa, N, N·m); slip i is dimensionless.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from terrain_estimation.checks import check_fields

Array = NDArray[np.float64]

__all__ = [
    "DEFAULT_SIMPSON_POINTS",
    "KAPVIK_WHEEL",
    "TABLE_II_SOIL",
    "ContactAngleConvergenceError",
    "RigidWheel",
    "WheelForces",
    "WheelOverloadError",
    "WongReeceSoil",
    "contact_angle",
    "drawbar_pull_and_resistive_torque",
    "max_stress_angle",
    "normal_load",
    "normal_stress",
    "shear_displacement",
    "shear_stress",
    "simpson_weights",
    "slip_ratio",
    "soil_shear_stress",
    "wheel_forces",
    "wheel_forces_from_motion",
    "wheel_load_capacity",
]

DEFAULT_SIMPSON_POINTS = 9
"""Simpson nodes per flow region (rear and front): 17 rim nodes in all.

Measured against 1025 nodes per region over the surrogate's 100×100 grid
(0 ≤ i ≤ 1, 0.1 ≤ W ≤ 200 N, Table II soil, Kapvik wheel): DP error RMS
0.010 N, max 0.032 N (at W = 200 N, i = 0); τ_R error RMS 0.0003 N·m, max
0.0007 N·m — an order of magnitude below the 4th-order surrogate's fit error.
The error falls as h^2.1, not h⁴: near the entry σ ∝ (θ0 − θ)^n with n = 1.1
is not smooth enough for Simpson's full order.
"""

_HALF_PI = 0.5 * math.pi


class WheelOverloadError(ValueError):
    """The load exceeds what the wheel can carry with a contact angle θ0 ≤ π/2."""


class ContactAngleConvergenceError(RuntimeError):
    """The contact-angle iteration (eq. 7) did not converge for some (W, i)."""


# ---------------------------------------------------------------------------
# Soil and wheel
# ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class WongReeceSoil:
    """Soil of the Wong–Reece rigid-wheel model; defaults are [RB] Table II.

    Table II's soil is the lunar simulant of Ding et al. with Wong's loose-sand
    c1, c2. Its k1, k2 were converted from k_c, k_φ with the Kapvik wheel width
    b = 70 mm; build a soil for another wheel width with :meth:`from_bekker`.

    Attributes:
        sinkage_exponent: n_s (–).
        cohesion: c (Pa).
        friction_angle: internal friction angle φ (rad).
        shear_deformation_modulus: K_s (m).
        pressure_sinkage_k1: k1 (Pa), eqs. 4–5.
        pressure_sinkage_k2: k2 (Pa/m), eqs. 4–5.
        max_stress_angle_c1: c1 (–), eq. 3.
        max_stress_angle_c2: c2 (–), eq. 3.
    """

    sinkage_exponent: float = 1.1
    cohesion: float = 250.0
    friction_angle: float = math.radians(31.9)
    shear_deformation_modulus: float = 11.4e-3
    pressure_sinkage_k1: float = 12.0e3
    pressure_sinkage_k2: float = 1845.3e3
    max_stress_angle_c1: float = 0.18
    max_stress_angle_c2: float = 0.32

    def __post_init__(self) -> None:
        check_fields(self, ("sinkage_exponent", "shear_deformation_modulus"))
        check_fields(self, ("cohesion", "pressure_sinkage_k1", "pressure_sinkage_k2"), rule="non_negative")
        if not (0.0 <= self.friction_angle < _HALF_PI):
            raise ValueError(f"WongReeceSoil.friction_angle must be in [0, π/2) rad, got {self.friction_angle}")
        c1, c2 = self.max_stress_angle_c1, self.max_stress_angle_c2
        # θ_m must stay inside (0, θ0] for every slip 0 ≤ i ≤ 1 (eq. 3 is linear in i).
        if not (math.isfinite(c1) and math.isfinite(c2) and 0.0 < c1 <= 1.0 and 0.0 < c1 + c2 <= 1.0):
            raise ValueError(f"WongReeceSoil: need 0 < c1 ≤ 1 and 0 < c1 + c2 ≤ 1, got c1={c1}, c2={c2}")

    @classmethod
    def from_bekker(
        cls, *, cohesive_modulus: float, frictional_modulus: float, wheel_width: float, **kwargs: Any
    ) -> WongReeceSoil:
        """Soil from Bekker's moduli: k1 = k_c b^(n−1), k2 = k_φ b^(n−1) ([RB] Table II note).

        Args:
            cohesive_modulus: k_c (Pa/m^(n−1), i.e. N/m^(n+1)).
            frictional_modulus: k_φ (Pa/m^n, i.e. N/m^(n+2)).
            wheel_width: b (m) the model will be used with.
            **kwargs: any other field of :class:`WongReeceSoil` (e.g.
                ``sinkage_exponent``), Table II otherwise.
        """
        if not (math.isfinite(wheel_width) and wheel_width > 0.0):
            raise ValueError(f"wheel_width must be finite and > 0 m, got {wheel_width}")
        n = float(kwargs.get("sinkage_exponent", cls.sinkage_exponent))
        scale = wheel_width ** (n - 1.0)
        return cls(
            pressure_sinkage_k1=cohesive_modulus * scale, pressure_sinkage_k2=frictional_modulus * scale, **kwargs
        )


@dataclass(frozen=True, kw_only=True)
class RigidWheel:
    """Rigid wheel; defaults are the Kapvik wheel of [RB] Table I.

    Attributes:
        radius: r_w (m).
        width: b_w (m).
    """

    radius: float = 0.075
    width: float = 0.070

    def __post_init__(self) -> None:
        check_fields(self)


TABLE_II_SOIL = WongReeceSoil()
"""[RB] Table II soil (lunar simulant of Ding et al.; c1, c2 of Wong's loose sand)."""

KAPVIK_WHEEL = RigidWheel()
"""[RB] Table I wheel: r_w = 75 mm, b_w = 70 mm."""


class WheelForces(NamedTuple):
    """Steady-state wheel–soil forces (arrays of the broadcast input shape).

    Attributes:
        drawbar_pull: DP (N), eq. 8 (eq. 10 in skid); positive pulls forward.
        resistive_torque: τ_R (N·m), eq. 9 (eq. 11 in skid); the soil's torque
            opposing the wheel's rotation, positive when driven.
        contact_angle: θ0 (rad) carrying the load, eq. 7. In skid the value at
            slip −i, i.e. the state eqs. 10–11 mirror (the paper gives none).
    """

    drawbar_pull: Array
    resistive_torque: Array
    contact_angle: Array


# ---------------------------------------------------------------------------
# Kinematics and stresses (eqs. 1–6)
# ---------------------------------------------------------------------------


def slip_ratio(wheel_speed: ArrayLike, wheel_radius: float, forward_velocity: ArrayLike) -> Array:
    """Slip (> 0) or skid (< 0) of a wheel, [RB] eqs. 1–2.

    ``i = 1 − v/(r ω)`` when ``|r ω| ≥ |v|`` (slip, eq. 1), ``i = r ω/v − 1``
    otherwise (skid, eq. 2). Driving forward (v, ω ≥ 0) gives −1 ≤ i ≤ 1: a
    locked wheel that slides has i = −1, a wheel spinning in place i = 1.
    A wheel at rest (v = ω = 0) has i = 0.

    Args:
        wheel_speed: ω (rad/s).
        wheel_radius: r_w (m).
        forward_velocity: v_w of the wheel centre along the terrain (m/s).

    Returns:
        Slip i (–), broadcast shape of the inputs.
    """
    omega = np.asarray(wheel_speed, dtype=float)
    v = np.asarray(forward_velocity, dtype=float)
    rim = wheel_radius * omega
    rim, v = np.broadcast_arrays(rim, v)
    slipping = np.abs(rim) >= np.abs(v)
    at_rest = (rim == 0.0) & (v == 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        slip = np.where(slipping, 1.0 - v / np.where(rim == 0.0, 1.0, rim), rim / np.where(v == 0.0, 1.0, v) - 1.0)
    return np.where(at_rest, 0.0, slip)


def max_stress_angle(contact_angle: ArrayLike, slip: ArrayLike, soil: WongReeceSoil = TABLE_II_SOIL) -> Array:
    """θ_m = θ0 (c1 + c2 i) (rad), [RB] eq. 3."""
    theta0 = np.asarray(contact_angle, dtype=float)
    return theta0 * (soil.max_stress_angle_c1 + soil.max_stress_angle_c2 * np.asarray(slip, dtype=float))


def _pressure(cos_difference: Array, soil: WongReeceSoil, wheel: RigidWheel) -> Array:
    """(k1 + k2 b)[(r/b)(cos θ' − cos θ0)]^n (Pa), the common form of eqs. 4–5.

    The bracket is clipped at 0: it is ≥ 0 inside the contact, and round-off
    must not feed a negative base to the non-integer power.
    """
    stiffness = soil.pressure_sinkage_k1 + soil.pressure_sinkage_k2 * wheel.width
    base = np.maximum((wheel.radius / wheel.width) * cos_difference, 0.0)
    return stiffness * base**soil.sinkage_exponent


def normal_stress(
    theta: ArrayLike,
    contact_angle: ArrayLike,
    slip: ArrayLike,
    soil: WongReeceSoil = TABLE_II_SOIL,
    wheel: RigidWheel = KAPVIK_WHEEL,
) -> Array:
    """Normal stress σ(θ) on the rim (Pa), [RB] eqs. 4 (front, θ_m ≤ θ ≤ θ0) and 5 (rear, 0 ≤ θ < θ_m).

    Zero outside the contact 0 ≤ θ ≤ θ0. Inputs broadcast; 0 ≤ i ≤ 1.
    """
    theta_, theta0, slip_ = np.broadcast_arrays(
        np.asarray(theta, dtype=float), np.asarray(contact_angle, dtype=float), np.asarray(slip, dtype=float)
    )
    theta_m = max_stress_angle(theta0, slip_, soil)
    front = theta_ >= theta_m
    with np.errstate(divide="ignore", invalid="ignore"):
        fraction = np.where(theta_m > 0.0, theta_ / np.where(theta_m > 0.0, theta_m, 1.0), 0.0)
    # eq. 5 maps the rear region [0, θ_m) onto the front profile (θ_m, θ0].
    equivalent_angle = np.where(front, theta_, theta0 - fraction * (theta0 - theta_m))
    sigma = _pressure(np.cos(equivalent_angle) - np.cos(theta0), soil, wheel)
    in_contact = (theta_ >= 0.0) & (theta_ <= theta0)
    return np.where(in_contact, sigma, 0.0)


def shear_displacement(
    theta: ArrayLike, contact_angle: ArrayLike, slip: ArrayLike, wheel: RigidWheel = KAPVIK_WHEEL
) -> Array:
    """Shear displacement j(θ) = r [(θ0 − θ) − (1 − i)(sin θ0 − sin θ)] (m), the exponent of [RB] eq. 6 times K_s."""
    theta_ = np.asarray(theta, dtype=float)
    theta0 = np.asarray(contact_angle, dtype=float)
    return wheel.radius * (
        (theta0 - theta_) - (1.0 - np.asarray(slip, dtype=float)) * (np.sin(theta0) - np.sin(theta_))
    )


def soil_shear_stress(
    normal_stress: ArrayLike, shear_displacement: ArrayLike, soil: WongReeceSoil = TABLE_II_SOIL
) -> Array:
    """Janosi–Hanamoto shear stress τ = (c + σ tan φ)(1 − exp(−j/K_s)) (Pa), [RB] eq. 6."""
    sigma = np.asarray(normal_stress, dtype=float)
    j = np.asarray(shear_displacement, dtype=float)
    strength = soil.cohesion + sigma * math.tan(soil.friction_angle)
    return strength * -np.expm1(-j / soil.shear_deformation_modulus)


def shear_stress(
    theta: ArrayLike,
    contact_angle: ArrayLike,
    slip: ArrayLike,
    soil: WongReeceSoil = TABLE_II_SOIL,
    wheel: RigidWheel = KAPVIK_WHEEL,
) -> Array:
    """Shear stress τ(θ) on the rim (Pa), [RB] eq. 6 with r_w/K_s; zero outside 0 ≤ θ ≤ θ0."""
    theta_, theta0, slip_ = np.broadcast_arrays(
        np.asarray(theta, dtype=float), np.asarray(contact_angle, dtype=float), np.asarray(slip, dtype=float)
    )
    sigma = normal_stress(theta_, theta0, slip_, soil, wheel)
    tau = soil_shear_stress(sigma, shear_displacement(theta_, theta0, slip_, wheel), soil)
    return np.where((theta_ >= 0.0) & (theta_ <= theta0), tau, 0.0)


# ---------------------------------------------------------------------------
# Rim integrals (eqs. 7–9)
# ---------------------------------------------------------------------------


def simpson_weights(points: int) -> Array:
    """Composite Simpson weights for ``points`` equally spaced nodes on [0, 1] (odd, ≥ 3)."""
    if points < 3 or points % 2 == 0:
        raise ValueError(f"Simpson's rule needs an odd number ≥ 3 of points, got {points}")
    weights = np.ones(points)
    weights[1:-1:2] = 4.0
    weights[2:-1:2] = 2.0
    return weights / (3.0 * (points - 1))


def _rim_integrals(
    theta0: Array, slip: Array, soil: WongReeceSoil, wheel: RigidWheel, points: int
) -> tuple[Array, Array, Array]:
    """(W, DP, τ_R) of eqs. 7–9 by Simpson's rule on [0, θ_m] and [θ_m, θ0]; inputs of equal shape.

    Node s ∈ [0, 1] sits at θ = s θ_m in the rear and θ_m + s (θ0 − θ_m) in
    the front; the rear's eq.-5 angle θ* = θ0 − s (θ0 − θ_m) then needs no
    division by θ_m (which vanishes with θ0).
    """
    s = np.linspace(0.0, 1.0, points)
    weights = simpson_weights(points)
    theta0_ = theta0[..., None]
    slip_ = slip[..., None]
    theta_m = max_stress_angle(theta0_, slip_, soil)
    cos_theta0 = np.cos(theta0_)
    rear = s * theta_m
    front = theta_m + s * (theta0_ - theta_m)
    angles = np.concatenate([rear, front], axis=-1)
    sigma = _pressure(np.concatenate([np.cos(theta0_ - s * (theta0_ - theta_m)), np.cos(front)], axis=-1) - cos_theta0,
                      soil, wheel)  # fmt: skip
    tau = soil_shear_stress(sigma, shear_displacement(angles, theta0_, slip_, wheel), soil)
    cos_a, sin_a = np.cos(angles), np.sin(angles)
    # Simpson weight of each node times the length of its region.
    dtheta = np.concatenate([weights * theta_m, weights * (theta0_ - theta_m)], axis=-1)
    br = wheel.width * wheel.radius
    load = br * np.sum(dtheta * (sigma * cos_a + tau * sin_a), axis=-1)
    drawbar_pull = br * np.sum(dtheta * (tau * cos_a - sigma * sin_a), axis=-1)
    resistive_torque = br * wheel.radius * np.sum(dtheta * tau, axis=-1)
    return load, drawbar_pull, resistive_torque


def _as_slip(slip: ArrayLike, *, allow_skid: bool) -> Array:
    slip_ = np.asarray(slip, dtype=float)
    low = -1.0 if allow_skid else 0.0
    if not np.all(np.isfinite(slip_) & (slip_ >= low) & (slip_ <= 1.0)):
        bad = slip_[~(np.isfinite(slip_) & (slip_ >= low) & (slip_ <= 1.0))]
        raise ValueError(f"slip must be finite and in [{low:g}, 1], got e.g. {bad.flat[0]}")
    return slip_


def _as_contact_angle(contact_angle: ArrayLike) -> Array:
    theta0 = np.asarray(contact_angle, dtype=float)
    if not np.all(np.isfinite(theta0) & (theta0 >= 0.0) & (theta0 <= _HALF_PI)):
        raise ValueError("contact angle must be finite and in [0, π/2] rad")
    return theta0


def normal_load(
    contact_angle: ArrayLike,
    slip: ArrayLike,
    soil: WongReeceSoil = TABLE_II_SOIL,
    wheel: RigidWheel = KAPVIK_WHEEL,
    *,
    simpson_points: int = DEFAULT_SIMPSON_POINTS,
) -> Array:
    """Normal load W (N) the wheel carries at contact angle θ0 and slip 0 ≤ i ≤ 1, [RB] eq. 7."""
    theta0, slip_ = np.broadcast_arrays(_as_contact_angle(contact_angle), _as_slip(slip, allow_skid=False))
    return _rim_integrals(theta0, slip_, soil, wheel, simpson_points)[0]


def drawbar_pull_and_resistive_torque(
    contact_angle: ArrayLike,
    slip: ArrayLike,
    soil: WongReeceSoil = TABLE_II_SOIL,
    wheel: RigidWheel = KAPVIK_WHEEL,
    *,
    simpson_points: int = DEFAULT_SIMPSON_POINTS,
) -> tuple[Array, Array]:
    """DP (N) and τ_R (N·m) at contact angle θ0 and slip 0 ≤ i ≤ 1, [RB] eqs. 8–9."""
    theta0, slip_ = np.broadcast_arrays(_as_contact_angle(contact_angle), _as_slip(slip, allow_skid=False))
    _, drawbar_pull, resistive_torque = _rim_integrals(theta0, slip_, soil, wheel, simpson_points)
    return drawbar_pull, resistive_torque


def wheel_load_capacity(
    slip: ArrayLike,
    soil: WongReeceSoil = TABLE_II_SOIL,
    wheel: RigidWheel = KAPVIK_WHEEL,
    *,
    simpson_points: int = DEFAULT_SIMPSON_POINTS,
) -> Array:
    """Load (N) carried at θ0 = π/2 (sunk to the axle): the limit of :func:`contact_angle`.

    W(θ0) increases monotonically on (0, π/2] for Table II's soil (tested),
    so this is the largest load eq. 7 has a root for.
    """
    slip_ = _as_slip(slip, allow_skid=False)
    return _rim_integrals(np.full(slip_.shape, _HALF_PI), slip_, soil, wheel, simpson_points)[0]


# ---------------------------------------------------------------------------
# Contact angle (eq. 7 inverted) and Algorithm 1
# ---------------------------------------------------------------------------


def contact_angle(
    load: ArrayLike,
    slip: ArrayLike,
    soil: WongReeceSoil = TABLE_II_SOIL,
    wheel: RigidWheel = KAPVIK_WHEEL,
    *,
    simpson_points: int = DEFAULT_SIMPSON_POINTS,
    overload: Literal["raise", "saturate", "nan"] = "raise",
    scan_points: int = 48,
    load_rtol: float = 1e-12,
    angle_tol: float = 1e-14,
    max_iterations: int = 100,
) -> Array:
    """Smallest contact angle θ0 ∈ [0, π/2] carrying ``load`` at ``slip`` (rad), [RB] eq. 7, Algorithm 1 step 3.

    Vectorised over the broadcast (W, i) pairs. W(θ0, i) is first tabulated on
    ``scan_points`` uniform intervals of [0, π/2] for each distinct slip; the
    first interval whose upper end reaches the load brackets the smallest root,
    which a vectorised Illinois iteration then refines. A root closer to 0 than
    one scan interval that W crosses twice inside that interval would be missed;
    for Table II's soil W is monotone in θ0 (tested).

    Args:
        load: W ≥ 0 (N); W = 0 gives θ0 = 0.
        slip: 0 ≤ i ≤ 1 (skid is handled by :func:`wheel_forces`).
        soil, wheel: model parameters.
        simpson_points: Simpson nodes per flow region (odd, ≥ 3).
        overload: what to do with a load above :func:`wheel_load_capacity`
            (no root with θ0 ≤ π/2): ``"raise"`` a :class:`WheelOverloadError`,
            ``"saturate"`` at θ0 = π/2 (the wheel then carries less than the
            load), or return ``"nan"``.
        scan_points: intervals of the bracketing scan.
        load_rtol: converged when |W(θ0) − load| ≤ load_rtol · load ...
        angle_tol: ... or when the bracket is narrower than this (rad).
        max_iterations: Illinois iterations before giving up.

    Raises:
        WheelOverloadError: a load is above capacity and ``overload="raise"``.
        ContactAngleConvergenceError: the iteration did not converge.
    """
    load_, slip_ = np.broadcast_arrays(np.asarray(load, dtype=float), _as_slip(slip, allow_skid=False))
    if not np.all(np.isfinite(load_) & (load_ >= 0.0)):
        raise ValueError("load must be finite and ≥ 0 N")
    if overload not in ("raise", "saturate", "nan"):
        raise ValueError(f"overload must be 'raise', 'saturate' or 'nan', got {overload!r}")
    shape = load_.shape
    loads = load_.ravel()
    slips = slip_.ravel()

    # Bracketing scan, once per distinct slip (a 100×100 grid has 100).
    distinct_slips, which = np.unique(slips, return_inverse=True)
    scan_angles = np.linspace(0.0, _HALF_PI, scan_points + 1)
    scan_theta, scan_slip = np.meshgrid(scan_angles, distinct_slips)
    scan_load = _rim_integrals(scan_theta, scan_slip, soil, wheel, simpson_points)[0]
    reached = scan_load[which] >= loads[:, None]
    reached[:, 0] = loads == 0.0  # W(0) = 0 exactly; only a zero load has the root θ0 = 0.
    has_root = reached.any(axis=1)
    upper = np.argmax(reached, axis=1)

    result = np.full(loads.shape, np.nan)
    if not np.all(has_root):
        capacity = scan_load[which[~has_root], -1]
        if overload == "raise":
            worst = int(np.argmax(loads[~has_root] - capacity))
            raise WheelOverloadError(
                f"{int(np.sum(~has_root))} load(s) exceed the capacity at θ0 = π/2, e.g. W = "
                f"{loads[~has_root][worst]:.6g} N > {capacity[worst]:.6g} N at i = {slips[~has_root][worst]:.6g}"
            )
        if overload == "saturate":
            result[~has_root] = _HALF_PI
    result[has_root & (upper == 0)] = 0.0

    active = np.flatnonzero(has_root & (upper > 0))
    rows = which[active]
    hi_index = upper[active]
    lo = scan_angles[hi_index - 1]
    hi = scan_angles[hi_index]
    target = loads[active]
    f_lo = scan_load[rows, hi_index - 1] - target  # < 0
    f_hi = scan_load[rows, hi_index] - target  # ≥ 0
    # A scan node that carries the load exactly is already the root.
    exact = f_hi == 0.0
    result[active[exact]] = hi[exact]
    keep = ~exact
    active, lo, hi, f_lo, f_hi, target = active[keep], lo[keep], hi[keep], f_lo[keep], f_hi[keep], target[keep]
    last_side = np.zeros(active.shape, dtype=np.int8)  # −1: lo moved last, +1: hi moved last

    for _ in range(max_iterations):
        if active.size == 0:
            break
        # Illinois: regula falsi, halving the stale end's value when one end moves twice running.
        theta = hi - f_hi * (hi - lo) / (f_hi - f_lo)
        theta = np.clip(theta, lo, hi)
        residual = _rim_integrals(theta, slips[active], soil, wheel, simpson_points)[0] - target
        below = residual < 0.0
        f_hi = np.where(below & (last_side == -1), 0.5 * f_hi, f_hi)
        f_lo = np.where(~below & (last_side == 1), 0.5 * f_lo, f_lo)
        lo = np.where(below, theta, lo)
        f_lo = np.where(below, residual, f_lo)
        hi = np.where(below, hi, theta)
        f_hi = np.where(below, f_hi, residual)
        last_side = np.where(below, -1, 1).astype(np.int8)
        done = (np.abs(residual) <= load_rtol * target) | (hi - lo <= angle_tol)
        result[active[done]] = theta[done]
        keep = ~done
        active, lo, hi, f_lo, f_hi = active[keep], lo[keep], hi[keep], f_lo[keep], f_hi[keep]
        target, last_side = target[keep], last_side[keep]
    if active.size:
        raise ContactAngleConvergenceError(
            f"contact angle did not converge in {max_iterations} iterations for {active.size} (W, i) pair(s), "
            f"e.g. W = {loads[active[0]]:.6g} N, i = {slips[active[0]]:.6g}, bracket [{lo[0]:.17g}, {hi[0]:.17g}] rad"
        )
    return result.reshape(shape)


def wheel_forces(
    load: ArrayLike,
    slip: ArrayLike,
    soil: WongReeceSoil = TABLE_II_SOIL,
    wheel: RigidWheel = KAPVIK_WHEEL,
    *,
    simpson_points: int = DEFAULT_SIMPSON_POINTS,
    overload: Literal["raise", "saturate", "nan"] = "raise",
) -> WheelForces:
    """DP, τ_R and θ0 of a wheel carrying ``load`` at slip/skid −1 ≤ i ≤ 1, [RB] Algorithm 1 steps 2–5.

    Slip (i ≥ 0): θ0 from eq. 7, then eqs. 8–9. Skid (i < 0): eqs. 10–11 from
    the values at −i and at 0 under the same load. Vectorised over the
    broadcast (W, i) pairs; see :func:`contact_angle` for ``overload``.
    """
    load_, slip_ = np.broadcast_arrays(np.asarray(load, dtype=float), _as_slip(slip, allow_skid=True))
    shape = load_.shape
    loads, slips = load_.ravel(), slip_.ravel()
    skid = slips < 0.0
    # One solve for the mirrored slips |i| and, for the skidding wheels, i = 0 (eqs. 10–11).
    all_loads = np.concatenate([loads, loads[skid]])
    all_slips = np.concatenate([np.abs(slips), np.zeros(int(skid.sum()))])
    theta0 = contact_angle(all_loads, all_slips, soil, wheel, simpson_points=simpson_points, overload=overload)
    _, drawbar_pull, resistive_torque = _rim_integrals(theta0, all_slips, soil, wheel, simpson_points)
    n = loads.size
    dp, tau = drawbar_pull[:n].copy(), resistive_torque[:n].copy()
    dp[skid] = -dp[skid] + 2.0 * drawbar_pull[n:]  # eq. 10
    tau[skid] = -tau[skid] + 2.0 * resistive_torque[n:]  # eq. 11
    return WheelForces(dp.reshape(shape), tau.reshape(shape), theta0[:n].reshape(shape))


def wheel_forces_from_motion(
    load: ArrayLike,
    wheel_speed: ArrayLike,
    forward_velocity: ArrayLike,
    soil: WongReeceSoil = TABLE_II_SOIL,
    wheel: RigidWheel = KAPVIK_WHEEL,
    *,
    simpson_points: int = DEFAULT_SIMPSON_POINTS,
    overload: Literal["raise", "saturate", "nan"] = "raise",
) -> WheelForces:
    """[RB] Algorithm 1 from W, ω and v: slip by eqs. 1–2, then :func:`wheel_forces`.

    Only −1 ≤ i ≤ 1 is modelled, i.e. ω and v of the same sign (or zero).
    """
    slip = slip_ratio(wheel_speed, wheel.radius, forward_velocity)
    return wheel_forces(load, slip, soil, wheel, simpson_points=simpson_points, overload=overload)
