"""Linear Kalman filter: the closed-form reference every other filter must
reproduce on a linear model, plus the update arithmetic they share.

Model (discrete time)::

    x_{k+1} = F x_k + B u_k + w,   w ~ N(0, Q)
    z_k     = H x_k + v,           v ~ N(0, R)

Same style as the nonlinear filters: ``predict(state, ...) -> state`` and
``update(state, z, ...) -> (state, UpdateInfo)`` over immutable
:class:`~terrain_estimation.filters.base.GaussianState` values.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np

from .base import (
    Array,
    GaussianState,
    SqrtGaussianState,
    StateSpaceModel,
    UpdateInfo,
    check_square,
    check_vector,
    nis_gate,
)
from .sigma_points import cholesky, solve_lower

__all__ = [
    "GatedFilter",
    "KalmanFilter",
    "ModelFilter",
    "check_measurement",
    "check_state",
    "initial_gaussian",
    "check_covariance",
    "check_gate_threshold",
    "check_factor",
    "joseph_update",
    "measurement_noise_factor",
    "process_noise_factor",
    "state_mean",
    "symmetrise",
    "whiten_innovation",
]


def check_measurement(z: Any, p: int, name: str = "z") -> Array:
    """Return ``z`` as a finite ``(p,)`` float array.

    Raises:
        ValueError: on a wrong shape, or a non-finite entry (the message names
            the first offending index, e.g. ``z[1] is not finite (nan)``). A
            NaN must never reach the innovation: it would poison the state.
    """
    arr = check_vector(name, z, p)
    bad = ~np.isfinite(arr)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{name}[{i}] is not finite ({arr[i]})")
    return arr


def check_covariance(name: str, value: Any, size: int) -> Array:
    """Return ``value`` as a finite, symmetric ``(size, size)`` array.

    Symmetry is checked to a relative ``1e-9`` of the largest entry (what a
    user-built covariance should satisfy); the returned matrix is exactly
    symmetrised.

    Raises:
        ValueError: on a wrong shape, non-finite entries or asymmetry.
    """
    arr = check_square(name, value, size)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} has non-finite entries")
    scale = max(float(np.max(np.abs(arr), initial=0.0)), np.finfo(float).tiny)
    if np.max(np.abs(arr - arr.T), initial=0.0) > 1e-9 * scale:
        raise ValueError(f"{name} must be symmetric")
    return symmetrise(arr)


def initial_gaussian(x0: Any, P0: Any) -> GaussianState:
    """Checked ``GaussianState`` from a finite mean ``(n,)`` and a symmetric ``P0`` ``(n, n)``.

    Shared by every filter's ``initial_state``; copies ``x0`` so that the
    caller's array never aliases the state.

    Raises:
        ValueError: naming ``x0`` or ``P0``.
    """
    x = np.asarray(x0, dtype=float)
    if x.ndim != 1 or not np.isfinite(x).all():
        raise ValueError(f"x0 must be a finite 1-D array, got shape {x.shape}")
    return GaussianState(x=x.copy(), P=check_covariance("P0", P0, x.size))


def check_gate_threshold(value: float | None) -> None:
    """A gate threshold is ``None`` (no gating) or a finite positive NIS bound.

    Raises:
        ValueError: otherwise.
    """
    if value is not None and not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"gate_threshold must be None or finite and > 0, got {value}")


def check_factor(name: str, value: Any, rows: int) -> Array:
    """Return ``value`` as a float ``(rows, k)`` square-root factor (any ``k ≥ 1``).

    Raises:
        ValueError: if it is not 2-D with ``rows`` rows.
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != rows or arr.shape[1] < 1:
        raise ValueError(f"{name} must have shape ({rows}, k) with k >= 1, got {arr.shape}")
    return arr


def process_noise_factor(model: Any, x: Array, u: Any, dt: float, override: Any, n: int) -> Array:
    """The step's checked ``√Q_k`` ``(n, q)``: the caller's ``process_noise_sqrt`` or, when None, the model's.

    Raises:
        ValueError: naming ``process_noise_sqrt`` or ``model.process_noise_sqrt``.
    """
    if override is None:
        return check_factor("model.process_noise_sqrt", model.process_noise_sqrt(x, u, dt), n)
    return check_factor("process_noise_sqrt", override, n)


