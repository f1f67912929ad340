"""Property test: the SCKF square-root factor stays a valid factor.

Random stable linear-ish models (a stable linear part plus a bounded tanh
term), random noise factors spanning six decades (process noise possibly
rank-deficient), random inputs; a few hundred steps each. After every predict
and update the factor must be lower-triangular with exact zeros above the
diagonal, a non-negative diagonal, finite, and ``P = S Sᵀ`` symmetric PSD.
Deterministic: ``derandomize=True``, no example database.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from terrain_estimation.filters import SquareRootCubatureKalmanFilter

STEPS = 250


@dataclass(frozen=True)
class LinearishModel:
    F: np.ndarray
    B: np.ndarray
    H: np.ndarray
    eps: float
    Lq: np.ndarray
    Lr: np.ndarray

    @property
    def state_dim(self) -> int:
        return int(self.F.shape[0])

    @property
    def measurement_dim(self) -> int:
        return int(self.H.shape[0])

    def f(self, x: np.ndarray, u: Any, dt: float) -> np.ndarray:
        return x @ self.F.T + self.eps * np.tanh(x) + self.B @ u

    def h(self, x: np.ndarray, u: Any) -> np.ndarray:
        return x @ self.H.T + self.eps * np.tanh(x[..., :1])

    def process_noise_sqrt(self, x: np.ndarray, u: Any, dt: float) -> np.ndarray:
        return self.Lq

    def measurement_noise_sqrt(self) -> np.ndarray:
        return self.Lr


@st.composite
def problems(draw):
    n = draw(st.integers(2, 6))
    p = draw(st.integers(1, 3))
    q = draw(st.integers(1, n))  # q < n: rank-deficient process noise
    seed = draw(st.integers(0, 2**32 - 1))
    radius = draw(st.floats(0.3, 0.99))
    eps = draw(st.floats(0.0, 0.2))
    log_q = draw(st.floats(-6.0, 0.0))
    log_r = draw(st.floats(-3.0, 1.0))
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    F = A * (radius / max(np.abs(np.linalg.eigvals(A))))
    model = LinearishModel(
        F=F,
        B=rng.standard_normal((n, 2)),
        H=rng.standard_normal((p, n)),
        eps=eps,
        Lq=10.0**log_q * rng.standard_normal((n, q)),
        Lr=10.0**log_r * (np.eye(p) + 0.3 * np.tril(rng.standard_normal((p, p)), -1)),
    )
    return model, seed


def assert_valid_factor(S: np.ndarray) -> None:
    assert np.isfinite(S).all()
    assert not np.triu(S, 1).any()
    assert (np.diagonal(S) >= 0.0).all()
    P = S @ S.T
    np.testing.assert_allclose(P, P.T, rtol=0, atol=1e-12 * max(1.0, np.abs(P).max()))
    assert np.linalg.eigvalsh(P).min() >= -1e-12 * max(1.0, np.abs(P).max())


@settings(
    max_examples=25,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(problems())
def test_sckf_factor_stays_valid(problem):
    model, seed = problem
    n = model.state_dim
    rng = np.random.default_rng(seed + 1)
    filt = SquareRootCubatureKalmanFilter()
    state = filt.initial_state(np.zeros(n), np.eye(n))
    x = rng.standard_normal(n)
    for _ in range(STEPS):
        u = rng.standard_normal(2)
        x = model.f(x, u, 0.01) + model.Lq @ rng.standard_normal(model.Lq.shape[1])
        z = model.h(x, u) + model.Lr @ rng.standard_normal(model.measurement_dim)
        state = filt.predict(state, model, u, 0.01)
        assert_valid_factor(state.S)
        state, info = filt.update(state, z, model, u)
        assert info.accepted
        assert np.isfinite(state.x).all()
        assert_valid_factor(state.S)
