"""The sim-to-real diagnosis sections of the benchmark (:mod:`terrain_analysis.tools.bench`).

* :func:`bench_sim2real` (in ``make bench``): wall and CPU time of
  :func:`~terrain_analysis.sim2real.diagnose.diagnose` on one simulated 60 s bag per vehicle with one
  withheld effect (issue 22's "a 60 s bag under a minute on 2 cores").
* :func:`bench_diagnosis_scaling` (``--only diagnosis_scaling``, or ``python -m
  terrain_analysis.tools.bench_sim2real``; issue 22/23's "cost linear in bag length"): the same case per
  vehicle simulated for 15, 30 and 60 s (the same seed: the shorter ride is the start of the longer),
  each diagnosed in a fresh process after an untimed, lightly optimised warm-up diagnosis of the shortest
  bag (the numba caches, lazy imports and first calls are not charged to it). Per bag: CPU seconds, CPU per bag second,
  replay-model evaluations (every call of the fits' residual function, cross-fits included), CPU per
  evaluation, the CPU outside the evaluations, and the ratio of CPU per bag second to the shortest
  bag's (1.00 = linear; within 10 % is the issue's rule). The stages' CPU (input checks, estimator,
  model build, attribution, where table) show which part grows. For the skid steer also the replays (runs of
  the dynamics: evaluations whose physics the replay cache does not hold yet) and their CPU, inside the
  evaluations' CPU.

Nothing asserts a time: the figures depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from terrain_analysis.tools.bench_common import (
    BenchConfig,
    add_json_arguments,
    machine_info,
    parse_bench_arguments,
    run_in_fresh_process,
    write_json,
)
from terrain_estimation.cli import cli_main

__all__ = [
    "SCALING_SECONDS",
    "SIM2REAL_CASES",
    "SIM2REAL_SECONDS",
    "bench_diagnosis_scaling",
    "bench_sim2real",
    "format_diagnosis_scaling",
    "format_sim2real",
]

SIM2REAL_CASES: tuple[tuple[str, dict[str, Any]], ...] = (
    ("quarter_car", {"effects.tire_contact_length": 0.2}),
    ("lrv", {"effects.sprung_mass_change": 0.2, "scenario.soils": ["lunar_regolith"], "scenario.speed": 2.0}),
    ("skid_steer", {"effects.gyro_bias": 0.01}),
    ("rover", {"effects.load_cell_bias": [0.0, 0.0, 3.0]}),
)
SIM2REAL_SECONDS = 60.0
SCALING_SECONDS: tuple[float, ...] = (15.0, 30.0, 60.0)


def bench_sim2real(cfg: BenchConfig) -> list[dict[str, Any]]:
    """Wall and CPU time of ``diagnose()`` on a simulated bag with one withheld effect, per vehicle."""
    from terrain_analysis.sim2real.diagnose import diagnose, supported_vehicles
    from vehicle_sim.tools.simulate import record

    full = cfg.drive_s >= 10.0
    duration = SIM2REAL_SECONDS if full else 6.0
    cases = SIM2REAL_CASES if full else SIM2REAL_CASES[:1]  # --quick: one short quarter-car bag
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="bench_sim2real_") as tmp:
        for vehicle, overrides in cases:
            if vehicle not in supported_vehicles():
                rows.append({"vehicle": vehicle, "skipped": "no replay model installed"})
                continue
            bag = Path(tmp) / vehicle
            try:
                record(vehicle, duration, bag, overrides={"seed": cfg.seed, **overrides})
            except Exception as exc:  # a bench row, not a crash: say why
                rows.append({"vehicle": vehicle, "skipped": f"could not simulate: {exc}"})
                continue
            wall0, cpu0 = time.perf_counter(), time.process_time()
            result = diagnose(bag, vehicle)
            wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
            a = result.attribution
            rows.append(
                {
                    "vehicle": vehicle,
                    "bag_s": duration,
                    "effect": _effect(overrides),
                    "wall_s": wall,
                    "cpu_s": cpu,
                    "candidates": len(a.ranking),
                    "pairs": len(a.pairs),
                    "verdict": a.verdict,
                }
            )
    return rows


def format_sim2real(rows: list[dict[str, Any]]) -> list[str]:
    """The sim-to-real section: time to diagnose one bag (issue 6 target: a 60 s bag in < 60 s)."""
    lines = [
        "Sim-to-real diagnosis (terrain-sim2real: where + every catalogue effect fitted/scored + pairs), one bag",
        f"  {'vehicle':<14}{'bag s':>7}{'wall s':>9}{'CPU s':>8}{'effects':>9}{'pairs':>7}  withheld effect → verdict",
    ]
    for r in rows:
        if "skipped" in r:
            lines.append(f"  {r['vehicle']:<14}  skipped: {r['skipped']}")
            continue
        lines.append(
            f"  {r['vehicle']:<14}{r['bag_s']:>7.0f}{r['wall_s']:>9.1f}{r['cpu_s']:>8.1f}{r['candidates']:>9d}"
            f"{r['pairs']:>7d}  {r['effect']} → {r['verdict'][:70]}"
        )
    return lines


def _effect(overrides: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in overrides.items() if k.startswith("effects."))


# ---------------------------------------------------------------------------
# Scaling with bag length
# ---------------------------------------------------------------------------


class _Meter:
    """CPU seconds and calls of the wrapped functions, by name."""

    def __init__(self) -> None:
        self.cpu: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self._depth: dict[str, int] = {}

    def wrap(self, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            depth = self._depth.get(name, 0)
            self._depth[name] = depth + 1
            t0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self._depth[name] = depth
                if depth == 0:  # a nested call is inside its caller's time
                    self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - t0
                self.calls[name] = self.calls.get(name, 0) + 1

        return timed


@contextlib.contextmanager
def _metered(meter: _Meter) -> Iterator[None]:
    """Time the diagnosis's stages and count the replay-model evaluations of every fit."""
    import terrain_analysis.sim2real.diagnose as diag
    import terrain_analysis.sim2real.fitting as fitting
    import terrain_analysis.sim2real.skid_steer_replay as skid_replay
    import terrain_estimation.tools.estimate as estimate

    patches: list[tuple[Any, str]] = [
        (diag, "screen_bag"),
        (diag, "build_model"),
        (diag, "attribute"),
        (diag, "where_table"),
        (estimate, "estimate_bag"),
        (fitting._Problem, "residuals"),
        (skid_replay, "replay_imu"),
    ]
    saved = [(owner, name, getattr(owner, name)) for owner, name in patches]
    try:
        for owner, name, fn in saved:
            setattr(owner, name, meter.wrap(name, fn))
        yield
    finally:
        for owner, name, fn in saved:
            setattr(owner, name, fn)


