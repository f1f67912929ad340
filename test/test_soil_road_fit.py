"""The compiled ḣ fit and the profile road's bookkeeping (``estimators.soil_road``, ``estimators.soil_road_fit``).

* The compiled fit weights agree with the numpy form they replaced (written out
  here as it was: ``np.linalg.solve(VᵀV, Vᵀ)`` on numpy's power table) to
  rounding, choose the same window and degree, and the estimator's estimates
  over the shipped LRV bag with either agree to rounding (1e-11 relative,
  1e-9 of their own σ).
* The median spacing kept from sorted differences as the buffer grows and is
  pruned equals numpy's median of the whole buffer, exactly.
* The window read off the buffer list gives ḣ(t) bit for bit and Σ_ε to rounding against the former
  window-array form, with and without smoothing.
* The adapter's early return for a profile sample that completes no step
  changes nothing a caller sees (outputs and health, message by message).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from terrain_estimation.estimators import soil_road
from terrain_estimation.estimators.soil_road_fit import fit_weights, slope_weights
from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimator, SoilStiffnessEstimatorConfig
from terrain_estimation.models.quarter_car import LRVParams

RNG_SEED = 20261128
LRV_BAG = Path(__file__).resolve().parents[1] / "bags" / "lrv_regolith_iso_g_2ms"


def _fit_weights_numpy(pt: np.ndarray, t: float, half_w: float, degree: int) -> tuple[int, np.ndarray, np.ndarray]:
    """The numpy form the compiled fit replaced (``lo = −1``: no fit)."""
    lo = int(pt.searchsorted(t - half_w, side="left"))
    hi = int(pt.searchsorted(t + half_w, side="right"))
    if hi - lo < degree + 2:
        return -1, np.empty(0), np.empty(0)
    s = (pt[lo:hi] - t) / half_w
    if s[0] > -0.5 or s[-1] < 0.5:
        return -1, np.empty(0), np.empty(0)
    v = s[:, None] ** np.arange(degree + 1, dtype=float)
    rows = np.linalg.solve(v.T @ v, v.T)
    return lo, rows[0], rows[1] / half_w


def _slope_weights_numpy(
    pt: np.ndarray, t: float, half_w: float, max_degree: int, lo_h: int, w_h: np.ndarray
) -> tuple[int, np.ndarray, float, float]:
    """The estimator's degree loop and noise terms as they were written with the numpy fit."""
    for degree in range(max_degree, 0, -2):
        lo, _, w1 = _fit_weights_numpy(pt, t, half_w, degree)
        if lo < 0:
            continue
        a, b = max(lo_h, lo), min(lo_h + w_h.size, lo + w1.size)
        cross = float(w_h[a - lo_h : b - lo_h] @ w1[a - lo : b - lo]) if b > a else 0.0
        return lo, w1, float(w1 @ w1), cross
    return -1, np.empty(0), 0.0, 0.0


def _stamps(rng: np.random.Generator, n: int) -> np.ndarray:
    """Jittered ≈ 1 kHz stamps with a few dropped samples, starting far from 0 (as a bag's do)."""
    steps = 1e-3 * rng.uniform(0.7, 1.3, n) + np.where(rng.random(n) < 0.03, 3e-3, 0.0)
    return 1.7e3 + np.cumsum(steps)


def _scale(a: np.ndarray) -> float:
    return float(np.max(np.abs(a))) if a.size else 1.0


@pytest.mark.parametrize("degree", [1, 2, 3, 5])
def test_fit_weights_agree_with_the_numpy_form_to_rounding(degree: int) -> None:
    rng = np.random.default_rng(RNG_SEED + degree)
    pt = _stamps(rng, 400)
    fits = 0
    for _ in range(300):
        t = float(rng.uniform(pt[0] - 0.01, pt[-1] + 0.01))
        half = float(rng.choice([0.002, 0.005, 0.015, 0.03, 0.05]))
        lo, w0, w1 = fit_weights(pt, t, half, degree)
        lo_ref, w0_ref, w1_ref = _fit_weights_numpy(pt, t, half, degree)
        assert lo == lo_ref  # the same window, and the same "no fit" decisions
        assert w0.size == w0_ref.size and w1.size == w1_ref.size
        if lo < 0:
            continue
        fits += 1
        assert np.max(np.abs(w0 - w0_ref)) <= 1e-12 * _scale(w0_ref)
        assert np.max(np.abs(w1 - w1_ref)) <= 1e-12 * _scale(w1_ref)
    assert fits > 100


