"""Tire force laws of the skid-steer truth plant: Pacejka's magic formula (the truth) and the brush (idealised).

The observer of [SS] (MODELS.md B.4, B.7) uses an isotropic brush tire with a
parabolic pressure distribution. A plant that runs the same law tests the
filter against its own model (DESIGN.md: "the truth is not the observer"), so
the plant's tire is its own: a semi-empirical *magic formula* (MF) tire with
load-dependent stiffness and friction and combined slip through normalised
slips. The brush law stays available as the plant option ``"brush"`` (the
paper's idealised setting, and the sim-to-real catalogue's nominal model); it
is implemented here, with the observer's arithmetic, so the plant imports no
force law from the observer.

Magic formula (Pacejka, *Tire and Vehicle Dynamics*, 3rd ed. 2012, §4.3.2,
pure-slip equations of MF 5.2/6.1 without shifts, camber or turn slip)::

    F_0(s) = D sin(C atan(B s − E (B s − atan(B s))))        (pure slip, s = κ or s_y)
    D   = μ(F_z) F_z,     μ(F_z) = μ (1 + p_D2 df_z),     df_z = (F_z − F_z0)/F_z0
    K_x = K_x0 (F_z/F_z0) exp(p_Kx3 df_z)                       (longitudinal slip stiffness)
    C_α = c_1 sin(2 atan(F_z / (p_Ky2 F_z0))),  c_1 = C_α0 / sin(2 atan(1/p_Ky2))
    B_x = K_x / (C_x D),   B_y = C_α / (C_y D)

so that at the nominal load F_z0 the small-slip stiffnesses are exactly the
datasheet values K_x0 = C_x and C_α0 = C_α of :class:`SkidSteerParams` (a real
tire matched to its datasheet), while away from it the cornering stiffness is
degressive (maximal at F_z = p_Ky2 F_z0), the longitudinal stiffness grows
slightly faster than the load and the friction coefficient falls with load.

Slips (practical slips, SAE J670 / ISO 8855; contact-point velocities v_x, v_y
of eqs. 3, 5 and the tread speed R ω)::

    V = max(|v_x|, V_low),   κ = (R ω − v_x)/V,   s_y = −v_y/V = −tan α

F_x has the sign of κ, F_y the sign of s_y. ``V_low`` keeps the slips finite
at standstill (where an MF tire is not defined; the plant's tire relaxation
then carries the low-speed behaviour).

Combined slip (normalised slips, Bakker, Nyborg & Pacejka, SAE 870421, 1987;
the "similarity" idea of Pacejka 2012 §4.3.1): with the pure-slip peak slips
κ_p = u_x/B_x and s_p = u_y/B_y, where u solves ``(1 − E) u + E atan(u) =
tan(π/(2C))`` (the argument at which C atan(·) = π/2),::

    n_x = κ/κ_p,  n_y = s_y/s_p,  ρ = √(n_x² + n_y²)
    F_x = F_x0(ρ κ_p) n_x/ρ,   F_y = F_y0(ρ s_p) n_y/ρ

i.e. both pure curves are read at the same fraction ρ of their peak slip. Pure
slip gives the pure curves exactly, small slips give ``F_x = K_x κ``,
``F_y = C_α s_y`` independently, both components peak together at ρ = 1 and the
resultant never exceeds μ(F_z) F_z. Past the peak the forces fall, shaped by E
(with the defaults 0.89 D at κ = 1, a wheel turning at twice the ground speed,
and 0.96 D at α = 30°). The curves are read up to ``ρ_max`` (default 4: κ ≈ 1.5,
α ≈ 43° at the nominal load) and held beyond: a fit holds only within its
measured slip range (|κ| ≤ 1.5 for the sample below), and the formula's
asymptote ``D sin(Cπ/2)`` (0.56 D for C_x = 1.62) is far below the sliding
friction of real tires (0.75–0.9 of the peak, Wong 2008 Table 1.3); held at
ρ_max the sliding forces are 0.82 D and 0.93 D. The direction stays that of the
normalised slip, so a wheel spinning at standstill pushes along its axis.

Default shape (:class:`MagicFormulaTire`): the values of a published MF fit of
a heavy radial tire (MSC PAC2002 sample property file of a 315/80 R22.5 truck
tire: p_Cx1 = 1.62, p_Ex1 = 0.5, p_Kx3 = 0.171, p_Cy1 = 1.29, p_Ey1 = −1.07,
p_Ky2 = 1.72; its friction falls by 5 % (x) and 20 % (y) per unit df_z, here
one isotropic 10 %). With the [SS] stiffnesses (C_x = 31.3 kN, C_α = 40.2
kN/rad at F_z0 = m g/6 = 4.9 kN, μ = 0.8) the peaks sit at κ_p = 0.37 and
α_p = 13°: a soft off-road tire, where the brush law saturates at σ = 0.38
and 16° and then stays flat.

Units: N, m, m/s, rad; slips dimensionless.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.checks import check_fields
from terrain_estimation.jit import compiled

__all__ = [
    "TIRE_LAWS",
    "MagicFormulaTire",
    "brush_forces",
    "magic_formula_forces",
    "magic_formula_slips",
    "peak_argument",
]

Array = NDArray[np.float64]

TIRE_LAWS: tuple[str, ...] = ("magic_formula", "brush")
"""Tire laws of the plant: the independent truth (``magic_formula``) and the observer's idealisation (``brush``)."""

