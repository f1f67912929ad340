"""Smoke test of ``python -m terrain_analysis.tools.bench --quick``: every row is printed.

No timing is asserted anywhere: the figures depend on the machine. Only that
the run completes, prints each row with finite numbers, and writes the same
figures as JSON.
"""

from __future__ import annotations

import json
import math

import pytest

pytest.importorskip("filterpy")
pytest.importorskip("vehicle_sim")

from terrain_analysis.tools import bench  # noqa: E402

EXPECTED_ROWS = (
    "machine:",
    "SCKF",
    "CKF",
    "UKF",
    "EKF",
    "SCKF compiled step",
    "EKF compiled step",
    "filterpy UKF (Merwe)",
    "bag quarter_car_graneville_iso_d_10ms",
    "bag lrv_regolith_iso_g_2ms",
    "core quarter_car",
    "core quarter_car numpy path",
    "core lrv",
    "core lrv numpy path",
    "simulate quarter_car",
    "simulate lrv",
)


def test_bench_quick_prints_every_row(capsys, tmp_path):
    out_json = tmp_path / "bench.json"
    assert bench.main(["--quick", "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    for label in EXPECTED_ROWS:
        rows = [line for line in lines if line.strip().startswith(label)]
        assert rows, f"row {label!r} missing from:\n{text}"
    assert set(EXPECTED_ROWS) == set(bench.ROW_LABELS)
    # Rocker-bogie section: every row printed, finite figures.
    for label in bench.ROVER_ROW_LABELS:
        assert any(line.strip().startswith(label) for line in lines), f"rover row {label!r} missing from:\n{text}"
    assert "nan" not in text.lower()

    figures = json.loads(out_json.read_text())
    assert set(figures) >= {"machine", "config", "filters", "throughput", "simulator"}
    assert figures["machine"]["cpu_count"] >= 1
    assert "OPENBLAS_NUM_THREADS" in figures["machine"]
    assert [r["filter"] for r in figures["filters"]] == [
        "SCKF",
        "CKF",
        "UKF",
        "EKF",
        "SCKF compiled step",
        "EKF compiled step",
        "filterpy UKF (Merwe)",
    ]
    # The compiled steps run the same filters on the same data: the same final k_tot to rounding.
    assert all(r["final_ktot_diff_vs_numpy_N_per_m"] < 1e-3 for r in figures["filters"][4:6])
    for r in figures["filters"]:
        assert r["steps"] == figures["config"]["steps"]
        assert math.isfinite(r["median_us"]) and r["median_us"] > 0 and r["p90_us"] >= r["median_us"]
        assert r["state_bytes"] > 0
    # filterpy ran the same model with the same sigma points as our UKF.
    assert figures["filters"][-1]["final_ktot_diff_vs_ours_N_per_m"] < 1.0
    for r in figures["throughput"] + figures["simulator"]:
        assert math.isfinite(r["x_real_time"]) and r["x_real_time"] > 0, r
        assert r["steps"] > 0, r
    bags = {r["row"]: r for r in figures["throughput"]}
    assert bags["bag quarter_car_graneville_iso_d_10ms"]["sim_s"] == pytest.approx(4.0, abs=0.02)
    assert 0.0 < bags["core quarter_car"]["filter_share"] <= 1.0
    # The core rows run the node's path (the compiled step); the numpy rows beside them are labelled as such.
    assert bags["core quarter_car"]["path"] == bags["core lrv"]["path"] == "compiled"
    assert bags["core quarter_car numpy path"]["path"] == bags["core lrv numpy path"]["path"] == "numpy"
    rover = figures["rover"]
    assert [r["filter"] for r in rover["filters"]] == ["rover E1", "rover E2", "rover E3"]
    for r in rover["filters"]:
        assert r["steps"] > 0 and math.isfinite(r["median_us"]) and r["median_us"] > 0, r
    for r in rover["throughput"] + rover["simulator"]:
        assert math.isfinite(r["x_real_time"]) and r["x_real_time"] > 0 and r["steps"] > 0, r
    # Sim-to-real section (--quick: one 6 s quarter-car bag diagnosed end to end).
    assert any(line.startswith("Sim-to-real diagnosis") for line in lines), text
    (s2r,) = figures["sim2real"]
    assert s2r["vehicle"] == "quarter_car" and "skipped" not in s2r, s2r
    assert math.isfinite(s2r["wall_s"]) and s2r["wall_s"] > 0 and s2r["candidates"] >= 9, s2r
