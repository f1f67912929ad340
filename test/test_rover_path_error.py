"""The contact angles' considered error from the path beyond the parabola and from the sinkage model (issue 21)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.estimators.rover_noise import ContactAngleBias, considered_variances
from terrain_estimation.estimators.rover_path_error import PathQuadratureError, sinkage_tilt_variance

NODES = np.array([-0.35, 0.0, 0.35])  # rear, middle, front wheel centres (m)
SIMPSON = np.array([1.0, 4.0, 1.0]) / 6.0
STEP = 0.003  # travel per estimator step (m), ≈ the rover's 1.35 cm/s at 5 Hz


def _trace(path: PathQuadratureError, gamma_at, distances) -> list[float]:
    """Feed exact contact angles γ(place) of the three wheels; returns the variance after each step."""
    out = []
    for s in distances:
        places = s + (NODES - NODES[0])
        out.append(path.update(float(s), gamma_at(places), np.zeros(3), NODES, SIMPSON))
    return out


def _simpson_error(slope, height, s: float) -> float:
    """The parabola's weighted tangent error on an analytic path (independent of the class's integration)."""
    places = s + (NODES - NODES[0])
    coef = np.polyfit(places - places.mean(), height(places), 2)
    fitted = np.polyval(np.polyder(coef), places - places.mean())
    return float(SIMPSON @ (np.arctan(slope(places)) - np.arctan(fitted)))


def test_path_error_is_simpsons_error_on_the_traced_profile() -> None:
    """A gentle wave (curvature < 1/l_w): after one wheelbase the variance follows the method's exact error."""
    amp, k = 0.1, 2.0 * math.pi / 1.2  # slope amplitude, wavenumber (curvature ≤ 0.52 m⁻¹)

    def slope(x):
        return amp * np.sin(k * x)

    def height(x):
        return -amp * np.cos(k * x) / k

    path = PathQuadratureError(memory=1.0, curvature_length=0.075)
    distances = np.arange(0.0, 1.5, STEP)
    out = _trace(path, lambda x: -np.arctan(slope(x)), distances)
    assert path.curvature is not None and path.curvature < 1.0 / 0.7
    assert not path.beyond_validity
    late = distances > 0.75
    expected = np.array([_simpson_error(slope, height, s) ** 2 for s in distances[late]])
    got = np.array(out)[late]
    # Exact estimates, but each sample's stated path error is subtracted: at most the exact error, close to it.
    assert np.all(got <= expected + 1e-12)
    assert np.sqrt(np.mean(got)) > 0.8 * np.sqrt(np.mean(expected))
    assert np.corrcoef(got, expected)[0, 1] > 0.9


def test_quartic_path_has_no_path_error() -> None:
    """Simpson's rule is exact for a cubic slope: a quartic path gives no error once traced."""
    path = PathQuadratureError(memory=1.0, curvature_length=0.075)
    out = _trace(path, lambda x: -np.arctan(0.05 * (x - 0.5) ** 3), np.arange(0.0, 1.2, STEP))
    assert max(out[-50:]) < 1e-9


def test_a_kink_passing_under_the_rover_gives_rms_a_sixth_of_its_slope_change() -> None:
    """A kink Δ between the wheels: errors from −Δ/3 to +Δ/6 as it passes, RMS Δ/6 (module docstring)."""
    delta = 0.02
    kink = 1.0

    def gamma_at(x):
        return -np.arctan(np.where(x < kink, 0.0, math.tan(delta)))

    path = PathQuadratureError(memory=1.0, curvature_length=0.075)
    distances = np.arange(0.0, 2.0, STEP)
    out = np.array(_trace(path, gamma_at, distances))
    passing = (distances > kink - 0.7 + 0.02) & (distances < kink - 0.02)  # the kink inside the span
    assert np.sqrt(np.mean(out[passing])) == pytest.approx(delta / 6.0, rel=0.1)
    assert np.max(out[distances > kink + 0.05]) < 1e-9  # the kink behind the rear wheel: no error


def test_sharp_bend_is_flagged_and_gets_at_least_the_kink_variance() -> None:
    """Curvature ≥ 1/l_w is beyond the method's validity: flagged, variance ≥ (slope change over the span / 6)²."""
    delta = 0.3

    def gamma_at(x):
        return -np.arctan(np.where(x < 1.0, 0.0, math.tan(delta)))

    path = PathQuadratureError(memory=1.0, curvature_length=0.075)
    distances = np.arange(0.0, 0.9, STEP)  # the bend 0.1 m ahead of the rear wheel at the end
    out = _trace(path, gamma_at, distances)
    assert path.beyond_validity
    assert path.curvature is not None and path.curvature * 0.7 >= 1.0
    assert out[-1] >= (delta / 6.0) ** 2 * 0.99
    before = path.variance
    assert path.update(float(distances[-1]), np.zeros(3), np.zeros(3), NODES, SIMPSON) == before  # no travel
    path.reset()
    assert path.variance == 0.0 and path.curvature is None and not path.beyond_validity


def test_profile_noise_is_subtracted() -> None:
    """Noisy estimates of a flat path, with their stated variance: the averaged variance stays ≈ 0."""
    rng = np.random.default_rng(5)
    sigma = 0.004
    path = PathQuadratureError(memory=25.0, curvature_length=0.075)
    out = []
    for s in np.arange(0.0, 3.0, STEP):
        out.append(path.update(float(s), sigma * rng.standard_normal(3), np.full(3, sigma**2), NODES, SIMPSON))
    assert np.mean(out[300:]) < 0.25 * sigma**2


def test_sinkage_tilt_is_the_front_rear_difference_over_the_wheelbase() -> None:
    """Equal spacing: Σ c_j (parabola slopes through ρ s)_j = ρ (s_front − s_rear)/l_w; a common depth: 0."""
    sink = np.array([0.018, 0.0145, 0.0136])
    var = sinkage_tilt_variance(NODES, sink, SIMPSON, 0.35)
    assert var == pytest.approx((0.35 * (sink[2] - sink[0]) / 0.7) ** 2, rel=1e-9)
    assert sinkage_tilt_variance(NODES, np.full(3, 0.02), SIMPSON, 0.35) == pytest.approx(0.0, abs=1e-20)
    assert sinkage_tilt_variance(NODES, sink, SIMPSON, 0.0) == 0.0
    with pytest.raises(ValueError, match="sinkage_relative_error"):
        ContactAngleBias(sinkage_relative_error=-0.1)


def test_model_variance_adds_to_the_floor_in_quadrature() -> None:
    gamma_var, load, load_var, pull, pull_var = (np.full(3, v) for v in (1e-6, 50.0, 1e-3, 2.0, 1e-2))
    bias = ContactAngleBias(sigma=0.003, from_repeat_pass=False)
    g, w, d = considered_variances(gamma_var, load, load_var, pull, pull_var, bias, 1.0, 4e-5)
    np.testing.assert_allclose(g, 1e-6 + 9e-6 + 4e-5)  # the repeat-pass 1.0 is ignored when switched off
    np.testing.assert_allclose(w, 1e-3 + 4.0 * 4.9e-5)
    np.testing.assert_allclose(d, 1e-2 + 2500.0 * 4.9e-5)