def measurement_noise_factor(model: Any, override: Any, p: int) -> Array:
    """The update's checked ``√R`` ``(p, r)``: the caller's ``measurement_noise_sqrt`` or, when None, the model's.

    Raises:
        ValueError: naming ``measurement_noise_sqrt`` or ``model.measurement_noise_sqrt``.
    """
    if override is None:
        return check_factor("model.measurement_noise_sqrt", model.measurement_noise_sqrt(), p)
    return check_factor("measurement_noise_sqrt", override, p)


def check_state(state: Any, n: int, *, factor: bool = False) -> tuple[Array, Array]:
    """``(x, P)`` of a state as float ``(n,)`` and ``(n, n)`` arrays, or ``(x, S)`` with ``factor``.

    Raises:
        ValueError: naming ``state.x``, ``state.P`` or ``state.S``.
    """
    x = check_vector("state.x", state.x, n)
    if factor:
        return x, check_square("state.S", state.S, n)
    return x, check_square("state.P", state.P, n)


def state_mean(state: Any) -> Array:
    """``state.x`` as a float 1-D array (its length defines ``n`` for a linear filter).

    Raises:
        ValueError: if it is not 1-D.
    """
    x = np.asarray(state.x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"state.x must be 1-D, got shape {x.shape}")
    return x


def symmetrise(P: Array) -> Array:  # matrix symbol of the literature
    """``(P + Pᵀ)/2``: removes the rounding asymmetry that would otherwise grow."""
    return 0.5 * (P + P.T)


def whiten_innovation(
    P_zz: Array,
    P_xz: Array,
    nu: Array,
) -> tuple[Array, Array, Array, float]:
    """Whiten the innovation and the cross covariance with ``L = chol(P_zz)``.

    With ``Y = L⁻¹ P_xzᵀ`` and ``w = L⁻¹ ν``: ``NIS = wᵀw``, the gain
    ``K = P_xz P_zz⁻¹ = Yᵀ L⁻¹``, ``K ν = Yᵀ w`` and ``K P_zz Kᵀ = Yᵀ Y``. One
    Cholesky and one triangular solve serve the gate, the mean and the
    covariance update, and ``P_zz`` is never inverted.

    Args:
        P_zz: innovation covariance ``(p, p)``.
        P_xz: state–measurement cross covariance ``(n, p)``.
        nu: innovation ``(p,)``.

    Returns:
        ``(L, Y, w, nis)`` with ``L`` ``(p, p)``, ``Y`` ``(p, n)``, ``w``
        ``(p,)``. If ``P_zz`` is not positive definite, ``nis`` is ``inf``
        (and ``L``, ``Y``, ``w`` are NaN) so
        that :func:`~terrain_estimation.filters.base.nis_gate` rejects the
        measurement instead of the filter dividing by a broken covariance.
    """
    n = P_xz.shape[0]
    p = P_zz.shape[0]
    try:
        L = cholesky(P_zz)
    except np.linalg.LinAlgError:
        nan = np.full((p, p + n + 1), np.nan)
        return nan[:, :p], nan[:, p : p + n], nan[:, p + n], float("inf")
    rhs = np.empty((p, n + 1))  # [P_xzᵀ, ν] (np.column_stack's values, one call)
    rhs[:, :n] = P_xz.T
    rhs[:, n] = nu
    sol = solve_lower(L, rhs)
    w = sol[:, n]
    return L, sol[:, :n], w, float(w @ w)


@dataclass(frozen=True, kw_only=True)
class GatedFilter:
    """What every filter of this package is configured with: its measurement gate.

    Args:
        gate_threshold: Mahalanobis gate on the NIS (e.g. a χ²_p quantile);
            ``None`` disables gating. A rejected measurement returns the
            prior state unchanged with ``accepted=False``.
    """

    gate_threshold: float | None = None

    def __post_init__(self) -> None:
        check_gate_threshold(self.gate_threshold)


