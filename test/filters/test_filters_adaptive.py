"""Strong tracking (MODELS.md B.9) and noise adaptation (B.10) building blocks."""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from terrain_estimation.filters import (
    CubatureKalmanFilter,
    StrongTrackingConfig,
    UnscentedKalmanFilter,
    adapt_noise_sqrt,
    innovation_is_consistent,
    strong_tracking_predict,
    suboptimal_fading_factor,
)
from terrain_estimation.filters.adaptive import whitened_innovation_is_consistent


def linear_moments(rng, n=3, p=2):
    """Exact predicted moments of a linear measurement, so ``H̃ = H`` exactly."""
    A = rng.standard_normal((n, n))
    P0 = A @ A.T + 0.1 * np.eye(n)  # P̄0, the propagated spread
    Lq = 0.3 * np.eye(n)
    Q = Lq @ Lq.T
    P_pred = P0 + Q
    H = rng.standard_normal((p, n))
    R = np.diag([0.2, 0.5])
    return H, P0, Q, P_pred, R, P_pred @ H.T, H @ P_pred @ H.T + R


def test_consistency_test():
    P_zz = np.diag([1.0, 2.0])
    assert innovation_is_consistent(np.array([1.0, 1.0]), P_zz, 1.0)  # 2 ≤ 3
    assert not innovation_is_consistent(np.array([2.0, 0.0]), P_zz, 1.0)  # 4 > 3
    assert innovation_is_consistent(np.array([2.0, 0.0]), P_zz, 3.0)


def test_innovation_covariance_recursion_and_consistent_case():
    rng = np.random.default_rng(0)
    H, P0, Q, P_pred, R, P_xz, P_zz = linear_moments(rng)
    cfg = StrongTrackingConfig(rho=0.9)
    e1 = np.array([0.1, -0.2])
    lam, V1 = suboptimal_fading_factor(e1, P_zz, P_xz, P_pred, R, Q, None, cfg)
    assert lam == 1.0, "a small innovation leaves the filter alone"
    np.testing.assert_array_equal(V1, np.outer(e1, e1))
    e2 = np.array([0.3, 0.1])
    lam, V2 = suboptimal_fading_factor(e2, P_zz, P_xz, P_pred, R, Q, V1, cfg)
    np.testing.assert_allclose(V2, (0.9 * V1 + np.outer(e2, e2)) / 1.9, rtol=1e-15)


@pytest.mark.parametrize("simplified", [False, True])
def test_fading_factor_equations(simplified):
    rng = np.random.default_rng(1)
    H, P0, Q, P_pred, R, P_xz, P_zz = linear_moments(rng)
    e = 4.0 * np.sqrt(np.diagonal(P_zz))
    V_prev = 0.5 * P_zz
    cfg = StrongTrackingConfig(rho=0.95, beta_w=1.5, lambda_max=100.0, simplified=simplified)
    lam, V = suboptimal_fading_factor(e, P_zz, P_xz, P_pred, R, Q, V_prev, cfg)
    V_exp = (0.95 * V_prev + np.outer(e, e)) / 1.95
    np.testing.assert_allclose(V, V_exp, rtol=1e-14)
    if simplified:
        c = np.trace(V_exp - 1.5 * R) / np.trace(P_zz - R)
    else:
        # Linear h: H̃ = P_xzᵀ P̄⁻¹ = H, and M = P_zz − R − HQHᵀ = H P̄0 Hᵀ.
        c = np.trace(V_exp - 1.5 * R - H @ Q @ H.T) / np.trace(H @ P0 @ H.T)
    assert c > 1.0
    assert lam == pytest.approx(c, rel=1e-12)


def test_fading_factor_is_capped_and_floored():
    rng = np.random.default_rng(2)
    H, P0, Q, P_pred, R, P_xz, P_zz = linear_moments(rng)
    big = 1e3 * np.sqrt(np.diagonal(P_zz))
    lam, _ = suboptimal_fading_factor(big, P_zz, P_xz, P_pred, R, Q, None, StrongTrackingConfig(lambda_max=7.0))
    assert lam == 7.0
    # Activation test off and a zero innovation: c < 1, floored at λ = 1.
    lam, _ = suboptimal_fading_factor(np.zeros(2), P_zz, P_xz, P_pred, R, Q, None, StrongTrackingConfig(gamma_th=None))
    assert lam == 1.0
    # tr(M) ≤ 0: no propagated spread to rescale.
    lam, _ = suboptimal_fading_factor(
        big, R, np.zeros((3, 2)), P_pred, R, Q, None, StrongTrackingConfig(simplified=True)
    )
    assert lam == 1.0


