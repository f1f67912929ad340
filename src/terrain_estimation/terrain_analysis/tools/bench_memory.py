"""Memory of estimation against bag length (issue 23 item 5): ``python -m terrain_analysis.tools.bench_memory``.

"Estimation streams the bag and never holds it whole. Report peak RSS per process and per worker; a 1 h bag
must not need more memory than a 1 min bag beyond its outputs."

Per vehicle the benchmark

* simulates a short bag (default 60 s) and makes a long one (default 3600 s) by repeating it with shifted stamps
  (:func:`repeat_bag`: every copy's log times and header stamps moved on by the short bag's span plus one
  sample interval; simulating an hour would take over an hour on a loaded 2-core machine, and a repeated minute
  is still a bag of that many messages for the reader, the checks, the filter and the writer). At each seam the
  vehicle's state jumps back to the start of the minute: the estimators may reject inputs or re-converge there,
  which costs estimates but no memory; the rejections are reported per bag;
* runs ``terrain-estimate`` on each bag in a child process and records its peak RSS (``ru_maxrss`` of that child
  from ``os.wait4``), wall and CPU time, the estimates written and the size of the output bag on disk;
* measures, in a child process per bag, with :mod:`tracemalloc` (which slows a run tenfold: so on two short
  bags, the first ``--trace-s`` seconds of the short bag, default 5 s, and twice that), what the run holds
  after each stage of ``terrain-estimate`` (the replay, which writes each estimate as it is made; the summary
  and closing the bag) and the size of the estimates kept in memory (deep, :func:`deep_size`: none since the
  run writes them as they come); the growth between the two lengths, per stage and by allocation site, names
  what grows;
* runs ``terrain-batch`` with 1 and 2 workers over the short bags (and, with ``--batch-long``, the long ones) and
  samples every process of its tree (``VmHWM``, the kernel's peak RSS of each, read every 0.2 s) for the peak
  RSS per worker.

The verdict per vehicle (:func:`verdict`): "streams" when the long bag's peak RSS exceeds the short one's by no
more than its extra estimates held in memory (extra estimates × bytes per estimate in memory, measured on the
short bag: about nothing, now that they are written as they come) plus a tolerance of
:data:`TOLERANCE_FRACTION` of the short bag's peak (allocator arenas, heap fragmentation, the writer's chunk
buffer: noise that does not scale with the bag); else it names what grows from the tracemalloc stages.

Nothing asserts a figure: they depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from terrain_analysis.tools.bench_common import (
    add_json_arguments,
    machine_info,
    parse_bench_arguments,
    run_in_fresh_process,
    write_json,
)
from terrain_estimation.cli import cli_main

__all__ = [
    "KEEP_MARKER",
    "TOLERANCE_FRACTION",
    "VEHICLES",
    "bench_batch_memory",
    "bench_memory",
    "deep_size",
    "format_batch",
    "format_memory",
    "repeat_bag",
    "verdict",
]

VEHICLES: tuple[str, ...] = ("quarter_car", "lrv", "skid_steer", "rover")
MB = 1024.0 * 1024.0
#: Share of the short bag's peak RSS allowed as growth that does not scale with the bag (see the module doc).
TOLERANCE_FRACTION = 0.05
#: The file that marks a ``--keep`` directory as this benchmark's own (its bags are reused, its outputs replaced).
KEEP_MARKER = ".bench_memory"
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time in little-endian CDR: int32 sec, uint32 nanosec


# ---------------------------------------------------------------------------
# Bags
# ---------------------------------------------------------------------------


def _header_first(store: Any, msgtype: str) -> bool:
    """True when ``msgtype``'s first field is a ``std_msgs/msg/Header`` (its stamp at bytes 4..12 of the CDR)."""
    fields = store.fielddefs[msgtype][1]
    if not fields:
        return False
    _name, (kind, spec) = fields[0]
    return bool(kind == 2 and spec == "std_msgs/msg/Header")  # 2: rosbags' Nodetype.NAME


