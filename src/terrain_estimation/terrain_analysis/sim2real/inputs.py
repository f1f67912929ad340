"""Input checks of the sim-to-real diagnosis: the estimators' rules, plausibility bounds and time gaps.

:func:`screen_bag` reads a bag once, checks every message of the topics the
vehicle's estimator reads, and writes the messages that pass, byte for byte,
to a scratch bag that the replay and the estimator then read. Rejected
messages are dropped and counted per reason (:class:`InputReport`). The checks:

1. Type and presence: every input topic of the vehicle's estimator must be in
   the bag with its message type (else the input cannot be used: exit 2,
   naming the topics expected and found). A message whose bytes do not
   decode is dropped and counted.
2. Absurd values (:data:`ABSURD`): a checked field beyond what no sensor of a
   ground vehicle reads (|ω| > 100 rad/s, a profile height beyond ±20 km, ...)
   is dropped before anything else sees it. Accelerometers are the guard's
   (3.: ``input.max_acceleration``), the estimators' own rule.
3. The estimator's own checks, :class:`~terrain_estimation.ros.validation.InputGuard`
   with the estimator's input topics and its ``input.*`` parameters, the
   bag's log time as the clock (as ``terrain-estimate``): frame, stamps
   (future, duplicate, out of order, a new time line), finite fields,
   covariances, gravity on the accelerometers (a stream in g or without
   gravity). When the gravity check first fails, the samples of that topic
   in the window before its verdict are dropped too (they may be of the same
   kind; the live node restarts its estimator instead).
4. Terrain profile (``point.x``, ``point.z``, not an accelerometer): against
   the last plausible sample, the distance may change by at most
   :data:`PROFILE_MAX_SPEED` × Δt + 1 cm and the height by at most
   :data:`PROFILE_MAX_SLOPE` × |Δx| + max(10 σ_h, 1 mm) (σ_h: the config's
   profile noise). A spike, or a change of unit of either field, fails it.
   The bound grows with the distance travelled since the last plausible
   sample, so a real step (a curb) is rejected only over its rise. The first
   plausible sample is one consistent with its successor.
5. Frozen sensor: :data:`FROZEN_SAMPLES` or more consecutive messages with
   identical checked fields, on a stream whose values otherwise change
   (fewer than :data:`FROZEN_NOISY_FRACTION` of its other consecutive pairs
   equal; a constant simulated wheel speed is not a frozen sensor) and not
   all zero (a wheel at rest): all but the first of the run are dropped.

Time gaps: a topic whose consecutive accepted stamps are further apart than
max(:data:`GAP_PERIODS` × its median period, ``min_gap``) (default
:data:`GAP_MIN_S`) has a gap; so do two time lines (the stamps went back for
good). The bag is split at every gap of any topic into segments; one segment
is analysed (the replay integrates across time, and a gap of an hour would be
an hour of invented road): by default the one in which all the topics
overlap longest, or the one asked for (``--segment``). The report lists
every segment, the one analysed and why.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.bag import BagError, msgtype_name, read_bag, require_topics, typestore
from terrain_estimation.ros.time import stamp_to_ns
from terrain_estimation.ros.validation import InputGuard, field_value
from terrain_estimation.tools.estimate import topic_name
from terrain_estimation.vehicles import estimator_parameters, get_vehicle

__all__ = [
    "ABSURD",
    "FROZEN_SAMPLES",
    "GAP_MIN_S",
    "GAP_PERIODS",
    "InputReport",
    "Segment",
    "screen_bag",
]

GAP_PERIODS = 10.0
"""A gap: consecutive stamps of a topic further apart than this many of its median periods ..."""
GAP_MIN_S = 0.5
"""... and than this many seconds (default; ``--max-gap``)."""

ABSURD: tuple[tuple[str, float, str], ...] = (
    ("angular_velocity.", 100.0, "rad/s"),
    ("velocity[", 1e4, "rad/s"),
    ("position[", 1e7, "rad"),
    ("effort[", 1e6, "N·m"),
    ("twist.linear.", 100.0, "m/s"),
    ("wrench.force.", 1e7, "N"),
    ("point.z", 2e4, "m"),
    ("point.x", 1e8, "m"),
)
"""(field prefix, bound, unit): a checked field with |value| above the bound is not a reading of a ground vehicle."""

PROFILE_MAX_SPEED = 100.0
"""[m/s] fastest change of the profile's distance ``point.x``."""
PROFILE_MAX_SLOPE = 5.0
"""[m/m] steepest change of the profile's height ``point.z`` with the distance (79°)."""

