"""Filters against each other and against filterpy on a nonlinear model.

Tolerance: ``assert_allclose(rtol=1e-9, atol=1e-9)`` on means and covariances
(entries are O(1e-3…1)).
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints as FilterpyPoints
from filterpy.kalman import UnscentedKalmanFilter as FilterpyUKF

from terrain_estimation.filters import (
    CubatureKalmanFilter,
    ExtendedKalmanFilter,
    SqrtGaussianState,
    SquareRootCubatureKalmanFilter,
    UnscentedKalmanFilter,
)

TOL = {"rtol": 1e-9, "atol": 1e-9}


@pytest.mark.parametrize(("alpha", "beta", "kappa"), [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0)])
def test_ukf_matches_filterpy(pendulum_model, pendulum_run, alpha, beta, kappa):
    """Same sigma points, same model, 20 steps: filterpy's UKF (per-point loop,
    redraw after predict, ``P − K S Kᵀ``) and ours agree."""
    m, run = pendulum_model, pendulum_run
    points = FilterpyPoints(3, alpha=alpha, beta=beta, kappa=kappa)
    fp = FilterpyUKF(
        dim_x=3,
        dim_z=2,
        dt=run.dt,
        hx=lambda x, u: m.h(x, u),
        fx=lambda x, dt, u: m.f(x, u, dt),
        points=points,
    )
    fp.x, fp.P = run.x0.copy(), run.P0.copy()
    fp.Q, fp.R = m.Lq @ m.Lq.T, m.Lr @ m.Lr.T

    ukf = UnscentedKalmanFilter(alpha=alpha, beta=beta, kappa=kappa)
    np.testing.assert_array_equal(ukf.point_set(3).Wm, points.Wm)
    np.testing.assert_array_equal(ukf.point_set(3).Wc, points.Wc)
    state = ukf.initial_state(run.x0, run.P0)
    for k in range(20):
        u, z = run.us[k], run.zs[k]
        fp.predict(u=u)
        state = ukf.predict(state, m, u, run.dt)
        np.testing.assert_allclose(state.x, fp.x, **TOL, err_msg=f"prior x, step {k}")
        np.testing.assert_allclose(state.P, fp.P, **TOL, err_msg=f"prior P, step {k}")
        fp.update(z, u=u)
        state, info = ukf.update(state, z, m, u)
        np.testing.assert_allclose(info.innovation, fp.y, **TOL)
        np.testing.assert_allclose(info.innovation_cov, fp.S, **TOL)
        np.testing.assert_allclose(state.x, fp.x, **TOL, err_msg=f"post x, step {k}")
        np.testing.assert_allclose(state.P, fp.P, **TOL, err_msg=f"post P, step {k}")


def run_filter(filt, model, run, steps=None):
    state = filt.initial_state(run.x0, run.P0)
    out = []
    for u, z in list(zip(run.us, run.zs, strict=True))[:steps]:
        prior = filt.predict(state, model, u, run.dt)
        state, info = filt.update(prior, z, model, u)
        out.append((prior, state, info))
    return out


def test_sckf_equals_ckf_on_nonlinear_model(pendulum_model, pendulum_run):
    """Eqs. 14–28 are the CKF in square-root form: same mean and covariance."""
    ckf = run_filter(CubatureKalmanFilter(), pendulum_model, pendulum_run)
    sckf = run_filter(SquareRootCubatureKalmanFilter(), pendulum_model, pendulum_run)
    for k, ((cp, cs, ci), (sp, ss, si)) in enumerate(zip(ckf, sckf, strict=True)):
        assert isinstance(ss, SqrtGaussianState)
        np.testing.assert_allclose(sp.x, cp.x, **TOL, err_msg=f"prior x, step {k}")
        np.testing.assert_allclose(sp.covariance, cp.P, **TOL, err_msg=f"prior P, step {k}")
        np.testing.assert_allclose(ss.x, cs.x, **TOL, err_msg=f"post x, step {k}")
        np.testing.assert_allclose(ss.covariance, cs.P, **TOL, err_msg=f"post P, step {k}")
        np.testing.assert_allclose(si.innovation_cov, ci.innovation_cov, **TOL)
        assert si.nis == pytest.approx(ci.nis, rel=1e-9)
        S_z = si.extras["innovation_cov_sqrt"]
        np.testing.assert_allclose(S_z @ S_z.T, si.innovation_cov, **TOL)


def test_sckf_factor_is_lower_triangular_and_finite(pendulum_model, pendulum_run):
    for prior, post, _ in run_filter(SquareRootCubatureKalmanFilter(), pendulum_model, pendulum_run):
        for S in (prior.S, post.S):
            assert np.isfinite(S).all()
            assert not np.triu(S, 1).any(), "exact zeros above the diagonal"
            assert (np.diagonal(S) >= 0.0).all()


def test_ukf_with_zero_centre_weight_is_the_ckf(pendulum_model, pendulum_run):
    """α = 1, β = 0, κ = 0 gives λ = 0: centre weight 0, the other points are ±√n S e_i."""
    ckf = run_filter(CubatureKalmanFilter(), pendulum_model, pendulum_run)
    ukf = run_filter(UnscentedKalmanFilter(alpha=1.0, beta=0.0, kappa=0.0), pendulum_model, pendulum_run)
    for (_, c, _), (_, u, _) in zip(ckf, ukf, strict=True):
        np.testing.assert_allclose(u.x, c.x, **TOL)
        np.testing.assert_allclose(u.P, c.P, **TOL)


@pytest.mark.parametrize(
    "filt",
    [
        ExtendedKalmanFilter(),
        UnscentedKalmanFilter(),
        CubatureKalmanFilter(),
        SquareRootCubatureKalmanFilter(),
    ],
    ids=["ekf", "ukf", "ckf", "sckf"],
)
def test_filters_track_the_pendulum(filt, pendulum_model, pendulum_run):
    """All four filters stay consistent-ish on the nonlinear run: symmetric PD
    covariance, and the final error within 3σ on every state."""
    out = run_filter(filt, pendulum_model, pendulum_run)
    for _, post, _ in out:
        P = post.covariance
        np.testing.assert_allclose(P, P.T, rtol=0, atol=1e-15)
        assert np.linalg.eigvalsh(P).min() > 0.0
    post = out[-1][1]
    err = post.x - pendulum_run.xs[-1]
    assert (np.abs(err) < 3.0 * np.sqrt(np.diagonal(post.covariance))).all()
