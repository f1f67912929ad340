"""The real-run check of the skid-steer estimator (tools/skid_real_check.py) on a shipped bag."""

from __future__ import annotations

import shutil
from pathlib import Path

from terrain_analysis.tools.skid_real_check import main

BAGS = Path(__file__).resolve().parents[1] / "bags"
CONFIG = Path(__file__).resolve().parents[1] / "config"


def test_a_shipped_run_holds_and_its_rest_is_measured(tmp_path: Path, capsys) -> None:
    root = tmp_path / "runs"
    shutil.copytree(BAGS / "skid_steer_straight_acceleration", root / "accel")
    out = tmp_path / "report.md"
    args = [str(root), "--config", str(CONFIG / "skid_steer.yaml"), "--namespace", "/skid_steer", "--out", str(out)]
    assert main(args) == 0
    row = next(line for line in out.read_text().splitlines() if line.startswith("| accel |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[3] == "0, 0, 0" and cells[-1] == "ok"
    assert int(cells[6]) > 50 and float(cells[7]) < 0.05  # the bag starts at rest
    assert "1 of 1 runs hold" in out.read_text()


def test_an_empty_directory_is_an_input_error(tmp_path: Path, capsys) -> None:
    assert main([str(tmp_path)]) == 2
    assert "no rosbag2 directory" in capsys.readouterr().err
