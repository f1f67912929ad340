"""Fuzzed input through every estimator's input checks and adapter (issue 7 must-show).

Real message streams from the bundled bags are corrupted by hypothesis: any
float field of any message set to NaN, ±inf, a huge or a tiny value, stamps
moved far ahead, back, or duplicated, frame ids replaced, arrays truncated.
Each message goes through the node's path (:class:`InputGuard`, then the
adapter), as :class:`~terrain_estimation.ros.framework.EstimatorNode` runs
it. Whatever the input, nothing raises, and every estimate the adapter
returns is finite: the framework's last-resort output check (which would drop
a non-finite estimate) never has to act.
"""

from __future__ import annotations

import copy
import math
from functools import cache
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from robustness_harness import float_paths

from terrain_estimation.bag import read_bag
from terrain_estimation.ros.time import ns_to_stamp, stamp_to_ns
from terrain_estimation.ros.validation import InputGuard, first_nonfinite
from terrain_estimation.tools.estimate import topic_name
from terrain_estimation.vehicles import VEHICLES, estimator_parameters

BAGS = Path(__file__).resolve().parents[1] / "bags"
STREAMS = {
    "quarter_car": ("quarter_car_graneville_iso_d_10ms", 700),
    "lrv": ("lrv_regolith_iso_g_2ms", 700),
    "skid_steer": ("skid_steer_s_shape", 400),
    "rover": ("rover_terrain_1", 400),
}
HOSTILE = [math.nan, math.inf, -math.inf, 1e300, -1e300, 1e-300, 0.0, -1.0]


@cache
def _stream(vehicle: str) -> tuple[tuple[str, Any, int], ...]:
    """The first input messages of the vehicle's bundled bag: (input key, message, log time)."""
    entry = VEHICLES[vehicle]
    adapter = entry.make_adapter(estimator_parameters(entry, None), entry.namespace)
    keys = {topic_name(entry.namespace, s.topic): s.key for s in adapter.inputs}
    name, count = STREAMS[vehicle]
    out = []
    for item in read_bag(BAGS / name, list(keys)):
        out.append((keys[item.topic], item.msg, item.log_time_ns))
        if len(out) >= count:
            break
    return tuple(out)


def _set(msg: Any, path: str, value: float) -> None:
    *parents, last = path.split(".")
    obj = msg
    for part in parents:
        obj = getattr(obj, part)
    if last.endswith("]"):
        attr, index = last[:-1].split("[")
        items = list(getattr(obj, attr))
        items[int(index)] = value
        setattr(obj, attr, items)
    else:
        setattr(obj, last, value)


corruption = st.tuples(
    st.integers(min_value=0, max_value=10_000),  # which message (mod stream length)
    st.sampled_from(["float", "stamp_ahead", "stamp_back", "stamp_repeat", "frame", "truncate"]),
    st.integers(min_value=0, max_value=10_000),  # which field
    st.sampled_from(HOSTILE),
)


def _apply(msg: Any, kind: str, which: int, value: float, previous_ns: int) -> Any:
    msg = copy.deepcopy(msg)
    if kind == "float":
        paths = float_paths(msg)
        if paths:
            _set(msg, paths[which % len(paths)], value)
    elif kind == "stamp_ahead":
        msg.header.stamp = ns_to_stamp(stamp_to_ns(msg.header.stamp) + 10**9 * (1 + which) * 3600)
    elif kind == "stamp_back":
        msg.header.stamp = ns_to_stamp(max(0, stamp_to_ns(msg.header.stamp) - 10**9 * (1 + which % 100)))
    elif kind == "stamp_repeat":
        msg.header.stamp = ns_to_stamp(previous_ns)
    elif kind == "frame":
        msg.header.frame_id = "not_the_frame"
    elif kind == "truncate":
        for name in ("velocity", "position", "effort"):
            if hasattr(msg, name):
                setattr(msg, name, [])
    return msg


@pytest.mark.parametrize("vehicle", sorted(STREAMS))
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(corruptions=st.lists(corruption, min_size=1, max_size=40))
def test_fuzzed_stream_never_raises_and_never_yields_a_non_finite_estimate(vehicle: str, corruptions) -> None:
    entry = VEHICLES[vehicle]
    values = estimator_parameters(entry, None)
    adapter = entry.make_adapter(values, entry.namespace)
    guard = InputGuard(adapter.inputs, values)
    stream = _stream(vehicle)
    plan: dict[int, list[tuple[str, int, float]]] = {}
    for index, kind, which, value in corruptions:
        plan.setdefault(index % len(stream), []).append((kind, which, value))
    previous_ns = 0
    estimates = 0
    for i, (key, msg, log_ns) in enumerate(stream):
        for kind, which, value in plan.get(i, []):
            msg = _apply(msg, kind, which, value, previous_ns)
        previous_ns = stamp_to_ns(msg.header.stamp)
        rejection = guard.check(key, msg, log_ns * 1e-9)
        if rejection is not None:
            if rejection.restart or rejection.rebase:
                adapter.reset()
            continue
        for _out_key, out in adapter.handle(key, msg):
            estimates += 1
            assert first_nonfinite(out) is None, (vehicle, first_nonfinite(out))
    assert estimates > 0  # the stream still produced estimates


def test_a_load_cell_reading_beyond_the_sides_weight_is_rejected_alone() -> None:
    """A rover load cell at 1e300 N passed the finite check and made the published W variance inf."""
    entry = VEHICLES["rover"]
    values = estimator_parameters(entry, None)
    adapter = entry.make_adapter(values, entry.namespace)
    guard = InputGuard(adapter.inputs, values)
    stream = _stream("rover")
    cells = [(i, key) for i, (key, _msg, _ns) in enumerate(stream) if key.startswith("load_")]
    assert cells, "the rover stream has no load-cell message"
    index, key = cells[0]
    rejections = []
    for i, (k, msg, log_ns) in enumerate(stream):
        if i == index:
            msg = copy.deepcopy(msg)
            msg.wrench.force.z = 1e300
        rejection = guard.check(k, msg, log_ns * 1e-9)
        if rejection is not None:
            rejections.append(rejection)
            continue
        for _out_key, out in adapter.handle(k, msg):
            assert first_nonfinite(out) is None
    assert len(rejections) == 1, rejections
    text = str(rejections[0])
    assert "wrench.force.z" in text and "1e+300" in text and "load" in text, text
