"""Smoke test of the rocker-bogie reproduction command (``make reproduce-rover``) in its --quick mode,
and unit tests of its helpers against hand-computed values.

The smoke test checks the shape of what the command writes, not the numbers:
the report and its figures exist, every section is there, every number of the
summary table (and of the whole report) is finite, and the summary rows the
issue asks for are present.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

reproduce_rover = pytest.importorskip("terrain_analysis.tools.reproduce_rover")
pytest.importorskip("vehicle_sim.plants.rover")

SECTIONS = (
    "## Summary",
    "## The true model: 4th-order global surrogate",
    "## Table V ",
    "## Time series",
    "## Table VI ",
    "## Table VII ",
    "## Error against terrain curvature",
    "## Speed: simulator and estimators",
    "## What did not reproduce and why",
)
FIGURES = (
    "table5_vs_paper.png",
    *(f"terrain{n}_timeseries.png" for n in range(1, 7)),
    "fit_surfaces.png",
    "fit_errors.png",
    "error_vs_curvature.png",
)
#: (case, start of the quantity) of summary rows that every run must show.
REQUIRED_ROWS = (
    ("Table V", "defaults: fraction of the 144 cells"),
    ("Table V", "paper's choices: fraction of the 144 cells"),
    ("Table VII", "E1+E2: τ_R model RMS"),
    ("Table VII", "E1+E2: DP model RMS"),
    ("Table VII", "E1+E3: τ_R model RMS"),
    ("Table VII", "E1+E3: DP model RMS"),
    ("Table VII", "E1+E2, paper's choices: DP model RMS"),
    ("speed", "estimators E1+E2, × real time (CPU)"),
    ("speed", "estimators E1+E3, × real time (CPU)"),
    ("speed", "simulator with the full Wong–Reece model, × real time (CPU)"),
    ("surrogate", "4th-order surrogate RMS, DP"),
)


def _summary_rows(text: str) -> list[list[str]]:
    """Cells of every row of the summary table, after its header and separator lines."""
    after_header = text.split("## Summary", 1)[1].split("| case | quantity |", 1)[1]
    table = []
    for line in after_header.splitlines()[2:]:
        if not line.startswith("| "):
            break
        table.append([cell.strip() for cell in re.split(r"(?<!\\)\|", line.strip())[1:-1]])
    return table


def test_quick_run_writes_report_and_figures(tmp_path: Path) -> None:
    out = tmp_path / "results"
    assert reproduce_rover.main(["--quick", "--jobs", "1", "--out", str(out)]) == 0

    report = out / "rover.md"
    assert report.is_file()
    text = report.read_text(encoding="utf-8")
    for heading in SECTIONS:
        assert heading in text, f"missing section {heading!r}"
    assert "Git revision" in text and "Wall time" in text and "Seeds" in text and "Run counts" in text
    # The re-drawn sensor noise reproduces the plant's own readings (the basis of the cheap extra seeds).
    assert "identical to the plant's, bit for bit, per terrain: 1: yes, 2: yes, 3: yes, 4: yes, 5: yes, 6: yes" in text

    rows = _summary_rows(text)
    for row in rows:
        assert len(row) == 6, row
        assert math.isfinite(float(row[2])), row
        assert row[5] in ("yes", "info", "**no**"), row
    for case, quantity in REQUIRED_ROWS:
        assert any(r[0] == case and r[1].startswith(quantity) for r in rows), (case, quantity)
    # No NaN or infinity anywhere in the report ("info" is a word, not a number).
    assert not re.search(r"\b(nan|inf)\b", text, flags=re.IGNORECASE)
    # Every Table V cell has a computed value and the paper's beside it (4 quantities × 12 rows), and
    # the paper's-choices configuration has its row per terrain.
    assert text.count("| E1+E2 | ") >= 4 * 6 and text.count("| E1+E3 | ") >= 4 * 6
    assert text.count("| E1+E2, paper's choices | ") >= 6 and text.count("| E1+E3, paper's choices | ") >= 6

    names = {p.name for p in (out / "rover").glob("*.png")}
    for name in FIGURES:
        assert name in names, f"missing figure {name}"
        path = out / "rover" / name
        assert path.stat().st_size > 1000
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text):
        assert (report.parent / link).is_file(), link


def test_paper_tables_have_every_cell() -> None:
    assert set(reproduce_rover.PAPER_TABLE5) == {(n, v) for n in range(1, 7) for v in ("e2", "e3")}
    assert all(len(v) == 12 for v in reproduce_rover.PAPER_TABLE5.values())
    # Estimator 1 is shared: the paper's slip and τ_R columns are the same for both variants.
    for n in range(1, 7):
        e2, e3 = reproduce_rover.PAPER_TABLE5[(n, "e2")], reproduce_rover.PAPER_TABLE5[(n, "e3")]
        assert e2[:3] == e3[:3] and e2[6:9] == e3[6:9]
    assert all(len(v) == 6 for v in reproduce_rover.PAPER_TABLE6.values())


def test_paper_choices_are_configuration_fields() -> None:
    """The paper's-choices variant switches real fields (a renamed field would silently drop out)."""
    choices = reproduce_rover.paper_choices()
    assert choices == reproduce_rover.PAPER_CHOICES
    cfg = reproduce_rover.variant_config("e3p")
    assert cfg.load_cell_axes == 1
    for name, value in choices.items():
        assert getattr(cfg, name) == value
    assert reproduce_rover.variant_config("e2").load_cell_axes == 2


def test_seeds_and_plan() -> None:
    seed = reproduce_rover.run_seed
    assert seed(1, 0) == seed(1, 0) != seed(1, 1)
    assert seed(2, 0) != seed(1, 0)
    counts = reproduce_rover.Counts()
    plan = reproduce_rover.build_plan(counts)
    terrains = [t for t in plan if t.kind == "terrain"]
    assert [t.terrain for t in terrains] == [1, 2, 3, 4, 5, 6]
    assert {t.terramechanics for t in terrains} == {"surrogate"}
    assert {t.terramechanics for t in plan if t.kind == "speed"} == {"surrogate", "wong_reece"}
    assert [counts.terrain_duration(n) for n in (1, 2, 3)] == [200.0, 200.0, 200.0]


def test_stamp_indices_and_wheel_rms() -> None:
    t = np.arange(0, 100) / 50.0
    idx, ok = reproduce_rover.stamp_indices(t, np.array([0.2, 0.4, 1.98, 2.0, 0.21]))
    assert idx[:3].tolist() == [10, 20, 99]
    assert ok.tolist() == [True, True, True, False, False]
    rms = reproduce_rover.wheel_rms(np.array([[1.0, 0.0, -2.0], [-1.0, 0.0, 2.0]]))
    np.testing.assert_allclose(rms, [1.0, 0.0, 2.0])
    assert np.isnan(reproduce_rover.wheel_rms(np.zeros((0, 3)))).all()


def test_convex_hull_and_inside() -> None:
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.5, 0.5], [0.2, 0.8]])
    hull = reproduce_rover.convex_hull(pts)
    assert hull.shape == (4, 2)
    assert {tuple(p) for p in hull} == {(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)}
    inside = reproduce_rover.inside_polygon(hull, np.array([0.5, 1.5, 1.0]), np.array([0.5, 0.5, 1.0]))
    assert inside.tolist() == [True, False, True]
