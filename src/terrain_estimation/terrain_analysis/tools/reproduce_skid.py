"""Reproduce the skid-steer motion-state results of the AN-STUKF paper (MODELS.md Part B, D.2).

``python -m terrain_analysis.tools.reproduce_skid [--runs N] [--out docs/results] [--jobs 2] [--quick]``

Every number the report shows is computed here, when the command runs, by the
project's own truth plant (:func:`vehicle_sim.plants.skid_steer.simulate_skid_steer`,
the paper's three manoeuvres of :data:`~vehicle_sim.plants.skid_steer.MANOEUVRES`
with roll/pitch load-transfer dynamics and tire relaxation on) and its own
estimator (:class:`~terrain_estimation.estimators.skid_steer.SkidSteerEstimator`
with ``filter="ukf"``, ``"stukf"`` and ``"an_stukf"``, fed the same sensor
data). The paper's numbers appear only as the comparison column (DESIGN.md);
the truth plant, its noise and the seeds are never tuned towards the paper.

Cases (as in the report):

1. Table 2: small-radius turn (≈ 5 km/h, 0.2 rad/s, counter-clockwise), errors
   of the body sideslip angle β over 20–40 s.
2. Table 3: S-shaped path at 30 km/h, errors of β over 20–25 s.
3. Straight acceleration 0 → 30 km/h: tracking lag and error of v̂x.
4. ICR in the small-radius turn (truth and filters, front axle beside), and
   its forward shift on the S-shape (4–10 s).
5. The paper's other observations in the turn (per-side slip, encoder yaw
   rate, tire sideslip angles).
6. Sensitivity (not in the paper): the turn with a truth whose tires differ
   from the observer's (C_α and μ changed).

Seeds: run ``i`` of manoeuvre group ``g`` uses the sensor-noise seed
``SeedSequence([ROOT_SEED, g, i]).generate_state(1)[0]``. The truth plant is
deterministic for a given scenario (the seed drives only the sensor noise),
which the report checks by comparing a digest of the truth of every run.
"""

from __future__ import annotations

import hashlib
import math
import multiprocessing
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.reporting import Claim, Report, claims_table, reproduction_arguments
from terrain_analysis.reporting import cpu_seconds as _cpu_seconds
from terrain_analysis.reporting import format_number as _fmt
from terrain_analysis.reporting import git_revision as _git_revision
from terrain_analysis.reporting import in_window as _window
from terrain_analysis.reporting import pyplot as _plt
from terrain_analysis.reporting import summary_stats as _stats
from terrain_estimation.cli import cli_main
from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from terrain_estimation.models.skid_steer import WHEEL_NAMES, SkidSteerParams, axle_positions
from vehicle_sim.plants.skid_steer import (
    MANOEUVRES,
    SkidSteerEffects,
    SkidSteerScenario,
    SkidSteerSensors,
    simulate_skid_steer,
)

