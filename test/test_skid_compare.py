"""The skid-steer comparison engine scores what it is given (tools/skid_compare.py)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from terrain_analysis.tools.skid_compare import _FilterRun, score_run, summarise


def _sim(n: int = 1000) -> SimpleNamespace:
    t = np.arange(1, n + 1) * 0.01
    vx = np.full(n, 2.0)
    vy = 0.05 * np.sin(t)
    r = np.full(n, 0.2)
    truth = SimpleNamespace(vx=vx, vy=vy, yaw_rate=r, body_sideslip=np.arctan2(vy, vx))
    return SimpleNamespace(t=t, truth=truth, seed=3)


def _run(sim: SimpleNamespace, offset: tuple[float, float, float], sigma: tuple[float, float, float]) -> _FilterRun:
    state = np.column_stack([sim.truth.vx, sim.truth.vy, sim.truth.yaw_rate]) + np.asarray(offset)
    n = sim.t.size
    return _FilterRun(
        t=sim.t.copy(),
        state=state,
        beta=np.arctan2(state[:, 1], state[:, 0]),
        covariance=np.tile(np.diag(np.square(sigma)), (n, 1, 1)),
        nis=np.full(n, math.nan),
        cpu_s=0.01,
        steps=n,
        resets=0,
    )


def test_errors_and_normalised_errors_against_the_truth() -> None:
    sim = _sim()
    figures = score_run(
        sim, _run(sim, (0.1, 0.02, 0.0), (0.1, 0.01, 0.01)), scenario="s", filter_name="f", window=(1, 10)
    )
    assert figures.rms_vx == pytest.approx(0.1) and figures.rms_vy == pytest.approx(0.02) and figures.rms_r == 0.0
    assert figures.normalised_vx == pytest.approx(1.0) and figures.normalised_vy == pytest.approx(4.0)
    assert figures.mean_nees == pytest.approx(5.0)
    assert figures.mean_abs_beta > 0.005 and figures.cpu_per_step_us == pytest.approx(10.0)
    assert math.isnan(figures.mean_nis)
    table = summarise([figures, figures])
    assert table[("s", "f")]["runs"] == 2 and table[("s", "f")]["rms_vx"] == pytest.approx(0.1)


def test_a_window_without_estimates_is_an_error() -> None:
    sim = _sim()
    with pytest.raises(ValueError, match="no estimate inside"):
        score_run(sim, _run(sim, (0, 0, 0), (1, 1, 1)), scenario="s", filter_name="f", window=(50, 60))


def test_command_line_writes_its_section(tmp_path, capsys) -> None:
    """One seed of the acceleration run through every filter of the comparison; a partial set is no verdict."""
    from terrain_analysis.tools.skid_compare import FILTERS, main

    out = tmp_path / "fair.md"
    assert main(["--seeds", "1", "--jobs", "1", "--scenarios", "straight_acceleration", "--out", str(out)]) == 0
    text = out.read_text()
    assert "fair-comparison" in text and all(f"| straight_acceleration | {f} | 1 |" in text for f in FILTERS)
    assert "nan" not in text.split("| straight_acceleration |")[1].split("\n")[0]
    assert main(["--seeds", "0"]) == 2
    assert "--seeds and --jobs must be >= 1" in capsys.readouterr().err


def test_consider_section_holds_the_estimates_and_ranks_the_settings() -> None:
    """The sensitivity section: the same estimates in every row, the variance growing with what is considered."""
    from terrain_analysis.tools.skid_compare import (
        CONSIDER_SETS,
        compare,
        consider_filters,
        consider_markdown,
        plan,
    )

    rows = compare(plan(["straight_acceleration"], [1000], consider_filters()))
    by = {r.filter: r for r in rows}
    assert list(by) == list(CONSIDER_SETS)
    assert len({(r.rms_vx, r.rms_vy, r.mean_abs_beta) for r in rows}) == 1
    vx = [by[f].normalised_vx for f in by]
    assert vx == sorted(vx, reverse=True) and vx[0] > 5.0 * vx[2]
    assert "| straight_acceleration | resistance 0.02, C_x 15 % (default) | 1 |" in consider_markdown(rows)