# Layout of the coefficient vector of the compiled kernels.
_FZ0, _KX0, _CA_MAX, _FZ_CA_PEAK, _PKX3, _PD2, _CX, _EX, _UX, _CY, _EY, _UY, _VLOW, _RHO_MAX = range(14)
_N_COEFFS = 14
#: Smallest normalised combined slip ρ evaluated through the curves; below it the linear limit (error O(ρ²)).
_RHO_LINEAR = 1e-9
#: Lowest friction factor 1 + p_D2 df_z (keeps μ(F_z) positive at any load).
_MIN_FRICTION_FACTOR = 0.1


def peak_argument(shape: float, curvature: float) -> float:
    """u = B s at the peak of ``sin(C atan(u − E (u − atan u)))``: the root of ``(1 − E) u + E atan u = tan(π/2C)``.

    The left side increases strictly for E < 1, so bisection finds the one root.

    Args:
        shape: C, in (1, 2).
        curvature: E, < 1.
    """
    if not (math.isfinite(shape) and 1.0 < shape < 2.0):
        raise ValueError(f"magic-formula shape factor C must be in (1, 2), got {shape}")
    if not (math.isfinite(curvature) and curvature < 1.0):
        raise ValueError(f"magic-formula curvature factor E must be finite and < 1, got {curvature}")
    target = math.tan(0.5 * math.pi / shape)
    low, high = 0.0, 1.0
    while (1.0 - curvature) * high + curvature * math.atan(high) < target:
        high *= 2.0
    for _ in range(200):
        mid = 0.5 * (low + high)
        if (1.0 - curvature) * mid + curvature * math.atan(mid) < target:
            low = mid
        else:
            high = mid
        if high - low <= 1e-15 * high:
            break
    return 0.5 * (low + high)


