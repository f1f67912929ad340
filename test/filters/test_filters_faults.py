"""Filter faults (issue 7): innovation gating, divergence detection, recovery.

Each protection has a test that fails when it is removed:

* the Mahalanobis gate (``nis_gate``): an outlier is rejected and the run
  stays accurate; the same run without a gate is ruined;
* the windowed NIS against its χ² band: a filter with a wrong measurement
  noise is found diverged, a consistent one is not (no false alarm);
* covariance blow-up: an unstable, unobserved model is caught long before
  its covariance overflows;
* gate lock-out: a gated filter that lost the track is re-initialised and
  tracks again;
* recovery: after a huge accepted measurement the filter restarts from the
  last good estimate (finite, near the truth), the fault is reported until
  it is consistent again, then cleared;
* a filter exception or a non-finite state never escapes
  :func:`~terrain_estimation.filters.faults.guarded_step`.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from conftest import LinearModel
from scipy.stats import chi2

from terrain_estimation.filters import (
    CubatureKalmanFilter,
    DivergenceConfig,
    DivergenceMonitor,
    ExtendedKalmanFilter,
    GaussianState,
    SqrtGaussianState,
    SquareRootCubatureKalmanFilter,
    UnscentedKalmanFilter,
    UpdateInfo,
    guarded_step,
    nis_band,
    sqrt_factor_fault,
)

GATE = float(chi2.ppf(0.9999, df=2))  # ≈ 18.4
FILTERS = {
    "ekf": ExtendedKalmanFilter,
    "ukf": UnscentedKalmanFilter,
    "ckf": CubatureKalmanFilter,
    "sckf": SquareRootCubatureKalmanFilter,
}


def stable_model(lr_scale: float = 1.0) -> LinearModel:
    """Two damped oscillators (spectral radius ≈ 0.96), two measurements, two inputs."""
    F = np.array([[0.95, 0.1, 0, 0], [-0.1, 0.9, 0, 0], [0, 0, 0.98, 0.05], [0, 0, -0.05, 0.97]])
    B = np.array([[0.1, 0.0], [0.0, 0.05], [0.02, 0.0], [0.0, 0.1]])
    H = np.array([[1.0, 0.0, 0.5, 0.0], [0.0, 0.3, 0.0, 1.0]])
    Lq = 0.05 * np.eye(4)
    Lr = lr_scale * np.array([[0.3, 0.0], [0.1, 0.2]])
    return LinearModel(F=F, B=B, H=H, Lq=Lq, Lr=Lr)


@dataclasses.dataclass
class Truth:
    """A simulated run of ``model`` (the truth), reproducible from ``seed``."""

    model: LinearModel
    seed: int
    steps: int
    dt: float = 0.1

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        m = self.model
        self.us = rng.standard_normal((self.steps, 2))
        self.xs = np.empty((self.steps, 4))
        self.zs = np.empty((self.steps, 2))
        x = np.zeros(4)
        for k in range(self.steps):
            x = m.f(x, self.us[k], self.dt) + m.Lq @ rng.standard_normal(4)
            self.xs[k] = x
            self.zs[k] = m.h(x, self.us[k]) + m.Lr @ rng.standard_normal(2)


def run(
    filt: Any,
    model: Any,
    truth: Truth,
    *,
    monitor: DivergenceMonitor | None = None,
    zs: Any = None,
    p0: float = 1.0,
):
    """Filter ``truth`` (or the measurements ``zs``) from ``N(0, p0 I)``; return the means and the checks."""
    zs = truth.zs if zs is None else zs
    state = filt.initial_state(np.zeros(4), p0 * np.eye(4))
    if monitor is not None:
        monitor.start(state)
    means, checks = [], []
    for k in range(truth.steps):
        if monitor is None:
            state = filt.predict(state, model, truth.us[k], truth.dt)
            state, _ = filt.update(state, zs[k], model, truth.us[k])
        else:
            state, _, check = guarded_step(filt, monitor, state, model, truth.us[k], truth.dt, zs[k])
            checks.append(check)
        means.append(np.asarray(state.x))
    return np.array(means), checks


# -- gating -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(FILTERS))
def test_gate_rejects_an_outlier_and_the_run_stays_accurate(name):
    """One 1000-σ outlier: gated, the estimate is untouched; without the gate it is ruined."""
    model = stable_model()
    truth = Truth(model, seed=3, steps=80)
    zs = truth.zs.copy()
    zs[40] += np.array([300.0, -300.0])
    gated, _ = run(FILTERS[name](gate_threshold=GATE), model, truth, zs=zs)
    clean, _ = run(FILTERS[name](gate_threshold=GATE), model, truth)
    ungated, _ = run(FILTERS[name](), model, truth, zs=zs)
    err_gated = np.abs(gated[40:50] - truth.xs[40:50]).max()
    err_ungated = np.abs(ungated[40:50] - truth.xs[40:50]).max()
    assert err_gated < 1.0, "a gated outlier must not move the estimate"
    assert err_ungated > 20.0, "the scenario must be one the gate matters for"
    # The gated run equals the clean one except for the skipped update.
    np.testing.assert_allclose(gated[:40], clean[:40], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", list(FILTERS))
def test_gate_is_a_mahalanobis_bound_on_the_nis(name):
    """Accept exactly when NIS ≤ threshold, whichever way the innovation points."""
    model = stable_model()
    filt = FILTERS[name](gate_threshold=GATE)
    prior = filt.predict(filt.initial_state(np.zeros(4), 0.1 * np.eye(4)), model, np.zeros(2), 0.1)
    P_zz = model.H @ prior.covariance @ model.H.T + model.Lr @ model.Lr.T
    L = np.linalg.cholesky(P_zz)
    z_hat = model.H @ prior.x
    for angle in np.linspace(0.0, 2 * np.pi, 7):
        direction = np.array([np.cos(angle), np.sin(angle)])
        for radius2, accepted in ((0.98 * GATE, True), (1.02 * GATE, False)):
            z = z_hat + L @ (np.sqrt(radius2) * direction)  # NIS = radius2
            post, info = filt.update(prior, z, model)
            assert info.nis == pytest.approx(radius2, rel=1e-9)
            assert info.accepted is accepted
            assert (post is prior) is (not accepted)


# -- divergence detection ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(FILTERS))
def test_consistent_filter_raises_no_false_alarm(name):
    model = stable_model()
    truth = Truth(model, seed=5, steps=1500)
    monitor = DivergenceMonitor()
    _, checks = run(FILTERS[name](gate_threshold=GATE), model, truth, monitor=monitor)
    assert monitor.divergences == 0 and monitor.fault is None
    assert sum(c.good for c in checks) > 0.9 * len(checks)


@pytest.mark.parametrize("name", ["ukf", "sckf"])
def test_wrong_measurement_noise_is_found_by_the_nis_band(name):
    """R configured 10× too small in σ: mean NIS ≈ 100, far above the band."""
    truth = Truth(stable_model(), seed=7, steps=200)
    monitor = DivergenceMonitor(DivergenceConfig(window=20, persistence=5, max_rejections=None))
    _, checks = run(FILTERS[name](), stable_model(lr_scale=0.1), truth, monitor=monitor)
    first = next(i for i, c in enumerate(checks) if c.diverged)
    assert first == 20 + 5 - 2  # full window at update 20, five consecutive checks out of band
    assert "above its chi-square band" in checks[first].reason
    assert checks[first].mean_nis > checks[first].band[1]


def test_too_large_noise_is_found_below_the_band_unless_check_low_is_off():
    truth = Truth(stable_model(), seed=7, steps=100)
    wrong = stable_model(lr_scale=10.0)
    monitor = DivergenceMonitor(DivergenceConfig(persistence=5))
    _, checks = run(UnscentedKalmanFilter(), wrong, truth, monitor=monitor)
    assert any("below its chi-square band" in c.reason for c in checks)
    relaxed = DivergenceMonitor(DivergenceConfig(persistence=5, check_low=False))
    run(UnscentedKalmanFilter(), wrong, truth, monitor=relaxed)
    assert relaxed.divergences == 0


@pytest.mark.parametrize("name", list(FILTERS))
def test_covariance_blow_up_is_caught_before_it_overflows(name):
    """An unstable, unobserved state: P grows 9× per step, caught at 10⁶× its reference."""
    model = stable_model()
    unstable = dataclasses.replace(model, F=3.0 * np.eye(4), H=np.zeros((2, 4)))
    filt = FILTERS[name]()
    monitor = DivergenceMonitor()
    state = filt.initial_state(np.zeros(4), np.eye(4))
    monitor.start(state)
    checks = []
    while not (checks and checks[-1].diverged) and len(checks) < 40:
        state = filt.predict(state, unstable, np.zeros(2), 0.1)
        checks.append(monitor.observe(state))
    assert checks[-1].diverged and "covariance blow-up" in checks[-1].reason
    assert len(checks) == 7  # 9^7 ≈ 4.8e6 > 1e6 (9^6 ≈ 5.3e5 is not)
    assert np.isfinite(np.asarray(state.covariance)).all()


def test_absolute_variance_bound():
    monitor = DivergenceMonitor(DivergenceConfig(max_variance=4.0, max_variance_growth=None))
    monitor.start(GaussianState(x=np.zeros(2), P=np.eye(2)))
    assert not monitor.observe(GaussianState(x=np.zeros(2), P=np.diag([1.0, 3.9]))).diverged
    check = monitor.observe(GaussianState(x=np.zeros(2), P=np.diag([1.0, 4.1])))
    assert check.diverged and "max_variance" in check.reason


def test_gate_lock_out_is_recovered():
    """The true position jumps by 25 (≈ 100σ of the measurement): the gated filter rejects every
    measurement from then on and is lost for ever; the monitor re-initialises it (the re-opened
    initial covariance, P0 = 100 I, lets the gate pass the new position) and it tracks again."""
    model = LinearModel(
        F=np.array([[1.0, 0.1], [0.0, 1.0]]),
        B=np.zeros((2, 1)),
        H=np.array([[1.0, 0.0]]),
        Lq=np.diag([0.01, 0.05]),
        Lr=np.array([[0.2]]),
    )
    rng = np.random.default_rng(17)
    x, xs, zs = np.zeros(2), [], []
    for k in range(150):
        x = model.f(x, np.zeros(1), 0.1) + model.Lq @ rng.standard_normal(2)
        if k == 50:
            x = x + np.array([25.0, 0.0])  # kidnapped
        xs.append(x)
        zs.append(model.h(x, None) + model.Lr @ rng.standard_normal(1))
    gate = float(chi2.ppf(0.9999, df=1))

    def final_error(monitor: DivergenceMonitor | None) -> float:
        filt = UnscentedKalmanFilter(gate_threshold=gate)
        state = filt.initial_state(np.zeros(2), 100.0 * np.eye(2))
        if monitor is not None:
            monitor.start(state)
        for k in range(150):
            if monitor is None:
                state = filt.predict(state, model, np.zeros(1), 0.1)
                state, _ = filt.update(state, zs[k], model)
            else:
                state, _, _ = guarded_step(filt, monitor, state, model, np.zeros(1), 0.1, zs[k])
        return float(abs(state.x[0] - xs[-1][0]))

    monitor = DivergenceMonitor(DivergenceConfig(max_rejections=5))
    assert final_error(None) > 20.0, "locked out: the gate rejects the new position for ever"
    assert final_error(monitor) < 1.0
    assert monitor.divergences == 1
    assert monitor.fault is None


# -- recovery ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(FILTERS))
def test_recovery_from_the_last_good_estimate_then_ok(name):
    """An accepted 1e4 measurement wrecks the (ungated) filter: it restarts from the last good
    estimate (finite, near the truth), reports the fault, and clears it once consistent again."""
    model = stable_model()
    truth = Truth(model, seed=13, steps=160)
    zs = truth.zs.copy()
    zs[60] = 1e4
    monitor = DivergenceMonitor()
    filt = FILTERS[name]()
    means, checks = run(filt, model, truth, zs=zs, monitor=monitor)
    div = [i for i, c in enumerate(checks) if c.diverged]
    assert len(div) == 1
    k = div[0]
    assert 60 < k <= 60 + 20, "detected within a window of the fault"
    assert np.isfinite(means).all()
    # The recovered mean is the last good one: a mean of the run before the bad update, near the
    # truth then.
    assert any(np.array_equal(means[k], means[j]) for j in range(40, 60))
    assert np.abs(means[k] - truth.xs[50:60]).min(axis=0).max() < 1.0
    assert np.abs(means[k]).max() < 10.0
    assert np.abs(means[59] - truth.xs[59]).max() < 1.0
    # Fault reported from the divergence until a full window is back in band, then cleared.
    cleared = next(i for i in range(k + 1, len(checks)) if checks[i].good)
    assert cleared >= k + 20
    assert monitor.fault is None
    assert np.abs(means[-20:] - truth.xs[-20:]).max() < 1.0


def test_fault_is_held_until_consistent_again():
    model = stable_model()
    truth = Truth(model, seed=13, steps=120)
    zs = truth.zs.copy()
    zs[60] = 1e4
    monitor = DivergenceMonitor()
    filt = UnscentedKalmanFilter()
    state = filt.initial_state(np.zeros(4), np.eye(4))
    monitor.start(state)
    faults = []
    for k in range(truth.steps):
        state, _, _ = guarded_step(filt, monitor, state, model, truth.us[k], truth.dt, zs[k])
        faults.append(monitor.fault)
    first = next(i for i, f in enumerate(faults) if f)
    last = max(i for i, f in enumerate(faults) if f)
    assert all(faults[first : last + 1]), "ERROR held without a gap"
    assert faults[-1] is None and last < truth.steps - 1, "then OK"
    assert "above its chi-square band" in faults[first]


def test_reinit_covariance_last_good():
    monitor = DivergenceMonitor(DivergenceConfig(reinit_covariance="last_good", window=1, persistence=1))
    filt = UnscentedKalmanFilter()
    start = filt.initial_state(np.zeros(1), np.eye(1))
    monitor.start(start)
    good = GaussianState(x=np.array([2.0]), P=np.array([[0.25]]))
    info = UpdateInfo(innovation=np.zeros(1), innovation_cov=np.eye(1), nis=1.0)
    assert monitor.observe(good, info).good
    assert monitor.observe(GaussianState(x=np.array([np.nan]), P=np.eye(1)), info).diverged
    again = monitor.recover(filt)
    np.testing.assert_array_equal(again.x, [2.0])
    np.testing.assert_array_equal(again.P, [[0.25]])


@dataclasses.dataclass(frozen=True)
class Faulty(LinearModel):
    """``f`` returns NaN once the first state exceeds ``limit`` (a broken model)."""

    limit: float = 5.0

    def f(self, x, u, dt):
        out = super().f(x, u, dt)
        return np.where(np.abs(x[..., :1]) > self.limit, np.nan, out)


@pytest.mark.parametrize("name", list(FILTERS))
def test_filter_exception_and_non_finite_inputs_never_escape(name):
    model = stable_model()
    faulty = Faulty(**{f.name: getattr(model, f.name) for f in dataclasses.fields(model)})
    filt = FILTERS[name]()
    monitor = DivergenceMonitor()
    state = filt.initial_state(np.zeros(4), 0.01 * np.eye(4))
    monitor.start(state)
    # The model raises inside the filter (check_points: non-finite model output).
    bad = filt.initial_state(np.array([6.0, 0, 0, 0]), 0.01 * np.eye(4))
    with pytest.raises(ValueError, match="not finite|non-finite"):
        filt.predict(bad, faulty, np.zeros(2), 0.1)
    state, info, check = guarded_step(filt, monitor, bad, faulty, np.zeros(2), 0.1, np.zeros(2))
    assert check.diverged and "filter step failed" in check.reason and info is None
    np.testing.assert_array_equal(state.x, np.zeros(4))
    # A non-finite or wrongly sized measurement is skipped (predict-only), not a fault.
    for z in ([np.nan, 0.0], [np.inf, 1.0], [0.0, 0.0, 0.0]):
        state, info, check = guarded_step(filt, monitor, state, model, np.zeros(2), 0.1, z)
        assert info is None and not check.diverged
        assert np.isfinite(state.x).all()


def test_sqrt_factor_fault_names_the_problem():
    assert sqrt_factor_fault(np.array([[1.0, 0.0], [0.5, 2.0]])) == ""
    assert "lower-triangular" in sqrt_factor_fault(np.array([[1.0, 1e-300], [0.5, 2.0]]))
    assert "negative diagonal" in sqrt_factor_fault(np.array([[1.0, 0.0], [0.5, -2.0]]))
    assert "non-finite" in sqrt_factor_fault(np.array([[np.nan, 0.0], [0.5, 2.0]]))
    assert "square" in sqrt_factor_fault(np.ones((2, 3)))
    monitor = DivergenceMonitor()
    monitor.start(SqrtGaussianState(x=np.zeros(2), S=np.eye(2)))
    check = monitor.observe(SqrtGaussianState(x=np.zeros(2), S=np.array([[1.0, 0.1], [0.0, 1.0]])))
    assert check.diverged and "lower-triangular" in check.reason


def test_nis_band_matches_chi_square():
    lo, hi = nis_band(40, 20, 0.99)
    assert lo == pytest.approx(chi2.ppf(0.005, 40) / 20)
    assert hi == pytest.approx(chi2.ppf(0.995, 40) / 20)
    assert lo < 2.0 < hi


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"window": 0}, "window"),
        ({"window": 2.5}, "window"),
        ({"persistence": True}, "persistence"),
        ({"probability": 1.0}, "probability"),
        ({"probability": float("nan")}, "probability"),
        ({"max_rejections": 0}, "max_rejections"),
        ({"max_variance_growth": 1.0}, "max_variance_growth"),
        ({"max_variance": -1.0}, "max_variance"),
        ({"reinit_covariance": "zero"}, "reinit_covariance"),
    ],
)
def test_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DivergenceConfig(**kwargs)


def test_monitor_needs_a_start_and_a_sound_start_state():
    monitor = DivergenceMonitor()
    with pytest.raises(RuntimeError, match="start"):
        monitor.observe(GaussianState(x=np.zeros(1), P=np.eye(1)))
    with pytest.raises(RuntimeError, match="start"):
        monitor.recover(UnscentedKalmanFilter())
    with pytest.raises(ValueError, match="faulty state"):
        monitor.start(GaussianState(x=np.array([np.nan]), P=np.eye(1)))