def repeat_bag(src: Path, dst: Path, copies: int, *, span_s: float | None = None) -> dict[str, Any]:
    """Write ``dst`` (MCAP, rosbag2 version 9) as ``copies`` back-to-back copies of ``src``'s every message
    (``span_s``: of its messages in the first ``span_s`` seconds only).

    Copy ``k`` has its log times and, for messages whose first field is a Header, its header stamp moved on by
    ``k × period``, with ``period`` = ``src``'s span (last − first log time) + the largest median interval of
    its topics, so that each topic's stamps keep increasing across a seam. Other stamps inside a message (none
    in this project's inputs) are copied unchanged. The bytes are patched in place, never decoded: the copies
    are the recorded messages. Returns the counts and the period (ns).
    """
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer

    from terrain_estimation.bag import typestore

    if copies < 1:
        raise ValueError(f"copies must be >= 1, got {copies}")
    store = typestore()
    with AnyReader([src], default_typestore=store) as reader:
        items = [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]
        qos = {c.topic: getattr(c.ext, "offered_qos_profiles", []) for c in reader.connections}
    if items and span_s is not None:
        end = items[0][2] + round(span_s * 1e9)
        items = [item for item in items if item[2] < end]
    if not items:
        raise ValueError(f"{src}: no messages")
    times: dict[str, list[int]] = {}
    for topic, _, t, _ in items:
        times.setdefault(topic, []).append(t)
    gaps = [
        sorted(b - a for a, b in zip(ts, ts[1:], strict=False))[(len(ts) - 1) // 2]
        for ts in times.values()
        if len(ts) > 1
    ]
    period = items[-1][2] - items[0][2] + max(gaps, default=1)
    dst.parent.mkdir(parents=True, exist_ok=True)
    scratch = dst.with_name(f".{dst.name}.partial-{os.getpid()}")
    shutil.rmtree(scratch, ignore_errors=True)
    headed = {msgtype: _header_first(store, msgtype) for _, msgtype, _, _ in items}
    with Writer(scratch, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, msgtype, _, _ in items:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store, offered_qos_profiles=qos[topic])
        for k in range(copies):
            shift = k * period
            for topic, msgtype, t, raw in items:
                if shift and headed[msgtype] and raw[:2] == b"\x00\x01" and len(raw) >= 12:
                    sec, nsec = _STAMP.unpack_from(raw, 4)
                    stamp = sec * 1_000_000_000 + nsec + shift
                    patched = bytearray(raw)
                    _STAMP.pack_into(patched, 4, stamp // 1_000_000_000, stamp % 1_000_000_000)
                    raw = bytes(patched)
                writer.write(conns[topic], t + shift, raw)
    # rosbags names the storage file after the directory: rename both so the bag is self-consistent
    (scratch / f"{scratch.name}.mcap").rename(scratch / f"{dst.name}.mcap")
    meta = scratch / "metadata.yaml"
    meta.write_text(meta.read_text().replace(f"{scratch.name}.mcap", f"{dst.name}.mcap"))
    shutil.rmtree(dst, ignore_errors=True)
    scratch.rename(dst)
    return {"messages": len(items) * copies, "copies": copies, "period_ns": period}


def _median_gap(times: Sequence[int]) -> int:
    gaps = sorted(b - a for a, b in zip(times, times[1:], strict=False))
    return gaps[(len(gaps) - 1) // 2]


def _check_repeated(bag: Path, expected: int) -> None:
    """Read ``bag`` back with rosbags' AnyReader: every message there, decodable, in time order."""
    from rosbags.highlevel import AnyReader

    from terrain_estimation.bag import typestore

    count, last = 0, -1
    with AnyReader([bag], default_typestore=typestore()) as reader:
        for i, (conn, t, raw) in enumerate(reader.messages()):
            if t < last:
                raise ValueError(f"{bag}: log times go back at message {i}")
            last = t
            if i % 997 == 0:  # a sample of every topic's messages decodes
                reader.deserialize(raw, conn.msgtype)
            count += 1
    if count != expected:
        raise ValueError(f"{bag}: {count} messages read back, {expected} written")


def _du(path: Path) -> int:
    """Bytes of the files under ``path``."""
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def keep_directory(path: Path) -> Path:
    """``path`` as the ``--keep`` directory: created with its marker when absent or empty, else only when it
    carries the marker. Raises FileExistsError (nothing written) for any other existing path."""
    if path.exists() and not (path / KEEP_MARKER).is_file() and (not path.is_dir() or any(path.iterdir())):
        raise FileExistsError(f"--keep {str(path)!r} exists and was not made by bench_memory (no {KEEP_MARKER})")
    path.mkdir(parents=True, exist_ok=True)
    (path / KEEP_MARKER).touch()
    return path


def make_bags(
    root: Path, vehicle: str, short_s: float, lengths: Sequence[float], seed: int | None = None
) -> dict[float, Path]:
    """The short bag (simulated; ``seed``: None for the vehicle's configured one) and every length in ``lengths``
    (repeats of it; a length below ``short_s``: its start), reused when present."""
    from vehicle_sim.tools.simulate import record

    short = root / f"{vehicle}_{short_s:g}s"
    if not (short / "metadata.yaml").is_file():
        _progress(f"simulating {vehicle} {short_s:g} s")
        record(vehicle, short_s, short, overrides=None if seed is None else {"seed": seed}, overwrite=short.exists())
    bags = {short_s: short}
    for length in lengths:
        if length == short_s:
            continue
        copies, span = (round(length / short_s), None) if length > short_s else (1, length)
        bag = root / f"{vehicle}_{length:g}s"
        if not (bag / "metadata.yaml").is_file():
            _progress(f"writing {bag.name} ({copies} × {short.name}" + (f", its first {span:g} s)" if span else ")"))
            info = repeat_bag(short, bag, copies, span_s=span)
            _check_repeated(bag, info["messages"])
        bags[length] = bag
    return bags


def _progress(text: str) -> None:
    print(f"  … {time.strftime('%H:%M:%S')} {text}", file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------
# One terrain-estimate process
# ---------------------------------------------------------------------------

_READ = re.compile(r"input messages read: (\d+) \((\d+) accepted, (\d+) rejected\)")
_REJECTED = re.compile(r"^\s+rejected (\d+): (.*)$", re.M)
_WROTE = re.compile(r"wrote (\d+) messages")


def run_estimate(bag: Path, vehicle: str, out: Path) -> dict[str, Any]:
    """``terrain-estimate`` on ``bag`` in a child process: its peak RSS (``ru_maxrss``), CPU, wall, output."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "terrain_estimation.tools.estimate", str(bag), "--vehicle", vehicle, "-o", str(out)]
    with tempfile.TemporaryFile("w+") as stdout, tempfile.TemporaryFile("w+") as stderr:
        wall0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=stdout, stderr=stderr, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - wall0
        proc.returncode = os.waitstatus_to_exitcode(status)
        stdout.seek(0)
        stderr.seek(0)
        text, err = stdout.read(), stderr.read()
    row: dict[str, Any] = {
        "exit": proc.returncode,
        "peak_rss_mb": usage.ru_maxrss / 1024.0,  # KiB on Linux
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "wall_s": wall,
        "output_mb": _du(out) / MB if out.exists() else 0.0,
        "estimates": int(m.group(1)) if (m := _WROTE.search(text)) else 0,
    }
    if (m := _READ.search(text)) is not None:
        row.update(read=int(m.group(1)), accepted=int(m.group(2)), rejected=int(m.group(3)))
    row["rejections"] = {reason: int(n) for n, reason in _REJECTED.findall(text)}
    if proc.returncode != 0:
        row["error"] = (err.strip().splitlines() or ["?"])[-1][:300]
    return row


# ---------------------------------------------------------------------------
# What the run holds (tracemalloc, in a child process)
# ---------------------------------------------------------------------------


def deep_size(obj: Any, seen: set[int] | None = None) -> int:
    """Bytes of ``obj`` and everything it refers to (each object once): containers, ``__slots__`` and
    ``__dict__`` attributes, numpy arrays' buffers. Shared immutable singletons (small ints, interned
    strings, None) are counted where first met."""
    import numpy as np

    seen = set() if seen is None else seen
    stack = [obj]
    total = 0
    while stack:
        o = stack.pop()
        if id(o) in seen:
            continue
        seen.add(id(o))
        if isinstance(o, np.ndarray):
            total += sys.getsizeof(o) + (o.nbytes if o.base is None else 0)
            continue
        total += sys.getsizeof(o)
        if isinstance(o, dict):
            stack.extend(o.keys())
            stack.extend(o.values())
        elif isinstance(o, (list, tuple, set, frozenset)):
            stack.extend(o)
        elif not isinstance(o, (str, bytes, int, float, bool, type(None))):
            for slot in getattr(type(o), "__slots__", ()):
                with contextlib.suppress(AttributeError):
                    stack.append(getattr(o, slot))
            if hasattr(o, "__dict__"):
                stack.append(o.__dict__)
    return total


def _traced(bag: str, warm: str, vehicle: str, out: str) -> dict[str, Any]:
    """``terrain-estimate``'s run (:func:`~terrain_estimation.tools.estimate.estimate_to_bag`, what the CLI runs)
    on ``bag`` under tracemalloc, after an untimed run on ``warm``: what is held and the peak of each stage, the
    allocation sites.

    Stages: the replay, which writes each estimate as it is made (up to the summary's first line: the writer
    still open); the summary and closing the bag (to the end of the run).
    """
    import gc
    import tracemalloc

    from terrain_estimation.tools import estimate as est

    est.estimate_bag(warm, vehicle)  # untraced warm-up: imports, numba caches, first calls (the short bag)
    gc.collect()
    tracemalloc.start(8)
    base = tracemalloc.take_snapshot()
    base_bytes = tracemalloc.get_traced_memory()[0]
    lines: list[str] = []
    at_summary: dict[str, Any] = {}

    def report(line: str) -> None:
        if not lines:  # the replay is done, the bag not yet closed
            gc.collect()
            at_summary["memory"] = tracemalloc.get_traced_memory()
            at_summary["snapshot"] = tracemalloc.take_snapshot()
            tracemalloc.reset_peak()
        lines.append(line)

    run, written = est.estimate_to_bag(bag, vehicle, out, overwrite=True, report=report)
    gc.collect()
    end = tracemalloc.get_traced_memory()
    snap_end = tracemalloc.take_snapshot()
    tracemalloc.stop()
    replay, snap_replay = at_summary["memory"], at_summary["snapshot"]
    outputs_bytes = deep_size(run.outputs)  # the estimates the run holds: none, they were written
    truth = run.__dict__.get("_truth") or {}
    return {
        "estimates": written,
        "truth_messages": sum(len(v) for v in truth.values()),
        "summary_lines": len(lines),
        "held_replay_mb": (replay[0] - base_bytes) / MB,
        "peak_replay_mb": (replay[1] - base_bytes) / MB,
        "held_end_mb": (end[0] - base_bytes) / MB,
        "peak_closing_mb": (end[1] - base_bytes) / MB,
        "outputs_mb": outputs_bytes / MB,
        "truth_mb": deep_size(truth) / MB,
        "bytes_per_estimate": outputs_bytes / max(written, 1),
        "sites_replay": _sites(snap_replay, base),
        "sites_end": _sites(snap_end, snap_replay),
    }


def _sites(after: Any, before: Any, top: int = 6) -> list[tuple[str, float]]:
    """The allocation sites (the innermost project frame, else the innermost one) holding the most more MB."""
    stats = after.compare_to(before, "traceback")
    by_site: dict[str, float] = {}
    for s in stats:
        frames = list(s.traceback)
        project = [f for f in frames if "terrain_" in f.filename or "vehicle_sim" in f.filename]
        f = (project or frames)[-1]  # compare_to's tracebacks list the most recent call last
        where = f"{Path(f.filename).name}:{f.lineno}"
        by_site[where] = by_site.get(where, 0.0) + s.size_diff / MB
    return sorted(by_site.items(), key=lambda kv: -kv[1])[:top]


def trace_estimate(bag: Path, warm: Path, vehicle: str, out: Path) -> dict[str, Any]:
    """:func:`_traced` in a fresh (spawned) process."""
    row = run_in_fresh_process(_traced, (str(bag), str(warm), vehicle, str(out)), error_key="error", what="traced")
    shutil.rmtree(out, ignore_errors=True)
    return row


# ---------------------------------------------------------------------------
# The verdict
# ---------------------------------------------------------------------------


def verdict(
    short: Mapping[str, Any],
    long: Mapping[str, Any],
    bytes_per_estimate: float,
    *,
    tolerance: float = TOLERANCE_FRACTION,
) -> dict[str, Any]:
    """Compare a long bag's ``terrain-estimate`` row with the short bag's (see the module doc).

    ``allowed_mb`` = (long − short estimates) × ``bytes_per_estimate`` (the estimates held in memory until they
    are written) + ``tolerance`` × the short bag's peak RSS. "streams" when the growth is within it.
    """
    growth = long["peak_rss_mb"] - short["peak_rss_mb"]
    outputs_mb = max(long["estimates"] - short["estimates"], 0) * bytes_per_estimate / MB
    slack_mb = tolerance * short["peak_rss_mb"]
    return {
        "growth_mb": growth,
        "growth_pct": 100.0 * growth / short["peak_rss_mb"] if short["peak_rss_mb"] > 0 else 0.0,
        "outputs_in_memory_mb": outputs_mb,
        "slack_mb": slack_mb,
        "allowed_mb": outputs_mb + slack_mb,
        "streams": growth <= outputs_mb + slack_mb,
    }


def _what_grows(short: Mapping[str, Any], long: Mapping[str, Any], scale: float = 1.0) -> str:
    """What grew from the short traced bag to the long one, per stage of ``terrain-estimate``, times ``scale``
    (the long bag's extra seconds over the traced bags' difference: a projection to the long bag). Stages
    (:func:`_traced`): what the run holds after the replay (which writes the estimates as it goes), the replay's
    transient peak above it, what is held at the end (after the summary and closing the bag), the closing's
    transient peak above it; then the sites holding the most more after the replay."""

    def grew(f: Any) -> float:
        return scale * (f(long) - f(short))

    parts = [
        f"held after the replay {grew(lambda t: t['held_replay_mb']):+.1f} MB",
        f"replay peak above it {grew(lambda t: t['peak_replay_mb'] - t['held_replay_mb']):+.1f} MB",
        f"held at the end {grew(lambda t: t['held_end_mb']):+.1f} MB",
        f"closing peak {grew(lambda t: t['peak_closing_mb'] - t['held_replay_mb']):+.1f} MB",
    ]
    sites = sorted(long.get("sites_replay", []), key=lambda kv: -kv[1])[:2]
    top = ", ".join(f"{k} {v:.1f}" for k, v in sites if v > 0.05)
    return "projected from the traces: " + "; ".join(parts) + (f" (replay's sites, MB: {top})" if top else "")


# ---------------------------------------------------------------------------
# The benchmark
# ---------------------------------------------------------------------------


def bench_memory(
    root: Path,
    vehicles: Sequence[str],
    *,
    short_s: float,
    long_s: float,
    trace_s: float,
    seed: int | None = None,
) -> list[dict[str, Any]]:
    """Per vehicle and bag length: the ``terrain-estimate`` row; per vehicle: the trace and the verdict."""
    rows: list[dict[str, Any]] = []
    for vehicle in vehicles:
        try:
            bags = make_bags(root, vehicle, short_s, (trace_s, 2 * trace_s, long_s), seed)
        except Exception as exc:  # a bench row, not a crash: say why
            rows.append({"vehicle": vehicle, "skipped": f"could not make the bags: {type(exc).__name__}: {exc}"})
            continue
        runs: dict[float, dict[str, Any]] = {}
        for length in sorted({short_s, long_s}):
            _progress(f"terrain-estimate {vehicle} {length:g} s")
            row = run_estimate(bags[length], vehicle, root / "out" / f"{vehicle}_{length:g}s")
            row.update(vehicle=vehicle, bag_s=length, x_real_time=length / row["cpu_s"] if row["cpu_s"] else 0.0)
            _progress(f"  peak RSS {row['peak_rss_mb']:.1f} MB, CPU {row['cpu_s']:.1f} s, {row['estimates']} estimates")
            runs[length] = row
            rows.append(row)
        traces: dict[str, dict[str, Any]] = {}
        for label, length in (("short", trace_s), ("long", 2 * trace_s)):
            _progress(f"tracemalloc {vehicle} {length:g} s")
            traces[label] = trace_estimate(
                bags[length], bags[short_s], vehicle, root / "out" / f"{vehicle}_{length:g}s_traced"
            )
        short, long = runs[short_s], runs[long_s]
        summary: dict[str, Any] = {"vehicle": vehicle, "kind": "verdict", "trace": traces, "trace_s": trace_s}
        if "error" in short or "error" in long or "error" in traces["short"]:
            summary["verdict"] = "not measured: " + str(
                short.get("error") or long.get("error") or traces["short"]["error"]
            )
        else:
            v = verdict(short, long, traces["short"]["bytes_per_estimate"])
            summary.update(v)
            scale = (long_s - short_s) / trace_s  # the traced bags differ by trace_s seconds
            what = _what_grows(traces["short"], traces["long"], scale)
            summary["verdict"] = "streams" if v["streams"] else "grows: " + what
        rows.append(summary)
    return rows


def format_memory(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The table of ``terrain-estimate`` runs, then one verdict line per vehicle (with its trace)."""
    lines = [
        "terrain-estimate memory against bag length (one child process per bag; peak RSS = ru_maxrss)",
        f"  {'vehicle':<12}{'bag s':>7}{'peak RSS MB':>12}{'growth MB':>10}{'growth %':>9}{'estimates':>10}"
        f"{'output MB':>10}{'CPU s':>8}{'wall s':>8}{'× real':>8}{'rejected':>9}",
    ]
    short: dict[str, Mapping[str, Any]] = {}
    for r in rows:
        if r.get("kind") == "verdict" or "skipped" in r:
            continue
        base = short.setdefault(r["vehicle"], r)
        growth = r["peak_rss_mb"] - base["peak_rss_mb"]
        pct = 100.0 * growth / base["peak_rss_mb"] if base["peak_rss_mb"] else 0.0
        g, p = ("", "") if base is r else (f"{growth:+.1f}", f"{pct:+.1f}")
        lines.append(
            f"  {r['vehicle']:<12}{r['bag_s']:>7.0f}{r['peak_rss_mb']:>12.1f}{g:>10}{p:>9}{r['estimates']:>10d}"
            f"{r['output_mb']:>10.1f}{r['cpu_s']:>8.1f}{r['wall_s']:>8.1f}{r['x_real_time']:>8.1f}"
            f"{r.get('rejected', 0):>9d}" + (f"  exit {r['exit']}: {r.get('error', '')}" if r["exit"] else "")
        )
    lines.append("  rejections by the input checks, top 3 reasons per bag (a long bag has a seam every short bag):")
    for r in rows:
        if r.get("kind") != "verdict" and "skipped" not in r and r.get("rejections"):
            top = "; ".join(f"{n} {why[:70]}" for why, n in sorted(r["rejections"].items(), key=lambda kv: -kv[1])[:3])
            lines.append(f"    {r['vehicle']:<12}{r['bag_s']:>6.0f} s: {top}")
    lines.append(
        "Verdict (streams: growth ≤ extra estimates × bytes per estimate in memory + "
        f"{100 * TOLERANCE_FRACTION:.0f} % of the short peak)"
    )
    for r in rows:
        if "skipped" in r:
            lines.append(f"  {r['vehicle']:<12}skipped: {r['skipped']}")
        if r.get("kind") != "verdict":
            continue
        lines.append(f"  {r['vehicle']:<12}{r['verdict']}")
        if "allowed_mb" in r:
            lines.append(
                f"  {'':<12}growth {r['growth_mb']:+.1f} MB, allowed {r['allowed_mb']:.1f} MB"
                f" (estimates {r['outputs_in_memory_mb']:.1f} + slack {r['slack_mb']:.1f})"
            )
        for label, t in r["trace"].items():
            if "error" in t:
                lines.append(f"  {'':<12}trace {label}: {t['error']}")
                continue
            lines.append(
                f"  {'':<12}tracemalloc {label:<5} {t['estimates']:>7d} estimates × {t['bytes_per_estimate']:.0f} B ="
                f" {t['outputs_mb']:.1f} MB held; after the replay {t['held_replay_mb']:.1f} MB (peak"
                f" {t['peak_replay_mb']:.1f}), at the end {t['held_end_mb']:.1f} MB (truth held"
                f" {t['truth_messages']} msgs {t['truth_mb']:.1f} MB), closing peak {t['peak_closing_mb']:.1f} MB"
            )
    return lines


# ---------------------------------------------------------------------------
# terrain-batch: peak RSS per worker
# ---------------------------------------------------------------------------


def _status_kib(pid: int, field: str) -> int | None:
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    m = re.search(rf"^{field}:\s+(\d+) kB", text, re.M)
    return int(m.group(1)) if m else None


def _role(cmdline: Sequence[str], parent: Sequence[str] = ()) -> str:
    """What a process of the batch's tree is, from its command line and its parent's: a Dask worker is spawned
    (``spawn_main``) or forked by a forkserver (its command line is the forkserver's)."""
    text = " ".join(cmdline)
    if "resource_tracker" in text:
        return "resource tracker"
    if "forkserver" in text:
        return "worker" if "forkserver" in " ".join(parent) else "forkserver"
    if "spawn_main" in text or "--multiprocessing-fork" in text:
        return "worker"
    return "other"


@contextlib.contextmanager
def _sampling(pid: int, every_s: float = 0.2) -> Iterator[dict[int, dict[str, Any]]]:
    """Sample the process tree of ``pid`` every ``every_s``: per process its role and peak RSS (VmHWM, MB)."""
    import psutil

    peaks: dict[int, dict[str, Any]] = {}
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            try:
                procs = [psutil.Process(pid), *psutil.Process(pid).children(recursive=True)]
            except psutil.Error:
                procs = []
            for p in procs:
                hwm = _status_kib(p.pid, "VmHWM")
                if hwm is None:
                    continue
                entry = peaks.get(p.pid)
                if entry is None:
                    with contextlib.suppress(psutil.Error):
                        cmd = p.cmdline()
                        parent = p.parent()
                        role = "batch" if p.pid == pid else _role(cmd, parent.cmdline() if parent else ())
                        entry = peaks[p.pid] = {"role": role, "peak_mb": 0.0, "cmd": " ".join(cmd)[:160]}
                if entry is not None:
                    entry["peak_mb"] = max(entry["peak_mb"], hwm / 1024.0)
            stop.wait(every_s)

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    try:
        yield peaks
    finally:
        stop.set()
        thread.join()


def bench_batch_memory(root: Path, bags: Sequence[Path], workers: Sequence[int]) -> list[dict[str, Any]]:
    """``terrain-batch`` over ``bags`` with each number of ``workers``: peak RSS per worker and of the batch."""
    rows: list[dict[str, Any]] = []
    listing = root / "batch_bags.txt"
    listing.write_text("".join(f"{b}\n" for b in bags))
    seconds = sum(_bag_seconds(b) for b in bags)
    for n in workers:
        out = root / f"batch_{n}w"
        shutil.rmtree(out, ignore_errors=True)
        _progress(f"terrain-batch {len(bags)} bags, {n} worker(s)")
        cmd = [sys.executable, "-m", "terrain_analysis.tools.batch", "--from-file", str(listing), "-o", str(out)]
        cmd += ["--workers", str(n), "--force"]
        wall0 = time.perf_counter()
        with tempfile.TemporaryFile("w+") as log:
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, text=True)
            with _sampling(proc.pid) as peaks:
                _, status, usage = os.wait4(proc.pid, 0)
            proc.returncode = os.waitstatus_to_exitcode(status)
            log.seek(0)
            tail = log.read().strip().splitlines()[-1:] or [""]
        wall = time.perf_counter() - wall0
        by_role: dict[str, list[float]] = {}
        for entry in peaks.values():
            by_role.setdefault(entry["role"], []).append(entry["peak_mb"])
        rows.append(
            {
                "workers": n,
                "bags": len(bags),
                "bag_s": seconds,
                "exit": proc.returncode,
                "wall_s": wall,
                "children_cpu_s": usage.ru_utime + usage.ru_stime,
                "batch_peak_rss_mb": usage.ru_maxrss / 1024.0,
                "worker_peak_rss_mb": sorted(by_role.get("worker", []), reverse=True),
                "other_peak_rss_mb": sorted(
                    [x for role, xs in by_role.items() if role not in ("worker", "batch") for x in xs], reverse=True
                ),
                "last_line": tail[0][:200],
                "processes": sorted(peaks.values(), key=lambda e: -e["peak_mb"]),
            }
        )
    return rows


def _bag_seconds(bag: Path) -> float:
    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:
        return float(reader.duration) * 1e-9


def format_batch(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The per-worker table of ``terrain-batch`` (peak RSS = each process's VmHWM, sampled every 0.2 s)."""
    lines = [
        "terrain-batch peak RSS per worker (VmHWM of each process of its tree, sampled every 0.2 s)",
        f"  {'workers':>7}{'bags':>6}{'bag s':>8}{'wall s':>8}{'× real':>8}{'batch MB':>10}  per worker MB"
        "  (others MB)",
    ]
    for r in rows:
        per = ", ".join(f"{x:.0f}" for x in r["worker_peak_rss_mb"]) or "-"
        other = ", ".join(f"{x:.0f}" for x in r["other_peak_rss_mb"]) or "-"
        status = "" if r["exit"] == 0 else f"  exit {r['exit']}: {r['last_line']}"
        lines.append(
            f"  {r['workers']:>7d}{r['bags']:>6d}{r['bag_s']:>8.0f}{r['wall_s']:>8.1f}"
            f"{r['bag_s'] / r['wall_s'] if r['wall_s'] else 0.0:>8.1f}{r['batch_peak_rss_mb']:>10.1f}  {per}  ({other})"
            + status
        )
    return lines


@cli_main("bench_memory")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="bench_memory", description="Peak RSS of terrain-estimate and terrain-batch against bag length (issue 23)."
    )
    parser.add_argument("--quick", action="store_true", help="short smoke run: 10 s against 60 s, quarter car")
    parser.add_argument("--vehicles", nargs="+", choices=VEHICLES, default=None, help="vehicles (default: all four)")
    parser.add_argument("--short-s", type=float, default=60.0, help="the simulated bag (s)")
    parser.add_argument("--long-s", type=float, default=3600.0, help="the long bag (s; repeats of the short one)")
    parser.add_argument("--trace-s", type=float, default=5.0, help="the traced bags: this and twice this (s)")
    parser.add_argument("--workers", type=int, nargs="*", default=[1, 2], help="terrain-batch workers (none: skip)")
    parser.add_argument("--batch-long", action="store_true", help="terrain-batch over the long bags too")
    parser.add_argument("--seed", type=int, default=None, help="seed of the simulated bags (default: configured)")
    parser.add_argument("--keep", metavar="DIR", help="make and keep the bags and outputs here (bags reused)")
    add_json_arguments(parser)
    args = parse_bench_arguments(parser, argv)
    short_s, long_s = (10.0, 60.0) if args.quick else (args.short_s, args.long_s)
    vehicles = args.vehicles or (["quarter_car"] if args.quick else list(VEHICLES))
    trace_s = args.trace_s
    if not 0 < short_s < long_s or not 0 < 2 * trace_s <= short_s:
        parser.error(
            f"need 0 < --short-s < --long-s and 0 < 2 × --trace-s <= --short-s, got {short_s}, {long_s}, {trace_s}"
        )
    with contextlib.ExitStack() as stack:
        if args.keep:
            root = keep_directory(Path(args.keep))
        else:
            root = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="bench_memory_")))
        rows = bench_memory(root, vehicles, short_s=short_s, long_s=long_s, trace_s=trace_s, seed=args.seed)
        made = [r["vehicle"] for r in rows if r.get("kind") == "verdict"]
        bags = [root / f"{v}_{short_s:g}s" for v in made]
        if args.batch_long:
            bags += [root / f"{v}_{long_s:g}s" for v in made]
        batch = bench_batch_memory(root, bags, args.workers) if bags and args.workers else []
    print("\n".join(format_memory(rows)))
    if batch:
        print("\n".join(format_batch(batch)))
    if args.json:
        write_json(args.json, {"machine": machine_info(), "estimate": rows, "batch": batch}, overwrite=args.overwrite)
    return 0


if __name__ == "__main__":
    sys.exit(main())
