"""Sigma-point sets and the square-root linear algebra they are drawn with.

A point set is a small frozen object (filterpy's vocabulary, see
``filterpy/kalman/sigma_points.py``) holding the *unit* points and the
weights for one state dimension ``n``. Drawing points is one matrix product,

    X = x̂ + U Sᵀ,    U: (m, n) unit points (row i = ξ_iᵀ),  S: (n, n),  X: (m, n),

so ``X_i = x̂ + S ξ_i`` for every point at once (MODELS.md A.5 eq. 14/19,
B.8). Any square-root factor ``S`` with ``S Sᵀ = P`` gives the same moments;
the filters pass a lower-triangular one.

Sets:

* :class:`CubaturePoints` — third-degree spherical-radial rule, ``2n`` points
  ``ξ = √n [I, −I]``, equal weights ``1/(2n)`` (Arasaratnam–Haykin 2009).
* :class:`MerweScaledSigmaPoints` — scaled unscented points, ``2n + 1`` points
  with separate mean and covariance weights (Wan–van der Merwe 2000;
  Julier–Uhlmann 2004; MODELS.md B.8).

:func:`tria` and :func:`robust_sqrt` produce the lower-triangular factors;
:func:`solve_lower` solves with them.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from .base import Array, check_square, check_vector

__all__ = [
    "SigmaPointSet",
    "CubaturePoints",
    "MerweScaledSigmaPoints",
    "cubature_points",
    "merwe_scaled_sigma_points",
    "tria",
    "robust_sqrt",
    "solve_lower",
]


def _frozen(a: Array) -> Array:
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class SigmaPointSet:
    """Unit points and weights of a deterministic sampling rule.

    Attributes:
        n: state dimension.
        unit: unit points ``(m, n)``; row ``i`` is ``ξ_iᵀ``. Read-only.
        Wm: mean weights ``(m,)``, summing to 1. Read-only.
        Wc: covariance weights ``(m,)``. Read-only.
    """

    n: int
    unit: Array = field(repr=False, compare=False)
    Wm: Array = field(repr=False, compare=False)
    Wc: Array = field(repr=False, compare=False)

    @property
    def num_points(self) -> int:
        """Number of points ``m``."""
        return int(self.unit.shape[0])

    def sigma_points(self, mean: Array, sqrt_cov: Array) -> Array:
        """Draw the points of ``N(mean, sqrt_cov sqrt_covᵀ)``.

        Args:
            mean: ``(n,)``.
            sqrt_cov: any square-root factor ``S`` of the covariance, ``(n, n)``.

        Returns:
            Points ``(m, n)``, one per row: ``X_i = mean + S ξ_i``.
        """
        x = check_vector("mean", mean, self.n)
        s = check_square("sqrt_cov", sqrt_cov, self.n)
        return x + self.unit @ s.T


@dataclass(frozen=True)
class CubaturePoints(SigmaPointSet):
    """Third-degree spherical-radial cubature rule (MODELS.md A.5, eq. 14).

    ``2n`` points ``ξ_i = √n e_i`` and ``ξ_{n+i} = −√n e_i``, all weights
    ``1/(2n)`` (``Wm == Wc``). Source: Arasaratnam & Haykin, *Cubature Kalman
    filters*, IEEE TAC 54(6), 2009.

    Build it with :func:`cubature_points` (cached per ``n``).
    """


@dataclass(frozen=True)
class MerweScaledSigmaPoints(SigmaPointSet):
    """Scaled unscented sigma points (MODELS.md B.8).

    ``λ = α²(n + κ) − n``; points ``χ_0 = x̂``, ``χ_i = x̂ + √(n+λ) S e_i``,
    ``χ_{n+i} = x̂ − √(n+λ) S e_i``; weights ``W_m0 = λ/(n+λ)``,
    ``W_c0 = W_m0 + 1 − α² + β``, ``W_mi = W_ci = 1/(2(n+λ))``. Same order and
    values as filterpy's ``MerweScaledSigmaPoints`` with its default Cholesky
    square root. Source: Wan & van der Merwe 2000; Julier & Uhlmann 2004.

    Build it with :func:`merwe_scaled_sigma_points` (cached per parameters).

    Attributes:
        alpha: spread ``α > 0``.
        beta: prior-knowledge term ``β`` (2 is optimal for a Gaussian).
        kappa: secondary scaling ``κ`` with ``n + κ > 0``.
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0


