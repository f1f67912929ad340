"""The soil-stiffness estimator's EKF step, compiled (numba).

One call runs a whole filter step of the extended Kalman filter
(:class:`~terrain_estimation.filters.ekf.ExtendedKalmanFilter`, MODELS.md A.6,
eqs. A.7–A.9) on the bilinear k_tot models of
:mod:`terrain_estimation.models.quarter_car` (quarter car and LRV, A.1–A.4)
with the ``"taylor4"`` discretisation:

* prediction: the mean through the sub-steps of the road (the model's ``f``),
  the transition Jacobian through the same sub-steps (``transition_jacobian``,
  its ``"exact"`` form with the k-derivatives of ``Φ`` and ``Γ`` from the block
  matrix ``[[A, E], [0, A]]``, or the ``"paper"`` form, the product of the
  discretised ``A_x``), the process-noise factor ``√Q_k`` at the mean k_tot
  (``process_noise_sqrt``) and ``P̄ = F P Fᵀ + √Q_k √Q_kᵀ``;
* the measurement noise ``R``, with the profile-error term ``G Σ_ε Gᵀ`` at the
  predicted mean and its Cholesky factor (the estimator's ``R_eff``);
* the linearised update with its NIS gate and the Joseph form
  (``filters.kalman.joseph_update``).

Why: the numpy form of a step (the Jacobian's loop over the sub-steps, the
model's methods and the Joseph update on 5×5 arrays) is mostly per-call
overhead; issue 23 measured 343 µs per step, and a 100-run quarter-car Monte
Carlo that includes the EKF about 70 s against 18.5 s with the SCKF alone
(``terrain-bench --only qc_monte_carlo`` prints both paths). The same mathematics as the public
``predict``/``update`` with the model's methods, which remain the reference and
run for ``"expm"`` or any filter object passed in: the small products, the
Cholesky factor and the triangular solves are loops here where numpy calls BLAS
and LAPACK, so results agree to rounding (about 1e-13 relative per step, 1e-12
over a ride), not bit for bit (``test/test_soil_stiffness_ekf.py``).
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

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
    advance,
    compile_step,
    input_gain,
    ktot,
    ktot_slope,
    measurement_sums,
    noise_factor,
    propagate,
    run_compiled_step,
    step_noise_factor,
    stiffness_map,
    taylor4,
    transition_matrices,
)
from terrain_estimation.filters.compiled_linalg import (
    all_finite,
    cholesky_lower,
    matmul,
    mul,
    mul_bt,
    solve_lower,
    symmetrise,
)
from terrain_estimation.jit import compiled

__all__ = ["ekf_step", "run_ekf_step", "warm_up_ekf"]


@compiled
def _transition(
    x: np.ndarray, us: np.ndarray, dt: float, ops: ModelOperands
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """The model's ``f(x, u, dt)`` and ``transition_jacobian(x, u, dt)`` at one state, through the sub-steps."""
    n = x.shape[0]
    nsub = us.shape[0]
    delta = dt / nsub
    e = ops.e
    b = ops.b
    km = stiffness_map(ops)
    k_raw = x[n - 1]
    k = ktot(k_raw, km)
    slope = ktot_slope(k_raw, km)
    x_f = propagate(x, us, dt, ops.a0, e, b, km)
    # The Jacobian runs its own recursion of x_j, as transition_jacobian does.
    a, phi, gam = transition_matrices(k, delta, ops.a0, e)
    gb = input_gain(gam, delta, b)
    nxt = np.empty(n)
    jac = np.eye(n)
    xj = x.copy()
    tmp = np.empty((n, n))
    if ops.paper_jacobian:
        # The product over sub-steps of A_x(x_j) discretised, A_x = A with ∂(A(x) x)/∂k in its last column.
        a_x = np.empty((n, n))
        phi_x = np.empty((n, n))
        gam_x = np.empty((n, n))
        for j in range(nsub):
            for r in range(n):
                s = 0.0
                for c in range(n):
                    s += e[r, c] * xj[c]
                for c in range(n):
                    a_x[r, c] = a[r, c]
                a_x[r, n - 1] += s * slope
            taylor4(a_x * delta, phi_x, gam_x)
            matmul(phi_x, jac, tmp)
            jac[:, :] = tmp
            advance(phi, gb, xj, us[j], nxt)
            xj[:] = nxt
            xj[n - 1] = k_raw
        return x_f, jac
    # Exact: the block [[A, E], [0, A]] discretised gives ∂Φ/∂k and ∂Γ/∂k as its upper-right blocks.
    m = 2 * n
    block = np.zeros((m, m))
    for r in range(n):
        for c in range(n):
            block[r, c] = a[r, c] * delta
            block[n + r, n + c] = a[r, c] * delta
            block[r, n + c] = e[r, c] * delta
    phi_b = np.empty((m, m))
    gam_b = np.empty((m, m))
    taylor4(block, phi_b, gam_b)
    dgb = np.empty(n)
    for r in range(n):
        s0 = 0.0
        s1 = 0.0
        for c in range(n):
            s0 += gam_b[r, c] * delta * b[c]
            s1 += gam_b[r, n + c] * delta * b[c]
        gb[r] = s0
        dgb[r] = s1
    sens = np.empty(n)
    for j in range(nsub):
        for r in range(n):
            s0 = 0.0
            s1 = 0.0
            for c in range(n):
                s0 += phi_b[r, n + c] * xj[c]
                s1 += phi_b[r, c] * xj[c]
            sens[r] = (s0 + dgb[r] * us[j]) * slope
            nxt[r] = s1 + gb[r] * us[j]
        # J ← Φ J + sens ⊗ J[-1]
        for r in range(n):
            for c in range(n):
                s = 0.0
                for i in range(n):
                    s += phi_b[r, i] * jac[i, c]
                tmp[r, c] = s + sens[r] * jac[n - 1, c]
        jac[:, :] = tmp
        xj[:] = nxt
        xj[n - 1] = k_raw
    for c in range(n):
        jac[n - 1, c] = 0.0
    jac[n - 1, n - 1] = 1.0
    return x_f, jac


