"""UKF / STUKF / AN-STUKF step composition (MODELS.md B.8–B.10) on the skid-steer observer model."""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from terrain_estimation.filters import (
    GaussianState,
    StrongTrackingConfig,
    UnscentedKalmanFilter,
    adapt_noise_sqrt,
    strong_tracking_predict,
)
from terrain_estimation.filters.an_stukf import AdaptiveStrongTrackingUKF, AnStukfResult
from terrain_estimation.models.skid_steer_observer import SkidSteerInput, SkidSteerObserverModel, tire_sideslips

MODEL = SkidSteerObserverModel()
RAD = MODEL.params.wheel_radius
# A left turn at 5 km/h with clearly non-zero tire sideslip.
U = SkidSteerInput(1.0 / RAD, 1.8 / RAD, 0.0, 0.2)
STATE = GaussianState(x=np.array([1.35, 0.02, 0.2]), P=np.diag([0.05**2, 0.03**2, 0.01**2]))
Z = np.array([0.15, 0.35, 0.21])
DT = 0.01


def assert_states_equal(a: GaussianState, b: GaussianState, tol: float = 1e-12) -> None:
    np.testing.assert_allclose(a.x, b.x, rtol=tol, atol=tol)
    np.testing.assert_allclose(a.P, b.P, rtol=tol, atol=tol * float(np.abs(b.P).max()))


def test_ukf_variant_equals_plain_ukf_predict_update():
    ukf = UnscentedKalmanFilter(alpha=1.0, beta=2.0, kappa=0.0)
    filt = AdaptiveStrongTrackingUKF(variant="ukf", ukf=ukf)
    post, res = filt.step(STATE, Z, MODEL, U, DT, memory=None)
    ref, info = ukf.update(ukf.predict(STATE, MODEL, U, DT), Z, MODEL, U)
    assert_states_equal(post, ref)
    assert res.nis == pytest.approx(info.nis, rel=1e-12)
    np.testing.assert_allclose(res.innovation, info.innovation, rtol=1e-12, atol=1e-15)
    assert (res.fading_factor, res.noise_scale, res.mean_abs_sideslip, res.memory) == (1.0, 1.0, 0.0, None)
    # And over a run of steps with changing inputs.
    rng = np.random.default_rng(0)
    s1 = s2 = STATE
    for k in range(20):
        u = SkidSteerInput(1.0 / RAD + 0.1 * k, 1.8 / RAD, 0.05, 0.2)
        z = Z + rng.normal(scale=[0.1, 0.1, 0.005])
        s1, _ = filt.step(s1, z, MODEL, u, DT)
        s2, _ = ukf.update(ukf.predict(s2, MODEL, u, DT), z, MODEL, u)
    assert_states_equal(s1, s2)


def test_stukf_equals_strong_tracking_predict_then_update():
    cfg = StrongTrackingConfig(rho=0.9, gamma_th=None)  # fading factor at every step
    ukf = UnscentedKalmanFilter()
    filt = AdaptiveStrongTrackingUKF(variant="stukf", ukf=ukf, strong_tracking=cfg)
    V = 0.5 * np.eye(3)
    z = Z + np.array([1.0, -0.8, 0.05])  # large innovation: λ > 1
    post, res = filt.step(STATE, z, MODEL, U, DT, memory=V)
    st = strong_tracking_predict(ukf, STATE, MODEL, U, DT, z, V_prev=V, config=cfg)
    ref, info = ukf.update(st.state, z, MODEL, U)
    assert st.fading_factor > 1.0
    assert res.fading_factor == pytest.approx(st.fading_factor, rel=1e-12)
    np.testing.assert_allclose(res.memory, st.V, rtol=1e-12)
    assert_states_equal(post, ref)
    assert res.nis == pytest.approx(info.nis, rel=1e-12)
    assert res.noise_scale == 1.0