@lru_cache(maxsize=64)
def cubature_points(n: int) -> CubaturePoints:
    """The cubature point set for dimension ``n`` (eq. 14: ``ξ = √n [I, −I]``).

    Raises:
        ValueError: if ``n < 1``.
    """
    n = _check_dim(n)
    eye = np.sqrt(n) * np.eye(n)
    unit = np.vstack([eye, -eye])
    w = np.full(2 * n, 1.0 / (2 * n))
    return CubaturePoints(n=n, unit=_frozen(unit), Wm=_frozen(w), Wc=_frozen(w.copy()))


@lru_cache(maxsize=64)
def merwe_scaled_sigma_points(
    n: int, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0
) -> MerweScaledSigmaPoints:
    """The scaled unscented point set (MODELS.md B.8) for dimension ``n``.

    Args:
        n: state dimension.
        alpha: spread ``α > 0``. A very small α makes ``W_m0`` large and
            negative (MODELS.md B.8 recommends α = 1 for n = 3).
        beta: ``β``; 2 for a Gaussian prior.
        kappa: ``κ``; requires ``n + κ > 0``. ``κ = 3 − n`` is Julier's choice.

    Raises:
        ValueError: on a non-positive α, a non-finite β/κ, or ``n + κ ≤ 0``.
    """
    n = _check_dim(n)
    if not (math.isfinite(alpha) and alpha > 0.0):
        raise ValueError(f"alpha must be finite and > 0, got {alpha}")
    if not math.isfinite(beta):
        raise ValueError(f"beta must be finite, got {beta}")
    if not (math.isfinite(kappa) and n + kappa > 0.0):
        raise ValueError(f"kappa must be finite with n + kappa > 0, got n={n}, kappa={kappa}")
    lam = alpha**2 * (n + kappa) - n
    c = n + lam  # = α²(n + κ) > 0 by the checks above
    scaled = np.sqrt(c) * np.eye(n)
    unit = np.vstack([np.zeros((1, n)), scaled, -scaled])
    wm = np.full(2 * n + 1, 0.5 / c)
    wc = wm.copy()
    wm[0] = lam / c
    wc[0] = lam / c + (1.0 - alpha**2 + beta)
    return MerweScaledSigmaPoints(
        n=n,
        unit=_frozen(unit),
        Wm=_frozen(wm),
        Wc=_frozen(wc),
        alpha=float(alpha),
        beta=float(beta),
        kappa=float(kappa),
    )


def _check_dim(n: int) -> int:
    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    return int(n)


def tria(A: Array) -> Array:  # matrix symbol of the literature
    """Lower-triangular ``S`` with ``S Sᵀ = A Aᵀ`` and a non-negative diagonal.

    Arasaratnam–Haykin's ``Tria(·)`` as MODELS.md A.5 writes it (eqs. 18, 23,
    28): ``S = qr(Aᵀ)ᵀ`` with ``R`` the upper factor of an economy QR. The
    QR sign convention is arbitrary, so each column is flipped to make the
    diagonal non-negative (a column sign flip leaves ``S Sᵀ`` unchanged).

    The QR is LAPACK ``dgeqrf`` called directly (scipy's build of it), the
    routine ``numpy.linalg.qr(mode="r")`` calls in numpy's build: the same
    ``R`` bit for bit on the filters' matrices (tested up to 40 rows; a
    threaded BLAS may split larger ones differently in the last bits).
    The square-root filters run three ``tria`` of 5×15 matrices per step,
    and numpy's wrapper (type dispatch, workspace query, ``triu`` of the
    result) cost ≈ 10 µs of the ≈ 11 µs of each; ``R`` is read from the
    upper triangle through a cached mask instead.

    Args:
        A: compound matrix ``(n, k)``, any ``k``; when ``k < n`` it is padded
            with zero columns so the factor is square.

    Returns:
        ``(n, n)`` float64 lower-triangular factor (exact zeros above the
        diagonal).
    """
    A = np.asarray(A, dtype=float)
    n, k = A.shape
    if k < n:
        A = np.hstack([A, np.zeros((n, n - k))])
    return _lower_factor(A.T, overwrite=False)


