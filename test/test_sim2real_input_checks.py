"""terrain-sim2real on damaged bags (issue 19, item 7): the estimators' input checks, plausibility bounds,
time gaps, wrong types and namespaces, and exit statuses that tell a finding from bad input from a bug.

The damaged bags are the shipped short bags rewritten in tmp_path.
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from terrain_analysis.sim2real import diagnose as diagnose_module
from terrain_analysis.sim2real.inputs import screen_bag
from terrain_analysis.tools.sim2real import main
from terrain_estimation.bag import AtomicBagWriter, read_bag
from terrain_estimation.cli import EXIT_INPUT, EXIT_INTERNAL

BAGS = Path(__file__).resolve().parents[1] / "bags"
QC = BAGS / "quarter_car_graneville_iso_d_10ms"
SKID = BAGS / "skid_steer_s_shape"

Edit = Callable[[int, str, Any, int], Iterator[tuple[str, Any, int]]]


def _rewrite(src: Path, dst: Path, edit: Edit) -> Path:
    """``src`` rewritten message by message: ``edit(index on its topic, topic, msg, log ns)`` yields what to write."""
    seen: dict[str, int] = {}
    with AtomicBagWriter(dst) as writer:
        for item in read_bag(src):
            i = seen.get(item.topic, 0)
            seen[item.topic] = i + 1
            for topic, msg, t_ns in edit(i, item.topic, item.msg, item.log_time_ns):
                writer.write(topic, msg, t_ns)
    return dst


def _run(bag: Path, vehicle: str, out: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> tuple[int, str, str]:
    code = main([str(bag), "--vehicle", vehicle, "-o", str(out), "--no-figures", "-q", *extra])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _verdict(out: str) -> str:
    return next(line for line in out.splitlines() if line.startswith("verdict:"))


@pytest.mark.timeout(150)
def test_an_hour_long_stamp_gap_splits_the_bag_and_the_run_takes_seconds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hour = 3_600_000_000_000

    def gap(i: int, topic: str, msg: Any, t_ns: int) -> Iterator[tuple[str, Any, int]]:
        if i >= 650:  # 6.5 s of the 10 s bag (100 Hz), then the recorder paused for an hour
            (msg.header.stamp if hasattr(msg, "header") else msg.clock).sec += 3600
            t_ns += hour
        yield topic, msg, t_ns

    bag = _rewrite(SKID, tmp_path / "gap", gap)
    started = time.monotonic()
    code, out, err = _run(bag, "skid_steer", tmp_path / "out", capsys)
    assert time.monotonic() - started < 60.0, "an hour of invented data was replayed"
    assert code in (0, 1), err
    report = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    segments = report["inputs"]["segments"]
    assert len(segments) == 2
    assert report["inputs"]["analysed"] == 0  # the 6.5 s before the gap, not the 3.5 s after
    assert segments[0]["overlap"] == pytest.approx(6.49, abs=0.02)
    assert report["duration"] < 7.0
    assert "segment 1 of 2 analysed" in out
    assert "segment 1 of 2" in (tmp_path / "out" / "diagnosis.md").read_text()


def test_absurd_and_nan_profile_samples_are_rejected_counted_and_leave_the_verdict(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def damage(i: int, topic: str, msg: Any, t_ns: int) -> Iterator[tuple[str, Any, int]]:
        if topic.endswith("terrain/profile"):
            if i == 2000:
                msg.point.z = 1e300  # beyond any terrain
            elif i == 3000:
                msg.point.z += 5.0  # a 5 m step within 1 cm of travel
            elif 1000 <= i < 1005:
                msg.point.z = math.nan
        elif topic.endswith("imu/body") and i in (150, 250):
            msg.linear_acceleration.z = math.nan
        yield topic, msg, t_ns

    bag = _rewrite(QC, tmp_path / "damaged", damage)
    code_ok, out_ok, err_ok = _run(QC, "quarter_car", tmp_path / "ok", capsys)
    code, out, err = _run(bag, "quarter_car", tmp_path / "out", capsys)
    assert (code, _verdict(out)) == (code_ok, _verdict(out_ok)), err
    rejected = json.loads((tmp_path / "out" / "diagnosis.json").read_text())["inputs"]["rejected"]
    assert rejected == {
        "terrain/profile: point.z is not finite": 5,
        "imu/body: linear_acceleration.z is not finite": 2,
        "terrain/profile: point.z is beyond ±20000 m (no sensor of a ground vehicle)": 1,
        "terrain/profile: point.z changes by more than 5 × the distance + 1 mm from the last plausible sample": 1,
    }
    assert "9 rejected (4 reasons)" in out
    assert "| 5 | terrain/profile: point.z is not finite |" in (tmp_path / "out" / "diagnosis.md").read_text()


def test_damage_the_repository_does_not_hold_is_rejected_by_kind(tmp_path: Path) -> None:
    """Duplicated messages, stamps going backwards, a frozen sensor, an accelerometer in g mid-bag."""

    def damage(i: int, topic: str, msg: Any, t_ns: int) -> Iterator[tuple[str, Any, int]]:
        yield topic, msg, t_ns
        if topic.endswith("joint_states") and 100 <= i < 110:
            yield topic, copy.deepcopy(msg), t_ns  # recorded twice
        if topic.endswith("terrain/profile") and i in (500, 501, 502):
            back = copy.deepcopy(msg)
            back.header.stamp.nanosec -= 50_000_000  # 50 ms back
            yield topic, back, t_ns

    frozen: dict[str, Any] = {}

    def sensor(i: int, topic: str, msg: Any, t_ns: int) -> Iterator[tuple[str, Any, int]]:
        if topic.endswith("imu/wheel") and 200 <= i < 240:  # stuck for 0.4 s, stamps going on
            if i == 200:
                frozen["a"] = msg.linear_acceleration.z
            msg.linear_acceleration.z = frozen["a"]
        if topic.endswith("imu/body") and i >= 150:  # in g from 1.5 s on
            msg.linear_acceleration.z /= 9.80665
        yield topic, msg, t_ns

    twice = _rewrite(QC, tmp_path / "twice", damage)
    stuck = _rewrite(twice, tmp_path / "stuck", sensor)
    report = screen_bag(stuck, "quarter_car", tmp_path / "checked")
    reasons = report.rejected
    assert reasons["joint_states: header.stamp duplicates the previous sample's"] == 10
    assert reasons["terrain/profile: header.stamp is before the previous sample's (out of order)"] == 3
    assert reasons["imu/wheel: every checked field frozen (20+ identical messages in a row)"] == 39
    assert any(r.startswith("imu/body: linear_acceleration") and "in g" in r for r in reasons)
    # no sample in g reaches the replay: those in the window before the verdict are dropped with it
    assert 0 < report.used["/quarter_car/imu/body"] <= 150
    assert report.read["/quarter_car/joint_states"] == 410


def test_a_topic_of_the_wrong_type_exits_2_naming_topic_and_types(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from sensor_msgs.msg import Imu

    def retype(i: int, topic: str, msg: Any, t_ns: int) -> Iterator[tuple[str, Any, int]]:
        if topic.endswith("terrain/profile"):
            imu = Imu()
            imu.header = msg.header
            msg = imu
        yield topic, msg, t_ns

    bag = _rewrite(QC, tmp_path / "retyped", retype)
    code, out, err = _run(bag, "quarter_car", tmp_path / "out", capsys)
    assert code == EXIT_INPUT
    assert "Traceback" not in err
    assert "/quarter_car/terrain/profile" in err
    assert "sensor_msgs/msg/Imu" in err and "geometry_msgs/msg/PointStamped" in err
    assert not (tmp_path / "out").exists()


def test_a_wrong_namespace_or_an_empty_bag_exits_2_naming_the_expected_topics(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _, err = _run(QC, "quarter_car", tmp_path / "out", capsys, "--namespace", "/elsewhere")
    assert code == EXIT_INPUT
    for topic in ("imu/body", "imu/wheel", "terrain/profile", "joint_states"):
        assert f"/elsewhere/{topic}" in err  # expected
        assert f"/quarter_car/{topic}" in err  # found
    with AtomicBagWriter(tmp_path / "empty"):
        pass
    code, _, err = _run(tmp_path / "empty", "skid_steer", tmp_path / "out", capsys)
    assert code == EXIT_INPUT
    assert "/skid_steer/imu" in err and "/skid_steer/joint_states" in err and "no topics" in err


def test_an_internal_error_exits_3_never_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise AttributeError("'NoneType' object has no attribute 'series'")

    monkeypatch.setattr(diagnose_module, "attribute", broken)
    code, out, err = _run(SKID, "skid_steer", tmp_path / "out", capsys)
    assert code == EXIT_INTERNAL
    assert "internal error" in err and "AttributeError" in err
    assert "verdict" not in out
