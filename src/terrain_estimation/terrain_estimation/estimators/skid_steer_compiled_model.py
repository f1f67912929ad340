"""The skid-steer brush observer models, compiled (numba): what :mod:`.skid_steer_compiled`'s filter step evaluates.

The process model ``f`` with its Euler sub-steps (:func:`_process`), the
measurement ``h`` (:func:`_measure`), the per-input terms they share (rolling
speeds, quasi-static loads, ``μ F_z``) and the unscented moments of ``h``
(:func:`_moments`, with the sigma points, means and whitening the filter step
uses), over
:class:`~terrain_estimation.models.skid_steer_observer.SkidSteerObserverModel`
(``"brush"``) and
:class:`~terrain_estimation.models.skid_steer_scales.SkidSteerTireScaleModel`
(``"brush_scales"``); and, on the Python side, the constants that describe a
model and its vehicle to the kernels (:func:`model_constants`,
:func:`_vehicle_constants`). The Python models remain the reference
(``test/test_skid_steer_compiled.py``): same forms, same order of operations.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from terrain_estimation.filters.base import Array
from terrain_estimation.filters.compiled_linalg import all_finite, cholesky_lower, mul, mul_bt, solve_lower, symmetrise
from terrain_estimation.jit import compiled

__all__ = ["ModelConstants", "Terms", "model_constants"]

#: numba's numpy error model (as :mod:`.skid_steer_compiled`'s kernels): a float division by zero gives inf or
#: NaN instead of raising; a NaN propagates to a non-finite result, which hands the step back to Python.
_kernel = compiled(error_model="numpy")

#: A step's per-input terms, as :func:`_terms` returns them: per-wheel ``R ω``, floored ``V_r``, ``μ F_z``,
#: ``3 μ F_z``, its divisor, ``F_z`` (arrays of the 2N wheels) and the slowest side's floored rolling speed.
Terms = tuple[Array, Array, Array, Array, Array, Array, float]

# Indices of the vehicle constants ``vc``.
_CX, _CA, _MASS, _IZ, _RADIUS, _FLOOR, _G, _H, _TRACK, _S1, _S2, _D, _NAX, _KAPPA_V, _GAIN, _QSTEP = range(16)
# Indices of a model's integer description ``mi``.
_PLAIN, _K, _RES, _SUBSTEPS, _MAXSUB, _ROW0 = range(6)
# Indices of a model's float description ``mf``.
_LO, _HI, _TAU, _RMAX, _RSPEED, _RNOM, _RTIME, _RSTD, _WALK = range(9)


@_kernel
def _terms(
    wl: float, wr: float, ax: float, ay: float, mu: float, vc: Array, axle_x: Array
) -> Terms:  # pragma: no cover - compiled
    """``SkidSteerObserverModel._terms`` and ``_loads``: per-wheel ``R ω``, ``V_r``, ``μ F_z``, ``3 μ F_z``,
    its divisor, ``F_z``, and the slowest side's floored rolling speed, in the Python forms' order."""
    radius = vc[_RADIUS]
    floor = vc[_FLOOR]
    rolling = max(min(abs(wl), abs(wr)) * radius, floor)
    n = axle_x.shape[0]
    m, g, h = vc[_MASS], vc[_G], vc[_H]
    s1, s2, d, nf = vc[_S1], vc[_S2], vc[_D], vc[_NAX]
    p0 = m * (g * s2 + ax * h * s1) / d
    q = -m * (nf * ax * h + g * s1) / d
    lateral = m * ay * h / (nf * vc[_TRACK])
    rl, rr = radius * wl, radius * wr
    fl, fr = max(abs(rl), floor), max(abs(rr), floor)
    roll = np.empty(2 * n)
    floored = np.empty(2 * n)
    mu_fz = np.empty(2 * n)
    limit = np.empty(2 * n)
    divisor = np.empty(2 * n)
    loads = np.empty(2 * n)
    for i in range(n):
        half = 0.5 * (p0 + q * axle_x[i])
        loads[i] = max(half - lateral, 0.0)
        loads[n + i] = max(half + lateral, 0.0)
        roll[i], roll[n + i] = rl, rr
        floored[i], floored[n + i] = fl, fr
    for w in range(2 * n):
        mu_fz[w] = mu * loads[w]
        limit[w] = 3.0 * mu_fz[w]
        divisor[w] = limit[w] if limit[w] > 0.0 else 1.0
    return roll, floored, mu_fz, limit, divisor, loads, rolling


@_kernel
def _multipliers(x: Array, mi: Array, mf: Array, out: Array) -> None:  # pragma: no cover - compiled
    """``_ScaledModelBase._multipliers`` of one point: ``out = [s_μ, s_Cα, s_Cx]`` (1 where not a state)."""
    out[0] = 1.0
    out[1] = 1.0
    out[2] = 1.0
    for j in range(mi[_K]):
        v = x[3 + j]
        lo, hi = mf[_LO], mf[_HI]
        if v < lo:  # np.clip: NaN stays NaN
            v = lo
        elif v > hi:
            v = hi
        out[mi[_ROW0 + j]] = math.exp(v)


@_kernel
def _force_sums(
    vx: float, vy: float, r: float, mult: Array, scaled: bool, terms: Terms, vc: Array, wx: Array, wy: Array
) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """``[ΣF_x, ΣF_y, M_z]`` of one point: ``scaled_force_sums`` (``scaled``) or the observer's ``_force_sums``."""
    roll, floored, mu_fz, limit, divisor, _, _ = terms
    if scaled:
        s0 = vc[_CX] * mult[2]
        s1 = -vc[_CA] * mult[1]
    else:
        s0 = vc[_CX]
        s1 = -vc[_CA]
    fx_sum = 0.0
    fy_sum = 0.0
    mz_sum = 0.0
    for w in range(wx.shape[0]):
        v0 = vx - r * wy[w]
        v1 = vy - r * -wx[w]
        v0 = roll[w] - v0
        v0 /= floored[w]
        v1 /= floored[w]
        v0 *= s0
        v1 *= s1
        gamma = math.hypot(v0, v1)
        if scaled:
            mf = mu_fz[w] * mult[0]
            lim = 3.0 * mf
            div = lim if lim > 0.0 else 1.0
        else:
            mf = mu_fz[w]
            lim = limit[w]
            div = divisor[w]
        t = lim if gamma > lim else gamma  # np.minimum (a NaN γ stays NaN)
        t /= div
        force = mf * t * (3.0 - 3.0 * t + t * t)
        scale = force / gamma if gamma > 0.0 else 0.0
        fx = v0 * scale
        fy = v1 * scale
        mz = fy * wx[w] + fx * -wy[w]
        if w == 0:
            fx_sum, fy_sum, mz_sum = fx, fy, mz
        else:
            fx_sum += fx
            fy_sum += fy
            mz_sum += mz
    return fx_sum, fy_sum, mz_sum


