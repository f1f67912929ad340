"""The quarter-car and LRV sections of the benchmark (:mod:`terrain_analysis.tools.bench`, items 1–3).

1. **Filter step**: predict + update of our four filters, of the compiled steps the node runs and of filterpy's
   UKF on the quarter-car model, one simulated drive, per-step median and 90th percentile.
2. **Estimator throughput**: ``estimate_bag`` over the recorded bags, and the ROS-free core fed a simulator
   run (the node's compiled step, and the numpy path beside it), as multiples of real time.
3. **Simulator**: ``vehicle_sim`` ``simulate()`` as a multiple of real time.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.tools.bench_common import (
    DT,
    SUBSTEPS,
    BenchConfig,
    FilterProxy,
    bag_duration_s,
    percentiles_us,
    speed_fields,
    speed_table,
)

__all__ = [
    "BAGS",
    "COMPILED_FILTERS",
    "FILTERPY_LABEL",
    "OUR_FILTERS",
    "bench_bag",
    "bench_core",
    "bench_filters",
    "bench_simulator",
    "drive_lrv",
    "drive_quarter_car",
    "format_quarter_car",
]

BAGS: tuple[tuple[str, str], ...] = (
    ("quarter_car_graneville_iso_d_10ms", "quarter_car"),
    ("lrv_regolith_iso_g_2ms", "lrv"),
)
OUR_FILTERS: tuple[tuple[str, str], ...] = (("SCKF", "sckf"), ("CKF", "ckf"), ("UKF", "ukf"), ("EKF", "ekf"))
#: The compiled steps the estimator node runs for its default SCKF and for the EKF (same model, same data).
COMPILED_FILTERS: tuple[tuple[str, str], ...] = (("SCKF compiled step", "sckf"), ("EKF compiled step", "ekf"))
FILTERPY_LABEL = "filterpy UKF (Merwe)"


def deep_bytes(obj: Any) -> int:
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


def drive_quarter_car(duration: float, seed: int) -> Any:
    """The quarter-car bag's world (Graneville loam, ISO D seed 11, 10 m/s), simulated."""
    from vehicle_sim.plants.quarter_car import QuarterCarVehicle, Scenario, SpeedProfile, simulate
    from vehicle_sim.terrain.profiles import iso8608_profile
    from vehicle_sim.terrain.soils import GRANEVILLE_LOAM, SoilPath

    scenario = Scenario(
        profile=iso8608_profile("D", 11), soil_path=SoilPath(GRANEVILLE_LOAM), speed=SpeedProfile.constant(10.0)
    )
    return simulate(QuarterCarVehicle(), scenario, duration, seed)


