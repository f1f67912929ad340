"""The skid-steer and rocker-bogie sections of the benchmark (:mod:`terrain_analysis.tools.bench`, items 4–5).

4. **Skid steer** ([SS], MODELS.md Part B): per-step time of the UKF, STUKF and AN-STUKF inside a
   ``SkidSteerEstimator`` fed one simulated small-radius turn, the estimator's throughput and the skid-steer
   simulator's speed.
5. **Rocker-bogie rover** ([RB], MODELS.md Part C): per-step time of Estimators 1–3 inside a
   ``RoverTerrainEstimator`` fed a simulated drive over Fig. 10's terrain 1, the estimators' throughput, and the
   rover simulator with the full Wong–Reece soil model and with its surrogate.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from terrain_analysis.tools.bench_common import DT, BenchConfig, FilterProxy, percentiles_us, speed_fields, speed_table

__all__ = [
    "ROVER_ROW_LABELS",
    "ROVER_TERRAIN",
    "ROVER_TERRAMECHANICS",
    "ROVER_VARIANTS",
    "SKID_FILTERS",
    "SKID_MANOEUVRE",
    "SKID_ROW_LABELS",
    "bench_rover",
    "bench_skid",
    "format_rover",
    "format_skid",
]

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


class _TimedStep(FilterProxy):
    """Delegates to an ``AdaptiveStrongTrackingUKF`` and records the time of every ``step``."""

    def __init__(self, inner: Any) -> None:
        super().__init__(inner)
        self.ns: list[int] = []

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
        **speed_fields(duration, sim_wall, int(result.t.size)),
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
        med, p90 = percentiles_us(timed_ns)
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
                **speed_fields(duration, wall, counters.steps),
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


class _TimedRoverFilter(FilterProxy):
    """Delegates to the UKF both rover estimators share; times each call, keyed by the model it runs."""

    def __init__(self, inner: Any, general_model: Any) -> None:
        super().__init__(inner)
        self.general_model = general_model
        self.ns: dict[str, list[int]] = {"general": [], "wheel_force": []}
        self._pending: dict[str, int] = {"general": 0, "wheel_force": 0}

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
                **speed_fields(cfg.drive_s, wall, int(result.time.size)),
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
                **speed_fields(cfg.drive_s, wall, steps),
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
        med, p90 = percentiles_us(ns) if ns else (math.nan, math.nan)
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


def format_skid(skid: dict[str, Any], cfg: dict[str, Any]) -> list[str]:
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
        *speed_table(
            "Skid-steer estimator throughput (SkidSteerEstimator fed the simulated run; × real time)",
            skid["throughput"],
            filter_column=True,
        ),
        "",
        *speed_table(
            "Skid-steer simulator (simulate_skid_steer(), RK4 at 2 ms, truth effects on)",
            skid["simulator"],
            filter_column=False,
        ),
    ]
    return lines


def format_rover(rover: dict[str, Any]) -> list[str]:
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
        *speed_table(
            "Rover estimator throughput (RoverTerrainEstimator fed the simulated run at 50 Hz; × real time)",
            rover["throughput"],
            filter_column=True,
        ),
        "",
        *speed_table(
            "Rover simulator (simulate_rover(), constrained multibody + soil, RK4 ≤ 2 ms, 50 Hz control)",
            rover["simulator"],
            filter_column=False,
        ),
    ]
    return lines
