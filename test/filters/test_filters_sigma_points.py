"""Point sets, ``tria``, ``robust_sqrt`` and ``solve_lower``."""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints as FilterpyPoints
from scipy.linalg import solve_triangular

from terrain_estimation.filters import (
    CubaturePoints,
    MerweScaledSigmaPoints,
    cubature_points,
    merwe_scaled_sigma_points,
    robust_sqrt,
    tria,
)
from terrain_estimation.filters.sigma_points import solve_lower


def random_factor(rng, n):
    A = rng.standard_normal((n, n))
    return np.linalg.cholesky(A @ A.T + 0.1 * np.eye(n))


def test_cubature_points_definition():
    ps = cubature_points(3)
    assert isinstance(ps, CubaturePoints)
    assert ps.num_points == 6
    np.testing.assert_array_equal(ps.unit, np.sqrt(3) * np.vstack([np.eye(3), -np.eye(3)]))
    np.testing.assert_array_equal(ps.Wm, np.full(6, 1 / 6))
    np.testing.assert_array_equal(ps.Wc, ps.Wm)
    assert cubature_points(3) is ps, "cached per n"
    with pytest.raises(ValueError):
        ps.Wm[0] = 1.0  # read-only: a shared cached set must not be corrupted


@pytest.mark.parametrize("factory", [cubature_points, merwe_scaled_sigma_points])
@pytest.mark.parametrize("n", [1, 2, 5])
def test_points_reproduce_mean_and_covariance(factory, n):
    rng = np.random.default_rng(n)
    mean = rng.standard_normal(n)
    S = random_factor(rng, n)
    ps = factory(n)
    X = ps.sigma_points(mean, S)
    assert X.shape == (ps.num_points, n)
    np.testing.assert_allclose(ps.Wm.sum(), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(ps.Wm @ X, mean, rtol=0, atol=1e-13)
    D = X - mean
    np.testing.assert_allclose((D.T * ps.Wc) @ D, S @ S.T, rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize(("alpha", "beta", "kappa"), [(1.0, 2.0, 0.0), (0.3, 2.0, 1.0), (1e-3, 2, 0)])
def test_merwe_points_match_filterpy(alpha, beta, kappa):
    rng = np.random.default_rng(3)
    n = 4
    mean = rng.standard_normal(n)
    S = random_factor(rng, n)
    ours = merwe_scaled_sigma_points(n, alpha, beta, kappa)
    assert isinstance(ours, MerweScaledSigmaPoints)
    theirs = FilterpyPoints(n, alpha=alpha, beta=beta, kappa=kappa)
    np.testing.assert_allclose(ours.Wm, theirs.Wm, rtol=1e-14)
    np.testing.assert_allclose(ours.Wc, theirs.Wc, rtol=1e-14)
    np.testing.assert_allclose(ours.sigma_points(mean, S), theirs.sigma_points(mean, S @ S.T), rtol=1e-10, atol=1e-12)


def test_merwe_weights_formula():
    ps = merwe_scaled_sigma_points(3, 0.5, 2.0, 0.0)
    lam = 0.25 * 3 - 3
    assert ps.Wm[0] == pytest.approx(lam / (3 + lam))
    assert ps.Wc[0] == pytest.approx(lam / (3 + lam) + 1 - 0.25 + 2)
    np.testing.assert_allclose(ps.Wm[1:], 1 / (2 * (3 + lam)))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n": 0}, "n must be"),
        ({"n": 3, "alpha": 0.0}, "alpha"),
        ({"n": 3, "beta": float("nan")}, "beta"),
        ({"n": 3, "kappa": -3.0}, "kappa"),
    ],
)
def test_merwe_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        merwe_scaled_sigma_points(**kwargs)


def test_sigma_points_check_shapes():
    ps = cubature_points(2)
    with pytest.raises(ValueError, match="mean"):
        ps.sigma_points(np.zeros(3), np.eye(2))
    with pytest.raises(ValueError, match="sqrt_cov"):
        ps.sigma_points(np.zeros(2), np.eye(3))


@pytest.mark.parametrize(("n", "k"), [(4, 9), (4, 4), (4, 2)])
def test_tria_is_a_lower_triangular_factor(n, k):
    rng = np.random.default_rng(k)
    A = rng.standard_normal((n, k))
    S = tria(A)
    assert S.shape == (n, n)
    assert not np.triu(S, 1).any()
    assert (np.diagonal(S) >= 0).all()
    np.testing.assert_allclose(S @ S.T, A @ A.T, rtol=1e-12, atol=1e-14)


def test_tria_of_a_cholesky_factor_is_itself():
    S = random_factor(np.random.default_rng(0), 5)
    np.testing.assert_allclose(tria(S), S, rtol=1e-12, atol=1e-14)


def test_robust_sqrt_positive_definite_is_cholesky():
    S = random_factor(np.random.default_rng(1), 4)
    np.testing.assert_array_equal(robust_sqrt(S @ S.T), np.linalg.cholesky(S @ S.T))


def test_robust_sqrt_projects_singular_and_indefinite():
    rng = np.random.default_rng(2)
    V = np.linalg.qr(rng.standard_normal((4, 4)))[0]
    P_singular = V @ np.diag([2.0, 1.0, 0.0, 0.0]) @ V.T
    S = robust_sqrt(P_singular)
    assert not np.triu(S, 1).any()
    np.testing.assert_allclose(S @ S.T, P_singular, atol=1e-12)
    P_indefinite = V @ np.diag([2.0, 1.0, 0.5, -1e-3]) @ V.T
    S = robust_sqrt(P_indefinite)
    np.testing.assert_allclose(S @ S.T, V @ np.diag([2.0, 1.0, 0.5, 0.0]) @ V.T, atol=1e-12)


@pytest.mark.parametrize("transpose", [False, True])
@pytest.mark.parametrize("shape", [(3,), (3, 5)])
def test_solve_lower_equals_scipy_solve_triangular(transpose, shape):
    rng = np.random.default_rng(4)
    L = random_factor(rng, 3)
    B = rng.standard_normal(shape)
    expected = solve_triangular(L, B, lower=True, trans="T" if transpose else "N")
    got = solve_lower(L, B, transpose=transpose)
    assert got.shape == B.shape
    np.testing.assert_allclose(got, expected, rtol=1e-14, atol=1e-15)