def test_stukf_fading_factor_is_one_on_consistent_innovations():
    ukf = UnscentedKalmanFilter()
    filt = AdaptiveStrongTrackingUKF(variant="stukf", ukf=ukf)
    # The predicted measurement itself: zero innovation.
    prior = ukf.predict(STATE, MODEL, U, DT)
    z_hat = ukf.measurement_moments(prior, MODEL, U).z_hat
    post, res = filt.step(STATE, z_hat, MODEL, U, DT)
    assert res.fading_factor == 1.0
    ref, _ = ukf.update(prior, z_hat, MODEL, U)
    assert_states_equal(post, ref)


def simulate(n_steps, seed, jump_at=None, jump=0.0):
    """Truth from the model itself (steady input) with the process noise Q0 and the IMU noise R0.

    An optional jump of vx (an event the model cannot predict) at step ``jump_at``.
    """
    rng = np.random.default_rng(seed)
    truth = SkidSteerObserverModel(max_euler_gain=0.05)
    x = np.array([1.35, 0.0, 0.15])
    u = SkidSteerInput(1.1 / RAD, 1.6 / RAD, 0.0, 0.2)
    out = []
    for k in range(n_steps):
        x = truth.f(x, u, DT) + rng.normal(scale=np.sqrt(MODEL.q0_diag))
        if k == jump_at:
            x = x + np.array([jump, 0.0, 0.0])
        z = truth.h(x, u) + rng.normal(scale=np.sqrt(MODEL.r0_diag))
        out.append((x.copy(), z))
    return u, out


def run(variant, u, data, **kwargs):
    filt = AdaptiveStrongTrackingUKF(variant=variant, **kwargs)
    state, memory = GaussianState(x=np.array([1.35, 0.0, 0.15]), P=np.diag([0.01, 0.01, 1e-4])), None
    results: list[AnStukfResult] = []
    states = []
    for _, z in data:
        state, res = filt.step(state, z, MODEL, u, DT, memory)
        memory = res.memory
        results.append(res)
        states.append(state.x)
    return np.array(states), results


def test_stukf_consistent_run_rarely_fades():
    u, data = simulate(300, seed=1)
    _, results = run("stukf", u, data)
    lam = np.array([r.fading_factor for r in results[20:]])
    assert np.mean(lam > 1.0) < 0.05, "consistent innovations pass the activation test (B.9)"
    assert np.all(lam >= 1.0)
    nis = np.mean([r.nis for r in results[20:]])
    assert 2.4 < nis < 3.6, "the filter is consistent on its own model (χ²₃ mean 3)"


def test_stukf_fades_after_a_step_change_and_tracks_faster():
    u, data = simulate(200, seed=2, jump_at=100, jump=0.5)
    truth = np.array([x for x, _ in data])
    st_states, st_results = run("stukf", u, data)
    ukf_states, _ = run("ukf", u, data)
    lam = np.array([r.fading_factor for r in st_results])
    assert np.all(lam[90:100] == 1.0)
    assert lam[100] > 1.0, "the innovation after the jump triggers the fading factor"
    # Right after the jump the strong-tracking filter is closer to the truth.
    err_st = np.abs(st_states[100:103, 0] - truth[100:103, 0]).sum()
    err_ukf = np.abs(ukf_states[100:103, 0] - truth[100:103, 0]).sum()
    assert err_st < err_ukf