def _diagnose_metered(bag: str, vehicle: str, out: str | None) -> dict[str, Any]:
    """One metered diagnosis (run in a fresh process by :func:`bench_diagnosis_scaling`)."""
    from terrain_analysis.sim2real.diagnose import diagnose

    meter = _Meter()
    with _metered(meter):
        wall0, cpu0 = time.perf_counter(), time.process_time()
        result = diagnose(bag, vehicle)
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    if out is not None:
        Path(out).write_text(json.dumps(result.to_dict(), indent=1, sort_keys=True) + "\n")
    a = result.attribution
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "evaluations": meter.calls.get("residuals", 0),
        "eval_cpu_s": meter.cpu.get("residuals", 0.0),
        "replays": meter.calls.get("replay_imu", 0),
        "replay_cpu_s": meter.cpu.get("replay_imu", 0.0),
        "stages": {k: v for k, v in meter.cpu.items() if k not in ("residuals", "replay_imu")},
        "fits": 1 + len(a.ranking) + len(a.pairs),
        "samples": a.train_samples + a.test_samples,
        "verdict": a.verdict,
    }


def _warm_and_diagnose(bag: str, vehicle: str, warm: str | None, out: str | None) -> dict[str, Any]:
    """The row of one bag after an untimed warm-up diagnosis of ``warm`` (none: no warm-up)."""
    if warm is not None:  # untimed: numba caches, lazy imports, first-call costs
        from terrain_analysis.sim2real.diagnose import diagnose
        from terrain_analysis.sim2real.fitting import AttributionSettings

        # Every stage and every candidate's replay once, with almost no optimising (a tenth of the cost).
        light = AttributionSettings(max_nfev=2, grid_points=0, max_starts=1, cross_fit=0, stability_regimes=0)
        with contextlib.suppress(Exception):  # a warm-up that fails still warmed what it ran
            diagnose(warm, vehicle, settings=light)
    return _diagnose_metered(bag, vehicle, out)