@dataclass(frozen=True, kw_only=True)
class MagicFormulaTire:
    """Shape, load sensitivity and low-speed floor of the plant's magic-formula tire.

    The stiffnesses at the nominal load and the friction coefficient are not
    here: they come from the vehicle (:class:`SkidSteerParams` C_x, C_α, μ, with
    the effects' changes) and from the ground surface under each wheel.

    Attributes:
        shape_longitudinal: C_x of F_x0 (p_Cx1), in (1, 2).
        curvature_longitudinal: E_x of F_x0 (p_Ex1), < 1.
        shape_lateral: C_y of F_y0 (p_Cy1), in (1, 2).
        curvature_lateral: E_y of F_y0 (p_Ey1), < 1.
        cornering_stiffness_peak_load: p_Ky2, the load at which C_α(F_z) is
            largest, in units of the nominal load (> 0).
        longitudinal_stiffness_load_exponent: p_Kx3 of
            ``K_x = K_x0 (F_z/F_z0) exp(p_Kx3 df_z)`` (dimensionless).
        friction_load_sensitivity: p_D2 of ``μ(F_z) = μ (1 + p_D2 df_z)``, in
            (−1, 1); negative: friction falls with load.
        low_speed: V_low, floor of the slip denominator (m/s, > 0).
        slip_range: ρ_max, the largest combined slip read from the curves, in
            units of the peak slip (> 1); the force is held beyond it.
    """

    shape_longitudinal: float = 1.62
    curvature_longitudinal: float = 0.5
    shape_lateral: float = 1.29
    curvature_lateral: float = -1.07
    cornering_stiffness_peak_load: float = 1.72
    longitudinal_stiffness_load_exponent: float = 0.171
    friction_load_sensitivity: float = -0.1
    low_speed: float = 0.1
    slip_range: float = 4.0

    def __post_init__(self) -> None:
        owner = "MagicFormulaTire"
        for name in ("shape_longitudinal", "shape_lateral"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 1.0 < value < 2.0):
                raise ValueError(f"{owner}.{name} must be in (1, 2), got {value}")
        for name in ("curvature_longitudinal", "curvature_lateral"):
            value = getattr(self, name)
            if not (math.isfinite(value) and -10.0 < value < 1.0):
                raise ValueError(f"{owner}.{name} must be in (−10, 1), got {value}")
        check_fields(self, ("cornering_stiffness_peak_load", "low_speed"))
        exponent = self.longitudinal_stiffness_load_exponent
        if not (math.isfinite(exponent) and abs(exponent) <= 5.0):
            raise ValueError(f"{owner}.longitudinal_stiffness_load_exponent must be in [−5, 5], got {exponent}")
        if not (math.isfinite(self.slip_range) and self.slip_range > 1.0):
            raise ValueError(f"{owner}.slip_range must be finite and > 1, got {self.slip_range}")
        sensitivity = self.friction_load_sensitivity
        if not (math.isfinite(sensitivity) and -1.0 < sensitivity < 1.0):
            raise ValueError(f"{owner}.friction_load_sensitivity must be in (−1, 1), got {sensitivity}")

    def coefficients(self, nominal_load: float, longitudinal_stiffness: float, cornering_stiffness: float) -> Array:
        """Coefficient vector of the compiled kernels for one tire (internal layout).

        Args:
            nominal_load: F_z0 (N) at which the stiffnesses hold.
            longitudinal_stiffness: K_x0 (N per unit κ) at F_z0.
            cornering_stiffness: C_α0 (N/rad) at F_z0.
        """
        for name, value in (
            ("nominal_load", nominal_load),
            ("longitudinal_stiffness", longitudinal_stiffness),
            ("cornering_stiffness", cornering_stiffness),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"MagicFormulaTire.coefficients: {name} must be finite and > 0, got {value}")
        peak = self.cornering_stiffness_peak_load
        c = np.empty(_N_COEFFS)
        c[_FZ0] = nominal_load
        c[_KX0] = longitudinal_stiffness
        c[_CA_MAX] = cornering_stiffness / math.sin(2.0 * math.atan(1.0 / peak))
        c[_FZ_CA_PEAK] = peak * nominal_load
        c[_PKX3] = self.longitudinal_stiffness_load_exponent
        c[_PD2] = self.friction_load_sensitivity
        c[_CX] = self.shape_longitudinal
        c[_EX] = self.curvature_longitudinal
        c[_UX] = peak_argument(self.shape_longitudinal, self.curvature_longitudinal)
        c[_CY] = self.shape_lateral
        c[_EY] = self.curvature_lateral
        c[_UY] = peak_argument(self.shape_lateral, self.curvature_lateral)
        c[_VLOW] = self.low_speed
        c[_RHO_MAX] = self.slip_range
        return c

    def longitudinal_stiffness_at(self, normal_load: Any, nominal_load: float, longitudinal_stiffness: float) -> Array:
        """K_x(F_z) = K_x0 (F_z/F_z0) exp(p_Kx3 df_z) (N per unit κ); 0 for F_z ≤ 0."""
        fz = np.maximum(np.asarray(normal_load, dtype=float), 0.0)
        dfz = (fz - nominal_load) / nominal_load
        return longitudinal_stiffness * (fz / nominal_load) * np.exp(self.longitudinal_stiffness_load_exponent * dfz)

    def cornering_stiffness_at(self, normal_load: Any, nominal_load: float, cornering_stiffness: float) -> Array:
        """C_α(F_z) = c_1 sin(2 atan(F_z/(p_Ky2 F_z0))) (N/rad), equal to C_α0 at F_z0; 0 for F_z ≤ 0."""
        fz = np.maximum(np.asarray(normal_load, dtype=float), 0.0)
        peak = self.cornering_stiffness_peak_load
        c1 = cornering_stiffness / math.sin(2.0 * math.atan(1.0 / peak))
        return c1 * np.sin(2.0 * np.arctan(fz / (peak * nominal_load)))

    def friction_at(self, normal_load: Any, nominal_load: float, friction: Any) -> Array:
        """μ(F_z) = μ max(1 + p_D2 df_z, 0.1): the peak friction coefficient at the load."""
        dfz = (np.asarray(normal_load, dtype=float) - nominal_load) / nominal_load
        return np.asarray(friction, dtype=float) * np.maximum(
            1.0 + self.friction_load_sensitivity * dfz, _MIN_FRICTION_FACTOR
        )

    def max_stiffnesses(
        self, nominal_load: float, longitudinal_stiffness: float, cornering_stiffness: float, max_load: float
    ) -> tuple[float, float]:
        """Bounds of K_x and C_α for loads up to ``max_load`` (N): for the plant's stiff-step bound."""
        kx = float(self.longitudinal_stiffness_at(max_load, nominal_load, longitudinal_stiffness))
        peak = self.cornering_stiffness_peak_load
        ca = float(self.cornering_stiffness_at(min(max_load, peak * nominal_load), nominal_load, cornering_stiffness))
        return max(kx, longitudinal_stiffness), max(ca, cornering_stiffness)


