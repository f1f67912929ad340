"""Property tests (hypothesis) of the filter fault protections (issue 7).

* The square-root cubature filter keeps its factor lower-triangular (exact
  zeros above the diagonal), finite, with a positive diagonal, over random
  small models, noise spanning ten decades, and random inputs. With a
  rank-deficient process noise the covariance may legitimately become
  singular (e.g. ``F = 0``): the diagonal is then only non-negative.
* The soil-stiffness estimator's compiled SCKF step
  (``estimators.soil_stiffness_sckf``, what the quarter-car and LRV nodes
  run) does the same over random quarter cars and LRVs (masses, stiffnesses,
  noise over decades, step lengths, sub-steps, road, profile-noise term).
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

from terrain_estimation.estimators.soil_stiffness_sckf import STATUS_OK, model_operands, run_step
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
from terrain_estimation.models.quarter_car import LRVModel, LRVParams, QuarterCarModel, QuarterCarParams

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


_compiled_steps = [0]


@st.composite
def bilinear_problems(draw):
    """A random quarter car or LRV (parameters ×0.3…3, noise over decades), its true k_tot, step and road."""
    lrv = draw(st.booleans())
    scale = st.floats(0.3, 3.0)
    q_scale = 10.0 ** draw(st.floats(-3.0, 3.0))
    r_scale = 10.0 ** draw(st.floats(-2.0, 2.0))
    common = {
        "c": (1_500.0 if lrv else 2_000.0) * draw(scale),
        "stiffness_state": draw(st.sampled_from(["k_tot", "log_k_s"])),
        "ktot_noise_form": draw(st.sampled_from(["per_step", "printed"])),
    }
    if lrv:
        p0 = LRVParams()
        params: Any = LRVParams(
            m_s=75.0 * draw(scale),
            k=15_000.0 * draw(scale),
            relative_damper=draw(st.booleans()),
            q_diag=tuple(v * q_scale for v in p0.q_diag),
            r_diag=tuple(v * r_scale for v in p0.r_diag),
            **common,
        )
        model: Any = LRVModel(params)
    else:
        p0 = QuarterCarParams()
        params = QuarterCarParams(
            m_s=455.0 * draw(scale),
            m_ns=45.5 * draw(scale),
            k=25_000.0 * draw(scale),
            k_t=175_000.0 * draw(scale),
            q_diag=tuple(v * q_scale for v in p0.q_diag),
            r_diag=tuple(v * r_scale for v in p0.r_diag),
            **common,
        )
        model = QuarterCarModel(params)
    k_true = model.k_series * draw(st.floats(0.01, 0.95))
    dt = draw(st.sampled_from([0.002, 0.005, 0.01, 0.0107, 0.02]))
    substeps = draw(st.integers(1, 20))
    road = 10.0 ** draw(st.floats(-3.0, 0.0))  # ḣ amplitude (m/s)
    profile_noise = draw(st.booleans())
    seed = draw(st.integers(0, 2**32 - 1))
    return model, k_true, dt, substeps, road, profile_noise, seed


@SETTINGS
@given(bilinear_problems())
def test_compiled_soil_stiffness_step_factor_stays_triangular_finite_and_positive(problem):
    model, k_true, dt, substeps, road, profile_noise, seed = problem
    n, p = model.state_dim, model.measurement_dim
    rng = np.random.default_rng(seed)
    ops = model_operands(model)
    filt = SquareRootCubatureKalmanFilter()
    p0 = np.full(n, 1e-4)
    p0[-1] = 1e8 if model.stiffness_state == "k_tot" else 0.3
    state = filt.initial_state(model.stiffness_state_of_ktot(0.5 * model.k_series) * np.eye(n)[-1], np.diag(p0))
    truth = model.stiffness_state_of_ktot(k_true) * np.eye(n)[-1]
    sqrt_r = np.sqrt(np.asarray(model.measurement_noise_sqrt()).diagonal())
    phase = rng.uniform(0.0, 6.3)
    for step in range(STEPS):
        t = step * dt + np.arange(substeps) * dt / substeps
        hdot = road * np.sin(7.0 * t + phase) + 0.2 * road * rng.standard_normal(substeps)
        truth = model.f(truth, hdot, dt)
        z = model.h(truth, hdot) + sqrt_r * rng.standard_normal(p)
        v_h, v_d = rng.uniform(0.0, 1e-8), rng.uniform(0.0, 1e-2)
        cov = rng.uniform(-1.0, 1.0) * np.sqrt(v_h * v_d)
        sigma_eps = np.array([[v_h, cov], [cov, v_d]])
        status, x_pred, S_pred, _, accepted, x, S = run_step(
            ops, model, state.x, state.S, hdot, dt, z, sigma_eps, profile_noise, None
        )
        assert status == STATUS_OK and accepted
        for mean, factor in ((x_pred, S_pred), (x, S)):
            assert np.isfinite(mean).all()
            assert_valid_factor(factor, True)
        state = replace(state, x=x, S=S)
        _compiled_steps[0] += 1


def test_compiled_soil_stiffness_property_figures():
    """Prints the figures of the compiled-step property test above."""
    print(f"\ncompiled soil-stiffness SCKF step: {_compiled_steps[0]} random predict+update steps, 0 failures")
    assert _compiled_steps[0] >= STEPS


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
