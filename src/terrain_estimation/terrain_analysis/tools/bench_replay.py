"""The replay sections of the benchmark (``python -m terrain_analysis.tools.bench --only skid_replay|replay``).

Item 6 of :mod:`terrain_analysis.tools.bench` (issues 20 and 23: "≥ 50× real time per core"): ``estimate_bag``
on the shipped skid-steer bags and a simulated S-shape bag, the compiled filter step against the previous
Python step, CPU µs per IMU sample and multiples of real time per core; and the start-up to the first
estimate of ``terrain-estimate`` in a fresh process for both import chains.

Item 6b (``--only replay``): ``estimate_bag`` on the shipped quarter-car, LRV and rover bags and on 60 s
simulated quarter-car and LRV bags, the bulk path (the default: the numeric inputs decoded and judged in
windows, as arrays, :mod:`terrain_estimation.tools.estimate_replay`) against the previous path (every message
decoded into its rclpy object, checked and handled one at a time, ``bulk=False``, the bag read through
rosbags' own loop and the estimate messages built through their constructors), in one run: CPU µs per input
message and multiples of real time per core.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.tools.bench_common import BAGS_DIR, BenchConfig, bag_duration_s

__all__ = [
    "REPLAY_BAGS",
    "SKID_BAGS",
    "SKID_PATHS",
    "SKID_SIM_SECONDS",
    "bench_replay",
    "bench_skid_replay",
    "format_replay",
    "format_skid_replay",
]

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


def _timed(run_once: Any, repeats: int) -> tuple[Any, float, float]:
    """``(result, CPU s, wall s)`` of ``run_once()``: medians of ``repeats`` timed calls after an untimed one."""
    result = run_once()  # untimed: imports, caches
    cpus, walls = [], []
    for _ in range(max(1, repeats)):
        c0, t0 = time.process_time(), time.perf_counter()
        result = run_once()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return result, float(np.median(cpus)), float(np.median(walls))


def _skid_bag_row(path: Path, label: str, reference: bool, repeats: int) -> dict[str, Any]:
    """CPU and wall time of ``estimate_bag`` over one skid-steer bag on one path (median of ``repeats``)."""
    from terrain_estimation.tools.estimate import estimate_bag

    duration, messages = bag_duration_s(path)
    run, cpu, wall = _timed(lambda: estimate_bag(path, "skid_steer", reference=reference), repeats)
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


def _previous_and_new(rows: list[dict[str, Any]]) -> list[tuple[str, dict[str, Any], dict[str, Any]]]:
    """``(bag, previous row, new row)`` per bag, in the rows' order."""
    by_bag: dict[str, dict[str, dict[str, Any]]] = {}
    for r in rows:
        by_bag.setdefault(r["bag"], {})[r["path"]] = r
    return [(name, paths["previous"], paths["new"]) for name, paths in by_bag.items()]


def format_skid_replay(figures: dict[str, Any]) -> str:
    """The skid-steer replay section of the readable table."""
    lines = [
        "Skid-steer replay (estimate_bag: read + decode + input checks + adapter + estimator + output messages), "
        "previous = Python filter step, new = compiled step; CPU of this process, median",
        f"  {'bag':<36}{'s':>6}{'steps':>7}  {'previous µs/step':>17}{'× real/core':>12}"
        f"  {'new µs/step':>12}{'× real/core':>12}{'× real wall':>12}{'speed-up':>10}",
    ]
    for name, old, new in _previous_and_new(figures["bags"]):
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


#: Item 6b's shipped bags: (bag, vehicle).
REPLAY_BAGS: tuple[tuple[str, str], ...] = (
    ("quarter_car_graneville_iso_d_10ms", "quarter_car"),
    ("lrv_regolith_iso_g_2ms", "lrv"),
    *((f"rover_terrain_{i}", "rover") for i in range(1, 7)),
)
#: Item 6b's simulated bags: (vehicle, simulator overrides): the shipped bags' worlds (``make bags``).
REPLAY_SIMULATED: tuple[tuple[str, dict[str, Any]], ...] = (
    ("quarter_car", {"scenario.road": "D", "scenario.road_seed": 11}),
    (
        "lrv",
        {"scenario.road": "G", "scenario.road_seed": 21, "scenario.speed": 2.0, "scenario.soils": ["lunar_regolith"]},
    ),
)


