"""The rover page's consistency misses are judged terrain by terrain, not only pooled (issue 21).

A pooled figure can meet the criteria by averaging a cautious terrain with an over-confident one; the page
named no miss when that happened ("Nowhere") while its own per-terrain rows carried ✗.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import pytest

rover_consistency = pytest.importorskip("terrain_analysis.tools.rover_consistency")


@dataclass
class _Stats:
    mean_normalised: float
    within_2sigma: float


class _Claims:
    def __init__(self) -> None:
        self.rows: list[tuple[Any, ...]] = []

    def claim(self, *row: Any) -> bool | None:
        self.rows.append(row)
        return bool(row[-1])


def _fig(e2: float, within: float) -> dict[str, Any]:
    return {"quantities": {q: _Stats(e2, within) for q, *_ in rover_consistency.QUANTITIES}}


def test_a_cautious_and_an_over_confident_terrain_are_both_named() -> None:
    per_terrain = {(1, "e2"): _fig(1.0, 0.95), (2, "e2"): _fig(0.2, 1.0), (6, "e2"): _fig(6.0, 0.8)}
    rr = _Claims()
    lines = rover_consistency._terrain_misses(rr, per_terrain, [1, 2, 6], "e2", "E1+E2")
    assert len(lines) == 2
    assert lines[0].startswith("- E1+E2, terrain 2: cautious: i 0.2 / 100 %")
    assert "over-confident" not in lines[0]
    assert lines[1].startswith("- E1+E2, terrain 6: over-confident: i 6 / 80 %")
    (claim,) = rr.rows
    assert claim[2] == pytest.approx(5 / 15) and claim[-1] is False


def test_every_terrain_consistent_makes_the_claim_hold() -> None:
    per_terrain = {(n, "e2"): _fig(1.1, 0.94) for n in (1, 2, 3)}
    rr = _Claims()
    assert rover_consistency._terrain_misses(rr, per_terrain, [1, 2, 3], "e2", "E1+E2") == []
    assert rr.rows[0][2] == 1.0 and rr.rows[0][-1] is True
