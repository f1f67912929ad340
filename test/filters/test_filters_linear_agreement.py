"""On a linear model every filter must be the Kalman filter.

Tolerance, everywhere in this module: elementwise
``|a − b| ≤ 1e-9 + 1e-9·|b|`` (``assert_allclose(rtol=1e-9, atol=1e-9)``),
for means and covariances, at every one of the 50 steps. The model's P stays
between ~1e-3 and ~1 (see ``make_linear_model``), so this is a relative
agreement of ~1e-9 or better.

The unscented transform is exact for a linear map for any weights whose
mean weights sum to 1 (the points are symmetric, so the centre deviation is 0
and ``W_c0`` never enters). Three parameter sets are checked:
``(α, β, κ) = (1, 0, 0)`` (centre weight 0: the cubature rule),
``(1, 2, 0)`` (the project default) and ``(0.5, 2, 3 − n)`` (negative
``W_m0 = −13/3``, still exact up to rounding).
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF

from terrain_estimation.filters import (
    CubatureKalmanFilter,
    ExtendedKalmanFilter,
    KalmanFilter,
    SquareRootCubatureKalmanFilter,
    UnscentedKalmanFilter,
)

TOL = {"rtol": 1e-9, "atol": 1e-9}

FILTERS = {
    "ekf": ExtendedKalmanFilter(),
    "ckf": CubatureKalmanFilter(),
    "sckf": SquareRootCubatureKalmanFilter(),
    "ukf_1_0_0": UnscentedKalmanFilter(alpha=1.0, beta=0.0, kappa=0.0),
    "ukf_1_2_0": UnscentedKalmanFilter(alpha=1.0, beta=2.0, kappa=0.0),
    "ukf_05_2_m1": UnscentedKalmanFilter(alpha=0.5, beta=2.0, kappa=-1.0),
}


def kalman_reference(model, run):
    """(prior, posterior) pairs of the linear Kalman filter over the run."""
    kf = KalmanFilter()
    Q = model.Lq @ model.Lq.T
    R = model.Lr @ model.Lr.T
    state = kf.initial_state(run.x0, run.P0)
    out = []
    for u, z in zip(run.us, run.zs, strict=True):
        prior = kf.predict(state, model.F, Q, model.B, u)
        state, info = kf.update(prior, z, model.H, R)
        assert info.accepted
        out.append((prior, state, info))
    return out


def test_kalman_filter_matches_filterpy(linear_model, linear_run):
    """The reference itself against filterpy's KalmanFilter (Joseph form too)."""
    m = linear_model
    fp = FilterpyKF(dim_x=4, dim_z=2, dim_u=2)
    fp.x, fp.P = linear_run.x0.copy(), linear_run.P0.copy()
    fp.F, fp.B, fp.H = m.F, m.B, m.H
    fp.Q, fp.R = m.Lq @ m.Lq.T, m.Lr @ m.Lr.T
    for (prior, post, _), u, z in zip(kalman_reference(m, linear_run), linear_run.us, linear_run.zs, strict=True):
        fp.predict(u=u)
        np.testing.assert_allclose(prior.x, fp.x, **TOL)
        np.testing.assert_allclose(prior.P, fp.P, **TOL)
        fp.update(z)
        np.testing.assert_allclose(post.x, fp.x, **TOL)
        np.testing.assert_allclose(post.P, fp.P, **TOL)


@pytest.mark.parametrize("name", list(FILTERS))
def test_filter_equals_kalman_filter_on_linear_model(name, linear_model, linear_run):
    filt = FILTERS[name]
    state = filt.initial_state(linear_run.x0, linear_run.P0)
    np.testing.assert_allclose(state.covariance, linear_run.P0, **TOL)
    ref = kalman_reference(linear_model, linear_run)
    for k, (u, z) in enumerate(zip(linear_run.us, linear_run.zs, strict=True)):
        ref_prior, ref_post, ref_info = ref[k]
        state = filt.predict(state, linear_model, u, linear_run.dt)
        np.testing.assert_allclose(state.x, ref_prior.x, **TOL, err_msg=f"prior x, step {k}")
        np.testing.assert_allclose(state.covariance, ref_prior.P, **TOL, err_msg=f"prior P, step {k}")
        state, info = filt.update(state, z, linear_model, u)
        assert info.accepted
        np.testing.assert_allclose(state.x, ref_post.x, **TOL, err_msg=f"post x, step {k}")
        np.testing.assert_allclose(state.covariance, ref_post.P, **TOL, err_msg=f"post P, step {k}")
        np.testing.assert_allclose(info.innovation, ref_info.innovation, **TOL)
        np.testing.assert_allclose(info.innovation_cov, ref_info.innovation_cov, **TOL)
        assert info.nis == pytest.approx(ref_info.nis, rel=1e-9, abs=1e-9)


def test_covariance_stays_in_checked_range(linear_model, linear_run):
    """Guards the meaning of the absolute part of TOL (see module docstring)."""
    for prior, post, _ in kalman_reference(linear_model, linear_run):
        for P in (prior.P, post.P):
            w = np.linalg.eigvalsh(P)
            assert 1e-4 < w.min() and w.max() < 10.0
