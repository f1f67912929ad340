"""Soil stiffness conversion, classifier and change detector (MODELS.md A.2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.models.soil import (
    SOIL_TABLE,
    CusumDetector,
    amplification_factor,
    clamp_k_tot,
    classify_soil,
    k_s_from_k_tot,
    k_tot_from_k_s,
    soil_stiffness_from_k_tot,
)

KT = 175e3

# Table 1 of [QC]: k_s, k_tot, k_t/(k_t − k_tot) with k_t = 175 kN/m
TABLE_1 = {
    "upland_sandy_loam": (218.1e3, 97.09e3, 2.25),
    "lete_sand": (2283.0e3, 162.54e3, 14.05),
    "rubicon_sandy_loam": (272.1e3, 106.50e3, 2.55),
    "north_gower_clayey_loam": (221.9e3, 97.84e3, 2.27),
    "graneville_loam": (651.1e3, 137.93e3, 4.72),
}


def test_table_is_data_and_complete() -> None:
    names = {c.name: c.k_s for c in SOIL_TABLE}
    for name, (k_s, _, _) in TABLE_1.items():
        assert names[name] == k_s
    assert names["lunar_regolith"] == 28.487e3


@pytest.mark.parametrize("name", sorted(TABLE_1))
def test_conversion_reproduces_table_1(name: str) -> None:
    k_s, k_tot, amp = TABLE_1[name]
    assert k_tot_from_k_s(k_s, KT) == pytest.approx(k_tot, rel=5e-4)
    assert k_s_from_k_tot(k_tot_from_k_s(k_s, KT), KT) == pytest.approx(k_s, rel=1e-12)
    assert amplification_factor(k_tot_from_k_s(k_s, KT), KT) == pytest.approx(amp, abs=0.006)


def test_lrv_regolith() -> None:
    assert k_tot_from_k_s(28.487e3, 15e3) == pytest.approx(9.826e3, rel=1e-3)


def test_clamp_keeps_k_s_finite() -> None:
    for k in (-1e9, -1.0, 0.0, KT, 2 * KT, np.inf, np.nan):
        k_s = k_s_from_k_tot(k, KT)
        assert np.isfinite(k_s) and k_s > 0
    assert clamp_k_tot(KT, KT) == pytest.approx(0.999 * KT)
    k_s, var = soil_stiffness_from_k_tot(KT * 2, np.nan, KT)
    assert np.isfinite(k_s) and np.isfinite(var) and var > 0
    arr = k_s_from_k_tot(np.array([1e4, 1e5]), KT)
    assert isinstance(arr, np.ndarray) and arr.shape == (2,)


@pytest.mark.parametrize("name", ["graneville_loam", "lete_sand", "upland_sandy_loam"])
def test_variance_propagation_matches_monte_carlo(name: str) -> None:
    _, k_tot, _ = TABLE_1[name]
    std = 1e-3 * k_tot  # small enough for first order to hold
    k_s, var = soil_stiffness_from_k_tot(k_tot, std**2, KT)
    assert var == pytest.approx(amplification_factor(k_tot, KT) ** 4 * std**2)
    rng = np.random.default_rng(42)
    samples = k_s_from_k_tot(rng.normal(k_tot, std, 400_000), KT)
    assert np.var(samples) == pytest.approx(var, rel=0.03)
    assert np.mean(samples) == pytest.approx(k_s, rel=1e-3)


@pytest.mark.parametrize("soil", SOIL_TABLE, ids=lambda c: c.name)
def test_classifier_picks_the_right_soil(soil) -> None:
    for bias in (0.97, 1.0, 1.03):
        k_s = soil.k_s * bias
        result = classify_soil(k_s, (0.01 * k_s) ** 2)
        if soil.name in ("upland_sandy_loam", "north_gower_clayey_loam"):
            # 1.7 % apart: either is right, the confidence says so
            assert result.name in ("upland_sandy_loam", "north_gower_clayey_loam")
            assert result.confidence < 0.75
        else:
            assert result.name == soil.name
            # Rubicon is only 20 % above Upland/North Gower (class spread 10 %)
            assert result.confidence > (0.6 if soil.name == "rubicon_sandy_loam" else 0.9)
        assert 0.0 <= result.confidence <= 1.0
        assert sum(result.probabilities) + result.unknown_probability == pytest.approx(1.0)
    exact = classify_soil(soil.k_s, 0.0)
    assert exact.name == soil.name or soil.name == "upland_sandy_loam"


def test_classifier_confidence_falls_with_uncertainty_and_distance() -> None:
    sharp = classify_soil(651.1e3, (10e3) ** 2)
    vague = classify_soil(651.1e3, (600e3) ** 2)
    far = classify_soil(20e6, (0.01 * 20e6) ** 2)
    between = classify_soil(float(np.sqrt(651.1e3 * 2283e3)), (1e3) ** 2)
    assert sharp.confidence > 0.95
    assert vague.confidence < sharp.confidence
    assert far.name == "lete_sand" and far.confidence < 0.05 and far.unknown_probability > 0.9
    assert between.confidence < 0.6
    bad = classify_soil(float("nan"), 1.0)
    assert bad.confidence == 0.0


def test_cusum_fires_on_a_step_and_not_on_a_stationary_run() -> None:
    rng = np.random.default_rng(7)
    det = CusumDetector(drift=1.0, threshold=50.0)
    stationary = rng.standard_normal(200_000)  # 33 min at 100 Hz
    assert not any(det.update(e) for e in stationary)
    det.reset()
    shifted = rng.standard_normal(400)
    shifted[200:] += 10.0  # a soil change: corrections of one sign, many σ
    alarms = [i for i, e in enumerate(shifted) if det.update(e)]
    assert alarms and 200 <= alarms[0] <= 210
    det.reset()
    down = rng.standard_normal(400)
    down[100:] -= 3.0
    alarms = [i for i, e in enumerate(down) if det.update(e)]
    assert alarms and 100 <= alarms[0] <= 140
    assert not det.update(float("nan"))
    with pytest.raises(ValueError):
        CusumDetector(threshold=0.0)


def _classify_reference(k_s, k_s_variance, table, class_log_std, unknown_weight, log_ks_range=(1e3, 1e8)):
    """classify_soil as first written (np.log of the table on every call, np.append, np.mean...)."""
    n = len(table)
    var_rel = float(k_s_variance) / (k_s * k_s)
    s2 = var_rel + class_log_std**2
    centres = np.log(np.array([c.k_s for c in table], dtype=float))
    log_post = -0.5 * (math.log(k_s) - centres) ** 2 / s2 - 0.5 * math.log(2.0 * math.pi * s2)
    log_post = log_post + math.log((1.0 - unknown_weight) / n)
    if unknown_weight > 0.0:
        width = math.log(log_ks_range[1]) - math.log(log_ks_range[0])
        log_post = np.append(log_post, math.log(unknown_weight) - math.log(width))
    post = np.exp(log_post - np.max(log_post))
    post /= post.sum()
    named = post[:n]
    best = int(np.argmax(named))
    return (
        table[best].name,
        float(named[best]),
        tuple(float(p) for p in named),
        (float(post[n]) if unknown_weight > 0.0 else 0.0),
    )


@pytest.mark.parametrize("unknown_weight", [0.0, 0.05, 0.5])
def test_classification_equals_its_first_form_bit_for_bit(unknown_weight):
    rng = np.random.default_rng(11)
    for table in (SOIL_TABLE, list(SOIL_TABLE[:3])):  # a list is accepted too
        for k_s, rel_std in zip(10 ** rng.uniform(3.5, 7.5, 300), 10 ** rng.uniform(-4, 0.5, 300), strict=True):
            got = classify_soil(k_s, (rel_std * k_s) ** 2, table, 0.1, unknown_weight)
            ref = _classify_reference(k_s, (rel_std * k_s) ** 2, table, 0.1, unknown_weight)
            assert (got.name, got.confidence, got.probabilities, got.unknown_probability) == ref
