"""``terrain-batch PATH... -o OUT``: estimate and/or diagnose every bag of a tree or list, on a Dask cluster.

For a fleet's recordings: every bag under the paths given (directories are
walked; ``--from-file`` reads paths one per line) is estimated as
``terrain-estimate`` does and/or diagnosed as ``terrain-sim2real`` does, each
bag a task on a Dask distributed cluster (:mod:`terrain_analysis.batch.engine`):
by default a local cluster of one worker process per core, or a running
cluster with ``--scheduler tcp://HOST:8786`` (whose workers must see the same
paths and have this package installed).

* The vehicle of each bag is ``--vehicle``, or detected from its topics, their
  types and namespace (:func:`terrain_analysis.batch.bags.detect_vehicle`);
  a bag no vehicle fits is a failure with the reason.
* Each bag is isolated: a corrupt bag, a bag of unknown vehicle, a failing
  estimator or a worker that dies is that bag's row, with its reason; the
  others go on.
* Runs resume: a bag whose outputs are up to date with its files (size and
  mtime, else SHA-256), the tool version (``--code-key``), the parameter
  files and the options is skipped and its
  earlier row kept (``--force`` redoes it); a bag that failed and has not
  changed since is not tried again (its row says so) unless ``--retry-failed``.
* A progress bar with an ETA goes to stderr (plain lines when it is not a
  terminal).
* One summary: ``OUT/summary.csv`` (and ``summary.parquet`` when pyarrow is
  installed), one row per bag (vehicle, duration, estimates, rejections by
  reason, final estimates, verdict, CPU time, status), and ``OUT/summary.md``
  and ``summary.html`` for a person. The outputs of each bag go under
  ``OUT/bags/<its path relative to the inputs' common root>/``.

The input bags are only read. Nothing is removed that this tool did not make:
an existing ``OUT`` not made by a project tool is refused (unless
``--overwrite``), and a bag's output directory not made by it is that bag's
failure.

Exit status (``terrain_estimation.cli``): 0 every bag done or up to date; 1
some bags failed, the others done (see the summary); 2 nothing produced (no
bag found, every bag failed, a bad option or output path); 3 internal error.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import html
import json
import os
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from terrain_analysis.batch.bags import (
    COLUMNS,
    TASKS,
    TOOL,
    BagJob,
    BatchOptions,
    code_version,
    failed_row,
    find_bags,
    process_bag,
    tool_version,
    up_to_date,
)
from terrain_estimation.cli import EXIT_FINDING, EXIT_INPUT, EXIT_OK, InputError, run_cli

__all__ = ["main", "run_batch", "write_summary"]


def _warm_worker() -> str:
    """Load the estimators and the vehicle table in a worker before its first bag (a worker's start-up)."""
    from terrain_analysis.batch.bags import code_version, vehicle_inputs

    vehicle_inputs()
    code_version()  # the sources as this worker loaded them (provenance of its rows)
    return str(os.getpid())


def _bag_bytes(path: Path) -> int:
    try:
        return sum(p.stat().st_size for p in path.iterdir() if p.is_file()) or 1
    except OSError:
        return 1


def run_batch(
    paths: Sequence[str],
    out: Path,
    options: BatchOptions,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    memory_limit: str = "auto",
    force: bool = False,
    retry_failed: bool = False,
    code_key: str = "version",
    overwrite: bool = False,
    log: Any = None,
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Run the batch; return ``(rows, run facts)`` after writing the summary into ``out``.

    Raises:
        InputError: no bag under ``paths``; ``out`` may not be written (is or holds an input, or exists
            and was not made by a project tool and ``overwrite`` is not set).
        EngineError: the cluster cannot be started or reached.
    """
    from terrain_analysis.batch.engine import Engine, Progress, Task, TaskResult
    from terrain_estimation.outputs import check_output_dir, prepare_output_dir

    say = log if log is not None else (lambda text: print(f"{TOOL}: {text}", file=sys.stderr, flush=True))
    started = time.monotonic()
    if options.config:  # the workers may not share the client's working directory
        options = dataclasses.replace(options, config=str(Path(options.config).absolute()))
    inputs = [*paths, *([options.config] if options.config else [])]
    check_output_dir(out, overwrite=overwrite, inputs=inputs)
    found, missing = find_bags(paths)
    if not found and not missing:
        raise InputError(
            f"no rosbag2 bag (a directory with metadata.yaml or .mcap/.db3 files) under {', '.join(paths)}"
        )
    version = {"tool": tool_version(code_key)}
    out = out.absolute()
    jobs = [BagJob(str(bag), rel, str(out / "bags" / rel), options, version) for bag, rel in found]
    rows: dict[str, dict[str, Any]] = {}
    for path, name in missing:
        job = BagJob(str(path), name, "", options, version)
        rows[name] = failed_row(job, f"{path} does not exist")
    todo = []
    for job in jobs:
        previous = None if force else up_to_date(job, retry_failed=retry_failed)
        if previous is not None:
            row = dict(previous)
            if previous.get("status") == "done":
                row["status"] = "skipped"
                row["reason"] = f"up to date (done {previous.get('finished')})"
                if previous.get("code") != code_version():  # provenance only (see --code-key)
                    made = str(previous.get("code")).rsplit(":", 1)[-1][:8]
                    row["reason"] += f"; made by sources {made}, now {code_version().rsplit(':', 1)[-1][:8]}"
            else:
                row["reason"] = (
                    f"unchanged since it failed at {previous.get('finished')} (--retry-failed tries again): "
                    f"{previous.get('reason')}"
                )
            rows[job.rel] = row
        else:
            todo.append(job)
    say(
        f"{len(found)} bags found, {len(found) - len(todo)} up to date or unchanged since they failed, "
        f"{len(todo)} to do ({', '.join(options.tasks)})"
    )
    facts: dict[str, Any] = {"bags_found": len(found), "todo": len(todo), "engine": "none (nothing to do)"}
    if not todo:
        prepare_output_dir(out, overwrite=overwrite, inputs=inputs, tool=TOOL)
    else:
        with Engine(scheduler, workers=workers, memory_limit=memory_limit) as engine:
            if scheduler:  # a running cluster may still be starting its workers
                engine.wait_for_workers(1, timeout_s=120.0)
            prepare_output_dir(out, overwrite=overwrite, inputs=inputs, tool=TOOL)  # once the cluster is there
            t0 = time.monotonic()
            try:  # every connected worker loads the estimators once, before its first bag
                warmed = engine.client.run(_warm_worker)
            except Exception as exc:  # an optimisation only: each task loads what it needs anyway
                say(f"worker warm-up failed ({type(exc).__name__}: {exc}); the bags load the estimators themselves")
                warmed = {}
            facts.update(
                engine=f"Dask distributed, {'scheduler ' + scheduler if scheduler else 'local cluster'}, "
                f"{engine.n_workers()} workers",
                workers=engine.n_workers(),
                warm_up_s=time.monotonic() - t0,
            )
            say(f"{facts['engine']} ready ({len(warmed)} workers warmed up in {facts['warm_up_s']:.1f} s)")
            weights = {job.rel: float(_bag_bytes(Path(job.bag))) for job in todo}
            progress = Progress(len(todo), "bags", total_weight=sum(weights.values()))
            tasks = [Task(job.rel, process_bag, (job,), weights[job.rel]) for job in todo]
            by_rel = {job.rel: job for job in todo}
            t1 = time.monotonic()

            def is_failure(result: TaskResult[Any]) -> bool:
                return isinstance(result.value, dict) and result.value.get("status") == "failed"

            for result in engine.run(tasks, progress=progress, failed=is_failure):
                if result.ok and isinstance(result.value, dict):
                    row = result.value
                else:
                    row = failed_row(by_rel[result.key], f"worker: {result.error}")
                row.update(cpu_s=result.cpu_s, wall_s=result.wall_s, worker=result.worker)
                if row.get("duration_s") and result.cpu_s > 0:
                    row["realtime_per_cpu"] = float(row["duration_s"]) / result.cpu_s
                rows[result.key] = row
                if row["status"] == "done":
                    _refresh_manifest(Path(row["output"]), row)
            facts["tasks_wall_s"] = time.monotonic() - t1
    facts["wall_s"] = time.monotonic() - started
    ordered = [rows[k] for k in sorted(rows)]
    write_summary(out, ordered, facts, options)
    return ordered, facts


def _refresh_manifest(out_dir: Path, row: Mapping[str, Any]) -> None:
    """Store the CPU and wall time (known to the engine only after the task) in the bag's ``batch.json``."""
    from terrain_analysis.batch.bags import MANIFEST

    path = out_dir / MANIFEST
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    manifest["row"] = dict(row)
    partial = path.with_name(f".{MANIFEST}.partial-{os.getpid()}")
    partial.write_text(json.dumps(manifest, indent=1, default=str) + "\n", encoding="utf-8")
    os.replace(partial, path)


def _fmt(value: Any, digits: int = 2) -> str:
    if value is None or value == "":
        return ""
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def _atomic_write(path: Path, text: str) -> None:
    partial = path.with_name(f".{path.name}.partial-{os.getpid()}")
    partial.write_text(text, encoding="utf-8")
    os.replace(partial, path)


def _rejections_text(row: Mapping[str, Any], limit: int = 3) -> str:
    try:
        reasons: dict[str, int] = json.loads(row.get("rejections") or "{}")
    except ValueError:
        return str(row.get("rejections"))
    items = sorted(reasons.items(), key=lambda kv: -kv[1])
    text = "; ".join(f"{n}× {r}" for r, n in items[:limit])
    return text + (f"; … {len(items) - limit} more reasons" if len(items) > limit else "")


def write_summary(
    out: Path, rows: Sequence[Mapping[str, Any]], facts: Mapping[str, Any], options: BatchOptions
) -> list[Path]:
    """Write ``summary.csv`` (and ``.parquet`` with pyarrow), ``summary.md`` and ``summary.html`` into ``out``."""
    table = [{c: r.get(c) for c in COLUMNS} for r in rows]
    written = []
    partial = out / f".summary.csv.partial-{os.getpid()}"
    with partial.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(COLUMNS))
        writer.writeheader()
        writer.writerows(table)
    os.replace(partial, out / "summary.csv")
    written.append(out / "summary.csv")
    try:
        import pyarrow as pa  # type: ignore[import-not-found, unused-ignore]
        import pyarrow.parquet as pq  # type: ignore[import-not-found, unused-ignore]
    except ImportError:
        pass
    else:
        pq.write_table(pa.Table.from_pylist(table), str(out / "summary.parquet"))
        written.append(out / "summary.parquet")
    md = _markdown(table, facts, options)
    _atomic_write(out / "summary.md", md)
    written.append(out / "summary.md")
    _atomic_write(out / "summary.html", _html(table, facts, options))
    written.append(out / "summary.html")
    return written


def _counts(rows: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    out = {"done": 0, "skipped": 0, "failed": 0}
    for r in rows:
        out[str(r["status"])] = out.get(str(r["status"]), 0) + 1
    return out


def _overview(
    rows: Sequence[Mapping[str, Any]], facts: Mapping[str, Any], options: BatchOptions
) -> list[tuple[str, str]]:
    counts = _counts(rows)
    ran = [r for r in rows if r["status"] == "done"]
    rec_s = sum(float(r["duration_s"] or 0) for r in ran)
    cpu_s = sum(float(r["cpu_s"] or 0) for r in ran)
    items = [
        (
            "bags",
            f"{len(rows)}: {counts['done']} done now, {counts['skipped']} up to date (skipped), "
            f"{counts['failed']} failed",
        ),
        ("tasks", ", ".join(options.tasks)),
        ("vehicle", options.vehicle or "detected per bag"),
        ("engine", str(facts.get("engine"))),
        ("tool version", code_version()),
        ("wall time", f"{float(facts.get('wall_s', 0)):.1f} s"),
    ]
    if ran:
        items.append(
            (
                "done now",
                f"{rec_s / 3600:.3f} h of recordings in {cpu_s:.1f} CPU s "
                f"({rec_s / cpu_s if cpu_s else float('nan'):.1f}× real time per core)",
            )
        )
    return items


def _per_vehicle(rows: Sequence[Mapping[str, Any]]) -> list[list[str]]:
    by: dict[str, dict[str, float]] = {}
    for r in rows:
        v = str(r["vehicle"] or "(unknown)")
        d = by.setdefault(v, {"bags": 0, "failed": 0, "h": 0.0, "est": 0, "rej": 0, "cpu": 0.0})
        d["bags"] += 1
        d["failed"] += r["status"] == "failed"
        d["h"] += float(r["duration_s"] or 0) / 3600
        d["est"] += int(r["estimates"] or 0)
        d["rej"] += int(r["rejected"] or 0)
        d["cpu"] += float(r["cpu_s"] or 0)
    return [
        [
            v,
            str(int(d["bags"])),
            str(int(d["failed"])),
            f"{d['h']:.3f}",
            str(int(d["est"])),
            str(int(d["rej"])),
            f"{d['cpu']:.1f}",
        ]
        for v, d in sorted(by.items())
    ]


def _bag_cells(r: Mapping[str, Any]) -> list[str]:
    result = r["verdict"] or r["final_estimate"] or ""
    if r["verdict"] and r["final_estimate"]:
        result = f"{r['final_estimate']} — {r['verdict']}"
    return [
        str(r["bag"]),
        str(r["status"]),
        str(r["vehicle"] or ""),
        _fmt(r["duration_s"], 1),
        _fmt(r["estimates"]),
        _fmt(r["rejected"]),
        str(result)[:240],
        _fmt(r["cpu_s"], 2),
        str(r["reason"] or "")[:300] if r["status"] != "done" else "",
    ]


BAG_HEAD = [
    "bag",
    "status",
    "vehicle",
    "duration (s)",
    "estimates",
    "rejected",
    "final estimate / verdict",
    "CPU (s)",
    "reason",
]
VEHICLE_HEAD = ["vehicle", "bags", "failed", "hours", "estimates", "rejected", "CPU (s)"]


def _md_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    def esc(s: str) -> str:
        return s.replace("|", "\\|").replace("\n", " ")

    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + [
        "| " + " | ".join(esc(c) for c in row) + " |" for row in rows
    ]


def _markdown(rows: Sequence[Mapping[str, Any]], facts: Mapping[str, Any], options: BatchOptions) -> str:
    lines = [f"# {TOOL} summary", "", f"Written {time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}.", ""]
    lines += [f"- **{k}**: {v}" for k, v in _overview(rows, facts, options)]
    lines += ["", "## Per vehicle", ""] + _md_table(VEHICLE_HEAD, _per_vehicle(rows))
    failed = [r for r in rows if r["status"] == "failed"]
    if failed:
        lines += ["", "## Failures", ""] + [f"- `{r['bag']}`: {r['reason']}" for r in failed]
    lines += ["", "## Per bag", ""] + _md_table(BAG_HEAD, [_bag_cells(r) for r in rows])
    rejected = [r for r in rows if r["rejected"]]
    if rejected:
        lines += ["", "## Rejections by reason", ""] + [f"- `{r['bag']}`: {_rejections_text(r, 6)}" for r in rejected]
    lines += ["", "Every column, per bag: `summary.csv`. Each bag's outputs: `bags/<bag>/`."]
    return "\n".join(lines) + "\n"


def _html(rows: Sequence[Mapping[str, Any]], facts: Mapping[str, Any], options: BatchOptions) -> str:
    def table(head: Sequence[str], body: Sequence[Sequence[str]]) -> str:
        th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
        trs = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in body)
        return f"<table><thead><tr>{th}</tr></thead><tbody>{trs}</tbody></table>"

    items = "".join(f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>" for k, v in _overview(rows, facts, options))
    style = (
        "body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:2px 6px;font-size:90%}tr.failed td{background:#fdd}"
    )
    return (
        f"<!doctype html><html><head><meta charset='utf-8'><title>{TOOL} summary</title><style>{style}</style>"
        f"</head><body><h1>{TOOL} summary</h1><ul>{items}</ul><h2>Per vehicle</h2>"
        + table(VEHICLE_HEAD, _per_vehicle(rows))
        + "<h2>Per bag</h2>"
        + table(BAG_HEAD, [_bag_cells(r) for r in rows])
        + "</body></html>\n"
    )


def main(argv: Sequence[str] | None = None) -> int:
    from terrain_estimation.vehicles import VEHICLES

    parser = argparse.ArgumentParser(
        prog=TOOL,
        description="Estimate and/or diagnose every bag of a directory tree or list on a Dask cluster; one summary.",
        epilog="Exit status: 0 every bag done or up to date, 1 some bags failed (the others done), "
        "2 nothing produced or bad input, 3 internal error.",
    )
    parser.add_argument("paths", nargs="*", help="bag directories, storage files, or directories to search for bags")
    parser.add_argument("--from-file", metavar="LIST", help="read more paths from LIST, one per line (# comments)")
    parser.add_argument("-o", "--output", required=True, help="output directory (summary and one directory per bag)")
    parser.add_argument(
        "--tasks",
        choices=["estimate", "diagnose", "both"],
        default="estimate",
        help="estimate (terrain-estimate), diagnose (terrain-sim2real) or both (default: estimate)",
    )
    parser.add_argument("--vehicle", choices=sorted(VEHICLES), help="vehicle of every bag (default: detected per bag)")
    parser.add_argument("--namespace", help="namespace of every bag (default: detected, else the vehicle's)")
    parser.add_argument("--config", help="parameter file (default: config/<vehicle>.yaml)")
    parser.add_argument(
        "--param", action="append", default=[], metavar="NAME=VALUE", help="override an estimator parameter"
    )
    parser.add_argument("--figures", action="store_true", help="write the diagnosis figures (PNG; slower)")
    parser.add_argument(
        "--scheduler", metavar="ADDRESS", help="run on this Dask scheduler (tcp://host:8786 or a scheduler file .json)"
    )
    parser.add_argument("--workers", type=int, help="local cluster: worker processes, 1-1024 (default: one per core)")
    parser.add_argument(
        "--memory-limit", default="auto", help="local cluster: memory per worker, e.g. 2GiB (default: auto)"
    )
    parser.add_argument("--force", action="store_true", help="redo every bag, even those up to date")
    parser.add_argument(
        "--code-key",
        choices=["version", "sources"],
        default="version",
        help="what a result must match besides its bag and options: the package version (default) or its "
        "sources too (any edit of the code redoes every bag)",
    )
    parser.add_argument(
        "--retry-failed", action="store_true", help="try again the bags that failed last time though unchanged"
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="write into an existing output directory not made by a project tool"
    )
    args = parser.parse_args(argv)

    def body() -> int:
        from terrain_estimation.params import parse_override

        paths = list(args.paths)
        if args.from_file:
            text = Path(args.from_file).read_text(encoding="utf-8")
            paths += [s for line in text.splitlines() if (s := line.split("#", 1)[0].strip())]
        if not paths:
            raise InputError("no input: give bag paths or directories, or --from-file LIST")
        if args.scheduler and args.workers is not None:
            raise InputError("--workers applies to the local cluster only; a running cluster (--scheduler) has its own")
        tasks = TASKS if args.tasks == "both" else (args.tasks,)
        options = BatchOptions(
            tasks=tasks,
            vehicle=args.vehicle,
            namespace=args.namespace,
            config=args.config,
            params=tuple(parse_override(p) for p in args.param),
            figures=args.figures,
        )
        from terrain_analysis.batch.engine import EngineError

        try:
            rows, facts = run_batch(
                paths,
                Path(args.output),
                options,
                scheduler=args.scheduler,
                workers=args.workers,
                memory_limit=args.memory_limit,
                force=args.force,
                retry_failed=args.retry_failed,
                code_key=args.code_key,
                overwrite=args.overwrite,
            )
        except EngineError as exc:  # an unreachable --scheduler, a bad --workers: the input, not a bug
            raise InputError(str(exc)) from exc
        counts = _counts(rows)
        remembered = sum(1 for r in rows if r["status"] == "failed" and str(r["reason"]).startswith("unchanged since"))
        print(
            f"{len(rows)} bags: {counts['done']} done, {counts['skipped']} up to date (skipped), "
            f"{counts['failed']} failed ({remembered} of them unchanged since an earlier failure, not retried) "
            f"in {facts['wall_s']:.1f} s; summary: {Path(args.output) / 'summary.md'} (table: summary.csv)"
        )
        for r in rows:
            if r["status"] == "failed":
                print(f"  failed {r['bag']}: {r['reason']}")
        if counts["done"] + counts["skipped"] == 0:
            print(f"{TOOL}: error: no bag produced a result", file=sys.stderr)
            return EXIT_INPUT
        return EXIT_FINDING if counts["failed"] else EXIT_OK

    return run_cli(TOOL, body, interrupted="interrupted; bags finished so far keep their outputs")


if __name__ == "__main__":
    sys.exit(main())