def _tria_rows(top: Array, bottom: Array) -> Array:
    """``tria(np.concatenate((top, bottom)).T)``: the compound matrix given by the rows of ``Aᵀ``, bit for bit.

    The square-root filters stack ``Aᵀ`` from two blocks (points, noise
    factor); here they are written straight into a Fortran-ordered array
    that LAPACK factors in place, instead of a concatenation that the
    ``dgeqrf`` wrapper then copies to Fortran order (the same values reach the
    same routine).

    Args:
        top: ``(k1, n)``; bottom: ``(k2, n)``.
    """
    k1, n = top.shape
    k = k1 + bottom.shape[0]
    rows = np.empty((max(k, n), n), order="F")
    rows[:k1] = top
    rows[k1:k] = bottom
    if k < n:
        rows[k:] = 0.0  # tria's zero columns
    return _lower_factor(rows, overwrite=True)


# scipy's BLAS/LAPACK wrappers, imported on first use: ``scipy.linalg`` takes about 0.2 s to import, and a
# filter run by a compiled step (the skid steer's) may never call them (issue 23: start-up).
_DTRSM: Any = None
_DGEQRF: Any = None


def _dtrsm() -> Any:
    global _DTRSM
    if _DTRSM is None:
        from scipy.linalg.blas import dtrsm

        _DTRSM = dtrsm
    return _DTRSM


def _dgeqrf(*args: Any, **kwargs: Any) -> Any:
    global _DGEQRF
    if _DGEQRF is None:
        from scipy.linalg.lapack import dgeqrf

        _DGEQRF = dgeqrf
    return _DGEQRF(*args, **kwargs)


def _lower_factor(rows: Array, *, overwrite: bool) -> Array:
    """The factor of :func:`tria` from ``Aᵀ`` ``(k ≥ n, n)`` (overwritten if ``overwrite`` and Fortran-ordered)."""
    n = rows.shape[1]
    # dgeqrf leaves R in the upper triangle of its first n rows and the
    # Householder vectors below it; Sᵀ = R.
    S = _dgeqrf(rows, lwork=_QR_LWORK_PER_COLUMN * n, overwrite_a=int(overwrite))[0][:n].T
    flip = np.where(S.diagonal() < 0.0, -1.0, 1.0)
    # np.where(lower, S * flip, 0.0) in one ufunc call into zeros (+0.0 above
    # the diagonal either way): tria runs three times per filter step.
    out = np.zeros((n, n))
    np.multiply(S, flip, out=out, where=_lower_mask(n))
    return out


#: Workspace of :func:`tria`'s ``dgeqrf`` per column: at least the block size
#: LAPACK's ``ilaenv`` gives ``dgeqrf`` (32), i.e. what numpy's workspace query
#: allocates. With less (scipy's default is 3 per column), ``dgeqrf`` narrows
#: its blocks, which changes ``R`` in the last bits from 32 columns on.
_QR_LWORK_PER_COLUMN = 64


@lru_cache(maxsize=16)
def _lower_mask(n: int) -> NDArray[np.bool_]:
    """Read-only boolean ``(n, n)`` mask of the lower triangle, diagonal included."""
    mask = np.tri(n, dtype=bool)
    mask.setflags(write=False)
    return mask


try:
    # The gufunc behind np.linalg.cholesky (numpy's own LAPACK), called as np.linalg.cholesky calls it.
    from numpy.linalg import _umath_linalg

    _CHOLESKY_LO: Any = _umath_linalg.cholesky_lo
except (ImportError, AttributeError):  # pragma: no cover - another numpy layout: the public function
    _CHOLESKY_LO = None


def _raise_not_positive_definite(err: str, flag: int) -> None:
    raise np.linalg.LinAlgError("Matrix is not positive definite")


def _raise_singular(err: str, flag: int) -> None:
    raise np.linalg.LinAlgError("Singular matrix")


try:
    _SOLVE1: Any = _umath_linalg.solve1
    _SOLVE: Any = _umath_linalg.solve
except (NameError, AttributeError):  # pragma: no cover - another numpy layout: the public function
    _SOLVE1 = _SOLVE = None


