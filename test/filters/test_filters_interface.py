"""The common interface: gating, shape and value checks, overrides, immutability."""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
from scipy.stats import chi2

from terrain_estimation.filters import (
    CubatureKalmanFilter,
    ExtendedKalmanFilter,
    GaussianState,
    KalmanFilter,
    SqrtGaussianState,
    SquareRootCubatureKalmanFilter,
    UnscentedKalmanFilter,
)

GATE = float(chi2.ppf(0.999, df=2))  # ≈ 13.8

FILTER_TYPES = {
    "ekf": ExtendedKalmanFilter,
    "ukf": UnscentedKalmanFilter,
    "ckf": CubatureKalmanFilter,
    "sckf": SquareRootCubatureKalmanFilter,
}


@pytest.fixture(params=list(FILTER_TYPES))
def filter_type(request):
    return FILTER_TYPES[request.param]


def predicted(filt, model, run):
    state = filt.initial_state(run.x0, run.P0)
    return filt.predict(state, model, run.us[0], run.dt)


def test_gate_rejects_outlier_and_accepts_normal_measurement(filter_type, linear_model, linear_run):
    filt = filter_type(gate_threshold=GATE)
    prior = predicted(filt, linear_model, linear_run)
    u = linear_run.us[0]
    z_hat = linear_model.H @ prior.x
    P_zz = linear_model.H @ prior.covariance @ linear_model.H.T + linear_model.Lr @ linear_model.Lr.T
    sigma = np.sqrt(np.diagonal(P_zz))

    outlier = z_hat + np.array([30.0, -30.0]) * sigma
    post, info = filt.update(prior, outlier, linear_model, u)
    assert not info.accepted
    assert post is prior, "a rejected measurement returns the prior unchanged"
    assert info.nis > GATE
    np.testing.assert_allclose(info.innovation, outlier - z_hat, rtol=1e-12)
    np.testing.assert_allclose(info.innovation_cov, P_zz, rtol=1e-10)

    normal = z_hat + np.array([0.5, -0.3]) * sigma
    post, info = filt.update(prior, normal, linear_model, u)
    assert info.accepted
    assert info.nis <= GATE
    assert not np.array_equal(post.x, prior.x)
    assert np.trace(post.covariance) < np.trace(prior.covariance)


def test_kalman_filter_gate(linear_model, linear_run):
    kf = KalmanFilter(gate_threshold=GATE)
    m = linear_model
    prior = kf.predict(kf.initial_state(linear_run.x0, linear_run.P0), m.F, m.Lq @ m.Lq.T)
    post, info = kf.update(prior, m.H @ prior.x + 100.0, m.H, m.Lr @ m.Lr.T)
    assert post is prior and not info.accepted
    post, info = kf.update(prior, m.H @ prior.x + 0.01, m.H, m.Lr @ m.Lr.T)
    assert info.accepted and post is not prior


def test_no_gate_accepts_everything(filter_type, linear_model, linear_run):
    filt = filter_type()
    prior = predicted(filt, linear_model, linear_run)
    _, info = filt.update(prior, np.array([1e3, -1e3]), linear_model, linear_run.us[0])
    assert info.accepted and info.nis > 1e4


@pytest.mark.parametrize("value", [-1.0, 0.0, float("nan"), float("inf")])
def test_gate_threshold_validated(filter_type, value):
    with pytest.raises(ValueError, match="gate_threshold"):
        filter_type(gate_threshold=value)


