"""The rover reproduction's runs: simulate each terrain once, re-noise its readings, estimate, pair with the truth.

Part of :mod:`terrain_analysis.tools.reproduce_rover`: the jobs of the plan
(:mod:`~terrain_analysis.tools.rover_plan`), run on the shared runner
(:class:`terrain_analysis.experiment.Runner`, the batch engine), and the error
definitions the report states (estimates paired with the truth at their
stamps).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.experiment import Runner
from terrain_analysis.tools.rover_plan import (
    ALL_VARIANTS,
    QUANTITIES,
    Counts,
    FloatArray,
    Task,
    run_seed,
    variant_config,
)
from terrain_estimation.estimators.rover import (
    RoverTerrainEstimator,
    TerrainResponseAccumulator,
    TerrainResponseConfig,
    TerrainResponseFit,
)
from vehicle_sim.plants.rover import (
    CONTROL_RATE,
    TERRAIN_NUMBERS,
    RoverRun,
    RoverScenario,
    RoverSensors,
    simulate_rover,
)
from vehicle_sim.terrain.terramechanics_surrogate import terramechanics_surrogate

__all__ = [
    "FloatArray",
    "Series",
    "TerrainData",
    "SpeedData",
    "Paired",
    "Results",
    "renoise",
    "estimate_run",
    "run_terrain",
    "run_speed",
    "stamp_indices",
    "wheel_rms",
    "pair",
    "run_task",
    "execute",
]

_TRUTH_FIELDS = (
    "slip",
    "normal_load",
    "resistive_torque",
    "drawbar_pull",
    "contact_angle",
    "terrain_curvature",
    "forward_velocity",
    "vertical_velocity",
)
_EST_FIELDS = ("slip", "normal_load", "resistive_torque", "drawbar_pull", "contact_angle")


# ---------------------------------------------------------------------------
# One terrain: simulate, re-noise, estimate
# ---------------------------------------------------------------------------


def renoise(run: RoverRun, seed: int) -> RoverSensors:
    """The sensor readings the plant would record for ``seed`` on the same (deterministic) truth.

    Replicates :meth:`vehicle_sim.plants.rover.RoverSimulator._measure` for the
    nominal plant (no effects, Gaussian noise): seven independent streams
    ``SeedSequence(seed).spawn(7)`` (bogie, gyro, velocimeter, accelerometer,
    wheel encoders, axial and perpendicular cells), Table IV σ of the run's
    scenario added to the truth's noise-free channels; effort = applied torque.

    Raises:
        ValueError: the run has effects, quantisation or delay switched on.
    """
    scenario = run.scenario
    if scenario.effects.active or scenario.sensors.quantise:
        raise ValueError("renoise supports the nominal plant only (no effects, no quantisation)")
    noise = scenario.sensors
    truth = run.truth
    n = run.time.size
    bogie_rng, gyro_rng, velocity_rng, accel_rng, wheel_rng, axial_rng, perp_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(7)
    )
    return RoverSensors(
        bogie_angle=np.asarray(truth.bogie_angle) + noise.bogie_angle_std * bogie_rng.standard_normal(n),
        pitch_rate=np.asarray(truth.pitch_rate) + noise.pitch_rate_std * gyro_rng.standard_normal(n),
        forward_velocity=np.asarray(truth.forward_velocity)
        + noise.forward_velocity_std * velocity_rng.standard_normal(n),
        acceleration=np.asarray(truth.specific_force) + noise.acceleration_std * accel_rng.standard_normal((n, 2)),
        wheel_angle=np.asarray(truth.configuration)[:, 4:7] + noise.wheel_angle_std * wheel_rng.standard_normal((n, 3)),
        load_axial=np.asarray(truth.load_axial) + noise.load_cell_std * axial_rng.standard_normal((n, 3)),
        load_perpendicular=np.asarray(truth.load_perpendicular)
        + noise.load_cell_std * perp_rng.standard_normal((n, 3)),
        effort=np.asarray(truth.wheel_torque).copy(),
    )


def _same_sensors(a: RoverSensors, b: RoverSensors) -> bool:
    return all(
        np.array_equal(np.asarray(getattr(a, name)), np.asarray(getattr(b, name)))
        for name in RoverSensors.__dataclass_fields__
    )


@dataclass
class Series:
    """One estimator variant's output over one run (arrays at the 5 Hz estimate stamps) and its 2-s samples."""

    t: FloatArray
    initialised: NDArray[np.bool_]
    values: dict[str, FloatArray]  # _EST_FIELDS → (N, 3)
    forward_speed: FloatArray
    wall_s: float
    cpu_s: float
    counters: dict[str, int]
    samples: dict[str, FloatArray]  # accumulator samples: t, slip, normal_load, drawbar_pull, resistive_torque
    accumulator: dict[str, int]
    fits: list[TerrainResponseFit] = field(default_factory=list)  # the online models, one per kept sample period
    variances: dict[str, FloatArray] = field(default_factory=dict)  # _EST_FIELDS → (N, 3) published variances
    settled: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))  # WheelTerrainArray.settled


