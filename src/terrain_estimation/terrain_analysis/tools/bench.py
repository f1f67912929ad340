"""``python -m terrain_analysis.tools.bench``: how fast the filters, the estimator and the simulator run.

One run prints, side by side (``make bench``):

1. **Filter step** — predict + update of the SCKF, CKF, UKF and EKF of
   :mod:`terrain_estimation.filters` on the quarter-car estimation model
   (:class:`~terrain_estimation.models.quarter_car.QuarterCarModel`, 10
   sub-steps of the measured road per 10 ms step, MODELS.md A.10), and of
   filterpy's ``UnscentedKalmanFilter`` with ``MerweScaledSigmaPoints`` running
   the *same* model (``fx``/``hx`` wrap ``f``/``h``; filterpy calls ``fx``
   once per sigma point, so every point runs its own sub-step loop, where our
   filters propagate all points as one ``(m, n, n)`` batch). Every filter is
   fed the same simulated drive (Graneville loam, ISO 8608 D, 10 m/s) and
   timed per step with ``time.perf_counter_ns`` after a warm-up; median and
   90th percentile. Beside them, the compiled SCKF and EKF steps that the
   estimator node runs (``estimators.soil_stiffness_sckf`` / ``_ekf``) on the
   same model and data. "state bytes": our immutable state value (mean and P or
   S); filterpy's filter object with its work arrays (that is its state).
2. **Estimator throughput** as a multiple of real time: the offline bag run
   (:func:`~terrain_estimation.tools.estimate.estimate_bag`: bag reading,
   deserialisation, adapter, estimator) on the two recorded bags, bag
   duration from the log stamps over wall time; and the ROS-free core
   (:class:`~terrain_estimation.estimators.soil_stiffness.SoilStiffnessEstimator`,
   same configuration) fed a ``vehicle_sim`` run directly, with the time
   spent inside the filter step measured around it. The "core" rows run what
   the node runs (the compiled SCKF / EKF step); the "numpy path" rows beside
   them run the same configuration through the filter's public numpy
   ``predict``/``update`` (the reference path, timed by a proxy). The
   µs-per-step column shows where the time goes: filter < core < bag.
3. **Simulator** (``vehicle_sim`` ``simulate()``) as a multiple of real time.
4. **Skid steer** ([SS], MODELS.md Part B): per-step time of the UKF, STUKF
   and AN-STUKF (:class:`~terrain_estimation.filters.an_stukf.AdaptiveStrongTrackingUKF`
   over the 3-state ``SkidSteerObserverModel``) side by side, each inside a
   :class:`~terrain_estimation.estimators.skid_steer.SkidSteerEstimator` fed
   the *same* simulated small-radius turn (``vehicle_sim`` truth plant,
   recorded once in memory, wheel speeds then IMU at 100 Hz); the filter
   step is timed by a proxy around ``filter.step``. The same runs give the
   estimator's throughput over the drive as a multiple of real time, and the
   skid-steer simulator's own speed.
5. **Rocker-bogie rover** ([RB], MODELS.md Part C): per-step time of
   Estimator 1 (UKF, 22 states) and of Estimator 2 (two-axis load cells) /
   3 (single-axis), 9 states each, inside a
   :class:`~terrain_estimation.estimators.rover.RoverTerrainEstimator` fed a
   simulated drive over Fig. 10's terrain 1 (50 Hz sensors, 5 Hz steps; the
   filter calls are timed by a proxy, keyed by the model they run); the
   estimators' throughput as a multiple of real time; and the rover simulator
   with the full Wong–Reece soil model and with its 4th-order surrogate.
6. **Skid-steer replay** (``--only skid_replay``; issue 20's and 23's "≥ 50× real time per
   core"): ``estimate_bag`` on the three shipped skid-steer bags and a simulated 60 s S-shape bag,
   the compiled filter step (the default path) and the previous path (the Python reference step,
   ``estimate_bag(..., reference=True)``) side by side in one run: CPU µs per IMU sample and
   multiples of real time per core (bag seconds over the process's CPU seconds, median of the
   repetitions after an untimed run), wall-clock figures beside them; and the start-up to the first
   estimate of ``terrain-estimate`` in a fresh process (warm numba cache), for the new import chain and
   for the previous one (``scipy.stats`` imported first, as ``filters.adaptive`` did before, and the
   Python step).
   6b. **Replay** (``--only replay``; issue 23's "≥ 50× real time per core" for the quarter car, the LRV and
   the rover's shared path): ``estimate_bag`` on the shipped quarter-car, LRV and rover bags and on 60 s
   simulated quarter-car and LRV bags (the shipped bags' worlds), the previous path (every message decoded,
   checked and handled one at a time, ``bulk=False``) beside the bulk path (the numeric inputs decoded and
   judged in windows, as arrays; the default), in one run: CPU µs per input message and multiples of real
   time per core (bag seconds over the process's CPU seconds, median of the repetitions after an untimed run).
7. **Quarter-car Monte Carlo** (``--only qc_monte_carlo``; issue 23's "the 100-run Monte Carlo with
   every filter in 60 s or less on 2 cores"): the 100 runs of case 1 of ``make reproduce-qc``
   (:func:`terrain_analysis.tools.reproduce_qc.build_plan`: Graneville loam, ISO D, 10 m/s, 12 s; every
   filter the case runs: SCKF, EKF, both with the printed ``Q_k``, and the SCKF with the ln k_s state) on
   2 workers of a local Dask cluster (the shared engine; its start-up and the workers' warm-up are
   printed on their own line, not in the rows), twice in one run: before (the EKF through its public numpy
   ``predict``/``update``, as before the compiled EKF step; the SCKF compiled as before) and after (both
   compiled, the default). Wall time, CPU time of the workers, and the largest difference between the
   two runs' k_s errors (the same rides, the same filters to rounding).
   7b. **Start-up** (``--only startup``; issue 23's "start-up under 1 s to the first message with a warm
   cache"): for every vehicle, a fresh ``python`` to the first estimate ``terrain-estimate`` keeps from its
   shipped bag (:mod:`~terrain_analysis.tools.bench_startup`), CPU and wall seconds, median of the repetitions
   after an untimed run.
8. **Machine**: CPU count and load average (other processes on the CPUs
   preempt long steps first, so a p90 far above the median usually means a
   busy machine), Python, numpy, ``OPENBLAS_NUM_THREADS`` (``make`` sets it to
   1; a threaded BLAS only adds stalls on these 5 × 5 matrices).

Nothing here asserts a time: the figures depend on the machine. ``--quick``
is a short smoke run (a few hundred steps, 2 s drives, one repetition);
``--json PATH`` also writes every figure.

The sections live in :mod:`~terrain_analysis.tools.bench_quarter_car` (1–3),
:mod:`~terrain_analysis.tools.bench_vehicles` (4–5), :mod:`~terrain_analysis.tools.bench_replay` (6) and
:mod:`~terrain_analysis.tools.bench_monte_carlo` (7), what they share in
:mod:`~terrain_analysis.tools.bench_common`; this module runs them and prints the report.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from terrain_analysis.tools.bench_common import (
    BAGS_DIR,
    BenchConfig,
    add_json_arguments,
    machine_info,
    parse_bench_arguments,
    write_json,
)
from terrain_analysis.tools.bench_monte_carlo import bench_qc_monte_carlo, format_qc_monte_carlo
from terrain_analysis.tools.bench_quarter_car import (
    BAGS,
    COMPILED_FILTERS,
    FILTERPY_LABEL,
    OUR_FILTERS,
    bench_bag,
    bench_core,
    bench_filters,
    bench_simulator,
    drive_lrv,
    drive_quarter_car,
    format_quarter_car,
)
from terrain_analysis.tools.bench_replay import bench_replay, bench_skid_replay, format_replay, format_skid_replay
from terrain_analysis.tools.bench_sim2real import SIM2REAL_CASES, bench_diagnosis_scaling, bench_sim2real
from terrain_analysis.tools.bench_sim2real import format_diagnosis_scaling as _format_diagnosis_scaling
from terrain_analysis.tools.bench_sim2real import format_sim2real as _format_sim2real
from terrain_analysis.tools.bench_startup import bench_startup, format_startup
from terrain_analysis.tools.bench_vehicles import (
    ROVER_ROW_LABELS,
    SKID_ROW_LABELS,
    bench_rover,
    bench_skid,
    format_rover,
    format_skid,
)
from terrain_estimation.cli import cli_main

__all__ = [
    "ROW_LABELS",
    "SKID_ROW_LABELS",
    "ROVER_ROW_LABELS",
    "SIM2REAL_CASES",
    "BenchConfig",
    "bench_core",
    "bench_qc_monte_carlo",
    "format_qc_monte_carlo",
    "main",
    "run_bench",
    "format_report",
]

#: Every row label the report prints (the smoke test checks them all).
ROW_LABELS: tuple[str, ...] = (
    "machine:",
    *(label for label, _ in OUR_FILTERS),
    *(label for label, _ in COMPILED_FILTERS),
    FILTERPY_LABEL,
    *(f"bag {name}" for name, _ in BAGS),
    "core quarter_car",
    "core quarter_car numpy path",
    "core lrv",
    "core lrv numpy path",
    "simulate quarter_car",
    "simulate lrv",
)


def run_bench(cfg: BenchConfig, bags_dir: Path = BAGS_DIR) -> dict[str, Any]:
    """Every figure of the report, as a JSON-able dict."""
    out: dict[str, Any] = {"machine": machine_info(), "config": dataclasses.asdict(cfg)}
    out["filters"] = bench_filters(cfg)
    sim_qc, run_qc = bench_simulator("quarter_car", drive_quarter_car, cfg)
    sim_lrv, run_lrv = bench_simulator("lrv", drive_lrv, cfg)
    throughput = []
    for name, vehicle in BAGS:
        throughput.append(bench_bag(bags_dir / name, vehicle, cfg.repeats))
    throughput.append(bench_core("quarter_car", run_qc))
    throughput.append(bench_core("quarter_car", run_qc, numpy_path=True))
    throughput.append(bench_core("lrv", run_lrv))
    throughput.append(bench_core("lrv", run_lrv, numpy_path=True))
    out["throughput"] = throughput
    out["simulator"] = [sim_qc, sim_lrv]
    out["skid_steer"] = bench_skid(cfg)
    out["rover"] = bench_rover(cfg)
    out["sim2real"] = bench_sim2real(cfg)
    return out


def format_report(figures: dict[str, Any]) -> str:
    """The readable table."""
    m = figures["machine"]
    cfg = figures["config"]
    load = "n/a" if m["load_avg_1min"] is None else f"{m['load_avg_1min']:.1f}"
    lines = [
        f"machine: {m['cpu_count']} CPUs (load average {load}), {m['platform']}, "
        f"Python {m['python']}, numpy {m['numpy']}, "
        f"OPENBLAS_NUM_THREADS={m['OPENBLAS_NUM_THREADS']}, OMP_NUM_THREADS={m['OMP_NUM_THREADS']}",
        "",
        *format_quarter_car(figures),
    ]
    if "skid_steer" in figures:
        lines += ["", *format_skid(figures["skid_steer"], cfg)]
    if "rover" in figures:
        lines += ["", *format_rover(figures["rover"])]
    if "sim2real" in figures:
        lines += ["", *_format_sim2real(figures["sim2real"])]
    return "\n".join(lines)


@cli_main("make bench")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="terrain-bench",
        description=(
            "Time the filters, the estimator (core and over the recorded bags) and the simulator; "
            "the skid-steer UKF / STUKF / AN-STUKF, estimator and simulator; and the rover's Estimators 1–3, "
            "estimator and simulator (full Wong–Reece and surrogate)."
        ),
    )
    parser.add_argument("--quick", action="store_true", help="short smoke run (few steps, 2 s drives)")
    add_json_arguments(parser)
    parser.add_argument("--bags", metavar="DIR", default=str(BAGS_DIR), help="directory of the recorded bags")
    parser.add_argument(
        "--only",
        choices=("skid_replay", "replay", "qc_monte_carlo", "diagnosis_scaling", "startup"),
        help=(
            "run one section only: skid_replay = the skid-steer bags, compiled step against the previous one; "
            "replay = the quarter-car, LRV and rover bags, bulk decoding and checks against one message at a time; "
            "qc_monte_carlo = the 100-run quarter-car Monte Carlo (reproduce-qc case 1, every filter) on 2 "
            "processes, the numpy EKF against the compiled one; diagnosis_scaling = the sim-to-real diagnosis of "
            "15, 30 and 60 s bags per vehicle (CPU per bag second, optimiser evaluations, ratio to linear); startup = "
            "a fresh process to the first estimate of terrain-estimate, every vehicle (warm cache)"
        ),
    )
    args = parse_bench_arguments(parser, argv)
    cfg = BenchConfig.quick() if args.quick else BenchConfig()
    sections: dict[str, tuple[Callable[[], dict[str, Any]], Callable[[dict[str, Any]], str]]] = {
        "skid_replay": (lambda: bench_skid_replay(cfg, Path(args.bags)), format_skid_replay),
        "replay": (lambda: bench_replay(cfg, Path(args.bags)), format_replay),
        "qc_monte_carlo": (lambda: bench_qc_monte_carlo(cfg), format_qc_monte_carlo),
        "startup": (lambda: bench_startup(cfg, Path(args.bags)), format_startup),
        "diagnosis_scaling": (
            lambda: {"rows": bench_diagnosis_scaling(cfg)},
            lambda f: "\n".join(_format_diagnosis_scaling(f["rows"])),
        ),
    }
    if args.only is not None:
        run, fmt = sections[args.only]
        section = run()
        print(fmt(section))
        figures = {"machine": machine_info(), args.only: section}
    else:
        figures = run_bench(cfg, Path(args.bags))
        print(format_report(figures))
    if args.json:
        print(f"\nwrote {write_json(args.json, figures, overwrite=args.overwrite)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
