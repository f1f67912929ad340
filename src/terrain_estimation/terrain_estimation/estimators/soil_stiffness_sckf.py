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
from typing import Any

import numpy as np

from terrain_estimation.estimators.soil_stiffness_kernels import (
    STATUS_FAILED,
    STATUS_OK,
    ModelOperands,
    ktot,
    measurement_noise_factor,
    model_operands,
    noise_factor,
    propagate,
    step_arguments,
    warm_up_arguments,
)
from terrain_estimation.filters.compiled_linalg import all_finite, solve_lower, tria
from terrain_estimation.jit import compiled

__all__ = ["STATUS_OK", "STATUS_FAILED", "ModelOperands", "model_operands", "run_step", "sckf_step", "warm_up"]


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
        *step_arguments(ops, model, u, dt, z, sigma_eps, profile_noise, gate),
    )


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
    # (14) cubature points X_i = x ± √n S[:, i]
    dX = np.empty((m, n))
    for i in range(n):
        for r in range(n):
            dX[i, r] = root_n * S[r, i]
            dX[n + i, r] = -root_n * S[r, i]
    # (15) through the sub-steps: x ← Φ(k_i) x + Γ(k_i) B ḣ_j, the stiffness state held.
    Xs = np.empty((m, n))
    col = np.empty(n)
    for i in range(m):
        for r in range(n):
            col[r] = x[r] + dX[i, r]
        Xs[i] = propagate(col, us, dt, a0, e, b, logistic, k_lo, k_hi, k_series)
    if not all_finite(Xs):
        return STATUS_FAILED, x.copy(), S.copy(), 0.0, False, x.copy(), S.copy()
    # √Q_k = √dt Γ_k(dt) G diag(σ) at the mean k_tot, its stiffness column replaced; stored transposed below χ*.
    L = noise_factor(x[n - 1], dt, a0, e, g, sigma_q, q_last, logistic, k_lo, k_hi, k_series, k_floor)
    rows = np.empty((m + n, n))
    for r in range(n):
        for c in range(n):
            rows[m + c, r] = L[r, c]
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
    S_pred = tria(rows)
    if not update:
        return STATUS_OK, x_pred, S_pred, 0.0, False, x_pred, S_pred
    p = z.shape[0]
    # √R_eff: R + G Σ_ε Gᵀ, G = [C(x̄) B, D] at the predicted mean.
    Rs, ok = measurement_noise_factor(
        x_pred[n - 1], p, b, c0, ce, d, sqrt_r, sigma_eps, profile_noise, logistic, k_lo, k_hi, k_series, k_floor
    )
    if not ok:
        return STATUS_FAILED, x_pred, S_pred, 0.0, False, x_pred, S_pred
    # (19)-(21) predicted measurement of the points around the prior
    for i in range(n):
        for r in range(n):
            dX[i, r] = root_n * S_pred[r, i]
            dX[n + i, r] = -root_n * S_pred[r, i]
    Z = np.empty((m, p))
    for i in range(m):
        for r in range(n):
            col[r] = x_pred[r] + dX[i, r]
        k = ktot(col[n - 1], logistic, k_lo, k_hi, k_series)
        for q in range(p):
            s0 = 0.0
            s1 = 0.0
            for c in range(n):
                s0 += col[c] * c0[q, c]
                s1 += col[c] * ce[q, c]
            Z[i, q] = s0 + k * s1 + d[q] * hdot_end
    if not all_finite(Z):
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
    S_z = tria(zrows)
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
    A = solve_lower(S_z, A, False)
    nis = 0.0
    for q in range(p):
        nis += A[q, n] * A[q, n]
    for q in range(p):
        if S_z[q, q] == 0.0:
            nis = math.inf
    if not (math.isfinite(nis) and nis <= gate):
        return STATUS_OK, x_pred, S_pred, nis, False, x_pred, S_pred
    # (26), second solve: S_zᵀ Wᵀ = A → Wᵀ (p, n); (27) x̂ = x̄ + W ν; (28) Ŝ = tria([χ − W 𝒵, W √R])
    Wt = solve_lower(S_z, A[:, :n].copy(), True)
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
    S_post = tria(prow)
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
    sckf_step(*warm_up_arguments())
    _warm = True
