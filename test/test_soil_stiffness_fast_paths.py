"""The soil-stiffness estimator's fast paths give the numbers of the plain forms.

The per-step cost of the quarter-car / LRV estimator was cut by calling
LAPACK directly (``tria``, the ``R_eff`` Cholesky), running the two Taylor
series of ``discretise`` as one stacked recursion, converting only the
profile samples a step reads, and computing the median spacing on the list;
then by the no-fit road weights and the gap search read off the buffer
list, the ḣ-window and waiting-step caches and the adapter's pairing
early-out. Each of those is meant to reproduce the former computation bit
for bit; these tests hold them to it (``np.array_equal`` or exact equality,
not a tolerance) against the straightforward forms they replaced, written
out here (the SCKF as first written included).

The exception is the estimator's SCKF step itself, since compiled
(``estimators.soil_stiffness_sckf``, its own tests in
``test_soil_stiffness_sckf.py``): the stream comparison with the SCKF as
first written holds it to rounding.
"""

from __future__ import annotations

import bisect
import contextlib
import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from terrain_estimation.estimators.soil_road import _fit_weights, _grid_offsets, _local_quadratic
from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimator, SoilStiffnessEstimatorConfig
from terrain_estimation.filters.base import SqrtGaussianState, UpdateInfo
from terrain_estimation.filters.sckf import SquareRootCubatureKalmanFilter
from terrain_estimation.filters.sigma_points import _tria_rows, solve_lower, tria
from terrain_estimation.models.quarter_car import (
    LRVModel,
    LRVParams,
    QuarterCarModel,
    QuarterCarParams,
    StepInput,
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


def test_large_batches_use_broadcast_operands_with_the_same_result() -> None:
    """Above the materialising limit the Horner operands are broadcast views: the same series."""
    model = QuarterCarModel()
    rng = np.random.default_rng(RNG_SEED + 5)
    a = model._a0 + rng.uniform(1e2, 1.75e5, size=2000)[:, None, None] * model._e
    phi, gam = discretise(a, 1e-3, "taylor4")
    phi_ref, gam_ref = _discretise_reference(a, 1e-3)
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


# ---------------------------------------------------------------------------
# The SCKF's unchecked entries, the fused discretisation and the per-step
# shortcuts of the estimator and its adapter (all bit for bit).
# ---------------------------------------------------------------------------


def _noise_reference(model: Any, x: np.ndarray, dt: float) -> np.ndarray:
    """``process_noise_sqrt`` as first written: its own discretisation at the mean's k_tot."""
    k_c = float(model.ktot_of(float(x[-1])))
    _, gam = _discretise_reference(model._a0 + k_c * model._e, dt)
    lq = math.sqrt(dt) * (gam @ model._g) * model._sigma_q
    lq[:, -1] = 0.0
    if model.stiffness_state == "log_k_s":
        lq[-1, -1] = np.sqrt(model._q_log_ks_per_step * dt / model._ktot_step_dt)
    elif model._noise_form == "per_step":
        lq[-1, -1] = np.sqrt(model._q_ktot_per_step * dt / model._ktot_step_dt)
    else:
        lq[-1, -1] = np.sqrt(dt) * dt * model._sigma_q[-1]
    return lq


def _f_reference(model: Any, pts: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    phi, gam = _discretise_reference(model.A(pts), dt / u.size)
    gb = gam @ model.B
    y = pts.copy()
    for uj in u:
        y = (phi @ y[:, :, None])[:, :, 0] + gb * uj
    y[:, -1] = pts[:, -1]
    return y


def _models() -> list[Any]:
    return [
        QuarterCarModel(QuarterCarParams(stiffness_state="k_tot")),
        QuarterCarModel(QuarterCarParams(stiffness_state="log_k_s")),
        QuarterCarModel(QuarterCarParams(ktot_noise_form="printed")),
        LRVModel(LRVParams(relative_damper=True, stiffness_state="log_k_s")),
        LRVModel(LRVParams(relative_damper=False, stiffness_state="k_tot")),
    ]


def _random_point_set(model: Any, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    n = model.state_dim
    x = rng.standard_normal(n) * 0.01
    x[-1] = rng.uniform(1e3, 1.7e5) if model.stiffness_state == "k_tot" else rng.uniform(-5.0, 5.0)
    spread = np.full(n, 0.01)
    spread[-1] = 3e4 if model.stiffness_state == "k_tot" else 0.5
    return x, x + rng.standard_normal((2 * n, n)) * spread


@pytest.mark.parametrize("index", range(5))
def test_f_and_the_process_noise_factor_are_the_plain_forms(index: int) -> None:
    """``f`` (stacked series, sub-step loop) and ``√Q_k`` (with its cache) against the forms written out, bit for bit.

    Step lengths repeat (noise-cache hits) and change.
    """
    model = _models()[index]
    rng = np.random.default_rng(RNG_SEED + 10 + index)
    dts = [0.010000000000000009, 0.009999999999999787, 0.0107, 0.003]
    for i in range(120):
        x, pts = _random_point_set(model, rng)
        if i % 7 == 3:
            x[-1] = model._noise_cache[1] if model.stiffness_state == "k_tot" and model._noise_cache else x[-1]
        u = rng.standard_normal(int(rng.integers(1, 14))) * 0.05
        dt = dts[i % len(dts)]
        pts_before = pts.copy()
        assert np.array_equal(model.f(pts, u, dt), _f_reference(model, pts, u, dt))
        assert np.array_equal(pts, pts_before)
        lq = model.process_noise_sqrt(x, u, dt)
        assert np.array_equal(lq, _noise_reference(model, x, dt))
        assert np.array_equal(model.process_noise_sqrt(x, u, dt), lq)


class _ReferenceSCKF(SquareRootCubatureKalmanFilter):
    """The SCKF's predict/update as first written (eqs. 14–28, public checks, numpy's QR)."""

    def predict(self, state: Any, model: Any, u: Any, dt: float, *, process_noise_sqrt: Any = None) -> Any:
        n = model.state_dim
        x = np.asarray(state.x, dtype=float)
        S = np.asarray(state.S, dtype=float)  # noqa: N806
        L = np.asarray(model.process_noise_sqrt(x, u, dt), dtype=float)  # noqa: N806
        unit = np.vstack([np.sqrt(n) * np.eye(n), -np.sqrt(n) * np.eye(n)])
        X = x + unit @ S.T  # noqa: N806
        Xs = np.asarray(model.f(X, u, dt), dtype=float)  # noqa: N806
        if not np.isfinite(Xs).all():
            raise ValueError("model.f returned non-finite values")
        x_pred = np.full(2 * n, 1.0 / (2 * n)) @ Xs
        chi = (Xs - x_pred) * (1.0 / math.sqrt(2 * n))
        return SqrtGaussianState(x=x_pred, S=_tria_reference(np.concatenate((chi, L.T)).T))

    def update(self, state: Any, z: Any, model: Any, u: Any = None, *, measurement_noise_sqrt: Any = None) -> Any:
        n, p = model.state_dim, model.measurement_dim
        x = np.asarray(state.x, dtype=float)
        S = np.asarray(state.S, dtype=float)  # noqa: N806
        zv = np.asarray(z, dtype=float)
        Rs = np.asarray(  # noqa: N806
            model.measurement_noise_sqrt() if measurement_noise_sqrt is None else measurement_noise_sqrt, dtype=float
        )
        unit = np.vstack([np.sqrt(n) * np.eye(n), -np.sqrt(n) * np.eye(n)])
        c = 1.0 / math.sqrt(2 * n)
        dX = unit @ S.T  # noqa: N806
        Z = np.asarray(model.h(x + dX, u), dtype=float)  # noqa: N806
        assert Z.shape == (2 * n, p)
        if not np.isfinite(Z).all():
            raise ValueError("model.h returned non-finite values")
        z_hat = np.full(2 * n, 1.0 / (2 * n)) @ Z
        Zc_t = (Z - z_hat) * c  # noqa: N806
        S_z = _tria_reference(np.concatenate((Zc_t, Rs.T)).T)  # noqa: N806
        chi_t = dX * c
        P_xz = chi_t.T @ Zc_t  # noqa: N806
        nu = zv - z_hat
        A = solve_lower(S_z, np.concatenate((P_xz.T, nu[:, None]), axis=1))  # noqa: N806
        nis = float(A[:, n] @ A[:, n])
        if not S_z.diagonal().all():
            nis = float("inf")
        if not (np.isfinite(nis) and (self.gate_threshold is None or nis <= self.gate_threshold)):
            return state, UpdateInfo(innovation=nu, innovation_cov=S_z @ S_z.T, nis=nis, accepted=False)
        W_t = solve_lower(S_z, A[:, :n], transpose=True)  # noqa: N806
        x_post = x + nu @ W_t
        S_post = _tria_reference(np.concatenate((chi_t - Zc_t @ W_t, Rs.T @ W_t)).T)  # noqa: N806
        info = UpdateInfo(innovation=nu, innovation_cov=S_z @ S_z.T, nis=nis, accepted=True)
        return SqrtGaussianState(x=x_post, S=S_post), info


@pytest.mark.parametrize("index", range(5))
@pytest.mark.parametrize("gate", [None, 3.0])
def test_sckf_public_methods_equal_the_reference_filter(index: int, gate: float | None) -> None:
    """SCKF.predict/update (LAPACK tria, one whitening solve) against the SCKF as first written, bit for bit."""
    model = _models()[index]
    filt = SquareRootCubatureKalmanFilter(gate_threshold=gate)
    ref = _ReferenceSCKF(gate_threshold=gate)
    rng = np.random.default_rng(RNG_SEED + 30 + index)
    n, p = model.state_dim, model.measurement_dim
    rejected = accepted = 0
    for _ in range(60):
        x, _ = _random_point_set(model, rng)
        p0 = np.diag(np.abs(rng.standard_normal(n)) * 1e-4)
        p0[-1, -1] = 1e8 if model.stiffness_state == "k_tot" else 0.3
        state = filt.initial_state(x, p0)
        hdot = rng.standard_normal(10) * 0.05
        u = StepInput(hdot, float(rng.standard_normal())) if rng.random() < 0.5 else hdot
        dt = 0.01
        prior = ref.predict(state, type(model)(model.params), u, dt)
        public = filt.predict(state, type(model)(model.params), u, dt)
        assert np.array_equal(public.x, prior.x) and np.array_equal(public.S, prior.S)
        z = rng.standard_normal(p) * 3.0
        rs = None if rng.random() < 0.3 else np.linalg.cholesky(np.diag(rng.uniform(0.3, 1.0, p)))
        ref_post, info = ref.update(prior, z, model, u, measurement_noise_sqrt=rs)
        pub_post, pub_info = filt.update(prior, z, model, u, measurement_noise_sqrt=rs)
        assert pub_info.nis == info.nis and pub_info.accepted == info.accepted
        assert np.array_equal(pub_info.innovation_cov, info.innovation_cov)
        if not info.accepted:
            rejected += 1
            assert pub_post is prior
        else:
            accepted += 1
            assert np.array_equal(pub_post.x, ref_post.x) and np.array_equal(pub_post.S, ref_post.S)
    assert accepted > 0 and (gate is None or rejected > 0)


def _estimate_key(e: Any) -> tuple[Any, ...]:
    """An estimate as exact values (floats by their bits)."""
    out = []
    for v in dataclasses.astuple(e):
        if isinstance(v, tuple):
            out.append(tuple(float(w).hex() for w in v))
        elif isinstance(v, float):
            out.append(v.hex())
        else:
            out.append(v)
    return tuple(out)


def _float_of_key(v: Any) -> float | None:
    """The float an :func:`_estimate_key` entry stands for, None if it is not one."""
    if isinstance(v, str):
        try:
            return float.fromhex(v)
        except ValueError:
            return None
    return None


def _stream_spread(got: Any, want: Any, path: str = "stream") -> float:
    """Largest relative difference of the floats of two :func:`_run_stream` outputs; everything else must be equal.

    Relative to the larger magnitude, at least 1e-9 (state components near zero).
    """
    if isinstance(want, (list, tuple)):
        assert type(got) is type(want) and len(got) == len(want), path
        return max(
            (_stream_spread(g, w, f"{path}[{i}]") for i, (g, w) in enumerate(zip(got, want, strict=True))),
            default=0.0,
        )
    g, w = _float_of_key(got), _float_of_key(want)
    if g is None or w is None:
        assert got == want, path
        return 0.0
    if math.isnan(g) or math.isnan(w):
        assert math.isnan(g) and math.isnan(w), path
        return 0.0
    return abs(g - w) / max(abs(g), abs(w), 1e-9)


def _run_stream(est: SoilStiffnessEstimator, events: list[tuple[Any, ...]]) -> list[Any]:
    """Feed events; the return of every call, the drained estimates, the counters and the state."""
    out: list[Any] = []
    for ev in events:
        if ev[0] == "p":
            r = est.add_profile_sample(*ev[1:])
        else:
            r = est.add_accelerations(*ev[1:])
        out.append(None if r is None else _estimate_key(r))
        drained = est.drain_estimates()
        if drained:
            out.append([_estimate_key(e) for e in drained])
    out.append(est.counters)
    return out


def _stream(
    seed: int, vehicle: str, *, hostile: bool, seconds: float = 3.0, huge: float = 1e300
) -> list[tuple[Any, ...]]:
    """A road at 1 kHz (jittered, with gaps) and accelerometers at 100–500 Hz, merged by stamp.

    The accelerations follow a stiff soil loosely (enough for the filter to
    converge and the change detector to run); ``hostile`` adds huge,
    non-finite and out-of-order samples (``huge``: the huge ones), a long
    IMU gap and a wheel accelerometer that goes missing.
    """
    rng = np.random.default_rng(seed)
    events: list[tuple[Any, ...]] = []
    t = 0.0
    speed = 2.0 if vehicle == "lrv" else 10.0
    while t < seconds + 0.1:
        t += 1e-3 * rng.uniform(0.9, 1.1)
        if hostile and 1.2 < t < 1.26:
            continue  # profile gap: predict-only steps
        h = 0.01 * math.sin(7.0 * t) + 0.003 * math.sin(41.0 * t) + 1e-4 * rng.standard_normal()
        if hostile and rng.random() < 0.002:
            h = float(rng.choice([math.nan, huge, -math.inf]))
        events.append((t, 0, ("p", t, speed * t, h)))
    acc_period = 0.002 if vehicle == "lrv" else 0.01
    ta = 0.0
    count = 0
    while ta < seconds:
        ta += acc_period
        count += 1
        if hostile and 2.0 < ta < 2.7:
            continue  # longer than max_step: a restart
        fb = 9.80665 + 2.0 * math.sin(7.0 * ta + 0.3) + 0.7 * rng.standard_normal()
        fw: float | None = 9.80665 + 20.0 * math.sin(41.0 * ta) + 0.7 * rng.standard_normal()
        if hostile:
            r = rng.random()
            if r < 0.02:
                fw = None
            elif r < 0.03:
                fb = float(rng.choice([math.nan, huge, -huge, math.inf]))
            elif r < 0.035:
                fw = huge
            if count % 97 == 50:
                fb = math.nan
        stamp = ta - (0.02 if hostile and rng.random() < 0.01 else 0.0)  # out of order
        events.append((stamp + 0.003 * rng.random(), 1, ("a", stamp, fb, fw)))
    events.sort(key=lambda e: (e[0], e[1]))
    return [e[2] for e in events]


_STREAM_CONFIGS = [
    ("quarter_car", {}),
    ("quarter_car", {"quarter_car": QuarterCarParams(stiffness_state="log_k_s")}),
    ("quarter_car", {"gate_threshold": 12.0, "profile_noise_std": 0.0}),
    ("lrv", {"lrv": LRVParams(relative_damper=True, stiffness_state="log_k_s")}),
    ("lrv", {"lrv": LRVParams(relative_damper=True), "profile_smoothing_s": 0.006, "hdot_window_m": 0.0}),
    ("quarter_car", {"profile_smoothing_s": 0.006, "change_threshold": 3.0}),
]


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("hostile", [False, True])
@pytest.mark.parametrize("case", range(len(_STREAM_CONFIGS)))
def test_estimator_compiled_step_equals_the_reference_filter(case: int, hostile: bool) -> None:
    """The default SCKF's compiled step gives, call by call, what the SCKF as first written gives, to rounding.

    Every flag, count, class and gate decision is equal. The floats differ
    by the rounding of another QR and other sums (``estimators.soil_stiffness_sckf``),
    which the filter's recursion amplifies as it amplifies any rounding: the
    bound is 10× the spread of the reference against itself with its
    initial covariance moved by one ulp (by 1e-13 relative on the hostile
    streams: there the soil-change detector, armed from the start, fires
    again and again, each move and re-open of the stiffness amplifies
    rounding, and the two paths differ by 1e-13 after 200 steps already), and
    at least 1e-8 relative. (On the
    plain streams both are ~1e-9; on the hostile ones, after samples of 1e6,
    up to 1e-2 for both.) The hostile samples are 1e6 here, not 1e300: a
    road sample of 1e300 feeds a ḣ of 1e301 to the LRV's predicted
    acceleration, whose cubature spread is then the rounding of the mean
    (1e286), so whether the update passes or overflows the NIS depends on
    the last bit. The estimator comes out of such steps either way
    (``test_robustness_fuzz.py`` holds it to finite estimates).
    """
    vehicle, extra = _STREAM_CONFIGS[case]
    cfg = SoilStiffnessEstimatorConfig(vehicle=vehicle, **extra)
    events = _stream(RNG_SEED + 40 + case, vehicle, hostile=hostile, huge=1e6)
    fast = SoilStiffnessEstimator(cfg)
    assert fast._sckf is fast.filter
    ref = SoilStiffnessEstimator(cfg, filter_impl=_ReferenceSCKF(gate_threshold=None))
    assert ref._sckf is None
    nudged = SoilStiffnessEstimator(cfg, filter_impl=_ReferenceSCKF(gate_threshold=None))
    nudged._p0 = nudged._p0 * (1.0 + 2.0**-50)
    want = _run_stream(ref, events)
    own_spread = _stream_spread(_run_stream(nudged, events), want)
    if hostile:
        # P0 moved by 1e-13, the difference the two paths already show after 200 steps there; a probe
        # that changes a discrete decision (flag, count) measures no spread and is not used.
        probe = SoilStiffnessEstimator(cfg, filter_impl=_ReferenceSCKF(gate_threshold=None))
        probe._p0 = probe._p0 * (1.0 + 1e-13)
        with contextlib.suppress(AssertionError):
            own_spread = max(own_spread, _stream_spread(_run_stream(probe, events), want))
    assert _stream_spread(_run_stream(fast, events), want) <= max(1e-8, 10.0 * own_spread)
    c = fast.counters
    assert c.updates_accepted > 5
    if "gate_threshold" in extra:
        assert c.gated > 0
    if hostile:
        assert c.predict_only > 0 and c.restarts > 0 and c.dropped_nonfinite > 0


def test_estimator_change_detector_runs_in_the_compared_streams() -> None:
    """The soil-change branch (alarm, move and re-open) is part of what the stream comparison covers."""
    cfg = SoilStiffnessEstimatorConfig(change_threshold=3.0, profile_smoothing_s=0.006)
    est = SoilStiffnessEstimator(cfg)
    _run_stream(est, _stream(RNG_SEED + 45, "quarter_car", hostile=False))
    assert est.counters.soil_changes > 0 and est.last_change is not None


def _road_reference_full(est: SoilStiffnessEstimator, t: float, u_sub: np.ndarray, delta: float) -> tuple[Any, ...]:
    """``_road_at_measurement`` without a ḣ fit, as first written (window arrays, searchsorted)."""
    pt_all = est._pt
    lo = max(bisect.bisect_left(pt_all, t) - 2, 0)
    hi = bisect.bisect_right(pt_all, t, lo) + 2
    pt = np.array(pt_all[lo:hi])
    var = est.config.profile_noise_std**2
    if t > pt[-1]:
        if pt.size >= 2:
            beta = (t - pt[-1]) / (pt[-1] - pt[-2])
            w_h = np.array([-beta, 1.0 + beta])
        else:
            w_h = np.ones(1)
    else:
        i = int(pt.searchsorted(t, side="right"))
        if i >= pt.size or i == 0:
            w_h = np.ones(1)
        else:
            a = (t - pt[i - 1]) / (pt[i] - pt[i - 1])
            w_h = np.array([1.0 - a, a])
    var_h = var * float(w_h @ w_h)
    var_d = 6.5 * var_h / delta**2 if u_sub.size >= 2 else 2.0 * var_h / delta**2
    cov = (1.5 if u_sub.size >= 2 else 1.0) * var_h / delta
    return None, np.array([[var_h, cov], [cov, var_d]])


@pytest.mark.parametrize("count", [1, 2, 300])
def test_road_at_measurement_without_fit_reads_the_list_as_the_window(count: int) -> None:
    est = _filled_estimator(SoilStiffnessEstimatorConfig(), count, RNG_SEED + 60)
    pt = est._pt
    rng = np.random.default_rng(RNG_SEED + 61)
    times = [pt[0] - 1e-3, pt[0], pt[-1], pt[-1] + 2e-3, *pt[:: max(1, count // 20)]]
    times += list(rng.uniform(pt[0] - 0.002, pt[-1] + 0.002, size=50))
    for t in times:
        for u_sub in (rng.standard_normal(10), rng.standard_normal(1)):
            hdot, sigma = est._road_at_measurement(float(t), u_sub, 1e-3)
            _, sigma_ref = _road_reference_full(est, float(t), u_sub, 1e-3)
            assert hdot is None and np.array_equal(sigma, sigma_ref)


def test_measurement_noise_factor_with_a_fed_through_road_error() -> None:
    """LRV with the relative damper (g_ḣ ≠ 0): the constant gain column is filled in as before."""
    est = SoilStiffnessEstimator(SoilStiffnessEstimatorConfig(vehicle="lrv", lrv=LRVParams(relative_damper=True)))
    rng = np.random.default_rng(RNG_SEED + 70)
    for _ in range(50):
        x = np.array([0.001, 0.01, rng.uniform(1e3, 1.4e4)])
        b = rng.standard_normal((2, 2)) * 1e-4
        sigma = b @ b.T
        g_h, g_d = est.model.profile_error_gains(x)
        assert g_d[0] != 0.0
        gain = np.stack([g_h, g_d], axis=1)
        rs = est.model.measurement_noise_sqrt()
        r_eff = rs @ rs.T + gain @ sigma @ gain.T
        assert np.array_equal(est._measurement_noise_sqrt(x, 1, sigma), np.linalg.cholesky(0.5 * (r_eff + r_eff.T)))


def test_grid_offsets_are_the_step_grid() -> None:
    rng = np.random.default_rng(RNG_SEED + 80)
    for _ in range(200):
        t_prev = float(rng.uniform(0.0, 1e4))
        dt = float(rng.choice([0.010000000000000009, 0.009999999999999787, rng.uniform(0.001, 0.5)]))
        n_sub = max(1, math.ceil(dt * 1000.0 - 1e-6))
        assert np.array_equal(t_prev + _grid_offsets(dt, n_sub), t_prev + dt * np.arange(n_sub + 1) / n_sub)


def _half_window_reference(est: SoilStiffnessEstimator, t: float) -> float:
    """``_hdot_half_window`` as first written (no cache)."""
    if not est._hdot_fit:
        return 0.0
    pt = est._pt
    i1 = bisect.bisect_right(pt, t) - 1
    i0 = bisect.bisect_left(pt, t - 0.05)
    if i1 <= i0:
        return 0.05
    v = abs(est._ps[i1] - est._ps[i0]) / (pt[i1] - pt[i0])
    return min(0.5 * est.config.hdot_window_m / v, 0.05) if math.isfinite(v) and v > 0.0 else 0.05


class _NoWaitSkip(SoilStiffnessEstimator):
    """The estimator re-examining its queue on every profile sample (the former behaviour)."""

    def _process_pending(self) -> Any:
        produced = super()._process_pending()
        self._profile_wait = -math.inf
        return produced

    def _hdot_half_window(self, t: float) -> float:
        value = super()._hdot_half_window(t)
        assert value == _half_window_reference(self, t)
        self._half_window_cache = (math.nan, 0.0)
        return value


@pytest.mark.parametrize("case", [0, 3, 4])
def test_waiting_step_and_half_window_caches_change_nothing(case: int) -> None:
    """The profile-wait skip and the ḣ window cache: the same estimates, returned by the same calls.

    The accelerometers run ahead of the profile in bursts, so steps wait
    for the road over several profile samples (the LRV's ḣ window needs
    15 ms past the step); the reference re-examines the queue every time.
    """
    vehicle, extra = _STREAM_CONFIGS[case]
    cfg = SoilStiffnessEstimatorConfig(vehicle=vehicle, **extra)
    events = _stream(RNG_SEED + 90 + case, vehicle, hostile=False, seconds=2.0)
    # Deliver the accelerometers up to 40 ms early: steps then wait for the road.
    shifted = []
    for i, ev in enumerate(events):
        key = ev[1] - (0.04 * ((i // 7) % 3) / 2.0 if ev[0] == "a" else 0.0)
        shifted.append((key, i, ev))
    events = [e for _, _, e in sorted(shifted)]
    fast, ref = SoilStiffnessEstimator(cfg), _NoWaitSkip(cfg)
    got, want = _run_stream(fast, events), _run_stream(ref, events)
    assert got == want
    assert fast.counters.updates_accepted > 100
    # the skip was taken (some profile samples found the queue head waiting)
    skipped = 0
    probe = SoilStiffnessEstimator(cfg)
    for ev in events:
        if ev[0] == "p" and probe._pending and ev[1] < probe._profile_wait:
            skipped += 1
        (probe.add_profile_sample if ev[0] == "p" else probe.add_accelerations)(*ev[1:])
    assert skipped > 0


def _flush_before_reference(adapter: Any, stamp_ns: int) -> None:
    """``SoilStiffnessAdapter._flush_before`` as first written (no early return)."""
    for t in sorted(t for t in adapter._body if t < stamp_ns):
        adapter.health.reject("imu/wheel: no sample with the body stamp (body-only update)")
        adapter.estimator.add_accelerations(t * 1e-9, adapter._body.pop(t), None)
    for t in [t for t in adapter._wheel if t < stamp_ns]:
        adapter.health.reject("imu/wheel: no body sample with its stamp (dropped)")
        del adapter._wheel[t]


def _drain_reference(adapter: Any) -> list[Any]:
    """``SoilStiffnessAdapter._drain`` as first written (the gappy window summed, the counters object)."""
    from terrain_estimation.ros import soil_stiffness as ros

    estimates = adapter.estimator.drain_estimates()
    h = adapter.health
    for e in estimates:
        h.updates += 1
        h.last_update_time = e.t
        if e.accepted:
            h.nis.append(e.nis)
        adapter._profile_gappy.append(e.profile_gap_ratio > ros.PROFILE_GAP_RATIO_WARN)
    if estimates:
        last = estimates[-1]
        c = adapter.estimator.counters
        h.status = f"k_s {last.k_s / 1e3:.1f} kN/m, {last.terrain_class} ({last.class_confidence:.2f})" + (
            ", converged" if last.converged else ", converging"
        )
        gappy = sum(adapter._profile_gappy)
        n = len(adapter._profile_gappy)
        h.warnings = (
            [
                f"terrain/profile: {gappy} of the last {n} steps lost profile samples (gap > "
                f"{ros.PROFILE_GAP_RATIO_WARN:g}x the sample spacing): the road between steps is interpolated "
                "and k_s biased; the node is not keeping up with the profiler, or the sensor drops samples"
            ]
            if gappy > ros.PROFILE_GAPPY_FRACTION_WARN * n
            else []
        )
        h.values.update(
            k_s=last.k_s,
            profile_gappy_steps=gappy,
            k_s_std=math.sqrt(last.k_s_variance),
            terrain_class=last.terrain_class,
            travel_speed=adapter.travel_speed,
            soil_changes=c.soil_changes,
            restarts=c.restarts,
            gated=c.gated,
            dropped_nonfinite=c.dropped_nonfinite,
            dropped_out_of_order=c.dropped_out_of_order,
            dropped_no_profile=c.dropped_no_profile,
            profile_rejected=c.profile_rejected,
            divergences=c.divergences,
        )
    fault = adapter.estimator.fault
    h.errors = ros.divergence_errors(fault, adapter.estimator.counters.divergences) if fault else []
    return estimates


def _adapter_messages(seed: int) -> list[tuple[str, Any]]:
    """Quarter-car input messages: 1 kHz profile, paired IMUs with lost, late and unpaired samples."""
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import Imu, JointState

    from terrain_estimation.ros.time import sec_to_stamp

    rng = np.random.default_rng(seed)
    timed: list[tuple[float, int, str, Any]] = []
    for i in range(1, 2500):
        t = i * 1e-3
        if (i // 100) % 4 == 1 and i % 100 < 6:
            continue  # lost profile samples: steps with gaps (the diagnostics' gappy window)
        m = PointStamped()
        m.header.stamp = sec_to_stamp(t)
        m.point.x, m.point.z = 10.0 * t, 0.01 * math.sin(7.0 * t) + 1e-4 * float(rng.standard_normal())
        timed.append((t, 0, "profile", m))
    for i in range(1, 240):
        t = i * 1e-2
        for key, z in (("imu_body", 9.8 + math.sin(7.0 * t)), ("imu_wheel", 9.8 + 10.0 * math.sin(41.0 * t))):
            r = rng.random()
            if r < 0.08:
                continue  # lost: the partner waits, then goes alone (body) or is dropped (wheel)
            m = Imu()
            m.header.stamp = sec_to_stamp(t)
            m.linear_acceleration.z = z + 0.5 * float(rng.standard_normal())
            delay = 0.06 if r < 0.12 else 0.001 * rng.random()  # late beyond the pair timeout
            timed.append((t + delay, 1, key, m))
        j = JointState()
        j.header.stamp = sec_to_stamp(t)
        j.name, j.velocity = ["wheel"], [25.0]
        timed.append((t + 0.0005, 2, "joint_states", j))
    timed.sort(key=lambda e: (e[0], e[1]))
    return [(key, msg) for _, _, key, msg in timed]


def test_adapter_pairing_and_drain_shortcuts_change_nothing() -> None:
    """The adapter's early-out pairing flush and drain: the same estimates, rejections and status."""
    from terrain_estimation.ros.soil_stiffness import make_adapter
    from terrain_estimation.tools.estimate import numeric_fields
    from terrain_estimation.vehicles import estimator_parameters, get_vehicle

    entry = get_vehicle("quarter_car")
    values = estimator_parameters(entry, None, None)
    fast, ref = make_adapter(values, entry.namespace), make_adapter(values, entry.namespace)
    ref._flush_before = lambda stamp_ns: _flush_before_reference(ref, stamp_ns)  # type: ignore[method-assign]
    ref._drain = lambda: _drain_reference(ref)  # type: ignore[method-assign]
    got, want = [], []
    for key, msg in _adapter_messages(RNG_SEED + 100):
        for adapter, out in ((fast, got), (ref, want)):
            published = adapter.handle(key, msg)
            h = adapter.health
            out.append((h.updates, h.last_update_time, list(h.nis), list(h.warnings), dict(h.values)))
            out.append(
                [(topic, numeric_fields(m), m.header.stamp.sec, m.header.stamp.nanosec) for topic, m in published]
            )
            out.append((adapter.health.errors, adapter.health.status, dict(adapter.health.rejected)))
    assert got == want
    rejected = fast.health.rejected
    assert any("body-only" in r for r in rejected) and any("dropped" in r for r in rejected)
    assert fast.health.values["profile_gappy_steps"] > 0 and len(fast._profile_gappy) == 200
    assert sum(1 for out in got if out and isinstance(out, list) and out) > 150


@pytest.mark.parametrize(
    ("k1", "k2", "n"), [(10, 5, 5), (10, 2, 5), (6, 3, 3), (10, 1, 5), (2, 1, 5), (1, 1, 3), (12, 2, 2)]
)
def test_tria_rows_is_tria_of_the_stacked_rows(k1: int, k2: int, n: int) -> None:
    """The in-place factor of two stacked row blocks: tria of their concatenation, bit for bit."""
    rng = np.random.default_rng(RNG_SEED + 110)
    for _ in range(300):
        top = rng.standard_normal((k1, n)) * 10.0 ** rng.uniform(-4, 4, size=n)
        bottom = np.tril(rng.standard_normal((k2, n)))
        if rng.random() < 0.2:
            top[:, int(rng.integers(n))] = 0.0
        top_before, bottom_before = top.copy(), bottom.copy()
        expected = tria(np.concatenate((top, bottom)).T)
        got = _tria_rows(top, bottom)
        assert np.array_equal(got, expected) and np.array_equal(np.signbit(got), np.signbit(expected))
        assert np.array_equal(got, _tria_reference(np.concatenate((top, bottom)).T))
        assert np.array_equal(top, top_before) and np.array_equal(bottom, bottom_before)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("hostile", [False, True])
@pytest.mark.parametrize("case", range(len(_STREAM_CONFIGS)))
def test_profile_samples_in_bulk_are_taken_as_one_at_a_time(case: int, hostile: bool) -> None:
    """add_profile_samples (an offline ride's lists, qc_runs) takes the samples add_profile_sample would take,
    with the same buffers, and hands back the one it must not (rejected, or one that may complete a queued
    step): the same estimates, counters and state as one call per sample, non-finite and out-of-order samples
    and steps waiting for the road included."""
    vehicle, extra = _STREAM_CONFIGS[case]
    cfg = SoilStiffnessEstimatorConfig(vehicle=vehicle, **extra)
    events = _stream(RNG_SEED + 120 + case, vehicle, hostile=hostile, seconds=2.0)
    bulk, single = SoilStiffnessEstimator(cfg), SoilStiffnessEstimator(cfg)
    got: list[Any] = []
    want: list[Any] = []
    handed_back = 0
    i = 0
    while i < len(events):
        if events[i][0] == "a":
            for est, out in ((bulk, got), (single, want)):
                est.add_accelerations(*events[i][1:])
                out.append([_estimate_key(e) for e in est.drain_estimates()])
            i += 1
            continue
        stop = i
        while stop < len(events) and events[stop][0] == "p":
            stop += 1
        t, s, h = ([ev[k] for ev in events[i:stop]] for k in (1, 2, 3))
        j = 0
        while j < len(t):
            j = bulk.add_profile_samples(t, s, h, j, len(t))
            if j < len(t):
                bulk.add_profile_sample(t[j], s[j], h[j])
                handed_back += 1
                j += 1
        for ev in events[i:stop]:
            single.add_profile_sample(*ev[1:])
        i = stop
    got.append(bulk.counters)
    want.append(single.counters)
    assert got == want
    assert (bulk._pt, bulk._ph, bulk._ps, bulk._last_distance) == (
        single._pt,
        single._ph,
        single._ps,
        single._last_distance,
    )
    assert bulk.counters.steps > 100 and handed_back > 0
    if hostile:
        assert bulk.counters.profile_rejected > 0
