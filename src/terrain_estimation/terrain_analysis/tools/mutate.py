"""``python -m terrain_analysis.tools.mutate``: damage a bag every way a robot or a person can, run the tools.

A table of mutations — values, units, signs, frames, types, stamps, gaps,
bytes, metadata, truncation, missing topics, namespaces, output paths — is
applied to a recorded bag (with rosbags alone: the damage does not go through
the project's own reader or writer). Each damaged bag is given to both
offline tools, ``terrain-estimate`` and ``terrain-sim2real``, in-process, and
each run is held to what must happen:

* the exit status (``terrain_estimation.cli``: 0 ok, 1 a gap found, 2 the
  input cannot be used, 3 internal error — never 3) and a message that names
  the damage (a rejection reason in the summary, or the error);
* nothing non-finite in any bag or JSON the tools write;
* no input file or directory modified or removed (every file hashed before and
  after).

``--out DIR`` keeps the damaged bags and outputs (a new directory); the table
goes to stdout as Markdown. Exit status 0 when every row behaves as expected,
1 when one does not.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import math
import os
import shutil
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["Case", "Expect", "Outcome", "MUTATIONS", "damage", "run_case", "tree_digest", "main"]

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


def tree_digest(path: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every file under ``path`` (or of the file), directories as ``<dir>``."""
    if path.is_file():
        return {path.name: hashlib.sha256(path.read_bytes()).hexdigest()}
    out: dict[str, str] = {}
    for p in sorted(path.rglob("*")):
        rel = str(p.relative_to(path))
        out[rel] = "<dir>" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@dataclass
class ToolRun:
    """One tool's run on a damaged bag."""

    status: int
    stdout: str
    stderr: str
    seconds: float

    @property
    def text(self) -> str:
        return self.stdout + "\n" + self.stderr

    def headline(self) -> str:
        """The line that says most about the run: the error, a rejection, or the result."""
        for line in self.stderr.splitlines():
            if ": error: " in line or "internal error" in line:
                return line.split(": error: ", 1)[-1].strip()
        for line in self.stdout.splitlines():
            if line.strip().startswith("rejected") or "not decode" in line:
                return line.strip()
        for line in reversed(self.stdout.splitlines()):
            if line.startswith(("wrote", "verdict")):
                return line.strip()
        return (self.stdout.strip().splitlines() or [""])[-1]


def _run_tool(main: Callable[[Sequence[str]], int], argv: Sequence[str]) -> ToolRun:
    out, err = io.StringIO(), io.StringIO()
    started = time.monotonic()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(list(argv))
        except SystemExit as exc:  # argparse
            status = int(exc.code or 0)
        except Exception:  # a tool that lets an exception out: an internal error, and the table goes on
            traceback.print_exc()
            print("uncaught exception: internal error", file=sys.stderr)
            status = 3
    return ToolRun(status, out.getvalue(), err.getvalue(), time.monotonic() - started)


def nonfinite_in_outputs(path: Path) -> list[str]:
    """Where a bag or JSON under ``path`` holds a non-finite number (bags decoded with the definitions they carry)."""
    found: list[str] = []
    if not path.exists():
        return found
    for meta in sorted(path.rglob("metadata.yaml")):
        from rosbags.highlevel import AnyReader

        with AnyReader([meta.parent]) as reader:
            for conn, _t, raw in reader.messages():
                msg = reader.deserialize(raw, conn.msgtype)
                bad = _first_nonfinite(msg)
                if bad is not None:
                    found.append(f"{conn.topic}: {bad}")
                    break
    for js in sorted(path.rglob("*.json")):
        bad = _first_nonfinite(json.loads(js.read_text(), parse_constant=lambda c: float(c)))
        if bad is not None:
            found.append(f"{js.name}: {bad}")
    return found


def _first_nonfinite(obj: Any, path: str = "") -> str | None:
    import numpy as np

    if isinstance(obj, float):
        return None if math.isfinite(obj) else f"{path} = {obj}"
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f" and not np.all(np.isfinite(obj)):
            return f"{path}[{int(np.flatnonzero(~np.isfinite(obj))[0])}]"
        return None
    if isinstance(obj, dict):
        items: Any = obj.items()
    elif isinstance(obj, (list, tuple)):
        items = enumerate(obj)
    elif hasattr(obj, "__dataclass_fields__"):
        items = ((k, getattr(obj, k)) for k in obj.__dataclass_fields__)
    else:
        return None
    for key, value in items:
        bad = _first_nonfinite(value, f"{path}.{key}" if path else str(key))
        if bad is not None:
            return bad
    return None


