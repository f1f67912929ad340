"""terrain-estimate writes each estimate as it is made (issue 23, memory).

The streamed run (:func:`~terrain_estimation.tools.estimate.estimate_to_bag`) must write the bag the run in
memory wrote (same connections, definitions, messages, order, log times) and print the same summary, keep no
estimate, and follow the tools' rules: a message rejected midway costs nothing already estimated (the bag is
closed and readable); a run that estimates nothing, or stops, leaves no output; a path it did not make is
never touched. No memory figure is asserted here (``python -m terrain_analysis.tools.bench_memory``).
"""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any

import pytest

from terrain_estimation.bag import AtomicBagWriter, BagError
from terrain_estimation.cli import InputError
from terrain_estimation.tools import estimate as est
from terrain_estimation.tools import estimate_truth
from terrain_estimation.tools.estimate import EstimationRun, _summary_lines, estimate_bag, estimate_to_bag
from terrain_estimation.tools.estimate_truth import TruthTally, numeric_fields, streamed_truth_errors

BAGS = Path(__file__).resolve().parents[1] / "bags"
SHIPPED = {
    "quarter_car": "quarter_car_graneville_iso_d_10ms",
    "lrv": "lrv_regolith_iso_g_2ms",
    "skid_steer": "skid_steer_s_shape",
    "rover": "rover_terrain_2",
}


def _content(bag: Path) -> tuple[list[tuple[Any, ...]], list[tuple[Any, ...]]]:
    """Every connection (topic, type, definition) and message (topic, log time, bytes) read back by AnyReader."""
    from rosbags.highlevel import AnyReader

    from terrain_estimation.bag import typestore

    with AnyReader([bag], default_typestore=typestore()) as reader:
        connections = [(c.id, c.topic, c.msgtype, c.msgdef.data, c.msgdef.format) for c in reader.connections]
        messages = [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]
    return connections, messages


@pytest.mark.parametrize("vehicle", sorted(SHIPPED))
def test_streamed_bag_and_summary_are_the_held_runs(vehicle: str, tmp_path: Path) -> None:
    bag = BAGS / SHIPPED[vehicle]
    held = estimate_bag(bag, vehicle)
    with AtomicBagWriter(tmp_path / "held", inputs=[bag]) as writer:
        writer.write_all(held.outputs)
    lines: list[str] = []
    run, written = estimate_to_bag(bag, vehicle, tmp_path / "streamed", report=lines.append)
    assert run.outputs == [] and run.streamed == written == len(held.outputs) > 0
    assert _content(tmp_path / "streamed") == _content(tmp_path / "held")
    assert lines == list(_summary_lines(held))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["held", "streamed"]  # no partial bag left