def test_slope_weights_take_the_same_degree_and_noise_terms() -> None:
    rng = np.random.default_rng(RNG_SEED + 10)
    pt = _stamps(rng, 400)
    lowered = 0
    for _ in range(400):
        t = float(rng.uniform(pt[0], pt[-1]))
        half = float(rng.choice([0.002, 0.003, 0.004, 0.015, 0.03]))
        i = int(pt.searchsorted(t, side="right"))
        lo_h = int(rng.integers(0, pt.size - 2)) if rng.random() < 0.2 else max(i - 1, 0)
        w_h = rng.standard_normal(int(rng.integers(1, 4)))
        got = slope_weights(pt, t, half, 5, lo_h, w_h)
        ref = _slope_weights_numpy(pt, t, half, 5, lo_h, w_h)
        assert got[0] == ref[0] and got[1].size == ref[1].size
        if ref[0] < 0:
            continue
        lowered += ref[1].size < 7  # fewer than 7 samples: a lower degree than 5
        assert np.max(np.abs(got[1] - ref[1])) <= 1e-12 * _scale(ref[1])
        assert got[2] == pytest.approx(ref[2], rel=1e-12)
        assert got[3] == pytest.approx(ref[3], rel=1e-11, abs=1e-12 * math.sqrt(ref[2]) * _scale(w_h))
    assert lowered > 0


def _run_bag(monkeypatch: pytest.MonkeyPatch | None) -> np.ndarray:
    from terrain_estimation.tools.estimate import estimate_bag

    if monkeypatch is not None:
        monkeypatch.setattr(soil_road, "fit_weights", _fit_weights_numpy)
        monkeypatch.setattr(soil_road, "slope_weights", _slope_weights_numpy)
    run = estimate_bag(LRV_BAG, "lrv")
    return np.array([[m.k_s, m.k_s_variance, m.k_tot, m.k_tot_variance, m.nis] for _, m, _ in run.outputs])


@pytest.mark.skipif(not LRV_BAG.is_dir(), reason="the shipped LRV bag is not in this checkout")
def test_lrv_bag_estimates_agree_with_the_numpy_fit_to_rounding(monkeypatch: pytest.MonkeyPatch) -> None:
    compiled = _run_bag(None)
    with monkeypatch.context() as m:
        reference = _run_bag(m)
    assert compiled.shape == reference.shape and compiled.shape[0] > 300
    # k_s, k_tot: within 1e-9 of their own σ and 1e-11 relative; the variances 1e-11 relative.
    for col, var_col in ((0, 1), (2, 3)):
        diff = np.abs(compiled[:, col] - reference[:, col])
        assert np.all(diff <= 1e-9 * np.sqrt(reference[:, var_col]))
        assert np.all(diff <= 1e-11 * np.abs(reference[:, col]))
        assert np.allclose(compiled[:, var_col], reference[:, var_col], rtol=1e-11, atol=0.0)
    assert np.allclose(compiled[:, 4], reference[:, 4], rtol=1e-6, atol=1e-9)


def _road_former(est: SoilStiffnessEstimator, t: float) -> tuple[float | None, np.ndarray | None]:
    """``_road_at_measurement`` as it was written on the window's arrays (the fits as now), for the fit case."""
    half = est._hdot_half_window(t)
    w = est._smooth_half_w
    reach = max(w, half)
    lo = max(int(np.searchsorted(est._pt, t - reach, side="left")) - 2, 0)
    hi = int(np.searchsorted(est._pt, t + reach, side="right")) + 2
    pt, ph = np.array(est._pt[lo:hi]), np.array(est._ph[lo:hi])
    var = est.config.profile_noise_std**2
    if t > pt[-1]:
        beta = (t - pt[-1]) / (pt[-1] - pt[-2])
        lo_h, w_h = pt.size - 2, np.array([-beta, 1.0 + beta])
    else:
        fit = soil_road._fit_weights(pt, t, w, 2) if w > 0.0 else None
        if fit is not None:
            lo_h, w_h = fit[0], fit[1]
        else:
            i = int(pt.searchsorted(t, side="right"))
            if i >= pt.size or i == 0:
                lo_h, w_h = min(max(i - 1, 0), pt.size - 1), np.ones(1)
            else:
                a = (t - pt[i - 1]) / (pt[i] - pt[i - 1])
                lo_h, w_h = i - 1, np.array([1.0 - a, a])
    var_h = var * float(w_h @ w_h)
    for degree in (5, 3, 1):
        fit = soil_road._fit_weights(pt, t, half, degree) if half > 0.0 else None
        if fit is not None:
            lo_d, _, w_d = fit
            a, b = max(lo_h, lo_d), min(lo_h + w_h.size, lo_d + w_d.size)
            cov = var * float(w_h[a - lo_h : b - lo_h] @ w_d[a - lo_d : b - lo_d]) if b > a else 0.0
            hdot = float(w_d @ ph[lo_d : lo_d + w_d.size])
            return hdot, np.array([[var_h, cov], [cov, var * float(w_d @ w_d)]])
    return None, None