def test_filters_are_immutable(filter_type):
    filt = filter_type(gate_threshold=5.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        filt.gate_threshold = 1.0  # type: ignore[misc]


def test_inputs_are_not_mutated(filter_type, linear_model, linear_run):
    filt = filter_type()
    state = filt.initial_state(linear_run.x0, linear_run.P0)
    snapshot = {k: np.copy(v) for k, v in vars(state).items()}
    prior = filt.predict(state, linear_model, linear_run.us[0], linear_run.dt)
    prior_snapshot = {k: np.copy(v) for k, v in vars(prior).items()}
    filt.update(prior, linear_run.zs[0], linear_model, linear_run.us[0])
    for k, v in snapshot.items():
        np.testing.assert_array_equal(getattr(state, k), v)
    for k, v in prior_snapshot.items():
        np.testing.assert_array_equal(getattr(prior, k), v)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda f, m, s, u: f.initial_state(np.zeros((4, 1)), np.eye(4)), "x0"),
        (lambda f, m, s, u: f.initial_state(np.zeros(4), np.eye(3)), "P0"),
        (lambda f, m, s, u: f.initial_state(np.zeros(4), np.triu(np.ones((4, 4)))), "P0"),
        (lambda f, m, s, u: f.initial_state(np.full(4, np.nan), np.eye(4)), "x0"),
        (
            lambda f, m, s, u: f.predict(dataclasses.replace(s, x=np.zeros(3)), m, u, 0.1),
            r"state\.x",
        ),
        (
            lambda f, m, s, u: f.update(dataclasses.replace(s, x=np.zeros(5)), np.zeros(2), m, u),
            r"state\.x",
        ),
        (lambda f, m, s, u: f.update(s, np.zeros(3), m, u), r"\bz\b"),
        (lambda f, m, s, u: f.update(s, np.zeros((2, 1)), m, u), r"\bz\b"),
        (lambda f, m, s, u: f.update(s, np.array([0.0, np.nan]), m, u), r"z\[1\] is not finite"),
        (lambda f, m, s, u: f.update(s, np.array([np.inf, 0.0]), m, u), r"z\[0\] is not finite"),
        (
            lambda f, m, s, u: f.update(s, np.zeros(2), m, u, measurement_noise_sqrt=np.eye(3)),
            "measurement_noise_sqrt",
        ),
        (
            lambda f, m, s, u: f.predict(s, m, u, 0.1, process_noise_sqrt=np.ones(4)),
            "process_noise_sqrt",
        ),
    ],
)
def test_shape_and_value_errors_name_the_argument(filter_type, linear_model, linear_run, call, match):
    filt = filter_type()
    state = filt.initial_state(linear_run.x0, linear_run.P0)
    with pytest.raises(ValueError, match=match):
        call(filt, linear_model, state, linear_run.us[0])


def test_wrong_covariance_shape_names_the_field(filter_type, linear_model, linear_run):
    filt = filter_type()
    state = filt.initial_state(linear_run.x0, linear_run.P0)
    field = "S" if isinstance(state, SqrtGaussianState) else "P"
    with pytest.raises(ValueError, match=rf"state\.{field}"):
        filt.predict(dataclasses.replace(state, **{field: np.eye(3)}), linear_model, linear_run.us[0], 0.1)


class NotVectorised:
    """Returns one state whatever it is given: the classic mistake."""

    def __init__(self, model):
        self.m = model
        self.state_dim, self.measurement_dim = model.state_dim, model.measurement_dim

    def f(self, x, u, dt):
        return self.m.f(np.atleast_2d(x)[0], u, dt)

    def h(self, x, u):
        return self.m.h(x, u)

    def process_noise_sqrt(self, x, u, dt):
        return self.m.Lq

    def measurement_noise_sqrt(self):
        return self.m.Lr


class NaNModel(NotVectorised):
    def f(self, x, u, dt):
        return np.full(np.shape(x), np.nan)

    def transition_jacobian(self, x, u, dt):
        return self.m.F


@pytest.mark.parametrize("ftype", [UnscentedKalmanFilter, CubatureKalmanFilter, SquareRootCubatureKalmanFilter])
def test_model_not_vectorised_is_reported(ftype, linear_model, linear_run):
    filt = ftype()
    state = filt.initial_state(linear_run.x0, linear_run.P0)
    with pytest.raises(ValueError, match=r"model\.f returned shape \(4,\)"):
        filt.predict(state, NotVectorised(linear_model), linear_run.us[0], 0.1)