def test_fading_factor_with_singular_predicted_covariance():
    """P̄ singular (the failure strong tracking is meant to survive): lstsq H̃."""
    P_pred = np.diag([1.0, 0.0])
    H = np.array([[1.0, 0.0]])
    R = np.array([[0.1]])
    lam, _ = suboptimal_fading_factor(
        np.array([3.0]), H @ P_pred @ H.T + R, P_pred @ H.T, P_pred, R, np.zeros((2, 2)), None
    )
    assert lam == pytest.approx((9.0 - 0.1) / 1.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"rho": 0.0}, "rho"),
        ({"rho": 1.5}, "rho"),
        ({"beta_w": 0.5}, "beta_w"),
        ({"gamma_th": 0.5}, "gamma_th"),
        ({"lambda_max": 0.9}, "lambda_max"),
    ],
)
def test_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        StrongTrackingConfig(**kwargs)


def test_strong_tracking_predict_consistent_is_plain_predict(pendulum_model, pendulum_run):
    ukf = UnscentedKalmanFilter()
    m, run = pendulum_model, pendulum_run
    state = ukf.initial_state(run.x0, run.P0)
    plain = ukf.predict(state, m, run.us[0], run.dt)
    z = m.h(plain.x, run.us[0])  # measurement at the predicted mean: a tiny innovation
    st = strong_tracking_predict(ukf, state, m, run.us[0], run.dt, z)
    assert st.fading_factor == 1.0
    np.testing.assert_array_equal(st.state.x, plain.x)
    np.testing.assert_array_equal(st.state.P, plain.P)
    np.testing.assert_allclose(st.V, np.outer(st.innovation, st.innovation))


def test_strong_tracking_predict_inflates_only_the_spread(pendulum_model, pendulum_run):
    ukf = UnscentedKalmanFilter()
    m, run = pendulum_model, pendulum_run
    state = ukf.initial_state(run.x0, run.P0)
    parts = ukf.propagate(state, m, run.us[0], run.dt)
    z = m.h(parts.x, run.us[0]) + np.array([2.0, -2.0])
    st = strong_tracking_predict(ukf, state, m, run.us[0], run.dt, z)
    assert 1.0 < st.fading_factor <= 10.0
    np.testing.assert_array_equal(st.state.x, parts.x)
    np.testing.assert_allclose(st.state.P, st.fading_factor * parts.P0 + parts.Q, rtol=1e-14)
    post, info = ukf.update(st.state, z, m, run.us[0])
    assert info.accepted


def test_strong_tracking_passes_noise_overrides(linear_model, linear_run):
    ckf = CubatureKalmanFilter()
    m, run = linear_model, linear_run
    state = ckf.initial_state(run.x0, run.P0)
    Lq2, Lr2 = 2.0 * m.Lq, 0.5 * m.Lr
    other = dataclasses.replace(m, Lq=Lq2, Lr=Lr2)
    z = run.zs[0] + 5.0
    a = strong_tracking_predict(ckf, state, m, run.us[0], 0.1, z, process_noise_sqrt=Lq2, measurement_noise_sqrt=Lr2)
    b = strong_tracking_predict(ckf, state, other, run.us[0], 0.1, z)
    assert a.fading_factor == pytest.approx(b.fading_factor, rel=1e-13)
    np.testing.assert_allclose(a.state.P, b.state.P, rtol=1e-13)


def test_strong_tracking_recovers_faster_after_a_jump(linear_model):
    """An unmodelled jump of the state: the STUKF error decays faster than the UKF's."""
    m = linear_model
    rng = np.random.default_rng(3)
    small_q = dataclasses.replace(m, Lq=0.01 * np.eye(4))
    ukf = UnscentedKalmanFilter()
    P0 = 0.01 * np.eye(4)
    plain = ukf.initial_state(np.zeros(4), P0)
    st_state = plain
    V = None
    x = np.zeros(4)
    err_plain, err_st = [], []
    for k in range(60):
        u = rng.standard_normal(2)
        x = m.F @ x + m.B @ u + 0.01 * rng.standard_normal(4)
        if k == 20:
            x = x + np.array([2.0, -1.0, 1.5, 0.5])
        z = m.H @ x + m.Lr @ rng.standard_normal(2)
        plain = ukf.predict(plain, small_q, u, 0.1)
        plain, _ = ukf.update(plain, z, small_q, u)
        st = strong_tracking_predict(ukf, st_state, small_q, u, 0.1, z, V_prev=V)
        V = st.V
        st_state, _ = ukf.update(st.state, z, small_q, u)
        if k > 20:
            err_plain.append(np.linalg.norm(plain.x - x))
            err_st.append(np.linalg.norm(st_state.x - x))
    ratio = sum(err_st[:20]) / sum(err_plain[:20])
    assert ratio < 0.7, ratio


