"""The quarter-car Monte Carlo section of the benchmark (``python -m terrain_analysis.tools.bench --only
qc_monte_carlo``).

Item 7 of :mod:`terrain_analysis.tools.bench` (issue 23: "the 100-run Monte Carlo with every filter in 60 s or
less on 2 cores"): case 1 of ``make reproduce-qc`` on a pool of 2 worker processes, twice in one run, the EKF
through its public numpy ``predict``/``update`` (before) and compiled (after); wall and CPU time, and the
largest difference between the two runs' k_s errors.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from terrain_analysis.tools.bench_common import BenchConfig

__all__ = ["QC_MC_JOBS", "QC_MC_PATHS", "bench_qc_monte_carlo", "format_qc_monte_carlo"]

#: The two runs of the Monte Carlo section: (label, the filters that run compiled).
QC_MC_PATHS: tuple[tuple[str, tuple[str, ...]], ...] = (("before", ("sckf",)), ("after", ("sckf", "ekf")))
QC_MC_JOBS = 2


def _qc_mc_run(plan: Sequence[Any], compiled: tuple[str, ...], jobs: int) -> tuple[float, float, list[Any]]:
    """(wall s, CPU s of the workers, results in plan order) of the rides of ``plan`` on ``jobs`` processes."""
    import multiprocessing
    import resource

    from terrain_analysis.tools.reproduce_qc import run_one
    from terrain_estimation.estimators.soil_stiffness import set_compiled_steps

    order = sorted(range(len(plan)), key=lambda k: -plan[k].cost)  # longest first, as reproduce_qc does
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    results: dict[int, Any] = {}
    with multiprocessing.get_context().Pool(jobs, initializer=set_compiled_steps, initargs=(compiled,)) as pool:
        for k, out in zip(order, pool.imap(run_one, [plan[k] for k in order], chunksize=1), strict=True):
            results[k] = out
        pool.close()
        pool.join()  # the workers are reaped: their CPU time is in RUSAGE_CHILDREN
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, [results[k] for k in range(len(plan))]


def bench_qc_monte_carlo(cfg: BenchConfig) -> dict[str, Any]:
    """The quarter-car Monte Carlo section (module docstring, item 7)."""
    from terrain_analysis.tools.reproduce_qc import Counts, build_plan
    from terrain_estimation.estimators.soil_stiffness_ekf import warm_up_ekf
    from terrain_estimation.estimators.soil_stiffness_sckf import warm_up

    # Both steps compiled (or loaded from numba's cache) here, before the workers fork: no run times the compiler.
    warm_up()
    warm_up_ekf()
    counts = Counts() if cfg.drive_s >= 10.0 else dataclasses.replace(Counts(), case1=4, case1_duration=4.0)
    plan = [spec for spec in build_plan(counts) if spec.key == "case1"]
    rows: list[dict[str, Any]] = []
    traces: dict[str, list[Any]] = {}
    for label, compiled in QC_MC_PATHS:
        wall, cpu, results = _qc_mc_run(plan, compiled, QC_MC_JOBS)
        traces[label] = [tr for _, tr in results]
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
        rows.append({"path": label, "compiled": list(compiled), "wall_s": wall, "cpu_s": cpu, "load_avg_1min": load})
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
        "variants": variants,
        "paths": rows,
        "max_abs_err_diff_pct": diff,
    }


def format_qc_monte_carlo(figures: dict[str, Any]) -> str:
    """The quarter-car Monte Carlo section of the readable table."""
    lines = [
        f"Quarter-car Monte Carlo: case 1 of reproduce-qc, {figures['runs']} runs of {figures['ride_s']:g} s "
        f"(simulate + {len(figures['variants'])} filters: {', '.join(figures['variants'])}) on "
        f"{figures['jobs']} worker processes",
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
        "before = the EKF through its public numpy predict/update (the previous path); CPU = the workers' user + "
        "system time; wall time on a machine whose load average exceeds its 2 cores measures the other processes too"
    )
    worst = ", ".join(f"{k} {v:.2g}" for k, v in figures["max_abs_err_diff_pct"].items())
    lines.append(f"  largest |k_s error before − after| over every estimate (percentage points): {worst}")
    return "\n".join(lines)
