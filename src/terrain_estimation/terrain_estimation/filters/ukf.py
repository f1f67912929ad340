"""Full-covariance sigma-point Kalman filters and the unscented Kalman filter.

:class:`SigmaPointKalmanFilter` is the additive-noise sigma-point recursion
of MODELS.md B.8; it is generic over the point set, so the unscented filter
(scaled sigma points, this module) and the cubature filter (:mod:`.ckf`)
differ only in their points and weights::

    predict:  χ = points(x̂, √P);  χ* = f(χ, u, dt);  x̄ = Σ W_m χ*
              P̄0 = Σ W_c (χ* − x̄)(χ* − x̄)ᵀ;   P̄ = P̄0 + Q_k,  Q_k = L Lᵀ
    update:   redraw χ from (x̄, P̄);  Z = h(χ, u);  ẑ = Σ W_m Z
              P_zz = Σ W_c (Z − ẑ)(Z − ẑ)ᵀ + R;   P_xz = Σ W_c (χ − x̄)(Z − ẑ)ᵀ
              K = P_xz P_zz⁻¹;  x̂ = x̄ + K (z − ẑ);  P = P̄ − K P_zz Kᵀ

The prediction is also available as its parts (:meth:`~SigmaPointKalmanFilter.propagate`
→ ``x̄, P̄0, Q_k``) and the measurement statistics on their own
(:meth:`~SigmaPointKalmanFilter.measurement_moments`): strong tracking
(:mod:`.adaptive`, MODELS.md B.9) rescales ``P̄0`` between the two.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import math
from abc import abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np

from .base import Array, GaussianState, StateSpaceModel, UpdateInfo
from .kalman import (
    ModelFilter,
    check_measurement,
    check_state,
    initial_gaussian,
    measurement_noise_factor,
    process_noise_factor,
    symmetrise,
    whiten_innovation,
)
from .sigma_points import SigmaPointSet, merwe_scaled_sigma_points, robust_sqrt

__all__ = [
    "SigmaPointKalmanFilter",
    "SigmaPointPrediction",
    "MeasurementMoments",
    "UnscentedKalmanFilter",
    "check_points",
]


def check_points(name: str, value: Any, m: int, d: int) -> Array:
    """A model's output for ``m`` points as a finite ``(m, d)`` array.

    Raises:
        ValueError: naming the model function, on a wrong shape (a model that
            does not vectorise over points returns ``(d,)``) or non-finite values.
    """
    arr = np.asarray(value, dtype=float)
    if arr.shape != (m, d):
        raise ValueError(f"{name} returned shape {arr.shape} for {m} points, expected ({m}, {d})")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} returned non-finite values")
    return arr


@dataclass(frozen=True)
class SigmaPointPrediction:
    """The parts of a sigma-point prediction (MODELS.md B.8).

    Attributes:
        x: predicted mean ``x̄`` ``(n,)``.
        P0: spread of the propagated points ``P̄0 = Σ W_c (χ* − x̄)(χ* − x̄)ᵀ`` ``(n, n)``.
        Q: process noise of the step ``Q_k = L Lᵀ`` ``(n, n)``.
    """

    x: Array
    P0: Array
    Q: Array

    def state(self, fading_factor: float = 1.0) -> GaussianState:
        """``GaussianState(x̄, λ P̄0 + Q_k)``; ``λ = 1`` is the plain prediction.

        Args:
            fading_factor: strong-tracking ``λ ≥ 1`` (MODELS.md B.9).
        """
        return GaussianState(x=self.x, P=symmetrise(fading_factor * self.P0 + self.Q))


@dataclass(frozen=True)
class MeasurementMoments:
    """Predicted measurement statistics at a state (MODELS.md B.8, update).

    Attributes:
        z_hat: predicted measurement ``ẑ`` ``(p,)``.
        P_zz: innovation covariance ``Σ W_c (Z − ẑ)(Z − ẑ)ᵀ + R`` ``(p, p)``.
        P_xz: cross covariance ``Σ W_c (χ − x̄)(Z − ẑ)ᵀ`` ``(n, p)``.
        R: measurement noise covariance used ``(p, p)``.
    """

    z_hat: Array
    P_zz: Array
    P_xz: Array
    R: Array


@dataclass(frozen=True, kw_only=True)
class SigmaPointKalmanFilter(ModelFilter[GaussianState, StateSpaceModel]):
    """Additive-noise sigma-point Kalman filter with full covariance, gated (:class:`~.kalman.GatedFilter`).

    ``predict`` and ``update`` (:class:`~.kalman.ModelFilter`) check their
    arguments, then run :meth:`_predict` and :meth:`_update`. Subclasses
    choose the point set (:meth:`point_set`). ``P`` is factored
    with :func:`~.sigma_points.robust_sqrt` to draw points: Cholesky, with a
    PSD projection only if rounding has made ``P`` indefinite.
    """

    @abstractmethod
    def point_set(self, n: int) -> SigmaPointSet:
        """The point set for state dimension ``n``."""

    def initial_state(self, x0: Any, P0: Any) -> GaussianState:
        """``GaussianState`` from a finite mean ``(n,)`` and a symmetric ``P0`` ``(n, n)``."""
        return initial_gaussian(x0, P0)

    def propagate(
        self,
        state: GaussianState,
        model: StateSpaceModel,
        u: Any,
        dt: float,
        *,
        process_noise_sqrt: Any = None,
    ) -> SigmaPointPrediction:
        """The prediction as its parts ``x̄, P̄0, Q_k`` (see :meth:`predict`)."""
        n = model.state_dim
        x, P = check_state(state, n)
        L = process_noise_factor(model, x, u, dt, process_noise_sqrt, n)
        return self._prediction(x, P, model, u, dt, L)

    def _prediction(
        self, x: Array, P: Array, model: StateSpaceModel, u: Any, dt: float, L: Array
    ) -> SigmaPointPrediction:
        """:meth:`propagate` on the checked ``x`` ``(n,)``, ``P`` ``(n, n)`` and ``√Q_k`` ``L`` ``(n, q)``."""
        x_new, P0 = self._propagate_points(x, P, model, u, dt)
        return SigmaPointPrediction(x=x_new, P0=P0, Q=L @ L.T)

    def _propagate_points(self, x: Array, P: Array, model: StateSpaceModel, u: Any, dt: float) -> tuple[Array, Array]:
        """``x̄, P̄0`` of :meth:`propagate` for an already checked float ``x`` ``(n,)`` and ``P`` ``(n, n)``.

        The one implementation of the prediction's points (``propagate`` and the
        AN-STUKF's step call it); only the model's output is checked here.
        """
        n = x.shape[0]
        ps = self.point_set(n)
        X = x + ps.unit @ robust_sqrt(P).T
        Xp = check_points("model.f", model.f(X, u, dt), ps.num_points, n)
        x_new = ps.Wm @ Xp
        D = Xp - x_new
        return x_new, symmetrise((D.T * ps.Wc) @ D)

    def _predict(self, x: Array, P: Array, model: StateSpaceModel, u: Any, dt: float, L: Array) -> GaussianState:
        """Time update: push the points through ``model.f`` (all at once).

        ``model`` supplies ``f`` (vectorised, ``(m, n)`` → ``(m, n)``) and
        ``process_noise_sqrt``. Returns ``GaussianState(x̄, P̄0 + Q_k)``.
        """
        return self._prediction(x, P, model, u, dt, L).state()

    def measurement_moments(
        self,
        state: GaussianState,
        model: StateSpaceModel,
        u: Any = None,
        *,
        measurement_noise_sqrt: Any = None,
    ) -> MeasurementMoments:
        """``ẑ, P_zz, P_xz, R`` from points redrawn at ``state`` (MODELS.md B.8).

        Args:
            state: predicted state, ``x`` ``(n,)``, ``P`` ``(n, n)``.
            model: supplies ``h`` (vectorised, ``(m, n)`` → ``(m, p)``) and
                ``measurement_noise_sqrt``.
            u: input passed to ``h``.
            measurement_noise_sqrt: ``(p, r)`` factor of ``R`` overriding the
                model's.
        """
        n = model.state_dim
        p = model.measurement_dim
        x, P = check_state(state, n)
        Rs = measurement_noise_factor(model, measurement_noise_sqrt, p)
        z_hat, P_zz, P_xz, R = self._moments(x, P, Rs, model, u)
        return MeasurementMoments(z_hat=z_hat, P_zz=P_zz, P_xz=P_xz, R=R)

    def _moments(
        self, x: Array, P: Array, Rs: Array, model: StateSpaceModel, u: Any
    ) -> tuple[Array, Array, Array, Array]:
        """``ẑ, P_zz, P_xz, R`` of :meth:`measurement_moments` for an already checked float ``x``
        ``(n,)``, ``P`` ``(n, n)`` and factor ``Rs`` ``(p, r)`` (only the model's output is checked)."""
        n = x.shape[0]
        ps = self.point_set(n)
        dX = ps.unit @ robust_sqrt(P).T  # χ − x̄ (the points are centred on x̄)
        Z = check_points("model.h", model.h(x + dX, u), ps.num_points, Rs.shape[0])
        z_hat = ps.Wm @ Z
        dZ = Z - z_hat
        dZ_w = dZ.T * ps.Wc
        R = Rs @ Rs.T
        return z_hat, symmetrise(dZ_w @ dZ + R), (dZ_w @ dX).T, R

    def _update(
        self, state: GaussianState, x: Array, P: Array, zv: Array, model: StateSpaceModel, u: Any, Rs: Array
    ) -> tuple[GaussianState, UpdateInfo]:
        """Measurement update, gated on the NIS ``νᵀ P_zz⁻¹ ν``.

        ``model`` supplies ``h`` (vectorised, ``(m, n)`` → ``(m, p)``) and
        ``measurement_noise_sqrt``; ``u`` is passed to ``h``.
        """
        return self._moments_update(state, zv, MeasurementMoments(*self._moments(x, P, Rs, model, u)))

    def update_with_moments(
        self,
        state: GaussianState,
        z: Any,
        model: StateSpaceModel,
        u: Any = None,
        *,
        measurement_noise_sqrt: Any = None,
    ) -> tuple[GaussianState, UpdateInfo, MeasurementMoments]:
        """:meth:`update` and the moments it was made with (:meth:`measurement_moments` at ``state``).

        For a caller that needs both (the rover's noise matching): the points are drawn and ``h`` is
        evaluated once; the numbers are those of the two calls.
        """
        zv = check_measurement(z, model.measurement_dim)
        mm = self.measurement_moments(state, model, u, measurement_noise_sqrt=measurement_noise_sqrt)
        return (*self._moments_update(state, zv, mm), mm)

    def _moments_update(
        self, state: GaussianState, zv: Array, mm: MeasurementMoments
    ) -> tuple[GaussianState, UpdateInfo]:
        """The gated update of ``state`` by the checked measurement ``zv`` from its moments ``mm``."""
        nu = zv - mm.z_hat
        post, nis = self._gain_update(state.x, state.P, nu, mm.P_zz, mm.P_xz)
        info = UpdateInfo(innovation=nu, innovation_cov=mm.P_zz, nis=nis, accepted=post is not None)
        return (state if post is None else GaussianState(x=post[0], P=post[1])), info

    def _gain_update(
        self, x: Any, P: Any, nu: Array, P_zz: Array, P_xz: Array
    ) -> tuple[tuple[Array, Array] | None, float]:
        """The gated gain step of :meth:`update`: ``((x̂, P), NIS)``, or ``(None, NIS)`` when the gate rejects."""
        _, Y, w, nis = whiten_innovation(P_zz, P_xz, nu)
        threshold = self.gate_threshold
        if not (math.isfinite(nis) and (threshold is None or nis <= threshold)):  # nis_gate, for a float
            return None, nis
        # K ν = Yᵀ w and K P_zz Kᵀ = Yᵀ Y (see whiten_innovation): P = P̄ − K P_zz Kᵀ.
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        return (x + Y.T @ w, symmetrise(P - Y.T @ Y)), nis


@dataclass(frozen=True, kw_only=True)
class UnscentedKalmanFilter(SigmaPointKalmanFilter):
    """Unscented Kalman filter with scaled sigma points (MODELS.md B.8).

    Args:
        alpha: spread ``α > 0`` (default 1: with ``κ = 0`` all weights are
            positive and well conditioned; a very small α makes ``W_m0``
            large and negative).
        beta: ``β`` (2 is optimal for a Gaussian prior).
        kappa: ``κ``, with ``n + κ > 0`` (checked when ``n`` is known).
        gate_threshold: NIS gate, ``None`` disables gating.
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (math.isfinite(self.alpha) and self.alpha > 0.0):
            raise ValueError(f"alpha must be finite and > 0, got {self.alpha}")
        if not math.isfinite(self.beta):
            raise ValueError(f"beta must be finite, got {self.beta}")
        if not math.isfinite(self.kappa):
            raise ValueError(f"kappa must be finite, got {self.kappa}")

    def point_set(self, n: int) -> SigmaPointSet:
        """Scaled sigma points for dimension ``n`` (cached)."""
        return merwe_scaled_sigma_points(n, self.alpha, self.beta, self.kappa)
