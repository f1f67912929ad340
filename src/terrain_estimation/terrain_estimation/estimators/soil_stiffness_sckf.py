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
from functools import partial
from typing import Any

import numpy as np

from terrain_estimation.estimators.soil_stiffness_kernels import (
    STATUS_FAILED,
    STATUS_OK,
    ModelOperands,
    StepData,
    compile_step,
    ktot,
    measurement_sums,
    model_operands,
    noise_factor,
    propagate,
    run_compiled_step,
    step_noise_factor,
    stiffness_map,
)
from terrain_estimation.filters.compiled_linalg import all_finite, mul, row_mean, solve_lower, tria
from terrain_estimation.jit import compiled

__all__ = ["STATUS_OK", "STATUS_FAILED", "ModelOperands", "model_operands", "run_step", "sckf_step", "warm_up"]


@compiled
def sckf_step(
    x: np.ndarray, S: np.ndarray, model: tuple[Any, ...], data: tuple[Any, ...]
) -> tuple[int, np.ndarray, np.ndarray, float, bool, np.ndarray, np.ndarray]:  # pragma: no cover
    """One SCKF step (predict through the sub-steps, then update unless ``step.update`` is False).

    Args:
        x, S: posterior mean ``(n,)`` and lower factor ``(n, n)`` of the previous step.
        model: the model's constants, a :class:`ModelOperands`'s fields as a plain tuple.
        data: the step's input, measurement, noise and gate, a :class:`StepData`'s fields as a plain tuple.

    Returns:
        ``(status, x̄, S̄, nis, accepted, x̂, Ŝ)``: the prior, the NIS of the
        update (0 without one; ``inf`` when ``S_z`` is singular), whether the
        update passed the gate, and the posterior (the prior itself when it
        did not). ``status`` :data:`STATUS_FAILED`: the step failed; the
        other outputs are then meaningless.
    """
    ops = ModelOperands(*model)
    step = StepData(*data)
    km = stiffness_map(ops)
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
        Xs[i] = propagate(col, step.us, step.dt, ops.a0, ops.e, ops.b, km)
    if not all_finite(Xs):
        return STATUS_FAILED, x.copy(), S.copy(), 0.0, False, x.copy(), S.copy()
    # √Q_k = √dt Γ_k(dt) G diag(σ) at the mean k_tot, its stiffness column replaced; stored transposed below χ*.
    L = noise_factor(x[n - 1], step.dt, step.q_last, ops.a0, ops.e, ops.g, ops.sigma_q, km)
    rows = np.empty((m + n, n))
    for r in range(n):
        for c in range(n):
            rows[m + c, r] = L[r, c]
    # (16)-(18)
    x_pred = row_mean(Xs)
    w = 1.0 / math.sqrt(m)
    for i in range(m):
        for r in range(n):
            rows[i, r] = (Xs[i, r] - x_pred[r]) * w
    S_pred = tria(rows)
    if not step.update:
        return STATUS_OK, x_pred, S_pred, 0.0, False, x_pred, S_pred
    z = step.z
    p = z.shape[0]
    # √R_eff: R + G Σ_ε Gᵀ, G = [C(x̄) B, D] at the predicted mean.
    Rs, ok = step_noise_factor(x_pred, ops, km, step)
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
        k = ktot(col[n - 1], km)
        for q in range(p):
            s0, s1 = measurement_sums(col, q, ops.c0, ops.ce)
            Z[i, q] = s0 + k * s1 + ops.d[q] * step.hdot_end
    if not all_finite(Z):
        return STATUS_FAILED, x_pred, S_pred, 0.0, False, x_pred, S_pred
    z_hat = row_mean(Z)
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
    A[:, :n] = mul(Zc.T, chi)  # P_xzᵀ = 𝒵 χᵀ
    for q in range(p):
        A[q, n] = z[q] - z_hat[q]
    # (26), first solve: S_z A = [P_xzᵀ, ν], which also whitens ν for the NIS
    A = solve_lower(S_z, A, False)
    nis = 0.0
    for q in range(p):
        nis += A[q, n] * A[q, n]
    for q in range(p):
        if S_z[q, q] == 0.0:
            nis = math.inf
    if not (math.isfinite(nis) and nis <= step.gate):
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
    prow[:m] = chi - mul(Zc, Wt)
    prow[m:] = mul(Rs.T, Wt)
    S_post = tria(prow)
    return STATUS_OK, x_pred, S_pred, nis, True, x_post, S_post


#: :func:`sckf_step` for a model (its :func:`model_operands` ``ops``) and a step's input as the model takes it:
#: ``run_step(ops, model, x, S, u, dt, z, sigma_eps, profile_noise, gate)`` (:func:`.run_compiled_step`).
run_step = partial(run_compiled_step, sckf_step)


def warm_up() -> None:
    """Compile :func:`sckf_step` (or load it from numba's cache) now, once per process (:func:`.compile_step`)."""
    compile_step(sckf_step)