@_kernel
def _resistance_sums(
    vx: float, r: float, coefficient: float, speed: float, loads: Array, wy: Array
) -> tuple[float, float]:  # pragma: no cover - compiled
    """``resistance_force_sums`` of one point: ``(ΣF_x, M_z)``."""
    fx_sum = 0.0
    mz_sum = 0.0
    for w in range(wy.shape[0]):
        fx = -(coefficient * loads[w]) * math.tanh((vx - r * wy[w]) / speed)
        if w == 0:
            fx_sum, mz_sum = fx, fx * -wy[w]
        else:
            fx_sum += fx
            mz_sum += fx * -wy[w]
    return fx_sum, mz_sum


@_kernel
def _resistance_coefficient(x: Array, n: int, mf: Array) -> float:  # pragma: no cover - compiled
    """``np.clip(rows[-1], 0, resistance_max)`` of one point."""
    c = x[n - 1]
    if c < 0.0:
        c = 0.0
    elif c > mf[_RMAX]:
        c = mf[_RMAX]
    return c


@_kernel
def _process(
    X: Array, dt: float, mi: Array, mf: Array, vc: Array, wx: Array, wy: Array, terms: Terms
) -> tuple[Array, bool]:  # pragma: no cover - compiled
    """``f`` of every point (rows of ``X``): the model's Euler sub-steps, then its scale clipping.

    Returns ``(X⁺, ok)``; ``ok`` False when a step needs more than ``max_substeps`` sub-steps.
    """
    _, _, _, _, _, loads, min_rolling = terms
    m, n = X.shape
    out = X.copy()
    plain = mi[_PLAIN] == 1
    k = mi[_K]
    res = mi[_RES] == 1
    mult = np.empty((m, 3))
    stiffest = 1.0
    for i in range(m):
        _multipliers(X[i], mi, mf, mult[i])
        if k > 0:
            for j in (1, 2):
                if i == 0 and j == 1:
                    stiffest = mult[i, j]
                elif mult[i, j] > stiffest or mult[i, j] != mult[i, j]:
                    stiffest = mult[i, j]
    gain = vc[_GAIN]
    if gain != gain:  # max_euler_gain None: the fixed count
        n_sub = mi[_SUBSTEPS]
    else:
        if plain:
            rate = vc[_KAPPA_V] / min_rolling
        else:
            rate = vc[_KAPPA_V] * stiffest / min_rolling
        ratio = dt * rate / gain - 1e-9
        if not ratio <= mi[_MAXSUB]:  # too many sub-steps (or a NaN scale): the Python step raises
            return out, False
        n_sub = max(mi[_SUBSTEPS], math.ceil(ratio))
        if n_sub > mi[_MAXSUB]:
            return out, False
    delta = dt / n_sub
    mass, iz = vc[_MASS], vc[_IZ]
    for i in range(m):
        c0, c1, c2 = X[i, 0], X[i, 1], X[i, 2]
        coefficient = _resistance_coefficient(X[i], n, mf) if res else 0.0
        for _ in range(n_sub):
            fx, fy, mz = _force_sums(c0, c1, c2, mult[i], k > 0, terms, vc, wx, wy)
            if plain:
                r0 = fx / mass + c1 * c2
                r1 = fy / mass + -c0 * c2
                r2 = mz / 1.0
                r0 *= delta
                r1 *= delta
                r2 *= delta
                r2 /= iz
                c0, c1, c2 = c0 + r0, c1 + r1, c2 + r2
            else:
                if res:
                    rfx, rmz = _resistance_sums(c0, c2, coefficient, mf[_RSPEED], loads, wy)
                    fx += rfx
                    fy += 0.0
                    mz += rmz
                r0 = fx / mass
                r1 = fy / mass
                r2 = mz / 1.0
                r0 += c1 * c2
                r1 -= c0 * c2
                r2 /= iz
                c0, c1, c2 = c0 + delta * r0, c1 + delta * r1, c2 + delta * r2
        out[i, 0], out[i, 1], out[i, 2] = c0, c1, c2
        if k > 0:
            tau = mf[_TAU]
            decay = math.exp(-dt / tau) if tau > 0.0 else 1.0
            for j in range(k):
                v = out[i, 3 + j]
                if tau > 0.0:
                    v *= decay
                if v < mf[_LO]:
                    v = mf[_LO]
                elif v > mf[_HI]:
                    v = mf[_HI]
                out[i, 3 + j] = v
        if res:
            nominal = mf[_RNOM]
            v = nominal + (out[i, n - 1] - nominal) * math.exp(-dt / mf[_RTIME])
            if v < 0.0:
                v = 0.0
            elif v > mf[_RMAX]:
                v = mf[_RMAX]
            out[i, n - 1] = v
    return out, True


