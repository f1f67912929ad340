"""Quarter-car and LRV estimation models against MODELS.md A.1–A.7 (appendix A.1–A.4)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.filters.base import JacobianModel, StateSpaceModel
from terrain_estimation.models.quarter_car import (
    LRVModel,
    LRVParams,
    QuarterCarModel,
    QuarterCarParams,
    StepInput,
    discretise,
)

MS, MNS, K, C, KT = 455.0, 45.5, 25e3, 2e3, 175e3
KTOT_GRANEVILLE = 651.1e3 * KT / (651.1e3 + KT)
X_NOM = np.array([0.012, 0.21, -0.0061, 0.47, KTOT_GRANEVILLE])
U_SUB = np.array([0.31, 0.12, -0.05, -0.22, -0.4, -0.18, 0.07, 0.25, 0.33, 0.29])


def test_protocols() -> None:
    for model in (QuarterCarModel(), LRVModel()):
        assert isinstance(model, StateSpaceModel)
        assert isinstance(model, JacobianModel)
    assert QuarterCarModel().state_dim == 5 and QuarterCarModel().measurement_dim == 2
    assert LRVModel().state_dim == 3 and LRVModel().measurement_dim == 1


def test_a_b_g_c_match_appendix() -> None:
    m = QuarterCarModel()
    x5 = X_NOM[4]
    expected_a = np.array(  # (A.1)
        [
            [0, 1, 0, -1, 0],
            [-K / MS, -C / MS, 0, C / MS, 0],
            [0, 0, 0, 1, 0],
            [K / MNS, C / MNS, -x5 / MNS, -C / MNS, 0],
            [0, 0, 0, 0, 0],
        ]
    )
    np.testing.assert_allclose(m.A(X_NOM), expected_a, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(m.B, [0, 0, -1, 0, 0])  # (A.2)
    np.testing.assert_array_equal(  # (A.3)
        m.G,
        [[0, 1, 0, 1, 0], [1, 1, 0, 1, 0], [0, 0, 0, 1, 0], [1, 1, 1, 1, 0], [0, 0, 0, 0, 1]],
    )
    assert round(np.linalg.det(m.G)) == 1
    np.testing.assert_allclose(m.C(X_NOM), expected_a[[1, 3]], rtol=1e-15)  # (A.4)
    # batched evaluation = row by row
    pts = np.stack([X_NOM, X_NOM * [1, 1, 1, 1, 0.5]])
    np.testing.assert_allclose(m.A(pts)[1], m.A(pts[1]))


def test_a_x_is_the_quarter_car_equations() -> None:
    """A(x)x + Bḣ in physical coordinates is exactly (P-2)."""
    m = QuarterCarModel()
    y1, v1, y2, v2, h, hdot = 0.031, -0.2, 0.012, 0.6, -0.004, 0.35
    k_tot = X_NOM[4]
    x = np.array([y1 - y2, v1, y2 - h, v2, k_tot])
    a1 = -(C * (v1 - v2) + K * (y1 - y2)) / MS
    a2 = -(C * (v2 - v1) + K * (y2 - y1) + k_tot * (y2 - h)) / MNS
    expected = [v1 - v2, a1, v2 - hdot, a2, 0.0]
    np.testing.assert_allclose(m.continuous_derivative(x, hdot), expected, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(m.h(x), [a1, a2], rtol=1e-14)


def test_lrv_reduction_and_relative_damper() -> None:
    lit = LRVModel()
    rel = LRVModel(LRVParams(relative_damper=True))
    ms, k, c = 75.0, 15e3, 1.5e3
    k_tot = k * 28.487e3 / (k + 28.487e3)
    x = np.array([0.02, -0.3, k_tot])
    expected = [[0, 1, 0], [-k_tot / ms, -c / ms, 0], [0, 0, 0]]
    np.testing.assert_allclose(lit.A(x), expected, rtol=1e-15)
    np.testing.assert_array_equal(lit.B, [-1, 0, 0])
    np.testing.assert_array_equal(rel.B, [-1, c / ms, 0])
    np.testing.assert_array_equal(lit.G, [[0, 1, 0], [1, 1, 0], [0, 0, 1]])
    hdot = np.array([0.1, 0.2, 0.4])  # ḣ at the end: 1.5·0.4 − 0.5·0.2 = 0.5
    np.testing.assert_allclose(lit.h(x, hdot), [(-k_tot * 0.02 + c * 0.3) / ms])
    np.testing.assert_allclose(rel.h(x, hdot), [(-k_tot * 0.02 - c * (-0.3 - 0.5)) / ms])
    assert lit.k_series == 15e3 and QuarterCarModel().k_series == 175e3


def test_step_input_carries_hdot_at_the_measurement_time() -> None:
    """StepInput: the same propagation as its sub-step array, its own ḣ(t) in the feed-through."""
    rel = LRVModel(LRVParams(relative_damper=True))
    ms, c = 75.0, 1.5e3
    x = np.array([0.02, -0.3, 9.8e3])
    hdot = np.array([0.1, 0.2, 0.4])
    base = rel.h(x, 0.0)[0]
    np.testing.assert_allclose(rel.h(x, StepInput(hdot, 0.7)), [base + c / ms * 0.7], rtol=1e-14)
    for fallback in (None, float("nan")):  # → extrapolation 1.5·0.4 − 0.5·0.2
        np.testing.assert_allclose(rel.h(x, StepInput(hdot, fallback)), [base + c / ms * 0.5], rtol=1e-14)
    np.testing.assert_array_equal(rel.f(x, StepInput(hdot, 0.7), 0.01), rel.f(x, hdot, 0.01))
    np.testing.assert_array_equal(
        rel.transition_jacobian(x, StepInput(hdot, 0.7), 0.01), rel.transition_jacobian(x, hdot, 0.01)
    )
    np.testing.assert_array_equal(rel.measurement_jacobian(x, StepInput(hdot, 0.7)), rel.measurement_jacobian(x))
    # without feed-through the end value is ignored
    lit = LRVModel()
    assert lit.h(x, StepInput(hdot, 5.0))[0] == lit.h(x, hdot)[0]


@pytest.mark.parametrize("vehicle", ["quarter_car", "lrv_relative", "lrv_literal"])
def test_profile_error_gains(vehicle: str) -> None:
    """``δz ≈ C B ε_h + D ε_ḣ``: closed forms, and a perturbed road through f and h."""
    if vehicle == "quarter_car":
        m: QuarterCarModel | LRVModel = QuarterCarModel()
        x = X_NOM
        expected_h, expected_d = [0.0, x[4] / MNS], [0.0, 0.0]
    else:
        relative = vehicle == "lrv_relative"
        m = LRVModel(LRVParams(relative_damper=relative))
        x = np.array([0.02, -0.3, 9.8e3])
        ms, c = 75.0, 1.5e3
        expected_h = [x[2] / ms - ((c / ms) ** 2 if relative else 0.0)]
        expected_d = [c / ms if relative else 0.0]
    g_h, g_d = m.profile_error_gains(x)
    np.testing.assert_allclose(g_h, expected_h, rtol=1e-14)
    np.testing.assert_allclose(g_d, expected_d, rtol=1e-14)
    np.testing.assert_allclose(m.profile_error_gains(np.stack([x, x]))[0], g_h)  # point sets: the mean
    # A step whose last grid elevation is off by ε (ḣ(t) held fixed): the
    # predicted accelerations move by ≈ g_h ε (first order in the 1 ms sub-step).
    eps, delta = 1e-4, 1e-3
    u = U_SUB.copy()
    u_eps = u.copy()
    u_eps[-1] += eps / delta
    z0 = m.h(m.f(x, StepInput(u, 0.3), 0.01), StepInput(u, 0.3))
    z1 = m.h(m.f(x, StepInput(u_eps, 0.3), 0.01), StepInput(u_eps, 0.3))
    np.testing.assert_allclose((z1 - z0) / eps, g_h, rtol=0.05, atol=0.01 * np.abs(g_h).max())


@pytest.mark.parametrize("which", ["phi", "gamma"])
def test_taylor_vs_expm_is_the_fifth_order_remainder(which: str) -> None:
    """Taylor4 (P-11) misses exactly the next series term: (Aδ)⁵/5! for Φ, A⁵δ⁶/6! for Γ."""
    a = QuarterCarModel(QuarterCarParams()).A(X_NOM)
    diffs = []
    for delta in (0.01, 0.005, 0.001):
        phi_t, gam_t = discretise(a, delta, "taylor4")
        phi_e, gam_e = discretise(a, delta, "expm")
        a5 = np.linalg.matrix_power(a * delta, 5)
        if which == "phi":
            diff, lead = phi_e - phi_t, a5 / math.factorial(5)
        else:
            diff, lead = gam_e - gam_t, a5 * delta / math.factorial(6)
        ratio = np.linalg.norm(diff) / np.linalg.norm(lead)
        assert 0.6 < ratio < 1.4, (delta, ratio)
        diffs.append(np.linalg.norm(diff))
    order = math.log(diffs[0] / diffs[1]) / math.log(2.0)
    assert (5.5 if which == "gamma" else 4.5) < order < (6.5 if which == "gamma" else 5.5)
    # documented magnitude: ≈ 6e-4 relative at the paper's 10 ms, ≈ 1e-8 at 1 ms
    phi_t, _ = discretise(a, 0.01, "taylor4")
    phi_e, _ = discretise(a, 0.01, "expm")
    assert 1e-4 < np.abs(phi_e - phi_t).max() / np.abs(phi_e).max() < 3e-3


def test_f_substeps_and_methods_agree() -> None:
    mt = QuarterCarModel()
    me = QuarterCarModel(QuarterCarParams(discretisation="expm"))
    xt, xe = mt.f(X_NOM, U_SUB, 0.01), me.f(X_NOM, U_SUB, 0.01)
    np.testing.assert_allclose(xt, xe, rtol=1e-6, atol=1e-10)
    # one sub-step of 10 ms: the paper's ZOH; Taylor and exact differ by ~1e-4
    d = np.abs(mt.f(X_NOM, 0.2, 0.01) - me.f(X_NOM, 0.2, 0.01))
    assert d[:4].max() < 1e-3 and d[4] == 0
    # N sub-steps of δ = N single steps of δ
    y = X_NOM.copy()
    for uj in U_SUB:
        y = mt.f(y, uj, 0.001)
    np.testing.assert_allclose(mt.f(X_NOM, U_SUB, 0.01), y, rtol=1e-12, atol=1e-15)


def test_f_vectorised_over_points_and_ktot_random_walk() -> None:
    m = QuarterCarModel()
    rng = np.random.default_rng(3)
    pts = X_NOM + rng.standard_normal((10, 5)) * [0.01, 0.1, 0.002, 0.1, 4e4]
    pts[0, 4] = -5e4  # outside (0, k_t): clamped in the dynamics, passed through
    pts[1, 4] = 3e5
    out = m.f(pts, U_SUB, 0.01)
    assert out.shape == (10, 5)
    for i in range(10):
        np.testing.assert_allclose(out[i], m.f(pts[i], U_SUB, 0.01), rtol=1e-13, atol=1e-15)
    np.testing.assert_array_equal(out[:, 4], pts[:, 4])
    kmin, kmax = m.ktot_bounds
    clamped = pts[0].copy()
    clamped[4] = kmin
    np.testing.assert_allclose(out[0, :4], m.f(clamped, U_SUB, 0.01)[:4])
    z = m.h(pts, U_SUB)
    assert z.shape == (10, 2)
    # hostile but finite: never NaN
    hostile = np.array([[1e3, -1e4, 1e3, 1e5, -1e12], [0, 0, 0, 0, 1e30]])
    assert np.isfinite(m.f(hostile, np.full(10, 1e6), 0.01)).all()
    assert np.isfinite(m.h(hostile)).all()
    assert np.isfinite(m.f(X_NOM, np.array([np.nan, 0.1]), 0.01)).all()


def _fd_jacobian(fun, x: np.ndarray, scales: np.ndarray) -> np.ndarray:
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = 1e-6 * scales[i]
        cols.append((fun(x + e) - fun(x - e)) / (2 * e[i]))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("method", ["taylor4", "expm"])
@pytest.mark.parametrize("vehicle", ["quarter_car", "lrv", "lrv_relative"])
def test_jacobians_match_central_differences(method: str, vehicle: str) -> None:
    if vehicle == "quarter_car":
        m: QuarterCarModel | LRVModel = QuarterCarModel(QuarterCarParams(discretisation=method))
        x = X_NOM
        scales = np.array([0.01, 0.1, 0.01, 0.1, 1e5])
    else:
        m = LRVModel(LRVParams(discretisation=method, relative_damper=vehicle == "lrv_relative"))
        x = np.array([0.013, -0.21, 9826.0])
        scales = np.array([0.01, 0.1, 1e4])
    for u in (U_SUB, 0.3):
        jac = m.transition_jacobian(x, u, 0.01)
        jac_fd = _fd_jacobian(lambda v, u=u: m.f(v, u, 0.01), x, scales)
        err = np.linalg.norm(jac - jac_fd, axis=0) / np.linalg.norm(jac_fd, axis=0)
        assert err.max() < 1e-6, err
    hx = m.measurement_jacobian(x, U_SUB)
    hx_fd = _fd_jacobian(lambda v: m.h(v, U_SUB), x, scales)
    np.testing.assert_allclose(hx, hx_fd, rtol=1e-7, atol=1e-12)


def test_paper_jacobian_omits_the_input_term() -> None:
    exact = QuarterCarModel()
    paper = QuarterCarModel(QuarterCarParams(ekf_jacobian="paper"))
    # one sub-step: the paper's form is the series of A_x (A.6)
    a_x = exact.A(X_NOM)
    a_x[3, 4] = -X_NOM[2] / MNS
    phi_x, _ = discretise(a_x, 0.01, "taylor4")
    np.testing.assert_allclose(paper.transition_jacobian(X_NOM, 0.0, 0.01), phi_x, rtol=1e-14)
    # with road input the k_tot columns differ by exactly ∂(B_k u)/∂k_tot
    u = 0.5
    d_u = exact.transition_jacobian(X_NOM, u, 0.01) - paper.transition_jacobian(X_NOM, u, 0.01)
    d_0 = exact.transition_jacobian(X_NOM, 0.0, 0.01) - paper.transition_jacobian(X_NOM, 0.0, 0.01)
    np.testing.assert_allclose(d_u[:, :4], 0.0, atol=1e-15)
    dk = 1.0
    _, g_hi = discretise(exact.A(X_NOM + [0, 0, 0, 0, dk]), 0.01, "taylor4")
    _, g_lo = discretise(exact.A(X_NOM - [0, 0, 0, 0, dk]), 0.01, "taylor4")
    input_term = (g_hi - g_lo) @ exact.B * u / (2 * dk)
    np.testing.assert_allclose(d_u[:, 4] - d_0[:, 4], input_term, rtol=1e-6, atol=1e-18)
    assert np.abs(input_term[3]) > 1e-9


def _lie_observability(m: QuarterCarModel, x: np.ndarray) -> np.ndarray:
    """∂/∂x L_f^i h, i = 0…n−1 (P-10), for the drift f = A(x)x.

    k_tot is constant along f, so L_f^i h = (A^{i+1} x)[rows] with A = A(x5);
    its x5-derivative is (dA^{i+1}/dx5 x)[rows], dA^j = Σ A^a E A^{j−1−a}.
    """
    n = m.state_dim
    a = m.A(x)
    e = np.zeros((n, n))
    e[3, 2] = -1.0 / MNS
    rows = []
    for i in range(n):
        j = i + 1
        aj = np.linalg.matrix_power(a, j)
        mp = np.linalg.matrix_power
        daj = sum(mp(a, p) @ e @ mp(a, j - 1 - p) for p in range(j))
        grad = aj.copy()
        grad[:, 4] = daj @ x
        rows.append(grad[[1, 3]])
    return np.vstack(rows)


def test_observability_rank_full_at_nominal_point() -> None:
    m = QuarterCarModel()
    # the closed form of L_f^1 h against a numerical Lie derivative
    eps = 1e-7
    fx = m.continuous_derivative(X_NOM)
    lie1 = (m.h(X_NOM + eps * fx) - m.h(X_NOM - eps * fx)) / (2 * eps)
    a = m.A(X_NOM)
    np.testing.assert_allclose(lie1, (a @ a @ X_NOM)[[1, 3]], rtol=1e-6)

    scale = np.diag([0.01, 0.1, 0.01, 0.1, 1e5])  # typical magnitudes: a fair SVD
    mobs = _lie_observability(m, X_NOM) @ scale
    mobs /= np.linalg.norm(mobs, axis=1, keepdims=True)
    sv = np.linalg.svd(mobs, compute_uv=False)
    assert np.linalg.matrix_rank(mobs, tol=1e-9 * sv[0]) == 5
    # at rest (all motion states zero) k_tot is not observable: excitation needed
    at_rest = X_NOM * [0, 0, 0, 0, 1]
    mobs0 = _lie_observability(m, at_rest) @ scale
    assert np.linalg.matrix_rank(mobs0, tol=1e-9 * np.abs(mobs0).max()) == 4


def test_process_noise_forms() -> None:
    dt = 0.01
    per_step = QuarterCarModel()
    printed = QuarterCarModel(QuarterCarParams(ktot_noise_form="printed"))
    lp = per_step.process_noise_sqrt(X_NOM, U_SUB, dt)
    lq = printed.process_noise_sqrt(X_NOM, U_SUB, dt)
    qp, qq = lp @ lp.T, lq @ lq.T
    assert qp[4, 4] == pytest.approx(1e3)
    assert qq[4, 4] == pytest.approx(dt**3 * 1e5)  # 0.1 (N/m)² per step (A.4)
    np.testing.assert_allclose(qp[:4, :4], qq[:4, :4])
    assert np.all(qp[4, :4] == 0)
    # states 1–4: Δt G_k Q G_kᵀ with G_k = Γ_k G, Γ_k over the whole step
    a = per_step.A(X_NOM)
    _, gam = discretise(a, dt, "taylor4")
    gk = gam @ per_step.G
    qd = dt * gk @ np.diag([1e-5, 1e-3, 1e-5, 1e-3, 0.0]) @ gk.T
    np.testing.assert_allclose(qp[:4, :4], qd[:4, :4], rtol=1e-12, atol=1e-20)
    # a longer step scales the k_tot random walk linearly
    assert (per_step.process_noise_sqrt(X_NOM, 0.0, 0.02)[4, 4]) ** 2 == pytest.approx(2e3)
    np.testing.assert_allclose(per_step.measurement_noise_sqrt(), np.diag(np.sqrt([0.5, 0.5])))


def test_params_validation() -> None:
    with pytest.raises(ValueError):
        QuarterCarParams(m_s=0.0)
    with pytest.raises(ValueError):
        QuarterCarParams(q_diag=(1.0, 1.0))
    with pytest.raises(ValueError):
        QuarterCarParams(discretisation="rk4")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        LRVParams(r_diag=(0.0,))
    with pytest.raises(ValueError):
        LRVParams(ktot_min_frac=0.5, ktot_max_frac=0.4)


def test_core_does_not_import_ros() -> None:
    import subprocess
    import sys

    code = (
        "import sys; import terrain_estimation.models.quarter_car, "
        "terrain_estimation.models.soil, terrain_estimation.estimators.soil_stiffness; "
        "sys.exit(1 if any(m.startswith('rclpy') for m in sys.modules) else 0)"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


# -- the "log_k_s" stiffness state -------------------------------------------------


def _log_models() -> tuple[QuarterCarModel, QuarterCarModel]:
    return QuarterCarModel(), QuarterCarModel(QuarterCarParams(stiffness_state="log_k_s"))


def test_log_state_maps_to_the_same_dynamics() -> None:
    lin, log = _log_models()
    s = log.stiffness_state_of_ktot(KTOT_GRANEVILLE)
    # s = ln(k_s / k_t): Graneville loam's 651.1 kN/m
    assert s == pytest.approx(math.log(651.1e3 / KT), rel=1e-12)
    assert float(log.ktot_of(s)) == pytest.approx(KTOT_GRANEVILLE, rel=1e-12)
    x_log = X_NOM.copy()
    x_log[-1] = s
    for u in (U_SUB, 0.3):
        y_lin, y_log = lin.f(X_NOM, u, 0.01), log.f(x_log, u, 0.01)
        np.testing.assert_allclose(y_log[:-1], y_lin[:-1], rtol=1e-10, atol=1e-14)
        assert y_log[-1] == s  # random walk: unchanged by the dynamics
    np.testing.assert_allclose(log.h(x_log, U_SUB), lin.h(X_NOM, U_SUB), rtol=1e-10, atol=1e-12)


def test_log_state_keeps_ktot_inside_the_series_stiffness() -> None:
    _, log = _log_models()
    s = np.array([-1e6, -40.0, -5.0, 0.0, 5.0, 40.0, 1e6])
    k = log.ktot_of(s)
    assert np.all(k > 0.0) and np.all(k < KT)
    assert float(log.ktot_of(0.0)) == pytest.approx(KT / 2)  # the paper's start guess k_t/2
    # k_s stays finite and positive at any state, even far beyond the clip.
    for v in (-1e6, 0.0, 1e6):
        k_tot, k_var, k_s, k_s_var = log.stiffness_moments(v, 0.04)
        assert all(math.isfinite(q) for q in (k_tot, k_var, k_s, k_s_var))
        assert k_s > 0.0
    # The state's range (default ±ln 100) bounds k_s and the dynamics' k_tot alike.
    assert log.stiffness_moments(1e6, 0.01)[2] == pytest.approx(100.0 * KT)
    assert log.stiffness_moments(-1e6, 0.01)[2] == pytest.approx(KT / 100.0)
    assert float(log.ktot_of(40.0)) == float(log.ktot_of(math.log(100.0)))
    assert log.project_stiffness_state(40.0) == pytest.approx(math.log(100.0))
    assert log.ktot_slope(40.0) == 0.0 and log.ktot_slope(0.0) == pytest.approx(KT / 4)
    narrow = QuarterCarModel(QuarterCarParams(stiffness_state="log_k_s", log_ks_range=(-1.0, 1.0)))
    assert narrow.project_stiffness_state(3.0) == 1.0
    with pytest.raises(ValueError, match="log_ks_range"):
        QuarterCarParams(log_ks_range=(1.0, -1.0))
    k_tot, _, k_s, k_s_var = log.stiffness_moments(math.log(651.1e3 / KT), 0.01)
    assert k_s == pytest.approx(651.1e3, rel=1e-12)
    assert math.sqrt(k_s_var) / k_s == pytest.approx(0.1, rel=1e-12)  # var of ln k_s = relative variance
    # Non-finite variance is reported as "unknown", never NaN.
    assert math.isfinite(log.stiffness_moments(0.0, float("nan"))[3])


@pytest.mark.parametrize("form", ["exact", "paper"])
def test_log_state_jacobians_match_central_differences(form: str) -> None:
    log = QuarterCarModel(QuarterCarParams(stiffness_state="log_k_s", ekf_jacobian=form))
    x = X_NOM.copy()
    x[-1] = log.stiffness_state_of_ktot(KTOT_GRANEVILLE)
    scales = np.array([0.01, 0.1, 0.01, 0.1, 1.0])
    hx = log.measurement_jacobian(x, U_SUB)
    hx_fd = _fd_jacobian(lambda v: log.h(v, U_SUB), x, scales)
    np.testing.assert_allclose(hx, hx_fd, rtol=1e-7, atol=1e-12)
    if form == "exact":
        jac = log.transition_jacobian(x, U_SUB, 0.01)
        jac_fd = _fd_jacobian(lambda v: log.f(v, U_SUB, 0.01), x, scales)
        err = np.linalg.norm(jac - jac_fd, axis=0) / np.linalg.norm(jac_fd, axis=0)
        assert err.max() < 1e-6, err


def test_log_state_process_noise_is_the_relative_walk() -> None:
    lin, log = _log_models()
    q = 4e-6
    log = QuarterCarModel(QuarterCarParams(stiffness_state="log_k_s", q_log_ks_per_step=q))
    x = X_NOM.copy()
    x[-1] = log.stiffness_state_of_ktot(KTOT_GRANEVILLE)
    lq_log = log.process_noise_sqrt(x, U_SUB, 0.02)
    lq_lin = lin.process_noise_sqrt(X_NOM, U_SUB, 0.02)
    np.testing.assert_allclose(lq_log[:-1, :-1], lq_lin[:-1, :-1], rtol=1e-12)
    assert lq_log[-1, -1] == pytest.approx(math.sqrt(q * 2.0))  # scales with the step: 0.02 s = 2 steps
    assert not np.any(lq_log[-1, :-1]) and not np.any(lq_log[:-1, -1])
    with pytest.raises(ValueError, match="stiffness_state"):
        QuarterCarParams(stiffness_state="ks")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="q_log_ks_per_step"):
        LRVParams(q_log_ks_per_step=-1.0)
