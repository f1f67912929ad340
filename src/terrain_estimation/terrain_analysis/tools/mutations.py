"""The damage ``terrain-mutate`` does to a bag, and what each offline tool must do with it.

Part of :mod:`terrain_analysis.tools.mutate`: :data:`MUTATIONS` is the table
of cases (values, units, signs, frames, types, stamps, gaps, bytes, metadata,
truncation, missing topics, namespaces, output paths), each with its
:class:`Expect` for ``terrain-estimate`` and ``terrain-sim2real``;
:func:`damage` writes a damaged copy of a bag with rosbags alone (the damage
does not go through the project's own reader or writer).
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["SAME", "Case", "Expect", "RawMessage", "Transform", "MUTATIONS", "damage"]

SAME = -1
"""An exit status: the same as the tool's on the undamaged bag (the damage must not flip a verdict)."""


@dataclass(frozen=True)
class Expect:
    """What a tool must do on a damaged bag.

    Attributes:
        statuses: the exit statuses allowed (SAME: the tool's status on the clean bag). Where
            damage leaves a vehicle without a sensor it needs, both "estimates from what is
            left, the damage counted" (0) and "no estimate, the damage named" (2) are right.
        text: a text the tool must print (stdout or stderr), case-insensitive; "" for none.
    """

    statuses: tuple[int, ...]
    text: str = ""


def _ok(text: str = "") -> Expect:
    return Expect((0,), text)


def _refused(text: str) -> Expect:
    return Expect((2,), text)


def _same(text: str = "") -> Expect:
    return Expect((SAME,), text)


def _rejected(text: str) -> Expect:
    """The damaged sensor's samples rejected with ``text``: estimates from the rest (0) or none (2)."""
    return Expect((0, 2), text)


def _rejected_or_same(text: str) -> Expect:
    """terrain-sim2real: the same verdict from the rest, or refused (2), the damage named."""
    return Expect((SAME, 2), text)


@dataclass(frozen=True)
class RawMessage:
    """One message of a bag as stored: topic, type, log time and CDR bytes."""

    topic: str
    msgtype: str
    log_time_ns: int
    raw: bytes


Transform = Callable[[RawMessage, Any], Iterator[RawMessage]]
"""Given a message and the typestore, the messages to write instead (none: dropped)."""


@dataclass(frozen=True)
class Case:
    """One kind of damage to a bag, and what each tool must do with it.

    Attributes:
        name: short identifier.
        kind: the damage's family (values, units, signs, frames, types, …).
        what: the damage in words.
        transform: rewrites the bag message by message (None: the bag is copied).
        post: damages the written bag directory (metadata, truncation, …).
        namespace: the namespace passed to the tools (None: the vehicle's).
        output: where terrain-estimate writes: "new", "input" (the input bag
            itself) or "existing" (a directory with another file in it).
        estimate, sim2real: what each tool must do.
    """

    name: str
    kind: str
    what: str
    estimate: Expect
    sim2real: Expect
    transform: Callable[[str], Transform] | None = None  # of the accelerometer topic
    post: Callable[[Path], None] | None = None
    namespace: str | None = None
    output: str = "new"


# -- message-level damage ---------------------------------------------------------------------


def _edit(topic_suffix: str, edit: Callable[[Any, int], Any], *, every: bool = False, at: float = 0.5) -> Transform:
    """Decode the messages of ``topic_suffix`` (the one at ``at`` of the bag's time, or every one) and ``edit`` them."""
    state = {"count": 0}

    def transform(msg: RawMessage, store: Any) -> Iterator[RawMessage]:
        if not msg.topic.endswith("/" + topic_suffix):
            yield msg
            return
        state["count"] += 1
        if not every and state["count"] != state["target"]:
            yield msg
            return
        decoded = store.deserialize_cdr(msg.raw, msg.msgtype)
        out = edit(decoded, state["count"])
        if out is None:
            return
        msgtype = getattr(out, "__msgtype__", msg.msgtype)
        yield RawMessage(msg.topic, msgtype, msg.log_time_ns, bytes(store.serialize_cdr(out, msgtype)))

    transform.state = state  # type: ignore[attr-defined]
    transform.at = at  # type: ignore[attr-defined]
    return transform


