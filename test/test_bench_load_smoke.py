"""Smoke test of ``python -m terrain_analysis.tools.bench_load --quick``: every row is printed.

No timing, latency, CPU or loss figure is asserted: they depend on the machine
and its load (the benchmark prints them; ``make bench-load`` writes
``docs/results/robustness.md``). Only that the run completes, prints each row
with finite numbers, and writes the same rows as JSON and Markdown.
"""

from __future__ import annotations

import json
import math

import pytest

pytest.importorskip("vehicle_sim")

from terrain_analysis.tools import bench_load  # noqa: E402


def test_bench_load_quick_prints_every_row(capsys, tmp_path):
    out_json = tmp_path / "load.json"
    out_md = tmp_path / "robustness.md"
    assert bench_load.main(["--quick", "--json", str(out_json), "--out", str(out_md)]) == 0
    lines = capsys.readouterr().out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("row "))
    table = lines[header + 1 :]
    for case in bench_load.cases(quick=True):
        (row,) = [line for line in table if line.split(" | ")[0].strip() == case.label]
        cells = [c.strip() for c in row.split(" | ")[1:]]
        assert len(cells) == len(bench_load.HEADER) - 1, row
        # n/a: the latency of the rows that estimate nothing (empty callbacks, the bare node).
        estimates_nothing = case.empty_callbacks or case.bare_node
        numbers = [float(c.split()[0].split("/")[0]) for c in cells if not (c == "n/a" and estimates_nothing)]
        assert all(math.isfinite(v) for v in numbers), row
    assert any(line.startswith("offline ceiling") for line in lines)

    figures = json.loads(out_json.read_text())
    assert [r["row"] for r in figures["rows"]] == bench_load.row_labels(quick=True)
    assert figures["machine"]["cpu_count"] >= 1
    for r in figures["rows"]:
        assert r["published"] > 0, r
    text = out_md.read_text()
    assert "python -m terrain_analysis.tools.bench_load --quick" in text
    assert all(label in text for label in bench_load.row_labels(quick=True))


def test_the_collector_reads_the_header_of_every_estimate_type_from_its_bytes():
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message

    from terrain_msgs.msg import SkidSteerState, SoilStiffness, WheelTerrainArray

    for cls, frame in (
        (SoilStiffness, "v3/base_link"),
        (Odometry, "v12/odom"),
        (SkidSteerState, ""),
        (WheelTerrainArray, "v0/kapvik/base_link_with_a_longer_name"),
    ):
        msg = cls()
        msg.header.stamp.sec, msg.header.stamp.nanosec = 1_234_567, 987_654_321
        msg.header.frame_id = frame
        assert bench_load.cdr_header(serialize_message(msg)) == (1_234_567_987_654_321, frame), cls.__name__


def test_a_flow_controlled_row_says_when_the_player_went_on_without_an_estimate():
    from terrain_analysis.tools.bench_load_report import verdicts

    row = {
        "row": "(e) rover bag max events+take",
        "case": {"factor": 0.0},
        "x_real_time": 3.0,
        "dropped": 0,
        "estimates": 10,
        "expected_estimates": 11,
        "flow_stalls": 0,
        "flow_stall_s": bench_load.FLOW_STALL_S,
    }
    (quiet,) = verdicts([row])
    assert "went on" not in quiet
    (stalled,) = verdicts([row | {"flow_stalls": 2}])
    assert "went on 2 time(s) after 2 s without an estimate" in stalled
