"""The skid-steer estimator's filter step and consider-covariance step, compiled (numba).

One call runs what :meth:`AdaptiveStrongTrackingUKF._step` (variant
``"adaptive"``: whitened strong tracking, innovation-matched noise scales,
MODELS.md B.8 and B.12) does over the brush observer models
(:class:`~terrain_estimation.models.skid_steer_observer.SkidSteerObserverModel`,
``"brush"``; :class:`~terrain_estimation.models.skid_steer_scales.SkidSteerTireScaleModel`,
``"brush_scales"``), followed by
:meth:`~terrain_estimation.estimators.skid_steer_consider.ConsiderCovariance.step`
(the Schmidt sensitivity ``Ψ`` through forward differences of the augmented
model's ``f`` and ``h``):

* the step's per-input terms (rolling speeds, quasi-static loads, ``μ F_z``);
* the sigma points through ``f`` with its Euler sub-steps (all points, one
  loop, no temporaries), the prediction's mean and spread, ``Q_k = s_q Q0``;
* the measurement moments (``h`` of the redrawn points), the whitened fading
  factor, the moments again when ``λ > 1``, the gain update with its gate;
* one Gauss–Newton step of the noise scales (Huber clip, ridge, bounds);
* ``Ψ`` carried over the step, and ``Ψ C Ψᵀ``.

Why: over a (3 + k)-state model the Python step makes some 300 numpy calls on
3×3 to 6×6 arrays and cost 500–1000 µs per IMU sample, 5–10× what the
arithmetic needs; a replay at 50× real time leaves 200 µs per sample for
everything (decode, checks, filter, outputs). Compiled, the step costs about
20–40 µs.

The same mathematics, operation for operation, as the Python classes, which
remain the reference and run whenever this step cannot (:data:`STATUS_FALLBACK`:
a covariance that needs :func:`~terrain_estimation.filters.sigma_points.robust_sqrt`'s
PSD projection, a non-finite model output, too many sub-steps, a singular
``P̄``, anything unusual): the force sums, the sub-step loop, the loads and the
noise follow the Python forms' order of operations; the small matrix products,
the Cholesky factors and the linear solves are loops here, where numpy calls
BLAS and LAPACK, so the results agree to rounding (about 1e-14 relative per
step; over a whole bag 1e-12, ``test/test_skid_steer_compiled.py``), not bit
for bit.

The observer models' kernels (``f``, ``h``, their per-input terms and the unscented moments of ``h``) and
the constants describing a model to them are in :mod:`.skid_steer_compiled_model`; the small linear
algebra (Cholesky, triangular and LU solves, matrix products) is :mod:`terrain_estimation.filters.compiled_linalg`'s,
shared with the soil-stiffness SCKF and EKF steps.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.filters.base import Array

__all__ = [
    "STATUS_OK",
    "STATUS_FALLBACK",
    "CompiledSkidSteerStep",
    "ModelConstants",
    "StepConstants",
    "StepInput",
    "model_constants",
    "filter_step",
    "warm_up",
]

#: The compiled step ran (its update may still have been gated).
STATUS_OK = 0
#: The compiled step cannot reproduce the Python step here: run the Python step (same results by construction).
STATUS_FALLBACK = 1

# -- the kernels --------------------------------------------------------------------------------
# numba is imported with the kernels (jit.compiled); everything below the marker is compiled.

from terrain_estimation.estimators.skid_steer_compiled_model import (  # noqa: E402
    _K,
    _PLAIN,
    _QSTEP,
    _RES,
    _RSTD,
    _RTIME,
    _WALK,
    ModelConstants,
    Terms,
    _mean,
    _measure,
    _moments,
    _points,
    _process,
    _quadratic,
    _terms,
    _trace_w,
    _vehicle_constants,
    _whiten,
    model_constants,
)
from terrain_estimation.filters.compiled_linalg import (  # noqa: E402 - after the constants the docstring names
    all_finite,
    cholesky_lower,
    mul,
    mul_bt,
    solve,
    solve_lower,
    symmetrise,
)
from terrain_estimation.jit import compiled  # noqa: E402

#: numba's numpy error model: a float division by zero gives inf or NaN (as the Python step's numpy does)
#: instead of raising ZeroDivisionError, and no division carries a zero test. The divisors here are positive
#: by construction; a NaN propagates to a non-finite result, which hands the step back (STATUS_FALLBACK).
_kernel = compiled(error_model="numpy")

#: A step's model input for :func:`filter_step`: ``(ω_l, ω_r, a_x, a_y, μ)``, what ``SkidSteerInput`` holds.
StepInput = tuple[float, float, float, float, float]
#: An index or integer-description array of :class:`StepConstants`.
IntArray = NDArray[np.int64]


class StepConstants(NamedTuple):
    """What :func:`filter_step` takes of one estimator's filter, model, vehicle and consider covariance (fixed
    over its life; :class:`CompiledSkidSteerStep` builds it)."""

    vc: Array  # vehicle constants (skid_steer_compiled_model._CX, ...)
    wx: Array  # wheel x positions (m)
    wy: Array  # wheel y positions (m)
    axle_x: Array  # axle x positions (m)
    mi: Array  # the model's integer description (ModelConstants.mi)
    mf: Array  # the model's float description (ModelConstants.mf)
    q0: Array  # the model's process noise diagonal
    r0: Array  # the model's measurement noise diagonal
    unit: Array  # the unit sigma points, one per row
    Wm: Array  # sigma-point mean weights
    Wc: Array  # sigma-point covariance weights
    fc: Array  # the filter constants (_GATE, ...)
    s_idx: IntArray  # consider: the state's rows in the augmented model
    c_idx: IntArray  # consider: the considered parameters' rows in the augmented model
    sqrt_c: Array  # consider: the parameters' standard deviations
    ami: Array  # consider: the augmented model's mi (the model's own without consider)
    amf: Array  # consider: the augmented model's mf


# Indices of the filter constants ``fc``.
(
    _GATE,
    _RHO,
    _BETA_W,
    _LAMBDA_MAX,
    _HAS_PROB,
    _NIS_THR,
    _SIMPLIFIED,
    _R_FORGET,
    _Q_FORGET,
    _R_FLOOR,
    _R_CEIL,
    _Q_FLOOR,
    _Q_CEIL,
    _HAS_CLIP,
    _CLIP_C2,
    _CLIP_KAPPA,
    _RIDGE,
    _ADAPT_R,
    _ADAPT_Q,
    _CONSIDER_STEP,
) = range(20)


@_kernel
def filter_step(
    x: Array,
    P: Array,
    memory: Array,
    fresh: bool,
    z: Array,
    u: StepInput,
    dt: float,
    psi: Array,
    consider: bool,
    constants: StepConstants,
) -> tuple[int, int, bool, float, float, float, Array]:  # pragma: no cover - compiled
    """One "adaptive" step of :class:`~terrain_estimation.filters.an_stukf.AdaptiveStrongTrackingUKF` and,
    with ``consider``, one :meth:`ConsiderCovariance.step` after it (module docstring).

    Args:
        x, P: the prior mean and covariance.
        memory: the packed adaptive memory (ignored when ``fresh``: the filter's first step).
        z: the measurement ``[a_x, a_y, r]``.
        u: the step's model input ``(ω_l, ω_r, a_x, a_y, μ)`` (wheel side, low-passed accelerations).
        dt: the step (s).
        psi: the consider sensitivity ``Ψ`` (with ``consider``).
        constants: the estimator's constants (:class:`StepConstants`).

    Returns:
        ``(status, consider_status, accepted, λ, s_q, NIS, buffer)``: the arrays ``x⁺, P⁺, ν, P_zz, P̄,
        P_xz``, the packed memory, ``s_r``, ``Ψ⁺`` and ``Ψ⁺ C Ψ⁺ᵀ`` one after the other in ``buffer``
        (:meth:`CompiledSkidSteerStep.unpack`); ``consider_status`` :data:`STATUS_OK` or
        :data:`STATUS_FALLBACK` (run the Python consider step).
    """
    wl, wr, ax, ay, mu = u
    vc, wx, wy, axle_x, mi, mf, q0, r0, unit, Wm, Wc, fc, s_idx, c_idx, sqrt_c, ami, amf = constants
    n = x.shape[0]
    p = 3
    bad = (STATUS_FALLBACK, STATUS_FALLBACK, False, 1.0, 1.0, 0.0, np.zeros(0))
    # AdaptiveMemory.unpack
    size = p * p + p + 2
    r_scale = np.ones(p)
    q_scale = 1.0
    has_V = False
    V_prev = np.zeros((p, p))
    if not fresh:
        if memory.shape[0] != size or not all_finite(memory):
            return bad
        for i in range(p):
            r_scale[i] = memory[p * p + i]
        q_scale = memory[p * p + p]
        if not (r_scale.min() > 0.0 and q_scale > 0.0):
            return bad
        if memory[size - 1] != 0.0:
            has_V = True
            for i in range(p):
                for j in range(p):
                    V_prev[i, j] = memory[i * p + j]
    terms = _terms(wl, wr, ax, ay, mu, vc, axle_x)
    # -- UnscentedKalmanFilter._propagate_points
    S, ok = cholesky_lower(P)
    if not ok:
        return bad
    X = _points(x, S, unit)
    Xp, ok = _process(X, dt, mi, mf, vc, wx, wy, terms)
    if not ok or not all_finite(Xp):
        return bad
    m = unit.shape[0]
    x_bar = _mean(Xp, Wm)
    D = np.empty((m, n))
    DwT = np.empty((n, m))  # Dᵀ diag(Wc)
    for i in range(m):
        for a in range(n):
            D[i, a] = Xp[i, a] - x_bar[a]
            DwT[a, i] = D[i, a] * Wc[i]
    P0 = symmetrise(mul(DwT, D))
    # -- the model's process noise (its own arithmetic) and R
    k = mi[_K]
    Lq0 = np.empty(n)
    if mi[_PLAIN] == 1:
        root = math.sqrt(dt / vc[_QSTEP])
        for a in range(3):
            Lq0[a] = math.sqrt(q0[a]) * root
    else:
        ratio = dt / vc[_QSTEP]
        for a in range(3):
            Lq0[a] = math.sqrt(q0[a] * ratio)
        for j in range(k):
            Lq0[3 + j] = mf[_WALK] * math.sqrt(dt)
        if mi[_RES] == 1:
            Lq0[n - 1] = mf[_RSTD] * math.sqrt(-math.expm1(-2.0 * dt / mf[_RTIME]))
    noise_scale = q_scale * 1.0
    root_q = math.sqrt(noise_scale)
    Qd = np.empty(n)
    for a in range(n):
        v = Lq0[a] * root_q
        Qd[a] = v * v
    Rs = np.empty(p)
    for a in range(p):
        Rs[a] = math.sqrt(r_scale[a] / 1.0) * math.sqrt(r0[a])
    Q = np.zeros((n, n))
    for a in range(n):
        Q[a, a] = Qd[a]
    Pq = np.empty((n, n))
    for a in range(n):
        for b in range(n):
            Pq[a, b] = P0[a, b] + Q[a, b]
    P_prior = symmetrise(Pq)
    z_hat, Pzz, Pxz, ok = _moments(x_bar, P_prior, Rs, unit, Wm, Wc, mi, mf, vc, wx, wy, terms)
    if not ok:
        return bad
    nu = np.empty(p)
    for q in range(p):
        nu[q] = z[q] - z_hat[q]
    R = np.zeros((p, p))
    for a in range(p):
        R[a, a] = Rs[a] * Rs[a]
    # -- whitened fading factor (adaptive._whitened_fading_factor)
    W, w, whitened = _whiten(Pzz, nu)
    V = np.empty((p, p))
    for i in range(p):
        for j in range(p):
            ee = nu[i] * nu[j]
            V[i, j] = (fc[_RHO] * V_prev[i, j] + ee) / (1.0 + fc[_RHO]) if has_V else ee
    lam = 1.0
    if whitened:
        ww = 0.0
        for q in range(p):
            ww += w[q] * w[q]
        if not (fc[_HAS_PROB] == 1.0 and ww <= fc[_NIS_THR]):
            N = np.empty((p, p))
            M = np.empty((p, p))
            for i in range(p):
                for j in range(p):
                    N[i, j] = V[i, j] - fc[_BETA_W] * R[i, j]
                    M[i, j] = Pzz[i, j] - R[i, j]
            if fc[_SIMPLIFIED] == 0.0:
                Ht, ok = solve(P_prior, Pxz)
                if not ok:
                    return bad  # P̄ singular: the Python step takes the least-squares H̃
                HQH = _quadratic(Ht, Q)
                for i in range(p):
                    for j in range(p):
                        N[i, j] -= HQH[i, j]
                        M[i, j] -= HQH[i, j]
            tr_m = _trace_w(W, M)
            if tr_m > 0.0:
                c = _trace_w(W, N) / tr_m
                if math.isfinite(c):
                    lam = min(max(1.0, c), fc[_LAMBDA_MAX])
    if lam != 1.0:
        for a in range(n):
            for b in range(n):
                Pq[a, b] = lam * P0[a, b] + Q[a, b]
        P_prior = symmetrise(Pq)
        z_hat, Pzz, Pxz, ok = _moments(x_bar, P_prior, Rs, unit, Wm, Wc, mi, mf, vc, wx, wy, terms)
        if not ok:
            return bad
        for q in range(p):
            nu[q] = z[q] - z_hat[q]
        W, w, whitened = _whiten(Pzz, nu)
    # -- UnscentedKalmanFilter._gain_update (whiten_innovation, gate)
    Lz, ok_z = cholesky_lower(Pzz)
    nis = math.inf
    accepted = False
    x_post = x_bar
    P_post = P_prior
    if ok_z:
        rhs = np.empty((p, n + 1))
        for q in range(p):
            for a in range(n):
                rhs[q, a] = Pxz[a, q]
            rhs[q, n] = nu[q]
        sol = solve_lower(Lz, rhs, False)  # [L⁻¹ P_xzᵀ, L⁻¹ ν]
        prod = mul(np.ascontiguousarray(sol.T), sol)  # [K P_zz Kᵀ, K ν; ·, NIS]
        nis = prod[n, n]
        if math.isfinite(nis) and nis <= fc[_GATE]:
            accepted = True
            x_post = np.empty(n)
            Pm = np.empty((n, n))
            for a in range(n):
                x_post[a] = x_bar[a] + prod[a, n]
                for b in range(n):
                    Pm[a, b] = P_prior[a, b] - prod[a, b]
            P_post = symmetrise(Pm)
    # -- noise_adaptation.update_noise_scales
    new_r = r_scale.copy()
    new_q = q_scale
    adapt_r = fc[_ADAPT_R] == 1.0
    adapt_q = fc[_ADAPT_Q] == 1.0
    if (adapt_r or adapt_q) and whitened:
        wn = 0.0
        for q in range(p):
            wn += w[q] * w[q]
        if math.isfinite(wn):
            g2 = 1.0
            kappa = 1.0
            if fc[_HAS_CLIP] == 1.0:
                kappa = fc[_CLIP_KAPPA]
                if wn > fc[_CLIP_C2]:
                    g2 = fc[_CLIP_C2] / wn
            mm = (p if adapt_r else 0) + (1 if adapt_q else 0)
            Xs = np.empty((mm, p, p))
            if adapt_r:
                WR = mul(W, R)
                for i in range(p):
                    for a in range(p):
                        for b in range(p):
                            Xs[i, a, b] = (W[a, i] * WR[b, i] + W[b, i] * WR[a, i]) * 0.5
            ok_q = True
            if adapt_q:
                Lp, ok_p = cholesky_lower(P_prior)
                if not ok_p:
                    ok_q = False  # the Python step's least-squares _hqh: run it
                else:
                    Ht = solve_lower(Lp, solve_lower(Lp, Pxz, False), True)
                    Xs[mm - 1] = mul_bt(mul(W, _quadratic(Ht, Q)), W)
            if not ok_q:
                return bad
            flat = Xs.reshape((mm, p * p))
            G = mul_bt(flat, flat)
            w_outer = np.empty((p * p, 1))  # (g²/κ) w wᵀ, flattened
            for a in range(p):
                for b in range(p):
                    w_outer[a * p + b, 0] = (g2 / kappa) * (w[a] * w[b])
            h = mul(flat, w_outer)
            for i in range(mm):
                t = 0.0
                for a in range(p):
                    t += Xs[i, a, a]
                h[i, 0] = h[i, 0] - t
            for i in range(mm):
                G[i, i] += fc[_RIDGE]
            Lg, ok_g = cholesky_lower(G)
            if ok_g:
                step = solve_lower(Lg, solve_lower(Lg, h, False), True)
                if all_finite(step):
                    if adapt_r:
                        for i in range(p):
                            v = r_scale[i] * math.exp((1.0 - fc[_R_FORGET]) * step[i, 0])
                            new_r[i] = min(max(v, fc[_R_FLOOR]), fc[_R_CEIL])
                    if adapt_q:
                        v = q_scale * math.exp((1.0 - fc[_Q_FORGET]) * step[mm - 1, 0])
                        new_q = min(max(v, fc[_Q_FLOOR]), fc[_Q_CEIL])
    mem_out = np.zeros(size)
    for i in range(p):
        for j in range(p):
            mem_out[i * p + j] = V[i, j]
    mem_out[size - 1] = 1.0
    for i in range(p):
        mem_out[p * p + i] = new_r[i]
    mem_out[p * p + p] = new_q
    # -- ConsiderCovariance.step
    c_status = STATUS_OK
    psi_out = psi
    cov = np.zeros((0, 0))
    if consider:
        c_status, psi_out, cov = _consider(
            x, x_post, psi, accepted, Pzz, Pxz, P_prior, P_post, dt, vc, wx, wy, ami, amf, s_idx, c_idx, sqrt_c,
            fc[_CONSIDER_STEP], terms,
        )  # fmt: skip
    # One buffer for every array (numba boxes each returned array at a cost of about 0.7 µs):
    # x⁺ (n) | P⁺ (n²) | ν (p) | P_zz (p²) | P̄ (n²) | P_xz (n p) | memory | s_r (p) | Ψ⁺ (n_s k) | Ψ⁺CΨ⁺ᵀ (n_s²)
    n_s = s_idx.shape[0]
    k_c = c_idx.shape[0]
    parts = (x_post, P_post.ravel(), nu, Pzz.ravel(), P_prior.ravel(), Pxz.ravel(), mem_out, r_scale)
    total = 0
    for part in parts:
        total += part.shape[0]
    buf = np.zeros(total + n_s * k_c + n_s * n_s)
    o = 0
    for part in parts:
        buf[o : o + part.shape[0]] = part
        o += part.shape[0]
    if consider and c_status == STATUS_OK:
        buf[o : o + n_s * k_c] = psi_out.ravel()
        buf[o + n_s * k_c :] = cov.ravel()
    return STATUS_OK, c_status, accepted, lam, noise_scale, nis, buf


@_kernel
def _consider(
    x_prev: Array,
    x_post: Array,
    psi: Array,
    accepted: bool,
    Pzz: Array,
    Pxz: Array,
    P_prior: Array,
    P_post: Array,
    dt: float,
    vc: Array,
    wx: Array,
    wy: Array,
    ami: Array,
    amf: Array,
    s_idx: Array,
    c_idx: Array,
    sqrt_c: Array,
    step: float,
    terms: Terms,
) -> tuple[int, Array, Array]:  # pragma: no cover - compiled
    """:meth:`ConsiderCovariance.step` and :meth:`~ConsiderCovariance.covariance` (``Ψ C Ψᵀ``)."""
    n_s = s_idx.shape[0]
    k = c_idx.shape[0]
    n_aug = 3 + ami[_K] + ami[_RES]
    fail = (STATUS_FALLBACK, psi.copy(), np.zeros((0, 0)))
    directions = np.zeros((n_aug, k))
    for i in range(n_s):
        for j in range(k):
            directions[s_idx[i], j] = psi[i, j]
    for j in range(k):
        directions[c_idx[j], j] = -1.0
    # _directional(f, x_prev, directions)
    xa = np.zeros(n_aug)
    for i in range(n_s):
        xa[s_idx[i]] = x_prev[i]
    eps = np.empty(k)
    for j in range(k):
        big = 0.0
        for i in range(n_aug):
            v = abs(directions[i, j])
            if v > big or v != v:
                big = v
        eps[j] = step / max(big, 1.0)
    pts = np.empty((k + 1, n_aug))
    for r in range(k + 1):
        for i in range(n_aug):
            pts[r, i] = xa[i]
    for j in range(k):
        for i in range(n_aug):
            pts[j + 1, i] += directions[i, j] * eps[j]
    out, ok = _process(pts, dt, ami, amf, vc, wx, wy, terms)
    if not ok:
        return fail
    new = np.empty((n_s, k))
    for j in range(k):
        for i in range(n_s):
            new[i, j] = (out[j + 1, s_idx[i]] - out[0, s_idx[i]]) / eps[j]
    if accepted:
        xb = np.zeros(n_aug)
        for i in range(n_s):
            xb[s_idx[i]] = x_post[i]
        hp = np.empty((k + 1, n_aug))
        for r in range(k + 1):
            for i in range(n_aug):
                hp[r, i] = xb[i]
        for j in range(k):
            hp[j + 1, c_idx[j]] += 1.0 * step
        hz = _measure(hp, ami, amf, vc, wx, wy, terms)
        p = 3
        Hc = np.empty((p, k))
        for j in range(k):
            for q in range(p):
                Hc[q, j] = (hz[j + 1, q] - hz[0, q]) / step
        Kt, ok1 = solve(Pzz, Pxz.T.copy())  # Kᵀ = P_zz⁻¹ P_xzᵀ
        A, ok2 = solve(P_prior, new)
        if not (ok1 and ok2):
            return fail
        new = mul(P_post, A) + mul(np.ascontiguousarray(Kt.T), Hc)  # P⁺ P̄⁻¹ Ψ⁻ + K H_c
    if not all_finite(new):
        return fail
    a = np.empty((n_s, k))
    for i in range(n_s):
        for j in range(k):
            a[i, j] = new[i, j] * sqrt_c[j]
    return STATUS_OK, new, symmetrise(mul_bt(a, a))


# -- the Python side ----------------------------------------------------------------------------


class CompiledSkidSteerStep:
    """:func:`filter_step` for one estimator's filter, model and consider covariance.

    Build it with :meth:`for_estimator` (None where the compiled step does not apply: another filter
    variant, a kinematic model, a strong-tracking criterion other than the whitened one, fixed noise
    factors on the filter).
    """

    def __init__(self, filt: Any, model: Any, consider: Any, mc: ModelConstants) -> None:
        from terrain_estimation.filters.noise_adaptation import huber_clip

        self.model = model
        self.mc = mc
        ps = filt.ukf.point_set(mc.n)
        st = filt._st
        noise = filt.noise
        gate = filt.ukf.gate_threshold
        if st.probability is not None:
            from terrain_estimation.filters.adaptive import nis_threshold

            thr = nis_threshold(3, st.probability)
        else:
            thr = math.inf
        c2, kappa = huber_clip(3, noise.clip_probability) if noise.clip_probability is not None else (0.0, 1.0)
        fc = np.array(
            [
                math.inf if gate is None else gate,
                st.rho,
                st.beta_w,
                st.lambda_max,
                float(st.probability is not None),
                thr,
                float(st.simplified),
                noise.r_forgetting,
                noise.q_forgetting,
                noise.r_floor,
                noise.r_ceiling,
                noise.q_floor,
                noise.q_ceiling,
                float(noise.clip_probability is not None),
                c2,
                kappa,
                noise.ridge,
                float(noise.adapt_r),
                float(noise.adapt_q),
                consider.config.step if consider is not None else 0.0,
            ],
            dtype=np.float64,
        )
        self.consider = consider
        self.amc: ModelConstants | None = None
        if consider is not None:
            amc = model_constants(consider.augmented)
            if amc is None:
                raise ValueError("the consider covariance's augmented model is not a brush model")
            self.amc = amc
            self.s_idx = np.ascontiguousarray(consider._s, dtype=np.int64)
            self.c_idx = np.ascontiguousarray(consider._c, dtype=np.int64)
            sqrt_c = np.sqrt(np.diag(consider._C)).astype(np.float64)
        else:
            self.s_idx = np.zeros(0, dtype=np.int64)
            self.c_idx = np.zeros(0, dtype=np.int64)
            sqrt_c = np.zeros(0)
        aug = mc if self.amc is None else self.amc
        # The filter_step constants of this filter, model and consider covariance, in StepConstants' order.
        vehicle = _vehicle_constants(model)
        model_arrays = (mc.mi, mc.mf, mc.q0, mc.r0)
        unit, Wm, Wc = (np.ascontiguousarray(a, dtype=np.float64) for a in (ps.unit, ps.Wm, ps.Wc))
        self.constants = StepConstants(
            *vehicle, *model_arrays, unit, Wm, Wc, fc, self.s_idx, self.c_idx, sqrt_c, aug.mi, aug.mf
        )
        self._no_memory = np.zeros(0)
        self._no_psi = np.zeros((0, 0))

    @classmethod
    def for_estimator(cls, filt: Any, model: Any, consider: Any) -> CompiledSkidSteerStep | None:
        """The compiled step of this filter, model and consider covariance, or None where it does not apply."""
        from terrain_estimation.filters.an_stukf import AdaptiveStrongTrackingUKF
        from terrain_estimation.filters.ukf import UnscentedKalmanFilter

        if type(filt) is not AdaptiveStrongTrackingUKF or filt.variant != "adaptive":
            return None
        if type(filt.ukf) is not UnscentedKalmanFilter or filt.q0_sqrt is not None or filt.r0_sqrt is not None:
            return None
        if filt._st.criterion != "whitened":
            return None
        mc = model_constants(model)
        if mc is None or model.measurement_dim != 3:
            return None
        if consider is not None and model_constants(consider.augmented) is None:
            return None
        return cls(filt, model, consider, mc)

    def run(
        self,
        x: Array,
        P: Array,
        memory: Array | None,
        z: Array,
        wl: float,
        wr: float,
        ax: float,
        ay: float,
        mu: float,
        dt: float,
        psi: Array | None,
    ) -> tuple[Any, ...]:
        """:func:`filter_step` on one step's values (``memory`` None: the first step; ``psi`` None: no consider
        covariance)."""
        fresh = memory is None
        memory = self._no_memory if memory is None else memory
        consider = psi is not None
        psi = self._no_psi if psi is None else psi
        return filter_step(x, P, memory, fresh, z, (wl, wr, ax, ay, mu), dt, psi, consider, self.constants)

    def unpack(self, buf: Array) -> tuple[Array, ...]:
        """``(x⁺, P⁺, ν, P_zz, P̄, P_xz, memory, s_r, Ψ⁺, Ψ⁺CΨ⁺ᵀ)``: views of :func:`filter_step`'s buffer."""
        n, p = self.mc.n, 3
        n_s, k = len(self.s_idx), len(self.c_idx)
        sizes = (n, n * n, p, p * p, n * n, n * p, p * p + p + 2, p, n_s * k, n_s * n_s)
        shapes = ((n,), (n, n), (p,), (p, p), (n, n), (n, p), (p * p + p + 2,), (p,), (n_s, k), (n_s, n_s))
        out = []
        o = 0
        for size, shape in zip(sizes, shapes, strict=True):
            out.append(buf[o : o + size].reshape(shape))
            o += size
        return tuple(out)


_warm: set[tuple[int, bool]] = set()


def warm_up(step: CompiledSkidSteerStep) -> None:
    """Compile :func:`filter_step` for this step's types (or load it from numba's cache) now.

    The estimator calls this when it is built, so that a node's first IMU sample does not wait for the
    compiler (tens of seconds the first time on a machine; about 0.1 s from numba's cache).
    """
    key = (step.mc.n, step.consider is not None)
    if key in _warm:
        return
    n = step.mc.n
    x = np.zeros(n)
    x[0] = 1.0
    P = np.eye(n) * 0.01
    psi = np.zeros((len(step.s_idx), len(step.c_idx))) if step.consider is not None else None
    step.run(x, P, None, np.zeros(3), 2.0, 2.0, 0.0, 0.0, 0.8, 0.01, psi)
    _warm.add(key)