def _set_accel(value: float, axis: str = "z") -> Callable[[str], Transform]:
    def make(accel_topic: str) -> Transform:
        def edit(m: Any, _i: int) -> Any:
            setattr(m.linear_acceleration, axis, value)
            return m

        return _edit(accel_topic, edit)

    return make


def _scale_accel(factor: float) -> Callable[[str], Transform]:
    def make(accel_topic: str) -> Transform:
        def edit(m: Any, _i: int) -> Any:
            a = m.linear_acceleration
            a.x, a.y, a.z = a.x * factor, a.y * factor, a.z * factor
            return m

        return _edit(accel_topic, edit, every=True)

    return make


def _gravity_removed(accel_topic: str) -> Transform:
    def edit(m: Any, _i: int) -> Any:
        m.linear_acceleration.z -= 9.80665
        return m

    return _edit(accel_topic, edit, every=True)


def _upside_down(accel_topic: str) -> Transform:
    def edit(m: Any, _i: int) -> Any:  # rotated 180° about x: y and z change sign
        a, w = m.linear_acceleration, m.angular_velocity
        a.y, a.z, w.y, w.z = -a.y, -a.z, -w.y, -w.z
        return m

    return _edit(accel_topic, edit, every=True)


def _frame(accel_topic: str) -> Transform:
    def edit(m: Any, _i: int) -> Any:
        m.header.frame_id = "base_link_wrong"
        return m

    return _edit(accel_topic, edit, every=True)


def _wrong_type(accel_topic: str) -> Transform:
    def transform(msg: RawMessage, store: Any) -> Iterator[RawMessage]:
        if not msg.topic.endswith("/" + accel_topic):
            yield msg
            return
        imu = store.deserialize_cdr(msg.raw, msg.msgtype)
        vec = store.types["geometry_msgs/msg/Vector3Stamped"](header=imu.header, vector=imu.linear_acceleration)
        msgtype = "geometry_msgs/msg/Vector3Stamped"
        yield RawMessage(msg.topic, msgtype, msg.log_time_ns, bytes(store.serialize_cdr(vec, msgtype)))

    return transform


def _garbage_bytes(accel_topic: str) -> Transform:
    def edit_raw(msg: RawMessage, _store: Any) -> Iterator[RawMessage]:
        yield RawMessage(msg.topic, msg.msgtype, msg.log_time_ns, b"\x00\x01\x00\x00" + b"\xff" * 7)

    return _raw_at(accel_topic, edit_raw)


def _raw_at(topic_suffix: str, edit: Transform, *, at: float = 0.5) -> Transform:
    """``edit`` the one message of ``topic_suffix`` at ``at`` of the topic's messages, raw."""
    state = {"count": 0}

    def transform(msg: RawMessage, store: Any) -> Iterator[RawMessage]:
        if msg.topic.endswith("/" + topic_suffix):
            state["count"] += 1
            if state["count"] == state["target"]:
                yield from edit(msg, store)
                return
        yield msg

    transform.state = state  # type: ignore[attr-defined]
    transform.at = at  # type: ignore[attr-defined]
    return transform


def _stamp_shift(seconds: float, *, from_fraction: float = 0.5, every_topic: bool = True) -> Callable[[str], Transform]:
    """Stamps (and log times) of every message from ``from_fraction`` of the bag on moved by ``seconds``."""

    def make(_accel_topic: str) -> Transform:
        state: dict[str, Any] = {}

        def transform(msg: RawMessage, store: Any) -> Iterator[RawMessage]:
            start = state["split_ns"]
            if msg.log_time_ns < start:
                yield msg
                return
            shift = round(seconds * 1e9)
            decoded = store.deserialize_cdr(msg.raw, msg.msgtype)
            header = getattr(decoded, "header", None)
            if header is not None:
                _add_ns(header.stamp, shift)
            elif hasattr(decoded, "clock"):
                _add_ns(decoded.clock, shift)
            raw = bytes(store.serialize_cdr(decoded, msg.msgtype))
            yield RawMessage(msg.topic, msg.msgtype, msg.log_time_ns + shift, raw)

        transform.split = from_fraction  # type: ignore[attr-defined]
        transform.state = state  # type: ignore[attr-defined]
        return transform

    return make


