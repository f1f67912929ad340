"""The start-up benchmark's child really reaches a first estimate (issue 23: it printed NaN for every vehicle
after the replay's output hook gained an argument, and nothing noticed)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from terrain_analysis.tools.bench_startup import _first_estimate

BAGS = Path(__file__).resolve().parents[1] / "bags"


@pytest.mark.timeout(120)
def test_startup_child_reaches_the_first_estimate() -> None:
    wall, cpu = _first_estimate("rover", BAGS / "rover_terrain_1")
    assert math.isfinite(wall) and math.isfinite(cpu)
    assert 0.0 < cpu <= wall * 2.0 + 1.0


def test_a_failing_child_is_an_error_not_nan(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match="exit"):
        _first_estimate("rover", tmp_path / "no_such_bag")
