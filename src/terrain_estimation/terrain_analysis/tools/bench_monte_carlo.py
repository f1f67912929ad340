"""The quarter-car Monte Carlo section of the benchmark (``python -m terrain_analysis.tools.bench --only
qc_monte_carlo``).

Item 7 of :mod:`terrain_analysis.tools.bench` (issue 23: "the 100-run Monte Carlo with every filter in 60 s or
less on 2 cores"): case 1 of ``make reproduce-qc`` on the project's engine (a local Dask cluster of 2 worker
processes, :class:`terrain_analysis.experiment.Runner`, as ``reproduce-qc --jobs 2`` runs it), twice in one run,
the EKF through its public numpy ``predict``/``update`` (before) and compiled (after); wall and CPU time, and the
largest difference between the two runs' k_s errors.

Each row times the rides only, as the pool it replaced did: the cluster is started, and every worker has
imported the ride and compiled (or loaded from numba's cache) both filter steps, before the clock starts. That
start-up (cluster start, worker warm-up) is new with the engine and printed on its own line; the CPU column is
the workers' CPU time in the rides (``time.process_time`` of each task), the scheduler's and client's CPU
during the rides on its own line. The workers are forked from a forkserver that imported the ride and loaded
both compiled steps once (:data:`WORKER_PRELOAD`, :func:`terrain_analysis.batch.engine.preload_workers`), so
the start-up pays those imports and numba's cache loads (or its compilation, after a kernel changed) once, not
once per worker; this process imports the ride (for the plan) meanwhile, inside the start-up. The issue's
figure, the Monte Carlo with every filter compiled including the engine's start-up, is printed as start-up +
the "after" row.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import os
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from terrain_analysis.tools.bench_common import BenchConfig

__all__ = ["QC_MC_JOBS", "QC_MC_PATHS", "WORKER_PRELOAD", "bench_qc_monte_carlo", "format_qc_monte_carlo"]

#: The two runs of the Monte Carlo section: (label, the filters that run compiled).
QC_MC_PATHS: tuple[tuple[str, tuple[str, ...]], ...] = (("before", ("sckf",)), ("after", ("sckf", "ekf")))
QC_MC_JOBS = 2
#: What the workers' forkserver imports and warms before it forks them: the ride, both compiled filter steps.
WORKER_PRELOAD: tuple[str, ...] = (
    "terrain_analysis.tools.qc_runs",
    "terrain_estimation.estimators.soil_stiffness_sckf:warm_up",
    "terrain_estimation.estimators.soil_stiffness_ekf:warm_up_ekf",
)


def _prepare_worker(compiled: tuple[str, ...]) -> None:
    """A worker's set-up: the ride's modules imported, both filter steps compiled, ``compiled`` chosen."""
    import terrain_analysis.tools.qc_runs  # noqa: F401  (the ride's imports, out of the timed rides)
    from terrain_estimation.estimators.soil_stiffness import set_compiled_steps
    from terrain_estimation.estimators.soil_stiffness_ekf import warm_up_ekf
    from terrain_estimation.estimators.soil_stiffness_sckf import warm_up

    warm_up()
    warm_up_ekf()
    set_compiled_steps(compiled)


def _qc_mc_run(runner: Any, plan: Sequence[Any], compiled: tuple[str, ...]) -> tuple[float, float, float, list[Any]]:
    """(wall s, CPU s of the workers' rides, CPU s of this process, results in plan order) of the rides of
    ``plan`` on ``runner``'s workers, with ``compiled`` steps."""
    from terrain_analysis.tools.qc_runs import run_one

    runner.setup_workers(_prepare_worker, compiled)
    worker0, cpu0, t0 = runner.worker_cpu_s, time.process_time(), time.perf_counter()
    results = runner.map(run_one, plan, weight=lambda spec: spec.cost)  # longest first, as reproduce_qc does
    wall = time.perf_counter() - t0
    return wall, runner.worker_cpu_s - worker0, time.process_time() - cpu0, results


def bench_qc_monte_carlo(cfg: BenchConfig) -> dict[str, Any]:
    """The quarter-car Monte Carlo section (module docstring, item 7)."""
    from terrain_analysis.batch.engine import preload_workers
    from terrain_analysis.experiment import Runner

    rows: list[dict[str, Any]] = []
    traces: dict[str, list[Any]] = {}
    preload_workers(*WORKER_PRELOAD)
    t0, cpu0 = time.perf_counter(), time.process_time()
    # This process's own imports of the ride (for the plan) on a thread, while the cluster starts: the
    # forkserver imports the same on the other core meanwhile.
    importer = threading.Thread(target=importlib.import_module, args=(WORKER_PRELOAD[0],), daemon=True)
    importer.start()
    with Runner(QC_MC_JOBS, what="rides", progress=False) as runner:
        cluster_s = time.perf_counter() - t0
        importer.join()
        from terrain_analysis.tools.qc_runs import Counts, build_plan

        counts = Counts() if cfg.drive_s >= 10.0 else dataclasses.replace(Counts(), case1=4, case1_duration=4.0)
        plan = [spec for spec in build_plan(counts) if spec.key == "case1"]
        runner.setup_workers(_prepare_worker, QC_MC_PATHS[0][1])  # imports and compilation: start-up, not rides
        warm_s = time.perf_counter() - t0 - cluster_s
        client_start_cpu = time.process_time() - cpu0
        for label, compiled in QC_MC_PATHS:
            wall, cpu, client_cpu, results = _qc_mc_run(runner, plan, compiled)
            traces[label] = [tr for _, tr in results]
            load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
            rows.append(
                {
                    "path": label,
                    "compiled": list(compiled),
                    "wall_s": wall,
                    "cpu_s": cpu,
                    "client_cpu_s": client_cpu,
                    "load_avg_1min": load,
                }
            )
    variants = [v.label for v in plan[0].variants]
    diff = {
        v: max(
            float(np.max(np.abs(a[v].err - b[v].err))) for a, b in zip(traces["before"], traces["after"], strict=True)
        )
        for v in variants
    }
    return {
        "runs": len(plan),
        "ride_s": counts.case1_duration,
        "jobs": QC_MC_JOBS,
        "engine": "Dask distributed, local cluster",
        "startup_s": {"cluster": cluster_s, "worker_warm_up": warm_s, "client_cpu": client_start_cpu},
        "worker_preload": list(WORKER_PRELOAD),
        "variants": variants,
        "paths": rows,
        "max_abs_err_diff_pct": diff,
    }


def format_qc_monte_carlo(figures: dict[str, Any]) -> str:
    """The quarter-car Monte Carlo section of the readable table."""
    lines = [
        f"Quarter-car Monte Carlo: case 1 of reproduce-qc, {figures['runs']} runs of {figures['ride_s']:g} s "
        f"(simulate + {len(figures['variants'])} filters: {', '.join(figures['variants'])}) on "
        f"{figures['jobs']} worker processes ({figures.get('engine', 'a multiprocessing pool')})",
        f"  {'path':<8}{'compiled steps':<18}{'wall s':>9}{'CPU s':>9}{'load avg':>10}",
    ]
    for r in figures["paths"]:
        lines.append(
            f"  {r['path']:<8}{'+'.join(r['compiled']):<18}{r['wall_s']:>9.1f}{r['cpu_s']:>9.1f}"
            f"{r['load_avg_1min']:>10.1f}"
        )
    old, new = figures["paths"][0], figures["paths"][1]
    lines.append(
        f"  speed-up {old['wall_s'] / new['wall_s']:.2f}× wall, {old['cpu_s'] / new['cpu_s']:.2f}× CPU; "
        "before = the EKF through its public numpy predict/update (the previous path); CPU = the workers' CPU time "
        "in the rides; wall time on a machine whose load average exceeds its 2 cores measures the other processes too"
    )
    if "startup_s" in figures:
        up = figures["startup_s"]
        client = "/".join(f"{r['client_cpu_s']:.1f}" for r in figures["paths"])
        start = up["cluster"] + up["worker_warm_up"]
        lines.append(
            f"  engine start-up, not in the rows: cluster {up['cluster']:.1f} s, workers' imports and filter "
            f"compilation {up['worker_warm_up']:.1f} s (wall); scheduler + client CPU during the rows {client} s"
        )
        if "client_cpu" in up:
            lines.append(
                f"  the workers are forked from one warm forkserver ({len(figures.get('worker_preload', []))} "
                f"preload entries: the ride's imports, both compiled steps); this process's CPU in the start-up "
                f"{up['client_cpu']:.1f} s"
            )
        lines.append(
            f"  {figures['runs']}-run Monte Carlo with every filter compiled, start-up included: "
            f"{start + new['wall_s']:.1f} s wall ({start:.1f} s start-up + {new['wall_s']:.1f} s rides; the "
            f"workers' CPU in the rides {new['cpu_s']:.1f} s, {new['cpu_s'] / figures['jobs']:.1f} s per worker)"
        )
    worst = ", ".join(f"{k} {v:.2g}" for k, v in figures["max_abs_err_diff_pct"].items())
    lines.append(f"  largest |k_s error before − after| over every estimate (percentage points): {worst}")
    return "\n".join(lines)
