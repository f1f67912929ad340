"""Shared vocabulary of the filter library: Gaussian states, the model
protocol every filter is generic over, and what an update reports.

Shape convention (checked at every filter entry, see :func:`check_vector`):

* state mean ``x``: ``(n,)``
* covariance ``P`` and its lower-triangular square-root factor ``S``: ``(n, n)``
  with ``P = S @ S.T``
* a set of sigma/cubature points: ``(m, n)``, one point per row
* measurement ``z``: ``(p,)``; measurement covariance ``R``: ``(p, p)``

Models evaluate a whole set of points at once: ``f`` and ``h`` take ``x`` of
shape ``(n,)`` or ``(m, n)`` and return ``(n,)``/``(p,)`` or ``(m, n)``/``(m, p)``
respectively. Vectorising over points is what makes a numpy sigma-point filter
fast enough for 100 Hz on board.

The filters are steps over a state value: ``predict(state, model, u, dt) ->
state`` and ``update(state, z, model, u) -> (state, UpdateInfo)``. A filter
object holds configuration only (sigma-point parameters, gate); it never
mutates a state in place.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = [
    "Array",
    "GaussianState",
    "SqrtGaussianState",
    "UpdateInfo",
    "StateSpaceModel",
    "JacobianModel",
    "check_vector",
    "check_square",
    "nis_gate",
]


@dataclass(frozen=True)
class GaussianState:
    """Mean and full covariance (EKF, UKF, CKF)."""

    x: Array
    P: Array

    @property
    def covariance(self) -> Array:
        return self.P


@dataclass(frozen=True)
class SqrtGaussianState:
    """Mean and lower-triangular square-root factor ``S`` (``P = S Sᵀ``).

    The square-root filters carry ``S`` only; ``covariance`` forms ``P`` for
    reporting and never feeds back into the filter.
    """

    x: Array
    S: Array

    @property
    def covariance(self) -> Array:
        return self.S @ self.S.T

    @property
    def P(self) -> Array:  # noqa: N802 - the symbol of the literature
        return self.covariance


@dataclass(frozen=True)
class UpdateInfo:
    """What one measurement update did.

    Attributes:
        innovation: ``z - ẑ``, shape ``(p,)``.
        innovation_cov: its predicted covariance ``S_zz``, ``(p, p)``.
        nis: normalised innovation squared ``νᵀ S_zz⁻¹ ν`` (χ²_p under a
            consistent filter).
        accepted: False when the gate rejected the measurement; the returned
            state is then the prior, unchanged.
    """

    innovation: Array
    innovation_cov: Array
    nis: float
    accepted: bool = True
    extras: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class StateSpaceModel(Protocol):
    """A discrete-time model ``x_{k+1} = f(x_k, u_k, dt) + w``, ``z = h(x, u) + v``.

    ``u`` is whatever the model needs over the step (a scalar, a vector, or
    the input samples between two filter steps); filters pass it through.
    """

    @property
    def state_dim(self) -> int: ...

    @property
    def measurement_dim(self) -> int: ...

    def f(self, x: Array, u: Any, dt: float) -> Array:
        """Propagate one state ``(n,)`` or a set of points ``(m, n)`` over ``dt``."""
        ...

    def h(self, x: Array, u: Any) -> Array:
        """Predicted measurement for ``(n,)`` → ``(p,)`` or ``(m, n)`` → ``(m, p)``."""
        ...

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        """A square-root factor ``L`` of the step's process noise, ``Q_k = L Lᵀ``.

        ``(n, q)`` with any ``q``; given as a factor so that square-root
        filters never factor a matrix that may not be positive definite.
        """
        ...

    def measurement_noise_sqrt(self) -> Array:
        """A square-root factor of ``R``, ``(p, r)``."""
        ...


@runtime_checkable
class JacobianModel(StateSpaceModel, Protocol):
    """A model that also gives the Jacobians the EKF needs."""

    def transition_jacobian(self, x: Array, u: Any, dt: float) -> Array:
        """``∂f/∂x`` at ``x`` ``(n,)``, shape ``(n, n)``."""
        ...

    def measurement_jacobian(self, x: Array, u: Any) -> Array:
        """``∂h/∂x`` at ``x`` ``(n,)``, shape ``(p, n)``."""
        ...


def check_vector(name: str, value: Any, size: int) -> Array:
    """Return ``value`` as a float ``(size,)`` array or raise a clear ValueError."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got {arr.shape}")
    return arr


def check_square(name: str, value: Any, size: int) -> Array:
    """Return ``value`` as a float ``(size, size)`` array or raise a clear ValueError."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (size, size):
        raise ValueError(f"{name} must have shape ({size}, {size}), got {arr.shape}")
    return arr


def nis_gate(nis: float, threshold: float | None) -> bool:
    """Mahalanobis gate: accept when ``nis <= threshold`` (None disables gating).

    A non-finite NIS is always rejected: it means the innovation or its
    covariance is already broken, and folding it in would poison the state.
    """
    if not np.isfinite(nis):
        return False
    return threshold is None or nis <= threshold