def _replay_row(path: Path, vehicle: str, bulk: bool, repeats: int) -> dict[str, Any]:
    """CPU and wall time of ``estimate_bag`` over one bag, on the bulk path or the previous one."""
    from terrain_estimation import bag
    from terrain_estimation.ros import soil_stiffness
    from terrain_estimation.tools.estimate import estimate_bag

    duration, _ = bag_duration_s(path)
    direct, fast_read = soil_stiffness._DIRECT_OUTPUT, bag._FAST_READ
    # The previous path built its messages through their setters and read the bag through rosbags' own loop.
    soil_stiffness._DIRECT_OUTPUT, bag._FAST_READ = direct and bulk, fast_read and bulk
    try:
        run, cpu, wall = _timed(lambda: estimate_bag(path, vehicle, bulk=bulk), repeats)
    finally:
        soil_stiffness._DIRECT_OUTPUT, bag._FAST_READ = direct, fast_read
    messages = run.inputs_read
    return {
        "bag": path.name,
        "vehicle": vehicle,
        "path": "new" if bulk else "previous",
        "bag_s": duration,
        "messages": messages,
        "estimates": len(run.outputs),
        "cpu_s": cpu,
        "wall_s": wall,
        "us_per_message": 1e6 * cpu / messages if messages else math.nan,
        "x_real_time_per_core": duration / cpu if cpu > 0 else math.inf,
    }


def bench_replay(cfg: BenchConfig, bags_dir: Path = BAGS_DIR) -> dict[str, Any]:
    """Item 6b (module docstring): previous and bulk path over the shipped and simulated bags."""
    import tempfile

    from vehicle_sim.tools.simulate import record

    rows: list[dict[str, Any]] = []
    sim_s = SKID_SIM_SECONDS if cfg.drive_s >= 10.0 else 4.0
    bags = [(bags_dir / name, vehicle) for name, vehicle in REPLAY_BAGS]
    if cfg.drive_s < 10.0:  # --quick: one bag of each kind
        bags = bags[:3]
    with tempfile.TemporaryDirectory(prefix="bench_replay_") as tmp:
        for vehicle, overrides in REPLAY_SIMULATED:
            sim = Path(tmp) / f"{vehicle}_sim_{sim_s:.0f}s"
            record(vehicle, sim_s, sim, overrides={"seed": cfg.seed, **overrides})
            bags.append((sim, vehicle))
        for path, vehicle in bags:
            for bulk in (False, True):
                rows.append(_replay_row(path, vehicle, bulk, cfg.repeats))
    return {"bags": rows}


def format_replay(figures: dict[str, Any]) -> str:
    """Item 6b of the readable table."""
    lines = [
        "Replay (estimate_bag: read + decode + input checks + adapter + estimator + estimate messages), CPU of this "
        "process, median; previous = one message at a time, new = numeric inputs decoded and checked in bulk",
        f"  {'bag':<36}{'vehicle':<12}{'s':>6}{'messages':>9}  {'previous µs/msg':>16}{'× real/core':>12}"
        f"  {'new µs/msg':>11}{'× real/core':>12}{'speed-up':>10}",
    ]
    for name, old, new in _previous_and_new(figures["bags"]):
        lines.append(
            f"  {name:<36}{new['vehicle']:<12}{new['bag_s']:>6.1f}{new['messages']:>9d}  "
            f"{old['us_per_message']:>16.1f}{old['x_real_time_per_core']:>12.1f}  {new['us_per_message']:>11.1f}"
            f"{new['x_real_time_per_core']:>12.1f}{old['cpu_s'] / new['cpu_s']:>10.2f}"
        )
    return "\n".join(lines)
