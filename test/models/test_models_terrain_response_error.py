"""The terrain-response model's stated error (issue 21, item 3): jackknife covariance, held-out error, bounded steps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.models.terrain_response import PolynomialModel2D, design_matrix, fit_polynomial_2d
from terrain_estimation.models.terrain_response_error import (
    block_labels,
    bounded_update,
    mahalanobis_distance,
    model_variance,
    validated_fit,
)

# The paper's local DP model (Table VI), used as an exact truth here.
DP_TRUE = PolynomialModel2D(order=2, coefficients=(-4.17, 31.5, -0.032, -38.8, 0.274, -1.66e-4))


def _track(rng: np.random.Generator, periods: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(period stamp, slip, load) of three wheels per 2-s period: slow sweeps with the rover's three W bands."""
    t = 2.0 * np.arange(periods)
    phase = rng.uniform(0.0, 2.0 * math.pi)
    slip = 0.2 + 0.12 * np.sin(0.04 * t[:, None] + phase + np.array([0.0, 0.7, 1.4]))
    load = np.array([62.0, 45.0, 39.0]) + 3.0 * np.sin(0.07 * t[:, None] + np.array([0.3, 1.0, 2.0]))
    return np.repeat(t, 3), slip.ravel(), load.ravel()


def _region_error(model: PolynomialModel2D, n: int = 25) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    region = model.validity
    assert region is not None
    ii, ww = np.meshgrid(
        np.linspace(region.slip_min, region.slip_max, n),
        np.linspace(region.load_min, region.load_max, n),
        indexing="ij",
    )
    return ii.ravel(), ww.ravel(), model.evaluate(ii.ravel(), ww.ravel()) - DP_TRUE.evaluate(ii.ravel(), ww.ravel())


def test_block_labels_are_contiguous_and_keep_periods_together() -> None:
    groups = np.array([4.0, 0.0, 0.0, 2.0, 2.0, 6.0, 8.0, 8.0, 4.0])
    labels = block_labels(groups, 2)
    assert set(labels.tolist()) == {0, 1}
    order = np.argsort(groups, kind="stable")
    assert np.all(np.diff(labels[order]) >= 0)  # contiguous in the period order
    for g in np.unique(groups):
        assert len(set(labels[groups == g].tolist())) == 1  # a period is never split
    assert block_labels(groups, 100).max() == 4  # at most one block per period


def test_mahalanobis_distance_matches_the_direct_formula() -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(size=(6, 6))
    cov = a @ a.T + 0.1 * np.eye(6)
    delta = rng.normal(size=6)
    assert mahalanobis_distance(delta, cov) == pytest.approx(math.sqrt(delta @ np.linalg.solve(cov, delta)), rel=1e-9)
    assert mahalanobis_distance(np.array([0.0, 1.0]), np.diag([1.0, 0.0])) == math.inf


def test_jackknife_covariance_and_holdout_match_the_spread_on_independent_noise() -> None:
    """White noise: the stated σ of the model's value agrees with its spread over 150 noise draws."""
    noise = 0.3
    rng = np.random.default_rng(11)
    t, slip, load = _track(rng, 60)
    points = (np.array([0.15, 0.25, 0.2]), np.array([45.0, 60.0, 40.0]))
    values, stated, holdout, residual = [], [], [], []
    for _ in range(150):
        y = DP_TRUE.evaluate(slip, load) + rng.normal(0.0, noise, slip.size)
        fit = validated_fit(slip, load, y, 2, groups=t)
        assert fit.jackknife and fit.blocks == 10 and fit.validation_samples == slip.size
        values.append(fit.model.evaluate(*points))
        stated.append(np.sqrt(model_variance(2, fit.covariance, *points)))
        holdout.append(fit.holdout_rms)
        residual.append(fit.rms)
    spread = np.std(np.array(values), axis=0)
    # Both stated variances carry the small-sample factor ν/(ν − 2) = 9/7 of 10 blocks (σ × 1.13).
    t_factor = math.sqrt(9 / 7)
    np.testing.assert_allclose(np.mean(np.array(stated), axis=0), t_factor * spread, rtol=0.2)
    assert 1.0 < np.mean(holdout) / (t_factor * noise) < 1.1  # the held-out error is the noise, not less
    assert np.mean(residual) < noise < np.mean(holdout)  # the residual understates it