@compiled
def _mf_wheel(kappa: float, slip_y: float, fz: float, mu: float, scale: float, c: Any) -> tuple[float, float]:
    """Magic-formula forces (F_x, F_y) of one wheel (N) from κ and s_y (module docstring)."""
    if fz <= 0.0 or mu <= 0.0 or scale <= 0.0:
        return 0.0, 0.0
    fz0 = c[_FZ0]
    dfz = (fz - fz0) / fz0
    factor = 1.0 + c[_PD2] * dfz
    if factor < _MIN_FRICTION_FACTOR:
        factor = _MIN_FRICTION_FACTOR
    d = mu * factor * fz
    kx = scale * c[_KX0] * (fz / fz0) * math.exp(c[_PKX3] * dfz)
    ca = scale * c[_CA_MAX] * math.sin(2.0 * math.atan(fz / c[_FZ_CA_PEAK]))
    kappa_peak = c[_UX] * c[_CX] * d / kx
    slip_peak = c[_UY] * c[_CY] * d / ca
    nx = kappa / kappa_peak
    ny = slip_y / slip_peak
    rho = math.sqrt(nx * nx + ny * ny)
    if rho < _RHO_LINEAR:
        return kx * kappa, ca * slip_y
    read = rho if rho < c[_RHO_MAX] else c[_RHO_MAX]
    sx = read * c[_UX]
    fx0 = d * math.sin(c[_CX] * math.atan(sx - c[_EX] * (sx - math.atan(sx))))
    sy = read * c[_UY]
    fy0 = d * math.sin(c[_CY] * math.atan(sy - c[_EY] * (sy - math.atan(sy))))
    return fx0 * nx / rho, fy0 * ny / rho


@compiled
def _mf_from_slips(kappa, slip_y, fz, mu, scale, c, out_x, out_y):
    """Flat arrays of equal length: forces from slips (the vectorised public function's kernel)."""
    for i in range(kappa.shape[0]):
        out_x[i], out_y[i] = _mf_wheel(kappa[i], slip_y[i], fz[i], mu[i], scale[i], c)


@compiled
def _mf_from_velocities(rolling, vx, vy, fz, mu, scale, c, out_x, out_y):
    """The plant's call: slips from tread speed R ω and contact velocities, then forces, per wheel."""
    v_low = c[_VLOW]
    for i in range(rolling.shape[0]):
        speed = abs(vx[i])
        if speed < v_low:
            speed = v_low
        out_x[i], out_y[i] = _mf_wheel((rolling[i] - vx[i]) / speed, -vy[i] / speed, fz[i], mu[i], scale[i], c)


def magic_formula_slips(rolling_speed: Any, v_x: Any, v_y: Any, low_speed: float) -> tuple[Array, Array]:
    """Practical slips (κ, s_y) = ((R ω − v_x)/V, −v_y/V), V = max(|v_x|, V_low); inputs broadcast (m/s)."""
    v = np.maximum(np.abs(np.asarray(v_x, dtype=float)), low_speed)
    return (np.asarray(rolling_speed, dtype=float) - np.asarray(v_x, dtype=float)) / v, -np.asarray(
        v_y, dtype=float
    ) / v