@dataclass
class Outcome:
    """A case's result: both tools' runs, and whether every rule held."""

    case: Case
    vehicle: str
    estimate: ToolRun
    sim2real: ToolRun | None
    input_unchanged: bool
    nonfinite: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def _check(tool: str, run: ToolRun, expect: Expect, clean_status: int | None) -> list[str]:
    """What ``run`` did against ``expect``; ``clean_status`` None: this is the reference run (SAME is what it did)."""
    allowed = {(run.status if clean_status is None else clean_status) if s == SAME else s for s in expect.statuses}
    problems = []
    if run.status not in allowed:
        problems.append(f"{tool} exited {run.status}, expected {' or '.join(str(s) for s in sorted(allowed, key=str))}")
    if run.status == 3:
        problems.append(f"{tool} hit an internal error")
    if expect.text and expect.text.lower() not in run.text.lower():
        problems.append(f"{tool} did not say {expect.text!r}")
    return problems


def run_case(
    case: Case,
    vehicle: str,
    source: Path,
    workdir: Path,
    *,
    clean_status: tuple[int | None, int | None] = (None, None),
    sim2real: bool = True,
) -> Outcome:
    """Damage ``source`` by ``case`` in ``workdir`` (a new directory), run both tools, check the rules.

    Args:
        clean_status: both tools' exit statuses on the undamaged bag (what SAME means); None:
            this is the undamaged bag's run.
        sim2real: run terrain-sim2real too.
    """
    from terrain_analysis.tools import sim2real as sim2real_tool
    from terrain_estimation.tools import estimate as estimate_tool
    from terrain_estimation.vehicles import estimator_parameters, get_vehicle

    entry = get_vehicle(vehicle)
    adapter = entry.make_adapter(estimator_parameters(entry), entry.namespace)
    accel = next(s.topic for s in adapter.inputs if s.gravity_fields)
    workdir.mkdir(parents=True)
    bag = damage(case, source, workdir / "input", accel)
    before = tree_digest(bag)
    source_before = tree_digest(source)
    ns = ["--namespace", case.namespace] if case.namespace else []
    output = workdir / "estimates"
    if case.output == "input":
        output = bag
    elif case.output == "existing":
        output.mkdir()
        (output / "notes.txt").write_text("a user's file\n")
    out_before = tree_digest(output) if output.exists() else {}
    est = _run_tool(estimate_tool.main, [str(bag), "--vehicle", vehicle, "-o", str(output), *ns])
    s2r = None
    if sim2real:
        s2r = _run_tool(
            sim2real_tool.main,
            [str(bag), "--vehicle", vehicle, "-o", str(workdir / "diagnosis"), "-q", "--no-figures", *ns],
        )
    unchanged = tree_digest(bag) == before and tree_digest(source) == source_before
    problems = _check("terrain-estimate", est, case.estimate, clean_status[0])
    if s2r is not None:
        problems += _check("terrain-sim2real", s2r, case.sim2real, clean_status[1])
    if not unchanged:
        problems.append("an input was modified")
    if case.output != "new" and tree_digest(output) != out_before:
        problems.append(f"the existing output path {output.name} was modified")
    if est.status == 0 and _message_count(output) == 0:
        problems.append("terrain-estimate exited 0 without writing an estimate")
    if est.status != 0 and case.output == "new" and output.exists():
        problems.append("terrain-estimate failed but left an output")
    nonfinite = [] if case.output != "new" else nonfinite_in_outputs(output)
    nonfinite += nonfinite_in_outputs(workdir / "diagnosis")
    problems += [f"non-finite value written: {n}" for n in nonfinite]
    return Outcome(case, vehicle, est, s2r, unchanged, nonfinite, problems)


def _message_count(bag: Path) -> int:
    from rosbags.rosbag2 import Reader

    if not (bag / "metadata.yaml").exists():
        return 0
    with Reader(bag) as reader:
        return int(reader.message_count)


def _status(run: ToolRun | None, workdir: str) -> str:
    if run is None:
        return "—"
    head = run.headline().replace("|", "\\|")
    if workdir:
        head = head.replace(workdir, "DIR")
    head = head if len(head) <= 110 else head[:107] + "…"
    return f"{run.status}: {head}"


def table(outcomes: Sequence[Outcome], workdir: str | os.PathLike[str] = "") -> list[str]:
    """The outcomes as Markdown table lines (``workdir`` written as DIR)."""
    lines = [
        "| vehicle | kind | damage | terrain-estimate (exit: message) | terrain-sim2real (exit: message) "
        "| input unchanged | as required |",
        "|---|---|---|---|---|---|---|",
    ]
    wd = str(workdir)
    for o in outcomes:
        verdict = "yes" if o.ok else "**no**: " + "; ".join(o.problems)
        lines.append(
            f"| {o.vehicle} | {o.case.kind} | {o.case.what} | {_status(o.estimate, wd)} | {_status(o.sim2real, wd)} | "
            f"{'yes' if o.input_unchanged else '**no**'} | {verdict} |"
        )
    return lines