def test_an_stukf_noise_scale_from_sideslip_at_the_predicted_mean():
    ukf = UnscentedKalmanFilter()
    cfg = StrongTrackingConfig(gamma_th=None)
    filt = AdaptiveStrongTrackingUKF(variant="an_stukf", ukf=ukf, strong_tracking=cfg, k_q=5.0, k_r=2.0)
    V = 0.2 * np.eye(3)
    post, res = filt.step(STATE, Z, MODEL, U, DT, memory=V)
    x_bar = ukf.predict(STATE, MODEL, U, DT).x
    a_bar = float(np.mean(np.abs(tire_sideslips(x_bar, MODEL.params))))
    assert a_bar > 0.05
    assert res.mean_abs_sideslip == pytest.approx(a_bar, rel=1e-12)
    assert res.noise_scale == pytest.approx(1.0 + 5.0 * a_bar, rel=1e-12)
    # The whole step equals strong tracking + update with the adapted Q_k, R_k.
    q0_sqrt, r0_sqrt = MODEL.process_noise_sqrt(STATE.x, U, DT), MODEL.measurement_noise_sqrt()
    noise = adapt_noise_sqrt(q0_sqrt, r0_sqrt, tire_sideslips(x_bar, MODEL.params), k_q=5.0, k_r=2.0)
    st = strong_tracking_predict(
        ukf,
        STATE,
        MODEL,
        U,
        DT,
        Z,
        V_prev=V,
        config=cfg,
        process_noise_sqrt=noise.process_noise_sqrt,
        measurement_noise_sqrt=noise.measurement_noise_sqrt,
    )
    ref, info = ukf.update(st.state, Z, MODEL, U, measurement_noise_sqrt=noise.measurement_noise_sqrt)
    assert res.fading_factor == pytest.approx(st.fading_factor, rel=1e-12)
    assert_states_equal(post, ref)
    np.testing.assert_allclose(res.innovation_cov, info.innovation_cov, rtol=1e-12)
    # R_k = R0 / (1 + K_r ᾱ) is what the update used.
    R0 = np.diag(MODEL.r0_diag)
    P_zz_plain = ukf.measurement_moments(st.state, MODEL, U).P_zz
    np.testing.assert_allclose(P_zz_plain - res.innovation_cov, R0 - R0 / (1 + 2.0 * a_bar), rtol=1e-9, atol=1e-15)


def test_an_stukf_without_gains_is_the_stukf():
    a, ra = AdaptiveStrongTrackingUKF(variant="an_stukf", k_q=0.0, k_r=0.0).step(STATE, Z, MODEL, U, DT)
    b, rb = AdaptiveStrongTrackingUKF(variant="stukf").step(STATE, Z, MODEL, U, DT)
    assert_states_equal(a, b)
    assert ra.noise_scale == 1.0 and ra.fading_factor == rb.fading_factor


def test_fixed_noise_factors_override_the_model():
    q0 = np.diag([0.05, 0.05, 0.01])
    r0 = np.diag([0.3, 0.3, 0.01])
    filt = AdaptiveStrongTrackingUKF(variant="ukf", q0_sqrt=q0, r0_sqrt=r0)
    ukf = filt.ukf
    post, _ = filt.step(STATE, Z, MODEL, U, DT)
    prior = ukf.predict(STATE, MODEL, U, DT, process_noise_sqrt=q0)
    ref, _ = ukf.update(prior, Z, MODEL, U, measurement_noise_sqrt=r0)
    assert_states_equal(post, ref)
    assert not filt.q0_sqrt.flags.writeable


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"variant": "ekf"}, "variant"),
        ({"k_q": -1.0}, "k_q"),
        ({"k_r": float("nan")}, "k_r"),
        ({"q0_sqrt": np.zeros(3)}, "q0_sqrt"),
        ({"ukf": object()}, "ukf"),
    ],
)
def test_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AdaptiveStrongTrackingUKF(**kwargs)


def test_an_stukf_needs_sideslip_and_finite_measurement():
    @dataclasses.dataclass
    class NoSideslip:
        inner: SkidSteerObserverModel

        state_dim = 3
        measurement_dim = 3

        def f(self, x, u, dt):
            return self.inner.f(x, u, dt)

        def h(self, x, u):
            return self.inner.h(x, u)

        def process_noise_sqrt(self, x, u, dt):
            return self.inner.process_noise_sqrt(x, u, dt)

        def measurement_noise_sqrt(self):
            return self.inner.measurement_noise_sqrt()

    with pytest.raises(ValueError, match="tire_sideslip"):
        AdaptiveStrongTrackingUKF().step(STATE, Z, NoSideslip(MODEL), U, DT)
    # ... which the other variants do not need.
    AdaptiveStrongTrackingUKF(variant="stukf").step(STATE, Z, NoSideslip(MODEL), U, DT)
    with pytest.raises(ValueError):
        AdaptiveStrongTrackingUKF().step(STATE, np.array([0.0, np.nan, 0.0]), MODEL, U, DT)


class _CountingModel:
    """The observer model, counting its ``h`` evaluations."""

    def __init__(self, inner: SkidSteerObserverModel) -> None:
        self.inner = inner
        self.h_calls = 0

    def __getattr__(self, name: str):
        return getattr(self.inner, name)

    def h(self, x, u):
        self.h_calls += 1
        return self.inner.h(x, u)