def _in_fresh_process(bag: Path, vehicle: str, warm: Path | None, out: Path | None) -> dict[str, Any]:
    args = (str(bag), vehicle, None if warm is None else str(warm), None if out is None else str(out))
    return run_in_fresh_process(_warm_and_diagnose, args, error_key="skipped", what="diagnosing")


def bench_diagnosis_scaling(
    cfg: BenchConfig,
    *,
    seconds: Sequence[float] = SCALING_SECONDS,
    vehicles: Sequence[str] | None = None,
    keep: Path | None = None,
    warm: bool = True,
) -> list[dict[str, Any]]:
    """CPU of ``diagnose()`` per bag second for bags of ``seconds`` length, per vehicle (see the module doc).

    ``keep``: a directory that receives the bags and each diagnosis's JSON (else a temporary one); bags
    already there are reused. ``warm``: diagnose the shortest bag once, untimed, in each process first.
    """
    from terrain_analysis.sim2real.diagnose import supported_vehicles
    from vehicle_sim.tools.simulate import record

    lengths = tuple(sorted(float(s) for s in seconds))
    if cfg.drive_s < 10.0:  # --quick: a tenth of the lengths
        lengths = tuple(s / 10.0 for s in lengths)
    cases = [c for c in SIM2REAL_CASES if vehicles is None or c[0] in vehicles]
    rows: list[dict[str, Any]] = []
    with contextlib.ExitStack() as stack:
        if keep is not None:
            root = keep_directory(keep)
        else:
            root = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="scaling_")))
        for vehicle, overrides in cases:
            if vehicle not in supported_vehicles():
                rows.append({"vehicle": vehicle, "skipped": "no replay model installed"})
                continue
            base: dict[str, Any] | None = None
            for length in lengths:
                bag = root / f"{vehicle}_{length:g}s"
                if not bag.exists():
                    record(vehicle, length, bag, overrides={"seed": cfg.seed, **overrides})
                out = root / f"{vehicle}_{length:g}s.json"
                # Warm-up: the shortest bag (numba caches, lazy imports, first calls), untimed.
                first = root / f"{vehicle}_{lengths[0]:g}s"
                row = _in_fresh_process(bag, vehicle, first if warm else None, out)
                row.update(vehicle=vehicle, bag_s=length, effect=_effect(overrides))
                if "skipped" not in row:
                    row["cpu_per_bag_s"] = row["cpu_s"] / length
                    row["cpu_per_eval_ms"] = 1e3 * row["eval_cpu_s"] / max(row["evaluations"], 1)
                    if base is None:
                        base = row
                    row["ratio_to_linear"] = row["cpu_per_bag_s"] / base["cpu_per_bag_s"]
                    row["eval_ratio"] = (row["evaluations"] / base["evaluations"]) if base["evaluations"] else 0.0
                rows.append(row)
                print(f"  … {vehicle} {length:g} s: {row.get('cpu_s', 0.0):.1f} CPU s", file=sys.stderr, flush=True)
    return rows


#: The file that marks a ``--keep`` directory as this benchmark's own (its bags and JSON may be reused, replaced).
KEEP_MARKER = ".bench_sim2real"