def test_non_finite_model_output_is_reported(filter_type, linear_model, linear_run):
    filt = filter_type()
    state = filt.initial_state(linear_run.x0, linear_run.P0)
    with pytest.raises(ValueError, match=r"model\.f returned non-finite"):
        filt.predict(state, NaNModel(linear_model), linear_run.us[0], 0.1)


def test_ukf_kappa_checked_against_dimension(linear_model, linear_run):
    filt = UnscentedKalmanFilter(kappa=-4.0)  # n + κ = 0 for n = 4
    state = filt.initial_state(linear_run.x0, linear_run.P0)
    with pytest.raises(ValueError, match="kappa"):
        filt.predict(state, linear_model, linear_run.us[0], 0.1)
    with pytest.raises(ValueError, match="alpha"):
        UnscentedKalmanFilter(alpha=0.0)


def test_measurement_noise_override(filter_type, linear_model, linear_run):
    """The override must act exactly like a model with that R."""
    filt = filter_type()
    prior = predicted(filt, linear_model, linear_run)
    z, u = linear_run.zs[0], linear_run.us[0]
    Lr2 = 3.0 * linear_model.Lr
    other = dataclasses.replace(linear_model, Lr=Lr2)
    a, ia = filt.update(prior, z, linear_model, u, measurement_noise_sqrt=Lr2)
    b, ib = filt.update(prior, z, other, u)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-13, atol=1e-15)
    assert ia.nis == pytest.approx(ib.nis, rel=1e-13)
    c, _ = filt.update(prior, z, linear_model, u)
    assert not np.allclose(a.covariance, c.covariance)


def test_process_noise_override(filter_type, linear_model, linear_run):
    filt = filter_type()
    state = filt.initial_state(linear_run.x0, linear_run.P0)
    Lq2 = np.hstack([linear_model.Lq, 0.1 * np.eye(4)])  # (n, q) with q ≠ n
    other = dataclasses.replace(linear_model, Lq=Lq2)
    u = linear_run.us[0]
    a = filt.predict(state, linear_model, u, 0.1, process_noise_sqrt=Lq2)
    b = filt.predict(state, other, u, 0.1)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-13, atol=1e-15)


def test_sckf_initial_state_from_singular_p0():
    filt = SquareRootCubatureKalmanFilter()
    P0 = np.diag([1.0, 0.0, 4.0])  # a known state: Cholesky fails, eigen fallback
    state = filt.initial_state(np.zeros(3), P0)
    assert not np.triu(state.S, 1).any()
    np.testing.assert_allclose(state.covariance, P0, atol=1e-14)


def test_full_covariance_state_types(linear_run):
    for ftype in (ExtendedKalmanFilter, UnscentedKalmanFilter, CubatureKalmanFilter, KalmanFilter):
        assert isinstance(ftype().initial_state(linear_run.x0, linear_run.P0), GaussianState)


def test_kalman_filter_argument_checks(linear_model, linear_run):
    kf = KalmanFilter()
    m = linear_model
    s = kf.initial_state(linear_run.x0, linear_run.P0)
    with pytest.raises(ValueError, match="F"):
        kf.predict(s, np.eye(3), np.eye(4))
    with pytest.raises(ValueError, match="u is required"):
        kf.predict(s, m.F, np.eye(4), m.B)
    with pytest.raises(ValueError, match=r"\bu\b"):
        kf.predict(s, m.F, np.eye(4), m.B, np.zeros(3))
    with pytest.raises(ValueError, match="H"):
        kf.update(s, np.zeros(2), np.eye(3), np.eye(2))
    with pytest.raises(ValueError, match="R"):
        kf.update(s, np.zeros(2), m.H, np.eye(3))


def test_core_does_not_import_rclpy():
    """STYLE principle 1: the math core knows no ROS."""
    code = (
        "import sys, terrain_estimation.filters as f; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rosbags')]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
