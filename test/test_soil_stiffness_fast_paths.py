"""The soil-stiffness estimator's fast paths give the numbers of the plain forms.

The per-step cost of the quarter-car / LRV estimator was cut by calling
LAPACK directly (``tria``, the ``R_eff`` Cholesky), running the two Taylor
series of ``discretise`` as one stacked recursion, converting only the
profile samples a step reads, and computing the median spacing on the list.
Each of those is meant to reproduce the former computation bit for bit; these
tests hold them to it (``np.array_equal``, not a tolerance) against the
straightforward forms they replaced.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from terrain_estimation.estimators.soil_stiffness import (
    SoilStiffnessEstimator,
    SoilStiffnessEstimatorConfig,
    _fit_weights,
    _local_quadratic,
)
from terrain_estimation.filters.sigma_points import tria
from terrain_estimation.models.quarter_car import (
    LRVModel,
    LRVParams,
    QuarterCarModel,
    QuarterCarParams,
    _clip,
    discretise,
)

RNG_SEED = 20261126


def _tria_reference(A: np.ndarray) -> np.ndarray:  # noqa: N803
    n, k = A.shape
    if k < n:
        A = np.hstack([A, np.zeros((n, n - k))])
    S = np.linalg.qr(A.T, mode="r").T
    return S * np.where(np.diagonal(S) < 0.0, -1.0, 1.0)


def _discretise_reference(a: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    eye = np.eye(a.shape[-1])
    ad = a * delta
    phi = eye + ad / 4.0
    phi = eye + ad @ phi / 3.0
    phi = eye + ad @ phi / 2.0
    phi = eye + ad @ phi
    gam = eye + ad / 5.0
    gam = eye + ad @ gam / 4.0
    gam = eye + ad @ gam / 3.0
    gam = eye + ad @ gam / 2.0
    return phi, gam * delta


@pytest.mark.parametrize("shape", [(5, 15), (5, 12), (2, 12), (2, 7), (5, 3), (3, 3), (1, 1), (40, 83), (150, 303)])
def test_tria_is_the_numpy_qr_factor(shape: tuple[int, int]) -> None:
    """Same factor as qr(Aᵀ)ᵀ with flipped columns; lower, diagonal >= 0, zeros above."""
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(50):
        A = rng.standard_normal(shape) * 10.0 ** rng.uniform(-4, 4, size=shape[1])  # noqa: N806
        S = tria(A)  # noqa: N806
        assert S.dtype == np.float64 and S.shape == (shape[0], shape[0])
        if shape[0] <= 40:
            assert np.array_equal(S, _tria_reference(A))
        else:  # a threaded BLAS may split a large QR differently from run to run: last bits only
            np.testing.assert_allclose(S, _tria_reference(A), rtol=1e-10, atol=1e-10 * np.abs(S).max())
        assert np.all(S[np.triu_indices(shape[0], 1)] == 0.0)
        assert np.all(np.diagonal(S) >= 0.0)
        np.testing.assert_allclose(S @ S.T, A @ A.T, rtol=1e-9, atol=1e-12 * np.abs(A @ A.T).max())


def test_tria_accepts_integer_input_and_does_not_alias_it() -> None:
    A = np.array([[1, 2], [3, 4]])  # noqa: N806
    S = tria(A)  # noqa: N806
    assert np.array_equal(S, _tria_reference(A.astype(float)))
    S[0, 0] = 99.0
    assert np.array_equal(A, [[1, 2], [3, 4]])


@pytest.mark.parametrize("vehicle", ["quarter_car", "lrv"])
def test_stacked_taylor_series_equals_two_horner_recursions(vehicle: str) -> None:
    model = QuarterCarModel() if vehicle == "quarter_car" else LRVModel(LRVParams(relative_damper=True))
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(200):
        k = rng.uniform(1e2, 1.75e5, size=int(rng.integers(1, 12)))
        a = model._a0 + k[:, None, None] * model._e
        delta = float(10.0 ** rng.uniform(-4.0, -1.5))
        for batch in (a, a[0]):
            phi, gam = discretise(batch, delta, "taylor4")
            phi_ref, gam_ref = _discretise_reference(batch, delta)
            assert phi.shape == phi_ref.shape and gam.shape == gam_ref.shape
            assert np.array_equal(phi, phi_ref) and np.array_equal(gam, gam_ref)


@pytest.mark.parametrize("state", ["k_tot", "log_k_s"])
def test_model_f_equals_the_sub_step_loop(state: str) -> None:
    """f of a point set is the plain sub-step loop x ← Φ x + Γb u_j, k_tot passed through."""
    model = QuarterCarModel(QuarterCarParams(stiffness_state=state))
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(50):
        x = rng.standard_normal(5) * 0.01
        x[-1] = rng.uniform(1e4, 1.7e5) if state == "k_tot" else rng.uniform(-3.0, 3.0)
        pts = x + rng.standard_normal((10, 5)) * 0.01
        u = rng.standard_normal(int(rng.integers(1, 14))) * 0.05
        dt = 0.01
        phi, gam = _discretise_reference(model.A(pts), dt / u.size)
        gb = gam @ model.B
        y = pts.copy()
        for uj in u:
            y = (phi @ y[:, :, None])[:, :, 0] + gb * uj
        y[:, -1] = pts[:, -1]
        assert np.array_equal(model.f(pts, u, dt), y)
        assert np.array_equal(model.f(pts[0], u, dt), y[0])


def test_clip_equals_np_clip_nan_and_signed_zero_included() -> None:
    v = np.array([-np.inf, -5.0, -0.0, 0.0, 0.5, 3.0, np.inf, np.nan])
    out = _clip(v, -1.0, 2.0)
    assert np.array_equal(out, np.clip(v, -1.0, 2.0), equal_nan=True)
    assert np.array_equal(np.signbit(out), np.signbit(np.clip(v, -1.0, 2.0)))
    assert float(_clip(7.0, 0.0, 1.0)) == 1.0


def _filled_estimator(config: SoilStiffnessEstimatorConfig, n: int, seed: int) -> SoilStiffnessEstimator:
    """An estimator whose profile buffer holds ``n`` jittered, gappy samples (no steps run)."""
    rng = np.random.default_rng(seed)
    est = SoilStiffnessEstimator(config)
    t = 0.0
    for _ in range(n):
        t += 1e-3 * rng.uniform(0.5, 1.5) + (0.004 if rng.random() < 0.05 else 0.0)
        est.add_profile_sample(t, 2.0 * t, 0.01 * math.sin(30.0 * t) + 1e-4 * rng.standard_normal())
    return est


def _on_grid_reference(est: SoilStiffnessEstimator, grid: np.ndarray) -> tuple[np.ndarray, float]:
    """``_profile_on_grid`` on the whole buffer, as it was written before the window."""
    pt, ph = np.asarray(est._pt), np.asarray(est._ph)
    w = est._smooth_half_w
    hg = _local_quadratic(pt, ph, grid, w) if w > 0.0 else np.interp(grid, pt, ph)
    beyond = grid > pt[-1]
    if np.any(beyond):
        slope = (ph[-1] - ph[-2]) / (pt[-1] - pt[-2]) if pt.size >= 2 else 0.0
        hg = np.where(beyond, ph[-1] + slope * (grid - pt[-1]), hg)
    i0 = max(int(np.searchsorted(pt, grid[0], side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(pt, grid[-1], side="left")), pt.size - 1)
    gaps = np.diff(pt[i0 : i1 + 1])
    max_gap = float(gaps.max()) if gaps.size else 0.0
    if grid[-1] > pt[-1]:
        max_gap = max(max_gap, float(grid[-1] - pt[-1]))
    return hg, max_gap


@pytest.mark.parametrize("smoothing", [0.0, 0.01])
def test_profile_window_gives_the_whole_buffer_reconstruction(smoothing: float) -> None:
    est = _filled_estimator(SoilStiffnessEstimatorConfig(profile_smoothing_s=smoothing), 300, RNG_SEED)
    pt = np.asarray(est._pt)
    rng = np.random.default_rng(RNG_SEED + 1)
    starts = [float(pt[0]) - 5e-10, float(pt[0]), float(pt[17]), float(pt[-1]) - 0.012, float(pt[-1]) - 0.004]
    starts += list(rng.uniform(pt[0], pt[-1] - 0.01, size=40))
    for t0 in starts:
        for n_sub, dt in ((10, 0.01), (8, 0.0107), (1, 0.01), (13, 0.0173)):
            grid = t0 + dt * np.arange(n_sub + 1) / n_sub
            hg, gap = est._profile_on_grid(grid)
            hg_ref, gap_ref = _on_grid_reference(est, grid)
            assert np.array_equal(hg, hg_ref) and gap == gap_ref


@pytest.mark.parametrize("count", [0, 1, 2, 3, 10, 11, 64, 257])
def test_profile_spacing_is_numpys_median(count: int) -> None:
    est = _filled_estimator(SoilStiffnessEstimatorConfig(), count, RNG_SEED + count)
    expected = float(np.median(np.diff(np.asarray(est._pt)))) if count >= 2 else 0.0
    assert est._profile_spacing() == expected


def _road_reference(est: SoilStiffnessEstimator, t: float, half: float) -> tuple[Any, ...]:
    """The interpolation / fit weights of ``_road_at_measurement`` on the whole buffer."""
    pt = np.asarray(est._pt)
    if t > pt[-1]:
        return ("extrapolate",)
    i = int(np.searchsorted(pt, t, side="right"))
    a = (t - pt[i - 1]) / (pt[i] - pt[i - 1]) if 0 < i < pt.size else None
    fit = None
    for degree in (5, 3, 1):
        fit = _fit_weights(pt, t, half, degree) if half > 0.0 else None
        if fit is not None:
            break
    hdot = None if fit is None else float(fit[2] @ np.asarray(est._ph)[fit[0] : fit[0] + fit[2].size])
    return a, hdot


def test_road_at_measurement_reads_the_same_samples_as_the_whole_buffer() -> None:
    """LRV with the ḣ fit: ḣ(t) and Σ_ε as the fits over the whole buffer give them."""
    cfg = SoilStiffnessEstimatorConfig(vehicle="lrv", lrv=LRVParams(relative_damper=True))
    est = _filled_estimator(cfg, 400, RNG_SEED + 2)
    pt = np.asarray(est._pt)
    rng = np.random.default_rng(RNG_SEED + 3)
    u_sub = rng.standard_normal(10)
    checked = 0
    for t in [*rng.uniform(pt[0] + 0.05, pt[-1] - 0.05, size=60), float(pt[200]), float(pt[-1]) + 1e-3]:
        hdot, sigma = est._road_at_measurement(float(t), u_sub, 1e-3)
        half = est._hdot_half_window(float(t))
        ref = _road_reference(est, float(t), half)
        if ref[0] == "extrapolate":
            assert sigma.shape == (2, 2)
            continue
        a, hdot_ref = ref
        assert hdot == hdot_ref
        var = est.config.profile_noise_std**2
        if a is not None:
            w_h = np.array([1.0 - a, a])
            assert sigma[0, 0] == var * float(w_h @ w_h)
        checked += 1
    assert checked > 50


def test_measurement_noise_factor_is_the_cholesky_factor_and_raises_on_indefinite() -> None:
    est = SoilStiffnessEstimator(SoilStiffnessEstimatorConfig())
    x = np.array([0.001, 0.01, 0.002, 0.03, 80e3])
    rng = np.random.default_rng(RNG_SEED + 4)
    for rows in (2, 1, 2):
        for _ in range(20):
            b = rng.standard_normal((2, 2)) * 1e-4
            sigma = b @ b.T
            g_h, g_d = est.model.profile_error_gains(x)
            gain = np.stack([g_h[:rows], g_d[:rows]], axis=1)
            rs = est.model.measurement_noise_sqrt()[:rows, :rows]
            r_eff = rs @ rs.T + gain @ sigma @ gain.T
            expected = np.linalg.cholesky(0.5 * (r_eff + r_eff.T))
            assert np.array_equal(est._measurement_noise_sqrt(x, rows, sigma), expected)
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        est._measurement_noise_sqrt(x, 2, np.array([[-1.0, 0.0], [0.0, 0.0]]))
