"""Models and data shared by the filter tests.

Two models implement :class:`~terrain_estimation.filters.base.JacobianModel`:

* ``LinearModel`` — ``x' = F x + B u``, ``z = H x``: the filters must equal the
  linear Kalman filter on it;
* ``PendulumModel`` — a damped pendulum with an unknown input gain carried as
  a random-walk state (bilinear like the quarter-car ``k_tot``) and a
  nonlinear measurement.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

Array = np.ndarray


@dataclass(frozen=True)
class LinearModel:
    """``x' = F x + B u + w``, ``z = H x + v``; vectorised over points (rows)."""

    F: Array
    B: Array
    H: Array
    Lq: Array
    Lr: Array

    @property
    def state_dim(self) -> int:
        return int(self.F.shape[0])

    @property
    def measurement_dim(self) -> int:
        return int(self.H.shape[0])

    def f(self, x: Array, u: Any, dt: float) -> Array:
        return x @ self.F.T + self.B @ np.asarray(u, dtype=float)

    def h(self, x: Array, u: Any) -> Array:
        return x @ self.H.T

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        return self.Lq

    def measurement_noise_sqrt(self) -> Array:
        return self.Lr

    def transition_jacobian(self, x: Array, u: Any, dt: float) -> Array:
        return self.F

    def measurement_jacobian(self, x: Array, u: Any) -> Array:
        return self.H


@dataclass(frozen=True)
class PendulumModel:
    """Euler-discretised damped pendulum driven by ``g·u`` with unknown gain ``g``.

    ``x = [θ, ω, g]``; ``θ' = θ + dt ω``, ``ω' = ω + dt (−a sin θ − b ω + g u)``,
    ``g' = g``; ``z = [sin θ + 0.5 ω, ω g]``.
    """

    a: float = 9.81
    b: float = 0.3
    Lq: Array = field(default_factory=lambda: np.diag([1e-3, 2e-2, 5e-2]))
    Lr: Array = field(default_factory=lambda: np.array([[0.05, 0.0], [0.01, 0.08]]))

    state_dim: int = 3
    measurement_dim: int = 2

    def f(self, x: Array, u: Any, dt: float) -> Array:
        th, om, g = x[..., 0], x[..., 1], x[..., 2]
        return np.stack([th + dt * om, om + dt * (-self.a * np.sin(th) - self.b * om + g * u), g], axis=-1)

    def h(self, x: Array, u: Any) -> Array:
        th, om, g = x[..., 0], x[..., 1], x[..., 2]
        return np.stack([np.sin(th) + 0.5 * om, om * g], axis=-1)

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        return self.Lq

    def measurement_noise_sqrt(self) -> Array:
        return self.Lr

    def transition_jacobian(self, x: Array, u: Any, dt: float) -> Array:
        th, om, g = x
        return np.array([[1.0, dt, 0.0], [-dt * self.a * np.cos(th), 1.0 - dt * self.b, dt * u], [0, 0, 1.0]])

    def measurement_jacobian(self, x: Array, u: Any) -> Array:
        th, om, g = x
        return np.array([[np.cos(th), 0.5, 0.0], [0.0, g, om]])


def make_linear_model(seed: int = 1) -> LinearModel:
    """A stable 4-state, 2-measurement, 2-input model with full-rank noise.

    Two lightly damped oscillators (spectral radius ≈ 0.99) coupled by a
    random perturbation; entries O(1) so that P stays O(1e-2…1).
    """
    rng = np.random.default_rng(seed)
    dt = 0.1
    osc = np.array([[1.0, dt], [-dt, 1.0 - 0.2 * dt]])
    F = np.block([[osc, np.zeros((2, 2))], [np.zeros((2, 2)), osc]])
    F = F + 0.02 * rng.standard_normal((4, 4))
    B = rng.standard_normal((4, 2)) * 0.1
    H = rng.standard_normal((2, 4))
    Lq = np.tril(rng.standard_normal((4, 4))) * 0.05 + 0.05 * np.eye(4)
    Lr = np.array([[0.3, 0.0], [0.1, 0.2]])
    return LinearModel(F=F, B=B, H=H, Lq=Lq, Lr=Lr)


@dataclass(frozen=True)
class Run:
    """A simulated run: initial belief, inputs and measurements."""

    x0: Array
    P0: Array
    us: Array
    zs: Array
    xs: Array
    dt: float


def simulate(
    model: Any,
    x_true0: Array,
    x0: Array,
    P0: Array,
    *,
    steps: int,
    seed: int,
    dt: float,
    u_shape: tuple[int, ...],
) -> Run:
    """Simulate ``steps`` noisy transitions; ``zs[k]`` measures ``xs[k]`` (after step k).

    Inputs are standard normal of shape ``u_shape`` per step (``()`` = scalar).
    """
    rng = np.random.default_rng(seed)
    n, p = model.state_dim, model.measurement_dim
    us = rng.standard_normal((steps, *u_shape))
    xs = np.empty((steps, n))
    zs = np.empty((steps, p))
    x = np.asarray(x_true0, dtype=float)
    Lr = model.measurement_noise_sqrt()
    for k in range(steps):
        Lq = model.process_noise_sqrt(x, us[k], dt)
        x = model.f(x, us[k], dt) + Lq @ rng.standard_normal(Lq.shape[1])
        xs[k] = x
        zs[k] = model.h(x, us[k]) + Lr @ rng.standard_normal(Lr.shape[1])
    return Run(x0=np.asarray(x0, float), P0=np.asarray(P0, float), us=us, zs=zs, xs=xs, dt=dt)


@pytest.fixture(scope="session")
def linear_model() -> LinearModel:
    return make_linear_model()


@pytest.fixture(scope="session")
def linear_run(linear_model: LinearModel) -> Run:
    rng = np.random.default_rng(7)
    A = rng.standard_normal((4, 4))
    P0 = 0.1 * A @ A.T + 0.05 * np.eye(4)
    return simulate(
        linear_model,
        np.array([1.0, 0.0, -0.5, 0.3]),
        np.array([0.8, 0.1, -0.3, 0.0]),
        P0,
        steps=50,
        seed=11,
        dt=0.1,
        u_shape=(2,),
    )


@pytest.fixture(scope="session")
def pendulum_model() -> PendulumModel:
    return PendulumModel()


@pytest.fixture(scope="session")
def pendulum_run(pendulum_model: PendulumModel) -> Run:
    return simulate(
        pendulum_model,
        np.array([0.6, 0.0, 2.0]),
        np.array([0.4, 0.2, 1.0]),
        np.diag([0.05, 0.1, 0.5]),
        steps=30,
        seed=5,
        dt=0.05,
        u_shape=(),
    )
