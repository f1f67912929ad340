"""classify_soil on floats (the estimator's every step) gives the numpy form's values bit for bit (issue 23)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.models.soil import SOIL_TABLE, SoilClass, _classify_arrays, classify_soil

RNG_SEED = 2323


def _as_arrays(
    k_s: float, var: float, table: tuple[SoilClass, ...], class_log_std: float, unknown_weight: float
) -> tuple[object, ...]:
    """The numpy form of the classification (as classify_soil computed it before), as comparable reprs."""
    var_rel = var / (k_s * k_s)
    if not math.isfinite(var_rel) or var_rel < 0.0:
        var_rel = 1e6
    s2 = var_rel + class_log_std**2
    c = _classify_arrays(math.log(k_s), s2, table, unknown_weight, (1e3, 1e8))
    return c.name, repr(c.confidence), repr(c.probabilities), repr(c.unknown_probability)


@pytest.mark.parametrize("classes", [1, 3, 6])
@pytest.mark.parametrize("unknown_weight", [0.05, 0.0, 0.5])
@pytest.mark.parametrize("class_log_std", [0.1, 0.01, 1.0])
def test_float_classification_is_the_array_one(classes: int, unknown_weight: float, class_log_std: float) -> None:
    table = SOIL_TABLE[:classes]
    rng = np.random.default_rng(RNG_SEED + classes)
    for k_s, rel in zip(10.0 ** rng.uniform(1, 10, 2000), 10.0 ** rng.uniform(-7, 2, 2000), strict=True):
        for var in (float((k_s * rel) ** 2), 0.0, -1.0, math.inf, math.nan):
            c = classify_soil(float(k_s), var, table, class_log_std, unknown_weight)
            got = (c.name, repr(c.confidence), repr(c.probabilities), repr(c.unknown_probability))
            assert got == _as_arrays(float(k_s), var, table, class_log_std, unknown_weight)


def test_large_tables_take_the_array_form() -> None:
    """Seven classes and more: numpy's pairwise sum, so the array form itself."""
    table = SOIL_TABLE + SOIL_TABLE[:2]
    c = classify_soil(300e3, 1e8, table)
    assert c == _classify_arrays(math.log(300e3), 1e8 / (300e3 * 300e3) + 0.1**2, table, 0.05, (1e3, 1e8))


def test_degenerate_estimates_name_the_first_class() -> None:
    for k_s in (0.0, -5.0, math.nan, math.inf, np.float64(math.nan)):
        c = classify_soil(k_s, 1.0)
        assert c.name == SOIL_TABLE[0].name and c.confidence == 0.0 and c.unknown_probability == 1.0
