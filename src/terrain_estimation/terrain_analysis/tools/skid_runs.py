"""The skid-steer reproduction's runs: the plan of seeded manoeuvres and what one run records.

Scenario definitions of ``python -m terrain_analysis.tools.reproduce_skid``: a
:class:`RunSpec` is one manoeuvre of the paper (or the tire-mismatch
sensitivity) with its run index; :func:`build_plan` lists every run;
:func:`run_one` simulates it and runs the three filters (UKF, STUKF,
AN-STUKF) over the same sensor data, returning a :class:`RunData`.

Seeds: run ``i`` of manoeuvre group ``g`` uses the sensor-noise seed
``SeedSequence([ROOT_SEED, g, i]).generate_state(1)[0]``; the mismatch
sensitivity reuses the turn's seeds (a paired comparison).
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from vehicle_sim.plants.skid_steer import (
    MANOEUVRES,
    SkidSteerEffects,
    SkidSteerScenario,
    simulate_skid_steer,
)

__all__ = [
    "ROOT_SEED",
    "FILTERS",
    "Counts",
    "RunSpec",
    "RunData",
    "Series",
    "build_plan",
    "run_one",
    "run_seed",
    "scenario_of",
]

ROOT_SEED = 3041
"""Root of every seed of the reproduction (see the module docstring)."""

FloatArray = NDArray[np.float64]

FILTERS: tuple[str, ...] = ("ukf", "stukf", "an_stukf")
FILTER_NAMES = {"ukf": "UKF", "stukf": "STUKF", "an_stukf": "AN-STUKF"}
_COLOURS = {"truth": "k", "ukf": "tab:blue", "stukf": "tab:green", "an_stukf": "tab:red", "gnss": "0.55"}
# The filters' traces often coincide: the UKF is drawn widest, underneath.
_WIDTHS = {"ukf": 2.2, "stukf": 1.4, "an_stukf": 0.8}

# Seed groups (the mismatch sensitivity reuses the turn's sensor-noise seeds: a paired comparison).
_GROUPS = {"straight_acceleration": 1, "small_radius_turn": 2, "s_shape": 3, "turn_mismatch": 2}

#: Floor of |β_ref| in the floored relative error (rad): 1°, a round value above
#: the GNSS β noise at 5 km/h (σ_v / v_x, computed in the report).
REL_FLOOR = math.radians(1.0)
#: "Faster", "better": the AN-STUKF must beat the UKF by this fraction; "no worse": within it.
MARGIN = 0.05
#: Tire sideslip beyond which the paper calls the rear tires saturated (deg; paper's observation).
_PAPER_REAR_SIDESLIP_DEG = 30.0
_PAPER_ICR_X = 3.0

# Paper Table 2 and 3 (MODELS.md D.2): max abs (rad), max rel (%), mean abs (rad), mean rel (%), std (rad).
PAPER_TABLE2: dict[str, tuple[float, float, float, float, float]] = {
    "ukf": (0.3619, 89.57, 0.0530, 49.47, 0.0732),
    "an_stukf": (0.1305, 46.11, 0.0201, 17.24, 0.0453),
}
PAPER_TABLE3: dict[str, tuple[float, float, float, float, float]] = {
    "ukf": (0.0278, 145.71, 0.0090, 34.05, 0.0108),
    "an_stukf": (0.0285, 119.35, 0.0085, 25.63, 0.0105),
}
_STATS = ("max_abs", "max_rel", "mean_abs", "mean_rel", "std", "mean_rel_floor")

# Truth of the sensitivity case: tires softer and less grippy than the observer assumes.
_MISMATCH_CORNERING = 0.7
_MISMATCH_FRICTION = 0.8


# ---------------------------------------------------------------------------
# Plan
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Counts:
    """Run counts, durations and windows of one invocation (times in s)."""

    runs: int = 20
    mismatch_runs: int = 10
    straight_duration: float = 20.0
    turn_duration: float = 45.0
    s_duration: float = 30.0
    turn_window: tuple[float, float] = (20.0, 40.0)
    s_window: tuple[float, float] = (20.0, 25.0)
    s_icr_window: tuple[float, float] = (4.0, 10.0)
    steady_delay: float = 2.0

    @classmethod
    def quick(cls) -> Counts:
        """Smoke run: one short run per case, windows moved inside the short runs."""
        return replace(
            cls().with_runs(1),
            straight_duration=11.0,
            turn_duration=12.0,
            s_duration=10.0,
            turn_window=(10.0, 12.0),
            s_window=(1.0, 5.0),
            steady_delay=1.0,
        )

    def with_runs(self, n: int) -> Counts:
        return replace(self, runs=n, mismatch_runs=max(1, n // 2))


@dataclass(frozen=True)
class RunSpec:
    """One simulated run: a manoeuvre (``case``), a run index, a duration."""

    case: str
    run: int
    duration: float

    @property
    def manoeuvre(self) -> str:
        return "small_radius_turn" if self.case == "turn_mismatch" else self.case


def run_seed(case: str, run: int) -> int:
    """Sensor-noise seed of run ``run`` of ``case``."""
    return int(np.random.SeedSequence([ROOT_SEED, _GROUPS[case], run]).generate_state(1)[0])


def build_plan(counts: Counts) -> list[RunSpec]:
    """Every run of the reproduction."""
    plan: list[RunSpec] = []
    for case, duration, n in (
        ("small_radius_turn", counts.turn_duration, counts.runs),
        ("s_shape", counts.s_duration, counts.runs),
        ("straight_acceleration", counts.straight_duration, counts.runs),
        ("turn_mismatch", counts.turn_duration, counts.mismatch_runs),
    ):
        plan += [RunSpec(case, i, duration) for i in range(n)]
    return plan


def scenario_of(spec: RunSpec) -> SkidSteerScenario:
    """The plant scenario of a run (the manoeuvre builder's truth, effects on)."""
    effects = SkidSteerEffects.truth_default()
    if spec.case == "turn_mismatch":
        effects = replace(effects, cornering_stiffness_change=_MISMATCH_CORNERING, friction_change=_MISMATCH_FRICTION)
    return MANOEUVRES[spec.manoeuvre](duration=spec.duration, effects=effects)


# ---------------------------------------------------------------------------
# One run
# ---------------------------------------------------------------------------


@dataclass
class Series:
    """One filter's estimates over a run (arrays at the IMU rate)."""

    t: FloatArray
    vx: FloatArray
    vy: FloatArray
    yaw_rate: FloatArray
    beta: FloatArray
    slip: FloatArray  # (N, 2) left, right
    tire_sideslip: FloatArray  # (N, 6)
    icr_x: FloatArray
    icr_y: FloatArray
    icr_valid: NDArray[np.bool_]
    fading: FloatArray
    noise_scale: FloatArray
    nis: FloatArray
    vx_encoder: FloatArray
    yaw_rate_encoder: FloatArray
    wall_s: float
    recoveries: int


@dataclass
class RunData:
    """A simulated run, its truth, its GNSS reference and the three filters' estimates."""

    spec: RunSpec
    seed: int
    t: FloatArray
    truth: dict[str, FloatArray]
    gnss: dict[str, FloatArray]
    series: dict[str, Series]
    sim_wall_s: float
    truth_digest: str
    speed_times: tuple[float, ...]
    speeds: tuple[float, ...]
    gnss_velocity_noise_std: float


_TRUTH_FIELDS = (
    "vx",
    "vy",
    "yaw_rate",
    "body_sideslip",
    "slip",
    "tire_sideslip",
    "icr_x",
    "icr_y",
    "icr_valid",
    "normal_load",
    "tire_force_y",
    "wheel_speed",
)


def _run_filter(sim: Any, name: str) -> Series:
    """Feed one estimator the run's sensors (joint state first, then the IMU sample of the same stamp)."""
    est = SkidSteerEstimator(SkidSteerEstimatorConfig.paper(filter=name))
    mv = sim.motor_velocity.tolist()
    acc = sim.linear_acceleration.tolist()
    gyro = sim.angular_velocity.tolist()
    out = []
    start = time.perf_counter()
    for i, t in enumerate(sim.t.tolist()):
        est.add_joint_state(t, mv[i][0], mv[i][1])
        est.add_imu(t, acc[i][0], acc[i][1], gyro[i][2])
        out.extend(est.drain_estimates())
    wall = time.perf_counter() - start

    def col(attr: str) -> FloatArray:
        return np.array([getattr(e, attr) for e in out], dtype=float)

    return Series(
        t=col("t"),
        vx=col("vx"),
        vy=col("vy"),
        yaw_rate=col("yaw_rate"),
        beta=col("body_sideslip"),
        slip=np.column_stack([col("slip_left"), col("slip_right")]),
        tire_sideslip=np.array([e.tire_sideslip for e in out], dtype=float),
        icr_x=col("icr_x"),
        icr_y=col("icr_y"),
        icr_valid=np.array([e.icr_valid for e in out], dtype=bool),
        fading=col("fading_factor"),
        noise_scale=col("noise_scale"),
        nis=col("nis"),
        vx_encoder=col("vx_encoder"),
        yaw_rate_encoder=col("yaw_rate_encoder"),
        wall_s=wall,
        recoveries=int(est.counters.recoveries),
    )


def run_one(spec: RunSpec) -> RunData:
    """Simulate one run and run the three filters over the same sensor data."""
    seed = run_seed(spec.case, spec.run)
    scenario = scenario_of(spec)
    start = time.perf_counter()
    sim = simulate_skid_steer(scenario, seed)
    sim_wall = time.perf_counter() - start
    truth = {name: np.asarray(getattr(sim.truth, name)) for name in _TRUTH_FIELDS}
    digest = hashlib.sha1(
        b"".join(np.ascontiguousarray(truth[k], dtype=float).tobytes() for k in ("vx", "vy", "yaw_rate"))
    ).hexdigest()[:12]
    gnss = {name: np.asarray(getattr(sim.gnss, name), dtype=float) for name in ("t", "vx", "vy")}
    series = {name: _run_filter(sim, name) for name in FILTERS}
    return RunData(
        spec=spec,
        seed=seed,
        t=np.asarray(sim.t, dtype=float),
        truth=truth,
        gnss=gnss,
        series=series,
        sim_wall_s=sim_wall,
        truth_digest=digest,
        speed_times=scenario.manoeuvre.speed_times,
        speeds=scenario.manoeuvre.speeds,
        gnss_velocity_noise_std=scenario.sensors.gnss_velocity_noise_std,
    )