def _add_ns(stamp: Any, shift: int) -> None:
    total = stamp.sec * 1_000_000_000 + stamp.nanosec + shift
    stamp.sec, stamp.nanosec = divmod(total, 1_000_000_000)


def _reorder(accel_topic: str) -> Transform:
    """The header stamps of two consecutive accelerometer samples swapped (recorded in arrival order)."""
    state: dict[str, Any] = {"count": 0, "held": None}

    def transform(msg: RawMessage, store: Any) -> Iterator[RawMessage]:
        if not msg.topic.endswith("/" + accel_topic):
            yield msg
            return
        state["count"] += 1
        if state["count"] not in (state["target"], state["target"] + 1):
            yield msg
            return
        decoded = store.deserialize_cdr(msg.raw, msg.msgtype)
        if state["held"] is None:  # the first of the pair waits for the second's stamp
            state["held"] = (msg, decoded)
            return
        first_msg, first = state["held"]
        first.header.stamp, decoded.header.stamp = decoded.header.stamp, first.header.stamp
        for raw_msg, m in ((first_msg, first), (msg, decoded)):
            yield RawMessage(
                raw_msg.topic, raw_msg.msgtype, raw_msg.log_time_ns, bytes(store.serialize_cdr(m, raw_msg.msgtype))
            )

    transform.state = state  # type: ignore[attr-defined]
    transform.at = 0.5  # type: ignore[attr-defined]
    return transform


def _duplicate(accel_topic: str) -> Transform:
    def edit(msg: RawMessage, _store: Any) -> Iterator[RawMessage]:
        yield msg
        yield msg

    return _raw_at(accel_topic, edit)


def _drop_topic(accel_topic: str) -> Transform:
    def transform(msg: RawMessage, _store: Any) -> Iterator[RawMessage]:
        if not msg.topic.endswith("/" + accel_topic):
            yield msg

    return transform


def _drop_all(_accel_topic: str) -> Transform:
    def transform(_msg: RawMessage, _store: Any) -> Iterator[RawMessage]:
        return iter(())

    return transform


# -- bag-level damage -------------------------------------------------------------------------


def _storage_file(bag: Path) -> Path:
    files = sorted(bag.glob("*.mcap")) + sorted(bag.glob("*.db3"))
    return files[0]


