"""``make demo``: simulate each vehicle, estimate live over ROS 2, summarise.

For every vehicle that exists so far, the vehicle's simulator node runs as a
process of its own (publishing ``/clock``, sensors and ground truth) and this
process runs its estimator node (``use_sim_time``) and a recorder, all
talking over ROS 2 topics through DDS on this host. The "estimates" column
says how many of the expected estimates arrived: fewer means messages were
lost (a loaded machine, or a real-time factor the estimator cannot keep).
Afterwards it prints one table per kind of estimate and writes plots under
``out/`` (``--out``; an existing non-empty directory no project tool made is
refused unless ``--overwrite``, and nothing there is deleted):

* soil stiffness (quarter car, LRV): final estimate against ground truth,
  time to converge, innovation consistency, the estimator's diagnostic level;
* skid-steer motion state: rms error of vx, vy, yaw rate and body sideslip
  against ground truth, the instantaneous centre of rotation (ICR) over the
  steady turn, the adaptive filter's fading factor and noise scale, the
  innovation consistency and diagnostic level from the node's diagnostics;
* rocker-bogie wheel terrain (the Kapvik rover, terrain 1): rms error of each
  wheel's slip, normal load W, drawbar pull DP and resistive torque τ_R
  against ground truth (mean over the rear, middle and front wheel), the
  online terrain models (``terrain_model``) received and how well the last
  one's DP(W, i) predicts the true DP inside its validity region, the
  innovation consistency and diagnostic level; the plot shows every wheel's W
  and DP with their ±2σ band against the truth.

Each :class:`DemoScenario` names its :class:`DemoKind`: what to record
(:class:`Recording`: message type, estimate topic, ground-truth topic, other
estimator outputs such as the rover's terrain models) and how to summarise,
plot and tabulate it (the kinds: :mod:`~terrain_analysis.tools.demo_kinds`).
:func:`run_scenario` does the ROS 2 part the same way for every kind
(:mod:`~terrain_analysis.tools.demo_record`).

A scenario also sets its real-time factor, the simulator's pace at most: 1
for all but the rover, which drives 40 s at 4x real time. Its estimator runs
at 5 Hz on 50 Hz sensors and keeps up with tens of times real time; the
simulator itself manages about 4.7x on an idle core
(``docs/results/rover.md``), so on a busy machine it runs slower (the
40 s took 18-33 s on a shared 2-core machine) and no estimate is lost.
``--realtime-factor`` runs every scenario at one factor instead.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from typing import Any

from terrain_analysis.tools.demo_kinds import (
    ROVER,
    SKID_STEER,
    SOIL_STIFFNESS,
)
from terrain_analysis.tools.demo_record import DemoKind, DemoScenario, run_scenario
from terrain_estimation.cli import EXIT_INPUT
from terrain_estimation.outputs import OutputPathError, prepare_output_dir

__all__ = ["SCENARIOS", "main"]

#: The scenarios ``make demo`` runs, in order.
SCENARIOS: tuple[DemoScenario, ...] = (
    DemoScenario(
        "quarter_car",
        "quarter car, ISO D, 10 m/s: Graneville loam, then Upland sandy loam after 100 m",
        20.0,
        {
            "scenario.road": "D",
            "scenario.speed": 10.0,
            "scenario.soils": ["graneville_loam", "upland_sandy_loam"],
            "scenario.soil_starts": [0.0, 100.0],
        },
        kind=SOIL_STIFFNESS,
    ),
    DemoScenario(
        "lrv",
        "LRV, ISO G, 2 m/s, lunar regolith",
        20.0,
        {"scenario.road": "G", "scenario.speed": 2.0, "scenario.soils": ["lunar_regolith"]},
        kind=SOIL_STIFFNESS,
    ),
    DemoScenario(
        "skid_steer",
        "skid steer, small-radius turn: 5 km/h, 0.2 rad/s counter-clockwise from 8 s (R ≈ 7 m)",
        28.0,
        {"scenario.manoeuvre": "small_radius_turn", "scenario.duration": 28.0},
        kind=SKID_STEER,
    ),
    DemoScenario(
        "rover",
        "Kapvik rocker-bogie, terrain 1 (rolling), 2 cm/s: Estimators 1 + 2, online terrain model",
        40.0,
        # the noise seed of bags/rover_terrain_1 (the same run, 10 s longer)
        {"scenario.terrain": "rolling", "seed": 51},
        kind=ROVER,
        # 200 simulator steps (50 Hz sensors), 20 estimates a second; the simulator's limit is about 4.7x
        realtime_factor=4.0,
    ),
)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="terrain-demo", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", default="out/demo", help="directory for the plots (default: out/demo; its own, or a new one)"
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="write the plots into --out even if it holds files and was not made by a project tool",
    )
    parser.add_argument(
        "--realtime-factor",
        type=float,
        default=None,
        help=(
            "simulated seconds per wall second for every scenario (default: each scenario's own, "
            "1 for all but the rover's 4: a soil-stiffness node, one Python process, can fall behind "
            "the 1 kHz profile topic at 1.5x real time on a busy 2-core machine; its diagnostics "
            "then WARN of lost profile samples)"
        ),
    )
    parser.add_argument(
        "--vehicle",
        action="append",
        choices=[s.vehicle for s in SCENARIOS],
        help="only these vehicles (repeatable; default: all)",
    )
    args = parser.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    # The plots go into a directory a project tool made (or an empty one); other files are never touched.
    try:
        out = prepare_output_dir(args.out, overwrite=args.overwrite, tool="terrain-demo")
    except OutputPathError as exc:
        print(f"terrain-demo: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    # results per kind, kinds in the order of their first scenario
    by_kind: dict[str, tuple[DemoKind[Any], list[Any]]] = {}
    for scenario in SCENARIOS:
        if args.vehicle and scenario.vehicle not in args.vehicle:
            continue
        factor = scenario.realtime_factor if args.realtime_factor is None else args.realtime_factor
        print(
            f"{scenario.vehicle}: {scenario.title} — simulating {scenario.duration:.0f} s at "
            f"{factor:g}x real time, estimating live over ROS 2 ...",
            file=sys.stderr,
        )
        kind = scenario.kind
        result = kind.summarise(run_scenario(scenario, factor))
        by_kind.setdefault(kind.name, (kind, []))[1].append(result)
        print(f"  plot: {kind.plot(result, out)}", file=sys.stderr)
    for kind, results in by_kind.values():
        print()
        print(kind.table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