@pytest.mark.parametrize("smoothing", [0.0, 0.004, 0.01])
def test_road_at_measurement_reads_the_window_off_the_list_as_the_window_arrays_did(smoothing: float) -> None:
    """ḣ(t) bit for bit and Σ_ε to rounding, with and without smoothing, also past the last sample."""
    cfg = SoilStiffnessEstimatorConfig(
        vehicle="lrv", lrv=LRVParams(relative_damper=True), profile_smoothing_s=smoothing, profile_noise_std=2e-4
    )
    rng = np.random.default_rng(RNG_SEED + 40)
    est = SoilStiffnessEstimator(cfg)
    for t in _stamps(rng, 500) - 1.7e3:
        est.add_profile_sample(float(t), 2.0 * float(t), 0.01 * math.sin(25.0 * t) + 2e-4 * rng.standard_normal())
    pt = np.asarray(est._pt)
    times = [*rng.uniform(pt[0] + 0.06, pt[-1] - 0.06, 80), float(pt[250]), float(pt[-1]) + 3e-4]
    fitted = 0
    for t in map(float, times):
        hdot, sigma = est._road_at_measurement(t, np.zeros(10), 1e-3)
        hdot_ref, sigma_ref = _road_former(est, t)
        assert hdot == hdot_ref
        if sigma_ref is not None:
            fitted += 1
            assert sigma[0, 0] == sigma_ref[0, 0]
            np.testing.assert_allclose(
                sigma, sigma_ref, rtol=1e-12, atol=1e-12 * math.sqrt(sigma_ref[0, 0] * sigma_ref[1, 1])
            )
    assert fitted > 70


def test_median_spacing_kept_sorted_equals_numpys_median_through_prunes_and_reset() -> None:
    cfg = SoilStiffnessEstimatorConfig(vehicle="lrv", lrv=LRVParams(relative_damper=True))
    est = SoilStiffnessEstimator(cfg)
    rng = np.random.default_rng(RNG_SEED + 20)
    checked = pruned = 0
    for _ in range(2):
        t, first = 0.0, len(est._pt)
        for k in range(3000):
            t += 1e-3 * rng.uniform(0.6, 1.4) + (0.004 if rng.random() < 0.02 else 0.0)
            est.add_profile_sample(t, 2.0 * t, 0.01 * math.sin(20.0 * t) + 1e-4 * rng.standard_normal())
            if k % 10 == 5:
                est.add_accelerations(t - 0.02, float(rng.normal(0.0, 0.5)))
            if k % 7 == 0:
                pt = np.asarray(est._pt)
                expected = float(np.median(np.diff(pt))) if pt.size >= 2 else 0.0
                assert est._profile_spacing() == expected
                checked += 1
            pruned += len(est._pt) < first
            first = len(est._pt)
        assert est.counters.steps > 100
        est.reset()
        assert est._profile_spacing() == 0.0
    assert checked > 500 and pruned > 20


def _adapter() -> Any:
    from terrain_estimation.tools.estimate import config_values
    from terrain_estimation.vehicles import get_vehicle

    entry = get_vehicle("lrv")
    return entry.make_adapter(config_values(entry), entry.namespace)


def _health(adapter: Any) -> tuple[Any, ...]:
    h = adapter.health
    return (h.updates, h.status, list(h.warnings), list(h.errors), dict(h.values), list(h.nis))


def test_adapter_early_return_for_a_stepless_profile_sample_changes_nothing() -> None:
    """Every message's outputs and the adapter's health after it, against the former form of the handler."""
    new, old = _adapter(), _adapter()

    def former(stamp_ns: int, values: Any) -> list[tuple[str, Any]]:
        old.estimator.add_profile_sample(stamp_ns * 1e-9, values[0], values[1])
        return old._outputs()

    old.handle_profile = former
    rng = np.random.default_rng(RNG_SEED + 30)
    published = 0
    for k in range(2500):
        t_ns = 1_000_000 * (k + 1)
        h = 0.01 * math.sin(12.0 * k * 1e-3) + 1e-4 * rng.standard_normal()
        if rng.random() < 0.01:
            h = math.nan  # rejected by the estimator: no step
        pairs = [(a, a.handle_profile(t_ns, (2e-3 * k, h))) for a in (new, old)]
        if k % 10 == 3:
            z = 9.81 + float(rng.normal(0.0, 0.5))
            pairs += [(a, a.handle_body(t_ns - 20_000_000, (z,))) for a in (new, old)]
        for (_, out_new), (_, out_old) in zip(pairs[0::2], pairs[1::2], strict=True):
            assert [(k_, m.k_s, m.nis, m.header.stamp.nanosec) for k_, m in out_new] == [
                (k_, m.k_s, m.nis, m.header.stamp.nanosec) for k_, m in out_old
            ]
            published += len(out_new)
        assert _health(new) == _health(old)
    assert published > 200