@compiled
def ekf_step(
    x: np.ndarray, P: np.ndarray, model: tuple[Any, ...], data: tuple[Any, ...]
) -> tuple[int, np.ndarray, np.ndarray, float, bool, np.ndarray, np.ndarray]:  # pragma: no cover
    """One EKF step (predict through the sub-steps, then update unless ``step.update`` is False).

    Args:
        x, P: posterior mean ``(n,)`` and covariance ``(n, n)`` of the previous step.
        model: the model's constants, a :class:`ModelOperands`'s fields as a plain tuple
            (``paper_jacobian``: the ``"paper"`` transition Jacobian).
        data: the step's input, measurement, noise and gate, a :class:`StepData`'s fields as a plain tuple.

    Returns:
        ``(status, x̄, P̄, nis, accepted, x̂, P̂)``: the prior, the NIS of the
        update (0 without one; ``inf`` when ``S`` is not positive definite),
        whether the update passed the gate, and the posterior (the prior
        itself when it did not). ``status`` :data:`STATUS_FAILED`: a
        non-finite ``f``, Jacobian or ``h``, or an ``R_eff`` that is not
        positive definite (where the public EKF raises); the other outputs are
        then meaningless.
    """
    ops = ModelOperands(*model)
    step = StepData(*data)
    km = stiffness_map(ops)
    n = x.shape[0]
    x_pred, F = _transition(x, step.us, step.dt, ops)
    if not (all_finite(x_pred) and all_finite(F)):
        return STATUS_FAILED, x.copy(), P.copy(), 0.0, False, x.copy(), P.copy()
    # √Q_k = √dt Γ_k(dt) G diag(σ) at the mean k_tot, its stiffness column replaced (process_noise_sqrt).
    L = noise_factor(x[n - 1], step.dt, step.q_last, ops.a0, ops.e, ops.g, ops.sigma_q, km)
    # P̄ = F P Fᵀ + L Lᵀ, symmetrised.
    P_pred = symmetrise(mul_bt(mul(F, P), F) + mul_bt(L, L))
    if not step.update:
        return STATUS_OK, x_pred, P_pred, 0.0, False, x_pred, P_pred
    # R, or R_eff = R + G Σ_ε Gᵀ with G = [C(x̄) B, D] at the predicted mean; R is used as √R √Rᵀ.
    Rs, ok = step_noise_factor(x_pred, ops, km, step)
    if not ok:
        return STATUS_FAILED, x_pred, P_pred, 0.0, False, x_pred, P_pred
    R = mul_bt(Rs, Rs)
    # ẑ = C(x̄) x̄ + D ḣ(t) and H = ∂h/∂x at x̄ (measurement_jacobian).
    z = step.z
    p = z.shape[0]
    k_raw = x_pred[n - 1]
    k = ktot(k_raw, km)
    slope = ktot_slope(k_raw, km)
    z_hat = np.empty(p)
    H = np.empty((p, n))
    for q in range(p):
        s0, s1 = measurement_sums(x_pred, q, ops.c0, ops.ce)
        for c in range(n):
            H[q, c] = ops.c0[q, c] + k * ops.ce[q, c]
        z_hat[q] = s0 + k * s1 + ops.d[q] * step.hdot_end
        H[q, n - 1] += s1 * slope
    if not (all_finite(z_hat) and all_finite(H)):
        return STATUS_FAILED, x_pred, P_pred, 0.0, False, x_pred, P_pred
    # Joseph-form update (joseph_update): S = H P̄ Hᵀ + R, L_S = chol(S), [Y, w] = L_S⁻¹ [P_xzᵀ, ν], NIS = wᵀw.
    nu = z - z_hat
    Pxz = mul_bt(P_pred, H)
    Szz = symmetrise(mul(H, Pxz) + R)
    Ls, ok = cholesky_lower(Szz)
    if not ok:
        return STATUS_OK, x_pred, P_pred, math.inf, False, x_pred, P_pred
    rhs = np.empty((p, n + 1))
    for q in range(p):
        for c in range(n):
            rhs[q, c] = Pxz[c, q]
        rhs[q, n] = nu[q]
    sol = solve_lower(Ls, rhs, False)
    nis = 0.0
    for q in range(p):
        nis += sol[q, n] * sol[q, n]
    if not (math.isfinite(nis) and nis <= step.gate):
        return STATUS_OK, x_pred, P_pred, nis, False, x_pred, P_pred
    Y = sol[:, :n].copy()
    K = solve_lower(Ls, Y, True).T.copy()
    I_KH = np.eye(n) - mul(K, H)
    P_post = symmetrise(mul_bt(mul(I_KH, P_pred), I_KH) + mul_bt(mul(K, R), K))
    x_post = x_pred.copy()
    for c in range(n):
        s = 0.0
        for q in range(p):
            s += Y[q, c] * sol[q, n]
        x_post[c] += s
    return STATUS_OK, x_pred, P_pred, nis, True, x_post, P_post


#: :func:`ekf_step` for a model (its ``model_operands`` ``ops``) and a step's input as the model takes it:
#: ``run_ekf_step(ops, model, x, P, u, dt, z, sigma_eps, profile_noise, gate)`` (:func:`.run_compiled_step`).
run_ekf_step = partial(run_compiled_step, ekf_step)


def warm_up_ekf() -> None:
    """Compile :func:`ekf_step` (or load it from numba's cache) now, once per process (:func:`.compile_step`).

    The estimator calls this when it is built with the EKF.
    """
    compile_step(ekf_step)