def test_estimates_are_written_while_the_bag_is_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The writer gets each estimate during the replay, not all of them at its end."""
    reads_at_write: list[int] = []
    runs: list[EstimationRun] = []
    real_run_adapter = est.run_adapter

    def spy_run_adapter(*args: Any, **kwargs: Any) -> EstimationRun:
        sink = kwargs["sink"]
        real_write = sink.writer.write

        def write(topic: str, msg: Any, log_time_ns: int) -> None:
            reads_at_write.append(runs[0].inputs_read if runs else -1)
            real_write(topic, msg, log_time_ns)

        sink.writer.write = write
        real_init = EstimationRun.__init__

        def init(self: EstimationRun, *a: Any, **k: Any) -> None:
            real_init(self, *a, **k)
            runs.append(self)

        monkeypatch.setattr(EstimationRun, "__init__", init)
        return real_run_adapter(*args, **kwargs)

    monkeypatch.setattr(est, "run_adapter", spy_run_adapter)
    run, written = estimate_to_bag(BAGS / SHIPPED["skid_steer"], "skid_steer", tmp_path / "out")
    assert len(reads_at_write) == written > 0
    assert reads_at_write[0] < run.inputs_read // 2 and reads_at_write == sorted(reads_at_write)


def _damaged(case_name: str, vehicle: str, target: Path) -> Path:
    from terrain_analysis.tools.mutations import MUTATIONS, damage
    from terrain_estimation.vehicles import get_vehicle

    case = next(c for c in MUTATIONS if c.name == case_name)
    entry = get_vehicle(vehicle)
    adapter = entry.make_adapter(est.config_values(entry), entry.namespace)
    accel = next(s.topic for s in adapter.inputs if s.gravity_fields)
    return damage(case, BAGS / SHIPPED[vehicle], target, accel)


@pytest.mark.parametrize("case", ["nan", "garbage", "reorder"])
def test_a_message_rejected_midway_loses_no_estimate(case: str, tmp_path: Path, capsys: Any) -> None:
    """The bag is closed properly and holds the estimates from before and after the bad message."""
    bag = _damaged(case, "quarter_car", tmp_path / "input")
    out = tmp_path / "out"
    assert est.main([str(bag), "--vehicle", "quarter_car", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "rejected 1:" in printed or "rejected 2:" in printed
    held = estimate_bag(bag, "quarter_car")
    with AtomicBagWriter(tmp_path / "held", inputs=[bag]) as writer:
        writer.write_all(held.outputs)
    assert _content(out) == _content(tmp_path / "held")
    clean = estimate_bag(BAGS / SHIPPED["quarter_car"], "quarter_car")
    # the estimates made before the damage are the clean bag's, and the run went on after it
    same = 0
    for (topic, msg, t), (ctopic, cmsg, ct) in zip(held.outputs, clean.outputs, strict=False):
        if (topic, t, numeric_fields(msg)) != (ctopic, ct, numeric_fields(cmsg)):
            break
        same += 1
    assert 0 < same < len(held.outputs) and held.outputs[-1][2] > clean.outputs[same][2]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["held", "input", "out"]


def test_no_estimate_leaves_nothing(tmp_path: Path) -> None:
    """A wrong namespace: exit 2, no output, no partial bag, not even the parent directories it would have made."""
    out = tmp_path / "new" / "deeper" / "out"
    status = est.main([str(BAGS / SHIPPED["lrv"]), "--vehicle", "lrv", "--namespace", "/nobody", "-o", str(out)])
    assert status == 2
    assert list(tmp_path.iterdir()) == []


def test_a_path_the_tool_did_not_make_is_untouched(tmp_path: Path) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("a user's file\n")
    for extra in ([], ["--overwrite"]):
        status = est.main([str(BAGS / SHIPPED["lrv"]), "--vehicle", "lrv", "-o", str(out), *extra])
        assert status == 2
        assert [p.name for p in out.iterdir()] == ["notes.txt"]
        assert (out / "notes.txt").read_text() == "a user's file\n"
    assert [p.name for p in tmp_path.iterdir()] == ["mine"]


def test_a_run_that_stops_midway_leaves_no_bag(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An internal error after some estimates were written: the partial bag goes, a previous bag stays."""
    out = tmp_path / "out"
    estimate_to_bag(BAGS / SHIPPED["lrv"], "lrv", out)
    before = _content(out)
    calls = {"n": 0}
    real = est.StreamedEstimates.__call__

    def failing(self: Any, topic: str, msg: Any, log_time_ns: int) -> None:
        calls["n"] += 1
        if calls["n"] > 50:
            raise RuntimeError("boom")
        real(self, topic, msg, log_time_ns)

    monkeypatch.setattr(est.StreamedEstimates, "__call__", failing)
    with pytest.raises(RuntimeError, match="boom"):
        estimate_to_bag(BAGS / SHIPPED["lrv"], "lrv", out, overwrite=True)
    assert _content(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_an_unreadable_bag_leaves_no_bag(tmp_path: Path) -> None:
    bag = _damaged("truncated", "skid_steer", tmp_path / "input")
    with pytest.raises(BagError, match="unreadable"):
        estimate_to_bag(bag, "skid_steer", tmp_path / "out")
    assert [p.name for p in tmp_path.iterdir()] == ["input"]
    with pytest.raises(InputError):
        estimate_to_bag(BAGS / SHIPPED["lrv"], "lrv", tmp_path / "out", namespace="/nobody")
    assert [p.name for p in tmp_path.iterdir()] == ["input"]


# -- the running comparison with ground truth ------------------------------------------------------------------


class _Stamp:
    def __init__(self, ns: int) -> None:
        self.sec, self.nanosec = divmod(ns, 1_000_000_000)


class _Header:
    def __init__(self, ns: int) -> None:
        self.stamp = _Stamp(ns)


class _Msg:
    """A message with a header and two numeric fields, as :func:`numeric_fields` walks them."""

    def __init__(self, ns: int, a: float, b: float) -> None:
        self.header, self.a, self.b = _Header(ns), a, b

    def get_fields_and_field_types(self) -> dict[str, str]:
        return {"header": "std_msgs/Header", "a": "double", "b": "double"}


def _scenario(seed: int, lag: int = 3) -> list[tuple[str, _Msg]]:
    """Truth at 100 Hz (one pair of stamps swapped), estimates at 50 Hz recorded up to ``lag`` samples before
    or after their truth, two of them before any truth, one with the stamp of a truth sample."""
    rng = random.Random(seed)
    events: list[tuple[float, str, _Msg]] = []
    truth_stamps = [10_000_000 * i + 5_000_000_000 for i in range(400)]
    truth_stamps[100], truth_stamps[101] = truth_stamps[101], truth_stamps[100]
    for i, ns in enumerate(truth_stamps):
        events.append((i, "truth", _Msg(ns, math.sin(i / 30), 2.0 + 0.01 * i)))
    for j in range(205):
        ns = 20_000_000 * j + 4_970_000_000 + rng.choice((0, 3_000_000, 10_000_000))
        where = (ns - 5_000_000_000) / 10_000_000 + rng.uniform(-lag, lag)
        events.append((where, "estimate", _Msg(ns, math.sin(j / 15) + rng.gauss(0, 0.1), 2.0 + rng.gauss(0, 0.5))))
    events.sort(key=lambda e: e[0])
    return [(kind, msg) for _, kind, msg in events]


def _reference(events: list[tuple[str, _Msg]]) -> dict[str, tuple[float, float, float]]:
    run = EstimationRun(
        outputs=[("/e", m, 0) for kind, m in events if kind == "estimate"], truth_fields={"/e": ("a", "b")}
    )
    run.truth_reader = lambda: iter([("/e", m) for kind, m in events if kind == "truth"])
    return streamed_truth_errors(run)["/e"]


@pytest.mark.parametrize("seed", range(5))
def test_truth_tally_pairs_as_the_streamed_errors(seed: int) -> None:
    events = _scenario(seed)
    tally = TruthTally(("a", "b"))
    for kind, msg in events:
        (tally.estimate if kind == "estimate" else tally.truth)(msg)
    got, want = tally.figures(), _reference(events)
    assert set(got) == set(want) == {"a", "b"}
    for name in want:
        assert got[name][1:] == want[name][1:]  # final errors: the same pairing, to the bit
        assert got[name][0] == pytest.approx(want[name][0], rel=1e-14, abs=0.0)  # summed another way
    assert tally.beyond_history == 0 and tally.pending == []


def test_truth_tally_without_truth_or_beyond_its_history(monkeypatch: pytest.MonkeyPatch) -> None:
    tally = TruthTally(("a",))
    tally.estimate(_Msg(1, 1.0, 0.0))
    assert tally.figures() == {}
    monkeypatch.setattr(estimate_truth, "HISTORY", 8)
    events = _scenario(0, lag=1)
    late = [e for e in events if e[0] == "estimate"][:3]  # three estimates recorded after every truth
    tally = TruthTally(("a", "b"))
    for kind, msg in [e for e in events if not any(e is x for x in late)] + late:
        (tally.estimate if kind == "estimate" else tally.truth)(msg)
    tally.figures()
    assert tally.beyond_history > 0