@_kernel
def _measure(
    X: Array, mi: Array, mf: Array, vc: Array, wx: Array, wy: Array, terms: Terms
) -> Array:  # pragma: no cover - compiled
    """``h`` of every point: ``[ΣF_x/m, ΣF_y/m, r]`` with the points' scales and resistance."""
    loads = terms[5]
    m, n = X.shape
    Z = np.empty((m, 3))
    mult = np.empty(3)
    k = mi[_K]
    res = mi[_RES] == 1
    mass = vc[_MASS]
    for i in range(m):
        _multipliers(X[i], mi, mf, mult)
        fx, fy, mz = _force_sums(X[i, 0], X[i, 1], X[i, 2], mult, k > 0, terms, vc, wx, wy)
        if res:
            coefficient = _resistance_coefficient(X[i], n, mf)
            rfx, _ = _resistance_sums(X[i, 0], X[i, 2], coefficient, mf[_RSPEED], loads, wy)
            fx += rfx
        Z[i, 0] = fx / mass
        Z[i, 1] = fy / mass
        Z[i, 2] = X[i, 2]
    return Z


@_kernel
def _points(x: Array, S: Array, unit: Array) -> Array:  # pragma: no cover - compiled
    """``x + unit Sᵀ``: the sigma points, one per row."""
    m, n = unit.shape
    X = mul_bt(unit, S)
    for i in range(m):
        for a in range(n):
            X[i, a] = x[a] + X[i, a]
    return X


