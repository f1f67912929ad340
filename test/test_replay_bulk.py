"""The offline replay's bulk path rejects the same messages as the live node's checks, and estimates the same.

``estimate_bag`` decodes the quarter car's and the LRV's numeric inputs (terrain profile, accelerometers) in
windows, as arrays, and judges the rules that need no state on arrays
(:func:`terrain_estimation.tools.estimate_replay.replay_bulk`); the previous path (``bulk=False``) decodes
every message into its rclpy object and runs the live node's :class:`InputGuard.check` on it. Bad samples of
every kind the checks know (wrong frame, a stamp ahead of the clock, duplicated, out of order, a time line
that went back for good, NaN and infinite fields, a glitch beyond the accelerometer's range, covariances not
finite, not symmetric or not measured, an accelerometer in g for a while, another frame length) are slipped
into the shipped quarter-car bag: both paths must count the same rejections and write the same estimates,
bit for bit. The bulk path takes runs of profile samples together (the guard's stamp order over the run, the
estimator's buffer filled up to the sample that completes a step); the tampered samples break runs where
the guard or the estimator (a stamp 1 ns after the one before) rejects a sample.
"""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import PointStamped
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu

from terrain_estimation.bag import AtomicBagWriter, _canonical_cdr, msgtype_of, read_bag
from terrain_estimation.ros.cdr import decoder_for, stamped_layout
from terrain_estimation.ros.time import ns_to_stamp, stamp_to_ns
from terrain_estimation.tools import estimate_replay
from terrain_estimation.tools.estimate import estimate_bag

BAGS = Path(__file__).resolve().parents[1] / "bags"
QC = BAGS / "quarter_car_graneville_iso_d_10ms"
YEAR_NS = 365 * 24 * 3600 * 1_000_000_000


def _tamper(msg: Any, topic: str, n: int, previous: dict[str, int]) -> Any:
    """The ``n``-th message of ``topic`` (1-based), damaged in one of the ways the checks know, or as it is."""
    if not hasattr(msg, "header"):
        return msg
    stamp = stamp_to_ns(msg.header.stamp)
    if topic.endswith("terrain/profile"):
        if n == 50:
            msg.header.frame_id = "elsewhere"  # another frame, of the same length or not
        elif n == 51:
            msg.header.frame_id = "odox"
        elif n == 60:
            msg.point.z = math.nan
        elif n == 61:
            msg.point.x = math.inf
        elif n == 70:
            msg.header.stamp = ns_to_stamp(stamp + YEAR_NS)
        elif n == 80:
            msg.header.stamp = ns_to_stamp(previous[topic])  # a duplicate
        elif n in (2500, 2501):
            # 1 ns after the one before: the guard's order passes it, the estimator's tolerance not (in a run)
            msg.header.stamp = ns_to_stamp(previous[topic] + 1)
            stamp = previous[topic] + 1
        elif 200 <= n < 205:
            msg.header.stamp = ns_to_stamp(stamp - 1_000_000_000)  # out of order, a few
        elif 1000 <= n < 1060:
            msg.header.stamp = ns_to_stamp(stamp - 2_000_000_000)  # gone back for good: a new time line
    elif topic.endswith("imu/body"):
        if n == 30:
            msg.linear_acceleration_covariance[4] = math.nan
        elif n == 40:
            msg.linear_acceleration_covariance[1] = 1.0  # not symmetric
        elif n == 45:
            msg.linear_acceleration.z = 1e3  # beyond input.max_acceleration: a glitch
        elif n == 55:
            msg.header.frame_id = "elsewhere"
        elif n == 65:
            msg.header.stamp = ns_to_stamp(stamp + YEAR_NS)
        elif 120 <= n < 200:
            msg.linear_acceleration.z /= 9.80665  # in g for a while: the gravity window's verdict
    elif topic.endswith("imu/wheel"):
        if n == 70:
            msg.linear_acceleration_covariance[0] = -1.0  # not measured
        elif n == 75:
            msg.linear_acceleration.z = math.nan
        elif n == 76:
            msg.header.stamp = ns_to_stamp(previous[topic])
    previous[topic] = stamp
    return msg


