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
7. **Quarter-car Monte Carlo** (``--only qc_monte_carlo``; issue 23's "the 100-run Monte Carlo with
   every filter in 60 s or less on 2 cores"): the 100 runs of case 1 of ``make reproduce-qc``
   (:func:`terrain_analysis.tools.reproduce_qc.build_plan`: Graneville loam, ISO D, 10 m/s, 12 s; every
   filter the case runs: SCKF, EKF, both with the printed ``Q_k``, and the SCKF with the ln k_s state) on
   a pool of 2 worker processes, twice in one run: before (the EKF through its public numpy
   ``predict``/``update``, as before the compiled EKF step; the SCKF compiled as before) and after (both
   compiled, the default). Wall time, CPU time of the workers, and the largest difference between the
   two runs' k_s errors (the same rides, the same filters to rounding).
8. **Machine**: CPU count and load average (other processes on the CPUs
   preempt long steps first, so a p90 far above the median usually means a
   busy machine), Python, numpy, ``OPENBLAS_NUM_THREADS`` (``make`` sets it to
   1; a threaded BLAS only adds stalls on these 5 × 5 matrices).

Nothing here asserts a time: the figures depend on the machine. ``--quick``
is a short smoke run (a few hundred steps, 2 s drives, one repetition);
``--json PATH`` also writes every figure.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from terrain_estimation.cli import cli_main

__all__ = [
    "ROW_LABELS",
    "SKID_ROW_LABELS",
    "ROVER_ROW_LABELS",
    "SIM2REAL_CASES",
    "BenchConfig",
    "bench_qc_monte_carlo",
    "format_qc_monte_carlo",
    "main",
    "run_bench",
    "format_report",
]

DT = 0.01  # filter step (s): 100 Hz, the estimator's rate
SUBSTEPS = 10  # 1 kHz road sub-steps per step (MODELS.md A.10)
BAGS_DIR = Path(__file__).resolve().parents[4] / "bags"  # the repository's bags/
BAGS: tuple[tuple[str, str], ...] = (
    ("quarter_car_graneville_iso_d_10ms", "quarter_car"),
    ("lrv_regolith_iso_g_2ms", "lrv"),
)
OUR_FILTERS: tuple[tuple[str, str], ...] = (("SCKF", "sckf"), ("CKF", "ckf"), ("UKF", "ukf"), ("EKF", "ekf"))
#: The compiled steps the estimator node runs for its default SCKF and for the EKF (same model, same data).
COMPILED_FILTERS: tuple[tuple[str, str], ...] = (("SCKF compiled step", "sckf"), ("EKF compiled step", "ekf"))
FILTERPY_LABEL = "filterpy UKF (Merwe)"

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

SKID_FILTERS: tuple[tuple[str, str], ...] = (("UKF", "ukf"), ("STUKF", "stukf"), ("AN-STUKF", "an_stukf"))
SKID_MANOEUVRE = "small_radius_turn"  # the paper's Table 2 manoeuvre: the tire model works hardest

#: Row labels of the skid-steer section (filter step, estimator throughput, simulator).
SKID_ROW_LABELS: tuple[str, ...] = (
    *(f"skid {label}" for label, _ in SKID_FILTERS),
    *(f"core skid_steer {name}" for _, name in SKID_FILTERS),
    "simulate skid_steer",
)

ROVER_VARIANTS: tuple[tuple[str, int], ...] = (("E1+E2", 2), ("E1+E3", 1))
ROVER_TERRAIN = "rolling"  # Fig. 10 terrain 1
ROVER_TERRAMECHANICS: tuple[str, ...] = ("surrogate", "wong_reece")

#: Row labels of the rover section (filter steps, estimator throughput, simulator).
ROVER_ROW_LABELS: tuple[str, ...] = (
    "rover E1",
    "rover E2",
    "rover E3",
    *(f"core rover {label}" for label, _ in ROVER_VARIANTS),
    *(f"simulate rover {name}" for name in ROVER_TERRAMECHANICS),
)


#: Sim-to-real diagnosis cases: (vehicle, simulator overrides of the withheld effect). Issue 6: a
#: 60 s bag must be diagnosed in under a minute on 2 cores.
SIM2REAL_CASES: tuple[tuple[str, dict[str, Any]], ...] = (
    ("quarter_car", {"effects.tire_contact_length": 0.2}),
    ("lrv", {"effects.sprung_mass_change": 0.2, "scenario.soils": ["lunar_regolith"], "scenario.speed": 2.0}),
    ("skid_steer", {"effects.gyro_bias": 0.01}),
    ("rover", {"effects.load_cell_bias": [0.0, 0.0, 3.0]}),
)
SIM2REAL_SECONDS = 60.0


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """How much to measure.

    Attributes:
        steps: timed filter steps per filter (after the warm-up).
        warmup: untimed filter steps first (caches, branch predictors, lazy imports).
        drive_s: simulated drive (s) of the core and simulator rows.
        repeats: timed repetitions of each bag run (the median is reported).
        seed: seed of the simulated drives.
    """

    steps: int = 2000
    warmup: int = 200
    drive_s: float = 10.0
    repeats: int = 3
    seed: int = 12

    @classmethod
    def quick(cls) -> BenchConfig:
        return cls(steps=200, warmup=20, drive_s=2.0, repeats=1)


# ---------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------


def machine_info() -> dict[str, Any]:
    """CPU count, platform, Python, numpy and BLAS thread settings."""
    load: float | None
    try:
        load = os.getloadavg()[0]  # other processes share the CPUs: p90s grow with it
    except (AttributeError, OSError):  # not on every platform
        load = None
    return {
        "cpu_count": os.cpu_count(),
        "load_avg_1min": load,
        "platform": f"{platform.system()} {platform.machine()}",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "unset"),
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "unset"),
    }