FROZEN_SAMPLES = 20
"""Consecutive identical messages that make a frozen sensor (on a stream that otherwise changes)."""
FROZEN_NOISY_FRACTION = 0.05
"""A stream "otherwise changes" when fewer than this fraction of its other consecutive pairs are equal."""

_NOT_CHECKS = frozenset({"input.take_queued", "input.fast_decode", "input.log_throttle"})  # how, not what

_Key = tuple[str, int, int]  # (topic, log time ns, occurrence): one message of the bag


@dataclass(frozen=True)
class Segment:
    """A stretch of the bag without a time gap.

    Attributes:
        time_line: 1 + how many times the stamps went back for good before it.
        start: [s] its first stamp, from the first stamp of its time line.
        end: [s] its last stamp, same origin.
        overlap: [s] how long every input topic has data in it (0: some topic has none).
        messages: accepted messages in it.
    """

    time_line: int
    start: float
    end: float
    overlap: float
    messages: int

    def __str__(self) -> str:
        line = f"time line {self.time_line}, " if self.time_line > 1 else ""
        return f"{line}{self.start:.3f}–{self.end:.3f} s ({self.overlap:.2f} s with every topic, {self.messages} msgs)"


@dataclass
class InputReport:
    """What the input checks did to one bag (``asdict`` is JSON-serialisable).

    Attributes:
        expected: input topic -> message type.
        read: topic -> messages read.
        used: topic -> messages the diagnosis uses (accepted, in the analysed segment).
        rejected: reason (topic, field, problem) -> messages dropped.
        outside: topic -> accepted messages left out with the other segments.
        segments: the bag's stretches without a time gap.
        analysed: index into ``segments`` of the one analysed.
        why: why that one.
        rules: the bounds applied, one line each.
        jumps: time gaps in the stamps as recorded (before any check), at most 3 per topic.
    """

    expected: dict[str, str]
    read: dict[str, int] = field(default_factory=dict)
    used: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    outside: dict[str, int] = field(default_factory=dict)
    segments: list[Segment] = field(default_factory=list)
    analysed: int = 0
    why: str = ""
    rules: list[str] = field(default_factory=list)
    jumps: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """One line: read, rejected, left out, segment."""
        text = (
            f"inputs: {sum(self.read.values())} messages read, {sum(self.rejected.values())} rejected "
            f"({len(self.rejected)} reasons), {sum(self.outside.values())} left out with other segments, "
            f"{sum(self.used.values())} used"
        )
        if len(self.segments) > 1:
            text += f"; segment {self.analysed + 1} of {len(self.segments)} analysed ({self.why})"
        if self.jumps:
            text += f"; time gaps in the stamps: {'; '.join(self.jumps)}"
        return text

    def lines(self) -> list[str]:
        """The summary, then one line per rejection reason (most frequent first)."""
        out = [self.summary()]
        for reason, count in sorted(self.rejected.items(), key=lambda kv: (-kv[1], kv[0])):
            out.append(f"  rejected {count}: {reason}")
        return out


def input_specs(
    vehicle: str, namespace: str | None, config: str | Path | None
) -> tuple[list[Any], Mapping[str, Any], str]:
    """(estimator input TopicSpecs, parameter values, namespace) the checks use for ``vehicle``.

    A skid-steer config of ``vehicle.kind: husky`` has no estimator node: its
    bags are checked with the skid-steer node's default ``input.*`` values and
    no frame check (the imported bags keep their own frames), under ``/husky``.
    """
    entry = get_vehicle(vehicle)
    husky = False
    if vehicle == "skid_steer" and config is not None:
        from terrain_analysis.sim2real.skid_steer import _config_kind

        husky = _config_kind(config) == "husky"
    ns = namespace if namespace is not None else ("/husky" if husky else entry.namespace)
    values = estimator_parameters(entry, None if husky else config)
    specs = list(entry.make_adapter(values, ns).inputs)
    if husky:
        specs = [replace(s, frame_id="") for s in specs]
    return specs, values, ns


def _absurd(path: str) -> tuple[float, str] | None:
    for prefix, bound, unit in ABSURD:
        if path.startswith(prefix):
            return bound, unit
    return None


