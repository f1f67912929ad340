"""The bench's quarter-car rows time what runs: the compiled filter step of the node, the numpy path beside it,
and the Monte Carlo section (``--only qc_monte_carlo``) runs the same rides on both EKF paths.

No time is asserted (the figures depend on the machine): which path each row ran, that every row is printed
with finite figures, and that both Monte Carlo runs give the same estimates.
"""

from __future__ import annotations

import json
import math

import pytest

pytest.importorskip("vehicle_sim")

from terrain_analysis.tools import bench, bench_quarter_car  # noqa: E402


@pytest.mark.parametrize("vehicle", ["quarter_car", "lrv"])
def test_core_rows_time_the_compiled_step_and_label_the_numpy_path(vehicle: str) -> None:
    drive = bench_quarter_car.drive_quarter_car if vehicle == "quarter_car" else bench_quarter_car.drive_lrv
    result = drive(1.0, 3)
    node = bench.bench_core(vehicle, result)
    reference = bench.bench_core(vehicle, result, numpy_path=True)
    assert node["row"] == f"core {vehicle}" and node["path"] == "compiled"
    assert reference["row"] == f"core {vehicle} numpy path" and reference["path"] == "numpy"
    for row in (node, reference):
        assert row["steps"] > 50 and math.isfinite(row["filter_us_per_step"]) and 0.0 < row["filter_share"] <= 1.0
    assert {node["row"], reference["row"]} <= set(bench.ROW_LABELS)


def test_qc_monte_carlo_section_prints_both_paths_with_the_same_estimates(capsys, tmp_path) -> None:
    out_json = tmp_path / "mc.json"
    assert bench.main(["--only", "qc_monte_carlo", "--quick", "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    assert text.startswith("Quarter-car Monte Carlo: case 1 of reproduce-qc")
    lines = [line.strip() for line in text.splitlines()]
    assert any(line.startswith("before  sckf ") for line in lines), text
    assert any(line.startswith("after   sckf+ekf ") for line in lines), text
    assert "nan" not in text.lower()
    mc = json.loads(out_json.read_text())["qc_monte_carlo"]
    assert mc["jobs"] == 2 and mc["runs"] >= 1
    assert mc["variants"] == ["sckf", "ekf", "sckf_printed", "ekf_printed", "sckf_log"]
    assert [p["compiled"] for p in mc["paths"]] == [["sckf"], ["sckf", "ekf"]]
    for p in mc["paths"]:
        assert p["wall_s"] > 0.0 and p["cpu_s"] > 0.0
    # The same rides and filters on both paths: the k_s errors agree to rounding (percentage points).
    assert all(v < 1e-8 for v in mc["max_abs_err_diff_pct"].values()), mc["max_abs_err_diff_pct"]