def _percentiles_us(samples_ns: Sequence[int]) -> tuple[float, float]:
    arr = np.asarray(samples_ns, dtype=float) * 1e-3
    return float(np.median(arr)), float(np.percentile(arr, 90))


def _deep_bytes(obj: Any) -> int:
    """Bytes of an object, its ``__dict__``/dataclass fields and the numpy arrays it holds (one level)."""
    total = sys.getsizeof(obj)
    if dataclasses.is_dataclass(obj):
        values = [getattr(obj, f.name) for f in dataclasses.fields(obj)]
    else:
        d = getattr(obj, "__dict__", {})
        total += sys.getsizeof(d)
        values = list(d.values())
    for v in values:
        if isinstance(v, np.ndarray):
            total += sys.getsizeof(v) + (v.nbytes if v.base is not None else 0)
        elif dataclasses.is_dataclass(v) or hasattr(v, "__dict__"):
            if isinstance(v, type) or callable(v):
                continue
            for a in getattr(v, "__dict__", {}).values():
                if isinstance(a, np.ndarray):
                    total += sys.getsizeof(a) + (a.nbytes if a.base is not None else 0)
    return total


def _drive_quarter_car(duration: float, seed: int) -> Any:
    """The quarter-car bag's world (Graneville loam, ISO D seed 11, 10 m/s), simulated."""
    from vehicle_sim.plants.quarter_car import QuarterCarVehicle, Scenario, SpeedProfile, simulate
    from vehicle_sim.terrain.profiles import iso8608_profile
    from vehicle_sim.terrain.soils import GRANEVILLE_LOAM, SoilPath

    scenario = Scenario(
        profile=iso8608_profile("D", 11), soil_path=SoilPath(GRANEVILLE_LOAM), speed=SpeedProfile.constant(10.0)
    )
    return simulate(QuarterCarVehicle(), scenario, duration, seed)


def _drive_lrv(duration: float, seed: int) -> Any:
    """The LRV bag's world (lunar regolith, ISO G seed 21, 2 m/s), simulated."""
    from vehicle_sim.plants.quarter_car import LRVVehicle, Scenario, SpeedProfile, simulate
    from vehicle_sim.terrain.profiles import iso8608_profile
    from vehicle_sim.terrain.soils import LUNAR_REGOLITH, SoilPath

    scenario = Scenario(
        profile=iso8608_profile("G", 21), soil_path=SoilPath(LUNAR_REGOLITH), speed=SpeedProfile.constant(2.0)
    )
    return simulate(LRVVehicle(), scenario, duration, seed)


# ---------------------------------------------------------------------------
# 1. Filter step
# ---------------------------------------------------------------------------


def _filter_data(n_steps: int, seed: int) -> tuple[Any, Any, Any]:
    """Sub-step inputs ``(n_steps, 10)`` (m/s), measurements ``(n_steps, 2)`` (m/s², gravity removed)
    and the simulation result, from a quarter-car drive of ``n_steps`` filter steps."""
    from terrain_analysis.pcrlb import quarter_car_truth

    result = _drive_quarter_car(n_steps * DT, seed)
    _, inputs = quarter_car_truth(result, SUBSTEPS / DT)
    assert result.wheel_accel_z is not None
    z = np.column_stack([result.body_accel_z, result.wheel_accel_z]) - result.scenario.gravity
    return inputs, z, result