def _profile_rejections(
    rows: Sequence[tuple[_Key, int, int, tuple[float, ...]]], topic: str, sigma_h: float
) -> dict[_Key, str]:
    """Implausible samples of a profile stream (rows: key, stamp ns, time line, (x, z)); module docstring, 4."""
    allow_z = max(10.0 * sigma_h, 1e-3)
    x_reason = f"{topic}: point.x changes faster than {PROFILE_MAX_SPEED:g} m/s from the last plausible sample"
    z_reason = (
        f"{topic}: point.z changes by more than {PROFILE_MAX_SLOPE:g} × the distance + {1e3 * allow_z:.3g} mm "
        "from the last plausible sample"
    )

    def problem(a: tuple[int, tuple[float, ...]], b: tuple[int, tuple[float, ...]]) -> str | None:
        dt = abs(b[0] - a[0]) * 1e-9
        dx = abs(b[1][0] - a[1][0])
        if dx > PROFILE_MAX_SPEED * dt + 0.01:
            return x_reason
        if abs(b[1][1] - a[1][1]) > PROFILE_MAX_SLOPE * dx + allow_z:
            return z_reason
        return None

    out: dict[_Key, str] = {}
    last: tuple[int, tuple[float, ...]] | None = None
    line = -1
    for i, (key, stamp, time_line, values) in enumerate(rows):
        here = (stamp, values)
        if time_line != line:
            line, last = time_line, None
        if last is None:
            nxt = rows[i + 1] if i + 1 < len(rows) and rows[i + 1][2] == line else None
            why = problem(here, (nxt[1], nxt[3])) if nxt is not None else None
        else:
            why = problem(last, here)
        if why is None:
            last = here
        else:
            out[key] = why
    return out


def _frozen_rejections(rows: Sequence[tuple[_Key, int, int, tuple[float, ...]]], topic: str) -> dict[_Key, str]:
    """All but the first message of each frozen run (module docstring, 5)."""
    same = [a[3] == b[3] and a[2] == b[2] for a, b in zip(rows[:-1], rows[1:], strict=True)]
    runs: list[tuple[int, int]] = []  # [first, last] message index of each long run of equal values
    start = 0
    for i in range(1, len(rows) + 1):
        if i == len(rows) or not same[i - 1]:
            if i - start >= FROZEN_SAMPLES and any(v != 0.0 for v in rows[start][3]):
                runs.append((start, i - 1))
            start = i
    if not runs:
        return {}
    in_run = sum(b - a for a, b in runs)
    other_pairs = len(same) - in_run
    if other_pairs < FROZEN_SAMPLES or (sum(same) - in_run) >= FROZEN_NOISY_FRACTION * other_pairs:
        return {}  # a stream that is often constant (quantised, noise-free): no evidence of a frozen sensor
    out: dict[_Key, str] = {}
    for a, b in runs:
        reason = f"{topic}: every checked field frozen ({FROZEN_SAMPLES}+ identical messages in a row)"
        for row in rows[a + 1 : b + 1]:
            out[row[0]] = reason
    return out


def _segments(
    rows: Mapping[str, Sequence[tuple[_Key, int, int, tuple[float, ...]]]], min_gap: float
) -> tuple[list[Segment], list[tuple[int, int, int]]]:
    """The gap-free segments of the accepted rows, and each one's (time line, first, last stamp ns)."""
    lines = sorted({r[2] for rs in rows.values() for r in rs})
    segments: list[Segment] = []
    bounds: list[tuple[int, int, int]] = []
    for line in lines:
        stamps = {t: np.sort(np.array([r[1] for r in rs if r[2] == line], dtype=np.int64)) for t, rs in rows.items()}
        present = [s for s in stamps.values() if s.size]
        origin = min(int(s[0]) for s in present)
        end = max(int(s[-1]) for s in present)
        cuts: list[tuple[int, int]] = []
        for s in present:
            if s.size < 2:
                continue
            d = np.diff(s)
            limit = max(GAP_PERIODS * float(np.median(d)), min_gap * 1e9)
            cuts += [(int(s[i]), int(s[i + 1])) for i in np.flatnonzero(d > limit)]
        pieces: list[tuple[int, int]] = []
        lo = origin
        for a, b in sorted(cuts):
            if a >= lo:
                pieces.append((lo, a))
            lo = max(lo, b)
        pieces.append((lo, end))
        for a, b in pieces:
            inside = [s[(s >= a) & (s <= b)] for s in stamps.values()]
            overlap = 0.0
            if all(x.size >= 2 for x in inside):
                overlap = max(0.0, (min(int(x[-1]) for x in inside) - max(int(x[0]) for x in inside)) * 1e-9)
            n = sum(int(x.size) for x in inside)
            segments.append(Segment(line + 1, (a - origin) * 1e-9, (b - origin) * 1e-9, overlap, n))
            bounds.append((line, a, b))
    return segments, bounds