@_kernel
def _mean(X: Array, Wm: Array) -> Array:  # pragma: no cover - compiled
    m, n = X.shape
    out = np.zeros(n)
    for a in range(n):
        s = 0.0
        for i in range(m):
            s += Wm[i] * X[i, a]
        out[a] = s
    return out


@_kernel
def _moments(
    x: Array,
    P: Array,
    Rdiag: Array,
    unit: Array,
    Wm: Array,
    Wc: Array,
    mi: Array,
    mf: Array,
    vc: Array,
    wx: Array,
    wy: Array,
    terms: Terms,
) -> tuple[Array, Array, Array, bool]:  # pragma: no cover - compiled
    """``UnscentedKalmanFilter._moments``: ``ẑ, P_zz, P_xz``; False where the Python step does more."""
    n = x.shape[0]
    S, ok = cholesky_lower(P)
    if not ok:
        return np.zeros(3), np.zeros((3, 3)), np.zeros((n, 3)), False
    m = unit.shape[0]
    zero = np.zeros(n)
    dX = _points(zero, S, unit)
    Xs = np.empty((m, n))
    for i in range(m):
        for a in range(n):
            Xs[i, a] = x[a] + dX[i, a]
    Z = _measure(Xs, mi, mf, vc, wx, wy, terms)
    if not all_finite(Z):
        return np.zeros(3), np.zeros((3, 3)), np.zeros((n, 3)), False
    z_hat = _mean(Z, Wm)
    p = 3
    dZw = np.empty((p, m))
    dZ = np.empty((m, p))
    for i in range(m):
        for q in range(p):
            dZ[i, q] = Z[i, q] - z_hat[q]
            dZw[q, i] = dZ[i, q] * Wc[i]
    Pzz = mul(dZw, dZ)
    for a in range(p):
        for b in range(p):
            Pzz[a, b] = Pzz[a, b] + (Rdiag[a] * Rdiag[a] if a == b else 0.0)
    Pxz = np.ascontiguousarray(mul(dZw, dX).T)
    return z_hat, symmetrise(Pzz), Pxz, True


@_kernel
def _whiten(S: Array, e: Array) -> tuple[Array, Array, bool]:  # pragma: no cover - compiled
    """``adaptive.whiten``: ``(L⁻¹, L⁻¹ e)``, False when ``S`` is not positive definite."""
    p = e.shape[0]
    L, ok = cholesky_lower(S)
    if not ok:
        return np.zeros((p, p)), np.zeros(p), False
    rhs = np.zeros((p, p + 1))
    for i in range(p):
        rhs[i, i] = 1.0
        rhs[i, p] = e[i]
    sol = solve_lower(L, rhs, False)
    return sol[:, :p].copy(), sol[:, p].copy(), True


