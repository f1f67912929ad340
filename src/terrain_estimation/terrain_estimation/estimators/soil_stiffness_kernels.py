"""The bilinear k_tot models of :mod:`~terrain_estimation.models.quarter_car`, compiled: what the SCKF and EKF share.

The soil-stiffness estimator runs its default SCKF
(:mod:`.soil_stiffness_sckf`) and its EKF (:mod:`.soil_stiffness_ekf`) as one
compiled call per filter step. Both take the model as the constants of
:class:`ModelOperands` (``ẋ = (A0 + k_tot E) x + B ḣ``, ``z = C(x) x + D ḣ``,
MODELS.md A.1–A.4) and evaluate it with the kernels here: the k_tot the
dynamics use for a stiffness-state value (:func:`ktot`, the model's
``ktot_of``) and its slope (:func:`ktot_slope`), and the ``"taylor4"``
discretisation (:func:`taylor4`). The models' numpy methods remain the
reference (``test/test_soil_stiffness_sckf.py``, ``test/test_soil_stiffness_ekf.py``).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from terrain_estimation.filters.compiled_linalg import cholesky_lower, matmul
from terrain_estimation.jit import compiled
from terrain_estimation.models.quarter_car_discrete import hdot_at_end, substep_inputs

__all__ = [
    "NO_MEASUREMENT",
    "measurement_noise_factor",
    "noise_factor",
    "propagate",
    "step_arguments",
    "warm_up_arguments",
    "STATUS_FAILED",
    "STATUS_OK",
    "ModelOperands",
    "ktot",
    "ktot_slope",
    "model_operands",
    "taylor4",
]

#: The compiled step ran (its posterior may still be rejected by the gate).
STATUS_OK = 0
#: A non-finite propagated or predicted point (or Jacobian), or an ``R_eff``
#: that is not positive definite: the step failed (the public filters raise
#: ValueError / LinAlgError there).
STATUS_FAILED = 1


class ModelOperands(NamedTuple):
    """The constants of a bilinear k_tot model that the compiled steps take (contiguous float64 copies)."""

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
    paper_jacobian: bool


def model_operands(model: Any) -> ModelOperands | None:
    """:class:`ModelOperands` of a ``QuarterCarModel`` / ``LRVModel``, None if the compiled steps cannot run it.

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
        paper_jacobian=model._jacobian_form == "paper",
    )


#: ``z`` of a predict-only step (not read).
NO_MEASUREMENT = np.zeros(1)


@compiled
def ktot(v: float, logistic: bool, lo: float, hi: float, k_series: float) -> float:  # pragma: no cover
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
def ktot_slope(v: float, logistic: bool, lo: float, hi: float, k_series: float) -> float:  # pragma: no cover
    """``dk_tot/dv`` of :func:`ktot` at ``v`` (the model's ``ktot_slope``): 0 where clamped or clipped."""
    if logistic:
        if not lo < v < hi:
            return 0.0
        sig = 1.0 / (1.0 + math.exp(-v))
        return k_series * sig * (1.0 - sig)
    return 1.0 if lo < v < hi else 0.0


@compiled
def taylor4(ad: np.ndarray, phi: np.ndarray, gam_over_delta: np.ndarray) -> None:  # pragma: no cover
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
        matmul(ad, p, buf)
        for i in range(n):
            for j in range(n):
                p[i, j] = buf[i, j] / divisors[0] + (1.0 if i == j else 0.0)
        matmul(ad, q, buf)
        for i in range(n):
            for j in range(n):
                q[i, j] = buf[i, j] / divisors[1] + (1.0 if i == j else 0.0)
    phi[:, :] = p
    gam_over_delta[:, :] = q


@compiled
def propagate(
    x: np.ndarray,
    us: np.ndarray,
    dt: float,
    a0: np.ndarray,
    e: np.ndarray,
    b: np.ndarray,
    logistic: bool,
    k_lo: float,
    k_hi: float,
    k_series: float,
) -> np.ndarray:  # pragma: no cover
    """The model's ``f`` for one state: ``x ← Φ(k) x + Γ(k) B ḣ_j`` over the sub-steps, the stiffness state held."""
    n = x.shape[0]
    delta = dt / us.shape[0]
    k = ktot(x[n - 1], logistic, k_lo, k_hi, k_series)
    a = np.empty((n, n))
    for r in range(n):
        for c in range(n):
            a[r, c] = (k * e[r, c] + a0[r, c]) * delta
    phi = np.empty((n, n))
    gam = np.empty((n, n))
    taylor4(a, phi, gam)
    gb = np.empty(n)
    for r in range(n):
        s = 0.0
        for c in range(n):
            s += gam[r, c] * delta * b[c]
        gb[r] = s
    col = x.copy()
    nxt = np.empty(n)
    for j in range(us.shape[0]):
        for r in range(n):
            s = 0.0
            for c in range(n):
                s += phi[r, c] * col[c]
            nxt[r] = s + gb[r] * us[j]
        col[:] = nxt
    col[n - 1] = x[n - 1]
    return col


