"""Extended Kalman filter over a :class:`~terrain_estimation.filters.base.JacobianModel`.

MODELS.md A.6 (the baseline of [QC], eqs. A.7–A.9)::

    x̄ = f(x̂, u, dt),           P̄ = F P Fᵀ + Q_k,   F = ∂f/∂x (x̂),   Q_k = L Lᵀ
    ẑ = h(x̄, u),               H = ∂h/∂x (x̄),      S = H P̄ Hᵀ + R
    K = P̄ Hᵀ S⁻¹,  x̂ = x̄ + K (z − ẑ),   P = (I − K H) P̄ (I − K H)ᵀ + K R Kᵀ

The paper prints the short form ``P = (I − K H) P̄``; the Joseph form used
here is algebraically equal for the optimal gain and stays symmetric
positive semi-definite under rounding.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .base import Array, GaussianState, JacobianModel, UpdateInfo
from .kalman import ModelFilter, initial_gaussian, joseph_update, symmetrise

__all__ = ["ExtendedKalmanFilter"]


def _check_output(name: str, value: Any, shape: tuple[int, ...]) -> Array:
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape:
        raise ValueError(f"{name} returned shape {arr.shape}, expected {shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} returned non-finite values")
    return arr


@dataclass(frozen=True, kw_only=True)
class ExtendedKalmanFilter(ModelFilter[GaussianState, JacobianModel]):
    """First-order EKF with Joseph-form update (MODELS.md A.6), gated (:class:`~.kalman.GatedFilter`).

    ``predict`` and ``update`` (:class:`~.kalman.ModelFilter`) check their
    arguments, then run :meth:`_predict` and :meth:`_update`.
    """

    def initial_state(self, x0: Any, P0: Any) -> GaussianState:
        """``GaussianState`` from a finite mean ``(n,)`` and a symmetric ``P0`` ``(n, n)``."""
        return initial_gaussian(x0, P0)

    def _predict(self, x: Array, P: Array, model: JacobianModel, u: Any, dt: float, L: Array) -> GaussianState:
        """Propagate mean through ``model.f`` and covariance through its Jacobian.

        ``model`` supplies ``f``, ``transition_jacobian`` and ``process_noise_sqrt``;
        returns the predicted state ``(x̄, P̄)``.
        """
        n = x.shape[0]
        x_new = _check_output("model.f", model.f(x, u, dt), (n,))
        F = _check_output("model.transition_jacobian", model.transition_jacobian(x, u, dt), (n, n))
        return GaussianState(x=x_new, P=symmetrise(F @ P @ F.T + L @ L.T))

    def _update(
        self, state: GaussianState, x: Array, P: Array, zv: Array, model: JacobianModel, u: Any, Rs: Array
    ) -> tuple[GaussianState, UpdateInfo]:
        """Linearised measurement update (Joseph form), gated on the NIS.

        ``model`` supplies ``h``, ``measurement_jacobian`` and ``measurement_noise_sqrt``;
        ``u`` is passed to ``h`` and its Jacobian.
        """
        n = x.shape[0]
        p = zv.shape[0]
        z_hat = _check_output("model.h", model.h(x, u), (p,))
        H = _check_output("model.measurement_jacobian", model.measurement_jacobian(x, u), (p, n))
        return joseph_update(state, x, P, zv, z_hat, H, Rs @ Rs.T, self.gate_threshold)