def estimate_run(time_s: FloatArray, sensors: RoverSensors, variant: str) -> Series:
    """Feed one estimator variant every 50 Hz sample (IMU, joints, velocimeter, load cells at each stamp)."""
    est = RoverTerrainEstimator(variant_config(variant))
    axes = est.config.load_cell_axes
    # Plain lists: time the estimator, not numpy indexing.
    ts = np.asarray(time_s, dtype=float).tolist()
    acc = np.asarray(sensors.acceleration).tolist()
    rate = np.asarray(sensors.pitch_rate).tolist()
    bogie = np.asarray(sensors.bogie_angle).tolist()
    wheel = np.asarray(sensors.wheel_angle).tolist()
    effort = np.asarray(sensors.effort).tolist()
    speed = np.asarray(sensors.forward_velocity).tolist()
    axial = np.asarray(sensors.load_axial).tolist()
    perp = np.asarray(sensors.load_perpendicular).tolist()
    two_axis = axes == 2
    out = []
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for k, t in enumerate(ts):
        est.add_imu(t, acc[k][0], acc[k][1], rate[k])
        est.add_joint_state(t, bogie[k], wheel[k], effort[k])
        est.add_velocimeter(t, speed[k])
        est.add_load_cells(t, axial[k], perp[k] if two_axis else None)
        out.extend(est.drain_estimates())
    est.flush()
    out.extend(est.drain_estimates())
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    accumulator = TerrainResponseAccumulator(TerrainResponseConfig())
    fits: list[TerrainResponseFit] = []
    used = 0
    for e in out:
        if not e.initialised:
            accumulator.add_estimate(e)
            # Refit as the node does with terrain_model.fit_every = 1: at each newly kept sample period.
            if accumulator.counters.buckets_used > used:
                used = accumulator.counters.buckets_used
                fit = accumulator.fit()
                if fit is not None:
                    fits.append(fit)
    accumulator.flush()
    return Series(
        t=np.array([e.t for e in out], dtype=float),
        initialised=np.array([e.initialised for e in out], dtype=bool),
        values={q: np.array([e.per_wheel(q) for e in out], dtype=float).reshape(-1, 3) for q in _EST_FIELDS},
        forward_speed=np.array([e.body.forward_speed for e in out], dtype=float),
        wall_s=wall,
        cpu_s=cpu,
        counters=dataclasses.asdict(est.counters),
        samples=accumulator.samples(),
        accumulator=dataclasses.asdict(accumulator.counters),
        fits=fits,
        variances={
            q: np.array([e.per_wheel(f"{q}_variance") for e in out], dtype=float).reshape(-1, 3) for q in _EST_FIELDS
        },
        settled=np.array([e.settled for e in out], dtype=bool),
    )


@dataclass
class TerrainData:
    """One terrain: the truth (50 Hz), each seed's estimates of both variants, timings."""

    terrain: int
    name: str
    duration: float
    terramechanics: str
    seeds: list[int]
    renoise_identical: bool
    time: FloatArray
    truth: dict[str, FloatArray]
    series: dict[tuple[int, str], Series]
    sim_wall_s: float
    sim_cpu_s: float
    substeps_mean: float


