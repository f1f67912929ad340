"""The soil-stiffness node's published k_s variance is held to its errors on truth runs (issue 21, item 1).

A few short nominal truth runs per vehicle (node defaults, 20 s, the first
``SETTLE_S`` = 5 s excluded), errors e = k̂_s − k_s against the plant's truth,
pooled over the runs:

* **LRV**: the issue's criterion holds: mean e²/σ² in [0.5, 2], and the share
  of |e| ≤ 2σ in [0.90, 0.99] (a Gaussian gives 0.954).
* **Quarter car**: mean e²/σ² in [0.25, 1.2] and the share within 2σ in
  [0.93, 1.0]. The lower ends are below the issue's 0.5 / 0.90 and the upper
  end of the share above its 98 %: on a constant soil the filter's random
  walk of the stiffness makes it cautious (e²/σ² ≈ 0.5–0.65, ≈ 99 % within 2σ;
  ``make reproduce-qc`` reports it in docs/results/quarter_car.md, section
  "Consistency of the published variances", and says why).

Each band fails when the published variance is wrong by a factor 3 either
way; :func:`test_bands_reject_a_variance_wrong_by_three` checks exactly that
on the same runs (the variance scaled by 3 and by 1/3 in the statistics,
which is what a 3× wrong published variance would give).
"""

from __future__ import annotations

import pytest

from terrain_analysis.reporting import Provenance, write_section
from terrain_analysis.tools import qc_consistency as qcc

# (vehicle) → (cells, mean e²/σ² band, within-2σ band)
BANDS = {
    "quarter_car": ((0, 2, 4, 5), (0.25, 1.2), (0.93, 1.0)),
    "lrv": ((0, 1, 4), (0.5, 2.0), (0.90, 0.99)),
}
DURATION = 20.0
SEEDS = 2


@pytest.fixture(scope="module")
def runs() -> dict[str, list[tuple[qcc.Case, dict]]]:
    plan = [
        c for c in qcc.build_plan(SEEDS, DURATION, effects=False) if c.cell in BANDS[c.vehicle][0] and c.seed < SEEDS
    ]
    out: dict[str, list[tuple[qcc.Case, dict]]] = {v: [] for v in BANDS}
    for case in plan:
        out[case.vehicle].append(qcc.run_case(case))
    return out


def _inside(stats: qcc.QuantityStats, vehicle: str) -> bool:
    _, e2, in2 = BANDS[vehicle]
    return e2[0] <= stats.mean_e2 <= e2[1] and in2[0] <= stats.within_2sigma <= in2[1]


@pytest.mark.parametrize("vehicle", sorted(BANDS))
def test_published_k_s_variance_matches_its_errors(runs: dict, vehicle: str) -> None:
    stats, (mean_nis, _, _) = qcc.pool(runs[vehicle])
    s = stats["k_s"]
    assert s.n > 1000 * len(runs[vehicle]), "every step after the settling time is scored"
    _, e2, in2 = BANDS[vehicle]
    assert e2[0] <= s.mean_e2 <= e2[1], f"{vehicle}: mean e²/σ² of k_s {s.mean_e2:.3f} outside {e2}"
    assert in2[0] <= s.within_2sigma <= in2[1], (
        f"{vehicle}: {s.within_2sigma:.3%} of k_s errors within 2σ, not in {in2}"
    )
    # k_tot and the stiffness state carry the same σ (first-order transforms of one scalar): same verdict.
    assert _inside(stats["k_tot"], vehicle) and _inside(stats["ln k_s (state)"], vehicle)
    dof = 2 if vehicle == "quarter_car" else 1
    assert 0.8 * dof <= mean_nis <= 1.25 * dof, f"{vehicle}: mean NIS {mean_nis:.2f} against {dof} dof"


@pytest.mark.parametrize("vehicle", sorted(BANDS))
@pytest.mark.parametrize("scale", [3.0, 1.0 / 3.0])
def test_bands_reject_a_variance_wrong_by_three(runs: dict, vehicle: str, scale: float) -> None:
    stats, _ = qcc.pool(runs[vehicle], variance_scale=scale)
    assert not _inside(stats["k_s"], vehicle), (
        f"{vehicle}: a k_s variance ×{scale:.3g} still passes "
        f"(e²/σ² {stats['k_s'].mean_e2:.3f}, within 2σ {stats['k_s'].within_2sigma:.3%})"
    )


def test_section_is_written_into_the_page(runs: dict, tmp_path) -> None:
    page = tmp_path / "quarter_car.md"
    page.write_text("# page written by reproduce_qc\n\nkept\n")
    results = [r for vehicle in sorted(runs) for r in runs[vehicle]]
    provenance = Provenance("python -m terrain_analysis.tools.qc_consistency --quick", 1, 1.0, 1.0, len(results))
    text = qcc.section(results, provenance)
    write_section(page, "qc-consistency", text)
    write_section(page, "qc-consistency", text)  # replaced in place, not appended twice
    out = page.read_text()
    assert out.startswith("# page written by reproduce_qc") and "kept" in out
    assert out.count("## Consistency of the published variances") == 1
    for heading in ("### Quarter car, nominal", "### LRV, nominal", "### Where the criterion is not met, and why"):
        assert heading in out