DEFAULT_BAGS = {
    "quarter_car": "quarter_car_graneville_iso_d_10ms",
    "lrv": "lrv_regolith_iso_g_2ms",
    "skid_steer": "skid_steer_s_shape",
    "rover": "rover_terrain_2",
}


def _write_report(page: str, lines: Sequence[str], summary: str, argv: Sequence[str] | None, seconds: float) -> None:
    """The table as the ``mutate`` section of ``page`` (the rest of the page is another command's)."""
    from terrain_analysis.reporting import git_revision, write_section

    command = "python -m terrain_analysis.tools.mutate " + " ".join(sys.argv[1:] if argv is None else argv)
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    text = [
        "## Damaged input: what the offline tools do with it (issue 19)",
        "",
        f"Produced by `{command.strip()}` on {when} at revision {git_revision()} in {seconds:.0f} s. Each row "
        "damages a shipped bag (with rosbags alone) and runs `terrain-estimate` and `terrain-sim2real` on it; "
        '"as required" holds each run to the exit status and message of its case '
        "(`terrain_analysis.tools.mutate.MUTATIONS`; 0 ok, 1 a gap found, 2 the input cannot be used, 3 a bug), "
        "to nothing non-finite written and to every input file hashed unchanged. DIR is the working directory. "
        "`test/test_mutation_suite.py` runs the same cases, and one of each kind on freshly simulated bags.",
        "",
        *lines,
        "",
        summary + ".",
    ]
    write_section(page, "terrain_analysis.tools.mutate", "\n".join(text))


def main(argv: Sequence[str] | None = None) -> int:
    from terrain_estimation.cli import EXIT_FINDING, EXIT_OK, run_cli

    parser = argparse.ArgumentParser(prog="terrain-mutate", description=__doc__.splitlines()[0])
    parser.add_argument("--vehicle", action="append", choices=sorted(DEFAULT_BAGS), help="vehicles (default: all)")
    parser.add_argument("--bags", default="bags", help="directory of the recorded bags (default: bags)")
    parser.add_argument("--only", action="append", help="run only these cases (by name)")
    parser.add_argument("--no-sim2real", action="store_true", help="run terrain-estimate only")
    parser.add_argument("--out", help="keep the damaged bags and outputs in this new directory")
    parser.add_argument(
        "--report", metavar="PAGE", help="also write the table as a section of this Markdown page (replaced if there)"
    )
    args = parser.parse_args(argv)

    def body() -> int:
        cases = [c for c in MUTATIONS if not args.only or c.name in args.only]
        outcomes: list[Outcome] = []
        keep = Path(args.out) if args.out else None
        if keep is not None and keep.exists():
            raise FileExistsError(f"--out {str(keep)!r} exists: give a new directory")
        started = time.monotonic()
        with tempfile.TemporaryDirectory(prefix="terrain-mutate-") as tmp:
            root = keep or Path(tmp)
            for vehicle in args.vehicle or sorted(DEFAULT_BAGS):
                source = Path(args.bags) / DEFAULT_BAGS[vehicle]
                clean = run_case(  # the reference: what SAME means
                    MUTATIONS[0], vehicle, source, root / vehicle / "clean_reference", sim2real=not args.no_sim2real
                )
                statuses = (clean.estimate.status, clean.sim2real.status if clean.sim2real else None)
                outcomes.append(clean)
                for case in cases:
                    if case is MUTATIONS[0]:
                        continue
                    o = run_case(
                        case,
                        vehicle,
                        source,
                        root / vehicle / case.name,
                        clean_status=statuses,
                        sim2real=not args.no_sim2real,
                    )
                    outcomes.append(o)
                    mark = "ok" if o.ok else "FAIL: " + "; ".join(o.problems)
                    print(f"  {vehicle:11s} {case.name:13s} {mark}", file=sys.stderr, flush=True)
            lines = table(outcomes, root)
        failed = [o for o in outcomes if not o.ok]
        summary = f"{len(outcomes) - len(failed)} of {len(outcomes)} cases as required"
        print("\n".join(lines) + f"\n\n{summary}")
        if args.report:
            _write_report(args.report, lines, summary, argv, time.monotonic() - started)
        return EXIT_OK if not failed else EXIT_FINDING

    return run_cli("terrain-mutate", body)


if __name__ == "__main__":
    sys.exit(main())
