"""Discretisation and step input of the bilinear k_tot models (MODELS.md A.10, P-11…P-13).

* :func:`discretise`: ``Φ = e^{Aδ}`` and ``Γ = ∫0^δ e^{As} ds`` of one or a
  batch of state matrices, by the paper's fourth-order series (``"taylor4"``,
  in a stacked Horner form) or exactly (``"expm"``).
* The input of one filter step: ḣ on ``N`` equal sub-steps
  (:func:`substep_inputs`), optionally with ḣ at the measurement time
  (:class:`StepInput`, :func:`hdot_at_end`) for a measurement with
  feed-through (the LRV's relative damper).

Used by :mod:`terrain_estimation.models.quarter_car` (the models) and
:mod:`terrain_estimation.models.quarter_car_road`; the public names are
importable from :mod:`terrain_estimation.models.quarter_car` too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.linalg

from terrain_estimation.filters.base import Array
from terrain_estimation.models.quarter_car_params import Discretisation

__all__ = ["StepInput", "discretise", "substep_inputs", "hdot_at_end"]

# ---------------------------------------------------------------------------
# Discretisation helpers (P-11…P-13)
# ---------------------------------------------------------------------------


#: Divisors of the stacked Horner recursion of :func:`discretise`, rows
#: ``(Φ, Γ/δ)`` per step: ``(4, 5)``, ``(3, 4)``, ``(2, 3)``, ``(1, 2)``.
_HORNER_DIVISORS = np.array([[4.0, 5.0], [3.0, 4.0], [2.0, 3.0], [1.0, 2.0]])
_HORNER_DIVISORS.setflags(write=False)


@lru_cache(maxsize=8)
def _eye(n: int) -> Array:
    """Read-only ``n × n`` identity (cached: one fewer allocation per call)."""
    eye = np.eye(n)
    eye.setflags(write=False)
    return eye


def discretise(a: Array, delta: float, method: Discretisation) -> tuple[Array, Array]:
    """Transition and input-integral matrices of ``ẋ = A x`` over one step.

    Args:
        a: continuous matrices ``A``, shape ``(n, n)`` or ``(m, n, n)``.
        delta: step length (s), > 0.
        method: ``"taylor4"`` — the paper's truncated series (P-11, P-12):
            ``Φ = Σ_{j=0..4} (Aδ)^j/j!``, ``Γ = Σ_{j=0..4} A^j δ^{j+1}/(j+1)!``;
            ``"expm"`` — exact, from ``exp([[Aδ, Iδ], [0, 0]])`` whose blocks
            are ``Φ = e^{Aδ}`` and ``Γ = ∫0^δ e^{As} ds``.

    Returns:
        ``(Φ, Γ)``, each with the shape of ``a``. ``B_k = Γ B``, ``G_k = Γ G``.
    """
    a = np.asarray(a, dtype=float)
    n = a.shape[-1]
    ad = a * delta
    if method == "taylor4":
        pair = _taylor4_pair(ad)
        return pair[0], pair[1] * delta
    if method == "expm":
        eye = _eye(n)
        big = np.zeros(a.shape[:-2] + (2 * n, 2 * n))
        big[..., :n, :n] = ad
        big[..., :n, n:] = eye * delta
        e = scipy.linalg.expm(big)
        return e[..., :n, :n], e[..., :n, n:]
    raise ValueError(f"unknown discretisation {method!r}")


def _taylor4_pair(ad: Array) -> Array:
    """The stacked pair ``(Φ, Γ/δ)`` ``(2, *ad.shape)`` of the ``"taylor4"`` series, from ``ad = A δ``.

    Horner form of the two truncated series, run on the stacked pair so that
    each of the three Horner steps is one call per operation::

        Φ:   I + Aδ/4,  I + Aδ·Φ/3,  I + Aδ·Φ/2,  I + Aδ·Φ
        Γ/δ: I + Aδ/5,  I + Aδ·Γ/4,  I + Aδ·Γ/3,  I + Aδ·Γ/2.

    Same products and divisions, element by element, as two separate
    recursions (x/1 is exact; ``X + I`` is ``I + X``), at half the numpy calls:
    the filters discretise a ``(2n, n, n)`` batch every step and Python
    overhead, not arithmetic, dominates at n = 5. The identity and the
    divisors are held at the full shape of the pair
    (:func:`_horner_operands`) and the steps run in place: a ufunc on two
    operands of one shape takes its contiguous loop, ≈ 3× cheaper than
    broadcasting a ``(2, 1, 1, 1)`` divisor at these sizes.
    """
    eye, (d0, d1, d2, d3) = _horner_operands(ad.shape)
    pair = np.divide(ad, d0)
    np.add(pair, eye, out=pair)
    buf = np.matmul(ad, pair)
    np.divide(buf, d1, out=buf)
    np.add(buf, eye, out=buf)
    np.matmul(ad, buf, out=pair)
    np.divide(pair, d2, out=pair)
    np.add(pair, eye, out=pair)
    np.matmul(ad, pair, out=buf)
    np.divide(buf, d3, out=buf)
    np.add(buf, eye, out=buf)
    return buf


@lru_cache(maxsize=32)
def _horner_operands(shape: tuple[int, ...]) -> tuple[Array, tuple[Array, Array, Array, Array]]:
    """Identity and the four divisor pairs of :func:`_taylor4_pair` at the full shape ``(2, *shape)``.

    The values of broadcasting ``I`` and :data:`_HORNER_DIVISORS`, materialised
    once per shape (read-only); a large batch gets read-only broadcast views
    instead (the same values, without holding megabytes in the cache).
    """
    full = (2, *shape)
    small = math.prod(full) <= _HORNER_MATERIALISE_MAX

    def operand(a: Array) -> Array:
        out = np.broadcast_to(a, full)
        if small:
            out = out.copy()
            out.setflags(write=False)
        return out

    divs = [operand(d.reshape((2,) + (1,) * len(shape))) for d in _HORNER_DIVISORS]
    return operand(np.eye(shape[-1])), (divs[0], divs[1], divs[2], divs[3])


#: Largest stacked pair (elements) whose Horner operands are materialised.
_HORNER_MATERIALISE_MAX = 1 << 14


def _clip(v: Any, lo: float, hi: float) -> Array:
    """``np.clip(v, lo, hi)`` for ``lo <= hi``: the same values (NaN stays NaN).

    Two ufunc calls instead of ``np.clip``'s Python-level dispatch, which
    costs ≈ 2 µs a call; the models clip on every ``f``, ``h`` and noise
    evaluation.
    """
    return np.minimum(np.maximum(v, lo), hi)


def _run_substeps(pts: Array, phi: Array, gb: Array, us: Array) -> Array:
    """The sub-step recursion of :meth:`_BilinearKtotModel.f`: ``x ← Φ x + Γb u_j`` per point.

    The points as ``(m, n, 1)`` columns and the input terms ``Γb·u_j`` of all
    sub-steps from one product (the same products the loop would form): each
    sub-step is then one matmul and one in-place add, which halves the
    per-sub-step numpy calls (10 sub-steps per 10 ms step at 1 kHz). The
    stiffness state is passed through unchanged (exact random walk, row 5 of
    A.1 is zero).

    Returns:
        ``(m, n)``, a new array.
    """
    gbu = us[:, None, None, None] * gb[:, :, None]
    col = pts[:, :, None]
    for gbu_j in gbu:
        col = np.matmul(phi, col)
        col += gbu_j
    y = col[:, :, 0]
    y[:, -1] = pts[:, -1]
    return y


def _discretise_with_input(
    a: Array,
    b: Array,
    delta: float,
    method: Discretisation,
) -> tuple[Array, Array]:
    """``(Φ, Γ b)`` for a batch ``a`` ``(m, n, n)`` and one input vector ``b`` ``(n,)``.

    The exact form needs only the ``(n+1)``-augmented exponential
    ``exp([[Aδ, bδ], [0, 0]])``, cheaper than the ``2n`` block of
    :func:`discretise`.
    """
    if method == "taylor4":
        phi, gam = discretise(a, delta, method)
        return phi, gam @ b
    n = a.shape[-1]
    aug = np.zeros(a.shape[:-2] + (n + 1, n + 1))
    aug[..., :n, :n] = a * delta
    aug[..., :n, n] = b * delta
    e = scipy.linalg.expm(aug)
    return e[..., :n, :n], e[..., :n, n]


@dataclass(frozen=True, eq=False)
class StepInput:
    """Input of one filter step: the sub-step ḣ and ḣ at the measurement time.

    Attributes:
        hdot: ḣ (m/s) on the ``N`` equal sub-steps of the step, ``(N,)``; the
            mean slope of the reconstructed road over each sub-step.
        hdot_end: ḣ (m/s) at the end of the step (the measurement time), for
            a measurement with feed-through (LRV relative damper). None → the
            extrapolation of :func:`hdot_at_end` from ``hdot``. The estimator
            fills it from a local cubic fit of the profile centred on the
            measurement time (``estimators.soil_stiffness``), which is far less
            noisy than differencing the profile samples.
    """

    hdot: Array
    hdot_end: float | None = None


def substep_inputs(u: Any) -> Array:
    """Normalise a model input to the ``(N,)`` array of sub-step ḣ values (m/s).

    A scalar (or ``None``, read as ḣ = 0) is one sub-step spanning the whole
    filter step; a :class:`StepInput` gives its ``hdot``. Non-finite entries
    are replaced by 0 so that a bad input sample can never turn a state into
    NaN.
    """
    if isinstance(u, StepInput):
        u = u.hdot
    if u is None:
        return np.zeros(1)
    arr = np.asarray(u, dtype=float)
    if arr.ndim != 1:
        arr = np.atleast_1d(arr).ravel()
    if arr.size == 0:
        return np.zeros(1)
    # A step's ten-odd values are checked faster as floats than by two numpy calls.
    if arr.size > 32 or not all(map(math.isfinite, arr.tolist())):
        finite = np.isfinite(arr)
        if not finite.all():
            arr = np.where(finite, arr, 0.0)
    return arr


def hdot_at_end(u: Any) -> float:
    """ḣ at the end of the step (the measurement time), m/s.

    A :class:`StepInput` with a finite ``hdot_end`` gives that value.
    Otherwise it is extrapolated from the sub-step means: ``u_j`` is the mean
    slope over sub-step j, i.e. ḣ at its midpoint to second order, and the
    end value is extrapolated linearly from the last two midpoints,
    ``1.5 u_{N−1} − 0.5 u_{N−2}``. Holding ``u_{N−1}`` instead lags ḣ by half a
    sub-step, which matters where ḣ feeds the measurement directly (LRV
    relative damper: c/m_s·ḣ dominates ÿ1 above the body mode, and the lag
    biased k_s by −6 % on ISO G at 2 m/s). The extrapolation differences
    three elevations one sub-step apart: white elevation noise σ_h becomes
    ḣ noise of ``√6.5 · σ_h/δ`` (0.25 m/s for 0.1 mm at 1 kHz), which is why
    the estimator supplies ``hdot_end`` from a fit instead.
    """
    if isinstance(u, StepInput) and u.hdot_end is not None and math.isfinite(u.hdot_end):
        return float(u.hdot_end)
    us = substep_inputs(u)
    if us.size < 2:
        return float(us[-1])
    return float(1.5 * us[-1] - 0.5 * us[-2])
