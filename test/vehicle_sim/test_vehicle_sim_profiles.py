"""Road profiles: exact analytic h and dh/ds, ISO 8608 PSD (MODELS.md A.8)."""

import numpy as np
import pytest

from vehicle_sim.terrain.profiles import (
    DEFAULT_BAND,
    ISO8608_CLASSES,
    ISO8608_GD_N0,
    ISO8608_N0,
    HarmonicProfile,
    check_iso8608_psd,
    fit_iso8608,
    flat_profile,
    iso8608_class_of,
    iso8608_class_range,
    iso8608_profile,
    meadow_c_standin,
    power_law_profile,
    sinusoidal_profile,
)

SEEDS = (11, 12, 13, 14)


def test_class_table():
    assert ISO8608_GD_N0["A"] == pytest.approx(16e-6)
    assert ISO8608_GD_N0["D"] == pytest.approx(1024e-6)
    assert ISO8608_GD_N0["H"] == pytest.approx(262144e-6)
    assert iso8608_class_range("D") == pytest.approx((512e-6, 2048e-6))
    assert iso8608_class_range("A")[0] == 0.0
    assert iso8608_class_range("H")[1] == np.inf
    assert iso8608_class_of(1024e-6) == "D"
    assert iso8608_class_of(2047e-6) == "D"
    assert iso8608_class_of(2049e-6) == "E"
    assert iso8608_class_of(1e-9) == "A"
    assert iso8608_class_of(1.0) == "H"
    with pytest.raises(ValueError):
        iso8608_profile("Z", 0)


def test_slope_is_derivative_of_elevation():
    profile = iso8608_profile("D", seed=3)
    s = np.linspace(0.0, 80.0, 401)
    ds = 1e-5
    numeric = (profile.elevation(s + ds) - profile.elevation(s - ds)) / (2 * ds)
    slope = profile.slope(s)
    np.testing.assert_allclose(numeric, slope, atol=1e-6 * np.abs(slope).max())


def test_uniform_grid_evaluation_matches_direct():
    profile = iso8608_profile("F", seed=4)
    for start, spacing, count in [(12.345, 0.005, 21), (1000.0, 0.01, 700), (3.0, 0.0, 5)]:
        s = start + spacing * np.arange(count)
        h_direct, dh_direct = profile.elevation_and_slope(s)
        h_grid, dh_grid = profile.evaluate_uniform(start, spacing, count)
        np.testing.assert_allclose(h_grid, h_direct, rtol=0, atol=1e-13)
        np.testing.assert_allclose(dh_grid, dh_direct, rtol=0, atol=1e-11)


def test_shape_is_preserved():
    profile = iso8608_profile("B", seed=1)
    s = np.linspace(0, 10, 12).reshape(3, 4)
    assert profile.elevation(s).shape == (3, 4)
    assert profile.slope(s).shape == (3, 4)
    assert np.ndim(profile.elevation(2.0)) == 0


def test_log_grid_variance_equals_band_integral():
    # Bin amplitudes integrate G_d exactly: Σ A²/2 = G0 n0² (1/n_min − 1/n_max) for w = 2.
    profile = iso8608_profile("D", seed=5)
    n_min, n_max = DEFAULT_BAND
    expected = ISO8608_GD_N0["D"] * ISO8608_N0**2 * (1 / n_min - 1 / n_max)
    assert profile.rms_elevation**2 == pytest.approx(expected, rel=1e-12)
    assert profile.spatial_frequencies.min() >= n_min
    assert profile.spatial_frequencies.max() <= n_max
    assert profile.n_harmonics == 2000


def test_seeded_and_reproducible():
    s = np.linspace(0, 50, 100)
    a = iso8608_profile("D", seed=9).elevation(s)
    b = iso8608_profile("D", seed=9).elevation(s)
    c = iso8608_profile("D", seed=10).elevation(s)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


@pytest.mark.parametrize("road_class", ["B", "D", "F", "G"])
def test_iso_class_psd_welch_averaged_over_seeds(road_class):
    checks = [check_iso8608_psd(iso8608_profile(road_class, seed), road_class) for seed in SEEDS]
    mean_psd = np.mean([check.psd for check in checks], axis=0)
    gd_n0, waviness = fit_iso8608(checks[0].spatial_frequency, mean_psd, checks[0].band)
    assert iso8608_class_of(gd_n0) == road_class
    assert gd_n0 == pytest.approx(ISO8608_GD_N0[road_class], rel=0.15)
    assert waviness == pytest.approx(2.0, abs=0.1)
    assert all(check.within_class for check in checks)


@pytest.mark.parametrize("road_class", ISO8608_CLASSES)
def test_every_class_realisation_within_its_range(road_class):
    check = check_iso8608_psd(iso8608_profile(road_class, seed=21), road_class, length=500.0)
    assert check.within_class, (check.gd_n0, check.road_class)


def test_psd_has_no_content_above_band():
    profile = iso8608_profile("D", seed=2, band=(0.05, 2.0))
    check = check_iso8608_psd(profile, "D", spacing=0.05)
    n, g = check.spatial_frequency, check.psd
    in_band = g[(n > 0.5) & (n < 1.5)].mean()
    above = g[(n > 4.0) & (n < 9.0)].mean()
    assert above < 1e-4 * in_band


def test_uniform_spacing_is_agostinacchio_grid_and_periodic():
    length = 200.0
    profile = iso8608_profile("D", seed=6, spacing="uniform", length=length)
    n = profile.spatial_frequencies
    np.testing.assert_allclose(np.diff(n), 1 / length)
    assert n[0] == pytest.approx(0.05)
    np.testing.assert_allclose(profile.amplitudes, np.sqrt(2 * ISO8608_GD_N0["D"] * (n / ISO8608_N0) ** -2 / length))
    s = np.linspace(0, 30, 50)
    np.testing.assert_allclose(profile.elevation(s + length), profile.elevation(s), atol=1e-12)
    check = check_iso8608_psd(profile, "D", length=length)
    assert check.within_class
    with pytest.raises(ValueError, match="length"):
        iso8608_profile("D", seed=6, spacing="uniform")


def test_meadow_c_standin_is_class_e():
    profile = meadow_c_standin(seed=7)
    assert profile.name == "meadow_c_standin"
    assert "stand-in" in profile.description
    assert check_iso8608_psd(profile, "E").within_class


def test_flat_and_sinusoid():
    flat = flat_profile()
    assert np.all(flat.elevation(np.arange(5.0)) == 0.0)
    h, dh = flat.evaluate_uniform(0.0, 0.1, 4)
    assert h.shape == dh.shape == (4,)
    sine = sinusoidal_profile(0.02, 4.0, phase=0.3)
    s = np.array([0.0, 1.0, 2.5])
    np.testing.assert_allclose(sine.elevation(s), 0.02 * np.cos(2 * np.pi * s / 4 + 0.3))
    np.testing.assert_allclose(sine.slope(s), -0.02 * 2 * np.pi / 4 * np.sin(2 * np.pi * s / 4 + 0.3))


def test_invalid_arguments():
    with pytest.raises(ValueError):
        power_law_profile(1e-3, 0, band=(1.0, 0.5))
    with pytest.raises(ValueError):
        power_law_profile(1e-3, 0, spacing="cubic")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        HarmonicProfile([1.0, 2.0], [1.0], [0.0, 0.0])