@pytest.mark.parametrize("variant", ["stukf", "an_stukf"])
def test_without_fading_the_update_reuses_the_moments_it_has(variant):
    """λ = 1: the update's points are the ones the fading factor was computed from, so ``h`` runs
    once per step and the posterior is exactly that of a fresh update."""
    ukf = UnscentedKalmanFilter()
    filt = AdaptiveStrongTrackingUKF(variant=variant, ukf=ukf)
    model = _CountingModel(MODEL)
    post, res = filt.step(STATE, Z, model, U, DT, memory=None)
    assert res.fading_factor == 1.0
    assert model.h_calls == 1
    # The reference: the same prediction, then an update that redraws the points.
    pred = ukf.propagate(STATE, MODEL, U, DT, process_noise_sqrt=MODEL.process_noise_sqrt(STATE.x, U, DT))
    rs = MODEL.measurement_noise_sqrt()
    if variant == "an_stukf":
        noise = adapt_noise_sqrt(
            MODEL.process_noise_sqrt(STATE.x, U, DT), rs, tire_sideslips(pred.x, MODEL.params), k_q=5.0, k_r=2.0
        )
        lq, rs = noise.process_noise_sqrt, noise.measurement_noise_sqrt
        pred = dataclasses.replace(pred, Q=lq @ lq.T)
    ref, info = ukf.update(pred.state(), Z, MODEL, U, measurement_noise_sqrt=rs)
    np.testing.assert_array_equal(post.x, ref.x)
    np.testing.assert_array_equal(post.P, ref.P)
    assert res.nis == info.nis
    # With fading, the update draws new points from the inflated covariance: h runs twice.
    model.h_calls = 0
    cfg = StrongTrackingConfig(gamma_th=None)
    _, res = AdaptiveStrongTrackingUKF(variant=variant, ukf=ukf, strong_tracking=cfg).step(
        STATE, Z + np.array([1.0, -0.8, 0.05]), model, U, DT, memory=0.5 * np.eye(3)
    )
    assert res.fading_factor > 1.0
    assert model.h_calls == 2


# -- the innovation-adaptive variant on the observer model (MODELS.md B.12) -------------------


def test_adaptive_variant_on_the_models_own_data_is_consistent_and_quiet():
    u, data = simulate(600, seed=3)
    _, results = run("adaptive", u, data)
    lam = np.array([r.fading_factor for r in results[50:]])
    assert np.mean(lam > 1.0) < 0.03, "whitened strong tracking: ≈ 1 % of the steps on consistent data"
    nis = np.mean([r.nis for r in results[50:]])
    assert 2.5 < nis < 3.5
    q = np.array([r.noise_scale for r in results[50:]])
    assert 0.5 < q.mean() < 2.0
    assert all(r.measurement_noise_scale is not None and r.measurement_noise_scale.shape == (3,) for r in results)


def test_adaptive_variant_scales_an_over_large_q0_down():
    """The observer's Q0 against a truth that moves 100× less in variance (B.12: NIS ≪ 3): the
    adaptive filter's Q scale falls and its NIS comes back to ≈ 3; the UKF's stays low."""
    rng = np.random.default_rng(4)
    truth = SkidSteerObserverModel(max_euler_gain=0.05)
    x = np.array([1.35, 0.0, 0.15])
    u = SkidSteerInput(1.1 / RAD, 1.6 / RAD, 0.0, 0.2)
    data = []
    for _ in range(1500):
        x = truth.f(x, u, DT) + rng.normal(scale=0.1 * np.sqrt(MODEL.q0_diag))
        data.append((x.copy(), truth.h(x, u) + rng.normal(scale=np.sqrt(MODEL.r0_diag))))
    _, adaptive = run("adaptive", u, data)
    _, plain = run("ukf", u, data)
    assert np.mean([r.nis for r in plain[500:]]) < 1.5
    assert 2.5 < np.mean([r.nis for r in adaptive[500:]]) < 3.5
    assert np.mean([r.noise_scale for r in adaptive[500:]]) < 0.2