def _truncate(bag: Path) -> None:
    storage = _storage_file(bag)
    size = storage.stat().st_size
    with storage.open("r+b") as f:
        f.truncate(size // 2)


def _no_metadata(bag: Path) -> None:
    (bag / "metadata.yaml").unlink()


def _garbage_metadata(bag: Path) -> None:
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [this is: {not, a bag")


def _corrupt_middle(bag: Path) -> None:
    """4 kB of (seeded) random bytes a third into the storage file: messages, or the structure around them."""
    import numpy as np

    storage = _storage_file(bag)
    size = storage.stat().st_size
    with storage.open("r+b") as f:
        f.seek(size // 3)
        f.write(np.random.default_rng(19).bytes(4096))


MUTATIONS: tuple[Case, ...] = (
    Case("clean", "none", "the bag as recorded", _ok("wrote"), _same()),
    Case("nan", "values", "one accelerometer sample NaN", _ok("not finite"), _same(), _set_accel(math.nan)),
    Case("inf", "values", "one accelerometer sample +inf", _ok("not finite"), _same(), _set_accel(math.inf)),
    Case(
        "spike", "values", "one accelerometer sample 1e300 (a glitch)", _ok("rejected 1:"), _same(), _set_accel(1e300)
    ),
    Case(
        "in_g",
        "units",
        "accelerometer in g, not m/s²",
        _rejected("in g"),
        _rejected_or_same("in g"),
        _scale_accel(1 / 9.80665),
    ),
    Case(
        "no_gravity",
        "units",
        "gravity removed from the accelerometer (not REP 145)",
        _rejected("lacks gravity"),
        _rejected_or_same("lacks gravity"),
        _gravity_removed,
    ),
    Case(
        "upside_down",
        "signs",
        "IMU mounted upside down (y, z flipped)",
        _rejected("upside down"),
        _rejected_or_same("upside down"),
        _upside_down,
    ),
    Case(
        "frame",
        "frames",
        "accelerometer in another frame",
        _rejected("frame_id"),
        _rejected_or_same("frame_id"),
        _frame,
    ),
    Case(
        "type",
        "types",
        "accelerometer recorded as Vector3Stamped",
        _refused("Vector3Stamped"),
        _refused("Vector3Stamped"),
        _wrong_type,
    ),
    Case("reorder", "stamps", "two accelerometer samples swapped", _ok("out of order"), _same(), _reorder),
    Case("duplicate", "stamps", "one accelerometer sample recorded twice", _ok("duplicates"), _same(), _duplicate),
    Case(
        "gap_1h",
        "gaps",
        "every stamp from mid-bag on +1 h",
        Expect((0, 2)),
        Expect((SAME, 2), "gap"),
        _stamp_shift(3600.0),
    ),
    Case(
        "garbage", "bytes", "one accelerometer message's bytes garbage", _ok("do not decode"), _same(), _garbage_bytes
    ),
    Case(
        "no_metadata",
        "metadata",
        "metadata.yaml removed",
        _refused("metadata"),
        _refused("metadata"),
        post=_no_metadata,
    ),
    Case(
        "bad_metadata",
        "metadata",
        "metadata.yaml not YAML",
        _refused("unreadable"),
        _refused("unreadable"),
        post=_garbage_metadata,
    ),
    Case(
        "truncated",
        "truncation",
        "storage file cut in half",
        _refused("unreadable"),
        _refused("unreadable"),
        post=_truncate,
    ),
    Case(
        "corrupt",
        "truncation",
        "4 kB of random bytes in the storage file",
        _refused("unreadable"),
        _refused("unreadable"),
        post=_corrupt_middle,
    ),
    Case(
        "missing",
        "missing topics",
        "the accelerometer topic not recorded",
        _rejected(""),
        _rejected_or_same(""),
        _drop_topic,
    ),
    Case(
        "empty",
        "missing topics",
        "a bag with no message",
        _refused("no input message"),
        _refused("expected"),
        _drop_all,
    ),
    Case(
        "namespace",
        "namespaces",
        "tools run with --namespace /wrong",
        _refused("/wrong"),
        _refused("/wrong"),
        namespace="/wrong",
    ),
    Case(
        "out_is_input",
        "output paths",
        "terrain-estimate -o <the input bag>",
        _refused("input"),
        _same(),
        output="input",
    ),
    Case(
        "out_exists",
        "output paths",
        "terrain-estimate -o <a directory with a file>",
        _refused("exists"),
        _same(),
        output="existing",
    ),
)


# -- applying damage and running the tools ---------------------------------------------------


def damage(case: Case, source: Path, target: Path, accel_topic: str) -> Path:
    """Write ``source`` damaged by ``case`` to the new directory ``target`` (rosbags only)."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer

    from terrain_estimation.bag import typestore

    store = typestore()
    if case.transform is None:
        shutil.copytree(source, target)
    else:
        transform = case.transform(accel_topic)
        with Reader(source) as reader:
            state = getattr(transform, "state", None)
            if state is not None and hasattr(transform, "at"):
                total = sum(c.msgcount for c in reader.connections if c.topic.endswith("/" + accel_topic))
                state["target"] = max(1, round(total * transform.at))
            if state is not None and hasattr(transform, "split"):
                state["split_ns"] = reader.start_time + round(transform.split * reader.duration)
            with Writer(target, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
                connections: dict[tuple[str, str], Any] = {}
                for conn, log_time, raw in reader.messages():
                    for out in transform(RawMessage(conn.topic, conn.msgtype, log_time, bytes(raw)), store):
                        key = (out.topic, out.msgtype)
                        if key not in connections:
                            connections[key] = writer.add_connection(out.topic, out.msgtype, typestore=store)
                        writer.write(connections[key], out.log_time_ns, out.raw)
                for conn in reader.connections:  # topics left without a message keep their connection
                    if (conn.topic, conn.msgtype) not in connections and conn.msgcount == 0:
                        connections[(conn.topic, conn.msgtype)] = writer.add_connection(
                            conn.topic, conn.msgtype, typestore=store
                        )
    if case.post is not None:
        case.post(target)
    return target