def test_stated_error_covers_a_slowly_varying_estimation_error() -> None:
    """Errors correlated over many periods (a slowly drifting bias): the residual understates the model error,
    the validated prediction RMS covers it."""
    rng = np.random.default_rng(5)
    covered_stated = covered_residual = within = 0
    runs = 60
    for _ in range(runs):
        t, slip, load = _track(rng, 60)
        # AR(1) error per wheel over the periods, ρ = 0.95, 0.4 N stationary σ.
        e = np.zeros((60, 3))
        for k in range(1, 60):
            e[k] = 0.95 * e[k - 1] + 0.4 * math.sqrt(1 - 0.95**2) * rng.normal(size=3)
        y = DP_TRUE.evaluate(slip, load) + e.ravel()
        fit = validated_fit(slip, load, y, 2, groups=t)
        ii, ww, err = _region_error(fit.model)
        true_rms = float(np.sqrt(np.mean(err**2)))
        covered_stated += true_rms <= fit.prediction_rms
        covered_residual += true_rms <= fit.rms
        within += float(np.mean(np.abs(err) <= 2.0 * fit.std(ii, ww)))
    assert covered_stated >= 0.75 * runs  # 52 of 60 (the residual: 32)
    assert covered_residual < covered_stated
    assert within / runs >= 0.85


def test_bounded_update_moves_at_most_max_jump_sigma() -> None:
    rng = np.random.default_rng(8)
    a = rng.normal(size=(6, 6))
    previous_cov = a @ a.T + 0.01 * np.eye(6)
    previous = rng.normal(size=6)
    fit = previous + 20.0 * rng.normal(size=6)
    fit_cov = 0.5 * previous_cov
    step = bounded_update(previous, previous_cov, fit, fit_cov, 1.0)
    assert step.limited and step.distance > 1.0
    delta = step.coefficients - previous
    assert mahalanobis_distance(delta, previous_cov) == pytest.approx(1.0, rel=1e-9)
    # Every coefficient and every linear combination (the model's value anywhere) within one previous σ.
    assert np.all(np.abs(delta) <= np.sqrt(np.diag(previous_cov)) * (1 + 1e-9))
    x = design_matrix(rng.uniform(0, 0.5, 200), rng.uniform(30, 70, 200), 2)
    assert np.all(np.abs(x @ delta) <= np.sqrt(np.einsum("nk,kl,nl->n", x, previous_cov, x)) * (1 + 1e-9))
    # The step not taken is stated: the covariance grows by o oᵀ.
    offset = fit - step.coefficients
    np.testing.assert_allclose(step.covariance, fit_cov + np.outer(offset, offset))
    # A small step, and the first model, pass unchanged.
    small = bounded_update(previous, previous_cov, previous + 1e-3 * np.diag(previous_cov) ** 0.5, fit_cov, 1.0)
    assert not small.limited and small.distance < 1.0
    first = bounded_update(None, None, fit, fit_cov, 1.0)
    np.testing.assert_array_equal(first.coefficients, fit)
    with pytest.raises(ValueError, match="max_jump"):
        bounded_update(previous, previous_cov, fit, fit_cov, 0.0)


def test_validated_fit_is_the_least_squares_fit_and_falls_back_without_blocks() -> None:
    rng = np.random.default_rng(2)
    t, slip, load = _track(rng, 12)
    y = DP_TRUE.evaluate(slip, load) + rng.normal(0.0, 0.2, slip.size)
    fit = validated_fit(slip, load, y, 2, groups=t)
    plain = fit_polynomial_2d(slip, load, y, 2)
    np.testing.assert_allclose(fit.model.coefficients, plain.model.coefficients)
    assert fit.rms == pytest.approx(plain.rms)
    cov = fit.covariance
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) >= -1e-12 * cov.max())
    assert fit.prediction_rms >= fit.holdout_rms > 0.0
    # One sample period: nothing can be held out; the classical covariance, residual-based error.
    one = validated_fit(slip, load, y, 2, groups=np.zeros(slip.size))
    assert not one.jackknife and one.validation_samples == 0 and one.blocks == 1
    assert one.holdout_rms > one.rms and np.all(np.isfinite(one.covariance))
    with pytest.raises(ValueError, match="max_blocks"):
        validated_fit(slip, load, y, 2, groups=t, max_blocks=1)


def test_a_bias_the_samples_share_is_stated_only_through_their_variances() -> None:
    """A per-wheel bias for the whole run reads as a W dependence (each wheel in its own load band): no hold-out
    sees it; the estimates' stated variance does."""
    rng = np.random.default_rng(9)
    with_variances = without = 0
    runs = 60
    for _ in range(runs):
        t, slip, load = _track(rng, 60)
        bias = np.tile(rng.normal(0.0, 0.5, 3), 60)
        y = DP_TRUE.evaluate(slip, load) + bias + rng.normal(0.0, 0.1, slip.size)
        stated = validated_fit(slip, load, y, 2, groups=t, sample_variances=np.full(slip.size, 0.5**2 + 0.1**2))
        blind = validated_fit(slip, load, y, 2, groups=t)
        assert stated.estimate_rms == pytest.approx(math.sqrt(0.26)) and blind.estimate_rms == 0.0
        _, _, err = _region_error(stated.model)
        true_rms = float(np.sqrt(np.mean(err**2)))
        with_variances += true_rms <= stated.prediction_rms
        without += true_rms <= blind.prediction_rms
    assert with_variances >= 0.75 * runs  # 49 of 60; without the variances 3
    assert without <= 0.5 * runs
