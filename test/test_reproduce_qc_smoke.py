"""Smoke test of the quarter-car reproduction command (``make reproduce-qc``) in its --quick mode.

Checks the shape of what the command writes, not the numbers: the report and
its figures exist, every case has its section, and every number of the
summary table parses as a finite float.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

reproduce_qc = pytest.importorskip("terrain_analysis.tools.reproduce_qc")

CASE_HEADINGS = [f"## Case {i} " for i in range(1, 9)]


def _summary_rows(text: str) -> list[list[str]]:
    """Cells of the summary table (header and separator excluded)."""
    section = text.split("## Summary", 1)[1]
    rows: list[list[str]] = []
    started = False
    for line in section.splitlines():
        if line.startswith("| case | quantity |"):
            started = True
            continue
        if not started:
            continue
        if not line.startswith("|"):
            break
        if line.startswith("|---"):
            continue
        # split on unescaped pipes only (quantities may contain "\|")
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        rows.append(cells)
    return rows


def test_quick_run_writes_report_and_figures(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "results"
    assert reproduce_qc.main(["--quick", "--jobs", "1", "--out", str(out)]) == 0

    report = out / "quarter_car.md"
    assert report.is_file()
    text = report.read_text(encoding="utf-8")
    for heading in CASE_HEADINGS + ["## Case 2b ", "## Case 2c "]:
        assert heading in text, f"missing section {heading!r}"
    assert "## What did not reproduce and why" in text
    assert "Git revision" in text and "Wall time" in text and "Seeds" in text

    rows = _summary_rows(text)
    assert len(rows) >= 10
    cases = {row[0] for row in rows}
    assert {"1", "2", "3", "4", "5", "7", "8"} <= cases
    for row in rows:
        assert len(row) == 6, row
        for cell in (row[2], row[3]):  # computed, paper
            value = float(cell)
            assert math.isfinite(value), row
        assert row[5] in ("yes", "info") or row[5].startswith("**no**"), row

    figures = sorted((out / "quarter_car").glob("*.png"))
    names = {p.name for p in figures}
    for name in (
        "case1_trajectory.png",
        "case1_rmse.png",
        "table4_profiles.png",
        "table4_speeds.png",
        "case3_lete_f.png",
        "meadow_c.png",
        "lrv.png",
        "profile_rate.png",
    ):
        assert name in names, f"missing figure {name}"
    for path in figures:
        assert path.stat().st_size > 1000
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # every embedded figure link resolves relative to the report
    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text):
        assert (report.parent / link).is_file(), link


def test_settle_time_and_windows() -> None:
    import numpy as np

    t = np.arange(1, 101) * 0.01
    err = np.where(t < 0.3, 50.0, 1.0)
    err[60] = 6.0  # one late excursion at t = 0.61 s
    trace = reproduce_qc.Trace(t=t, err=err, k_tot=np.zeros_like(t), k_tot_max=1.0, recoveries=0, finite=True)
    value, censored = reproduce_qc.settle_time(trace, 0.0, 1.0, 5.0)
    assert not censored and value == pytest.approx(0.62)
    value, censored = reproduce_qc.settle_time(trace, 0.0, 1.0, 0.5)
    assert censored and value == pytest.approx(1.0)
    assert reproduce_qc.rmse(trace, 0.7, 1.0) == pytest.approx(1.0)
    assert reproduce_qc.mean_abs(trace, 0.7, 1.0) == pytest.approx(1.0)
    assert reproduce_qc.run_seeds(1, 0) == reproduce_qc.run_seeds(1, 0) != reproduce_qc.run_seeds(1, 1)