StateT = TypeVar("StateT", GaussianState, SqrtGaussianState)
ModelT = TypeVar("ModelT", bound=StateSpaceModel)


@dataclass(frozen=True, kw_only=True)
class ModelFilter(GatedFilter, ABC, Generic[StateT, ModelT]):
    """The checked entry of ``predict``/``update`` that every filter over a model shares.

    The EKF, the sigma-point filters and the square-root CKF take the same
    arguments and check them the same way (the state's shapes, the
    measurement, the step's noise factors: the caller's override or the
    model's); each then runs its own equations on the checked arrays,
    :meth:`_predict` and :meth:`_update`. ``carries_factor`` says whether the
    state carries the square-root factor ``S`` instead of ``P``.
    """

    carries_factor: ClassVar[bool] = False

    def predict(
        self,
        state: StateT,
        model: ModelT,
        u: Any,
        dt: float,
        *,
        process_noise_sqrt: Any = None,
    ) -> StateT:
        """Time update: propagate the state through ``model.f`` (the filter's :meth:`_predict`).

        Args:
            state: posterior at step k, ``x`` ``(n,)``, ``P`` (or ``S``) ``(n, n)``.
            model: supplies ``f``, ``process_noise_sqrt`` and what the filter
                needs besides (see its :meth:`_predict`).
            u: input over the step, passed through to the model.
            dt: step length (s).
            process_noise_sqrt: ``(n, q)`` factor overriding
                ``model.process_noise_sqrt(x, u, dt)`` for this step.

        Returns:
            The predicted state.

        Raises:
            ValueError: on wrong shapes or non-finite model outputs.
        """
        n = model.state_dim
        x, P = check_state(state, n, factor=self.carries_factor)
        L = process_noise_factor(model, x, u, dt, process_noise_sqrt, n)
        return self._predict(x, P, model, u, dt, L)

    def update(
        self,
        state: StateT,
        z: Any,
        model: ModelT,
        u: Any = None,
        *,
        measurement_noise_sqrt: Any = None,
    ) -> tuple[StateT, UpdateInfo]:
        """Measurement update, gated on the NIS (the filter's :meth:`_update`).

        Args:
            state: predicted state, ``x`` ``(n,)``, ``P`` (or ``S``) ``(n, n)``.
            z: measurement ``(p,)``, finite.
            model: supplies ``h``, ``measurement_noise_sqrt`` and what the
                filter needs besides (see its :meth:`_update`).
            u: input passed to ``h``.
            measurement_noise_sqrt: ``(p, r)`` factor of ``R`` overriding the
                model's for this update (noise-adaptive filters).

        Returns:
            ``(posterior, info)``; the prior itself with ``info.accepted=False``
            when the gate rejects.

        Raises:
            ValueError: on wrong shapes, a non-finite measurement or non-finite model outputs.
        """
        n = model.state_dim
        p = model.measurement_dim
        x, P = check_state(state, n, factor=self.carries_factor)
        zv = check_measurement(z, p)
        Rs = measurement_noise_factor(model, measurement_noise_sqrt, p)
        return self._update(state, x, P, zv, model, u, Rs)

    @abstractmethod
    def _predict(self, x: Array, P: Array, model: ModelT, u: Any, dt: float, L: Array) -> StateT:
        """:meth:`predict` on the checked mean ``x`` ``(n,)``, ``P`` (or ``S``) ``(n, n)`` and ``√Q_k`` ``L``."""

    @abstractmethod
    def _update(
        self, state: StateT, x: Array, P: Array, zv: Array, model: ModelT, u: Any, Rs: Array
    ) -> tuple[StateT, UpdateInfo]:
        """:meth:`update` on the checked ``x``, ``P`` (or ``S``), measurement ``zv`` ``(p,)`` and ``√R`` ``Rs``.

        ``state`` is the prior, returned itself when the gate rejects.
        """