@pytest.fixture(scope="module")
def tampered(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("bulk") / "tampered"
    counts: dict[str, int] = {}
    previous: dict[str, int] = {}
    with AtomicBagWriter(out) as writer:
        for item in read_bag(QC):
            counts[item.topic] = counts.get(item.topic, 0) + 1
            msg = _tamper(item.msg, item.topic, counts[item.topic], previous)
            writer.write(item.topic, msg, item.log_time_ns)
    return out


def _digest(run: Any) -> list[tuple[str, int, bytes]]:
    return [(t, ns, _canonical_cdr(serialize_message(m), msgtype_of(m))) for t, m, ns in run.outputs]


@pytest.mark.parametrize("bag", ["tampered", "quarter_car_graneville_iso_d_10ms", "lrv_regolith_iso_g_2ms"])
def test_bulk_and_message_paths_reject_the_same_and_estimate_the_same(
    bag: str, tampered: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tampered if bag == "tampered" else BAGS / bag
    vehicle = "lrv" if bag.startswith("lrv") else "quarter_car"
    decoded = []
    original = estimate_replay._decode_window

    def counting(*args: Any) -> Any:
        out = original(*args)
        decoded.append(len(out[0]))
        return out

    taken = []
    original_run = estimate_replay._take_run

    def counting_runs(*args: Any) -> int:
        out = original_run(*args)
        taken.append(out)
        return out

    monkeypatch.setattr(estimate_replay, "_decode_window", counting)
    monkeypatch.setattr(estimate_replay, "_take_run", counting_runs)
    bulk = estimate_bag(path, vehicle)
    assert sum(decoded) > 0.8 * bulk.inputs_read  # the bulk path did run: profile and accelerometers
    # ... and most profile samples went in runs (the guard's order and the estimator's buffer, per run)
    assert sum(taken) > 0.7 * bulk.topics_read[next(t for t in bulk.topics_read if t.endswith("terrain/profile"))]
    if bag == "tampered":
        assert 0 in taken  # a run whose first sample the guard did not accept: it went one by one
    previous = estimate_bag(path, vehicle, bulk=False)
    assert bulk.rejected == previous.rejected
    assert (bulk.accepted, bulk.inputs_read, bulk.restarts) == (
        previous.accepted,
        previous.inputs_read,
        previous.restarts,
    )
    assert bulk.topics_read == previous.topics_read
    assert _digest(bulk) == _digest(previous)
    if bag == "tampered":
        reasons = " | ".join(bulk.rejected)
        for words in (
            "frame_id",
            "not finite",
            "ahead of the clock",
            "duplicates",
            "out of order",
            "new time line",
            "not symmetric",
            "max_acceleration",
            "lacks gravity",
        ):
            assert words in reasons, (words, bulk.rejected)
        assert bulk.restarts >= 2  # the accelerometer in g and the new time line


def _random_value(rng: random.Random) -> float:
    if rng.random() < 0.05:
        return rng.choice([math.nan, math.inf, -math.inf, -0.0, 1e308, 5e-324])
    return rng.gauss(0.0, 10.0)


@pytest.mark.parametrize("frame", ["a", "odom", "abcdefg", "abcdefgh", "quarter_car/odom", "ünï"])
def test_stamped_layout_reads_what_the_decoder_reads(frame: str) -> None:
    rng = random.Random(frame)
    cases = (
        (PointStamped, ("point.x", "point.z")),
        (Imu, ("linear_acceleration.z", "linear_acceleration.z", "linear_acceleration_covariance")),
    )
    for cls, fields in cases:
        layout = stamped_layout(cls, frame, fields)
        assert layout is not None
        raws, expected = [], []
        for _ in range(40):
            msg = cls()
            msg.header.frame_id = frame
            msg.header.stamp.sec = rng.randint(-(2**31), 2**31 - 1)
            msg.header.stamp.nanosec = rng.randint(0, 999_999_999)
            if cls is PointStamped:
                msg.point.x, msg.point.y, msg.point.z = (_random_value(rng) for _ in range(3))
            else:
                msg.linear_acceleration.x, msg.linear_acceleration.z = _random_value(rng), _random_value(rng)
                msg.orientation.w = _random_value(rng)
                msg.linear_acceleration_covariance = np.array([_random_value(rng) for _ in range(9)])
            raw = _canonical_cdr(serialize_message(msg), msgtype_of(msg))
            assert len(raw) == layout.length
            raws.append(raw)
            got = decoder_for(cls)(raw)
            numbers = (
                [got.point.x, got.point.z]
                if cls is PointStamped
                else [got.linear_acceleration.z] * 2 + got.linear_acceleration_covariance.tolist()
            )
            expected.append((stamp_to_ns(got.header.stamp), numbers))
        match, stamp_ns, values = layout.decode(raws)
        assert match.all()
        assert stamp_ns.tolist() == [s for s, _ in expected]
        assert values.tobytes() == np.array([v for _, v in expected]).tobytes()
        other = stamped_layout(cls, frame[:-1] + ("x" if frame[-1] != "x" else "y"), fields)
        assert other is not None and not other.decode(raws)[0].any()  # another frame of that length: no match
