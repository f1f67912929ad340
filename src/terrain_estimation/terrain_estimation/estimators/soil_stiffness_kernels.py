"""The bilinear k_tot models of :mod:`~terrain_estimation.models.quarter_car`, compiled: what the SCKF and EKF share.

The soil-stiffness estimator runs its default SCKF
(:mod:`.soil_stiffness_sckf`) and its EKF (:mod:`.soil_stiffness_ekf`) as one
compiled call per filter step, ``step(x, factor, ops, step)``. Both take the
model as the constants of :class:`ModelOperands` (``ẋ = (A0 + k_tot E) x + B ḣ``,
``z = C(x) x + D ḣ``, MODELS.md A.1–A.4) and the step's input, measurement,
noise and gate as a :class:`StepData` (:func:`run_compiled_step` builds it from
a step's input as the model takes it), and evaluate the model with the kernels
here: the k_tot the dynamics use for a stiffness-state value (:func:`ktot`,
the model's ``ktot_of``) and its slope (:func:`ktot_slope`), the ``"taylor4"``
discretisation (:func:`taylor4`, :func:`transition_matrices`), the sub-steps
(:func:`propagate`), the noise factors and the measurement rows. The models'
numpy methods remain the reference (``test/test_soil_stiffness_sckf.py``,
``test/test_soil_stiffness_ekf.py``).

The compiled steps take ``ops`` and ``step`` as plain tuples (the fields in
order) and make the named tuples inside: numba's dispatcher types a plain
tuple of arrays and numbers in C, but a named tuple through Python, which
cost about 8 µs a call, a fifth of a whole step.
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
    "advance",
    "compile_step",
    "input_gain",
    "measurement_noise_factor",
    "measurement_sums",
    "noise_factor",
    "propagate",
    "run_compiled_step",
    "step_noise_factor",
    "transition_matrices",
    "warm_up_arguments",
    "STATUS_FAILED",
    "STATUS_OK",
    "ModelOperands",
    "StepData",
    "StiffnessMap",
    "ktot",
    "ktot_or_floor",
    "ktot_slope",
    "model_operands",
    "stiffness_map",
    "taylor4",
]

#: The compiled step ran (its posterior may still be rejected by the gate).
STATUS_OK = 0
#: A non-finite propagated or predicted point (or Jacobian), or an ``R_eff``
#: that is not positive definite: the step failed (the public filters raise
#: ValueError / LinAlgError there).
STATUS_FAILED = 1


class ModelOperands(NamedTuple):
    """The constants of a bilinear k_tot model that the compiled steps take (contiguous float64 copies).

    Attributes:
        a0, e, b, g: the model's ``A0``, ``E`` ``(n, n)``, ``B`` ``(n,)``, ``G`` ``(n, n)``.
        sigma_q: process-noise standard deviations ``(n,)`` (column scale of ``√Q_k``).
        logistic, k_lo, k_hi, k_series: ``ktot_of``: clamp into ``[k_lo, k_hi]``, or
            ``k_series · logistic`` of the value clipped into ``[k_lo, k_hi]``.
        k_floor: the k_tot a non-finite mean stands for (the model's lower clamp).
        c0, ce, d: the model's measurement rows (``z = (C0 + k_tot Ce) x + D ḣ``).
        sqrt_r: the accelerometers' standard deviations (``√R`` is its diagonal).
        feedthrough: ``D`` is not zero (ḣ at the measurement time enters ``z``).
        paper_jacobian: the EKF's ``"paper"`` transition Jacobian instead of the exact one.
    """

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


class StepData(NamedTuple):
    """What one compiled filter step takes besides the previous posterior and the model's constants.

    Attributes:
        us: ḣ (m/s) of the ``N`` equal sub-steps spanning ``dt``, finite ``(N,)``.
        dt: filter step (s).
        q_last: ``√Q_k``'s last diagonal entry (the stiffness random walk over ``dt``).
        update: False for a predict-only step.
        z: measurement ``(p,)``, finite (p = 1: the body accelerometer alone); not read without an update.
        hdot_end: ḣ at the measurement time (the ``D ḣ`` feed-through; 0 without one).
        sigma_eps: ``Σ_ε`` ``(2, 2)`` of the elevation / ḣ errors of the road.
        profile_noise: add ``G Σ_ε Gᵀ`` to ``R`` (``profile_noise_std > 0``).
        gate: NIS threshold (``inf``: no gate).
    """

    us: np.ndarray
    dt: float
    q_last: float
    update: bool
    z: np.ndarray
    hdot_end: float
    sigma_eps: np.ndarray
    profile_noise: bool
    gate: float


class StiffnessMap(NamedTuple):
    """The map from the stiffness state to the k_tot the dynamics use: :class:`ModelOperands`'s numbers for it.

    Numbers only: the kernels that run per cubature point take it, and the arrays they need, instead of the
    whole :class:`ModelOperands`, whose eight arrays numba reference-counts at every call (about 0.7 µs a
    step through the points' sub-steps alone).
    """

    logistic: bool
    k_lo: float
    k_hi: float
    k_series: float
    k_floor: float


@compiled
def stiffness_map(ops: ModelOperands) -> StiffnessMap:  # pragma: no cover
    """The :class:`StiffnessMap` of a model's constants."""
    return StiffnessMap(ops.logistic, ops.k_lo, ops.k_hi, ops.k_series, ops.k_floor)


#: ``z`` of a predict-only step (not read).
NO_MEASUREMENT = np.zeros(1)


@compiled
def ktot(v: float, km: StiffnessMap) -> float:  # pragma: no cover
    """k_tot the dynamics use for a last-state value (``ktot_of``): clamp, or logistic of the clipped value."""
    # Written as comparisons so that a NaN stays NaN, as min(max(v, lo), hi) keeps it.
    c = v
    if c < km.k_lo:
        c = km.k_lo
    elif c > km.k_hi:
        c = km.k_hi
    if km.logistic:
        return km.k_series / (1.0 + math.exp(-c))
    return c


@compiled
def ktot_or_floor(v: float, km: StiffnessMap) -> float:  # pragma: no cover
    """:func:`ktot` of a mean last-state value, the lower clamp ``k_floor`` where it is not finite."""
    return ktot(v, km) if math.isfinite(v) else km.k_floor


@compiled
def ktot_slope(v: float, km: StiffnessMap) -> float:  # pragma: no cover
    """``dk_tot/dv`` of :func:`ktot` at ``v`` (the model's ``ktot_slope``): 0 where clamped or clipped."""
    lo, hi = km.k_lo, km.k_hi
    if km.logistic:
        if not lo < v < hi:
            return 0.0
        sig = 1.0 / (1.0 + math.exp(-v))
        return km.k_series * sig * (1.0 - sig)
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
def transition_matrices(
    k: float, delta: float, a0: np.ndarray, e: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """``A = A0 + k E`` and the ``"taylor4"`` ``Φ``, ``Γ/δ`` of ``A δ`` (the model's ``discretise``)."""
    n = a0.shape[0]
    a = np.empty((n, n))
    for r in range(n):
        for c in range(n):
            a[r, c] = a0[r, c] + k * e[r, c]
    phi = np.empty((n, n))
    gam = np.empty((n, n))
    taylor4(a * delta, phi, gam)
    return a, phi, gam


@compiled
def input_gain(gam: np.ndarray, delta: float, b: np.ndarray) -> np.ndarray:  # pragma: no cover
    """``Γ B`` ``(n,)`` of a sub-step from :func:`taylor4`'s ``Γ/δ``."""
    n = b.shape[0]
    gb = np.empty(n)
    for r in range(n):
        s = 0.0
        for c in range(n):
            s += gam[r, c] * delta * b[c]
        gb[r] = s
    return gb


@compiled
def advance(phi: np.ndarray, gb: np.ndarray, x: np.ndarray, u: float, out: np.ndarray) -> None:  # pragma: no cover
    """One sub-step ``out = Φ x + Γ B u`` (``out`` must not alias ``x``)."""
    n = x.shape[0]
    for r in range(n):
        s = 0.0
        for c in range(n):
            s += phi[r, c] * x[c]
        out[r] = s + gb[r] * u


@compiled
def propagate(
    x: np.ndarray, us: np.ndarray, dt: float, a0: np.ndarray, e: np.ndarray, b: np.ndarray, km: StiffnessMap
) -> np.ndarray:  # pragma: no cover
    """The model's ``f`` for one state: ``x ← Φ(k) x + Γ(k) B ḣ_j`` over the sub-steps, the stiffness state held."""
    n = x.shape[0]
    delta = dt / us.shape[0]
    _, phi, gam = transition_matrices(ktot(x[n - 1], km), delta, a0, e)
    gb = input_gain(gam, delta, b)
    col = x.copy()
    nxt = np.empty(n)
    for j in range(us.shape[0]):
        advance(phi, gb, col, us[j], nxt)
        col[:] = nxt
    col[n - 1] = x[n - 1]
    return col


@compiled
def noise_factor(
    k_mean: float,
    dt: float,
    q_last: float,
    a0: np.ndarray,
    e: np.ndarray,
    g: np.ndarray,
    sigma_q: np.ndarray,
    km: StiffnessMap,
) -> np.ndarray:  # pragma: no cover
    """``√Q_k = √dt Γ_k(dt) G diag(σ)`` at the mean stiffness state ``k_mean``, its stiffness column replaced by
    ``q_last e_k`` (the model's ``process_noise_sqrt``); ``(n, n)``."""
    n = a0.shape[0]
    _, _, gam = transition_matrices(ktot_or_floor(k_mean, km), dt, a0, e)
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
def measurement_sums(x: np.ndarray, q: int, c0: np.ndarray, ce: np.ndarray) -> tuple[float, float]:  # pragma: no cover
    """``(C0 x, Ce x)`` of measurement ``q`` at one state: ``z_q = C0 x + k_tot Ce x + D_q ḣ``."""
    s0 = 0.0
    s1 = 0.0
    for c in range(x.shape[0]):
        s0 += x[c] * c0[q, c]
        s1 += x[c] * ce[q, c]
    return s0, s1


@compiled
def measurement_noise_factor(
    k_mean: float,
    b: np.ndarray,
    c0: np.ndarray,
    ce: np.ndarray,
    d: np.ndarray,
    sqrt_r: np.ndarray,
    km: StiffnessMap,
    p: int,
    sigma_eps: np.ndarray,
    profile_noise: bool,
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
    k_p = ktot_or_floor(k_mean, km)
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


@compiled
def step_noise_factor(
    x_pred: np.ndarray, ops: ModelOperands, km: StiffnessMap, step: StepData
) -> tuple[np.ndarray, bool]:  # pragma: no cover
    """:func:`measurement_noise_factor` of a step's measurement ``step.z`` at the predicted mean ``x_pred``:
    ``√R``, or with ``step.profile_noise`` the factor of ``R_eff = R + G Σ_ε Gᵀ``, ``G = [C(x̄) B, D]``
    (the update of both compiled filters); ``ok`` False where ``R_eff`` is not positive definite."""
    return measurement_noise_factor(
        x_pred[x_pred.shape[0] - 1],
        ops.b,
        ops.c0,
        ops.ce,
        ops.d,
        ops.sqrt_r,
        km,
        step.z.shape[0],
        step.sigma_eps,
        step.profile_noise,
    )


def run_compiled_step(
    kernel: Any,
    ops: ModelOperands,
    model: Any,
    x: Any,
    factor: Any,
    u: Any,
    dt: float,
    z: np.ndarray | None,
    sigma_eps: np.ndarray,
    profile_noise: bool,
    gate: float | None,
) -> tuple[int, np.ndarray, np.ndarray, float, bool, np.ndarray, np.ndarray]:
    """A compiled step ``kernel(x, factor, ops, step)`` for ``model`` (its :func:`model_operands` ``ops``) and a
    step's input as the model takes it (the :class:`StepData` ``step``), both passed as plain tuples.

    Args:
        kernel: the compiled step (the SCKF's or the EKF's).
        ops, model: the model's :func:`model_operands` and the model (for its stiffness noise over ``dt``).
        x, factor: the previous posterior (mean, and the filter's lower factor or covariance).
        u: the step's sub-step ḣ ``(N,)`` or a ``StepInput`` (ḣ at the measurement time for a feed-through).
        dt: the filter step (s).
        z: the measured accelerations ``(p,)``; None for a predict-only step.
        sigma_eps, profile_noise: ``Σ_ε`` and whether it enters ``R``.
        gate: the filter's NIS gate (None: none).

    Returns:
        ``kernel``'s tuple ``(status, x̄, prior factor, nis, accepted, x̂, posterior factor)``.
    """
    # A StepData's fields, in order, as a plain tuple (see the note on the compiled steps' arguments).
    step = (
        substep_inputs(u),
        dt,
        model._stiffness_noise_sqrt(dt),
        z is not None,
        NO_MEASUREMENT if z is None else z,
        hdot_at_end(u) if ops.feedthrough else 0.0,
        sigma_eps,
        profile_noise,
        math.inf if gate is None else float(gate),
    )
    x = np.ascontiguousarray(x, dtype=float)
    factor = np.ascontiguousarray(factor, dtype=float)
    return kernel(x, factor, tuple(ops), step)


def warm_up_arguments() -> tuple[Any, ...]:
    """A 2-state mean, factor, :class:`ModelOperands` and :class:`StepData` of the types a real step passes:
    calling a compiled step with them compiles the one signature every step uses."""
    n = 2
    eye = np.eye(n)
    ops = ModelOperands(
        eye.copy(), eye.copy(), np.zeros(n), eye.copy(), np.ones(n), False, 0.0, 1.0, 1.0, 0.0,
        np.zeros((1, n)), np.zeros((1, n)), np.zeros(1), np.ones(1), False, False,
    )  # fmt: skip
    step = StepData(np.zeros(1), 0.01, 0.0, True, np.zeros(1), 0.0, np.zeros((2, 2)), False, math.inf)
    return np.zeros(n), eye.copy(), tuple(ops), tuple(step)


_compiled: set[Any] = set()


def compile_step(kernel: Any) -> None:
    """Compile a step ``kernel`` (or load it from numba's cache) now, once per process.

    The estimator calls this for its filter when it is built, so that a node's
    first filter step does not wait for the compiler: about 7 s the first time on a
    machine, a fraction of a second once numba's on-disk cache holds it.
    """
    if kernel in _compiled:
        return
    kernel(*warm_up_arguments())
    _compiled.add(kernel)
