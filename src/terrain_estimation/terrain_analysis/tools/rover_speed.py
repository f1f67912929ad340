"""The rover reproduction's speed section: simulator and estimators as multiples of real time.

Part of :mod:`terrain_analysis.tools.reproduce_rover`.
"""

from __future__ import annotations

import os

import numpy as np

from terrain_analysis.tools.rover_plan import (
    ALL_VARIANTS,
    ESTIMATOR_SPEED_MIN,
    SIMULATOR_SPEED_MIN,
    VARIANT_NAMES,
    VARIANTS,
    Counts,
)
from terrain_analysis.tools.rover_report import RoverReport
from terrain_analysis.tools.rover_runs import Results

__all__ = ["section_speed"]


def section_speed(rr: RoverReport, res: Results, counts: Counts) -> None:
    lines = [
        "## Speed: simulator and estimators as multiples of real time",
        "",
        "× real time = simulated seconds per second. **CPU**: per CPU second of the process doing the work "
        "(`time.process_time`, what the code costs on one free core); **wall**: per elapsed second (longer when "
        f"the machine is shared: {os.cpu_count()} CPUs, other processes and the other worker compete). The "
        "issue's criteria are evaluated on the CPU figure; both are shown.",
        "",
        "| what | simulated (s) | wall (s) | CPU (s) | × real time (CPU) | × real time (wall) | RK4 steps per 20 ms |",
        "|---|---|---|---|---|---|---|",
    ]
    speeds: dict[str, tuple[float, float]] = {}
    for name, label in (
        ("wong_reece", "simulator, full Wong–Reece model"),
        ("surrogate", "simulator, 4th-order surrogate"),
    ):
        s = res.speed.get(name)
        if s is None:
            continue
        cpu_x, wall_x = s.duration / s.cpu_s, s.duration / s.wall_s
        speeds[name] = (cpu_x, wall_x)
        lines.append(
            f"| {label} (terrain 1) | {s.duration:g} | {s.wall_s:.1f} | {s.cpu_s:.1f} | {cpu_x:.2f} | {wall_x:.2f} | "
            f"{s.substeps_mean:.1f} |"
        )
    terr = list(res.terrains.values())
    if terr:
        sim_s = sum(d.duration for d in terr)
        wall = sum(d.sim_wall_s for d in terr)
        cpu = sum(d.sim_cpu_s for d in terr)
        lines.append(
            f"| simulator, {terr[0].terramechanics}, the six terrain runs | {sim_s:g} | {wall:.1f} | {cpu:.1f} | "
            f"{sim_s / cpu:.2f} | {sim_s / wall:.2f} | {np.mean([d.substeps_mean for d in terr]):.1f} |"
        )
    est_speed: dict[str, tuple[float, float]] = {}
    for v in ALL_VARIANTS:
        sim_s = wall = cpu = 0.0
        steps = 0
        for d in terr:
            for (_, vv), ser in d.series.items():
                if vv != v:
                    continue
                sim_s += d.duration
                wall += ser.wall_s
                cpu += ser.cpu_s
                steps += int(ser.counters["steps"]) + int(ser.counters["initialisations"])
        if cpu <= 0.0:
            continue
        est_speed[v] = (sim_s / cpu, sim_s / wall)
        lines.append(
            f"| estimators {VARIANT_NAMES[v]} (`RoverTerrainEstimator`, 50 Hz input, 5 Hz steps; "
            f"{1e3 * cpu / max(steps, 1):.1f} ms CPU per step) | {sim_s:g} | {wall:.1f} | {cpu:.1f} | "
            f"{sim_s / cpu:.1f} | {sim_s / wall:.1f} | — |"
        )
    lines += [
        "",
        'The paper: "Real-time estimator speeds have not been achieved in the MATLAB simulation of the '
        'estimator". `make bench` times the Estimator 1 and 2/3 steps separately.',
        "",
    ]
    rr.rep.add_section(lines)
    rr.notes["speeds"] = speeds
    rr.notes["est_speed"] = est_speed
    for v in VARIANTS:
        if v in est_speed:
            cpu_x, wall_x = est_speed[v]
            rr.claim(
                "speed",
                f"estimators {VARIANT_NAMES[v]}, × real time (CPU)",
                cpu_x,
                "not real time (MATLAB)",
                f"≥ {ESTIMATOR_SPEED_MIN:g} (issue)",
                cpu_x >= ESTIMATOR_SPEED_MIN,
            )
            rr.claim("speed", f"estimators {VARIANT_NAMES[v]}, × real time (wall)", wall_x, "—", "—", None)
    if "wong_reece" in speeds:
        cpu_x, wall_x = speeds["wong_reece"]
        rr.claim(
            "speed",
            "simulator with the full Wong–Reece model, × real time (CPU)",
            cpu_x,
            "— (MATLAB ode45 with the surrogate)",
            f"≥ {SIMULATOR_SPEED_MIN:g} (issue)",
            cpu_x >= SIMULATOR_SPEED_MIN,
        )
        rr.claim("speed", "simulator with the full Wong–Reece model, × real time (wall)", wall_x, "—", "—", None)
    if "surrogate" in speeds:
        rr.claim("speed", "simulator with the surrogate, × real time (CPU)", speeds["surrogate"][0], "—", "—", None)
