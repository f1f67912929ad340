"""The soil-stiffness estimator's SCKF step, compiled (numba).

One call runs a whole filter step of the square-root cubature Kalman filter
(MODELS.md A.5, eqs. 14–28) on the bilinear k_tot models of
:mod:`terrain_estimation.models.quarter_car` (quarter car and LRV,
``ẋ = (A0 + k_tot E) x + B ḣ``, ``z = C(x) x + D ḣ``, A.1–A.4) with the
``"taylor4"`` discretisation:

* prediction: the cubature points through the sub-steps of the road, the
  process-noise factor ``√Q_k`` at the mean k_tot over the whole step, and
  ``tria([χ*, √Q_k])``;
* the measurement-noise factor ``√R_eff`` with the profile-error term
  ``G Σ_ε Gᵀ`` at the predicted mean (Cholesky);
* the update with its NIS gate and ``tria([χ − 𝒵 Wᵀ, W √R])``.

Why: at the quarter car's 100 Hz filter rate and 1 kHz profile, numpy's
per-call overhead on 5×5 matrices, not arithmetic, made the step cost about
200 µs, which kept one node from following a bag replayed at 20× real time
(issue 7). Compiled, a step of the quarter car's recorded bag costs about 17 µs.

The same mathematics as the public
``SquareRootCubatureKalmanFilter.predict``/``update`` with the model's ``f``/``h``/noise methods,
which remain the reference: ``tria`` is a Householder QR written out
(LAPACK's ``dgeqrf`` accumulates differently) and the small products are
loops, so results agree to rounding (about 1e-13 relative), not bit for bit
(``test/test_soil_stiffness_sckf.py``).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from terrain_estimation.jit import compiled
from terrain_estimation.models.quarter_car import hdot_at_end, substep_inputs

__all__ = ["STATUS_OK", "STATUS_FAILED", "ModelOperands", "model_operands", "run_step", "sckf_step", "warm_up"]

#: :func:`sckf_step` ran (its posterior may still be rejected by the gate).
STATUS_OK = 0
#: A non-finite propagated or predicted point, or an ``R_eff`` that is not
#: positive definite: the step failed (the public SCKF raises ValueError /
#: LinAlgError there).
STATUS_FAILED = 1


class ModelOperands(NamedTuple):
    """The constants of a bilinear k_tot model that :func:`sckf_step` takes (contiguous float64 copies)."""

    a0: np.ndarray
    e: np.ndarray
    b: np.ndarray
    g: np.ndarray
    sigma_q: np.ndarray
    logistic: bool
    k_lo: float
    k_hi: float
    k_series: float
    k_floor: float
    c0: np.ndarray
    ce: np.ndarray
    d: np.ndarray
    sqrt_r: np.ndarray
    feedthrough: bool


def model_operands(model: Any) -> ModelOperands | None:
    """:class:`ModelOperands` of a ``QuarterCarModel`` / ``LRVModel``, None if :func:`sckf_step` cannot run it.

    It runs the ``"taylor4"`` discretisation only (``"expm"`` goes through the
    public filter methods).
    """
    if getattr(model, "_method", None) != "taylor4":
        return None

    def arr(a: Any) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=np.float64).copy()

    logistic = model.stiffness_state == "log_k_s"
    lo, hi = model._log_ks_range if logistic else model.ktot_bounds
    return ModelOperands(
        a0=arr(model._a0),
        e=arr(model._e),
        b=arr(model._b),
        g=arr(model._g),
        sigma_q=arr(model._sigma_q),
        logistic=logistic,
        k_lo=float(lo),
        k_hi=float(hi),
        k_series=float(model.k_series),
        k_floor=float(model.ktot_bounds[0]),
        c0=arr(model._c0),
        ce=arr(model._ce),
        d=arr(model._d),
        sqrt_r=arr(model._sqrt_r),
        feedthrough=bool(np.any(model._d)),
    )


#: ``z`` of a predict-only step (not read).
_NO_MEASUREMENT = np.zeros(1)


def run_step(
    ops: ModelOperands,
    model: Any,
    x: Any,
    S: Any,
    u: Any,
    dt: float,
    z: np.ndarray | None,
    sigma_eps: np.ndarray,
    profile_noise: bool,
    gate: float | None,
) -> tuple[int, np.ndarray, np.ndarray, float, bool, np.ndarray, np.ndarray]:
    """:func:`sckf_step` for ``model`` (its :func:`model_operands` ``ops``) and a step's input as the model takes it.

    Args:
        x, S: the previous posterior (mean, lower factor).
        u: the step's sub-step ḣ ``(N,)`` or a ``StepInput`` (ḣ at the
            measurement time for a feed-through).
        z: the measured accelerations ``(p,)``; None for a predict-only step.
        sigma_eps, profile_noise: ``Σ_ε`` and whether it enters ``R``.
        gate: the SCKF's NIS gate (None: none).

    Returns:
        :func:`sckf_step`'s tuple.
    """
    return sckf_step(
        np.ascontiguousarray(x, dtype=float),
        np.ascontiguousarray(S, dtype=float),
        substep_inputs(u),
        dt,
        ops.a0,
        ops.e,
        ops.b,
        ops.g,
        ops.sigma_q,
        model._stiffness_noise_sqrt(dt),
        ops.logistic,
        ops.k_lo,
        ops.k_hi,
        ops.k_series,
        ops.k_floor,
        z is not None,
        _NO_MEASUREMENT if z is None else z,
        ops.c0,
        ops.ce,
        ops.d,
        hdot_at_end(u) if ops.feedthrough else 0.0,
        ops.sqrt_r,
        sigma_eps,
        profile_noise,
        math.inf if gate is None else float(gate),
    )


@compiled
def _ktot(v: float, logistic: bool, lo: float, hi: float, k_series: float) -> float:  # pragma: no cover
    """k_tot the dynamics use for a last-state value (``ktot_of``): clamp, or logistic of the clipped value."""
    # Written as comparisons so that a NaN stays NaN, as min(max(v, lo), hi) keeps it.
    c = v
    if c < lo:
        c = lo
    elif c > hi:
        c = hi
    if logistic:
        return k_series / (1.0 + math.exp(-c))
    return c


@compiled
def _matmul(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """``out = a @ b`` for small square matrices (out must not alias a or b)."""
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += a[i, k] * b[k, j]
            out[i, j] = s


@compiled
def _taylor4(ad: np.ndarray, phi: np.ndarray, gam_over_delta: np.ndarray) -> None:  # pragma: no cover
    """``Φ`` and ``Γ/δ`` of the ``"taylor4"`` series from ``ad = A δ`` (Horner form, as ``_taylor4_pair``).

    ``Φ = I + Aδ(I + Aδ/2 (I + Aδ/3 (I + Aδ/4)))``,
    ``Γ/δ = I + Aδ/2 (I + Aδ/3 (I + Aδ/4 (I + Aδ/5)))``.
    """
    n = ad.shape[0]
    p = np.empty((n, n))
    q = np.empty((n, n))
    buf = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            eye = 1.0 if i == j else 0.0
            p[i, j] = ad[i, j] / 4.0 + eye
            q[i, j] = ad[i, j] / 5.0 + eye
    for divisors in ((3.0, 4.0), (2.0, 3.0), (1.0, 2.0)):
        _matmul(ad, p, buf)
        for i in range(n):
            for j in range(n):
                p[i, j] = buf[i, j] / divisors[0] + (1.0 if i == j else 0.0)
        _matmul(ad, q, buf)
        for i in range(n):
            for j in range(n):
                q[i, j] = buf[i, j] / divisors[1] + (1.0 if i == j else 0.0)
    phi[:, :] = p
    gam_over_delta[:, :] = q


@compiled
def _tria(rows: np.ndarray) -> np.ndarray:  # pragma: no cover
    """``tria`` of the compound matrix whose transpose is ``rows`` ``(k, n)``: lower ``S`` with ``S Sᵀ = rowsᵀ rows``.

    Householder QR of ``rows`` (overwritten); ``S = Rᵀ`` with each column's
    sign chosen so that the diagonal is non-negative (the convention of
    :func:`~terrain_estimation.filters.sigma_points.tria`). ``k < n`` is read
    as zero rows below, as ``tria`` pads.
    """
    k, n = rows.shape
    for j in range(min(k, n)):
        # The reflector that zeroes rows[j+1:, j]: v = x + sign(x0)‖x‖ e0, H = I − 2vvᵀ/vᵀv.
        scale = 0.0
        for i in range(j, k):
            scale = max(scale, abs(rows[i, j]))
        if scale == 0.0:
            continue
        norm2 = 0.0
        for i in range(j, k):
            t = rows[i, j] / scale
            norm2 += t * t
        alpha = scale * math.sqrt(norm2)
        x0 = rows[j, j]
        if x0 < 0.0:
            alpha = -alpha
        v0 = x0 + alpha
        # With vᵀv = 2 α v0 (‖x‖² + 2 x0 α + α², α² = ‖x‖²), H = I − τ w wᵀ for
        # w = v / v0 (w0 = 1, |w_i| ≤ 1) and τ = v0 / α, as LAPACK's dlarfg
        # scales it: no product of two large entries, so no overflow the
        # result itself would not have.
        tau = v0 / alpha
        for i in range(j + 1, k):
            rows[i, j] /= v0
        for c in range(j + 1, n):
            s = rows[j, c]
            for i in range(j + 1, k):
                s += rows[i, j] * rows[i, c]
            s *= tau
            rows[j, c] -= s
            for i in range(j + 1, k):
                rows[i, c] -= s * rows[i, j]
        rows[j, j] = -alpha
        for i in range(j + 1, k):
            rows[i, j] = 0.0
    S = np.zeros((n, n))
    for j in range(min(k, n)):
        sign = -1.0 if rows[j, j] < 0.0 else 1.0
        for i in range(j, n):
            S[i, j] = rows[j, i] * sign
    return S


@compiled
def _solve_lower(L: np.ndarray, B: np.ndarray, transpose: bool) -> np.ndarray:  # pragma: no cover
    """``L X = B`` (or ``Lᵀ X = B``) by substitution, ``L`` lower-triangular ``(p, p)``, ``B`` ``(p, m)``.

    No check of the diagonal (as BLAS ``dtrsm``): a zero gives inf/NaN, which
    the caller turns into an infinite NIS.
    """
    p, m = B.shape
    X = B.copy()
    for c in range(m):
        if not transpose:
            for i in range(p):
                s = X[i, c]
                for j in range(i):
                    s -= L[i, j] * X[j, c]
                X[i, c] = s / L[i, i]
        else:
            for i in range(p - 1, -1, -1):
                s = X[i, c]
                for j in range(i + 1, p):
                    s -= L[j, i] * X[j, c]
                X[i, c] = s / L[i, i]
    return X


@compiled
def _cholesky_lower(A: np.ndarray) -> tuple[np.ndarray, bool]:  # pragma: no cover
    """Lower Cholesky factor of a symmetric ``A`` (its lower triangle read); ``ok`` False if not positive definite."""
    p = A.shape[0]
    L = np.zeros((p, p))
    for j in range(p):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:  # NaN included
            return L, False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, p):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    return L, True


@compiled
def _all_finite(a: np.ndarray) -> bool:  # pragma: no cover
    for v in a.ravel():
        if not math.isfinite(v):
            return False
    return True


@compiled
def sckf_step(
    x: np.ndarray,
    S: np.ndarray,
    us: np.ndarray,
    dt: float,
    a0: np.ndarray,
    e: np.ndarray,
    b: np.ndarray,
    g: np.ndarray,
    sigma_q: np.ndarray,
    q_last: float,
    logistic: bool,
    k_lo: float,
    k_hi: float,
    k_series: float,
    k_floor: float,
    update: bool,
    z: np.ndarray,
    c0: np.ndarray,
    ce: np.ndarray,
    d: np.ndarray,
    hdot_end: float,
    sqrt_r: np.ndarray,
    sigma_eps: np.ndarray,
    profile_noise: bool,
    gate: float,
) -> tuple[int, np.ndarray, np.ndarray, float, bool, np.ndarray, np.ndarray]:  # pragma: no cover
    """One SCKF step (predict through the sub-steps, then update unless ``update`` is False).

    Args:
        x, S: posterior mean ``(n,)`` and lower factor ``(n, n)`` of the previous step.
        us: ḣ (m/s) of the ``N`` equal sub-steps spanning ``dt``, finite ``(N,)``.
        dt: filter step (s).
        a0, e, b, g: the model's ``A0``, ``E`` ``(n, n)``, ``B`` ``(n,)``, ``G`` ``(n, n)``.
        sigma_q: process-noise standard deviations ``(n,)`` (column scale of ``√Q_k``).
        q_last: ``√Q_k``'s last diagonal entry (the stiffness random walk over ``dt``).
        logistic, k_lo, k_hi, k_series: ``ktot_of``: clamp into ``[k_lo, k_hi]``, or
            ``k_series · logistic`` of the value clipped into ``[k_lo, k_hi]``.
        k_floor: the k_tot a non-finite mean stands for (the model's lower clamp).
        update: False for a predict-only step.
        z: measurement ``(p,)``, finite (p = 1: the body accelerometer alone).
        c0, ce, d: the model's measurement rows, at least ``p`` of each.
        hdot_end: ḣ at the measurement time (the ``D ḣ`` feed-through; 0 without one).
        sqrt_r: the accelerometers' standard deviations (``√R`` is its diagonal), ≥ ``p``.
        sigma_eps: ``Σ_ε`` ``(2, 2)`` of the elevation / ḣ errors of the road.
        profile_noise: add ``G Σ_ε Gᵀ`` to ``R`` (``profile_noise_std > 0``).
        gate: NIS threshold (``inf``: no gate).

    Returns:
        ``(status, x̄, S̄, nis, accepted, x̂, Ŝ)``: the prior, the NIS of the
        update (0 without one; ``inf`` when ``S_z`` is singular), whether the
        update passed the gate, and the posterior (the prior itself when it
        did not). ``status`` :data:`STATUS_FAILED`: the step failed; the
        other outputs are then meaningless.
    """
    n = x.shape[0]
    m = 2 * n
    root_n = math.sqrt(n)
    nsub = us.shape[0]
    delta = dt / nsub
    # (14) cubature points X_i = x ± √n S[:, i]
    dX = np.empty((m, n))
    for i in range(n):
        for r in range(n):
            dX[i, r] = root_n * S[r, i]
            dX[n + i, r] = -root_n * S[r, i]
    # (15) through the sub-steps: x ← Φ(k_i) x + Γ(k_i) B ḣ_j, the stiffness state held.
    Xs = np.empty((m, n))
    a = np.empty((n, n))
    phi = np.empty((n, n))
    gam = np.empty((n, n))
    gb = np.empty(n)
    col = np.empty(n)
    nxt = np.empty(n)
    for i in range(m):
        for r in range(n):
            col[r] = x[r] + dX[i, r]
        k = _ktot(col[n - 1], logistic, k_lo, k_hi, k_series)
        for r in range(n):
            for c in range(n):
                a[r, c] = (k * e[r, c] + a0[r, c]) * delta
        _taylor4(a, phi, gam)
        for r in range(n):
            s = 0.0
            for c in range(n):
                s += gam[r, c] * delta * b[c]
            gb[r] = s
        last = col[n - 1]
        for j in range(nsub):
            for r in range(n):
                s = 0.0
                for c in range(n):
                    s += phi[r, c] * col[c]
                nxt[r] = s + gb[r] * us[j]
            col[:] = nxt
        col[n - 1] = last
        Xs[i] = col
    if not _all_finite(Xs):
        return STATUS_FAILED, x.copy(), S.copy(), 0.0, False, x.copy(), S.copy()
    # √Q_k = √dt Γ_k(dt) G diag(σ) at the mean k_tot, its stiffness column replaced.
    k_mean = x[n - 1]
    k_c = _ktot(k_mean, logistic, k_lo, k_hi, k_series) if math.isfinite(k_mean) else k_floor
    for r in range(n):
        for c in range(n):
            a[r, c] = (k_c * e[r, c] + a0[r, c]) * dt
    _taylor4(a, phi, gam)
    rows = np.empty((m + n, n))
    sq_dt = math.sqrt(dt)
    for r in range(n):
        for c in range(n):
            s = 0.0
            for j in range(n):
                s += gam[r, j] * dt * g[j, c]
            rows[m + c, r] = sq_dt * s * sigma_q[c]  # L[r, c], stored transposed
    for r in range(n):
        rows[m + n - 1, r] = 0.0
    rows[m + n - 1, n - 1] = q_last
    # (16)-(18)
    x_pred = np.zeros(n)
    for i in range(m):
        for r in range(n):
            x_pred[r] += Xs[i, r]
    for r in range(n):
        x_pred[r] /= m
    w = 1.0 / math.sqrt(m)
    for i in range(m):
        for r in range(n):
            rows[i, r] = (Xs[i, r] - x_pred[r]) * w
    S_pred = _tria(rows)
    if not update:
        return STATUS_OK, x_pred, S_pred, 0.0, False, x_pred, S_pred
    p = z.shape[0]
    # √R_eff: R + G Σ_ε Gᵀ, G = [C(x̄) B, D] at the predicted mean.
    Rs = np.zeros((p, p))
    if profile_noise:
        k_pm = x_pred[n - 1]
        k_p = _ktot(k_pm, logistic, k_lo, k_hi, k_series) if math.isfinite(k_pm) else k_floor
        gain = np.empty((p, 2))
        for r in range(p):
            s = 0.0
            for c in range(n):
                s += (c0[r, c] + k_p * ce[r, c]) * b[c]
            gain[r, 0] = s
            gain[r, 1] = d[r]
        r_eff = np.empty((p, p))
        for r in range(p):
            for c in range(p):
                s = 0.0
                for i in range(2):
                    for j in range(2):
                        s += gain[r, i] * sigma_eps[i, j] * gain[c, j]
                r_eff[r, c] = s + (sqrt_r[r] * sqrt_r[r] if r == c else 0.0)
        Rs, ok = _cholesky_lower(0.5 * (r_eff + r_eff.T))
        if not ok:
            return STATUS_FAILED, x_pred, S_pred, 0.0, False, x_pred, S_pred
    else:
        for r in range(p):
            Rs[r, r] = sqrt_r[r]
    # (19)-(21) predicted measurement of the points around the prior
    for i in range(n):
        for r in range(n):
            dX[i, r] = root_n * S_pred[r, i]
            dX[n + i, r] = -root_n * S_pred[r, i]
    Z = np.empty((m, p))
    for i in range(m):
        for r in range(n):
            col[r] = x_pred[r] + dX[i, r]
        k = _ktot(col[n - 1], logistic, k_lo, k_hi, k_series)
        for q in range(p):
            s0 = 0.0
            s1 = 0.0
            for c in range(n):
                s0 += col[c] * c0[q, c]
                s1 += col[c] * ce[q, c]
            Z[i, q] = s0 + k * s1 + d[q] * hdot_end
    if not _all_finite(Z):
        return STATUS_FAILED, x_pred, S_pred, 0.0, False, x_pred, S_pred
    z_hat = np.zeros(p)
    for i in range(m):
        for q in range(p):
            z_hat[q] += Z[i, q]
    for q in range(p):
        z_hat[q] /= m
    # (22)-(23) S_z = tria([𝒵, √R]); (24)-(25) P_xz = χ 𝒵ᵀ
    zrows = np.empty((m + p, p))
    Zc = np.empty((m, p))
    for i in range(m):
        for q in range(p):
            Zc[i, q] = (Z[i, q] - z_hat[q]) * w
            zrows[i, q] = Zc[i, q]
    for r in range(p):
        for q in range(p):
            zrows[m + r, q] = Rs[q, r]
    S_z = _tria(zrows)
    chi = dX * w
    A = np.empty((p, n + 1))
    for q in range(p):
        for r in range(n):
            s = 0.0
            for i in range(m):
                s += chi[i, r] * Zc[i, q]
            A[q, r] = s
        A[q, n] = z[q] - z_hat[q]
    # (26), first solve: S_z A = [P_xzᵀ, ν], which also whitens ν for the NIS
    A = _solve_lower(S_z, A, False)
    nis = 0.0
    for q in range(p):
        nis += A[q, n] * A[q, n]
    for q in range(p):
        if S_z[q, q] == 0.0:
            nis = math.inf
    if not (math.isfinite(nis) and nis <= gate):
        return STATUS_OK, x_pred, S_pred, nis, False, x_pred, S_pred
    # (26), second solve: S_zᵀ Wᵀ = A → Wᵀ (p, n); (27) x̂ = x̄ + W ν; (28) Ŝ = tria([χ − W 𝒵, W √R])
    Wt = _solve_lower(S_z, A[:, :n].copy(), True)
    x_post = x_pred.copy()
    for r in range(n):
        s = 0.0
        for q in range(p):
            s += (z[q] - z_hat[q]) * Wt[q, r]
        x_post[r] += s
    prow = np.empty((m + p, n))
    for i in range(m):
        for r in range(n):
            s = 0.0
            for q in range(p):
                s += Zc[i, q] * Wt[q, r]
            prow[i, r] = chi[i, r] - s
    for i in range(p):
        for r in range(n):
            s = 0.0
            for q in range(p):
                s += Rs[q, i] * Wt[q, r]
            prow[m + i, r] = s
    S_post = _tria(prow)
    return STATUS_OK, x_pred, S_pred, nis, True, x_post, S_post


_warm = False


def warm_up() -> None:
    """Compile :func:`sckf_step` (or load it from numba's cache) now, once per process.

    The estimator calls this when it is built, so that a node's first filter
    step does not wait for the compiler: about 7 s the first time on a
    machine, a fraction of a second once numba's on-disk cache holds it.
    """
    global _warm
    if _warm:
        return
    n = 2
    eye = np.eye(n)
    one = np.ones(1)
    sckf_step(
        np.zeros(n), eye.copy(), np.zeros(1), 0.01, eye.copy(), eye.copy(), np.zeros(n), eye.copy(), np.ones(n),
        0.0, False, 0.0, 1.0, 1.0, 0.0, True, np.zeros(1), np.zeros((1, n)), np.zeros((1, n)), np.zeros(1), 0.0,
        one, np.zeros((2, 2)), False, math.inf,
    )  # fmt: skip
    _warm = True
