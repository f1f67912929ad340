"""The start-up section of the benchmark (``python -m terrain_analysis.tools.bench --only startup``).

Issue 23's "start-up under 1 s to the first message with a warm cache": for every vehicle, a fresh
``python`` runs what ``terrain-estimate`` runs (the parameters from ``config/<vehicle>.yaml``, the adapter and
its estimator, the replay of the vehicle's shipped bag) and reports the CPU time of its process and the wall
time since it was started when the first estimate is kept. One untimed run first fills numba's and Python's
caches; the median of the repetitions is printed, with the load average (the wall time of a busy machine
measures the other processes too; the CPU time much less so).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.tools.bench_common import BAGS_DIR, BenchConfig

__all__ = ["STARTUP_BAGS", "bench_startup", "format_startup"]

#: (vehicle, shipped bag) of each row.
STARTUP_BAGS: tuple[tuple[str, str], ...] = (
    ("quarter_car", "quarter_car_graneville_iso_d_10ms"),
    ("lrv", "lrv_regolith_iso_g_2ms"),
    ("skid_steer", "skid_steer_s_shape"),
    ("rover", "rover_terrain_1"),
)

_CHILD = """
import os, sys, time
from terrain_estimation.tools import estimate as te
from terrain_estimation.tools import estimate_replay as replay
from terrain_estimation.vehicles import get_vehicle
keep = replay._keep
def first(run, *args):
    keep(run, *args)
    if run.outputs or run.streamed:
        print("FIRST", time.process_time(), flush=True)
        os._exit(0)
replay._keep = first
entry = get_vehicle(sys.argv[1])
values = te.config_values(entry)
adapter = entry.make_adapter(values, entry.namespace)
te.run_adapter(adapter, entry.namespace, sys.argv[2], values=values)
print("NONE", time.process_time(), flush=True)
"""


def _first_estimate(vehicle: str, bag: Path) -> tuple[float, float]:
    """(wall, CPU) seconds from a fresh ``python`` to the first estimate kept from ``bag`` (NaN: the bag gave none).

    The child exits as soon as it prints the first estimate's CPU time, so its run is the wall time.

    Raises:
        RuntimeError: the child failed (its exit status and the end of its stderr): a broken benchmark
            must not print NaN as if the estimator had produced nothing.
    """
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _CHILD, vehicle, str(bag)], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"start-up benchmark of {vehicle} on {bag}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
    found = [line.split() for line in proc.stdout.splitlines() if line.startswith("FIRST")]
    return (wall, float(found[0][1])) if found else (math.nan, math.nan)


def bench_startup(cfg: BenchConfig, bags_dir: Path = BAGS_DIR) -> dict[str, Any]:
    """The start-up section (module docstring)."""
    rows = []
    for vehicle, name in STARTUP_BAGS:
        bag = bags_dir / name
        _first_estimate(vehicle, bag)  # untimed: numba's cache, Python's bytecode
        samples = [_first_estimate(vehicle, bag) for _ in range(max(1, cfg.repeats))]
        rows.append(
            {
                "vehicle": vehicle,
                "bag": name,
                "wall_s": float(np.median([w for w, _ in samples])),
                "cpu_s": float(np.median([c for _, c in samples])),
                "cpu_s_min": float(min(c for _, c in samples)),
                "load_avg_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan,
            }
        )
    return {"rows": rows}


def format_startup(figures: dict[str, Any]) -> str:
    """The start-up section of the readable table."""
    lines = [
        "Start-up to the first estimate of terrain-estimate (fresh process, warm cache; median of the repetitions)",
        f"  {'vehicle':<13}{'bag':<36}{'wall s':>8}{'CPU s':>8}{'min CPU s':>11}{'load avg':>10}",
    ]
    for r in figures["rows"]:
        lines.append(
            f"  {r['vehicle']:<13}{r['bag']:<36}{r['wall_s']:>8.2f}{r['cpu_s']:>8.2f}{r['cpu_s_min']:>11.2f}"
            f"{r['load_avg_1min']:>10.1f}"
        )
    return "\n".join(lines)