def screen_bag(
    bag: str | Path,
    vehicle: str,
    out: Path,
    *,
    namespace: str | None = None,
    config: str | Path | None = None,
    segment: int | None = None,
    min_gap: float = GAP_MIN_S,
    progress: Callable[[str], None] | None = None,
) -> InputReport:
    """Check ``bag``'s inputs of ``vehicle`` and write what passes, of one segment, to the bag ``out``.

    Args:
        bag: the recorded bag.
        vehicle: ``quarter_car``, ``lrv``, ``skid_steer`` or ``rover``.
        out: the screened bag to write (a new directory).
        namespace, config: as for the estimator (default: the vehicle's).
        segment: 1-based index of the segment to analyse (default: the longest).
        min_gap: [s] shortest time gap that splits the bag (with :data:`GAP_PERIODS`).
        progress: called with progress lines.

    Raises:
        MissingTopicsError, TopicTypeError: an input topic is missing or of another type.
        Sim2RealError: no usable message, no segment with every topic, a bad ``segment``.
        BagError: the bag is unreadable.
    """
    if not (min_gap > 0.0 and math.isfinite(min_gap)):
        raise Sim2RealError(f"the shortest time gap must be a positive number of seconds, got {min_gap}")
    specs, values, ns = input_specs(vehicle, namespace, config)
    by_topic = {topic_name(ns, s.topic): s for s in specs}
    report = InputReport(expected={t: msgtype_name(s.msg_type) for t, s in by_topic.items()})
    require_topics(bag, report.expected)
    sigma_h = float(values.get("estimator.profile_noise_std", 0.0) or 0.0)
    report.rules = [
        "the estimator's input checks (InputGuard: frame, stamps, finite fields, covariances, gravity) with "
        + ", ".join(f"{k} = {v}" for k, v in sorted(values.items()) if k.startswith("input.") and k not in _NOT_CHECKS),
        "absurd values: " + ", ".join(f"|{p.rstrip('.[')}| > {b:g} {u}" for p, b, u in ABSURD),
        f"terrain profile: |Δx| ≤ {PROFILE_MAX_SPEED:g} m/s × Δt + 1 cm and |Δz| ≤ {PROFILE_MAX_SLOPE:g} |Δx| + "
        f"{1e3 * max(10.0 * sigma_h, 1e-3):.3g} mm from the last plausible sample",
        f"frozen sensor: {FROZEN_SAMPLES}+ identical messages in a row on a stream that otherwise changes",
        f"time gap: stamps further apart than max({GAP_PERIODS:g} median periods, {min_gap:g} s) split the bag",
    ]
    guard = InputGuard(specs, values)
    rows: dict[str, list[tuple[_Key, int, int, tuple[float, ...]]]] = {t: [] for t in by_topic}
    seen: dict[tuple[str, int], int] = {}
    time_line = 0
    previous: dict[str, int] = {}  # topic -> last stamp read (ns), for the jumps

    def reject(reason: str, n: int = 1) -> None:
        report.rejected[reason] = report.rejected.get(reason, 0) + n

    def undecodable(topic: str, log_ns: int, exc: Exception) -> None:
        seen[(topic, log_ns)] = seen.get((topic, log_ns), 0) + 1  # the copy counts every message
        report.read[topic] = report.read.get(topic, 0) + 1
        reject(f"{topic}: message bytes do not decode ({type(exc).__name__})")

    if progress is not None:
        progress(f"checking the inputs of {bag} ({vehicle}, namespace {ns})")
    for item in read_bag(bag, list(by_topic), types=report.expected, on_undecodable=undecodable):
        topic, spec, msg = item.topic, by_topic[item.topic], item.msg
        n = seen.get((topic, item.log_time_ns), 0)
        seen[(topic, item.log_time_ns)] = n + 1
        key: _Key = (topic, item.log_time_ns, n)
        report.read[topic] = report.read.get(topic, 0) + 1
        stamp_ns = stamp_to_ns(msg.header.stamp)
        if topic in previous and abs(stamp_ns - previous[topic]) > min_gap * 1e9:
            if sum(j.startswith(spec.topic + ":") for j in report.jumps) < 3:
                jump = (stamp_ns - previous[topic]) * 1e-9
                report.jumps.append(f"{spec.topic}: {jump:+.3f} s after message {report.read[topic] - 1}")
        previous[topic] = stamp_ns
        paths = (*spec.fields, *spec.gravity_fields)
        checked: list[float] = []
        why = None
        for path in paths:
            try:
                value = float(field_value(msg, path))
            except LookupError:
                value = math.nan  # a missing joint: the guard names it
            bound = _absurd(path)
            if bound is not None and math.isfinite(value) and abs(value) > bound[0]:
                why = f"{spec.topic}: {path} is beyond ±{bound[0]:g} {bound[1]} (no sensor of a ground vehicle)"
                break
            checked.append(value)
        if why is not None:
            reject(why)
            continue
        rejection = guard.check(spec.key, msg, item.log_time_ns * 1e-9)
        if rejection is not None:
            reject(rejection.reason)
            if rejection.rebase:
                time_line += 1
            elif rejection.restart:  # the window before the verdict may be of the same kind
                stamp = stamp_to_ns(msg.header.stamp)
                window = int(float(values["input.gravity_window"]) * 1e9)
                kept = [r for r in rows[topic] if r[2] != time_line or r[1] < stamp - window]
                if len(kept) < len(rows[topic]):
                    reject(f"{rejection.reason} (in the window before the verdict)", len(rows[topic]) - len(kept))
                    rows[topic] = kept
            continue
        rows[topic].append((key, stamp_to_ns(msg.header.stamp), time_line, tuple(checked)))
    if not report.read:
        raise Sim2RealError(f"bag {str(bag)!r}: no message on {', '.join(by_topic)} could be read")

    for topic, spec in by_topic.items():
        dropped: dict[_Key, str] = {}
        if "point.x" in spec.fields and "point.z" in spec.fields:
            xz = [
                (r[0], r[1], r[2], (r[3][spec.fields.index("point.x")], r[3][spec.fields.index("point.z")]))
                for r in rows[topic]
            ]
            dropped.update(_profile_rejections(xz, spec.topic, sigma_h))
        dropped.update(_frozen_rejections([r for r in rows[topic] if r[0] not in dropped], spec.topic))
        for reason in dropped.values():
            reject(reason)
        rows[topic] = [r for r in rows[topic] if r[0] not in dropped]

    empty = [t for t, rs in rows.items() if len(rs) < 2]
    if empty:
        raise Sim2RealError(
            f"bag {str(bag)!r}: fewer than 2 messages pass the input checks on {', '.join(empty)}; "
            + "; ".join(report.lines()[1:]).strip()
        )
    report.segments, bounds = _segments(rows, min_gap)
    if segment is not None:
        if not 1 <= segment <= len(report.segments):
            raise Sim2RealError(
                f"--segment {segment}: the bag has {len(report.segments)} segment(s): "
                + "; ".join(f"{i + 1}: {s}" for i, s in enumerate(report.segments))
            )
        report.analysed, report.why = segment - 1, "asked for"
    else:
        report.analysed = max(range(len(report.segments)), key=lambda i: report.segments[i].overlap)
        report.why = "the longest with every topic"
    chosen = report.segments[report.analysed]
    if chosen.overlap <= 0.0:
        raise Sim2RealError(
            f"bag {str(bag)!r}: no segment in which every input topic has data: "
            + "; ".join(f"{i + 1}: {s}" for i, s in enumerate(report.segments))
        )
    line, lo, hi = bounds[report.analysed]
    keep: set[_Key] = set()
    for topic, rs in rows.items():
        inside = [r[0] for r in rs if r[2] == line and lo <= r[1] <= hi]
        report.used[topic] = len(inside)
        report.outside[topic] = len(rs) - len(inside)
        keep.update(inside)
    _copy(bag, out, keep)
    return report


def _copy(bag: str | Path, out: Path, keep: Iterable[_Key]) -> None:
    """Write the messages ``keep`` of ``bag`` to the new MCAP bag ``out``, bytes unchanged, in recorded order."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer

    wanted = set(keep)
    topics = {k[0] for k in wanted}
    seen: dict[tuple[str, int], int] = {}
    try:
        with Reader(Path(bag) if Path(bag).is_dir() else Path(bag).parent) as reader:
            conns = [c for c in reader.connections if c.topic in topics]
            writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
            writer.open()
            try:
                targets = {c.topic: writer.add_connection(c.topic, c.msgtype, typestore=typestore()) for c in conns}
                for conn, timestamp, raw in reader.messages(connections=conns):
                    n = seen.get((conn.topic, timestamp), 0)
                    seen[(conn.topic, timestamp)] = n + 1
                    if (conn.topic, timestamp, n) in wanted:
                        writer.write(targets[conn.topic], timestamp, bytes(raw))
            finally:
                writer.close()
    except BagError:
        raise
    except Exception as exc:  # rosbags/storage errors: name the bag
        raise BagError(f"bag {str(bag)!r}: copying its checked messages failed: {type(exc).__name__}: {exc}") from exc
