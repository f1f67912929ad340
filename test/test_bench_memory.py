"""The memory benchmark (terrain_analysis.tools.bench_memory): its bags, its verdict rule and its tables.

One real run (a 10 s simulated quarter-car bag against 1 min of repeats of it); no assertion on a memory figure
or a time: those depend on the machine and its load.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("rosbags")

from terrain_analysis.tools import bench_memory as bm  # noqa: E402

MB = 1024.0 * 1024.0


pytestmark = pytest.mark.timeout(900)  # a real run: simulation, four child processes, tracemalloc


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    root = tmp_path_factory.mktemp("bench_memory")
    rows = bm.bench_memory(root, ["quarter_car"], short_s=10.0, long_s=60.0, trace_s=0.5)
    return root, rows


def _stamps(bag: Path) -> dict[str, list[tuple[int, int]]]:
    """Topic -> (log time, header stamp ns) of every message (stamp -1 where the type has no header)."""
    from rosbags.highlevel import AnyReader

    from terrain_estimation.bag import typestore

    store = typestore()
    out: dict[str, list[tuple[int, int]]] = {}
    with AnyReader([bag], default_typestore=store) as reader:
        for conn, t, raw in reader.messages():
            stamp = -1
            if bm._header_first(store, conn.msgtype):
                sec, nsec = struct.unpack_from("<iI", raw, 4)
                stamp = sec * 1_000_000_000 + nsec
            out.setdefault(conn.topic, []).append((t, stamp))
    return out


def test_repeated_bag_shifts_log_times_and_header_stamps(run: tuple[Path, list[dict[str, Any]]]) -> None:
    root, _ = run
    short, long = _stamps(root / "quarter_car_10s"), _stamps(root / "quarter_car_60s")
    assert set(short) == set(long)
    for topic, msgs in short.items():
        copies = long[topic]
        assert len(copies) == 6 * len(msgs)
        period = copies[len(msgs)][0] - msgs[0][0]
        assert period > msgs[-1][0] - msgs[0][0]  # each copy starts after the previous one ends
        for k in range(6):
            for (t, stamp), (t2, stamp2) in zip(msgs, copies[k * len(msgs) : (k + 1) * len(msgs)], strict=True):
                assert t2 == t + k * period
                assert stamp2 == (-1 if stamp == -1 else stamp + k * period)
        assert all(b[0] > a[0] for a, b in zip(copies, copies[1:], strict=False))
    assert any(s != -1 for msgs in short.values() for _, s in msgs)  # the inputs carry headers: they were patched


def test_cut_bag_is_the_start_of_the_short_one(run: tuple[Path, list[dict[str, Any]]]) -> None:
    root, _ = run
    short, cut = _stamps(root / "quarter_car_10s"), _stamps(root / "quarter_car_0.5s")
    t0 = min(m[0][0] for m in short.values())
    for topic, msgs in cut.items():
        assert msgs == [m for m in short[topic] if m[0] < t0 + 500_000_000]


def test_real_run_rows_and_table(run: tuple[Path, list[dict[str, Any]]]) -> None:
    _, rows = run
    estimates = [r for r in rows if r.get("kind") != "verdict"]
    assert [r["bag_s"] for r in estimates] == [10.0, 60.0]
    for r in estimates:
        assert r["exit"] == 0, r.get("error")
        assert r["peak_rss_mb"] > 0 and r["cpu_s"] > 0 and r["output_mb"] > 0
        assert r["read"] == r["accepted"] + r["rejected"]
    # six copies, six times the estimates (the seams may cost a few)
    assert 5.5 * estimates[0]["estimates"] <= estimates[1]["estimates"] <= 6 * estimates[0]["estimates"] + 10
    (summary,) = [r for r in rows if r.get("kind") == "verdict"]
    for label in ("short", "long"):
        t = summary["trace"][label]
        assert "error" not in t, t
        assert t["estimates"] > 0 and t["summary_lines"] > 0
        # The CLI writes each estimate as it is made and compares with the ground truth in the same pass:
        # it holds neither (an empty list of outputs is all that deep_size finds).
        assert t["truth_messages"] == 0 and t["outputs_mb"] * MB < 100
    assert summary["trace"]["long"]["estimates"] >= 1.8 * summary["trace"]["short"]["estimates"]
    expected = bm.verdict(estimates[0], estimates[1], summary["trace"]["short"]["bytes_per_estimate"])
    assert summary["streams"] == expected["streams"]
    assert summary["verdict"] == "streams" if expected["streams"] else summary["verdict"].startswith("grows: ")
    table = "\n".join(bm.format_memory(rows))
    assert "quarter_car" in table and "Verdict" in table and "tracemalloc short" in table


def _row(rss: float, estimates: int) -> dict[str, Any]:
    return {"peak_rss_mb": rss, "estimates": estimates}


def test_verdict_rule() -> None:
    per = 1000.0  # bytes per estimate
    short = _row(200.0, 6000)
    # 354 000 extra estimates of 1000 B: 337.6 MB explained, plus 5 % of 200 MB
    explained = 354_000 * per / MB
    ok = bm.verdict(short, _row(200.0 + explained + 9.9, 360_000), per)
    assert ok["streams"] and ok["slack_mb"] == pytest.approx(10.0)
    assert ok["outputs_in_memory_mb"] == pytest.approx(explained)
    assert ok["growth_pct"] == pytest.approx(100 * (explained + 9.9) / 200.0)
    bad = bm.verdict(short, _row(200.0 + explained + 10.1, 360_000), per)
    assert not bad["streams"]
    # no more estimates: only the slack is allowed; a smaller peak always streams
    assert not bm.verdict(short, _row(211.0, 6000), per)["streams"]
    assert bm.verdict(short, _row(190.0, 3000), per)["streams"]


def test_what_grows_names_the_stages() -> None:
    short = {"held_replay_mb": 1.0, "peak_replay_mb": 2.0, "held_end_mb": 0.5, "peak_closing_mb": 5.0}
    long = {
        "held_replay_mb": 2.0,
        "peak_replay_mb": 4.0,
        "held_end_mb": 0.5,
        "peak_closing_mb": 7.0,
        "sites_replay": [("estimate_truth.py:191", 2.0)],
    }
    text = bm._what_grows(short, long, scale=10.0)
    assert "held after the replay +10.0 MB" in text and "replay peak above it +10.0 MB" in text
    assert "held at the end +0.0 MB" in text and "closing peak +10.0 MB" in text
    assert "estimate_truth.py:191 2.0" in text


def test_format_batch_and_roles() -> None:
    assert bm._role(["python", "-c", "from multiprocessing.spawn import spawn_main; spawn_main()"]) == "worker"
    assert bm._role(["python", "-c", "from multiprocessing.resource_tracker import main;main(5)"]) == "resource tracker"
    fork = ["python", "-c", "from multiprocessing.forkserver import main; main(31, 32)"]
    assert bm._role(fork, ["python", "-m", "terrain_analysis.tools.batch"]) == "forkserver"
    assert bm._role(fork, fork) == "worker"  # forked by the forkserver: its command line
    rows = [
        {
            "workers": 2,
            "bags": 4,
            "bag_s": 240.0,
            "exit": 0,
            "wall_s": 60.0,
            "batch_peak_rss_mb": 150.0,
            "worker_peak_rss_mb": [240.0, 230.0],
            "other_peak_rss_mb": [13.0],
            "last_line": "",
        }
    ]
    lines = bm.format_batch(rows)
    assert "240, 230" in lines[-1] and "(13)" in lines[-1] and "4.0" in lines[-1]


def test_cli_refuses_bad_lengths(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        bm.main(["--short-s", "60", "--long-s", "30"])
    assert exc.value.code == 2
    assert "--long-s" in capsys.readouterr().err


def test_keep_directory_refuses_a_foreign_one(tmp_path: Path) -> None:
    (tmp_path / "mine.txt").write_text("x")
    with pytest.raises(FileExistsError):
        bm.keep_directory(tmp_path)
    fresh = bm.keep_directory(tmp_path / "new")
    assert (fresh / bm.KEEP_MARKER).is_file()
    assert bm.keep_directory(fresh) == fresh  # its own: reused
