"""The consistency statistics (analysis/consistency.py) on data whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from terrain_estimation.analysis.consistency import (
    chi2_mean_band,
    consistency_report,
    integrated_autocorrelation_time,
    nees,
    window_share,
)


def test_band_of_a_mean_of_chi2_values() -> None:
    lo, hi = chi2_mean_band(3, 1)
    assert lo == pytest.approx(0.2158, abs=1e-3) and hi == pytest.approx(9.348, abs=1e-3)
    lo, hi = chi2_mean_band(3, 200)
    assert 2.6 < lo < 3.0 < hi < 3.4


def test_nees_of_known_errors() -> None:
    P = np.array([[[4.0, 0.0], [0.0, 1.0]]])
    assert nees([[2.0, 1.0]], P)[0] == pytest.approx(2.0)
    assert nees([3.0], [9.0])[0] == pytest.approx(1.0)


def test_autocorrelation_time_of_white_and_ar1_data() -> None:
    rng = np.random.default_rng(1)
    white = rng.standard_normal(20000)
    assert integrated_autocorrelation_time(white) == pytest.approx(1.0, abs=0.15)
    phi = 0.9  # AR(1): tau = (1 + phi) / (1 - phi) = 19
    ar = np.zeros(50000)
    for k in range(1, ar.size):
        ar[k] = phi * ar[k - 1] + white[k % white.size]
    assert integrated_autocorrelation_time(ar) == pytest.approx(19.0, rel=0.2)


def _ar_errors(rng: np.random.Generator, n: int, phi: float, sigma: float) -> np.ndarray:
    w = rng.standard_normal(n) * sigma * np.sqrt(1 - phi**2)
    e = np.zeros(n)
    e[0] = sigma * rng.standard_normal()
    for k in range(1, n):
        e[k] = phi * e[k - 1] + w[k]
    return e


def test_a_consistent_filter_passes_and_an_overconfident_one_fails() -> None:
    """Correlated errors with the right variance sit in their bands; the same errors claimed 3x smaller do not."""
    rng = np.random.default_rng(7)
    n, sigmas = 6000, (0.1, 0.05, 0.01)
    t = np.arange(n) * 0.01
    e = np.column_stack([_ar_errors(rng, n, 0.95, s) for s in sigmas])
    P = np.tile(np.diag(np.square(sigmas)), (n, 1, 1))
    rep = consistency_report(t, e, P, ("vx", "vy", "r"))
    assert rep.mean_nees == pytest.approx(3.0, rel=0.25)
    assert rep.nees_windows.share >= 0.85 and rep.nees_windows.tau > 5
    for q in rep.quantities:
        assert q.mean_normalised == pytest.approx(1.0, rel=0.35)
        assert 0.88 < q.within_2sigma <= 1.0
    over = consistency_report(t, e, P / 9.0, ("vx", "vy", "r"))
    assert over.nees_windows.share < 0.3 and over.nees_windows.above > 0
    assert over.quantity("vy").within_2sigma < 0.7


def test_white_nis_in_band_and_inflated_nis_out() -> None:
    rng = np.random.default_rng(3)
    t = np.arange(20000) * 0.01
    good = rng.chisquare(3, t.size)
    share = window_share(good, t, 3)
    assert share.windows == 99 and share.share >= 0.88
    assert window_share(0.2 * good, t, 3).below == share.windows  # a filter 5x too cautious
    with pytest.raises(ValueError, match="window"):
        window_share(good, t, 3, window=0.0)