@dataclass
class SpeedData:
    """One simulator-speed run."""

    terramechanics: str
    duration: float
    wall_s: float
    cpu_s: float
    substeps_mean: float
    samples: int


def _simulate(scenario: RoverScenario) -> tuple[RoverRun, float, float]:
    wall0, cpu0 = time.perf_counter(), time.process_time()
    run = simulate_rover(scenario)
    return run, time.perf_counter() - wall0, time.process_time() - cpu0


def run_terrain(task: Task) -> TerrainData:
    """Simulate the terrain once (seed of run 0) and run both variants on every seed's readings."""
    terramechanics_surrogate()  # fit the surrogate before any timing (cached per process)
    name = TERRAIN_NUMBERS[task.terrain]
    seeds = [run_seed(task.terrain, i) for i in range(task.seeds)]
    scenario = RoverScenario(
        terrain=name,
        duration=task.duration,
        seed=seeds[0],
        terramechanics=task.terramechanics,
        start_x=task.start_x,
    )
    run, sim_wall, sim_cpu = _simulate(scenario)
    identical = _same_sensors(renoise(run, seeds[0]), run.sensors)
    series: dict[tuple[int, str], Series] = {}
    for i, seed in enumerate(seeds):
        if i == 0:
            sensors = run.sensors
        elif identical:
            sensors = renoise(run, seed)
        else:  # the plant's noise changed: simulate this seed in full
            other, wall, cpu = _simulate(replace(scenario, seed=seed))
            sim_wall, sim_cpu = sim_wall + wall, sim_cpu + cpu
            sensors = other.sensors
        for v in ALL_VARIANTS:
            series[(i, v)] = estimate_run(run.time, sensors, v)
    truth = {f: np.asarray(getattr(run.truth, f), dtype=float) for f in _TRUTH_FIELDS}
    return TerrainData(
        terrain=task.terrain,
        name=name,
        duration=task.duration,
        terramechanics=task.terramechanics,
        seeds=seeds,
        renoise_identical=identical,
        time=np.asarray(run.time, dtype=float),
        truth=truth,
        series=series,
        sim_wall_s=sim_wall,
        sim_cpu_s=sim_cpu,
        substeps_mean=float(np.mean(run.truth.substeps)),
    )


def run_speed(task: Task) -> SpeedData:
    """Simulator speed: terrain 1 for ``task.duration`` s with the given terramechanics."""
    terramechanics_surrogate()  # the surrogate's one-off fit is not part of the stepping speed
    scenario = RoverScenario(
        terrain=TERRAIN_NUMBERS[task.terrain],
        duration=task.duration,
        seed=run_seed(task.terrain, 0),
        terramechanics=task.terramechanics,
    )
    run, wall, cpu = _simulate(scenario)
    return SpeedData(task.terramechanics, task.duration, wall, cpu, float(np.mean(run.truth.substeps)), run.time.size)


def run_task(task: Task) -> TerrainData | SpeedData:
    """One job of the plan (module level: the engine's workers unpickle it)."""
    return run_terrain(task) if task.kind == "terrain" else run_speed(task)


# ---------------------------------------------------------------------------
# Metrics (definitions stated in the report)
# ---------------------------------------------------------------------------


def stamp_indices(
    time_s: FloatArray, stamps: FloatArray, tol: float = 1e-6
) -> tuple[NDArray[np.int_], NDArray[np.bool_]]:
    """(index of the 50 Hz sample at each stamp, whether it exists within ``tol``)."""
    ts = np.asarray(time_s, dtype=float)
    st = np.asarray(stamps, dtype=float)
    if ts.size == 0:
        return np.zeros(st.shape, dtype=int), np.zeros(st.shape, dtype=bool)
    rate = (ts.size - 1) / (ts[-1] - ts[0]) if ts.size > 1 else CONTROL_RATE
    idx = np.rint((st - ts[0]) * rate).astype(int)
    ok = (idx >= 0) & (idx < ts.size)
    idx = np.clip(idx, 0, ts.size - 1)
    ok &= np.abs(ts[idx] - st) <= tol
    return idx, ok


