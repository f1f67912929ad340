"""The Wong–Reece wheel of the single-wheel rig check: steady-state drawbar pull and sinkage.

The project's rigid-wheel model ([RB] eqs. 3–11, the discretisation of :mod:`vehicle_sim.terrain.wong_reece`) with
the rig's effects built in (slip-dependent exponent, rear contact, skid stresses, grousers, bulldozing), compiled.
Units SI (m, rad, Pa, N).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.jit import compiled

__all__ = [
    "NOMINAL",
    "RIG_WHEEL",
    "RIG_WHEEL_RADIUS",
    "RIG_WHEEL_WIDTH",
    "WheelGeometry",
    "WheelSoil",
    "bearing_capacity_factors",
    "bulldozing_resistance",
    "rim_stresses",
    "steady_state",
    "tip_slip",
]

FloatArray = NDArray[np.float64]

RIG_WHEEL_RADIUS = 0.058
"""Rig wheel radius r (m)."""
RIG_WHEEL_WIDTH = 0.05
"""Rig wheel width b (m)."""
RIG_SOIL_UNIT_WEIGHT = 13.0e3
"""Specific weight γ of the rig's soil (N/m³; the authors' 13.0 kN/m³)."""

_SIMPSON_POINTS = 9  # = vehicle_sim.terrain.wong_reece.DEFAULT_SIMPSON_POINTS (tested equal)
_SCAN_POINTS = 48


@dataclass(frozen=True)
class WheelSoil:
    """Wheel, soil and effect parameters of one evaluation (all scalars; SI).

    Attributes:
        k_c, k_phi: Bekker moduli (N/m^(n+1), N/m^(n+2)); σ = (k_c/b + k_φ) z^n.
        n: Sinkage exponent at zero slip (–).
        n_slip, n_skid: Slip dependence of n: n + n_slip i (i ≥ 0), n + n_skid |i| (i < 0).
        cohesion: c (Pa).
        friction_angle: φ (rad).
        shear_modulus: K (m).
        c1, c2: θ_m = θ0 (c1 + c2 i).
        rear_ratio: λ of the exit angle θ_r = −λ θ0.
        slip_sinkage: c of k_eff = k/(1 + c|i|) (rover plant's implementation).
        skid_stresses: evaluate the stresses at the skid itself instead of eqs. 10–11.
        radius, width: r, b (m).
        grouser_height: h_e, the effective grouser height (m): the soil is sheared
            on the cylinder through the grouser tips, r + h_e, at the tip slip
            (0: a smooth rim; :func:`tip_slip`).
        bulldozing: κ, the fraction of Wong's passive bulldozing resistance
            mobilised ahead of a skidding wheel (0: none; :func:`bulldozing_resistance`).
        unit_weight: γ, the soil's specific weight (N/m³), for the bulldozing wedge.
    """

    k_c: float = 0.0
    k_phi: float = 8.0e6
    n: float = 1.46
    n_slip: float = 0.0
    n_skid: float = 0.0
    cohesion: float = 1.0e3
    friction_angle: float = math.radians(29.0)
    shear_modulus: float = 0.021
    c1: float = 0.18
    c2: float = 0.32
    rear_ratio: float = 0.0
    slip_sinkage: float = 0.0
    skid_stresses: bool = False
    radius: float = RIG_WHEEL_RADIUS
    width: float = RIG_WHEEL_WIDTH
    grouser_height: float = 0.0
    bulldozing: float = 0.0
    unit_weight: float = RIG_SOIL_UNIT_WEIGHT


NOMINAL = WheelSoil()
"""The rig authors' soil (README values) and the rig's wheel, every effect off."""


@dataclass(frozen=True)
class WheelGeometry:
    """The rig wheel's geometry (an option of the driver: the rig has been run with other wheels).

    Attributes:
        radius: Rim radius r (m), 0.005–2.
        width: Rim width b (m), 0.005–2.
        grouser_count: Number of grousers (lugs) on the rim, 0 (smooth) to 360.
        grouser_height: Their height above the rim (m), 0 for a smooth wheel,
            otherwise > 0 and below half the radius.

    Raises:
        Sim2RealError: a value out of its range, or grousers with no height (or
            a height with no grousers), naming the option and the value.
    """

    radius: float = RIG_WHEEL_RADIUS
    width: float = RIG_WHEEL_WIDTH
    grouser_count: int = 0
    grouser_height: float = 0.0

    def __post_init__(self) -> None:
        for name in ("radius", "width"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and 0.005 <= value <= 2.0):
                raise Sim2RealError(f"wheel {name} must be in [0.005, 2] m, got {value!r}")
        count, height = self.grouser_count, self.grouser_height
        if isinstance(count, bool) or not isinstance(count, int | np.integer) or not 0 <= count <= 360:
            raise Sim2RealError(f"grouser count must be a whole number in [0, 360], got {count!r}")
        if not (isinstance(height, int | float) and math.isfinite(height) and height >= 0.0):
            raise Sim2RealError(f"grouser height must be a finite length >= 0 m, got {height!r}")
        if (count > 0) != (height > 0.0):
            raise Sim2RealError(
                f"grousers need both a count and a height: got count {count} and height {height} m "
                "(a smooth wheel has 0 and 0)"
            )
        if height >= 0.5 * self.radius:
            raise Sim2RealError(
                f"grouser height {height} m must be below half the wheel radius ({0.5 * self.radius:g} m)"
            )

    @property
    def grousered(self) -> bool:
        """True if the wheel has grousers."""
        return self.grouser_count > 0

    @property
    def grouser_spacing(self) -> float:
        """Arc length between grouser tips (m); inf for a smooth wheel."""
        if not self.grousered:
            return math.inf
        return 2.0 * math.pi * (self.radius + self.grouser_height) / self.grouser_count

    def describe(self) -> str:
        """One line for the report."""
        text = f"r = {1e3 * self.radius:g} mm, b = {1e3 * self.width:g} mm"
        if self.grousered:
            return (
                f"{text}, {self.grouser_count} grousers {1e3 * self.grouser_height:g} mm high "
                f"({1e3 * self.grouser_spacing:.0f} mm apart at the tips)"
            )
        return f"{text}, smooth"


RIG_WHEEL = WheelGeometry()
"""The smooth wheel of ``all_smooth_data.mat`` (r = 58 mm, b = 50 mm)."""


def _simpson_weights(points: int) -> FloatArray:
    w = np.ones(points)
    w[1:-1:2] = 4.0
    w[2:-1:2] = 2.0
    return w / (3.0 * (points - 1))


_WEIGHTS = _simpson_weights(_SIMPSON_POINTS)


@compiled
def _rim_row(
    theta0: float, slip: float, n: float, soil: FloatArray, weights: FloatArray
) -> tuple[float, float, float]:  # pragma: no cover - compiled (tested through steady_state)
    """(W, DP, τ_R) of [RB] eqs. 7–9 at one (θ0, i, n); exit angle −λ θ0.

    For i ≥ 0 exactly the project's model. For i < 0 (only with ``skid_stresses``)
    the stresses are evaluated at the skid itself: θ_m = c1 θ0 (Wong's slip law
    θ_m = θ0 (c1 + c2 i) is not extrapolated into skid) and τ odd in j.

    ``soil`` = (stiffness k_c/b + k_φ, c, tan φ, K, c1, c2, λ, r, b). The same
    Simpson discretisation as :mod:`vehicle_sim.terrain.wong_reece`: nodes
    s ∈ [0, 1] at θ_r + s (θ_m − θ_r) behind and θ_m + s (θ0 − θ_m) in front
    of θ_m; the rear's eq.-5 angle θ* = θ0 − s (θ0 − θ_m).
    """
    stiffness, cohesion, tan_phi, shear_k, c1, c2, rear, r, b = (
        soil[0],
        soil[1],
        soil[2],
        soil[3],
        soil[4],
        soil[5],
        soil[6],
        soil[7],
        soil[8],
    )
    points = weights.size
    tm = theta0 * (c1 + c2 * max(slip, 0.0))
    tr = -rear * theta0
    cos0 = math.cos(theta0)
    sin0 = math.sin(theta0)
    load = 0.0
    dp = 0.0
    torque = 0.0
    for region in range(2):
        for k in range(points):
            s = k / (points - 1)
            if region == 0:
                angle = tr + s * (tm - tr)
                equivalent = theta0 - s * (theta0 - tm)
                dtheta = weights[k] * (tm - tr)
            else:
                angle = tm + s * (theta0 - tm)
                equivalent = angle
                dtheta = weights[k] * (theta0 - tm)
            base = r * (math.cos(equivalent) - cos0)
            sigma = stiffness * base**n if base > 0.0 else 0.0
            j = r * ((theta0 - angle) - (1.0 - slip) * (sin0 - math.sin(angle)))
            # Janosi–Hanamoto, odd in j (j < 0 only in skid: the shear opposes the motion).
            tau = math.copysign((cohesion + sigma * tan_phi) * -math.expm1(-abs(j) / shear_k), j)
            ca = math.cos(angle)
            sa = math.sin(angle)
            load += dtheta * (sigma * ca + tau * sa)
            dp += dtheta * (tau * ca - sigma * sa)
            torque += dtheta * tau
    br = b * r
    return br * load, br * dp, br * r * torque


@compiled
def _contact_angle_row(
    load: float, slip: float, n: float, soil: FloatArray, weights: FloatArray, scan_points: int
) -> float:  # pragma: no cover - compiled (tested through steady_state)
    """Smallest θ0 ∈ [0, π/2] with W(θ0) = load (eq. 7), saturated at π/2 (overload).

    A scan of ``scan_points`` intervals brackets the first crossing, an
    Illinois iteration refines it (as :func:`vehicle_sim.terrain.wong_reece.contact_angle`).
    """
    if load <= 0.0:
        return 0.0
    h = 0.5 * math.pi / scan_points
    lo = 0.0
    f_lo = -load
    hi = 0.0
    f_hi = -load
    found = False
    for k in range(1, scan_points + 1):
        hi = k * h
        f_hi = _rim_row(hi, slip, n, soil, weights)[0] - load
        if f_hi >= 0.0:
            found = True
            break
        lo = hi
        f_lo = f_hi
    if not found:
        return 0.5 * math.pi
    if f_hi == 0.0:
        return hi
    last = 0
    theta = hi
    for _ in range(100):
        denom = f_hi - f_lo
        if denom == 0.0:
            break
        theta = min(max(hi - f_hi * (hi - lo) / denom, lo), hi)
        res = _rim_row(theta, slip, n, soil, weights)[0] - load
        if abs(res) <= 1e-12 * load or hi - lo <= 1e-14:
            return theta
        if res < 0.0:
            if last == -1:
                f_hi *= 0.5
            lo = theta
            f_lo = res
            last = -1
        else:
            if last == 1:
                f_lo *= 0.5
            hi = theta
            f_hi = res
            last = 1
    return theta


@compiled
def _steady_rows(
    load: FloatArray,
    slip: FloatArray,
    n0: float,
    n_slip: float,
    n_skid: float,
    slip_sinkage: float,
    direct_skid: bool,
    soil: FloatArray,
    weights: FloatArray,
    scan_points: int,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled (tested through steady_state)
    rows = load.size
    dp = np.empty(rows)
    theta = np.empty(rows)
    for k in range(rows):
        i = min(max(slip[k], -1.0), 1.0)
        mag = abs(i)
        scale = 1.0 + slip_sinkage * mag
        w = max(load[k], 0.0) * scale
        n = n0 + (n_skid if i < 0.0 else n_slip) * mag
        evaluated = i if direct_skid else mag
        t0 = _contact_angle_row(w, evaluated, n, soil, weights, scan_points)
        d = _rim_row(t0, evaluated, n, soil, weights)[1]
        if i < 0.0 and not direct_skid:
            t00 = _contact_angle_row(w, 0.0, n0, soil, weights, scan_points)
            d = -d + 2.0 * _rim_row(t00, 0.0, n0, soil, weights)[1]
        dp[k] = d / scale
        theta[k] = t0
    return dp, theta


def _soil_vector(p: WheelSoil) -> FloatArray:
    return np.array(
        [
            p.k_c / p.width + p.k_phi,
            p.cohesion,
            math.tan(p.friction_angle),
            p.shear_modulus,
            p.c1,
            p.c2,
            p.rear_ratio,
            p.radius,
            p.width,
        ]
    )


def steady_state(load: ArrayLike, slip: ArrayLike, p: WheelSoil = NOMINAL) -> tuple[FloatArray, FloatArray]:
    """Drawbar pull DP (N) and sinkage z (m) of the wheel at loads W (N) and slips −1 ≤ i ≤ 1.

    Slip (i ≥ 0): θ0 from eq. 7, DP from eq. 8. Skid (i < 0): DP(i) = −DP(−i) + 2 DP(0)
    (eq. 10) under the same load, z from θ0 at −i; with a slip-dependent
    exponent the mirrored state has n(i) and DP(0) has n0. Slip-sinkage
    scales the load and the forces as the rover plant does (forces at
    W (1 + c|i|), divided by 1 + c|i|). Overload saturates at θ0 = π/2.
    Inputs broadcast; outputs have their shape.
    """
    load_, slip_ = np.broadcast_arrays(np.asarray(load, dtype=float), np.asarray(slip, dtype=float))
    rim_slip = np.ascontiguousarray(slip_.ravel())
    shear = p
    if p.grouser_height > 0.0:
        # The soil between the grousers moves with the wheel: shear on the tip cylinder at the tip slip.
        shear = dataclasses.replace(p, radius=p.radius + p.grouser_height)
        rim_slip = tip_slip(rim_slip, p.radius, p.grouser_height)
    dp, theta0 = _steady_rows(
        np.ascontiguousarray(load_.ravel()),
        rim_slip,
        float(p.n),
        float(p.n_slip),
        float(p.n_skid),
        float(p.slip_sinkage),
        bool(p.skid_stresses),
        _soil_vector(shear),
        _WEIGHTS,
        _SCAN_POINTS,
    )
    sinkage = shear.radius * (1.0 - np.cos(theta0))
    if p.bulldozing > 0.0:
        dp = dp - p.bulldozing * bulldozing_resistance(sinkage, np.ascontiguousarray(slip_.ravel()), theta0, shear)
    return dp.reshape(load_.shape), sinkage.reshape(load_.shape)


def tip_slip(slip: ArrayLike, radius: float, grouser_height: float) -> FloatArray:
    """Slip of the grouser tips (radius r + h) for the rim slip i (the rig's definition, −1 ≤ i ≤ 1).

    With ρ = V_rim/V_x (1/(1 − i) in drive, 1 + i in skid) the tips move at
    ρ_t = ρ (r + h)/r, and i_t = (ρ_t − 1)/max(1, ρ_t). In drive this is the
    rover plant's i_g = 1 − (1 − i) r/(r + h).
    """
    i = np.clip(np.asarray(slip, dtype=float), -1.0, 1.0)
    with np.errstate(divide="ignore"):
        rho = np.where(i >= 0.0, 1.0 / np.maximum(1.0 - i, 1e-9), 1.0 + i)
    rho_t = rho * (radius + grouser_height) / radius
    return np.asarray((rho_t - 1.0) / np.maximum(1.0, rho_t), dtype=float)


def bearing_capacity_factors(friction_angle: float) -> tuple[float, float, float]:
    """(N_c, N_q, N_γ) of a strip footing (Prandtl–Reissner N_q, N_c; Vesić's N_γ) at friction angle φ (rad)."""
    tan_phi = math.tan(max(friction_angle, 1e-6))
    n_q = math.exp(math.pi * tan_phi) * math.tan(0.25 * math.pi + 0.5 * friction_angle) ** 2
    n_c = (n_q - 1.0) / tan_phi
    n_gamma = 2.0 * (n_q + 1.0) * tan_phi
    return n_c, n_q, n_gamma


def bulldozing_resistance(sinkage: ArrayLike, slip: ArrayLike, theta0: ArrayLike, p: WheelSoil) -> FloatArray:
    """Resistance (N, ≥ 0) of the soil wedge a skidding wheel pushes ahead, mobilised by the skid.

    Wong's bulldozing resistance of a wheel with sinkage z (Bekker's passive
    earth pressure on a vertical blade of width b; Wong, *Theory of Ground
    Vehicles*, ch. 2)::

        R_b = b (0.67 c z K_pc + 0.5 γ z² K_pγ),
        K_pc = (N_c − tan φ) cos² φ,  K_pγ = (2 N_γ / tan φ + 1) cos² φ

    (:func:`bearing_capacity_factors`). The wedge builds only when the rim
    slides *forward* over the soil, i.e. in skid (i < 0): a driven wheel
    throws the soil back. It is mobilised like the Janosi–Hanamoto shear,
    by the soil's displacement ahead of the wheel over the contact,
    j = |i| r θ0: R = R_b (1 − exp(−j/K)) for i < 0, 0 otherwise. No
    parameter is new (c, φ, γ, K are the soil's); the effect's coefficient
    κ (:attr:`WheelSoil.bulldozing`) scales R (1: the full passive wedge).
    """
    z = np.asarray(sinkage, dtype=float)
    i = np.asarray(slip, dtype=float)
    theta = np.asarray(theta0, dtype=float)
    n_c, _, n_gamma = bearing_capacity_factors(p.friction_angle)
    tan_phi = math.tan(max(p.friction_angle, 1e-6))
    cos2 = math.cos(p.friction_angle) ** 2
    k_pc = (n_c - tan_phi) * cos2
    k_pg = (2.0 * n_gamma / tan_phi + 1.0) * cos2
    full = p.width * (0.67 * p.cohesion * z * k_pc + 0.5 * p.unit_weight * z**2 * k_pg)
    mobilised = np.where(i < 0.0, -np.expm1(-np.abs(i) * p.radius * theta / p.shear_modulus), 0.0)
    return np.asarray(full * mobilised, dtype=float)


def rim_stresses(theta0: float, slip: float, n: float, p: WheelSoil) -> tuple[float, float, float]:
    """(W, DP, τ_R) of the rim's stresses at contact angle θ0, slip i and sinkage exponent n ([RB] eqs. 7–9)."""
    return _rim_row(theta0, slip, n, _soil_vector(p), _WEIGHTS)


def contact_angle_of_sinkage(sinkage: float, radius: float) -> float:
    """θ0 = acos(1 − z/r) of a sinkage z (m) below the surface (0 above it, π/2 at z ≥ r)."""
    return math.acos(min(max(1.0 - sinkage / radius, 0.0), 1.0))