def bench_filters(cfg: BenchConfig) -> list[dict[str, Any]]:
    """Per-step (predict + update) time of our four filters and of filterpy's UKF."""
    try:
        from filterpy.kalman import MerweScaledSigmaPoints
        from filterpy.kalman import UnscentedKalmanFilter as FilterpyUKF
    except ImportError as exc:  # a development dependency, not a run-time one
        raise RuntimeError("the filter benchmark compares with filterpy: pip install -r requirements-dev.txt") from exc

    from terrain_estimation.estimators.soil_stiffness import make_filter
    from terrain_estimation.models.quarter_car import QuarterCarModel

    n = cfg.warmup + cfg.steps
    inputs, z, _ = _filter_data(n, cfg.seed)
    model = QuarterCarModel()
    x0 = np.array([0.0, 0.0, 0.0, 0.0, 0.5 * model.k_series])  # "half the tire stiffness" (A.5)
    P0 = np.diag([1e-4, 1e-2, 1e-4, 1e-2, 50e3**2])  # noqa: N806 - the estimator's default P0

    rows: list[dict[str, Any]] = []
    final_ktot: dict[str, float] = {}
    for label, name in OUR_FILTERS:
        filt = make_filter(name)
        state = filt.initial_state(x0, P0)
        times: list[int] = []
        for k in range(n):
            u = inputs[k]
            t0 = time.perf_counter_ns()
            state = filt.predict(state, model, u, DT)
            state, _ = filt.update(state, z[k], model, u)
            t1 = time.perf_counter_ns()
            if k >= cfg.warmup:
                times.append(t1 - t0)
        med, p90 = _percentiles_us(times)
        final_ktot[name] = float(state.x[-1])
        rows.append(
            {"filter": label, "median_us": med, "p90_us": p90, "steps": len(times), "state_bytes": _deep_bytes(state)}
        )

    # The compiled steps of the estimator (what the node runs): the same filters, model and data.
    from terrain_estimation.estimators.soil_stiffness_ekf import run_ekf_step, warm_up_ekf
    from terrain_estimation.estimators.soil_stiffness_kernels import model_operands
    from terrain_estimation.estimators.soil_stiffness_sckf import run_step, warm_up

    warm_up()
    warm_up_ekf()
    ops = model_operands(model)
    assert ops is not None
    no_profile_noise = np.zeros((2, 2))
    for label, name in COMPILED_FILTERS:
        filt = make_filter(name)
        state = filt.initial_state(x0, P0)
        run = run_step if name == "sckf" else run_ekf_step
        x, fac = state.x, (state.S if name == "sckf" else state.P)
        times = []
        for k in range(n):
            t0 = time.perf_counter_ns()
            _, _, _, _, _, x, fac = run(ops, model, x, fac, inputs[k], DT, z[k], no_profile_noise, False, None)
            t1 = time.perf_counter_ns()
            if k >= cfg.warmup:
                times.append(t1 - t0)
        med, p90 = _percentiles_us(times)
        final = dataclasses.replace(state, x=x, **({"S": fac} if name == "sckf" else {"P": fac}))
        rows.append(
            {
                "filter": label,
                "median_us": med,
                "p90_us": p90,
                "steps": len(times),
                "state_bytes": _deep_bytes(final),
                # The compiled step is the filter's public predict/update to rounding.
                "final_ktot_diff_vs_numpy_N_per_m": abs(float(x[-1]) - final_ktot[name]),
            }
        )

    # filterpy: same model, same data; fx/hx see one sigma point (n,) at a time.
    def fx(x: Any, dt: float, u: Any) -> Any:
        return model.f(x, u, dt)

    def hx(x: Any, u: Any) -> Any:
        return model.h(x, u)

    points = MerweScaledSigmaPoints(5, alpha=1.0, beta=2.0, kappa=0.0)  # = our UKF's defaults
    ukf = FilterpyUKF(dim_x=5, dim_z=2, dt=DT, hx=hx, fx=fx, points=points)
    ukf.x = x0.copy()
    ukf.P = P0.copy()
    Lr = model.measurement_noise_sqrt()  # noqa: N806
    ukf.R = Lr @ Lr.T
    times = []
    for k in range(n):
        u = inputs[k]
        t0 = time.perf_counter_ns()
        # Q_k at the prior mean, as our filters take it (process_noise_sqrt).
        Lq = model.process_noise_sqrt(ukf.x, u, DT)  # noqa: N806
        ukf.Q = Lq @ Lq.T
        ukf.predict(u=u)
        ukf.update(z[k], u=u)
        t1 = time.perf_counter_ns()
        if k >= cfg.warmup:
            times.append(t1 - t0)
    med, p90 = _percentiles_us(times)
    ours = next(r for r in rows if r["filter"] == "UKF")
    rows.append(
        {
            "filter": FILTERPY_LABEL,
            "median_us": med,
            "p90_us": p90,
            "steps": len(times),
            "state_bytes": _deep_bytes(ukf),
            # Same model, same sigma points: the estimates must agree (a check
            # that the comparison is like for like).
            "final_ktot_diff_vs_ours_N_per_m": abs(float(ukf.x[-1]) - final_ktot["ukf"]),
        }
    )
    for r in rows:
        r["ratio_to_our_ukf"] = r["median_us"] / ours["median_us"]
    return rows


# ---------------------------------------------------------------------------
# 2. Estimator throughput
# ---------------------------------------------------------------------------


def _bag_duration_s(path: Path) -> tuple[float, int]:
    """(last − first log stamp (s), message count) of a bag."""
    from terrain_estimation.bag import read_bag

    first = last = None
    count = 0
    for item in read_bag(path):
        first = item.log_time_ns if first is None else min(first, item.log_time_ns)
        last = item.log_time_ns if last is None else max(last, item.log_time_ns)
        count += 1
    if first is None or last is None:
        return 0.0, 0
    return (last - first) * 1e-9, count


def bench_bag(path: Path, vehicle: str, repeats: int) -> dict[str, Any]:
    """``estimate_bag`` wall time over the bag (median of ``repeats`` after one untimed run)."""
    from terrain_estimation.tools.estimate import estimate_bag

    duration, messages = _bag_duration_s(path)
    run = estimate_bag(path, vehicle)  # untimed: imports, typestore, caches
    walls = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        run = estimate_bag(path, vehicle)
        walls.append(time.perf_counter() - t0)
    wall = float(np.median(walls))
    steps = len(run.outputs)
    return {
        "row": f"bag {path.name}",
        "vehicle": vehicle,
        "sim_s": duration,
        "wall_s": wall,
        "x_real_time": duration / wall if wall > 0 else math.inf,
        "steps": steps,
        "us_per_step": 1e6 * wall / steps if steps else math.nan,
        "messages": messages,
    }