__all__ = [
    "ROOT_SEED",
    "FILTERS",
    "Claim",
    "Counts",
    "RunSpec",
    "RunData",
    "SideslipErrors",
    "run_seed",
    "run_one",
    "sideslip_errors",
    "values_at",
    "tracking_lag",
    "icr_statistics",
    "build_plan",
    "claims_table",
    "main",
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
        return cls(
            runs=1,
            mismatch_runs=1,
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


# ---------------------------------------------------------------------------
# Metrics (definitions stated in the report)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class SideslipErrors:
    """Error statistics of e = β̂ − β_ref over a window (rad; relative errors as fractions).

    Attributes:
        max_abs: max |e|.
        max_rel: max |e| / |β_ref|.
        mean_abs: mean |e|.
        mean_rel: mean |e| / |β_ref| (the paper's definition; explodes where β_ref ≈ 0).
        std: standard deviation of e (population, ddof = 0).
        mean_rel_floor: mean |e| / max(|β_ref|, floor).
        n: number of samples.
    """

    max_abs: float
    max_rel: float
    mean_abs: float
    mean_rel: float
    std: float
    mean_rel_floor: float
    n: int


def sideslip_errors(estimate: Any, reference: Any, floor: float = REL_FLOOR) -> SideslipErrors:
    """Table 2/3 statistics of ``estimate − reference`` (paired samples, rad)."""
    est = np.asarray(estimate, dtype=float)
    ref = np.asarray(reference, dtype=float)
    if est.shape != ref.shape or est.ndim != 1 or est.size == 0:
        raise ValueError(f"need two equally long non-empty 1-D arrays, got {est.shape} and {ref.shape}")
    e = est - ref
    abs_e = np.abs(e)
    abs_ref = np.abs(ref)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(abs_ref > 0.0, abs_e / abs_ref, np.inf)
    rel_floor = abs_e / np.maximum(abs_ref, floor)
    return SideslipErrors(
        max_abs=float(abs_e.max()),
        max_rel=float(rel.max()),
        mean_abs=float(abs_e.mean()),
        mean_rel=float(rel.mean()),
        std=float(np.std(e)),
        mean_rel_floor=float(rel_floor.mean()),
        n=int(e.size),
    )


def values_at(t: Any, values: Any, stamps: Any, tol: float = 1e-6) -> FloatArray:
    """``values`` (sampled at increasing ``t``) at the sample whose stamp equals each of ``stamps``.

    Raises:
        ValueError: a stamp has no sample within ``tol``.
    """
    ta = np.asarray(t, dtype=float)
    va = np.asarray(values)
    sa = np.asarray(stamps, dtype=float)
    idx = np.clip(np.searchsorted(ta, sa), 1, ta.size - 1) if ta.size > 1 else np.zeros(sa.shape, dtype=int)
    if ta.size > 1:
        left_closer = np.abs(ta[idx - 1] - sa) <= np.abs(ta[idx] - sa)
        idx = np.where(left_closer, idx - 1, idx)
    gap = np.abs(ta[idx] - sa) if sa.size else np.zeros(0)
    if np.any(gap > tol):
        worst = float(sa[int(np.argmax(gap))])
        raise ValueError(f"no sample within {tol} s of stamp {worst}")
    return np.asarray(va[idx], dtype=float)


def tracking_lag(
    t_est: Any,
    estimate: Any,
    t_truth: Any,
    truth: Any,
    t0: float,
    t1: float,
    max_shift: float = 1.0,
    resolution: float = 1e-3,
) -> float:
    """Time shift τ (s) that best aligns the estimate with the delayed truth over t0 < t ≤ t1.

    τ = argmin Σ (x̂(t) − x(t − τ))² over a grid of ``resolution`` in
    [−max_shift, max_shift], refined by a parabola through the minimum and
    its neighbours. τ > 0: the estimate lags the truth; τ < 0: it leads.
    """
    te = np.asarray(t_est, dtype=float)
    xe = np.asarray(estimate, dtype=float)
    mask = _window(te, t0, t1)
    te, xe = te[mask], xe[mask]
    if te.size < 2:
        raise ValueError(f"fewer than two estimates in ({t0}, {t1}]")
    shifts = np.arange(-max_shift, max_shift + 0.5 * resolution, resolution)
    shifted = np.interp(te[None, :] - shifts[:, None], np.asarray(t_truth, dtype=float), np.asarray(truth, float))
    cost = np.sum((xe[None, :] - shifted) ** 2, axis=1)
    k = int(np.argmin(cost))
    tau = float(shifts[k])
    if 0 < k < shifts.size - 1:
        c0, c1, c2 = cost[k - 1], cost[k], cost[k + 1]
        curvature = c0 - 2.0 * c1 + c2
        if curvature > 0.0:
            tau += 0.5 * resolution * float(c0 - c2) / float(curvature)
    return tau


def icr_statistics(icr_x: Any, icr_y: Any, valid: Any) -> tuple[float, float, float, float, float]:
    """(mean x, std x, mean y, std y, median x) of the valid ICR samples (m); NaN without any."""
    ok = np.asarray(valid, dtype=bool)
    x = np.asarray(icr_x, dtype=float)[ok]
    y = np.asarray(icr_y, dtype=float)[ok]
    if x.size == 0:
        return (math.nan,) * 5
    return float(x.mean()), float(x.std()), float(y.mean()), float(y.std()), float(np.median(x))


def _ramp(speed_times: Sequence[float], speeds: Sequence[float]) -> tuple[float, float]:
    """(start, end) of the first rising segment of the speed reference (s)."""
    for i in range(len(speeds) - 1):
        if speeds[i + 1] > speeds[i]:
            return float(speed_times[i]), float(speed_times[i + 1])
    raise ValueError("the speed reference has no rising segment")


def _sideslip_metrics(run: RunData, window: tuple[float, float], out: dict[str, float]) -> None:
    t0, t1 = window
    g = run.gnss
    gm = _window(g["t"], t0, t1)
    stamps = g["t"][gm]
    beta_gnss = np.arctan2(g["vy"][gm], g["vx"][gm])
    tm = _window(run.t, t0, t1)
    beta_truth = run.truth["body_sideslip"]
    out["truth.beta_mean"] = float(np.mean(beta_truth[tm]))
    out["truth.beta_mean_abs"] = float(np.mean(np.abs(beta_truth[tm])))
    out["gnss.beta_mean_abs"] = float(np.mean(np.abs(beta_gnss)))
    out["gnss.frac_below_floor"] = float(np.mean(np.abs(beta_gnss) < REL_FLOOR))
    out["truth.beta_min_abs"] = float(np.min(np.abs(beta_truth[tm])))
    out["gnss.beta_noise_std"] = float(np.std(beta_gnss - values_at(run.t, beta_truth, stamps)))
    out["gnss.vx_mean"] = float(np.mean(g["vx"][gm]))
    for name, s in run.series.items():
        sm = _window(s.t, t0, t1)
        for ref_name, errs in (
            ("gnss", sideslip_errors(values_at(s.t, s.beta, stamps), beta_gnss)),
            ("truth", sideslip_errors(s.beta[sm], values_at(run.t, beta_truth, s.t[sm]))),
        ):
            for stat in _STATS:
                out[f"{name}.{ref_name}.{stat}"] = getattr(errs, stat)
        vy_hat = values_at(s.t, s.vy, stamps)
        out[f"{name}.vy_gnss_mae"] = float(np.mean(np.abs(vy_hat - g["vy"][gm])))
        out[f"{name}.vy_truth_mae"] = float(np.mean(np.abs(s.vy[sm] - values_at(run.t, run.truth["vy"], s.t[sm]))))
        out[f"{name}.vx_truth_mae"] = float(np.mean(np.abs(s.vx[sm] - values_at(run.t, run.truth["vx"], s.t[sm]))))
        out[f"{name}.fading_active"] = float(np.mean(s.fading[sm] > 1.0))
        out[f"{name}.noise_scale_mean"] = float(np.mean(s.noise_scale[sm]))
        out[f"{name}.nis_mean"] = float(np.mean(s.nis[sm]))
        out[f"{name}.us_per_step"] = 1e6 * s.wall_s / max(s.t.size, 1)
        out[f"{name}.recoveries"] = float(s.recoveries)


def _turn_metrics(run: RunData, window: tuple[float, float], out: dict[str, float]) -> None:
    t0, t1 = window
    tm = _window(run.t, t0, t1)
    tr = run.truth
    sources: dict[str, tuple[Any, Any, Any, Any, Any]] = {
        "truth": (tr["icr_x"], tr["icr_y"], tr["icr_valid"], tr["slip"], tr["tire_sideslip"])
    }
    for name, s in run.series.items():
        sm = _window(s.t, t0, t1)
        sources[name] = (s.icr_x[sm], s.icr_y[sm], s.icr_valid[sm], s.slip[sm], s.tire_sideslip[sm])
    for src, (ix, iy, ok, slip, alpha) in sources.items():
        if src == "truth":
            ix, iy, ok, slip, alpha = ix[tm], iy[tm], ok[tm], slip[tm], alpha[tm]
        mx, sx, my, sy, _ = icr_statistics(ix, iy, ok)
        out[f"{src}.icr_x_mean"], out[f"{src}.icr_x_std"] = mx, sx
        out[f"{src}.icr_y_mean"], out[f"{src}.icr_y_std"] = my, sy
        out[f"{src}.slip_left"] = float(np.mean(slip[:, 0]))
        out[f"{src}.slip_right"] = float(np.mean(slip[:, 1]))
        deg = np.degrees(np.asarray(alpha, dtype=float))
        for k, wheel in enumerate(WHEEL_NAMES):
            out[f"{src}.alpha_deg.{wheel}"] = float(np.mean(deg[:, k]))
        rear = np.abs(deg[:, [2, 5]])
        out[f"{src}.rear_alpha_abs_mean_deg"] = float(rear.mean())
        out[f"{src}.rear_alpha_abs_max_deg"] = float(rear.max())
        out[f"{src}.negative_alpha_wheels"] = float(np.sum(np.mean(deg, axis=0) < 0.0))
    s = run.series["an_stukf"]  # the encoder yaw rate comes from the wheel speeds: the same for every filter
    sm = _window(s.t, t0, t1)
    r_true = values_at(run.t, tr["yaw_rate"], s.t[sm])
    out["encoder.yaw_rate_minus_true"] = float(np.mean(s.yaw_rate_encoder[sm] - r_true))
    out["encoder.yaw_rate_ratio"] = float(np.mean(s.yaw_rate_encoder[sm]) / np.mean(r_true))
    out["truth.yaw_rate_mean"] = float(np.mean(tr["yaw_rate"][tm]))
    out["truth.vx_mean"] = float(np.mean(tr["vx"][tm]))
    # Physics of the ICR position: lateral force balance and axle loads.
    fy = tr["tire_force_y"][tm]
    out["truth.fy_net"] = float(np.mean(np.abs(fy.sum(axis=1))))
    out["truth.fy_abs_sum"] = float(np.mean(np.abs(fy).sum(axis=1)))
    fz = tr["normal_load"][tm]
    axle_load = fz[:, :3] + fz[:, 3:]
    for k in range(3):
        out[f"truth.axle_load.{k}"] = float(np.mean(axle_load[:, k]))


def _s_icr_metrics(run: RunData, window: tuple[float, float], out: dict[str, float]) -> None:
    tm = _window(run.t, *window)
    tr = run.truth
    out["truth.icr_x_median_early"] = icr_statistics(tr["icr_x"][tm], tr["icr_y"][tm], tr["icr_valid"][tm])[4]
    for name, s in run.series.items():
        sm = _window(s.t, *window)
        out[f"{name}.icr_x_median_early"] = icr_statistics(s.icr_x[sm], s.icr_y[sm], s.icr_valid[sm])[4]


def _straight_metrics(run: RunData, steady_delay: float, out: dict[str, float]) -> None:
    start, end = _ramp(run.speed_times, run.speeds)
    duration = float(run.t[-1])
    steady = (end + steady_delay, duration)
    tr = run.truth
    out["ramp.start"], out["ramp.end"] = start, end
    tm_ramp, tm_steady = _window(run.t, start, end), _window(run.t, *steady)
    out["truth.slip_ramp"] = float(np.mean(tr["slip"][tm_ramp]))
    out["truth.slip_steady"] = float(np.mean(tr["slip"][tm_steady]))
    sources: dict[str, tuple[FloatArray, FloatArray, FloatArray | None]] = {
        name: (s.t, s.vx, s.slip) for name, s in run.series.items()
    }
    enc = run.series["an_stukf"]
    sources["encoder"] = (enc.t, enc.vx_encoder, None)
    for name, (ts, vx, slip) in sources.items():
        out[f"{name}.lag"] = tracking_lag(ts, vx, run.t, tr["vx"], start, end)
        rm, sm = _window(ts, start, end), _window(ts, *steady)
        err_ramp = vx[rm] - values_at(run.t, tr["vx"], ts[rm])
        err_steady = vx[sm] - values_at(run.t, tr["vx"], ts[sm])
        out[f"{name}.ramp_mean_err"] = float(np.mean(err_ramp))
        out[f"{name}.ramp_mae"] = float(np.mean(np.abs(err_ramp)))
        out[f"{name}.steady_mae"] = float(np.mean(np.abs(err_steady)))
        out[f"{name}.steady_mean_err"] = float(np.mean(err_steady))
        if slip is not None:
            out[f"{name}.slip_ramp"] = float(np.mean(slip[rm]))
            out[f"{name}.slip_steady"] = float(np.mean(slip[sm]))
    for name, s in run.series.items():
        out[f"{name}.fading_active"] = float(np.mean(s.fading > 1.0))
        out[f"{name}.us_per_step"] = 1e6 * s.wall_s / max(s.t.size, 1)


def run_metrics(run: RunData, counts: Counts) -> dict[str, float]:
    """Every per-run number of the report (keys ``source.quantity``)."""
    out: dict[str, float] = {"sim_wall_s": run.sim_wall_s}
    case = run.spec.case
    if case in ("small_radius_turn", "turn_mismatch"):
        _sideslip_metrics(run, counts.turn_window, out)
        _turn_metrics(run, counts.turn_window, out)
    elif case == "s_shape":
        _sideslip_metrics(run, counts.s_window, out)
        _s_icr_metrics(run, counts.s_icr_window, out)
    else:
        _straight_metrics(run, counts.steady_delay, out)
    return out


# ---------------------------------------------------------------------------
# Running the plan
# ---------------------------------------------------------------------------


@dataclass
class Results:
    """Per-case metrics of every run, the first run's data (figures) and the truth digests."""

    metrics: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    first: dict[str, RunData] = field(default_factory=dict)
    digests: dict[str, set[str]] = field(default_factory=dict)
    seeds: dict[str, list[int]] = field(default_factory=dict)

    def values(self, case: str, key: str) -> list[float]:
        return [m[key] for m in self.metrics.get(case, []) if key in m]

    def stats(self, case: str, key: str) -> dict[str, float]:
        return _stats(self.values(case, key))

    def mean(self, case: str, key: str) -> float:
        v = self.values(case, key)
        return float(np.mean(v)) if v else math.nan


def _imap(plan: Sequence[RunSpec], jobs: int) -> Iterator[RunData]:
    if jobs <= 1:
        yield from (run_one(spec) for spec in plan)
        return
    with multiprocessing.get_context().Pool(jobs) as pool:
        yield from pool.imap_unordered(run_one, plan, chunksize=1)


def execute(plan: Sequence[RunSpec], counts: Counts, jobs: int, progress: bool = True) -> Results:
    """Run the plan (longest runs first) over ``jobs`` processes; keep metrics, not traces."""
    order = sorted(plan, key=lambda s: -s.duration)
    total = sum(s.duration for s in order)
    done = 0.0
    start = time.monotonic()
    last = -math.inf
    per_case: dict[str, dict[int, dict[str, float]]] = {}
    res = Results()
    for n, run in enumerate(_imap(order, jobs), start=1):
        case = run.spec.case
        per_case.setdefault(case, {})[run.spec.run] = run_metrics(run, counts)
        res.digests.setdefault(case, set()).add(run.truth_digest)
        res.seeds.setdefault(case, []).append(run.seed)
        if run.spec.run == 0:
            res.first[case] = run
        done += run.spec.duration
        now = time.monotonic()
        if progress and (now - last > 5.0 or n == len(order)):
            last = now
            left = (now - start) * (total - done) / max(done, 1e-9)
            print(
                f"  [{n}/{len(order)} runs] {now - start:6.0f} s elapsed, ~{left:5.0f} s left "
                f"(last: {case} run {run.spec.run})",
                file=sys.stderr,
                flush=True,
            )
    res.metrics = {case: [runs[i] for i in sorted(runs)] for case, runs in per_case.items()}
    return res


# ---------------------------------------------------------------------------
# Summary claims
# ---------------------------------------------------------------------------


@dataclass
class SkidReport:
    """The quarter-car report's pieces (figures, sections, "not reproduced") plus the claims."""

    rep: Report
    claims: list[Claim] = field(default_factory=list)

    def claim(
        self, case: str, quantity: str, computed: float, paper: str, criterion: str, holds: bool | None
    ) -> bool | None:
        self.claims.append(Claim(case, quantity, computed, paper, criterion, holds))
        return holds


def _r(x: float) -> str:
    """A value in rad (4 decimals, or 3 significant digits if tiny)."""
    return _fmt(x, 4)


def _diag(values: Sequence[float]) -> str:
    return ", ".join(f"{v:.3g}" for v in values)


def _runs(n: int) -> str:
    return f"{n} run" if n == 1 else f"{n} runs"


def _pct(x: float) -> str:
    return _fmt(100.0 * x, 1)


def _pm(s: dict[str, float], scale: float = 1.0, digits: int = 4) -> str:
    """mean ± std; a spread at floating-point round-off of the mean (a deterministic quantity) shows as 0."""
    std = s["std"] if s["std"] > 1e-9 * max(abs(s["mean"]), 1e-6) else 0.0
    return f"{_fmt(scale * s['mean'], digits)} ± {_fmt(scale * std, digits)}"


# ---------------------------------------------------------------------------
# Sections
# ---------------------------------------------------------------------------


def _sideslip_table(res: Results, case: str, ref: str, paper: Mapping[str, tuple[float, ...]] | None) -> list[str]:
    lines = [
        "| filter | max abs (rad) | max rel (%) | mean abs (rad) | mean rel (%) | std (rad) | "
        f"mean rel, floor {math.degrees(REL_FLOOR):g}° (%) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in FILTERS:
        cells = []
        for stat in _STATS:
            s = res.stats(case, f"{name}.{ref}.{stat}")
            cells.append(_pm(s, 100.0, 1) if "rel" in stat else _pm(s))
        lines.append(f"| {FILTER_NAMES[name]} (mean ± std over runs) | " + " | ".join(cells) + " |")
    if paper is not None:
        for name, vals in paper.items():
            lines.append(
                f"| *paper {FILTER_NAMES[name]}* | {vals[0]} | {vals[1]} | {vals[2]} | {vals[3]} | {vals[4]} | — |"
            )
    return lines


def _fig_sideslip(sk: SkidReport, run: RunData, window: tuple[float, float], fname: str, title: str) -> str:
    plt = _plt()
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    t0, t1 = window
    lo, hi = max(0.0, t0 - 5.0), min(float(run.t[-1]), t1 + 5.0)
    tm = (run.t >= lo) & (run.t <= hi)
    g = run.gnss
    gm = (g["t"] >= lo) & (g["t"] <= hi)
    ax = axes[0]
    ax.plot(g["t"][gm], np.arctan2(g["vy"][gm], g["vx"][gm]), ".", ms=3, color=_COLOURS["gnss"], label="β GNSS (10 Hz)")
    ax.plot(run.t[tm], run.truth["body_sideslip"][tm], color=_COLOURS["truth"], lw=1.5, label="β truth")
    for name, s in run.series.items():
        sm = (s.t >= lo) & (s.t <= hi)
        ax.plot(s.t[sm], s.beta[sm], color=_COLOURS[name], lw=_WIDTHS[name], label=FILTER_NAMES[name])
        err = s.beta[sm] - values_at(run.t, run.truth["body_sideslip"], s.t[sm])
        axes[1].plot(s.t[sm], err, color=_COLOURS[name], lw=_WIDTHS[name], label=FILTER_NAMES[name])
    for a in axes:
        a.axvspan(t0, t1, color="0.92", zorder=0)
    ax.set_ylabel("body sideslip β (rad)")
    ax.legend(fontsize=8, ncol=3)
    ax.set_title(title, fontsize=9)
    axes[1].axhline(0.0, color="k", lw=0.5)
    axes[1].set_ylabel("β̂ − β truth (rad)")
    axes[1].set_xlabel("time (s)  (shaded: analysis window)")
    fig.tight_layout()
    path = sk.rep.fig(fname)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return sk.rep.link(path, title)


def _fig_error_runs(sk: SkidReport, res: Results, counts: Counts) -> str:
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, (case, label) in zip(
        axes, (("small_radius_turn", "small-radius turn"), ("s_shape", "S-shape")), strict=True
    ):
        data, names = [], []
        for ref in ("gnss", "truth"):
            for name in FILTERS:
                data.append(res.values(case, f"{name}.{ref}.mean_abs"))
                names.append(f"{FILTER_NAMES[name]}\nvs {'GNSS' if ref == 'gnss' else 'truth'}")
        ax.boxplot(data)
        ax.set_xticks(range(1, len(names) + 1))
        ax.set_xticklabels(names, fontsize=7)
        ax.set_yscale("log")
        ax.set_ylabel("mean |e_β| per run (rad)")
        ax.set_title(f"{label}: {len(res.metrics.get(case, []))} runs", fontsize=9)
        paper = PAPER_TABLE2 if case == "small_radius_turn" else PAPER_TABLE3
        for name, vals in paper.items():
            ax.axhline(vals[2], ls="--", lw=0.8, color=_COLOURS[name], label=f"paper {FILTER_NAMES[name]}")
        ax.legend(fontsize=7)
    fig.tight_layout()
    path = sk.rep.fig("sideslip_error_runs.png")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return sk.rep.link(path, "per-run mean absolute β error")


def _section_tables(sk: SkidReport, res: Results, counts: Counts) -> None:
    for case, table, window, paper, label in (
        ("small_radius_turn", "Table 2", counts.turn_window, PAPER_TABLE2, "small-radius turn"),
        ("s_shape", "Table 3", counts.s_window, PAPER_TABLE3, "S-shaped path"),
    ):
        if case not in res.metrics:
            continue
        n = len(res.metrics[case])
        t0, t1 = window
        noise = res.stats(case, "gnss.beta_noise_std")
        lines = [
            f"## {table} — {label}: body sideslip angle errors over {t0:g}–{t1:g} s",
            "",
            f"**{_runs(n)}** (sensor-noise seeds differ, truth identical), the three filters on the same sensor data. "
            f"Truth in the window: mean β = {_r(res.mean(case, 'truth.beta_mean'))} rad, mean |β| = "
            f"{_r(res.mean(case, 'truth.beta_mean_abs'))} rad; mean |β_GNSS| = "
            f"{_r(res.mean(case, 'gnss.beta_mean_abs'))} rad; the GNSS β noise (std of β_GNSS − β truth at the "
            f"GNSS stamps) is {_r(noise['mean'])} rad at v_x ≈ {_fmt(res.mean(case, 'gnss.vx_mean'))} m/s. "
            f"The smallest |β| of the truth in the window is {_r(res.mean(case, 'truth.beta_min_abs'))} rad and "
            f"{_pct(res.mean(case, 'gnss.frac_below_floor'))} % of the GNSS samples have |β_GNSS| < "
            f"{math.degrees(REL_FLOOR):g}°: the paper's relative error |e|/|β_ref| is dominated by those samples "
            "(its mean and max explode and vary wildly between runs); the floored column does not.",
            "",
            "**Against the GNSS reference** (the paper's definition: e = β̂ − β_GNSS at the 10 Hz GNSS stamps, "
            "β_GNSS = atan2(v_y,GNSS, v_x,GNSS)):",
            "",
            *_sideslip_table(res, case, "gnss", paper),
            "",
            "**Against the simulator truth at 100 Hz** (e = β̂ − β at every estimate; the paper had no such truth):",
            "",
            *_sideslip_table(res, case, "truth", None),
            "",
        ]
        vy_rows = ", ".join(
            f"{FILTER_NAMES[f]} {_r(res.mean(case, f'{f}.vy_gnss_mae'))} / {_r(res.mean(case, f'{f}.vy_truth_mae'))}"
            for f in FILTERS
        )
        lines += [
            f"Mean |v̂y − v_y| against GNSS / truth (m/s, mean over runs): {vy_rows}. "
            "Mean |v̂x − v_x| against truth (m/s): "
            + ", ".join(f"{FILTER_NAMES[f]} {_r(res.mean(case, f'{f}.vx_truth_mae'))}" for f in FILTERS)
            + ".",
            "",
        ]
        run0 = res.first.get(case)
        if run0 is not None:
            lines += [
                _fig_sideslip(sk, run0, window, f"{case}_sideslip.png", f"{table}: {label}, run 0 (seed {run0.seed})"),
                "",
            ]
        if case == "s_shape":
            lines += [_fig_error_runs(sk, res, counts), ""]
        sk.rep.sections.append("\n".join(lines))
        _claims_table23(sk, res, case, table, paper)


def _claims_table23(
    sk: SkidReport, res: Results, case: str, table: str, paper: Mapping[str, tuple[float, ...]]
) -> None:
    p_ratio = paper["an_stukf"][2] / paper["ukf"][2]
    for ref, ref_text in (("gnss", "vs GNSS"), ("truth", "vs truth 100 Hz")):
        ukf = res.mean(case, f"ukf.{ref}.mean_abs")
        an = res.mean(case, f"an_stukf.{ref}.mean_abs")
        ratio = an / ukf
        if case == "small_radius_turn":
            sk.claim(
                table,
                f"AN-STUKF / UKF mean |e_β| {ref_text}",
                ratio,
                f"{p_ratio:.3f} ({paper['an_stukf'][2]}/{paper['ukf'][2]})",
                "≤ 0.5",
                ratio <= 0.5,
            )
        else:
            sk.claim(
                table,
                f"AN-STUKF / UKF mean |e_β| {ref_text}",
                ratio,
                f"{p_ratio:.3f} ({paper['an_stukf'][2]}/{paper['ukf'][2]})",
                f"≤ {1 + MARGIN:g} (no worse)",
                ratio <= 1.0 + MARGIN,
            )
    for name in ("ukf", "an_stukf"):
        sk.claim(
            table,
            f"{FILTER_NAMES[name]} mean |e_β| vs GNSS (rad)",
            res.mean(case, f"{name}.gnss.mean_abs"),
            f"{paper[name][2]}",
            "—",
            None,
        )
        sk.claim(
            table,
            f"{FILTER_NAMES[name]} mean relative |e_β| vs GNSS (%)",
            100.0 * res.mean(case, f"{name}.gnss.mean_rel"),
            f"{paper[name][3]}",
            "—",
            None,
        )


def _fig_straight(sk: SkidReport, run: RunData) -> str:
    plt = _plt()
    start, end = _ramp(run.speed_times, run.speeds)
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    axes[0].plot(run.t, run.truth["vx"], color=_COLOURS["truth"], lw=1.5, label="v_x truth")
    enc = run.series["an_stukf"]
    axes[0].plot(enc.t, enc.vx_encoder, color="tab:orange", lw=0.8, label="encoder R(ω_l+ω_r)/2")
    axes[1].plot(
        enc.t, enc.vx_encoder - values_at(run.t, run.truth["vx"], enc.t), color="tab:orange", lw=0.8, label="encoder"
    )
    for name, s in run.series.items():
        axes[0].plot(s.t, s.vx, color=_COLOURS[name], lw=_WIDTHS[name], label=FILTER_NAMES[name])
        axes[1].plot(s.t, s.vx - values_at(run.t, run.truth["vx"], s.t), color=_COLOURS[name], lw=_WIDTHS[name])
    for a in axes:
        a.axvspan(start, end, color="0.92", zorder=0)
    axes[0].set_ylabel("v_x (m/s)")
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"Straight acceleration, run 0 (seed {run.seed}); shaded: speed ramp", fontsize=9)
    axes[1].set_ylabel("v̂_x − v_x (m/s)")
    axes[1].set_ylim(-0.3, 0.3)
    axes[1].axhline(0.0, color="k", lw=0.5)
    axes[1].set_xlabel("time (s)")
    fig.tight_layout()
    path = sk.rep.fig("straight_acceleration_vx.png")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return sk.rep.link(path, "straight acceleration")


def _section_straight(sk: SkidReport, res: Results, counts: Counts) -> None:
    case = "straight_acceleration"
    if case not in res.metrics:
        return
    n = len(res.metrics[case])
    start, end = res.mean(case, "ramp.start"), res.mean(case, "ramp.end")
    lines = [
        "## Straight acceleration 0 → 30 km/h: tracking of v_x",
        "",
        f"**{_runs(n)}**. Speed ramp of the reference: {start:g}–{end:.2f} s (from the manoeuvre's speed knots), "
        f"steady speed from {end + counts.steady_delay:.2f} s to the end ({counts.straight_duration:g} s).",
        "",
        "Definitions. **Lag τ**: the time shift that best aligns v̂x(t) with the delayed truth v_x(t − τ) over the "
        "ramp in the least-squares sense (grid of 1 ms over ±1 s, parabolic refinement); τ > 0 means the estimate "
        "lags, τ < 0 that it leads (e.g. a constant over-estimate b on a ramp of slope a gives τ = −b/a). "
        "**Ramp error**: mean signed and mean absolute v̂x − v_x over the ramp. **Steady**: mean |v̂x − v_x| at "
        "steady speed. The encoder-only speed R(ω_l + ω_r)/2 is shown for reference.",
        "",
        "| estimate | lag τ (s) | mean \\|τ\\| (s) | ramp mean error (m/s) | ramp mean \\|error\\| (m/s) | "
        "steady mean \\|error\\| (m/s) | side slip on the ramp | at steady speed |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in (*FILTERS, "encoder"):
        label = FILTER_NAMES.get(name, "encoder only")
        lag = res.stats(case, f"{name}.lag")
        abs_lag = float(np.mean(np.abs(res.values(case, f"{name}.lag"))))
        slip = (
            f"{_pm(res.stats(case, f'{name}.slip_ramp'))} | {_pm(res.stats(case, f'{name}.slip_steady'))}"
            if name != "encoder"
            else f"{_pm(res.stats(case, 'truth.slip_ramp'))} (truth) | "
            f"{_pm(res.stats(case, 'truth.slip_steady'))} (truth)"
        )
        lines.append(
            f"| {label} | {_pm(lag)} | {_fmt(abs_lag, 4)} | {_pm(res.stats(case, f'{name}.ramp_mean_err'))} | "
            f"{_pm(res.stats(case, f'{name}.ramp_mae'))} | {_pm(res.stats(case, f'{name}.steady_mae'))} | {slip} |"
        )
    lines += [
        "",
        "At steady speed every filter sits near the encoder speed (mean signed error "
        + ", ".join(f"{FILTER_NAMES[f]} {_fmt(res.mean(case, f'{f}.steady_mean_err'), 4)}" for f in FILTERS)
        + f", encoder {_fmt(res.mean(case, 'encoder.steady_mean_err'), 4)} m/s): the truth needs a positive slip "
        f"(κ = {_fmt(res.mean(case, 'truth.slip_steady'), 4)}) to overcome the motion resistance, which the "
        f"observer does not model (its slip estimate: {_fmt(res.mean(case, 'an_stukf.slip_steady'), 4)}).",
        "",
        "Strong tracking active (λ > 1) on a fraction of the steps of the whole run: "
        + ", ".join(f"{FILTER_NAMES[f]} {_pct(res.mean(case, f'{f}.fading_active'))} %" for f in FILTERS)
        + ".",
        "",
    ]
    run0 = res.first.get(case)
    if run0 is not None:
        lines += [_fig_straight(sk, run0), ""]
    sk.rep.sections.append("\n".join(lines))
    ukf_lag = float(np.mean(np.abs(res.values(case, "ukf.lag"))))
    an_lag = float(np.mean(np.abs(res.values(case, "an_stukf.lag"))))
    sk.claim(
        "accel",
        "AN-STUKF / UKF mean |lag τ| over the ramp",
        an_lag / ukf_lag if ukf_lag > 0 else math.inf,
        "< 1 (AN-STUKF faster, Fig. of the straight run)",
        f"≤ {1 - MARGIN:g}",
        an_lag <= (1 - MARGIN) * ukf_lag,
    )
    ratio = res.mean(case, "an_stukf.ramp_mae") / res.mean(case, "ukf.ramp_mae")
    sk.claim(
        "accel",
        "AN-STUKF / UKF mean |v̂x − v_x| over the ramp",
        ratio,
        "< 1 (AN-STUKF faster)",
        f"≤ {1 - MARGIN:g}",
        ratio <= 1 - MARGIN,
    )
    ratio = res.mean(case, "an_stukf.steady_mae") / res.mean(case, "ukf.steady_mae")
    sk.claim(
        "accel",
        "AN-STUKF / UKF mean |v̂x − v_x| at steady speed",
        ratio,
        "≈ 1 (equal at steady speed)",
        f"within 1 ± {MARGIN:g}",
        abs(ratio - 1.0) <= MARGIN,
    )
    ramp, steady = res.mean(case, "truth.slip_ramp"), res.mean(case, "truth.slip_steady")
    sk.claim(
        "accel",
        "truth side slip on the ramp (mean of both sides)",
        ramp,
        "rises while accelerating, ≈ 0 at steady speed",
        f"> steady ({_fmt(steady, 4)})",
        ramp > steady,
    )


def _fig_icr(sk: SkidReport, run: RunData, window: tuple[float, float], params: SkidSteerParams) -> str:
    plt = _plt()
    t0, t1 = window
    fig = plt.figure(figsize=(10, 7))
    ax_plan = fig.add_subplot(1, 2, 1)
    ax_x = fig.add_subplot(2, 2, 2)
    ax_y = fig.add_subplot(2, 2, 4, sharex=ax_x)
    xa = axle_positions(params)
    half = 0.5 * params.track
    for x in xa:
        ax_plan.plot([x, x], [-half, half], color="0.4", lw=1)
        ax_plan.plot([x, x], [-half, half], "s", color="0.4", ms=6)
    ax_plan.plot([xa[-1], xa[0]], [0, 0], color="0.7", lw=0.8)
    ax_plan.plot(0, 0, "+", color="k", ms=10, label="CM")
    ax_plan.axvline(xa[0], ls=":", color="0.4", lw=0.8, label=f"front axle x = {xa[0]:.3f} m")
    ax_plan.axvline(_PAPER_ICR_X, ls="--", color="tab:purple", lw=0.8, label=f"paper ICR_x ≈ {_PAPER_ICR_X:g} m")
    tm = _window(run.t, t0, t1) & run.truth["icr_valid"].astype(bool)
    ax_plan.plot(run.truth["icr_x"][tm], run.truth["icr_y"][tm], ".", ms=2, color="k", label="truth")
    ax_x.plot(run.t, np.where(run.truth["icr_valid"], run.truth["icr_x"], np.nan), color="k", lw=1.2, label="truth")
    ax_y.plot(run.t, np.where(run.truth["icr_valid"], run.truth["icr_y"], np.nan), color="k", lw=1.2)
    for name, s in run.series.items():
        sm = _window(s.t, t0, t1) & s.icr_valid
        ax_plan.plot(s.icr_x[sm], s.icr_y[sm], ".", ms=1.5, color=_COLOURS[name], alpha=0.5, label=FILTER_NAMES[name])
        lw = 0.8 * _WIDTHS[name]
        ax_x.plot(s.t, np.where(s.icr_valid, s.icr_x, np.nan), color=_COLOURS[name], lw=lw, label=FILTER_NAMES[name])
        ax_y.plot(s.t, np.where(s.icr_valid, s.icr_y, np.nan), color=_COLOURS[name], lw=lw)
    ax_plan.set_aspect("equal", adjustable="datalim")
    ax_plan.set_xlabel("x body (m, forward)")
    ax_plan.set_ylabel("y body (m, left)")
    ax_plan.set_title(f"ICR over {t0:g}–{t1:g} s in the body frame", fontsize=9)
    ax_plan.legend(fontsize=7, loc="upper right")
    for a in (ax_x, ax_y):
        a.axvspan(t0, t1, color="0.92", zorder=0)
    ax_x.axhline(xa[0], ls=":", color="0.4", lw=0.8)
    ax_x.axhline(_PAPER_ICR_X, ls="--", color="tab:purple", lw=0.8)
    ax_x.set_ylim(-4.0, 4.0)
    ax_x.set_ylabel("ICR_x (m)")
    ax_x.legend(fontsize=7)
    ax_y.set_ylim(0.0, 20.0)
    ax_y.set_ylabel("ICR_y (m)")
    ax_y.set_xlabel("time (s)")
    fig.suptitle(f"Small-radius turn, run 0 (seed {run.seed}): instantaneous centre of rotation", fontsize=10)
    fig.tight_layout()
    path = sk.rep.fig("small_radius_turn_icr.png")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return sk.rep.link(path, "ICR trace")


def _section_icr(sk: SkidReport, res: Results, counts: Counts) -> None:
    case = "small_radius_turn"
    if case not in res.metrics:
        return
    params = SkidSteerParams()
    front = float(axle_positions(params)[0])
    t0, t1 = counts.turn_window
    lines = [
        f"## ICR in the small-radius turn ({t0:g}–{t1:g} s)",
        "",
        "ICR in body axes (eq. 41): ICR_x = −v_y/r, ICR_y = v_x/r, over the samples with |r| > 0.02 rad/s. Per run "
        "the mean and std over the window; the table gives the mean over runs of each (± the std over runs). "
        f"Front axle at x = {front:+.3f} m (axle positions {', '.join(f'{x:+.3f}' for x in axle_positions(params))} "
        "m relative to the CM).",
        "",
        "| source | ICR_x mean (m) | ICR_x std within run (m) | ICR_y mean (m) | ICR_y std within run (m) | "
        "ahead of the front axle? |",
        "|---|---|---|---|---|---|",
    ]
    for src in ("truth", *FILTERS):
        mx = res.stats(case, f"{src}.icr_x_mean")
        lines.append(
            f"| {FILTER_NAMES.get(src, 'truth')} | {_pm(mx, digits=3)} | {_fmt(res.mean(case, f'{src}.icr_x_std'), 3)} "
            f"| {_pm(res.stats(case, f'{src}.icr_y_mean'), digits=3)} | "
            f"{_fmt(res.mean(case, f'{src}.icr_y_std'), 3)} | {'yes' if mx['mean'] > front else 'no'} |"
        )
    lines.append(f"| *paper* | ≈ {_PAPER_ICR_X:g} | — | on the left (> 0) | — | yes |")
    vx, r = res.mean(case, "truth.vx_mean"), res.mean(case, "truth.yaw_rate_mean")
    implied = math.atan2(-_PAPER_ICR_X * r, vx)
    lines += [
        "",
        f"An ICR at x = {_PAPER_ICR_X:g} m at this turn's v_x = {_fmt(vx, 3)} m/s and r = {_fmt(r, 3)} rad/s would "
        f"need v_y = −ICR_x·r = {_fmt(-_PAPER_ICR_X * r, 3)} m/s, i.e. β = {_r(implied)} rad; the truth's mean β "
        f"over the window is {_r(res.mean(case, 'truth.beta_mean'))} rad.",
        "",
    ]
    run0 = res.first.get(case)
    if run0 is not None:
        lines += [_fig_icr(sk, run0, counts.turn_window, params), ""]
    s_case = "s_shape"
    if s_case in res.metrics:
        a, b = counts.s_icr_window
        lines += [
            f"S-shape at 30 km/h, {a:g}–{b:g} s (the paper's ICR window): median ICR_x over the valid samples, "
            f"mean over runs: truth {_fmt(res.mean(s_case, 'truth.icr_x_median_early'), 3)} m, "
            + ", ".join(f"{FILTER_NAMES[f]} {_fmt(res.mean(s_case, f'{f}.icr_x_median_early'), 3)} m" for f in FILTERS)
            + f" (small-radius turn, truth: {_fmt(res.mean(case, 'truth.icr_x_mean'), 3)} m). The median is used "
            "because ICR_x = −v_y/r is ill-conditioned where r crosses zero between the lobes.",
            "",
        ]
    sk.rep.sections.append("\n".join(lines))
    for src in ("truth", "an_stukf", "ukf"):
        value = res.mean(case, f"{src}.icr_x_mean")
        sk.claim(
            "ICR",
            f"{FILTER_NAMES.get(src, 'truth')} ICR_x, mean over {t0:g}–{t1:g} s (m)",
            value,
            f"≈ {_PAPER_ICR_X:g} (ahead of the front axle)",
            f"> front axle {front:.3f}",
            value > front,
        )
    value = res.mean(case, "truth.icr_y_mean")
    sk.claim("ICR", "truth ICR_y, mean (m)", value, "> 0 (on the left)", "> 0", value > 0.0)
    if s_case in res.metrics:
        s_val = res.mean(s_case, "truth.icr_x_median_early")
        turn_val = res.mean(case, "truth.icr_x_mean")
        a, b = counts.s_icr_window
        sk.claim(
            "ICR",
            f"truth ICR_x on the S-shape at 30 km/h, {a:g}–{b:g} s, median (m)",
            s_val,
            "shifts forward at speed",
            f"> turn ({_fmt(turn_val, 3)})",
            s_val > turn_val,
        )


def _fig_turn(sk: SkidReport, run: RunData, window: tuple[float, float]) -> str:
    plt = _plt()
    t0, t1 = window
    fig, axes = plt.subplots(3, 1, figsize=(9, 8.5), sharex=True)
    an = run.series["an_stukf"]
    for k, (side, ls) in enumerate((("left", "-"), ("right", "--"))):
        axes[0].plot(run.t, run.truth["slip"][:, k], ls, color="k", lw=1.2, label=f"truth {side}")
        axes[0].plot(an.t, an.slip[:, k], ls, color=_COLOURS["an_stukf"], lw=0.8, label=f"AN-STUKF {side}")
    axes[0].set_ylabel("side slip κ")
    axes[0].set_ylim(-0.6, 0.6)
    axes[0].legend(fontsize=7, ncol=2)
    axes[1].plot(run.t, run.truth["yaw_rate"], color="k", lw=1.2, label="r truth")
    axes[1].plot(an.t, an.yaw_rate_encoder, color="tab:orange", lw=0.8, label="encoder R(ω_r − ω_l)/B")
    axes[1].plot(an.t, an.yaw_rate, color=_COLOURS["an_stukf"], lw=0.8, label="AN-STUKF")
    axes[1].set_ylabel("yaw rate (rad/s)")
    axes[1].legend(fontsize=7)
    deg = np.degrees(run.truth["tire_sideslip"])
    for k, wheel in enumerate(WHEEL_NAMES):
        axes[2].plot(run.t, deg[:, k], lw=0.9, label=f"{wheel} truth")
    for lim in (-_PAPER_REAR_SIDESLIP_DEG, _PAPER_REAR_SIDESLIP_DEG):
        axes[2].axhline(lim, ls="--", color="tab:purple", lw=0.8)
    axes[2].set_ylabel("tire sideslip α (deg)")
    axes[2].set_ylim(-40, 40)
    axes[2].legend(fontsize=7, ncol=6)
    axes[2].set_xlabel("time (s)")
    for a in axes:
        a.axvspan(t0, t1, color="0.92", zorder=0)
    axes[0].set_title(f"Small-radius turn, run 0 (seed {run.seed}): slips, yaw rate, tire sideslip", fontsize=9)
    fig.tight_layout()
    path = sk.rep.fig("small_radius_turn_observations.png")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return sk.rep.link(path, "turn observations")


def _section_turn_obs(sk: SkidReport, res: Results, counts: Counts) -> None:
    case = "small_radius_turn"
    if case not in res.metrics:
        return
    t0, t1 = counts.turn_window
    lines = [
        f"## Other observations of the paper in the small-radius turn ({t0:g}–{t1:g} s)",
        "",
        "Means over the window, mean ± std over runs. Side slip κ per side (B.3, > 0 in traction); tire sideslip "
        "α per wheel (eq. 6, degrees; wheel order FL, ML, RL, FR, MR, RR); encoder yaw rate R(ω_r − ω_l)/B from "
        "the measured motor speeds.",
        "",
        "| source | κ left | κ right | " + " | ".join(f"α {w} (°)" for w in WHEEL_NAMES) + " | rear \\|α\\| mean (°) | "
        "rear \\|α\\| max (°) |",
        "|---|---|---|" + "---|" * len(WHEEL_NAMES) + "---|---|",
    ]
    for src in ("truth", *FILTERS):
        alphas = " | ".join(_fmt(res.mean(case, f"{src}.alpha_deg.{w}"), 1) for w in WHEEL_NAMES)
        lines.append(
            f"| {FILTER_NAMES.get(src, 'truth')} | {_pm(res.stats(case, f'{src}.slip_left'), digits=3)} | "
            f"{_pm(res.stats(case, f'{src}.slip_right'), digits=3)} | {alphas} | "
            f"{_fmt(res.mean(case, f'{src}.rear_alpha_abs_mean_deg'), 1)} | "
            f"{_fmt(res.mean(case, f'{src}.rear_alpha_abs_max_deg'), 1)} |"
        )
    lines += [
        f"| *paper* | < 0 | > 0 | all < 0 | | | | | | beyond ≈ {_PAPER_REAR_SIDESLIP_DEG:g} | |",
        "",
        f"Encoder yaw rate minus true yaw rate: {_pm(res.stats(case, 'encoder.yaw_rate_minus_true'))} rad/s "
        f"(encoder / true = {_fmt(res.mean(case, 'encoder.yaw_rate_ratio'), 3)}; true r = "
        f"{_fmt(res.mean(case, 'truth.yaw_rate_mean'), 4)} rad/s).",
        "",
        "Filter internals over the window (mean over runs): strong tracking active (λ > 1) on "
        + ", ".join(f"{FILTER_NAMES[f]} {_pct(res.mean(case, f'{f}.fading_active'))} %" for f in FILTERS)
        + " of the steps; mean NIS "
        + ", ".join(f"{FILTER_NAMES[f]} {_fmt(res.mean(case, f'{f}.nis_mean'), 3)}" for f in FILTERS)
        + f" (3 for a consistent filter); AN-STUKF noise scale 1 + K_q ᾱ = "
        f"{_fmt(res.mean(case, 'an_stukf.noise_scale_mean'), 3)}; filter recoveries "
        + ", ".join(f"{FILTER_NAMES[f]} {_fmt(sum(res.values(case, f'{f}.recoveries')), 0)}" for f in FILTERS)
        + "; estimator cost "
        + ", ".join(f"{FILTER_NAMES[f]} {_fmt(res.mean(case, f'{f}.us_per_step'), 0)} µs" for f in FILTERS)
        + " per sample.",
        "",
    ]
    run0 = res.first.get(case)
    if run0 is not None:
        lines += [_fig_turn(sk, run0, counts.turn_window), ""]
    sk.rep.sections.append("\n".join(lines))
    for src in ("truth", "an_stukf"):
        label = FILTER_NAMES.get(src, "truth")
        right, left = res.mean(case, f"{src}.slip_right"), res.mean(case, f"{src}.slip_left")
        sk.claim("turn", f"{label} right (outer) side slip κ_r", right, "> 0", "> 0", right > 0.0)
        sk.claim("turn", f"{label} left (inner) side slip κ_l", left, "< 0", "< 0", left < 0.0)
    diff = res.mean(case, "encoder.yaw_rate_minus_true")
    sk.claim("turn", "encoder yaw rate − true yaw rate (rad/s)", diff, "> 0 (encoder too large)", "> 0", diff > 0.0)
    rear = res.mean(case, "truth.rear_alpha_abs_mean_deg")
    sk.claim(
        "turn",
        "truth rear tire |α|, mean (°)",
        rear,
        f"beyond ≈ {_PAPER_REAR_SIDESLIP_DEG:g}",
        f"≥ {_PAPER_REAR_SIDESLIP_DEG:g}",
        rear >= _PAPER_REAR_SIDESLIP_DEG,
    )
    neg = res.mean(case, "truth.negative_alpha_wheels")
    sk.claim("turn", "truth: wheels with mean α < 0 (of 6)", neg, "6 (all α negative)", "= 6", neg >= 6.0)


def _section_mismatch(sk: SkidReport, res: Results, counts: Counts) -> None:
    case = "turn_mismatch"
    if case not in res.metrics:
        return
    t0, t1 = counts.turn_window
    n = len(res.metrics[case])
    lines = [
        "## Sensitivity (not in the paper): the turn with tires the observer does not know",
        "",
        f"**{_runs(n)}** of the small-radius turn (same sensor-noise seeds as the first {_runs(n)} of the turn) "
        "with the truth's tires changed through the plant's effect catalogue: "
        + f"`cornering_stiffness_change={_MISMATCH_CORNERING:g}`, `friction_change={_MISMATCH_FRICTION:g}`"
        + " (C_α and μ of the truth scaled; the observer keeps Table 1's C_α and μ = "
        f"{SkidSteerParams().friction:g}). This is a check of whether the AN-STUKF's adaptive noise helps when "
        "the tire model is wrong, the situation it was designed for; it is not tuned to anything.",
        "",
        *_sideslip_table(res, case, "truth", None),
        "",
        f"Errors against the truth at 100 Hz over {t0:g}–{t1:g} s. Mean NIS: "
        + ", ".join(f"{FILTER_NAMES[f]} {_fmt(res.mean(case, f'{f}.nis_mean'), 3)}" for f in FILTERS)
        + "; strong tracking active on "
        + ", ".join(f"{FILTER_NAMES[f]} {_pct(res.mean(case, f'{f}.fading_active'))} %" for f in FILTERS)
        + " of the steps; truth ICR_x "
        + f"{_fmt(res.mean(case, 'truth.icr_x_mean'), 3)} m, mean β {_r(res.mean(case, 'truth.beta_mean'))} rad.",
        "",
    ]
    sk.rep.sections.append("\n".join(lines))
    ratio = res.mean(case, "an_stukf.truth.mean_abs") / res.mean(case, "ukf.truth.mean_abs")
    sk.claim("sensitivity", "tire mismatch: AN-STUKF / UKF mean |e_β| vs truth", ratio, "—", "—", None)


def _not_reproduced(sk: SkidReport, res: Results, counts: Counts) -> list[str]:
    """Bullets for every failed claim, with the computed evidence of why."""
    out: list[str] = []
    failed = [c for c in sk.claims if c.holds is False]
    if not failed:
        return out
    turn, s_case = "small_radius_turn", "s_shape"
    params = SkidSteerParams()
    cfg = SkidSteerEstimatorConfig.paper()
    xa = axle_positions(params)
    front = float(xa[0])
    if any(c.case in ("Table 2", "Table 3", "accel") for c in failed):
        mismatch = "turn_mismatch"
        mismatch_ratio = res.mean(mismatch, "an_stukf.truth.mean_abs") / res.mean(mismatch, "ukf.truth.mean_abs")
        fading = {f: res.mean(turn, f"{f}.fading_active") for f in FILTERS}
        turn_ratio = res.mean(turn, "an_stukf.truth.mean_abs") / res.mean(turn, "ukf.truth.mean_abs")
        s_ratio = res.mean(s_case, "an_stukf.truth.mean_abs") / res.mean(s_case, "ukf.truth.mean_abs")
        accel = "straight_acceleration"
        out.append(
            "- **AN-STUKF vs UKF (Tables 2, 3, straight run).** The three filters give nearly the same estimates: "
            f"AN-STUKF / UKF mean |e_β| against the truth is {_fmt(turn_ratio, 3)} in the turn and "
            f"{_fmt(s_ratio, 3)} on the S-shape, and their v_x lags on the ramp are "
            + ", ".join(f"{FILTER_NAMES[f]} {_fmt(res.mean(accel, f'{f}.lag'), 4)} s" for f in FILTERS)
            + ". Why: (1) **strong tracking never fires** (λ > 1 on "
            + ", ".join(f"{FILTER_NAMES[f]} {_pct(fading[f])} %" for f in FILTERS)
            + " of the turn's steps), so STUKF = UKF. Its test e_kᵀe_k > γ_th·tr(P_zz) (γ_th = "
            f"{cfg.strong_tracking.gamma_th:g}) asks for innovations {cfg.strong_tracking.gamma_th:g} times larger "
            "than the filter expects, while the mean NIS is "
            + ", ".join(f"{FILTER_NAMES[f]} {_fmt(res.mean(turn, f'{f}.nis_mean'), 3)}" for f in FILTERS)
            + " (3 for a consistent filter): the default R0 of the accelerations, "
            f"{_diag(cfg.r0_diag[:1])} (m/s²)², is "
            f"{_fmt(cfg.r0_diag[0] / SkidSteerSensors().accel_noise_std ** 2, 1)} × the simulated accelerometer "
            "noise variance, and the observer shares its tire and load physics with the truth (which adds only "
            "roll/pitch load-transfer dynamics and tire relaxation). (2) **The adaptive noise has no growing model "
            "error to absorb**: it scales Q up and R down with the mean tire sideslip (noise scale "
            f"{_fmt(res.mean(turn, 'an_stukf.noise_scale_mean'), 3)} in the turn), which lets more sensor noise "
            "into the estimate; with the model this close to the truth the UKF's error against the truth is "
            f"{_r(res.mean(turn, 'ukf.truth.mean_abs'))} rad (the paper's UKF: {PAPER_TABLE2['ukf'][2]} rad against "
            "its GNSS), and the AN-STUKF's is the same or slightly larger. The sensitivity case with softer, less "
            "grippy truth tires (C_α × "
            f"{_MISMATCH_CORNERING:g}, μ × {_MISMATCH_FRICTION:g}; mean NIS UKF "
            f"{_fmt(res.mean('turn_mismatch', 'ukf.nis_mean'), 3)}, strong tracking active on "
            f"{_pct(res.mean('turn_mismatch', 'stukf.fading_active'))} % of the STUKF's steps) does not change "
            f"that: AN-STUKF / UKF = {_fmt(mismatch_ratio, 3)}. The paper's vehicle had real model errors "
            "(terrain, suspension, tire) and its Q/R, gains and thresholds are not given; nothing in the plant or "
            "the filters was changed here to create an advantage."
        )
        out.append(
            f"- **Against GNSS the errors are GNSS noise.** At 5 km/h the GNSS β noise is "
            f"{_r(res.mean(turn, 'gnss.beta_noise_std'))} rad "
            f"(σ_v = {_fmt(SkidSteerSensors().gnss_velocity_noise_std, 3)} m/s over v_x) while the truth's mean "
            f"|β| is {_r(res.mean(turn, 'truth.beta_mean_abs'))} rad, so every "
            "filter's error against the GNSS reference, and its ratio to |β_GNSS|, measures the reference's noise: "
            "the paper's relative errors (|e|/|β_ref|) explode here (see Table 2's max/mean rel); the floored "
            "column and the truth table are the meaningful ones."
        )
    if any(c.case == "ICR" or c.quantity.startswith("truth: wheels") or "rear tire" in c.quantity for c in failed):
        loads = [res.mean(turn, f"truth.axle_load.{k}") for k in range(3)]
        centroid = sum(w * x for w, x in zip(loads, xa, strict=True)) / sum(loads)
        mass = params.mass
        vx, r = res.mean(turn, "truth.vx_mean"), res.mean(turn, "truth.yaw_rate_mean")
        out.append(
            f"- **ICR near the CM, not ahead of the front axle.** The truth puts the ICR at x = "
            f"{_fmt(res.mean(turn, 'truth.icr_x_mean'), 3)} m (filters "
            + ", ".join(f"{FILTER_NAMES[f]} {_fmt(res.mean(turn, f'{f}.icr_x_mean'), 3)} m" for f in FILTERS)
            + f"), not beyond the front axle at {front:+.3f} m. This is what the shared physics gives, explained "
            "by the lateral force balance: the lateral tire forces must sum to the centripetal force m·v_x·r = "
            f"{_fmt(mass * vx * r, 0)} N, while their magnitudes sum to "
            f"{_fmt(res.mean(turn, 'truth.fy_abs_sum'), 0)} N "
            f"(net |ΣF_y| = {_fmt(res.mean(turn, 'truth.fy_net'), 0)} N): at 5 km/h they almost cancel, so the ICR "
            "(where the lateral sliding velocity changes sign) sits where the axles ahead of it and behind it "
            "carry equal lateral force. With the axle loads "
            + ", ".join(f"{w:.0f}" for w in loads)
            + f" N (front, middle, rear; nearly equal) that is near the load-weighted axle centroid x = "
            f"{centroid:+.3f} m. An ICR at x ≈ {_PAPER_ICR_X:g} m would put every axle's lateral velocity on the same "
            f"side (β ≈ {_r(math.atan2(-_PAPER_ICR_X * r, vx))} rad) and so all six lateral forces in the same "
            "direction: with magnitudes like the ones this turn produces, a net lateral force "
            f"{_fmt(res.mean(turn, 'truth.fy_abs_sum') / max(mass * vx * r, 1e-9), 0)} times the centripetal force, "
            "which nothing in a 5 km/h turn balances; the same balance makes the front tires' α "
            f"positive (truth: mean α FL {_fmt(res.mean(turn, 'truth.alpha_deg.FL'), 1)}°, FR "
            f"{_fmt(res.mean(turn, 'truth.alpha_deg.FR'), 1)}°) and keeps the rear |α| at "
            f"{_fmt(res.mean(turn, 'truth.rear_alpha_abs_mean_deg'), 1)}°, not beyond {_PAPER_REAR_SIDESLIP_DEG:g}°. "
            "What put the paper's ICR ahead of the front axle (terrain, the rocker arms, a measurement effect of "
            "the GNSS β) cannot be recovered from its text; it is not what this physics gives, and nothing was "
            "tuned to move the ICR."
        )
    covered = {"Table 2", "Table 3", "accel", "ICR"}
    for c in failed:
        if c.case not in covered and not c.quantity.startswith("truth: wheels") and "rear tire" not in c.quantity:
            out.append(f"- **{c.case}: {c.quantity}** = {c.computed:.4g} (paper: {c.paper}; criterion {c.criterion}).")
    return out


# ---------------------------------------------------------------------------
# Report assembly
# ---------------------------------------------------------------------------


def _write_report(
    sk: SkidReport,
    res: Results,
    counts: Counts,
    argv: Sequence[str],
    jobs: int,
    wall: float,
    cpu: float,
    quick: bool,
    n_runs: int,
) -> Path:
    rep = sk.rep
    command = "python -m terrain_analysis.tools.reproduce_skid " + " ".join(argv)
    deterministic = ", ".join(
        f"{case}: {'yes' if len(d) == 1 else f'NO ({len(d)} different)'}" for case, d in sorted(res.digests.items())
    )
    sensors = SkidSteerSensors()
    cfg = SkidSteerEstimatorConfig.paper()
    st = cfg.strong_tracking
    n_claims = sum(c.holds is not None for c in sk.claims)
    n_hold = sum(c.holds is True for c in sk.claims)
    failed = sum(c.holds is False for c in sk.claims)
    header = [
        "# Skid-steer motion states — reproduction of the AN-STUKF paper (UKF, STUKF, AN-STUKF)",
        "",
        "Written by the command, not by hand: every number below was computed by this project's simulator and "
        "estimator when the command ran; the paper's values are the comparison column only (DESIGN.md). Nothing "
        "in the truth plant, the noise or the seeds was tuned towards the paper.",
        "",
        f"- Command: `{command.strip()}`" + ("  (**--quick smoke run: too few runs to compare**)" if quick else ""),
        f"- Git revision: `{_git_revision()}`",
        f"- Wall time: {wall:.0f} s on {jobs} worker process(es), {n_runs} simulated runs; CPU time {cpu:.0f} s "
        "(this process and its workers; the wall time is longer when the machine is shared)",
        f"- Run counts: small-radius turn {len(res.metrics.get('small_radius_turn', []))} runs "
        f"({counts.turn_duration:g} s), S-shape {len(res.metrics.get('s_shape', []))} runs ({counts.s_duration:g} s), "
        f"straight acceleration {len(res.metrics.get('straight_acceleration', []))} runs "
        f"({counts.straight_duration:g} s), tire-mismatch sensitivity {len(res.metrics.get('turn_mismatch', []))} "
        f"runs ({counts.turn_duration:g} s). Mean ± std are over runs.",
        f"- Seeds: run i of manoeuvre group g uses the sensor-noise seed "
        f"`numpy.random.SeedSequence([{ROOT_SEED}, g, i]).generate_state(1)[0]`; groups: 1 = straight "
        "acceleration, 2 = small-radius turn (and the mismatch sensitivity: paired), 3 = S-shape. The seed "
        "drives only the sensor noise (IMU, encoders, GNSS): the truth plant is deterministic for a given "
        f"scenario. Truth identical in every run (digest of v_x, v_y, r): {deterministic}.",
        "- Truth: `vehicle_sim.plants.skid_steer.simulate_skid_steer` on the scenarios of `MANOEUVRES` "
        "(RK4, 2 ms steps; the plant's magic-formula tire, wheel-side drive dynamics, motion resistance, "
        "roll/pitch load-transfer dynamics and tire relaxation on; a cascaded PI driver tracks the speed and "
        "yaw-rate references). Sensors at 100 Hz: "
        f"accelerometer σ = {sensors.accel_noise_std:g} m/s², gyro σ = {sensors.gyro_noise_std:g} rad/s, motor "
        f"encoders {sensors.encoder_counts_per_revolution} counts/rev with σ = {sensors.motor_velocity_noise_std:g}"
        f" rad/s on the velocity; RTK-GNSS reference at {sensors.gnss_rate:g} Hz with σ = "
        f"{sensors.gnss_velocity_noise_std:g} m/s on the body-frame v_x, v_y.",
        "- Estimator: `SkidSteerEstimator` with its defaults (MODELS.md B.7–B.10): α = "
        f"{cfg.ukf_alpha:g}, β = {cfg.ukf_beta:g}, κ = {cfg.ukf_kappa:g}; Q0 = diag({_diag(cfg.q0_diag)}) per "
        f"{cfg.q_step_dt * 1e3:g} ms, R0 = diag({_diag(cfg.r0_diag)}); strong tracking ρ = {st.rho:g}, "
        f"γ_th = {st.gamma_th}, λ_max = {st.lambda_max:g}; adaptive noise K_q = {cfg.k_q:g}, "
        f"K_r = {cfg.k_r:g} rad⁻¹. Each filter is "
        "fed the same samples: the motor speeds, then the IMU sample of the same stamp.",
        "- Error definitions (MODELS.md D.2): e = β̂ − β_ref; max |e|, max |e|/|β_ref|, mean |e|, mean "
        "|e|/|β_ref|, std of e (population). β_ref = β_GNSS = atan2(v_y,GNSS, v_x,GNSS) at the 10 Hz GNSS stamps "
        "(the estimate taken at the same stamp), as the paper; also against the simulator's truth β at 100 Hz. "
        "The paper's relative error explodes where |β_ref| ≈ 0; the column **mean rel, floor** uses "
        f"|e| / max(|β_ref|, {math.degrees(REL_FLOOR):g}° = {REL_FLOOR:.4f} rad), a round floor above the GNSS β "
        "noise at 5 km/h (std of β_GNSS − β truth in the turn: "
        f"{_r(res.mean('small_radius_turn', 'gnss.beta_noise_std'))} rad). Windows are t0 < t ≤ t1.",
        "",
        "## Summary",
        "",
        "Criteria: the issue's requirements (AN-STUKF's mean |e_β| at most half the UKF's in the turn; no worse on "
        f"the S-shape, read as within {MARGIN:.0%}; faster tracking in the acceleration, read as a ≥ {MARGIN:.0%} "
        "smaller lag or error, so that numerically equal filters do not count as faster) and the paper's "
        'qualitative observations as stated in the "paper" column; "info" rows make no claim.',
        "",
        claims_table(sk.claims),
        "",
        f"**{n_hold} of {n_claims} claims hold**"
        + (
            f'; the {failed} rows marked **no** are discussed in "What did not reproduce and why" at the end.'
            if failed
            else "."
        ),
        "",
    ]
    not_reproduced = _not_reproduced(sk, res, counts)
    tail = [
        "## What did not reproduce and why",
        "",
        *(not_reproduced or ["- Everything in the summary holds."]),
        "",
        "General causes (MODELS.md B.1): every equation of the paper (1–41) was lost and is reconstructed from the "
        "literature; the paper's Q/R, gains, thresholds, μ, wheel inertia and the exact tire model are not given; "
        "its reference was a real RTK-GNSS on a real vehicle, where the model errors the adaptive stages address "
        "are large. Here the truth plant runs its own magic-formula tire (load-dependent stiffness and friction) "
        "and suspension-force loads against the observer's brush tire and quasi-static loads; they share only "
        "the geometry and kinematics (the plant adds wheel and suspension dynamics and tire relaxation). The "
        "filters are the paper's as reconstructed (`SkidSteerEstimatorConfig.paper()`: B.10's Q0/R0, brush "
        "model); the fair comparison with a consistently tuned UKF and the project's default is "
        "`docs/results/skid_steer_fair.md`.",
        "",
    ]
    text = "\n".join(header) + "\n" + "\n\n".join(rep.sections) + "\n\n" + "\n".join(tail)
    rep.out.write_text(text, encoding="utf-8")
    return rep.out


@cli_main("reproduce-skid")
def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args, argv_list = reproduction_arguments(
        "python -m terrain_analysis.tools.reproduce_skid",
        (__doc__ or "").splitlines()[0],
        argv,
        runs_help="seeded runs per manoeuvre (default 20)",
        quick_help="smoke run: one short run per case (< 1 min)",
    )
    counts = Counts.quick() if args.quick else Counts()
    if args.runs is not None:
        counts = counts.with_runs(args.runs)
    out_dir = Path(args.out)
    fig_dir = out_dir / "skid_steer"
    fig_dir.mkdir(parents=True, exist_ok=True)
    plan = build_plan(counts)
    print(f"reproduce_skid: {len(plan)} simulated runs on {args.jobs} process(es)", file=sys.stderr, flush=True)
    start = time.monotonic()
    cpu0 = _cpu_seconds()
    res = execute(plan, counts, args.jobs)
    sk = SkidReport(Report(out=out_dir / "skid_steer.md", fig_dir=fig_dir))
    for writer in (_section_tables, _section_straight, _section_icr, _section_turn_obs, _section_mismatch):
        writer(sk, res, counts)
    wall = time.monotonic() - start
    cpu = _cpu_seconds() - cpu0
    path = _write_report(sk, res, counts, argv_list, args.jobs, wall, cpu, args.quick, len(plan))
    print(claims_table(sk.claims))
    print(f"\nreport: {path} (wall time {wall:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