def solve(a: Array, b: Array) -> Array:
    """``np.linalg.solve(a, b)``, bit for bit, without the wrapper's argument handling for float64 arrays.

    The same gufunc (LAPACK ``gesv``) under the same floating-point error state (a singular ``a`` raises
    ``numpy.linalg.LinAlgError``), as :func:`cholesky` does for its factor: the rover's estimator solves
    about a dozen systems of 3 to 11 unknowns per step, where the wrapper's type and shape dispatch cost
    more than the solve. Anything but float64 ndarrays with a square ``a`` goes through
    ``np.linalg.solve`` itself.
    """
    if (
        _SOLVE1 is None
        or type(a) is not np.ndarray
        or type(b) is not np.ndarray
        or a.dtype != np.float64
        or b.dtype != np.float64
        or a.ndim < 2
        or a.shape[-1] != a.shape[-2]
    ):
        return np.asarray(np.linalg.solve(a, b))
    gufunc = _SOLVE1 if b.ndim == 1 else _SOLVE
    with np.errstate(call=_raise_singular, invalid="call", over="ignore", divide="ignore", under="ignore"):
        return np.asarray(gufunc(a, b, signature="dd->d"))


def cholesky(P: Array) -> Array:
    """``np.linalg.cholesky(P)``, bit for bit, without the wrapper's argument handling for a float64 array.

    The same gufunc under the same floating-point error state (a matrix that
    is not positive definite raises ``numpy.linalg.LinAlgError``); the
    wrapper's type and shape dispatch cost more than factoring the 3×3
    matrices of the skid-steer filter, three times per step. Anything but a
    float64 ndarray (or a numpy without that gufunc) goes through
    ``np.linalg.cholesky`` itself.
    """
    if _CHOLESKY_LO is None or type(P) is not np.ndarray or P.dtype != np.float64:
        return np.asarray(np.linalg.cholesky(P))
    with np.errstate(call=_raise_not_positive_definite, invalid="call", over="ignore", divide="ignore", under="ignore"):
        return np.asarray(_CHOLESKY_LO(P, signature="d->d"))


def robust_sqrt(P: Array) -> Array:
    """Lower-triangular factor ``S`` with ``S Sᵀ ≈ P`` that never fails on a PSD ``P``.

    Cholesky when ``P`` is positive definite (the normal case, exact).
    Otherwise ``P`` is projected on the PSD cone: symmetric eigen-decomposition
    with the eigenvalues clipped at 0, ``S = tria(V √Λ)``. Why: a
    full-covariance filter must still draw points when rounding has made ``P``
    singular or slightly indefinite (a state with zero variance, or the
    loss of positive definiteness that strong tracking is meant to cure, MODELS.md
    B.9); a Cholesky failure there would stop the filter.

    Args:
        P: ``(n, n)`` covariance (only its symmetric part is used on the
            fallback path; the Cholesky path reads the lower triangle).

    Returns:
        ``(n, n)`` lower-triangular factor. Non-finite input gives a
        non-finite factor or raises ``numpy.linalg.LinAlgError``.
    """
    try:
        return cholesky(P)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(0.5 * (P + P.T))
        return tria(V * np.sqrt(np.clip(w, 0.0, None)))


def solve_lower(L: Array, B: Array, *, transpose: bool = False) -> Array:
    """Solve ``L X = B`` (or ``Lᵀ X = B``) for a lower-triangular ``L``.

    The triangular solves of the gain (MODELS.md A.5 eq. 26) and of the NIS.
    Calls the Level-3 BLAS ``dtrsm`` that ``scipy.linalg.solve_triangular``
    reaches through LAPACK ``dtrtrs``. Why not ``solve_triangular`` itself:
    OpenBLAS's ``dtrtrs`` hands even a 2×2 system to its worker threads, and
    on a loaded CPU (the on-board computer runs other nodes) a step then
    stalls for milliseconds waiting for a thread; measured on the 5-state
    quarter-car model under load, 0.8–1.7 ms per step against ~0.1 ms with
    ``dtrsm``, which runs small systems single-threaded and is ~8× cheaper.
    Results are identical (same BLAS kernel).

    ``dtrsm`` does not check the diagonal: a singular ``L`` gives ``inf``/NaN
    entries, which callers turn into an infinite NIS (a rejected update).

    Args:
        L: lower-triangular ``(p, p)``; the strict upper triangle is ignored.
        B: right-hand side ``(p,)`` or ``(p, k)``.
        transpose: solve with ``Lᵀ`` instead of ``L``.

    Returns:
        ``X`` with the shape of ``B``.
    """
    dtrsm = _DTRSM if _DTRSM is not None else _dtrsm()
    if B.ndim == 1:
        return cast(Array, dtrsm(1.0, L, B[:, None], lower=1, trans_a=int(transpose))[:, 0])
    return cast(Array, dtrsm(1.0, L, B, lower=1, trans_a=int(transpose)))