@_kernel
def _trace_w(W: Array, M: Array) -> float:  # pragma: no cover - compiled
    """``Σ (W M) ∘ W`` = ``tr(W M Wᵀ)``."""
    p = W.shape[0]
    t = 0.0
    for i in range(p):
        for j in range(p):
            s = 0.0
            for k in range(p):
                s += W[i, k] * M[k, j]
            t += s * W[i, j]
    return t


@_kernel
def _quadratic(Ht: Array, Q: Array) -> Array:  # pragma: no cover - compiled
    """``Htᵀ Q Ht``."""
    return mul(mul(np.ascontiguousarray(Ht.T), Q), Ht)


# -- the Python side ----------------------------------------------------------------------------


@dataclass(frozen=True)
class ModelConstants:
    """A brush observer model as :func:`filter_step` takes it: integer and float descriptions and its noise."""

    mi: Array
    mf: Array
    q0: Array
    r0: Array
    n: int


def model_constants(model: Any) -> ModelConstants | None:
    """The :class:`ModelConstants` of a ``SkidSteerObserverModel`` or ``SkidSteerTireScaleModel``, None for
    any other model (the kinematic ones, a ground-slope state pair: the Python step runs them)."""
    from terrain_estimation.models.skid_steer_observer import SkidSteerObserverModel
    from terrain_estimation.models.skid_steer_scales import SCALE_NAMES, SkidSteerTireScaleModel

    if type(model) is SkidSteerObserverModel:
        base = model
        mi = [1, 0, 0, base.substeps, base.max_substeps, 0, 0, 0]
        mf = [0.0] * 9
        n = 3
    elif type(model) is SkidSteerTireScaleModel and not model.scales.slope:  # the slope: the Python step
        base = model.base
        sc = model.scales
        k = sc.scale_count
        rows = [SCALE_NAMES.index(s) for s in sc.states[:k]] + [0] * (3 - k)
        mi = [0, k, int(sc.resistance), base.substeps, base.max_substeps, *rows]
        lo, hi = model._log_bounds
        mf = [
            lo,
            hi,
            sc.reversion_time_s,
            sc.resistance_max,
            sc.resistance_speed,
            sc.resistance_nominal,
            sc.resistance_time_s,
            sc.resistance_std,
            sc.walk_std,
        ]
        n = model.state_dim
    else:
        return None
    return ModelConstants(
        mi=np.array(mi, dtype=np.int64),
        mf=np.array(mf, dtype=np.float64),
        q0=np.array(base.q0_diag, dtype=np.float64),
        r0=np.array(base.r0_diag, dtype=np.float64),
        n=n,
    )


def _vehicle_constants(model: Any) -> tuple[Array, Array, Array, Array]:
    """``(vc, wheel_x, wheel_y, axle_x)`` of a brush model's vehicle."""
    base = getattr(model, "base", model)
    p = base.params
    xa_t, s1, s2, d, n_axles = base._axles
    gain = base.max_euler_gain
    vc = np.array(
        [
            p.longitudinal_stiffness,
            p.cornering_stiffness,
            p.mass,
            p.yaw_inertia,
            p.wheel_radius,
            p.rolling_speed_floor,
            p.gravity,
            p.cg_height,
            p.track,
            s1,
            s2,
            d,
            n_axles,
            base.relaxation_rate_per_speed,
            math.nan if gain is None else gain,
            base.q_step_dt,
        ],
        dtype=np.float64,
    )
    return (
        vc,
        np.ascontiguousarray(base._wheel_x, dtype=np.float64),
        np.ascontiguousarray(base._wheel_y, dtype=np.float64),
        np.array(xa_t, dtype=np.float64),
    )