def drive_lrv(duration: float, seed: int) -> Any:
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

    result = drive_quarter_car(n_steps * DT, seed)
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
        med, p90 = percentiles_us(times)
        final_ktot[name] = float(state.x[-1])
        rows.append(
            {"filter": label, "median_us": med, "p90_us": p90, "steps": len(times), "state_bytes": deep_bytes(state)}
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
        med, p90 = percentiles_us(times)
        final = dataclasses.replace(state, x=x, **({"S": fac} if name == "sckf" else {"P": fac}))
        rows.append(
            {
                "filter": label,
                "median_us": med,
                "p90_us": p90,
                "steps": len(times),
                "state_bytes": deep_bytes(final),
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
    med, p90 = percentiles_us(times)
    ours = next(r for r in rows if r["filter"] == "UKF")
    rows.append(
        {
            "filter": FILTERPY_LABEL,
            "median_us": med,
            "p90_us": p90,
            "steps": len(times),
            "state_bytes": deep_bytes(ukf),
            # Same model, same sigma points: the estimates must agree (a check
            # that the comparison is like for like).
            "final_ktot_diff_vs_ours_N_per_m": abs(float(ukf.x[-1]) - final_ktot["ukf"]),
        }
    )
    for r in rows:
        r["ratio_to_our_ukf"] = r["median_us"] / ours["median_us"]
    return rows


def bench_bag(path: Path, vehicle: str, repeats: int) -> dict[str, Any]:
    """``estimate_bag`` wall time over the bag (median of ``repeats`` after one untimed run)."""
    from terrain_estimation.tools.estimate import estimate_bag

    duration, messages = bag_duration_s(path)
    run = estimate_bag(path, vehicle)  # untimed: imports, typestore, caches
    walls = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        run = estimate_bag(path, vehicle)
        walls.append(time.perf_counter() - t0)
    wall = float(np.median(walls))
    steps = len(run.outputs)
    return {"row": f"bag {path.name}", "vehicle": vehicle, **speed_fields(duration, wall, steps), "messages": messages}


class _StepTimer(FilterProxy):
    """Accumulates the time spent in the calls it wraps (``ns``) and counts the filter steps (``steps``)."""

    def __init__(self, inner: Any) -> None:
        super().__init__(inner)
        self.ns = 0
        self.steps = 0

    def _timed(self, fn: Callable[..., Any], args: Any, kwargs: Any, steps: int) -> Any:
        t0 = time.perf_counter_ns()
        try:
            return fn(*args, **kwargs)
        finally:
            self.ns += time.perf_counter_ns() - t0
            self.steps += steps


class _TimedFilter(_StepTimer):
    """Delegates to a filter and accumulates the time spent in predict and update (one step each)."""

    def predict(self, *args: Any, **kwargs: Any) -> Any:
        return self._timed(self.inner.predict, args, kwargs, 1)

    def update(self, *args: Any, **kwargs: Any) -> Any:
        return self._timed(self.inner.update, args, kwargs, 0)


class _TimedCompiledStep(_StepTimer):
    """Wraps an estimator's compiled filter step (``_compiled_step``: the SCKF or EKF) and accumulates its time.

    Installed on the estimator instance, so that the estimator runs exactly the
    path it runs in the node (the compiled step), with the filter's share
    measured around it.
    """

    def __init__(self, est: Any, name: str) -> None:
        super().__init__(getattr(est, name))
        setattr(est, name, self)

    def __call__(self, *args: Any) -> Any:
        return self._timed(self.inner, args, {}, 1)


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
        **speed_fields(duration, wall, steps),
        "filter_us_per_step": 1e-3 * timed.ns / timed.steps if timed.steps else math.nan,
        "filter_share": 1e-9 * timed.ns / wall if wall > 0 else math.nan,
    }


def bench_simulator(vehicle: str, drive: Callable[[float, int], Any], cfg: BenchConfig) -> tuple[dict[str, Any], Any]:
    """``simulate()`` wall time for ``cfg.drive_s``; also returns the run (it feeds the core row)."""
    drive(0.1, cfg.seed)  # untimed: profile caches, imports
    t0 = time.perf_counter()
    result = drive(cfg.drive_s, cfg.seed)
    wall = time.perf_counter() - t0
    return {
        "row": f"simulate {vehicle}",
        "vehicle": vehicle,
        **speed_fields(cfg.drive_s, wall, int(result.t.size)),
    }, result


def format_quarter_car(figures: dict[str, Any]) -> list[str]:
    """The filter-step, estimator-throughput and simulator sections of the readable report."""
    cfg = figures["config"]
    lines = [
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
        *speed_table(
            "Estimator throughput (× real time = simulated or recorded seconds per wall second)",
            figures["throughput"],
            filter_column=True,
        ),
        "  (bag = read + deserialise + adapter + estimator; core = estimator alone, same config, the node's path "
        "(compiled filter step); core … numpy path = the same through the filter's public numpy predict/update, "
        "the reference, not what runs; filter = the filter step inside it)",
        "",
        *speed_table(
            "Simulator (vehicle_sim simulate(), RK4 at 1 ms, 1 kHz profile)", figures["simulator"], filter_column=False
        ),
    ]
    return lines
