"""Property tests (hypothesis) of the filter fault protections (issue 7).

* The square-root cubature filter keeps its factor lower-triangular (exact
  zeros above the diagonal), finite, with a positive diagonal, over random
  small models, noise spanning ten decades, and random inputs. With a
  rank-deficient process noise the covariance may legitimately become
  singular (e.g. ``F = 0``): the diagonal is then only non-negative.
* :func:`~terrain_estimation.filters.faults.guarded_step` never lets a
  non-finite estimate or an exception out, for every filter, over random
  models (some with a fault: ``f`` NaN beyond a random bound) and hostile
  measurements (huge, NaN, infinite values).

The number of random steps is a budget shared by the examples, set by the
environment variable ``TERRAIN_PROPERTY_STEPS`` (default 4000, about a
second). The issue's long run is ``TERRAIN_PROPERTY_STEPS=1000000``; each
test prints its figures (run pytest with ``-s`` to see them). Deterministic:
``derandomize=True``, no example database.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from terrain_estimation.filters import (
    CubatureKalmanFilter,
    DivergenceConfig,
    DivergenceMonitor,
    ExtendedKalmanFilter,
    SquareRootCubatureKalmanFilter,
    UnscentedKalmanFilter,
    guarded_step,
    sqrt_factor_fault,
)

EXAMPLES = 20
TOTAL_STEPS = int(os.environ.get("TERRAIN_PROPERTY_STEPS", "4000"))
STEPS = max(1, TOTAL_STEPS // EXAMPLES)
SETTINGS = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)


@dataclass(frozen=True)
class RandomModel:
    """``f = F x + ε tanh(x) + B u``, ``z = H x + ε tanh(x₀)``, with Jacobians (EKF).

    ``limit``: a model fault, ``f`` is NaN where ``|x₀| > limit`` (the filters
    raise on it).
    """

    F: np.ndarray
    B: np.ndarray
    H: np.ndarray
    eps: float
    Lq: np.ndarray
    Lr: np.ndarray
    limit: float = np.inf

    @property
    def state_dim(self) -> int:
        return int(self.F.shape[0])

    @property
    def measurement_dim(self) -> int:
        return int(self.H.shape[0])

    def f(self, x: np.ndarray, u: Any, dt: float) -> np.ndarray:
        out = x @ self.F.T + self.eps * np.tanh(x) + self.B @ u
        if np.isfinite(self.limit):
            out = np.where(np.abs(x[..., :1]) > self.limit, np.nan, out)
        return out

    def h(self, x: np.ndarray, u: Any) -> np.ndarray:
        return x @ self.H.T + self.eps * np.tanh(x[..., :1])

    def process_noise_sqrt(self, x: np.ndarray, u: Any, dt: float) -> np.ndarray:
        return self.Lq

    def measurement_noise_sqrt(self) -> np.ndarray:
        return self.Lr

    def transition_jacobian(self, x: np.ndarray, u: Any, dt: float) -> np.ndarray:
        return self.F + self.eps * np.diag(1.0 - np.tanh(x) ** 2)

    def measurement_jacobian(self, x: np.ndarray, u: Any) -> np.ndarray:
        J = self.H.copy()
        J[:, 0] += self.eps * (1.0 - np.tanh(x[0]) ** 2)
        return J


@st.composite
def problems(draw):
    """A random stable model, its noise (10⁻⁷…10³ in σ), an input scale and a seed."""
    n = draw(st.integers(1, 6))
    p = draw(st.integers(1, 3))
    q = draw(st.integers(1, n + 1))  # q < n: rank-deficient process noise
    seed = draw(st.integers(0, 2**32 - 1))
    radius = draw(st.floats(0.0, 0.995))
    eps = draw(st.floats(0.0, 0.3))
    log_q = draw(st.floats(-7.0, 1.0))
    log_r = draw(st.floats(-4.0, 3.0))
    log_u = draw(st.floats(-3.0, 3.0))
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    F = A * (radius / max(np.abs(np.linalg.eigvals(A)).max(), 1e-12))
    model = RandomModel(
        F=F,
        B=rng.standard_normal((n, 2)),
        H=rng.standard_normal((p, n)),
        eps=eps,
        Lq=10.0**log_q * rng.standard_normal((n, q)),
        Lr=10.0**log_r * (np.eye(p) + 0.3 * np.tril(rng.standard_normal((p, p)), -1)),
    )
    return model, seed, 10.0**log_u, q >= n


def simulate_step(model: RandomModel, x: np.ndarray, u_scale: float, rng: np.random.Generator):
    u = u_scale * rng.standard_normal(2)
    x = model.f(x, u, 0.01) + model.Lq @ rng.standard_normal(model.Lq.shape[1])
    z = model.h(x, u) + model.Lr @ rng.standard_normal(model.measurement_dim)
    return x, u, z


def assert_valid_factor(S: np.ndarray, positive: bool) -> None:
    assert sqrt_factor_fault(S) == "", sqrt_factor_fault(S)
    if positive:
        assert (np.diagonal(S) > 0.0).all(), np.diagonal(S)


_sckf_steps = [0]


@SETTINGS
@given(problems())
def test_sckf_factor_stays_triangular_finite_and_positive(problem):
    model, seed, u_scale, full_rank_q = problem
    n = model.state_dim
    rng = np.random.default_rng(seed + 1)
    filt = SquareRootCubatureKalmanFilter()
    state = filt.initial_state(np.zeros(n), np.eye(n))
    x = rng.standard_normal(n)
    for _ in range(STEPS):
        x, u, z = simulate_step(model, x, u_scale, rng)
        state = filt.predict(state, model, u, 0.01)
        assert_valid_factor(state.S, full_rank_q)
        assert np.isfinite(state.x).all()
        state, info = filt.update(state, z, model, u)
        assert info.accepted
        assert np.isfinite(state.x).all()
        assert_valid_factor(state.S, full_rank_q)
        _sckf_steps[0] += 1


def test_sckf_property_figures():
    """Prints the figures of the property test above (it ran first, in file order)."""
    print(f"\nSCKF factor property: {_sckf_steps[0]} random predict+update steps, 0 failures")
    assert _sckf_steps[0] >= STEPS


FILTERS = (ExtendedKalmanFilter, UnscentedKalmanFilter, CubatureKalmanFilter, SquareRootCubatureKalmanFilter)
HOSTILE = (np.nan, np.inf, -np.inf, 1e300, -1e300, 1e150, 1e30)
_guarded = {"steps": 0, "divergences": 0}


@SETTINGS
@given(
    problems(),
    st.sampled_from(FILTERS),
    st.one_of(st.none(), st.floats(1.0, 100.0)),
    st.floats(0.0, 0.3),
    st.one_of(st.just(np.inf), st.floats(0.5, 20.0)),
)
def test_guarded_filters_never_publish_a_non_finite_estimate(problem, filter_type, gate, hostile_rate, limit):
    model, seed, u_scale, _ = problem
    model = replace(model, limit=limit)
    n = model.state_dim
    rng = np.random.default_rng(seed + 2)
    filt = filter_type(gate_threshold=gate)
    monitor = DivergenceMonitor(DivergenceConfig(window=10, persistence=5, max_rejections=5))
    state = filt.initial_state(np.zeros(n), np.eye(n))
    monitor.start(state)
    x = rng.standard_normal(n)
    for _ in range(max(1, STEPS // 4)):
        x, u, z = simulate_step(model, x, u_scale, rng)
        if rng.random() < hostile_rate:
            z = z.copy()
            z[rng.integers(z.size)] = HOSTILE[rng.integers(len(HOSTILE))]
        state, _, check = guarded_step(filt, monitor, state, model, u, 0.01, z)
        assert np.isfinite(np.asarray(state.x)).all()
        assert np.isfinite(np.asarray(state.covariance)).all()
        if isinstance(filt, SquareRootCubatureKalmanFilter):
            assert sqrt_factor_fault(state.S) == ""
        _guarded["steps"] += 1
        _guarded["divergences"] += check.diverged


def test_guarded_property_figures():
    """Prints the figures of the guarded-filter property test above."""
    print(
        f"\nguarded filters: {_guarded['steps']} random steps with hostile measurements, "
        f"{_guarded['divergences']} divergences recovered, 0 non-finite estimates, 0 exceptions"
    )
    assert _guarded["steps"] >= STEPS // 4