def magic_formula_forces(
    kappa: Any,
    slip_y: Any,
    normal_load: Any,
    *,
    tire: MagicFormulaTire,
    nominal_load: float,
    longitudinal_stiffness: float,
    cornering_stiffness: float,
    friction: Any,
    stiffness_scale: Any = 1.0,
) -> tuple[Array, Array]:
    """Combined-slip magic-formula forces (module docstring); all array arguments broadcast.

    Args:
        kappa: longitudinal slip κ (positive in traction).
        slip_y: lateral slip s_y = −tan α (positive where F_y is).
        normal_load: F_z (N); F_z ≤ 0 gives no force.
        tire: shape and load sensitivity.
        nominal_load: F_z0 (N).
        longitudinal_stiffness, cornering_stiffness: K_x0 (N), C_α0 (N/rad) at F_z0.
        friction: μ of the surface (peak, at F_z0).
        stiffness_scale: factor on K_x and C_α (the surface's).

    Returns:
        ``(F_x, F_y)`` in N, the broadcast shape.
    """
    c = tire.coefficients(nominal_load, longitudinal_stiffness, cornering_stiffness)
    arrays = np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (kappa, slip_y, normal_load, friction, stiffness_scale))
    )
    shape = arrays[0].shape
    flat = [np.ascontiguousarray(a.reshape(-1)) for a in arrays]
    out_x, out_y = np.empty(flat[0].size), np.empty(flat[0].size)
    _mf_from_slips(*flat, c, out_x, out_y)
    return out_x.reshape(shape), out_y.reshape(shape)


def brush_forces(
    sigma_x: Any,
    sigma_y: Any,
    normal_load: Any,
    *,
    longitudinal_stiffness: Any,
    cornering_stiffness: Any,
    friction: Any,
) -> tuple[Array, Array]:
    """The paper's brush tire (MODELS.md B.4): combined theoretical slip, parabolic pressure, one μ.

    ::

        γ = √((C_x σ_x)² + (C_α σ_y)²),   t = min(γ, 3 μ F_z)/(3 μ F_z)
        F = μ F_z t (3 − 3t + t²),   F_x = (C_x σ_x/γ) F,   F_y = (C_α σ_y/γ) F

    (Pacejka 2012 ch. 3; Svendenius 2007). The plant's own implementation,
    with the observer's arithmetic (``terrain_estimation.models.skid_steer.
    brush_tire_forces``) so the ``"brush"`` option reproduces the idealised
    plant bit for bit. All arguments broadcast; ``F_z ≤ 0`` gives no force.
    """
    cx_sx = np.asarray(longitudinal_stiffness, dtype=float) * np.asarray(sigma_x, dtype=float)
    ca_sy = np.asarray(cornering_stiffness, dtype=float) * np.asarray(sigma_y, dtype=float)
    fz = np.maximum(np.asarray(normal_load, dtype=float), 0.0)
    mu_fz = np.asarray(friction, dtype=float) * fz
    gamma = np.hypot(cx_sx, ca_sy)
    limit = 3.0 * mu_fz
    t = np.minimum(gamma, limit) / np.where(limit > 0.0, limit, 1.0)
    force = mu_fz * t * (3.0 - 3.0 * t + t * t)
    scale = np.divide(force, gamma, out=np.zeros(np.broadcast(force, gamma).shape), where=gamma > 0.0)
    return cx_sx * scale, ca_sy * scale


class MagicFormulaWheels:
    """The plant's per-evaluation call of the magic formula on its wheels (preallocated, compiled).

    Args:
        tire: shape and load sensitivity.
        nominal_load: F_z0 (N).
        longitudinal_stiffness, cornering_stiffness: K_x0 (N), C_α0 (N/rad) at F_z0.
        n_wheels: number of wheels.
    """

    def __init__(
        self,
        tire: MagicFormulaTire,
        nominal_load: float,
        longitudinal_stiffness: float,
        cornering_stiffness: float,
        n_wheels: int,
    ) -> None:
        self.tire = tire
        self.coefficients = tire.coefficients(nominal_load, longitudinal_stiffness, cornering_stiffness)
        self._ones = np.ones(n_wheels)
        self._n = n_wheels

    def forces(
        self, rolling_speed: Array, v_x: Array, v_y: Array, normal_load: Array, friction: Any, stiffness_scale: Any
    ) -> tuple[Array, Array]:
        """(F_x, F_y) per wheel (N) from tread speeds R ω, contact velocities (m/s), loads (N), μ and scale."""
        mu = friction if isinstance(friction, np.ndarray) else friction * self._ones
        scale = stiffness_scale if isinstance(stiffness_scale, np.ndarray) else stiffness_scale * self._ones
        out_x, out_y = np.empty(self._n), np.empty(self._n)
        _mf_from_velocities(rolling_speed, v_x, v_y, normal_load, mu, scale, self.coefficients, out_x, out_y)
        return out_x, out_y
