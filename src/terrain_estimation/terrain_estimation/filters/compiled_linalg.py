"""Small dense linear algebra for the compiled filter steps (numba): one home for every kernel that needs it.

The compiled steps (the soil-stiffness SCKF and EKF,
:mod:`terrain_estimation.estimators.soil_stiffness_sckf` and
:mod:`terrain_estimation.estimators.soil_stiffness_ekf`; the skid-steer AN-STUKF,
:mod:`terrain_estimation.estimators.skid_steer_compiled`) work on 1×1 to 10×10
matrices, where a call into numpy / BLAS / LAPACK costs more than the arithmetic.
These loops are what they call instead: the Cholesky factor, triangular and
general solves, the ``tria`` QR factor of a square-root filter, products and
symmetrisation. They follow LAPACK's algorithms (``dpotrf``, ``dtrsm``,
``dgesv``'s partial pivoting, ``dgeqrf``'s Householder reflectors) but not its
blocking and accumulation order, so their results agree with numpy's to rounding,
not bit for bit (``test/test_soil_stiffness_sckf.py``,
``test/test_skid_steer_compiled.py``).

Every kernel is compiled with numba's ``error_model="numpy"``: a float division
by zero gives inf or NaN as in numpy / BLAS (a zero pivot of a triangular solve,
say) instead of raising ``ZeroDivisionError``; the callers turn a non-finite
result into a rejected update or a failed step.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, L, ...) of the papers

from __future__ import annotations

import math

import numpy as np

from terrain_estimation.filters.base import Array
from terrain_estimation.jit import compiled

__all__ = [
    "all_finite",
    "cholesky_lower",
    "matmul",
    "mul",
    "mul_bt",
    "row_mean",
    "solve",
    "solve_lower",
    "symmetrise",
    "tria",
]

_kernel = compiled(error_model="numpy")


@_kernel
def all_finite(a: Array) -> bool:  # pragma: no cover - compiled
    """Every entry of ``a`` is finite."""
    for v in a.ravel():
        if not math.isfinite(v):
            return False
    return True


@_kernel
def cholesky_lower(A: Array) -> tuple[Array, bool]:  # pragma: no cover - compiled
    """Lower Cholesky factor of a symmetric ``A`` (its lower triangle read); ``ok`` False where LAPACK's ``dpotrf``
    fails (not positive definite, NaN included)."""
    n = A.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:  # NaN included
            return L, False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
    return L, True


@_kernel
def solve_lower(L: Array, B: Array, transpose: bool) -> Array:  # pragma: no cover - compiled
    """``L X = B`` (or ``Lᵀ X = B``) by substitution, ``L`` lower-triangular ``(p, p)``, ``B`` ``(p, k)``.

    No check of the diagonal (as BLAS ``dtrsm``): a zero gives inf/NaN.
    """
    p, k = B.shape
    X = B.copy()
    for c in range(k):
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


@_kernel
def solve(A: Array, B: Array) -> tuple[Array, bool]:  # pragma: no cover - compiled
    """``A X = B`` by LU with partial pivoting (``np.linalg.solve``'s algorithm); False when singular."""
    n = A.shape[0]
    k = B.shape[1]
    M = A.copy()
    X = B.copy()
    for col in range(n):
        piv = col
        best = abs(M[col, col])
        for r in range(col + 1, n):
            if abs(M[r, col]) > best:
                best = abs(M[r, col])
                piv = r
        if best == 0.0 or best != best:
            return X, False
        if piv != col:
            for c in range(n):
                M[col, c], M[piv, c] = M[piv, c], M[col, c]
            for c in range(k):
                X[col, c], X[piv, c] = X[piv, c], X[col, c]
        for r in range(col + 1, n):
            f = M[r, col] / M[col, col]
            if f != 0.0:
                for c in range(col + 1, n):
                    M[r, c] -= f * M[col, c]
                for c in range(k):
                    X[r, c] -= f * X[col, c]
    for col in range(n - 1, -1, -1):
        for c in range(k):
            s = X[col, c]
            for j in range(col + 1, n):
                s -= M[col, j] * X[j, c]
            X[col, c] = s / M[col, col]
    return X, True


@_kernel
def matmul(a: Array, b: Array, out: Array) -> None:  # pragma: no cover - compiled
    """``out = a @ b`` for ``a`` ``(r, k)``, ``b`` ``(k, c)`` (``out`` must not alias ``a`` or ``b``)."""
    rows, inner = a.shape
    cols = b.shape[1]
    for i in range(rows):
        for j in range(cols):
            s = 0.0
            for k in range(inner):
                s += a[i, k] * b[k, j]
            out[i, j] = s


@_kernel
def mul(a: Array, b: Array) -> Array:  # pragma: no cover - compiled
    """``a @ b`` as a new array."""
    out = np.empty((a.shape[0], b.shape[1]))
    matmul(a, b, out)
    return out


@_kernel
def mul_bt(a: Array, b: Array) -> Array:  # pragma: no cover - compiled
    """``a @ bᵀ`` as a new array, ``a`` ``(r, k)``, ``b`` ``(c, k)``."""
    return mul(a, b.T)


@_kernel
def row_mean(a: Array) -> Array:  # pragma: no cover - compiled
    """The mean of the rows of ``a`` ``(m, d)``: ``(d,)``, summed in row order, then divided by ``m``."""
    m, d = a.shape
    out = np.zeros(d)
    for i in range(m):
        for r in range(d):
            out[r] += a[i, r]
    for r in range(d):
        out[r] /= m
    return out


@_kernel
def symmetrise(A: Array) -> Array:  # pragma: no cover - compiled
    """``(A + Aᵀ)/2`` as a new array."""
    n = A.shape[0]
    out = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.5 * (A[i, j] + A[j, i])
    return out


@_kernel
def tria(rows: Array) -> Array:  # pragma: no cover - compiled
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