@dataclass(frozen=True, kw_only=True)
class KalmanFilter(GatedFilter):
    """Linear Kalman filter with the Joseph-form covariance update, gated (:class:`GatedFilter`)."""

    def initial_state(self, x0: Any, P0: Any) -> GaussianState:
        """``GaussianState`` from a mean ``(n,)`` and a symmetric covariance ``(n, n)``."""
        return initial_gaussian(x0, P0)

    def predict(
        self,
        state: GaussianState,
        F: Any,
        Q: Any,
        B: Any = None,
        u: Any = None,
    ) -> GaussianState:
        """``x̄ = F x + B u``, ``P̄ = F P Fᵀ + Q``.

        Args:
            state: prior, ``x`` ``(n,)``, ``P`` ``(n, n)``.
            F: transition matrix ``(n, n)``.
            Q: process noise covariance ``(n, n)``.
            B: input matrix ``(n, r)``; ``None`` for no input.
            u: input ``(r,)``; required when ``B`` is given.
        """
        x = state_mean(state)
        n = x.shape[0]
        P = check_square("state.P", state.P, n)
        F = check_square("F", F, n)
        Q = check_square("Q", Q, n)
        x_new = F @ x
        if B is not None:
            Bm = np.asarray(B, dtype=float)
            if Bm.ndim != 2 or Bm.shape[0] != n:
                raise ValueError(f"B must have shape ({n}, r), got {Bm.shape}")
            if u is None:
                raise ValueError("u is required when B is given")
            x_new = x_new + Bm @ check_vector("u", u, Bm.shape[1])
        return GaussianState(x=x_new, P=symmetrise(F @ P @ F.T + Q))

    def update(
        self,
        state: GaussianState,
        z: Any,
        H: Any,
        R: Any,
    ) -> tuple[GaussianState, UpdateInfo]:
        """Measurement update, Joseph form ``P = (I−KH) P (I−KH)ᵀ + K R Kᵀ``.

        The Joseph form keeps ``P`` symmetric positive semi-definite for any
        gain, where the short form ``(I − KH) P`` loses it to rounding
        (filterpy ``kalman/EKF.py`` explains the same choice).

        Args:
            state: predicted state, ``x`` ``(n,)``, ``P`` ``(n, n)``.
            z: measurement ``(p,)``, finite.
            H: measurement matrix ``(p, n)``.
            R: measurement noise covariance ``(p, p)``.

        Returns:
            ``(posterior, info)``; the prior itself when the gate rejects.
        """
        x = state_mean(state)
        n = x.shape[0]
        P = check_square("state.P", state.P, n)
        Hm = np.asarray(H, dtype=float)
        if Hm.ndim != 2 or Hm.shape[1] != n:
            raise ValueError(f"H must have shape (p, {n}), got {Hm.shape}")
        p = Hm.shape[0]
        zv = check_measurement(z, p)
        R = check_square("R", R, p)
        return joseph_update(state, x, P, zv, Hm @ x, Hm, R, self.gate_threshold)


def joseph_update(
    prior: GaussianState,
    x: Array,
    P: Array,
    z: Array,
    z_hat: Array,
    H: Array,
    R: Array,
    gate_threshold: float | None,
) -> tuple[GaussianState, UpdateInfo]:
    """Gated linear(ised) update shared by the Kalman filter and the EKF.

    Args:
        prior: the predicted state, returned unchanged on rejection.
        x, P: its mean ``(n,)`` and covariance ``(n, n)`` (already checked).
        z: measurement ``(p,)``; z_hat: predicted measurement ``(p,)``.
        H: (linearised) measurement matrix ``(p, n)``; R: ``(p, p)``.
        gate_threshold: NIS gate, ``None`` for none.
    """
    nu = z - z_hat
    P_xz = P @ H.T
    P_zz = symmetrise(H @ P_xz + R)
    L, Y, w, nis = whiten_innovation(P_zz, P_xz, nu)
    if not nis_gate(nis, gate_threshold):
        return prior, UpdateInfo(innovation=nu, innovation_cov=P_zz, nis=nis, accepted=False)
    K = solve_lower(L, Y, transpose=True).T
    I_KH = np.eye(x.shape[0]) - K @ H
    P_new = symmetrise(I_KH @ P @ I_KH.T + K @ R @ K.T)
    post = GaussianState(x=x + Y.T @ w, P=P_new)
    return post, UpdateInfo(innovation=nu, innovation_cov=P_zz, nis=nis, accepted=True)