def wheel_rms(error: Any) -> FloatArray:
    """Per-wheel RMS of an (N, 3) error array (NaN for no rows)."""
    e = np.asarray(error, dtype=float).reshape(-1, 3)
    if e.shape[0] == 0:
        return np.full(3, math.nan)
    return np.asarray(np.sqrt(np.mean(e * e, axis=0)), dtype=float)


def _window_mean(values: FloatArray, idx: NDArray[np.int_], n: int) -> FloatArray:
    """Mean of values[k − n + 1 … k] (rows) for each k of ``idx`` (fewer at the start)."""
    csum = np.vstack([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    lo = np.maximum(idx + 1 - n, 0)
    return np.asarray((csum[idx + 1] - csum[lo]) / (idx + 1 - lo)[:, None], dtype=float)


@dataclass
class Paired:
    """One series' estimates paired with the truth at the estimate stamps (initialisation dropped)."""

    t: FloatArray
    est: dict[str, FloatArray]
    truth: dict[str, FloatArray]
    truth_window: dict[str, FloatArray]
    delta: FloatArray  # δ = atan(−ż0^R / ẋ0^R) of the truth (rad), [RB] V-B
    kappa: FloatArray  # |κ_t| per wheel (1/m)


def pair(data: TerrainData, s: Series) -> Paired:
    idx, ok = stamp_indices(data.time, s.t)
    keep = ok & ~s.initialised
    k = idx[keep]
    per_window = int(round(CONTROL_RATE / 5.0))
    truth = {q: data.truth[q][k] for q in _EST_FIELDS}
    window = {q: _window_mean(data.truth[q], k, per_window) for q in QUANTITIES}
    vz, vx = data.truth["vertical_velocity"][k], data.truth["forward_velocity"][k]
    return Paired(
        t=s.t[keep],
        est={q: s.values[q][keep] for q in _EST_FIELDS},
        truth=truth,
        truth_window=window,
        delta=np.arctan2(-vz, vx),
        kappa=np.abs(data.truth["terrain_curvature"][k]),
    )


@dataclass
class Results:
    """Everything the report needs, computed from the jobs' outputs."""

    terrains: dict[int, TerrainData] = field(default_factory=dict)
    speed: dict[str, SpeedData] = field(default_factory=dict)
    paired: dict[tuple[int, int, str], Paired] = field(default_factory=dict)
    settle: float = 10.0

    def seeds(self, terrain: int) -> int:
        return len(self.terrains[terrain].seeds)

    def cell_values(self, terrain: int, variant: str, quantity: str, kind: str = "stamp") -> FloatArray:
        """(seeds, 3) per-wheel RMS of one Table V cell group; kind: stamp | settled | window."""
        rows = []
        for i in range(self.seeds(terrain)):
            p = self.paired[(terrain, i, variant)]
            truth = p.truth_window[quantity] if kind == "window" else p.truth[quantity]
            err = p.est[quantity] - truth
            if kind == "settled":
                err = err[p.t > self.settle]
            rows.append(wheel_rms(err))
        return np.array(rows, dtype=float)


def execute(plan: Sequence[Task], counts: Counts, runner: Runner) -> Results:
    """Run the plan on ``runner`` (the batch engine, heaviest jobs first) and pair every series with the truth.

    The results are folded in plan order, whatever order the jobs finish in.
    """
    outputs = runner.map(run_task, plan, weight=lambda t: t.cost, key=lambda t: t.label)
    res = Results(settle=counts.settle)
    for task, data in zip(plan, outputs, strict=True):
        if isinstance(data, TerrainData):
            res.terrains[task.terrain] = data
            for (i, v), s in data.series.items():
                res.paired[(task.terrain, i, v)] = pair(data, s)
        else:
            res.speed[data.terramechanics] = data
    return res
