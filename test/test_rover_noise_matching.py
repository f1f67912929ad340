"""The rover's innovation-matched noise scales on a stationary synthetic case (issue 21 follow-up).

:func:`~terrain_estimation.estimators.rover_noise.match_noise_scales` sets a
process-noise scale from past innovations only (the scale used at step k was
matched on ν_1 … ν_{k−1}) with a 1-s memory (forgetting 0.8). On a stationary
random walk seen through white noise — the model the matching assumes — the
scale must settle at the truth's and the innovations must then be as large as
their predicted S (mean ν²/S = 1), whatever the base the scale starts from: no
bias from the short memory (Jensen) nor from the Huber clip. The rover's
load cells ran ν²/S ≈ 0.92 on the 40-s runs for another reason (their W, DP
walks started from a base 3× the change per step and the matching needs tens
of seconds to come down; rover_noise, "Noise blocks").
"""

# ruff: noqa: N806 - matrix symbols of the literature

from __future__ import annotations

import numpy as np
import pytest

from terrain_estimation.estimators.rover_noise import NoiseBlock, NoiseMatchingConfig, match_noise_scales


def _matched_random_walk(base_q: float, true_q: float, r: float, steps: int, seed: int) -> tuple[float, float]:
    """Mean ν²/S and mean scale after a burn-in: a scalar random walk, one matched Q block."""
    rng = np.random.default_rng(seed)
    cfg = NoiseMatchingConfig()
    x, x_hat, P, s = 0.0, 0.0, 1.0, np.ones(1)
    ratios, scales = [], []
    for k in range(steps):
        x += rng.normal(0.0, np.sqrt(true_q))
        y = x + rng.normal(0.0, np.sqrt(r))
        q = float(s[0]) * base_q
        P_prior = P + q
        S = P_prior + r
        nu = y - x_hat
        if k >= steps // 5:
            ratios.append(nu * nu / S)
            scales.append(float(s[0]))
        s = match_noise_scales(s, [NoiseBlock("Q", np.array([[q]]))], np.array([nu]), np.array([[S]]), cfg)
        K = P_prior / S
        x_hat += K * nu
        P = (1.0 - K) * P_prior
    return float(np.mean(ratios)), float(np.exp(np.mean(np.log(scales))))


@pytest.mark.parametrize("base_over_true", [0.1, 1.0, 9.0])
def test_matched_scale_is_unbiased_on_a_stationary_random_walk(base_over_true: float) -> None:
    true_q, r = 0.0025, 1.0e-4  # the rover's cells: ≈ 0.05 N per step against a window noise of 0.01 N
    ratio, scale = _matched_random_walk(base_over_true * true_q, true_q, r, 20000, 7)
    # 16 000 counted steps: the mean of ν²/S has a standard error of ≈ 0.02 (correlated through the scale).
    assert ratio == pytest.approx(1.0, abs=0.06)
    # The scale's geometric mean lands at the truth's Q (in units of the base).
    assert scale * base_over_true == pytest.approx(1.0, rel=0.15)
