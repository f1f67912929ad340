"""The soil-stiffness adapter's run of profile samples (``handle_profile_run``, the offline replay's path)
does what ``handle_profile`` does sample by sample: the same estimates, bit for bit, and the same buffers and
counters, also where the estimator rejects a sample inside a run (a stamp 1 ns after the one before passes
the node's checks, not the estimator's 1 ns tolerance) and where a run ends in a filter step."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from rclpy.serialization import serialize_message

from terrain_estimation.bag import _canonical_cdr, msgtype_of, read_bag
from terrain_estimation.ros.time import stamp_to_ns
from terrain_estimation.tools import estimate as te
from terrain_estimation.vehicles import get_vehicle

BAGS = Path(__file__).resolve().parents[1] / "bags"


def _adapter(vehicle: str) -> Any:
    entry = get_vehicle(vehicle)
    return entry.make_adapter(te.config_values(entry), entry.namespace)


def _cdr(msg: Any) -> bytes:
    """The message's canonical bytes (serialize_message leaves its padding as it finds it)."""
    return _canonical_cdr(serialize_message(msg), msgtype_of(msg))


def _state(adapter: Any) -> tuple[Any, ...]:
    e = adapter.estimator
    return (list(e._pt), list(e._ph), list(e._ps), e._last_distance, dict(e.counts), e._profile_wait)


@pytest.mark.parametrize(
    ("bag", "vehicle"), [("quarter_car_graneville_iso_d_10ms", "quarter_car"), ("lrv_regolith_iso_g_2ms", "lrv")]
)
def test_profile_runs_do_what_single_samples_do(bag: str, vehicle: str) -> None:
    one, runs = _adapter(vehicle), _adapter(vehicle)
    assert "profile" in runs.field_runs
    out_one: list[bytes] = []
    out_runs: list[bytes] = []
    pending: list[tuple[int, tuple[float, float]]] = []
    n_profile = 0

    def flush() -> None:
        produced = runs.handle_profile_run([s for s, _ in pending], [v for _, v in pending])
        out_runs.extend(_cdr(m) for _, batch in produced for _k, m in batch)
        pending.clear()

    previous = 0
    for item in read_bag(BAGS / bag):
        key = next((spec.key for spec in one.inputs if item.topic.endswith("/" + spec.topic)), None)
        if key is None:  # not an input (clock, ground truth)
            continue
        if key == "profile":
            n_profile += 1
            stamp = stamp_to_ns(item.msg.header.stamp)
            if n_profile % 97 in (0, 1):  # 1 ns after the one before: rejected by the estimator, not the guard
                stamp = previous + 1
            previous = stamp
            values = (item.msg.point.x, item.msg.point.z)
            out_one.extend(_cdr(m) for _k, m in one.handle_profile(stamp, values))
            pending.append((stamp, values))
            continue
        flush()
        out_one.extend(_cdr(m) for _k, m in one.handle(key, item.msg))
        out_runs.extend(_cdr(m) for _k, m in runs.handle(key, item.msg))
        assert _state(one) == _state(runs)
    flush()
    assert len(out_one) > 300
    assert out_one == out_runs
    assert _state(one) == _state(runs)
    assert one.estimator.counts["profile_rejected"] > 30  # the 1 ns samples were rejected inside runs