def keep_directory(path: Path) -> Path:
    """``path`` as the benchmark's ``--keep`` directory: created with its marker when absent or empty; an existing
    one only when it carries the marker (a directory this benchmark made), since the run reuses the bags in it
    and replaces its JSON files. Raises FileExistsError (nothing written) for any other existing path."""
    if path.exists() and not (path / KEEP_MARKER).is_file() and (not path.is_dir() or any(path.iterdir())):
        raise FileExistsError(
            f"--keep {str(path)!r} exists and was not made by this benchmark (no {KEEP_MARKER}): its files would be "
            "reused as the benchmark's bags or replaced; give a new directory"
        )
    path.mkdir(parents=True, exist_ok=True)
    (path / KEEP_MARKER).touch()
    return path


def format_diagnosis_scaling(rows: list[dict[str, Any]]) -> list[str]:
    """The scaling table: CPU per bag second against the shortest bag's (1.00 = linear)."""
    lines = [
        "Sim-to-real diagnosis cost against bag length (one process per bag, after an untimed warm-up diagnosis)",
        f"  {'vehicle':<12}{'bag s':>6}{'CPU s':>8}{'wall s':>8}{'CPU/bag s':>10}{'×linear':>8}"
        f"{'evals':>7}{'×evals':>7}{'ms/eval':>8}{'eval CPU':>9}{'other':>7}{'fits':>5}{'replays':>8}{'CPU':>6}"
        "  stages (CPU s) → verdict",
    ]
    for r in rows:
        if "skipped" in r:
            lines.append(f"  {r['vehicle']:<12}{r.get('bag_s', 0):>6.0f}  skipped: {r['skipped']}")
            continue
        stages = " ".join(f"{k.split('_')[0][:6]} {v:.1f}" for k, v in r["stages"].items())
        lines.append(
            f"  {r['vehicle']:<12}{r['bag_s']:>6.0f}{r['cpu_s']:>8.1f}{r['wall_s']:>8.1f}{r['cpu_per_bag_s']:>10.3f}"
            f"{r['ratio_to_linear']:>8.2f}{r['evaluations']:>7d}{r['eval_ratio']:>7.2f}{r['cpu_per_eval_ms']:>8.1f}"
            f"{r['eval_cpu_s']:>9.1f}{r['cpu_s'] - r['eval_cpu_s']:>7.1f}{r['fits']:>5d}{r.get('replays', 0):>8d}"
            f"{r.get('replay_cpu_s', 0.0):>6.1f}  {stages} → "
            f"{r['verdict'][:60]}"
        )
    return lines


@cli_main("bench_sim2real")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="bench_sim2real", description="Diagnosis cost against bag length, per vehicle (issue 22/23)."
    )
    parser.add_argument("--quick", action="store_true", help="short smoke run (a tenth of the lengths, quarter car)")
    parser.add_argument("--seconds", type=float, nargs="+", default=list(SCALING_SECONDS), help="bag lengths (s)")
    parser.add_argument("--vehicles", nargs="+", default=None, help="vehicles (default: all four)")
    parser.add_argument("--keep", metavar="DIR", help="keep the bags and each diagnosis's JSON here (reused)")
    parser.add_argument("--no-warm", action="store_true", help="no untimed warm-up diagnosis per process")
    add_json_arguments(parser)
    args = parse_bench_arguments(parser, argv)
    cfg = BenchConfig.quick() if args.quick else BenchConfig()
    vehicles = args.vehicles if not args.quick else (args.vehicles or ["quarter_car"])
    rows = bench_diagnosis_scaling(
        cfg,
        seconds=args.seconds,
        vehicles=vehicles,
        keep=Path(args.keep) if args.keep else None,
        warm=not args.no_warm,
    )
    print("\n".join(format_diagnosis_scaling(rows)))
    if args.json:
        write_json(args.json, {"machine": machine_info(), "diagnosis_scaling": rows}, overwrite=args.overwrite)
    return 0


if __name__ == "__main__":
    sys.exit(main())
