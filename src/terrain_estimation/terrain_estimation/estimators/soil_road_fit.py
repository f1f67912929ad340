"""The local polynomial fits of the profile road, compiled (numba): value and slope weights at a time.

:mod:`.soil_road` reconstructs ḣ at the measurement time (the LRV's
feed-through) as the slope of a local least-squares polynomial fitted to the
profile samples around it, and the variance of the elevation there from the
weights of such a fit (MODELS.md A.10). The weights are rows 0 and 1 of the
pseudo-inverse ``(VᵀV)⁻¹Vᵀ`` of the fit's Vandermonde matrix, at every filter
step: in numpy (the power table, two products and ``np.linalg.solve`` with
some 30 right-hand sides) that cost ≈ 23 µs a step, the largest part of the
LRV's replay outside the filter; compiled, ≈ 2.5 µs with the call.

The same normal equations ``VᵀV``, here solved for the two unit vectors by LU
with partial pivoting (:func:`~terrain_estimation.filters.compiled_linalg.solve`,
``np.linalg.solve``'s algorithm but not LAPACK's blocking and accumulation order)
and multiplied by ``V`` (``VᵀV`` is symmetric), with the powers of ``s`` by
repeated multiplication. So the weights agree with the numpy form to rounding, not
bit for bit: ``VᵀV`` has a condition number ≈ 2000 for the quintic, and on the LRV
bags the weights differ by at most 1e-13 of the largest weight; the estimates
(k_s, k_tot and their variances) by at most 7e-13 relative and 2.3e-12 of their
own σ, less than summing ``VᵀV`` in another order within numpy moves them (9e-13,
3.6e-12 σ). ``test/test_soil_road_fit.py`` holds the weights to 1e-12 against the
numpy form, written out there.
"""

from __future__ import annotations

import numpy as np

from terrain_estimation.filters.base import Array
from terrain_estimation.filters.compiled_linalg import solve
from terrain_estimation.jit import compiled

__all__ = ["fit_weights", "slope_weights", "warm_up_fits"]

_kernel = compiled(error_model="numpy")


@_kernel
def _fit_rows(pt: Array, t: float, half_w: float, degree: int) -> tuple[int, Array, Array]:  # pragma: no cover
    """The window of the fit of degree ``degree`` at ``t`` over ``|t_i − t| ≤ half_w`` and what its weights need.

    Returns:
        ``(lo, V, Y)``: the window's first sample, its Vandermonde matrix ``V`` (M × (d+1)) in
        ``s = (t_i − t)/half_w``, and ``Y = (VᵀV)⁻¹ [e₀ e₁]``; the value weights are ``V Y[:, 0]``,
        the slope weights ``V Y[:, 1] / half_w`` (rows 0 and 1 of ``(VᵀV)⁻¹Vᵀ``, as ``VᵀV`` is
        symmetric). ``lo = −1`` when the window holds fewer than ``degree + 2`` samples or does
        not reach at least half-way to each of its edges (the fit would extrapolate), or the
        normal equations are singular.
    """
    lo = int(np.searchsorted(pt, t - half_w))
    hi = int(np.searchsorted(pt, t + half_w, side="right"))
    m, n = hi - lo, degree + 1
    if m < degree + 2 or (pt[lo] - t) / half_w > -0.5 or (pt[hi - 1] - t) / half_w < 0.5:
        return -1, np.empty((0, n)), np.empty((n, 2))
    v = np.empty((m, n))
    for i in range(m):
        s = (pt[lo + i] - t) / half_w  # in [−1, 1]: a well-conditioned Vandermonde matrix
        p = 1.0
        for k in range(n):
            v[i, k] = p
            p *= s
    normal = np.empty((n, n))
    for j in range(n):
        for k in range(j, n):
            acc = 0.0
            for i in range(m):
                acc += v[i, j] * v[i, k]
            normal[j, k] = normal[k, j] = acc
    unit = np.zeros((n, 2))
    unit[0, 0] = unit[1, 1] = 1.0
    y, ok = solve(normal, unit)
    return (lo if ok else -1), v, y


@_kernel
def fit_weights(pt: Array, t: float, half_w: float, degree: int) -> tuple[int, Array, Array]:  # pragma: no cover
    """Weights of the value and of the slope at ``t`` of the local fit of degree ``degree`` over ``|t_i − t| ≤ half_w``.

    ``(lo, w0, w1)``: the value is ``w0 · h[lo:lo+M]``, the slope ``w1 · h[lo:lo+M]``;
    ``lo = −1`` (and empty weights) where :func:`_fit_rows` finds no fit.
    """
    lo, v, y = _fit_rows(pt, t, half_w, degree)
    if lo < 0:
        return -1, np.empty(0), np.empty(0)
    m, n = v.shape
    w0, w1 = np.empty(m), np.empty(m)
    for i in range(m):
        a0 = a1 = 0.0
        for k in range(n):
            a0 += v[i, k] * y[k, 0]
            a1 += v[i, k] * y[k, 1]
        w0[i], w1[i] = a0, a1 / half_w
    return lo, w0, w1


@_kernel
def slope_weights(
    pt: Array, t: float, half_w: float, max_degree: int, lo_h: int, w_h: Array
) -> tuple[int, Array, float, float]:  # pragma: no cover - compiled
    """The slope weights at ``t`` of the highest odd degree ≤ ``max_degree`` whose fit the window allows.

    Returns:
        ``(lo, w1, ‖w1‖², w_h·w1)``: ``lo = −1`` when no degree fits; the last term is
        the dot product of ``w1`` with the elevation weights ``w_h`` (starting at
        sample ``lo_h``) over the samples they share, 0 when they share none.
    """
    for degree in range(max_degree, 0, -2):  # fewer samples: a lower (odd) degree
        lo, v, y = _fit_rows(pt, t, half_w, degree)
        if lo < 0:
            continue
        m, n = v.shape
        w1 = np.empty(m)
        norm2 = 0.0
        for i in range(m):
            a1 = 0.0
            for k in range(n):
                a1 += v[i, k] * y[k, 1]
            w1[i] = a1 / half_w
            norm2 += w1[i] * w1[i]
        cross = 0.0
        for i in range(max(lo, lo_h), min(lo + m, lo_h + w_h.size)):
            cross += w_h[i - lo_h] * w1[i - lo]
        return lo, w1, norm2, cross
    return -1, np.empty(0), 0.0, 0.0


def warm_up_fits() -> None:
    """Compile :func:`fit_weights` and :func:`slope_weights` (or load them from numba's cache) now.

    An estimator that fits ḣ calls this at construction, so the ~7 ms of loading the kernels
    is paid at start-up, not at its first filter step. Same inputs' types as the steps'.
    """
    pt = np.linspace(-0.01, 0.01, 21)
    lo, w0, _ = fit_weights(pt, 0.0, 0.01, 2)
    slope_weights(pt, 0.0, 0.01, 5, lo, w0)
