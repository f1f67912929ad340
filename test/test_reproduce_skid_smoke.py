"""Smoke test of the skid-steer reproduction command (``make reproduce-skid``) in its --quick mode,
and unit tests of its metric functions against hand-computed values.

The smoke test checks the shape of what the command writes, not the numbers:
the report and its figures exist, every section is there, and every number of
the summary table (and of the whole report) is finite.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

reproduce_skid = pytest.importorskip("terrain_analysis.tools.reproduce_skid")
pytest.importorskip("vehicle_sim.plants.skid_steer")

SECTIONS = (
    "## Summary",
    "## Table 2 ",
    "## Table 3 ",
    "## Straight acceleration",
    "## ICR in the small-radius turn",
    "## Other observations of the paper",
    "## Sensitivity (not in the paper)",
    "## What did not reproduce and why",
)
FIGURES = (
    "small_radius_turn_sideslip.png",
    "s_shape_sideslip.png",
    "sideslip_error_runs.png",
    "straight_acceleration_vx.png",
    "small_radius_turn_icr.png",
    "small_radius_turn_observations.png",
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
    assert reproduce_skid.main(["--quick", "--jobs", "1", "--out", str(out)]) == 0

    report = out / "skid_steer.md"
    assert report.is_file()
    text = report.read_text(encoding="utf-8")
    for heading in SECTIONS:
        assert heading in text, f"missing section {heading!r}"
    assert "Git revision" in text and "Wall time" in text and "Seeds" in text
    assert "Truth identical in every run" in text

    rows = _summary_rows(text)
    assert len(rows) >= 20
    assert {"Table 2", "Table 3", "accel", "ICR", "turn"} <= {row[0] for row in rows}
    for row in rows:
        assert len(row) == 6, row
        assert math.isfinite(float(row[2])), row
        assert row[5] in ("yes", "info", "**no**"), row
    # No NaN or infinity anywhere in the report ("info" is a word, not a number).
    assert not re.search(r"\b(nan|inf)\b", text, flags=re.IGNORECASE)

    names = {p.name for p in (out / "skid_steer").glob("*.png")}
    for name in FIGURES:
        assert name in names, f"missing figure {name}"
        path = out / "skid_steer" / name
        assert path.stat().st_size > 1000
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text):
        assert (report.parent / link).is_file(), link


def test_sideslip_errors_hand_computed() -> None:
    est = np.array([0.1, 0.2, -0.1])
    ref = np.array([0.05, 0.25, -0.2])
    # e = (0.05, −0.05, 0.1); |e|/|ref| = (1, 0.2, 0.5); |e|/max(|ref|, 0.1) = (0.5, 0.2, 0.5)
    errs = reproduce_skid.sideslip_errors(est, ref, floor=0.1)
    assert errs.max_abs == pytest.approx(0.1)
    assert errs.mean_abs == pytest.approx(0.2 / 3)
    assert errs.max_rel == pytest.approx(1.0)
    assert errs.mean_rel == pytest.approx(1.7 / 3)
    assert errs.mean_rel_floor == pytest.approx(0.4)
    # population std of e: mean 1/30, squared deviations sum 0.0116667, / 3
    assert errs.std == pytest.approx(math.sqrt(0.035 / 9))
    assert errs.n == 3


def test_sideslip_errors_zero_reference_and_shapes() -> None:
    errs = reproduce_skid.sideslip_errors([0.01, 0.02], [0.0, 0.02], floor=0.01)
    assert math.isinf(errs.max_rel) and math.isinf(errs.mean_rel)  # the paper's relative error explodes at 0
    assert errs.mean_rel_floor == pytest.approx(0.5)  # (0.01/0.01 + 0)/2
    with pytest.raises(ValueError):
        reproduce_skid.sideslip_errors([0.1, 0.2], [0.1])


def test_values_at_matches_stamps() -> None:
    t = np.arange(1, 101) * 0.01
    v = 10.0 * t
    got = reproduce_skid.values_at(t, v, [0.1, 0.5, 1.0])
    np.testing.assert_allclose(got, [1.0, 5.0, 10.0])
    with pytest.raises(ValueError):
        reproduce_skid.values_at(t, v, [0.105])


def test_tracking_lag_ramp_shift_and_offset() -> None:
    t_truth = np.arange(0, 1001) * 0.01
    truth = np.clip(t_truth - 1.0, 0.0, None)  # ramp of 1 m/s² from 1 s
    t_est = t_truth.copy()
    delayed = np.clip(t_est - 1.05, 0.0, None)  # the truth 50 ms late
    assert reproduce_skid.tracking_lag(t_est, delayed, t_truth, truth, 2.0, 9.0) == pytest.approx(0.05, abs=1e-6)
    # A constant over-estimate b on a ramp of slope a leads by b/a.
    assert reproduce_skid.tracking_lag(t_est, truth + 0.02, t_truth, truth, 2.0, 9.0) == pytest.approx(-0.02, abs=1e-6)
    # Sub-grid shift of a smooth signal: the parabolic refinement resolves it.
    wave = np.sin(t_truth)
    late = np.sin(t_est - 0.1234)
    assert reproduce_skid.tracking_lag(t_est, late, t_truth, wave, 1.0, 9.0) == pytest.approx(0.1234, abs=2e-4)


def test_icr_statistics_uses_valid_samples_only() -> None:
    mx, sx, my, sy, med = reproduce_skid.icr_statistics([1.0, 3.0, 100.0], [5.0, 7.0, 0.0], [True, True, False])
    assert (mx, sx, my, sy, med) == pytest.approx((2.0, 1.0, 6.0, 1.0, 2.0))
    assert all(math.isnan(v) for v in reproduce_skid.icr_statistics([1.0], [1.0], [False]))


def test_seeds_and_plan() -> None:
    seed = reproduce_skid.run_seed
    assert seed("small_radius_turn", 0) == seed("small_radius_turn", 0) != seed("small_radius_turn", 1)
    assert seed("s_shape", 0) != seed("small_radius_turn", 0)
    assert seed("turn_mismatch", 3) == seed("small_radius_turn", 3)  # paired sensitivity runs
    counts = reproduce_skid.Counts()
    plan = reproduce_skid.build_plan(counts)
    per_case: dict[str, int] = {}
    for spec in plan:
        per_case[spec.case] = per_case.get(spec.case, 0) + 1
    assert per_case["small_radius_turn"] == per_case["s_shape"] == per_case["straight_acceleration"] >= 20
    assert counts.turn_window == (20.0, 40.0) and counts.s_window == (20.0, 25.0)


def test_claims_table_escapes_pipes() -> None:
    claim = reproduce_skid.Claim("turn", "mean |e|", 0.5, "< 1", "≤ 0.5", True)
    table = reproduce_skid.claims_table([claim])
    assert "mean \\|e\\|" in table and table.splitlines()[-1].endswith("| yes |")