class _TimedFilter:
    """Delegates to a filter and accumulates the time spent in predict and update."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.ns = 0
        self.steps = 0

    def initial_state(self, x0: Any, P0: Any) -> Any:  # noqa: N803
        return self.inner.initial_state(x0, P0)

    def predict(self, *args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter_ns()
        try:
            return self.inner.predict(*args, **kwargs)
        finally:
            self.ns += time.perf_counter_ns() - t0
            self.steps += 1

    def update(self, *args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter_ns()
        try:
            return self.inner.update(*args, **kwargs)
        finally:
            self.ns += time.perf_counter_ns() - t0


class _TimedCompiledStep:
    """Wraps an estimator's compiled filter step (``_compiled_step``: the SCKF or EKF) and accumulates its time.

    Installed on the estimator instance, so that the estimator runs exactly the
    path it runs in the node (the compiled step), with the filter's share
    measured around it.
    """

    def __init__(self, est: Any, name: str) -> None:
        self.inner = getattr(est, name)
        self.ns = 0
        self.steps = 0
        setattr(est, name, self)

    def __call__(self, *args: Any) -> Any:
        t0 = time.perf_counter_ns()
        try:
            return self.inner(*args)
        finally:
            self.ns += time.perf_counter_ns() - t0
            self.steps += 1


def bench_core(vehicle: str, result: Any, numpy_path: bool = False) -> dict[str, Any]:
    """The ROS-free estimator core fed a simulator run in the bag's order (profile, then IMU).

    ``numpy_path`` False: the estimator the node builds (its configuration, the compiled SCKF / EKF step), the
    step's time measured around the compiled call. True: the same configuration through the filter's public numpy
    ``predict``/``update`` (``filter_impl``), timed by a proxy around them: the reference path, not what runs.
    """
    from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimator, make_filter
    from terrain_estimation.ros.soil_stiffness import estimator_config
    from terrain_estimation.vehicles import estimator_parameters, get_vehicle

    config = estimator_config(estimator_parameters(get_vehicle(vehicle)))  # as the bag run
    timed: Any
    if numpy_path:
        timed = _TimedFilter(make_filter(config.filter))
        est = SoilStiffnessEstimator(config, filter_impl=timed)
    else:
        est = SoilStiffnessEstimator(config)
        compiled_step = "_compiled_step" if est._sckf is not None or est._ekf is not None else None
        if compiled_step is None:  # e.g. an "expm" configuration: the node runs the public methods too
            est = SoilStiffnessEstimator(config, filter_impl=_TimedFilter(est.filter))
            timed = est.filter
        else:
            timed = _TimedCompiledStep(est, compiled_step)
    # Plain Python lists: the loop below should time the estimator, not numpy indexing.
    pt, ps, ph = (a.tolist() for a in (result.profile.t, result.profile.distance, result.profile.elevation))
    ta = result.t.tolist()
    fb = result.body_accel_z.tolist()
    fw = result.wheel_accel_z.tolist() if result.wheel_accel_z is not None else [None] * len(ta)
    j = 0
    t0 = time.perf_counter()
    for i, t in enumerate(ta):
        while j < len(pt) and pt[j] <= t + 1e-9:
            est.add_profile_sample(pt[j], ps[j], ph[j])
            j += 1
        est.add_accelerations(t, fb[i], fw[i])
    wall = time.perf_counter() - t0
    steps = est.counters.steps
    duration = float(result.t[-1])
    return {
        "row": f"core {vehicle}" + (" numpy path" if numpy_path else ""),
        "vehicle": vehicle,
        "path": "numpy" if numpy_path else ("compiled" if isinstance(timed, _TimedCompiledStep) else "numpy"),
        "filter": config.filter,
        "sim_s": duration,
        "wall_s": wall,
        "x_real_time": duration / wall if wall > 0 else math.inf,
        "steps": steps,
        "us_per_step": 1e6 * wall / steps if steps else math.nan,
        "filter_us_per_step": 1e-3 * timed.ns / timed.steps if timed.steps else math.nan,
        "filter_share": 1e-9 * timed.ns / wall if wall > 0 else math.nan,
    }


# ---------------------------------------------------------------------------
# 3. Simulator
# ---------------------------------------------------------------------------


def bench_simulator(vehicle: str, drive: Callable[[float, int], Any], cfg: BenchConfig) -> tuple[dict[str, Any], Any]:
    """``simulate()`` wall time for ``cfg.drive_s``; also returns the run (it feeds the core row)."""
    drive(0.1, cfg.seed)  # untimed: profile caches, imports
    t0 = time.perf_counter()
    result = drive(cfg.drive_s, cfg.seed)
    wall = time.perf_counter() - t0
    row = {
        "row": f"simulate {vehicle}",
        "vehicle": vehicle,
        "sim_s": cfg.drive_s,
        "wall_s": wall,
        "x_real_time": cfg.drive_s / wall if wall > 0 else math.inf,
        "steps": int(result.t.size),
        "us_per_step": 1e6 * wall / result.t.size,
    }
    return row, result


# ---------------------------------------------------------------------------
# 4. Skid steer
# ---------------------------------------------------------------------------


class _TimedStep:
    """Delegates to an ``AdaptiveStrongTrackingUKF`` and records the time of every ``step``."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.ns: list[int] = []

    def initial_state(self, x0: Any, P0: Any) -> Any:  # noqa: N803
        return self.inner.initial_state(x0, P0)

    def step(self, *args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter_ns()
        try:
            return self.inner.step(*args, **kwargs)
        finally:
            self.ns.append(time.perf_counter_ns() - t0)


def _drive_skid(duration: float, seed: int) -> Any:
    """The paper's small-radius turn (truth effects on), simulated for ``duration`` s."""
    from vehicle_sim.plants.skid_steer import MANOEUVRES, simulate_skid_steer

    return simulate_skid_steer(MANOEUVRES[SKID_MANOEUVRE](duration=duration), seed)


def bench_skid(cfg: BenchConfig) -> dict[str, Any]:
    """UKF / STUKF / AN-STUKF per-step time and estimator throughput on one simulated turn, and the simulator."""
    from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig

    # Enough samples for the warm-up and the timed steps (the first sample only initialises).
    duration = max(cfg.drive_s, (cfg.warmup + cfg.steps + 1) * DT)
    _drive_skid(0.1, cfg.seed)  # untimed: imports, caches
    t0 = time.perf_counter()
    result = _drive_skid(duration, cfg.seed)
    sim_wall = time.perf_counter() - t0
    simulator = {
        "row": "simulate skid_steer",
        "vehicle": "skid_steer",
        "sim_s": duration,
        "wall_s": sim_wall,
        "x_real_time": duration / sim_wall if sim_wall > 0 else math.inf,
        "steps": int(result.t.size),
        "us_per_step": 1e6 * sim_wall / result.t.size,
    }
    # The same samples for every filter, as plain lists (time the estimator, not numpy indexing).
    ts = result.t.tolist()
    motor = result.motor_velocity.tolist()
    accel = result.linear_acceleration.tolist()
    gyro = result.angular_velocity.tolist()
    filters: list[dict[str, Any]] = []
    throughput: list[dict[str, Any]] = []
    for label, name in SKID_FILTERS:
        est = SkidSteerEstimator(SkidSteerEstimatorConfig.paper(filter=name))
        timed = _TimedStep(est.filter)
        est.filter = timed  # type: ignore[assignment]
        start = time.perf_counter()
        for i, t in enumerate(ts):
            est.add_joint_state(t, motor[i][0], motor[i][1])
            est.add_imu(t, accel[i][0], accel[i][1], gyro[i][2])
            est.drain_estimates()
        wall = time.perf_counter() - start
        counters = est.counters
        timed_ns = timed.ns[cfg.warmup : cfg.warmup + cfg.steps]
        med, p90 = _percentiles_us(timed_ns)
        filters.append(
            {
                "filter": f"skid {label}",
                "variant": name,
                "median_us": med,
                "p90_us": p90,
                "steps": len(timed_ns),
                "strong_tracking_active": counters.strong_tracking_active,
                "recoveries": counters.recoveries,
            }
        )
        throughput.append(
            {
                "row": f"core skid_steer {name}",
                "vehicle": "skid_steer",
                "sim_s": duration,
                "wall_s": wall,
                "x_real_time": duration / wall if wall > 0 else math.inf,
                "steps": counters.steps,
                "us_per_step": 1e6 * wall / counters.steps if counters.steps else math.nan,
                "filter_us_per_step": 1e-3 * sum(timed.ns) / len(timed.ns) if timed.ns else math.nan,
                "filter_share": 1e-9 * sum(timed.ns) / wall if wall > 0 else math.nan,
            }
        )
    ukf = filters[0]["median_us"]
    for r in filters:
        r["ratio_to_ukf"] = r["median_us"] / ukf
    return {
        "manoeuvre": SKID_MANOEUVRE,
        "duration_s": duration,
        "filters": filters,
        "throughput": throughput,
        "simulator": [simulator],
    }


# ---------------------------------------------------------------------------
# 5. Rocker-bogie rover
# ---------------------------------------------------------------------------


class _TimedRoverFilter:
    """Delegates to the UKF both rover estimators share; times each call, keyed by the model it runs."""

    def __init__(self, inner: Any, general_model: Any) -> None:
        self.inner = inner
        self.general_model = general_model
        self.ns: dict[str, list[int]] = {"general": [], "wheel_force": []}
        self._pending: dict[str, int] = {"general": 0, "wheel_force": 0}

    def initial_state(self, x0: Any, P0: Any) -> Any:  # noqa: N803
        return self.inner.initial_state(x0, P0)

    def _key(self, model: Any) -> str:
        return "general" if model is self.general_model else "wheel_force"

    def predict(self, state: Any, model: Any, *args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter_ns()
        try:
            return self.inner.predict(state, model, *args, **kwargs)
        finally:
            self._pending[self._key(model)] = time.perf_counter_ns() - t0

    def update(self, state: Any, y: Any, model: Any, *args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter_ns()
        key = self._key(model)
        try:
            return self.inner.update(state, y, model, *args, **kwargs)
        finally:
            # One step of an estimator = its predict + its update.
            self.ns[key].append(self._pending[key] + time.perf_counter_ns() - t0)
            self._pending[key] = 0


def _drive_rover(duration: float, seed: int, terramechanics: str = "surrogate") -> Any:
    """Kapvik over Fig. 10's terrain 1 for ``duration`` s (Table IV sensor noise)."""
    from vehicle_sim.plants.rover import RoverScenario, simulate_rover

    return simulate_rover(
        RoverScenario(terrain=ROVER_TERRAIN, duration=duration, seed=seed, terramechanics=terramechanics)  # type: ignore[arg-type]
    )


def bench_rover(cfg: BenchConfig) -> dict[str, Any]:
    """Estimator 1 and 2/3 per-step time, estimator throughput and simulator speed of the rocker-bogie rover."""
    from terrain_estimation.estimators.rover import RoverEstimatorConfig, RoverTerrainEstimator
    from vehicle_sim.terrain.terramechanics_surrogate import terramechanics_surrogate

    terramechanics_surrogate()  # untimed: the surrogate's one-off fit
    simulator: list[dict[str, Any]] = []
    run = None
    for name in ROVER_TERRAMECHANICS:
        _drive_rover(0.1, cfg.seed, name)  # untimed: imports, caches
        t0 = time.perf_counter()
        result = _drive_rover(cfg.drive_s, cfg.seed, name)
        wall = time.perf_counter() - t0
        simulator.append(
            {
                "row": f"simulate rover {name}",
                "vehicle": "rover",
                "sim_s": cfg.drive_s,
                "wall_s": wall,
                "x_real_time": cfg.drive_s / wall if wall > 0 else math.inf,
                "steps": int(result.time.size),
                "us_per_step": 1e6 * wall / result.time.size,
            }
        )
        if name == "surrogate":
            run = result
    assert run is not None
    # The same samples for every variant, as plain lists (time the estimator, not numpy indexing).
    s = run.sensors
    ts = run.time.tolist()
    acc, rate, bogie = s.acceleration.tolist(), s.pitch_rate.tolist(), s.bogie_angle.tolist()
    wheel, effort, speed = s.wheel_angle.tolist(), s.effort.tolist(), s.forward_velocity.tolist()
    axial, perp = s.load_axial.tolist(), s.load_perpendicular.tolist()
    warmup = min(5, max(0, len(ts) // 100))  # first steps of each repetition: caches, lazy imports
    filters: dict[str, list[int]] = {"E1": [], "E2": [], "E3": []}
    throughput: list[dict[str, Any]] = []
    for label, axes in ROVER_VARIANTS:
        walls, filter_ns, steps = [], 0, 0
        for _ in range(max(1, cfg.repeats)):
            est = RoverTerrainEstimator(RoverEstimatorConfig(load_cell_axes=axes))
            timed = _TimedRoverFilter(est.filter, est.general_model)
            est.filter = timed  # type: ignore[assignment]
            start = time.perf_counter()
            for k, t in enumerate(ts):
                est.add_imu(t, acc[k][0], acc[k][1], rate[k])
                est.add_joint_state(t, bogie[k], wheel[k], effort[k])
                est.add_velocimeter(t, speed[k])
                est.add_load_cells(t, axial[k], perp[k] if axes == 2 else None)
                est.drain_estimates()
            walls.append(time.perf_counter() - start)
            steps = est.counters.steps + est.counters.initialisations
            filter_ns += sum(timed.ns["general"]) + sum(timed.ns["wheel_force"])
            if axes == 2:
                filters["E1"] += timed.ns["general"][warmup:]
            filters["E2" if axes == 2 else "E3"] += timed.ns["wheel_force"][warmup:]
        wall = float(np.median(walls))
        total_wall = float(np.sum(walls))
        throughput.append(
            {
                "row": f"core rover {label}",
                "vehicle": "rover",
                "sim_s": cfg.drive_s,
                "wall_s": wall,
                "x_real_time": cfg.drive_s / wall if wall > 0 else math.inf,
                "steps": steps,
                "us_per_step": 1e6 * wall / steps if steps else math.nan,
                "filter_us_per_step": 1e-3 * filter_ns / (steps * len(walls)) if steps else math.nan,
                "filter_share": 1e-9 * filter_ns / total_wall if total_wall > 0 else math.nan,
            }
        )
    states = {
        "E1": "UKF, 22 states, 11 measurements",
        "E2": "UKF, 9 states, two-axis cells",
        "E3": "UKF, 9 states, single-axis cells",
    }
    rows: list[dict[str, Any]] = []
    for name, ns in filters.items():
        med, p90 = _percentiles_us(ns) if ns else (math.nan, math.nan)
        rows.append(
            {"filter": f"rover {name}", "model": states[name], "median_us": med, "p90_us": p90, "steps": len(ns)}
        )
    e1 = float(rows[0]["median_us"])
    for r in rows:
        r["ratio_to_e1"] = float(r["median_us"]) / e1 if e1 > 0.0 and math.isfinite(e1) else math.nan
    return {
        "terrain": ROVER_TERRAIN,
        "duration_s": cfg.drive_s,
        "filters": rows,
        "throughput": throughput,
        "simulator": simulator,
    }


# ---------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------


def run_bench(cfg: BenchConfig, bags_dir: Path = BAGS_DIR) -> dict[str, Any]:
    """Every figure of the report, as a JSON-able dict."""
    out: dict[str, Any] = {"machine": machine_info(), "config": dataclasses.asdict(cfg)}
    out["filters"] = bench_filters(cfg)
    sim_qc, run_qc = bench_simulator("quarter_car", _drive_quarter_car, cfg)
    sim_lrv, run_lrv = bench_simulator("lrv", _drive_lrv, cfg)
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


def bench_sim2real(cfg: BenchConfig) -> list[dict[str, Any]]:
    """Wall and CPU time of ``diagnose()`` on a simulated bag with one withheld effect, per vehicle."""
    import tempfile

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
                    "effect": ", ".join(f"{k}={v}" for k, v in overrides.items() if k.startswith("effects.")),
                    "wall_s": wall,
                    "cpu_s": cpu,
                    "candidates": len(a.ranking),
                    "pairs": len(a.pairs),
                    "verdict": a.verdict,
                }
            )
    return rows


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
        f"Filter step (predict + update), QuarterCarModel n=5 p=2, {SUBSTEPS} road sub-steps per {DT * 1e3:.0f} ms "
        f"step, {cfg['steps']} steps after {cfg['warmup']} warm-up",
        f"  {'filter':<22}{'median µs':>11}{'p90 µs':>10}{'× our UKF':>11}{'state bytes':>13}",
    ]
    for r in figures["filters"]:
        lines.append(
            f"  {r['filter']:<22}{r['median_us']:>11.1f}{r['p90_us']:>10.1f}{r['ratio_to_our_ukf']:>11.2f}"
            f"{r['state_bytes']:>13d}"
        )
    compiled_rows = [r for r in figures["filters"] if "final_ktot_diff_vs_numpy_N_per_m" in r]
    lines.append(
        "  (compiled step = what the estimator node runs for the SCKF / EKF; final k_tot differs from the numpy "
        "filter's by " + ", ".join(f"{r['final_ktot_diff_vs_numpy_N_per_m']:.3g}" for r in compiled_rows) + " N/m)"
    )
    fp = next(r for r in figures["filters"] if r["filter"] == FILTERPY_LABEL)
    lines.append(
        f"  (filterpy runs the same model and sigma points: final k_tot differs from our UKF by "
        f"{fp['final_ktot_diff_vs_ours_N_per_m']:.3g} N/m; state bytes: ours = the state value, "
        "filterpy = the filter object)"
    )
    lines += [
        "",
        "Estimator throughput (× real time = simulated or recorded seconds per wall second)",
        f"  {'what':<44}{'sim s':>7}{'wall s':>9}{'× real time':>13}{'µs/step':>10}{'filter µs/step':>16}",
    ]
    for r in figures["throughput"]:
        filt = f"{r['filter_us_per_step']:.0f} ({100 * r['filter_share']:.0f} %)" if "filter_us_per_step" in r else "-"
        lines.append(
            f"  {r['row']:<44}{r['sim_s']:>7.2f}{r['wall_s']:>9.3f}{r['x_real_time']:>13.1f}"
            f"{r['us_per_step']:>10.0f}{filt:>16}"
        )
    lines.append(
        "  (bag = read + deserialise + adapter + estimator; core = estimator alone, same config, the node's path "
        "(compiled filter step); core … numpy path = the same through the filter's public numpy predict/update, "
        "the reference, not what runs; filter = the filter step inside it)"
    )
    lines += [
        "",
        "Simulator (vehicle_sim simulate(), RK4 at 1 ms, 1 kHz profile)",
        f"  {'what':<44}{'sim s':>7}{'wall s':>9}{'× real time':>13}{'µs/step':>10}",
    ]
    for r in figures["simulator"]:
        lines.append(
            f"  {r['row']:<44}{r['sim_s']:>7.2f}{r['wall_s']:>9.3f}{r['x_real_time']:>13.1f}{r['us_per_step']:>10.0f}"
        )
    if "skid_steer" in figures:
        lines += ["", *_format_skid(figures["skid_steer"], cfg)]
    if "rover" in figures:
        lines += ["", *_format_rover(figures["rover"])]
    if "sim2real" in figures:
        lines += ["", *_format_sim2real(figures["sim2real"])]
    return "\n".join(lines)


def _format_sim2real(rows: list[dict[str, Any]]) -> list[str]:
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


def _format_skid(skid: dict[str, Any], cfg: dict[str, Any]) -> list[str]:
    """The skid-steer section of the readable table."""
    lines = [
        f"Skid-steer filter step (predict + update inside SkidSteerEstimator), SkidSteerObserverModel n=3 p=3, "
        f"{skid['manoeuvre']} ({skid['duration_s']:.1f} s simulated, the same samples for every filter), "
        f"{cfg['steps']} steps after {cfg['warmup']} warm-up",
        f"  {'filter':<22}{'median µs':>11}{'p90 µs':>10}{'× UKF':>11}{'λ > 1 steps':>13}",
    ]
    for r in skid["filters"]:
        lines.append(
            f"  {r['filter']:<22}{r['median_us']:>11.1f}{r['p90_us']:>10.1f}{r['ratio_to_ukf']:>11.2f}"
            f"{r['strong_tracking_active']:>13d}"
        )
    lines += [
        "",
        "Skid-steer estimator throughput (SkidSteerEstimator fed the simulated run; × real time)",
        f"  {'what':<44}{'sim s':>7}{'wall s':>9}{'× real time':>13}{'µs/step':>10}{'filter µs/step':>16}",
    ]
    for r in skid["throughput"]:
        filt = f"{r['filter_us_per_step']:.0f} ({100 * r['filter_share']:.0f} %)"
        lines.append(
            f"  {r['row']:<44}{r['sim_s']:>7.2f}{r['wall_s']:>9.3f}{r['x_real_time']:>13.1f}"
            f"{r['us_per_step']:>10.0f}{filt:>16}"
        )
    lines += [
        "",
        "Skid-steer simulator (simulate_skid_steer(), RK4 at 2 ms, truth effects on)",
        f"  {'what':<44}{'sim s':>7}{'wall s':>9}{'× real time':>13}{'µs/step':>10}",
    ]
    for r in skid["simulator"]:
        lines.append(
            f"  {r['row']:<44}{r['sim_s']:>7.2f}{r['wall_s']:>9.3f}{r['x_real_time']:>13.1f}{r['us_per_step']:>10.0f}"
        )
    return lines


def _format_rover(rover: dict[str, Any]) -> list[str]:
    """The rocker-bogie section of the readable table."""
    lines = [
        f"Rover filter steps (predict + update inside RoverTerrainEstimator, 5 Hz), terrain {rover['terrain']} "
        f"({rover['duration_s']:.1f} s simulated, the same samples for both variants)",
        f"  {'filter':<22}{'median µs':>11}{'p90 µs':>10}{'× E1':>11}{'steps':>8}  model",
    ]
    for r in rover["filters"]:
        lines.append(
            f"  {r['filter']:<22}{r['median_us']:>11.1f}{r['p90_us']:>10.1f}{r['ratio_to_e1']:>11.2f}"
            f"{r['steps']:>8d}  {r['model']}"
        )
    lines += [
        "",
        "Rover estimator throughput (RoverTerrainEstimator fed the simulated run at 50 Hz; × real time)",
        f"  {'what':<44}{'sim s':>7}{'wall s':>9}{'× real time':>13}{'µs/step':>10}{'filter µs/step':>16}",
    ]
    for r in rover["throughput"]:
        filt = f"{r['filter_us_per_step']:.0f} ({100 * r['filter_share']:.0f} %)"
        lines.append(
            f"  {r['row']:<44}{r['sim_s']:>7.2f}{r['wall_s']:>9.3f}{r['x_real_time']:>13.1f}"
            f"{r['us_per_step']:>10.0f}{filt:>16}"
        )
    lines += [
        "",
        "Rover simulator (simulate_rover(), constrained multibody + soil, RK4 ≤ 2 ms, 50 Hz control)",
        f"  {'what':<44}{'sim s':>7}{'wall s':>9}{'× real time':>13}{'µs/step':>10}",
    ]
    for r in rover["simulator"]:
        lines.append(
            f"  {r['row']:<44}{r['sim_s']:>7.2f}{r['wall_s']:>9.3f}{r['x_real_time']:>13.1f}{r['us_per_step']:>10.0f}"
        )
    return lines


# ---------------------------------------------------------------------------
# 6. Skid-steer replay, compiled step against the previous (Python) step
# ---------------------------------------------------------------------------

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

    duration, messages = _bag_duration_s(path)
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


# ---------------------------------------------------------------------------
# 7. Quarter-car Monte Carlo (case 1 of reproduce-qc), numpy EKF against compiled
# ---------------------------------------------------------------------------

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
    parser.add_argument("--json", metavar="PATH", help="also write every figure to this JSON file")
    parser.add_argument("--bags", metavar="DIR", default=str(BAGS_DIR), help="directory of the recorded bags")
    parser.add_argument(
        "--only",
        choices=("skid_replay", "qc_monte_carlo"),
        help=(
            "run one section only: skid_replay = the skid-steer bags, compiled step against the previous one; "
            "qc_monte_carlo = the 100-run quarter-car Monte Carlo (reproduce-qc case 1, every filter) on 2 "
            "processes, the numpy EKF against the compiled one"
        ),
    )
    args = parser.parse_args(argv)
    cfg = BenchConfig.quick() if args.quick else BenchConfig()
    sections: dict[str, tuple[Callable[[], dict[str, Any]], Callable[[dict[str, Any]], str]]] = {
        "skid_replay": (lambda: bench_skid_replay(cfg, Path(args.bags)), format_skid_replay),
        "qc_monte_carlo": (lambda: bench_qc_monte_carlo(cfg), format_qc_monte_carlo),
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
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(figures, indent=2) + "\n")
        print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