def test_noise_adaptation_law():
    q0 = np.diag([0.02, 0.02, 0.005])
    r0 = np.diag([0.1, 0.1, 0.005])
    slips = np.array([0.1, -0.1, 0.2, -0.2, 0.0, 0.3])  # mean |α| = 0.15 rad
    out = adapt_noise_sqrt(q0, r0, slips, k_q=5.0, k_r=2.0)
    assert out.mean_abs_slip == pytest.approx(0.15)
    assert out.noise_scale == pytest.approx(1.75)
    np.testing.assert_allclose(out.process_noise_sqrt @ out.process_noise_sqrt.T, q0 @ q0.T * 1.75, rtol=1e-14)
    np.testing.assert_allclose(out.measurement_noise_sqrt @ out.measurement_noise_sqrt.T, r0 @ r0.T / 1.3, rtol=1e-14)
    base = adapt_noise_sqrt(q0, r0, slips, k_q=0.0, k_r=0.0)
    np.testing.assert_array_equal(base.process_noise_sqrt, q0)
    np.testing.assert_array_equal(base.measurement_noise_sqrt, r0)


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        ((np.eye(2), np.eye(2), [0.1]), {"k_q": -1.0, "k_r": 0.0}, "k_q"),
        ((np.eye(2), np.eye(2), [0.1]), {"k_q": 0.0, "k_r": np.nan}, "k_r"),
        ((np.eye(2), np.eye(2), []), {"k_q": 1.0, "k_r": 1.0}, "slip_angles"),
        ((np.eye(2), np.eye(2), [np.nan]), {"k_q": 1.0, "k_r": 1.0}, "slip_angles"),
        ((np.ones(2), np.eye(2), [0.1]), {"k_q": 1.0, "k_r": 1.0}, "q0_sqrt"),
        ((np.eye(2), np.ones(2), [0.1]), {"k_q": 1.0, "k_r": 1.0}, "r0_sqrt"),
    ],
)
def test_noise_adaptation_validation(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        adapt_noise_sqrt(*args, **kwargs)


# -- whitened criterion (MODELS.md B.12) -------------------------------------------------------


def test_strong_tracking_predict_with_the_whitened_criterion(pendulum_model, pendulum_run):
    """The whitened test acts on the NIS: a tiny innovation leaves the prediction alone, a large one
    inflates only the propagated spread, as the paper's criterion does."""
    ukf = UnscentedKalmanFilter()
    m, run = pendulum_model, pendulum_run
    cfg = StrongTrackingConfig(criterion="whitened")
    state = ukf.initial_state(run.x0, run.P0)
    parts = ukf.propagate(state, m, run.us[0], run.dt)
    quiet = strong_tracking_predict(ukf, state, m, run.us[0], run.dt, m.h(parts.x, run.us[0]), config=cfg)
    assert quiet.fading_factor == 1.0
    np.testing.assert_array_equal(quiet.state.P, parts.state().P)
    z = m.h(parts.x, run.us[0]) + np.array([2.0, -2.0])
    loud = strong_tracking_predict(ukf, state, m, run.us[0], run.dt, z, config=cfg)
    assert 1.0 < loud.fading_factor <= 10.0
    np.testing.assert_allclose(loud.state.P, loud.fading_factor * parts.P0 + parts.Q, rtol=1e-14)


def test_paper_criterion_misses_a_small_variance_channel_the_whitened_one_catches():
    """Two channels of very different variance (m/s² and rad/s): a 4σ innovation in the small one
    is invisible to eᵀe ≤ γ tr(P_zz), not to eᵀP_zz⁻¹e ≤ χ²_2."""
    P_zz = np.diag([0.1, 2.5e-5])
    e = np.array([0.0, 4.0 * 0.005])
    assert innovation_is_consistent(e, P_zz, 3.0)
    assert not whitened_innovation_is_consistent(e, P_zz, 0.99)
    assert whitened_innovation_is_consistent(np.array([0.3, 0.0]), P_zz, 0.99)
