"""The message loops of ``terrain-estimate`` (:func:`terrain_estimation.tools.estimate.run_adapter`).

Two loops feed an adapter the input messages of a bag in recorded order, through the node's input checks
(:class:`~terrain_estimation.ros.validation.InputGuard`), and give the same estimates:

* :func:`replay_messages`, the previous path: every message decoded into its rclpy object, checked by
  :meth:`InputGuard.check <terrain_estimation.ros.validation.InputGuard.check>`, handed to ``adapter.handle``.
* :func:`replay_bulk`, the default: the bag is read in windows of :data:`WINDOW` messages (it is streamed,
  never held whole). In each window, the samples of a topic that the adapter can take as numbers
  (``adapter.field_handlers``: the quarter car's and the LRV's terrain profile, four fifths of their
  messages) and whose checks need no message object
  (:meth:`InputGuard.stamp_only <terrain_estimation.ros.validation.InputGuard.stamp_only>`) are decoded
  together as arrays (:class:`~terrain_estimation.ros.cdr.StampedLayout`) and judged together on every rule
  that needs no state (:meth:`InputGuard.stateless_ok <terrain_estimation.ros.validation.InputGuard.stateless_ok>`:
  the frame, a stamp ahead of the clock, fields finite and within bounds); each then takes its turn in the
  recorded order, where only its stamp's order is left to judge (:meth:`InputGuard.check_stamp
  <terrain_estimation.ros.validation.InputGuard.check_stamp>`) before its numbers go to the adapter. A
  sample the arrays do not pass (another length, frame or encapsulation, a non-finite field, a stamp
  ahead of the clock, a value out of bounds) and every other message go the previous path's way, one by
  one, so that a rejection names the same reason; ``test/test_replay_bulk.py`` checks that both paths
  reject the same messages and give the same estimates. Samples next to each other of a topic whose only
  rule left is its stamps' order (the profile: no covariance, no accelerometer window), with a run handler
  (``adapter.field_runs``), go together: the guard accepts the run up to its first stamp not after the one
  before (:meth:`InputGuard.accept_run <terrain_estimation.ros.validation.InputGuard.accept_run>`; that one
  and the rest go one by one) and the adapter takes them in one call, each sample as its own handler would.
  The bag is read a chunk at a time (:func:`~terrain_estimation.bag.read_bag_raw_batches`).

Both loops keep the estimates in ``run.outputs``, or hand each to ``Replay.sink`` as it is made (a run that
writes them as they come: :mod:`terrain_estimation.tools.estimate_stream`); with ``Replay.truth`` the
ground-truth topics read in the same pass go to it in recorded order.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from terrain_estimation.bag import RawTally, read_bag, read_bag_raw_batches
from terrain_estimation.ros.framework import JudgedInputs
from terrain_estimation.ros.validation import InputGuard, first_nonfinite

__all__ = ["WINDOW", "Replay", "replay_bulk", "replay_messages"]

WINDOW = 1024
"""Messages read ahead and decoded together by :func:`replay_bulk` (about 60 kB of a quarter car's bag)."""

_INT64_END = 2**63
Undecodable = Callable[[str, int, BaseException], None]
Handler = Callable[[int, Sequence[float]], list[tuple[str, Any]]]
RunHandler = Callable[[Sequence[int], Sequence[Sequence[float]]], list[tuple[int, list[tuple[str, Any]]]]]
"""A handler of a run of samples (stamps ns, checked fields): (index in the run, outputs) of those with outputs."""
Sink = Callable[[str, Any, int], None]
"""Given each estimate kept, as it is made: (absolute topic, message, log time ns)."""
TruthSink = Callable[[str, Any], None]
"""Given each decoded message of a ground-truth topic read in the replay's pass: (truth topic, message)."""


class _Progress:
    """The replay's progress line on stderr, every 2 s."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.started = self.last = time.monotonic()

    def tick(self, run: Any) -> None:
        if self.enabled and time.monotonic() - self.last > 2.0:
            self.last = time.monotonic()
            print(
                f"  ... {run.inputs_read} messages, {len(run.outputs) + run.streamed} estimates,"
                f" {self.last - self.started:.0f} s",
                file=sys.stderr,
            )


def _keep(
    run: Any, outputs: Mapping[str, str], produced: list[tuple[str, Any]], log_time_ns: int, sink: Sink | None
) -> None:
    """The adapter's outputs of one message into ``run.outputs`` (or to ``sink``, counted in ``run.streamed``),
    a non-finite one counted and dropped."""
    for key, out in produced:
        bad = first_nonfinite(out)
        if bad is not None:
            reason = f"{outputs[key]}: {bad[0]} not finite"
            run.outputs_dropped[reason] = run.outputs_dropped.get(reason, 0) + 1
            continue
        if sink is None:
            run.outputs.append((outputs[key], out, log_time_ns))
        else:
            sink(outputs[key], out, log_time_ns)
            run.streamed += 1


def _rejected(run: Any, adapter: Any, rejection: Any) -> None:
    run.rejected[rejection.reason] = run.rejected.get(rejection.reason, 0) + 1
    if rejection.restart or rejection.rebase:
        run.restarts += 1
        adapter.reset()


@dataclass(frozen=True)
class Replay:
    """What both message loops are given by :func:`~terrain_estimation.tools.estimate.run_adapter`.

    Attributes:
        run: the :class:`~terrain_estimation.tools.estimate.EstimationRun` filled in.
        adapter: the vehicle's adapter.
        bag: the bag; ``read``: the topics read (the inputs, and the truth on the previous path); ``types``:
            topic -> expected type.
        undecodable: told of each message whose bytes do not decode (it counts them in ``run``).
        inputs: absolute input topic -> adapter key; ``outputs``: adapter output key -> absolute topic.
        guard: the node's input checks (None: none).
        progress: a progress line on stderr every 2 s.
        sink: given each estimate as it is made, instead of ``run.outputs`` (None: kept there).
        truth: given the messages of the topics of ``read`` that are not inputs (ground truth), in recorded
            order (None: the previous path's ``eager`` collects them).
    """

    run: Any
    adapter: Any
    bag: str | Path
    read: list[str]
    types: Mapping[str, str]
    undecodable: Undecodable
    inputs: Mapping[str, str]
    outputs: Mapping[str, str]
    guard: InputGuard | None
    progress: bool
    sink: Sink | None = None
    truth: TruthSink | None = None


def replay_messages(r: Replay, truth_topics: Mapping[str, str], eager: dict[str, list[Any]]) -> None:
    """The previous path (module docstring): every message decoded, checked and handled as an object; the
    ground truth (``truth_topics``, when ``r.read`` has them) collected into ``eager`` (or given to ``r.truth``)."""
    run, adapter, inputs, outputs, guard = r.run, r.adapter, r.inputs, r.outputs, r.guard
    eager_truth = len(r.read) > len(inputs)
    judged = isinstance(adapter, JudgedInputs)
    ticker = _Progress(r.progress)
    for item in read_bag(r.bag, r.read, types=r.types, on_undecodable=r.undecodable):
        if eager_truth and item.topic in truth_topics:
            if r.truth is not None:
                r.truth(item.topic, item.msg)
            else:
                eager.setdefault(truth_topics[item.topic], []).append(item.msg)
            continue
        run.inputs_read += 1
        run.topics_read[item.topic] = run.topics_read.get(item.topic, 0) + 1
        key_in = inputs[item.topic]
        if guard is not None:
            rejection = guard.check(key_in, item.msg, item.log_time_ns * 1e-9)
            if rejection is not None:
                _rejected(run, adapter, rejection)
                continue
            if judged:  # estimates made before the gravity check has judged every accelerometer are not converged
                adapter.inputs_judged = guard.gravity_judged
        run.accepted += 1
        _keep(run, outputs, adapter.handle(key_in, item.msg), item.log_time_ns, r.sink)
        ticker.tick(run)


class _Lane:
    """An input topic :func:`replay_bulk` decodes and judges in bulk: its key, layout, the adapter's handler,
    how many of the decoded columns are checked fields (the rest: covariances, ``widths`` each), and the
    adapter's handler of a run of its samples (``adapter.field_runs``; None: one by one)."""

    def __init__(
        self, key: str, layout: Any, handler: Handler, checked: int, widths: Sequence[int], run: RunHandler | None
    ) -> None:
        self.key, self.layout, self.handler, self.checked, self.widths = key, layout, handler, checked, tuple(widths)
        self.run = run


def _lanes(adapter: Any, guard: InputGuard | None, topics: Mapping[str, str]) -> dict[str, _Lane]:
    """Absolute topic -> its :class:`_Lane`, for the inputs :func:`replay_bulk` decodes and judges in bulk."""
    from terrain_estimation.ros.cdr import stamped_layout

    handlers: Mapping[str, Handler] = getattr(adapter, "field_handlers", None) or {}
    runs: Mapping[str, RunHandler] = getattr(adapter, "field_runs", None) or {}
    if guard is None or not handlers:
        return {}
    lanes: dict[str, _Lane] = {}
    for topic, key in topics.items():
        handler = handlers.get(key)
        fields = guard.array_fields(key) if handler is not None else ()
        if handler is None or not fields:
            continue
        spec = guard.inputs[key]
        layout = stamped_layout(spec.msg_type, spec.frame_id, fields)
        if layout is None:
            continue
        checked = len(fields) - len(spec.covariances)
        widths = [layout.dtype[f"v{i}"].shape[0] if layout.dtype[f"v{i}"].shape else 1 for i in range(len(fields))]
        run = runs.get(key) if guard.order_only(key) else None
        lanes[topic] = _Lane(key, layout, handler, checked, widths[checked:], run)
    return lanes


def replay_bulk(r: Replay) -> None:
    """The default path (module docstring): windows of messages, the adapter's numeric inputs in bulk."""
    run, adapter, inputs, outputs, guard, undecodable = r.run, r.adapter, r.inputs, r.outputs, r.guard, r.undecodable
    sink, truth = r.sink, r.truth if r.truth is not None else _no_truth
    lanes = _lanes(adapter, guard, inputs)
    judged = isinstance(adapter, JudgedInputs)
    ticker = _Progress(r.progress)
    tally = RawTally()
    window: list[tuple[Any, int, bytes, Callable[[bytes], Any]]] = []

    def flush() -> None:
        bulk, runs = _decode_window(window, lanes, guard) if lanes else ({}, {})
        i, end = 0, len(window)
        while i < end:
            conn, log_time_ns, raw, decode = window[i]
            i += 1
            topic = conn.topic
            sample = bulk.get(i - 1)
            last = runs.get(i - 1)
            if last is not None:  # a run of samples left only their stamps' order to judge
                taken = _take_run(run, adapter, lanes[topic], guard, judged, bulk, window, i - 1, last, outputs, sink)
                if taken:
                    i += taken - 1
                    continue
            if sample is None:
                try:
                    msg = decode(raw)
                except Exception as exc:  # one message's bytes: reject it and go on, as the nodes do
                    tally.undecodable(topic, exc)
                    undecodable(topic, log_time_ns, exc)
                    continue
            if topic not in inputs:  # a ground-truth topic (read only for ``r.truth``)
                truth(topic, msg)
                continue
            run.inputs_read += 1
            run.topics_read[topic] = run.topics_read.get(topic, 0) + 1
            key_in = inputs[topic]
            if guard is not None:
                if sample is None:
                    rejection = guard.check(key_in, msg, log_time_ns * 1e-9)
                else:
                    rejection = guard.check_decoded(key_in, sample[0], sample[1], sample[2])
                if rejection is not None:
                    _rejected(run, adapter, rejection)
                    continue
                if judged:  # estimates made before the gravity check has judged every accelerometer: not converged
                    adapter.inputs_judged = guard.gravity_judged
            run.accepted += 1
            if sample is None:
                produced = adapter.handle(key_in, msg)
            else:
                produced = lanes[topic].handler(sample[0], sample[1])
            if produced:
                _keep(run, outputs, produced, log_time_ns, sink)
        ticker.tick(run)
        window.clear()

    for batch in read_bag_raw_batches(r.bag, r.read, types=r.types, tally=tally):
        start = 0
        while start < len(batch):  # windows of WINDOW messages, wherever the batches end
            room = WINDOW - len(window)
            window.extend(batch[start : start + room])
            start += room
            if len(window) >= WINDOW:
                flush()
    flush()


def _take_run(
    run: Any,
    adapter: Any,
    lane: _Lane,
    guard: Any,
    judged: bool,
    bulk: Mapping[int, tuple[int, list[float], list[np.ndarray]]],
    window: Sequence[tuple[Any, int, bytes, Any]],
    first: int,
    last: int,
    outputs: Mapping[str, str],
    sink: Sink | None,
) -> int:
    """The lane samples ``window[first:last + 1]`` (a run of one :meth:`~InputGuard.order_only` topic that passed
    the checks on arrays) as the one-by-one loop takes them, while the guard accepts them
    (:meth:`~InputGuard.accept_run`), through the lane's run handler: how many it took (the next, if any, goes
    the one-by-one way)."""
    stamps = [bulk[j][0] for j in range(first, last + 1)]
    taken = guard.accept_run(lane.key, stamps)
    if not taken:
        return 0
    topic = window[first][0].topic
    run.inputs_read += taken
    run.topics_read[topic] = run.topics_read.get(topic, 0) + taken
    if judged:  # (the guard's verdict is the same for the whole run: no accelerometer in it)
        adapter.inputs_judged = guard.gravity_judged
    run.accepted += taken
    if taken < len(stamps):
        del stamps[taken:]
    assert lane.run is not None
    for offset, produced in lane.run(stamps, [bulk[j][1] for j in range(first, first + taken)]):
        _keep(run, outputs, produced, window[first + offset][1], sink)
    return taken


def _no_truth(topic: str, _msg: Any) -> None:
    raise AssertionError(f"{topic}: read by replay_bulk without a truth sink")


def _decode_window(
    window: Sequence[tuple[Any, int, bytes, Any]], lanes: Mapping[str, _Lane], guard: InputGuard | None
) -> tuple[dict[int, tuple[int, list[float], list[np.ndarray]]], dict[int, int]]:
    """Index in ``window`` -> (stamp ns, checked fields, covariances) of the lane samples that passed the
    checks on arrays (:meth:`~terrain_estimation.ros.validation.InputGuard.stateless_ok`), and, for the lanes
    with a run handler, the runs of two or more such samples next to each other: first index -> last."""
    assert guard is not None
    out: dict[int, tuple[int, list[float], list[np.ndarray]]] = {}
    runs: dict[int, int] = {}
    by_topic: dict[str, list[int]] = {}
    for i, item in enumerate(window):
        by_topic.setdefault(item[0].topic, []).append(i)
    for topic, lane in lanes.items():
        length = lane.layout.length
        # (a log time past int64, from a damaged bag, goes the one-by-one way too)
        rows = [i for i in by_topic.get(topic, ()) if len(window[i][2]) == length and window[i][1] < _INT64_END]
        if not rows:
            continue
        match, stamp_ns, values = lane.layout.decode([window[i][2] for i in rows])
        clock_ns = np.array([window[i][1] for i in rows], dtype=np.int64)
        checked = values[:, : lane.checked]
        ok = match & guard.stateless_ok(lane.key, stamp_ns, clock_ns, checked)
        stamps, numbers = stamp_ns.tolist(), checked.tolist()
        passed = np.flatnonzero(ok).tolist()
        if lane.run is not None:
            _find_runs([rows[j] for j in passed], runs)
        if not lane.widths:
            for j in passed:
                out[rows[j]] = (stamps[j], numbers[j], [])
            continue
        bounds = np.cumsum((lane.checked, *lane.widths)).tolist()
        spans = list(zip(bounds[:-1], bounds[1:], strict=True))
        for j in passed:
            row = values[j]
            out[rows[j]] = (stamps[j], numbers[j], [row[a:b] for a, b in spans])
    return out, runs


def _find_runs(indices: Sequence[int], runs: dict[int, int]) -> None:
    """The runs of two or more consecutive numbers in the increasing ``indices`` into ``runs``: first -> last."""
    start = previous = -2
    for index in indices:
        if index != previous + 1:
            if previous > start:
                runs[start] = previous
            start = index
        previous = index
    if previous > start:
        runs[start] = previous
