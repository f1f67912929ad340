"""The skid-steer replay section of the benchmark (``python -m terrain_analysis.tools.bench --only skid_replay``).

Item 6 of :mod:`terrain_analysis.tools.bench` (issues 20 and 23: "≥ 50× real time per core"): ``estimate_bag``
on the shipped skid-steer bags and a simulated S-shape bag, the compiled filter step against the previous
Python step, CPU µs per IMU sample and multiples of real time per core; and the start-up to the first
estimate of ``terrain-estimate`` in a fresh process for both import chains.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.tools.bench_common import BAGS_DIR, BenchConfig, bag_duration_s

__all__ = ["SKID_BAGS", "SKID_PATHS", "SKID_SIM_SECONDS", "bench_skid_replay", "format_skid_replay"]

SKID_BAGS: tuple[str, ...] = ("skid_steer_s_shape", "skid_steer_small_radius_turn", "skid_steer_straight_acceleration")
SKID_SIM_SECONDS = 60.0
#: The paths compared: (label, ``estimate_bag``'s ``reference`` argument).
SKID_PATHS: tuple[tuple[str, bool], ...] = (("previous", True), ("new", False))

_STARTUP_CHILD = """
import sys, time
if {previous!r} == "1":
    import scipy.stats  # the previous import chain: filters.adaptive imported it for chi2
from terrain_estimation.tools import estimate as te
from terrain_estimation.vehicles import get_vehicle
entry = get_vehicle("skid_steer")
values = te.config_values(entry)
adapter = entry.make_adapter(values, entry.namespace)
if {previous!r} == "1":
    adapter.set_compiled(False)
handle = adapter.handle
def first(key, msg):
    out = handle(key, msg)
    if out:
        print("FIRST", time.process_time(), flush=True)
        adapter.handle = handle
    return out
adapter.handle = first
te.run_adapter(adapter, entry.namespace, {bag!r}, values=values)
"""


def _startup_s(bag: Path, previous: bool) -> tuple[float, float]:
    """(wall, CPU) seconds from a fresh ``python`` to the first estimate of the skid-steer replay of ``bag``."""
    import subprocess

    code = _STARTUP_CHILD.format(previous="1" if previous else "0", bag=str(bag))
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    wall, cpu = math.nan, math.nan
    for line in proc.stdout:
        if line.startswith("FIRST"):
            wall = time.perf_counter() - t0
            cpu = float(line.split()[1])
            break
    proc.kill()
    proc.wait()
    return wall, cpu


def _skid_bag_row(path: Path, label: str, reference: bool, repeats: int) -> dict[str, Any]:
    """CPU and wall time of ``estimate_bag`` over one skid-steer bag on one path (median of ``repeats``)."""
    from terrain_estimation.tools.estimate import estimate_bag

    duration, messages = bag_duration_s(path)
    run = estimate_bag(path, "skid_steer", reference=reference)  # untimed: imports, caches
    cpus, walls = [], []
    for _ in range(max(1, repeats)):
        c0, t0 = time.process_time(), time.perf_counter()
        run = estimate_bag(path, "skid_steer", reference=reference)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    cpu, wall = float(np.median(cpus)), float(np.median(walls))
    steps = len(run.messages("/skid_steer/skid_steer/state"))
    return {
        "bag": path.name,
        "path": label,
        "bag_s": duration,
        "messages": messages,
        "steps": steps,
        "cpu_s": cpu,
        "wall_s": wall,
        "us_per_step": 1e6 * cpu / steps if steps else math.nan,
        "x_real_time_per_core": duration / cpu if cpu > 0 else math.inf,
        "x_real_time_wall": duration / wall if wall > 0 else math.inf,
    }


def bench_skid_replay(cfg: BenchConfig, bags_dir: Path = BAGS_DIR) -> dict[str, Any]:
    """The skid-steer replay section (module docstring, item 6)."""
    import tempfile

    from vehicle_sim.tools.simulate import record

    rows: list[dict[str, Any]] = []
    startup: list[dict[str, Any]] = []
    sim_s = SKID_SIM_SECONDS if cfg.drive_s >= 10.0 else 4.0
    with tempfile.TemporaryDirectory(prefix="bench_skid_") as tmp:
        sim = Path(tmp) / f"skid_steer_sim_s_shape_{sim_s:.0f}s"
        record("skid_steer", sim_s, sim, overrides={"seed": cfg.seed, "scenario.manoeuvre": "s_shape"})
        bags = [bags_dir / name for name in SKID_BAGS] + [sim]
        for path in bags:
            for label, reference in SKID_PATHS:
                rows.append(_skid_bag_row(path, label, reference, cfg.repeats))
        for label, reference in SKID_PATHS:
            _startup_s(bags[0], reference)  # untimed: fills numba's and Python's caches
            samples = [_startup_s(bags[0], reference) for _ in range(max(1, cfg.repeats))]
            startup.append(
                {
                    "path": label,
                    "wall_s": float(np.median([w for w, _ in samples])),
                    "cpu_s": float(np.median([c for _, c in samples])),
                }
            )
    return {"bags": rows, "startup": startup}


def format_skid_replay(figures: dict[str, Any]) -> str:
    """The skid-steer replay section of the readable table."""
    lines = [
        "Skid-steer replay (estimate_bag: read + decode + input checks + adapter + estimator + output messages), "
        "previous = Python filter step, new = compiled step; CPU of this process, median",
        f"  {'bag':<36}{'s':>6}{'steps':>7}  {'previous µs/step':>17}{'× real/core':>12}"
        f"  {'new µs/step':>12}{'× real/core':>12}{'× real wall':>12}{'speed-up':>10}",
    ]
    by_bag: dict[str, dict[str, dict[str, Any]]] = {}
    for r in figures["bags"]:
        by_bag.setdefault(r["bag"], {})[r["path"]] = r
    for name, paths in by_bag.items():
        old, new = paths["previous"], paths["new"]
        lines.append(
            f"  {name:<36}{new['bag_s']:>6.1f}{new['steps']:>7d}  {old['us_per_step']:>17.0f}"
            f"{old['x_real_time_per_core']:>12.1f}  {new['us_per_step']:>12.0f}{new['x_real_time_per_core']:>12.1f}"
            f"{new['x_real_time_wall']:>12.1f}{old['cpu_s'] / new['cpu_s']:>10.1f}"
        )
    lines.append("  Start-up to the first estimate (fresh process, warm cache; median):")
    for r in figures["startup"]:
        chain = "scipy.stats imported, Python step" if r["path"] == "previous" else "lazy chi2, compiled step"
        lines.append(f"    {r['path']:<10}{r['wall_s']:>7.2f} s wall {r['cpu_s']:>7.2f} s CPU  ({chain})")
    return "\n".join(lines)