@compiled
def noise_factor(
    k_mean: float,
    dt: float,
    a0: np.ndarray,
    e: np.ndarray,
    g: np.ndarray,
    sigma_q: np.ndarray,
    q_last: float,
    logistic: bool,
    k_lo: float,
    k_hi: float,
    k_series: float,
    k_floor: float,
) -> np.ndarray:  # pragma: no cover
    """``√Q_k = √dt Γ_k(dt) G diag(σ)`` at the mean stiffness state ``k_mean``, its stiffness column replaced by
    ``q_last e_k`` (the model's ``process_noise_sqrt``); ``(n, n)``."""
    n = a0.shape[0]
    k_c = ktot(k_mean, logistic, k_lo, k_hi, k_series) if math.isfinite(k_mean) else k_floor
    a = np.empty((n, n))
    for r in range(n):
        for c in range(n):
            a[r, c] = (k_c * e[r, c] + a0[r, c]) * dt
    phi = np.empty((n, n))
    gam = np.empty((n, n))
    taylor4(a, phi, gam)
    L = np.empty((n, n))
    sq_dt = math.sqrt(dt)
    for r in range(n):
        for c in range(n):
            s = 0.0
            for j in range(n):
                s += gam[r, j] * dt * g[j, c]
            L[r, c] = sq_dt * s * sigma_q[c]
    for r in range(n):
        L[r, n - 1] = 0.0
    L[n - 1, n - 1] = q_last
    return L


@compiled
def measurement_noise_factor(
    k_mean: float,
    p: int,
    b: np.ndarray,
    c0: np.ndarray,
    ce: np.ndarray,
    d: np.ndarray,
    sqrt_r: np.ndarray,
    sigma_eps: np.ndarray,
    profile_noise: bool,
    logistic: bool,
    k_lo: float,
    k_hi: float,
    k_series: float,
    k_floor: float,
) -> tuple[np.ndarray, bool]:  # pragma: no cover
    """Lower factor of the first ``p`` measurements' noise: ``√R`` (diagonal), or with ``profile_noise`` the
    Cholesky factor of ``R_eff = R + G Σ_ε Gᵀ``, ``G = [C(x̄) B, D]`` at the mean stiffness state ``k_mean``
    (the estimator's ``_measurement_noise_sqrt``); ``ok`` False where ``R_eff`` is not positive definite."""
    n = b.shape[0]
    Rs = np.zeros((p, p))
    if not profile_noise:
        for r in range(p):
            Rs[r, r] = sqrt_r[r]
        return Rs, True
    k_p = ktot(k_mean, logistic, k_lo, k_hi, k_series) if math.isfinite(k_mean) else k_floor
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
    return cholesky_lower(0.5 * (r_eff + r_eff.T))


def step_arguments(
    ops: ModelOperands,
    model: Any,
    u: Any,
    dt: float,
    z: np.ndarray | None,
    sigma_eps: np.ndarray,
    profile_noise: bool,
    gate: float | None,
) -> tuple[Any, ...]:
    """The arguments after the state (mean and factor or covariance) that the compiled steps take, in their order.

    Args:
        ops, model: the model's :func:`model_operands` and the model (for its stiffness noise over ``dt``).
        u: the step's sub-step ḣ ``(N,)`` or a ``StepInput`` (ḣ at the measurement time for a feed-through).
        dt: the filter step (s).
        z: the measured accelerations ``(p,)``; None for a predict-only step.
        sigma_eps, profile_noise: ``Σ_ε`` and whether it enters ``R``.
        gate: the filter's NIS gate (None: none).
    """
    return (
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
        NO_MEASUREMENT if z is None else z,
        ops.c0,
        ops.ce,
        ops.d,
        hdot_at_end(u) if ops.feedthrough else 0.0,
        ops.sqrt_r,
        sigma_eps,
        profile_noise,
        math.inf if gate is None else float(gate),
    )


def warm_up_arguments() -> tuple[Any, ...]:
    """A 2-state mean, factor and :func:`step_arguments` of the types a real step passes: calling a compiled step
    with them compiles the one signature every step uses."""
    n = 2
    eye = np.eye(n)
    return (
        np.zeros(n), eye.copy(), np.zeros(1), 0.01, eye.copy(), eye.copy(), np.zeros(n), eye.copy(), np.ones(n),
        0.0, False, 0.0, 1.0, 1.0, 0.0, True, np.zeros(1), np.zeros((1, n)), np.zeros((1, n)), np.zeros(1), 0.0,
        np.ones(1), np.zeros((2, 2)), False, math.inf,
    )  # fmt: skip
