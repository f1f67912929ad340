"""``python -m terrain_analysis.tools.batch_bench``: terrain-batch's throughput with 1 and 2 workers.

Issue 23's scaling row and its projection to a 100-worker cluster. The
benchmark:

1. simulates ``--per-vehicle`` bags of ``--duration`` s for each of the four
   vehicles into ``--bags`` (once; on the engine itself, with varied seeds),
   and adds one corrupt copy (a truncated MCAP file) that must be reported;
2. runs ``terrain-batch`` (:func:`terrain_analysis.tools.batch.run_batch`,
   estimation) over them on a local cluster of 1 worker, then of 2 workers,
   each into a fresh output directory, and prints the throughput: bags and
   recording hours per hour, per worker, the speed-up 1 → 2, the cluster
   start-up and the warm-up (estimators loaded in every worker);
3. runs the 2-worker batch a second time, which must skip everything, and
   times it;
4. measures the scheduler's overhead per task: no-op tasks through the same
   :class:`~terrain_analysis.batch.engine.Engine` path (``run_isolated``,
   ``as_completed``), in bulk and one at a time, and what stays serial in the
   client per bag (finding bags, the up-to-date check, the summary);
5. writes the figures and a projection to 100 workers into
   ``docs/results/performance.md`` (section ``batch_scaling``).

The machine is shared: the load average before and after is printed and
written; figures taken under load say so.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = ["main"]

SECTION = "batch_scaling"
VEHICLES = ("quarter_car", "lrv", "skid_steer", "rover")


def _simulate(vehicle: str, duration: float, seed: int, out: str) -> str:
    """One simulated bag (runs in a worker)."""
    from vehicle_sim.tools.simulate import main as simulate

    status = simulate(["--vehicle", vehicle, "--duration", f"{duration:g}", "-o", out, "--param", f"seed={seed}"])
    if status != 0:
        raise RuntimeError(f"terrain-simulate --vehicle {vehicle} exited {status}")
    return out


def _noop(i: int) -> int:
    return i


def make_bags(root: Path, per_vehicle: int, duration: float, workers: int) -> list[Path]:
    """Simulate the benchmark's bags into ``root`` (kept if already there) plus one corrupt bag."""
    from terrain_analysis.batch.engine import Engine, Progress

    todo = []
    for vehicle in VEHICLES:
        for i in range(per_vehicle):
            path = root / vehicle / f"{vehicle}_{i:02d}"
            if not (path / "metadata.yaml").is_file():
                todo.append((vehicle, duration, 1000 + 17 * i + VEHICLES.index(vehicle), str(path)))
    if todo:
        print(f"simulating {len(todo)} bags of {duration:g} s into {root} ...", file=sys.stderr)
        with Engine(workers=workers) as engine:
            for r in engine.map(_simulate, todo, progress=Progress(len(todo), "simulated bags")):
                if not r.ok:
                    raise RuntimeError(f"simulation failed: {r.error}")
    corrupt = root / "corrupt" / "truncated"
    if not corrupt.exists():
        source = root / "quarter_car" / "quarter_car_00"
        corrupt.mkdir(parents=True)
        shutil.copy(source / "metadata.yaml", corrupt / "metadata.yaml")
        mcap = next(source.glob("*.mcap"))
        data = mcap.read_bytes()
        (corrupt / mcap.name).write_bytes(data[: len(data) // 2])
    return sorted(p.parent for p in root.rglob("metadata.yaml"))


def _autogroup() -> bool:
    """True when the kernel shares the CPU between sessions first (then between the processes of each)."""
    try:
        return Path("/proc/sys/kernel/sched_autogroup_enabled").read_text().strip() == "1"
    except OSError:
        return False


def _load() -> float:
    return os.getloadavg()[0]


def _overhead(workers: int, n: int) -> dict[str, float]:
    """Per-task overhead of the engine: ``n`` no-ops in bulk, and 30 one at a time."""
    from terrain_analysis.batch.engine import Engine, Task

    with Engine(workers=workers) as engine:
        engine.map(_noop, [(i,) for i in range(2 * workers)])  # workers up
        t = time.perf_counter()
        results = list(engine.run([Task(f"noop-{i}", _noop, (i,)) for i in range(n)]))
        bulk = (time.perf_counter() - t) / n
        assert all(r.ok for r in results)
        t = time.perf_counter()
        for i in range(30):
            list(engine.run([Task(f"one-{i}", _noop, (i,))]))
        single = (time.perf_counter() - t) / 30
    return {"bulk_ms": bulk * 1e3, "roundtrip_ms": single * 1e3}


def _serial_per_bag(bags: Sequence[Path], out: Path) -> dict[str, float]:
    """Client-side work per bag that no worker takes over: finding it, the up-to-date check, the summary row."""
    from terrain_analysis.batch.bags import BagJob, BatchOptions, find_bags, tool_version, up_to_date
    from terrain_analysis.tools.batch import write_summary

    roots = sorted({str(b.parent.parent) for b in bags})
    t = time.perf_counter()
    found, _ = find_bags(roots)
    find_s = time.perf_counter() - t
    options = BatchOptions()
    version = {"tool": tool_version()}
    jobs = [BagJob(str(b), rel, str(out / "bags" / rel), options, version) for b, rel in found]
    t = time.perf_counter()
    rows = [up_to_date(j) or {} for j in jobs]
    check_s = time.perf_counter() - t
    scratch = Path(tempfile.mkdtemp(prefix="batch-bench-summary-"))
    t = time.perf_counter()
    write_summary(scratch, [dict(r, bag=j.rel) for r, j in zip(rows, jobs, strict=True)], {}, options)
    summary_s = time.perf_counter() - t
    shutil.rmtree(scratch)
    n = max(len(jobs), 1)
    return {"find_ms": find_s / n * 1e3, "check_ms": check_s / n * 1e3, "summary_ms": summary_s / n * 1e3}


def _batch_pass(bags: str, out: Path, workers: int) -> dict[str, Any]:
    """One timed terrain-batch run (estimation) over ``bags`` into a fresh ``out``."""
    from terrain_analysis.batch.bags import BatchOptions
    from terrain_analysis.tools.batch import run_batch

    if out.exists():  # a previous pass of this benchmark, inside its own scratch root
        shutil.rmtree(out)
    t = time.perf_counter()
    rows, facts = run_batch([bags], out, BatchOptions(), workers=workers, log=lambda _text: None)
    total = time.perf_counter() - t
    done = [r for r in rows if r["status"] == "done"]
    return {
        "rows": rows,
        "done": len(done),
        "failed": [r for r in rows if r["status"] == "failed"],
        "total_s": total,
        "tasks_wall_s": facts["tasks_wall_s"],
        "warm_up_s": facts["warm_up_s"],
        "startup_s": total - facts["tasks_wall_s"] - facts["warm_up_s"],
        "cpu_s": sum(float(r["cpu_s"] or 0) for r in done),
        "rec_s": sum(float(r["duration_s"] or 0) for r in done),
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="batch_bench", description=__doc__.splitlines()[0])
    parser.add_argument("--bags", default="/tmp/batch_bench_bags", help="where the simulated bags are (made if absent)")
    parser.add_argument("--per-vehicle", type=int, default=5, help="bags per vehicle, 1-50 (default 5: 20 bags)")
    parser.add_argument("--duration", type=float, default=30.0, help="seconds per bag, 2-600 (default 30)")
    parser.add_argument("--out", default="/tmp/batch_bench_out", help="scratch output root (replaced each run)")
    parser.add_argument("--overhead-tasks", type=int, default=500, help="no-op tasks for the overhead, 50-20000")
    parser.add_argument("--page", default="docs/results/performance.md", help="results page")
    parser.add_argument("--no-page", action="store_true", help="print only")
    parser.add_argument("--repeat", type=int, default=2, help="passes of each worker count, best kept, 1-5")
    args = parser.parse_args(argv)
    if not 1 <= args.repeat <= 5:
        parser.error("--repeat must be in [1, 5]")
    if not 1 <= args.per_vehicle <= 50 or not 2 <= args.duration <= 600 or not 50 <= args.overhead_tasks <= 20000:
        parser.error("--per-vehicle in [1, 50], --duration in [2, 600] s, --overhead-tasks in [50, 20000]")

    from terrain_analysis.batch.bags import BatchOptions
    from terrain_analysis.tools.batch import run_batch

    load0 = _load()
    bags = make_bags(Path(args.bags), args.per_vehicle, args.duration, os.cpu_count() or 1)
    out_root = Path(args.out)
    if out_root.exists():
        marker = out_root / ".batch-bench"
        if not marker.is_file():
            parser.error(f"{out_root} exists and was not made by this benchmark; choose another --out")
        shutil.rmtree(out_root)
    out_root.mkdir(parents=True)
    (out_root / ".batch-bench").write_text("scratch of terrain_analysis.tools.batch_bench\n")
    runs: dict[int, Any] = {}
    loads = [load0]
    for rep in range(args.repeat):  # alternated, the best pass of each kept: the least disturbed by others' jobs
        for workers in (1, 2):
            loads.append(_load())
            result = _batch_pass(args.bags, out_root / f"w{workers}", workers)
            best = runs.get(workers)
            kept = best is None or result["tasks_wall_s"] < best["tasks_wall_s"]
            if kept:
                runs[workers] = result
            print(
                f"{workers} worker(s), pass {rep + 1}: {result['done']} bags done, {len(result['failed'])} failed "
                f"in {result['tasks_wall_s']:.1f} s of tasks (+{result['warm_up_s']:.1f} s warm-up, "
                f"{result['total_s']:.1f} s in all); CPU {result['cpu_s']:.1f} s for {result['rec_s']:.0f} s of "
                f"recordings{'' if kept else ' (not the best pass)'}",
                flush=True,
            )
    t = time.perf_counter()
    rows2, facts2 = run_batch([args.bags], out_root / "w2", BatchOptions(), workers=2, log=lambda _text: None)
    second_s = time.perf_counter() - t
    skipped = sum(1 for r in rows2 if r["status"] == "skipped")
    print(f"second 2-worker run: {skipped} of {len(rows2)} bags skipped, {facts2['todo']} redone, in {second_s:.2f} s")
    loads.append(_load())
    overhead = _overhead(2, args.overhead_tasks)
    serial = _serial_per_bag(bags, out_root / "w2")
    loads.append(_load())
    r1, r2 = runs[1], runs[2]
    bags_h = {w: runs[w]["done"] / runs[w]["tasks_wall_s"] * 3600 for w in (1, 2)}
    speedup = r1["tasks_wall_s"] / r2["tasks_wall_s"]
    speedup_all = r1["total_s"] / r2["total_s"]
    per_bag_cpu = r2["cpu_s"] / max(r2["done"], 1)
    rt_per_core = r2["rec_s"] / r2["cpu_s"] if r2["cpu_s"] else float("nan")
    print(
        f"throughput: 1 worker {bags_h[1]:.0f} bags/h, 2 workers {bags_h[2]:.0f} bags/h (×{speedup:.2f}; "
        f"×{speedup_all:.2f} counting start-up); {bags_h[2] / 2:.0f} bags/h per worker"
    )
    print(
        f"scheduler overhead per task: {overhead['bulk_ms']:.2f} ms in bulk, "
        f"{overhead['roundtrip_ms']:.1f} ms one at a time"
    )
    print(
        f"serial in the client per bag: find {serial['find_ms']:.2f} ms, up-to-date check {serial['check_ms']:.2f} ms, "
        f"summary {serial['summary_ms']:.2f} ms"
    )
    print(f"load average (1 min) before/during/after: {', '.join(f'{x:.2f}' for x in loads)}")
    failed_names = [str(f["bag"]) for f in r2["failed"]]
    reasons = "; ".join(f"`{f['bag']}`: {str(f['reason']).rstrip('.')}" for f in r2["failed"])
    loaded = max(loads) > 0.7
    n_bags = r2["done"] + len(r2["failed"])
    # the projection: 100 workers, the same bags, and a fleet of 10 000 ten-minute bags
    proj_workers = 100
    fleet_bags, fleet_len = 10_000, 600.0
    fleet_cpu = fleet_bags * fleet_len / rt_per_core
    serial_per_bag_s = (serial["find_ms"] + serial["check_ms"] + serial["summary_ms"]) / 1e3
    sched_s = fleet_bags * overhead["bulk_ms"] / 1e3
    ideal = fleet_cpu / proj_workers
    fleet_wall = ideal + sched_s + fleet_bags * serial_per_bag_s + r2["startup_s"] + r2["warm_up_s"]
    cmd = "python -m terrain_analysis.tools.batch_bench" + ("" if argv is None else " " + " ".join(argv))
    text = "\n".join(
        [
            "## Batch scaling: terrain-batch with 1 and 2 workers, and a projection to 100 (issue 23)",
            "",
            f"Command: `{cmd}` ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {os.cpu_count()} cores; "
            f"1-min load average before/during/after {', '.join(f'{x:.2f}' for x in loads)}"
            + (
                "; **other engineers' jobs were running on the same 2 cores: figures taken under load**"
                if loaded
                else ""
            )
            + ").",
            "",
            f"Best of {args.repeat} alternated passes per worker count (the least disturbed by other jobs). "
            f"Input: {n_bags} bags: {args.per_vehicle} simulated bags of {args.duration:g} s for each of "
            f"{', '.join(VEHICLES)} (`python -m vehicle_sim.tools.simulate`, varied seeds) and one corrupt bag "
            "(a copy cut to half its MCAP file). Estimation only (`terrain-batch --tasks estimate`), a fresh "
            "output directory per run, a local Dask cluster.",
            "",
            "| | 1 worker | 2 workers |",
            "|---|---|---|",
            f"| bags done / failed | {r1['done']} / {len(r1['failed'])} | {r2['done']} / {len(r2['failed'])} |",
            f"| wall time of the tasks | {r1['tasks_wall_s']:.1f} s | {r2['tasks_wall_s']:.1f} s |",
            f"| cluster start-up + worker warm-up (estimators loaded) | "
            f"{r1['startup_s']:.1f} + {r1['warm_up_s']:.1f} s | "
            f"{r2['startup_s']:.1f} + {r2['warm_up_s']:.1f} s |",
            f"| whole command | {r1['total_s']:.1f} s | {r2['total_s']:.1f} s |",
            f"| CPU time of the bags | {r1['cpu_s']:.1f} s | {r2['cpu_s']:.1f} s |",
            f"| throughput (tasks) | {bags_h[1]:.0f} bags/h | {bags_h[2]:.0f} bags/h |",
            f"| bags per hour per worker | {bags_h[1]:.0f} | {bags_h[2] / 2:.0f} |",
            f"| bags per hour per worker with a core of its own (3600 s / CPU s per bag) | "
            f"{3600 * r1['done'] / r1['cpu_s']:.0f} | {3600 * r2['done'] / r2['cpu_s']:.0f} |",
            f"| recording hours per hour per worker | {r1['rec_s'] / r1['tasks_wall_s']:.1f} | "
            f"{r2['rec_s'] / r2['tasks_wall_s'] / 2:.1f} |",
            "",
            "The wall-time rows depend on what else runs on the machine; the CPU-time row does not (much): it "
            "is what a worker with a core to itself would do."
            + (
                " This kernel groups the processes of a session for CPU sharing (`sched_autogroup_enabled` = 1): "
                "while other sessions keep the cores busy, this benchmark's session gets its group's share "
                "whether it runs 1 worker or 2, so the speed-up below measures the machine's load as much as "
                "the batch."
                if _autogroup() and loaded
                else ""
            ),
            f"Speed-up from 1 to 2 workers: **×{speedup:.2f}** on the tasks' wall time (×{speedup_all:.2f} for the "
            f"whole command, start-up included); the issue asks ≥ ×1.7"
            + (" — met." if speedup >= 1.7 else " — **not met in this run**" + (" (under load)." if loaded else ".")),
            f"Corrupt bag: {reasons or 'none reported (unexpected)'}"
            + ("; every other bag done." if r2["done"] == n_bags - len(failed_names) else "."),
            f"Second 2-worker run over the same bags: {skipped} of {len(rows2)} skipped as up to date, "
            f"{facts2['todo']} redone (the corrupt bag, unchanged, is reported failed again without being "
            f"retried), {second_s:.2f} s.",
            "",
            "Per-task overhead, measured (2 workers, no-op tasks through the same engine path: `run_isolated` in "
            f"the worker, `as_completed` in the client): **{overhead['bulk_ms']:.2f} ms per task** with "
            f"{args.overhead_tasks} tasks submitted at once (the scheduler's throughput limit, about "
            f"{1e3 / overhead['bulk_ms']:.0f} tasks/s), {overhead['roundtrip_ms']:.1f} ms for one task alone "
            "(latency). Serial in the client, per bag: finding it "
            f"{serial['find_ms']:.2f} ms, the up-to-date check {serial['check_ms']:.2f} ms, its summary row "
            f"{serial['summary_ms']:.2f} ms.",
            "",
            "### Projection to a 100-worker cluster",
            "",
            f"What parallelises: the bags, each one task ({per_bag_cpu:.2f} CPU s for a {args.duration:g} s bag here, "
            f"{rt_per_core:.0f}× real time per core, reading and writing included). "
            "What stays serial: the client's walk of the tree, the "
            "up-to-date check of every bag and the summary (the figures above, per bag), the scheduler, "
            "which places every task one after another (the bulk overhead above), and the cluster's start-up "
            "and each worker's warm-up (once per worker, in parallel). A single bag is never split: a batch "
            "cannot finish before its longest bag.",
            "",
            f"For a fleet of {fleet_bags:,} bags of {fleet_len / 60:.0f} min "
            f"({fleet_bags * fleet_len / 3600:,.0f} h of "
            f"recordings) at the {rt_per_core:.0f}× real time per core measured here: {fleet_cpu / 3600:.1f} CPU h; on "
            f"{proj_workers} workers {ideal / 60:.1f} min if perfectly parallel, plus at most "
            f"{sched_s:.0f} s of scheduler time ({overhead['bulk_ms']:.2f} ms × {fleet_bags:,}; an upper bound: "
            "the scheduler places the next tasks while the workers run theirs), "
            f"{fleet_bags * serial_per_bag_s:.0f} s of client work and about "
            f"{r2['startup_s'] + r2['warm_up_s']:.0f} s of start-up: about {fleet_wall / 60:.1f} min "
            f"({ideal / fleet_wall * 100:.0f} % parallel efficiency, at worst). The scheduler overhead is "
            f"{overhead['bulk_ms'] / 1e3 / (fleet_len / rt_per_core) * 100:.3f} % of a 10-min bag's task, so it "
            f"stays negligible until tasks are near {overhead['bulk_ms'] * proj_workers:.0f} ms each "
            f"({proj_workers} workers × {overhead['bulk_ms']:.2f} ms: the scheduler could then no longer keep "
            "them busy). Not measured: reading the bags over a network filesystem, which on a cluster may "
            "well cost more than the estimation itself; the bags must be on storage every worker sees at "
            "the same path.",
        ]
    )
    print()
    print(text)
    if not args.no_page:
        from terrain_analysis.reporting import write_section
        from terrain_analysis.tools.batch_engine_choice import PAGE_TITLE

        write_section(args.page, SECTION, text, title=PAGE_TITLE, note=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
