"""Square-root cubature Kalman filter, exactly MODELS.md A.5 eqs. (14)–(28).

[QC] (Reina, Leanza, Messina) after Arasaratnam & Haykin, *Cubature Kalman
filters*, IEEE TAC 54(6), 2009. ``S`` is a lower-triangular factor,
``P = S Sᵀ``; ``ξ = √n [I, −I]``, weights ``1/(2n)``. Point sets are stored as
rows, so every "matrix of columns" of the paper appears transposed here::

    X_i = S ξ_i + x̂                                           (14)
    X*_i = f(X_i, u, dt)                                       (15)
    x̄ = (1/2n) Σ X*_i                                         (16)
    χ* = (1/√2n) [X*_1 − x̄ … X*_2n − x̄]                       (17)
    S̄ = tria([χ*, √Q_k])                                      (18)
    X_i = S̄ ξ_i + x̄;  Z_i = h(X_i, u);  ẑ = (1/2n) Σ Z_i      (19)–(21)
    𝒵 = (1/√2n) [Z_i − ẑ];  S_z = tria([𝒵, √R])               (22)–(23)
    χ = (1/√2n) [X_i − x̄];  P_xz = χ 𝒵ᵀ                        (24)–(25)
    W = (P_xz / S_zᵀ) / S_z   (two triangular solves)          (26)
    x̂ = x̄ + W (z − ẑ)                                         (27)
    S = tria([χ − W 𝒵, W √R])                                  (28)

with ``tria(A) = qr(Aᵀ)ᵀ`` (:func:`~.sigma_points.tria`) and the triangular
solves by :func:`~.sigma_points.solve_lower` (BLAS ``dtrsm``, see there why
not ``scipy.linalg.solve_triangular``). The recursion never
forms ``P`` and never factors a matrix: every factor comes from a QR of
stacked factors, which cannot fail and keeps ``P`` positive semi-definite by
construction. Only :meth:`SquareRootCubatureKalmanFilter.initial_state`
factors the user's ``P0``.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .base import Array, SqrtGaussianState, StateSpaceModel, UpdateInfo
from .kalman import ModelFilter, initial_gaussian
from .sigma_points import _tria_rows, cubature_points, robust_sqrt, solve_lower
from .ukf import check_points

__all__ = ["SquareRootCubatureKalmanFilter"]


@dataclass(frozen=True, kw_only=True)
class SquareRootCubatureKalmanFilter(ModelFilter[SqrtGaussianState, StateSpaceModel]):
    """Square-root CKF carrying ``SqrtGaussianState(x, S)`` (MODELS.md A.5), gated (:class:`~.kalman.GatedFilter`).

    ``predict`` and ``update`` (:class:`~.kalman.ModelFilter`) check their
    arguments, then run :meth:`_predict` and :meth:`_update`.
    """

    carries_factor = True

    def initial_state(self, x0: Any, P0: Any) -> SqrtGaussianState:
        """``SqrtGaussianState`` from a finite mean ``(n,)`` and a symmetric ``P0``.

        ``P0`` is factored with :func:`~.sigma_points.robust_sqrt` (Cholesky,
        or a PSD projection by clipped eigenvalues when ``P0`` is singular or
        slightly indefinite): the only factorisation this filter performs.
        """
        g = initial_gaussian(x0, P0)
        return SqrtGaussianState(x=g.x, S=robust_sqrt(g.P))

    def _predict(self, x: Array, S: Array, model: StateSpaceModel, u: Any, dt: float, L: Array) -> SqrtGaussianState:
        """Time update, eqs. (14)–(18).

        ``model`` supplies ``f`` (vectorised, ``(2n, n)`` → ``(2n, n)``) and
        ``process_noise_sqrt`` (``√Q_k``, ``(n, q)``). Returns
        ``SqrtGaussianState(x̄, S̄)`` with ``S̄`` lower-triangular.
        """
        n = x.shape[0]
        ps = cubature_points(n)
        X = x + ps.unit @ S.T  # (14)
        Xs = check_points("model.f", model.f(X, u, dt), 2 * n, n)  # (15)
        x_pred, S_pred = _time_update(ps.Wm, Xs, L)
        return SqrtGaussianState(x=x_pred, S=S_pred)

    def _update(
        self, state: SqrtGaussianState, x: Array, S: Array, zv: Array, model: StateSpaceModel, u: Any, Rs: Array
    ) -> tuple[SqrtGaussianState, UpdateInfo]:
        """Measurement update, eqs. (19)–(28), gated on the NIS.

        The NIS ``‖S_z⁻¹ ν‖²`` reuses the first triangular solve of the gain
        (26), so gating costs nothing extra. ``model`` supplies ``h``
        (vectorised, ``(2n, n)`` → ``(2n, p)``) and ``measurement_noise_sqrt``
        (``√R``, ``(p, r)``).

        Returns:
            ``(posterior, info)``; ``info.innovation_cov = S_z S_zᵀ`` (formed
            for reporting only) and ``info.extras["innovation_cov_sqrt"] = S_z``.
            On rejection the prior itself with ``info.accepted=False``.
        """
        nu, S_z, nis, post = self._update_core(x, S, zv, model.h, u, Rs, zv.shape[0])
        extras = {"innovation_cov_sqrt": S_z}
        info = UpdateInfo(innovation=nu, innovation_cov=S_z @ S_z.T, nis=nis, accepted=post is not None, extras=extras)
        return (state if post is None else SqrtGaussianState(x=post[0], S=post[1])), info

    def _update_core(
        self, x: Array, S: Array, zv: Array, h: Callable[[Array, Any], Array], u: Any, Rs: Array, p: int
    ) -> tuple[Array, Array, float, tuple[Array, Array] | None]:
        """Eqs. (19)–(28) on checked arrays: ``(ν, S_z, NIS, (x̂, S) or None when gated)``."""
        n = x.shape[0]
        ps = cubature_points(n)
        c = 1.0 / math.sqrt(2 * n)
        dX = ps.unit @ S.T  # X_i − x̄ of (19)
        Z = check_points("model.h", h(x + dX, u), 2 * n, p)  # (19)-(20)
        z_hat = ps.Wm @ Z  # (21)
        Zc_t = (Z - z_hat) * c  # (22), transposed: 𝒵ᵀ (2n, p)
        S_z = _tria_rows(Zc_t, Rs.T)  # (23): tria([𝒵, √R])
        chi_t = dX * c  # (24), transposed: χᵀ (2n, n)
        P_xz = chi_t.T @ Zc_t  # (25)
        nu = zv - z_hat
        # First solve of (26), S_z A = [P_xzᵀ, ν]: also whitens ν for the NIS ‖S_z⁻¹ν‖².
        A = solve_lower(S_z, np.concatenate((P_xz.T, nu[:, None]), axis=1))
        w = A[:, n]
        nis = float(w @ w)
        if not all(S_z.diagonal().tolist()):
            # S_z singular (R = 0 and degenerate points): no usable innovation;
            # an infinite NIS makes the gate reject it whatever the threshold.
            nis = float("inf")
        if not (math.isfinite(nis) and (self.gate_threshold is None or nis <= self.gate_threshold)):
            return nu, S_z, nis, None  # nis_gate's rejection, inlined (a per-step numpy scalar call)
        # Second solve of (26), S_zᵀ Wᵀ = A: W = P_xz S_z⁻ᵀ S_z⁻¹.
        W_t = solve_lower(S_z, A[:, :n], transpose=True)
        x_post = x + nu @ W_t  # (27)
        S_post = _tria_rows(chi_t - Zc_t @ W_t, Rs.T @ W_t)  # (28)
        return nu, S_z, nis, (x_post, S_post)


def _time_update(Wm: Array, Xs: Array, L: Array) -> tuple[Array, Array]:
    """Eqs. (16)–(18) from the propagated points ``(2n, n)`` and ``√Q_k`` ``(n, q)``: ``(x̄, S̄)``."""
    x_pred = Wm @ Xs  # (16)
    chi_star_t = (Xs - x_pred) * (1.0 / math.sqrt(Xs.shape[0]))  # (17), transposed
    S_pred = _tria_rows(chi_star_t, L.T)  # (18): tria([χ*, √Q_k])
    return x_pred, S_pred
