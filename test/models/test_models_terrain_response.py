"""2-D polynomial terrain-response model ([RB] II-E, MODELS.md C.2, C.7)."""

import numpy as np
import pytest

from terrain_estimation.models.terrain_response import (
    PolynomialModel2D,
    ValidityRegion,
    coefficient_count,
    design_matrix,
    fit_polynomial_2d,
    order_from_coefficient_count,
    polynomial_exponents,
)


def operating_samples(n: int = 60, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Scattered (i, W) in the estimator's operating range (MODELS.md C.2: 35 ≤ W ≤ 70 N)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(0.0, 0.4, n), rng.uniform(35.0, 70.0, n)


def test_coefficient_order_is_the_messages():
    # TerrainResponseModel.msg: for d = 0..order, for k = d..0: i^k W^(d−k).
    assert polynomial_exponents(2) == ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))
    assert polynomial_exponents(0) == ((0, 0),)
    exponents = polynomial_exponents(4)
    assert len(exponents) == coefficient_count(4) == 15
    assert exponents[6:10] == ((3, 0), (2, 1), (1, 2), (0, 3))
    i, w = 0.3, 50.0
    np.testing.assert_allclose(design_matrix(i, w, 2)[0], [1.0, i, w, i**2, i * w, w**2], rtol=1e-15)
    assert PolynomialModel2D(order=3, coefficients=[0.0] * 10).exponents == polynomial_exponents(3)


def test_order_from_coefficient_count():
    for order in range(7):
        assert order_from_coefficient_count(coefficient_count(order)) == order
    for count in (0, 2, 4, 7, 11):
        with pytest.raises(ValueError):
            order_from_coefficient_count(count)
    model = PolynomialModel2D.from_coefficients(np.arange(6.0))
    assert model.order == 2
    with pytest.raises(ValueError):
        PolynomialModel2D(order=2, coefficients=(1.0, 2.0))


def test_evaluate_is_the_sum_of_terms():
    rng = np.random.default_rng(0)
    coefficients = rng.normal(size=15)
    model = PolynomialModel2D(order=4, coefficients=coefficients)
    i, w = rng.uniform(-1, 1, 50), rng.uniform(0.1, 200.0, 50)
    np.testing.assert_allclose(model.evaluate(i, w), design_matrix(i, w, 4) @ coefficients, rtol=1e-12)
    # Broadcasting: a grid from row and column vectors.
    grid = model.evaluate(i[:5, None], w[None, :7])
    assert grid.shape == (5, 7)
    assert grid[2, 3] == pytest.approx(float(model.evaluate(i[2], w[3])), rel=1e-14)


@pytest.mark.parametrize(("order", "load_range"), [(2, (35.0, 70.0)), (4, (0.1, 200.0))])
def test_fit_reproduces_an_exact_polynomial(order, load_range):
    rng = np.random.default_rng(order)
    # Coefficients of realistic size for each term (W up to 200 N, W⁴ up to 1.6e9).
    exponents = polynomial_exponents(order)
    true = np.array([rng.normal() * 10.0 / load_range[1] ** m for _, m in exponents])
    truth = PolynomialModel2D(order=order, coefficients=true)
    i = rng.uniform(0.0, 1.0, 400)
    w = rng.uniform(*load_range, 400)
    fit, rms = fit_polynomial_2d(i, w, truth.evaluate(i, w), order)
    assert fit.order == order
    np.testing.assert_allclose(fit.evaluate(i, w), truth.evaluate(i, w), rtol=0, atol=1e-9)
    np.testing.assert_allclose(fit.coefficients, true, rtol=1e-9)
    assert rms < 1e-9


def test_fit_returns_raw_coefficients_in_message_order():
    i, w = operating_samples()
    values = 0.5 - 2.0 * i + 0.01 * w + 3.0 * i**2 - 0.02 * i * w + 1e-4 * w**2
    fit, _ = fit_polynomial_2d(i, w, values, 2)
    np.testing.assert_allclose(fit.coefficients, [0.5, -2.0, 0.01, 3.0, -0.02, 1e-4], rtol=1e-9, atol=1e-12)


def test_weights_multiply_squared_residuals():
    i, w = operating_samples(40)
    rng = np.random.default_rng(11)
    values = 1.0 + 2.0 * i - 0.01 * w + rng.normal(0.0, 0.3, i.size)
    counts = rng.integers(1, 4, i.size)
    # Integer weights = repeated samples.
    weighted, weighted_rms = fit_polynomial_2d(i, w, values, 2, weights=counts)
    repeated, repeated_rms = fit_polynomial_2d(np.repeat(i, counts), np.repeat(w, counts), np.repeat(values, counts), 2)
    np.testing.assert_allclose(weighted.coefficients, repeated.coefficients, rtol=1e-9, atol=1e-12)
    assert weighted_rms == pytest.approx(repeated_rms, rel=1e-9)
    plain, _ = fit_polynomial_2d(i, w, values, 2)
    assert not np.allclose(plain.coefficients, weighted.coefficients, rtol=1e-6)
    # Zero weight removes an outlier, also from the validity region.
    i_out, w_out = np.append(i, 0.9), np.append(w, 150.0)
    values_out = np.append(values, 1e3)
    cleaned, _ = fit_polynomial_2d(i_out, w_out, values_out, 2, weights=np.append(np.ones(i.size), 0.0))
    np.testing.assert_allclose(cleaned.coefficients, plain.coefficients, rtol=1e-9, atol=1e-12)
    assert cleaned.validity is not None
    assert cleaned.validity.load_max == pytest.approx(w.max())
    with pytest.raises(ValueError):
        fit_polynomial_2d(i, w, values, 2, weights=-np.ones(i.size))


def test_fit_rms_and_validity_region():
    i, w = operating_samples()
    values = np.sin(3.0 * i) * w / 50.0
    model, rms = fit_polynomial_2d(i, w, values, 2)
    residual = model.evaluate(i, w) - values
    assert rms == pytest.approx(float(np.sqrt(np.mean(residual**2))), rel=1e-12)
    assert rms > 0.0
    assert model.validity == ValidityRegion(slip_min=i.min(), slip_max=i.max(), load_min=w.min(), load_max=w.max())
    inside = model.validity.contains(np.array([i.mean(), i.max() + 0.01, i.mean()]), np.array([50.0, 50.0, 20.0]))
    np.testing.assert_array_equal(inside, [True, False, False])


def test_rank_deficient_data_is_rejected():
    w = np.linspace(35.0, 70.0, 30)
    with pytest.raises(ValueError, match="rank"):
        fit_polynomial_2d(np.full(30, 0.2), w, w, 2)  # one slip value cannot fix i² terms
    with pytest.raises(ValueError):
        fit_polynomial_2d([0.1, 0.2], [40.0, 50.0], [1.0, 2.0], 2)  # fewer samples than terms
    with pytest.raises(ValueError):
        fit_polynomial_2d([0.1, np.nan, 0.3], [40.0, 50.0, 60.0], [1.0, 2.0, 3.0], 0)
