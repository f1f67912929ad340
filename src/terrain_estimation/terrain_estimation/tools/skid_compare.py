"""Skid-steer filters on truth runs: errors, consistency and cost, scenario × filter × seed (issue 20).

The engine of the fair comparison: every filter gets the same simulated
sensor data of a run, and every figure is computed against the plant's truth
at the sensor rate (100 Hz), never against the GNSS reference:

* errors: mean ``|e_β|`` (body sideslip, only where the truth speed exceeds
  :data:`BETA_MIN_SPEED`: β is undefined at standstill), RMS of ``e_vy``,
  ``e_vx`` and ``e_r`` over the scored window;
* consistency (:mod:`terrain_estimation.analysis.consistency`): NEES of
  ``(v_x, v_y, r)`` from the published twist covariance and NIS of the
  accepted updates, each against its 95 % χ² band in 2 s windows, and per
  quantity the mean ``e²/σ²`` and the share of errors within 2σ;
* cost: CPU seconds per filter step (``time.process_time``, the filter's
  share of the run; the simulation is not counted).

:func:`compare` runs a plan on a process pool (``jobs``) and returns one row
per (scenario, filter, seed); :func:`summarise` averages over seeds. The
command line prints the table; ``reproduce_skid`` writes it into its report.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.analysis.consistency import consistency_report
from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig

__all__ = ["BETA_MIN_SPEED", "Job", "RunFigures", "compare", "run_filter_on", "score_run", "summarise"]

FloatArray = NDArray[np.float64]

#: [m/s] β errors are scored only where the true planar speed exceeds this.
BETA_MIN_SPEED = 0.5


@dataclass(frozen=True)
class RunFigures:
    """One filter on one run.

    Attributes:
        scenario, filter, seed: What ran.
        mean_abs_beta: Mean |β̂ − β| (rad) where the true speed > BETA_MIN_SPEED.
        rms_vy, rms_vx: RMS velocity errors (m/s).
        rms_r: RMS yaw-rate error (rad/s).
        mean_nees: Mean NEES of (v_x, v_y, r) (3 when consistent).
        nees_share: Share of 2 s windows whose mean NEES is in its 95 % band.
        mean_nis: Mean NIS of the accepted updates (3 when consistent).
        nis_share: Share of 2 s windows whose mean NIS is in its 95 % band.
        normalised_vx, normalised_vy, normalised_r: Mean e²/σ² per quantity.
        within_2sigma_vy: Share of |e_vy| ≤ 2σ.
        cpu_per_step_us: CPU time per filter step (µs).
        steps: Filter steps.
        resets: Limit resets + divergences + recoveries + restarts.
    """

    scenario: str
    filter: str
    seed: int
    mean_abs_beta: float
    rms_vy: float
    rms_vx: float
    rms_r: float
    mean_nees: float
    nees_share: float
    mean_nis: float
    nis_share: float
    normalised_vx: float
    normalised_vy: float
    normalised_r: float
    within_2sigma_vy: float
    cpu_per_step_us: float
    steps: int
    resets: int


@dataclass(frozen=True)
class _FilterRun:
    t: FloatArray
    state: FloatArray  # (T, 3): vx, vy, r
    beta: FloatArray
    covariance: FloatArray  # (T, 3, 3)
    nis: FloatArray  # nan where no update
    cpu_s: float
    steps: int
    resets: int


def run_filter_on(sim: Any, config: SkidSteerEstimatorConfig) -> _FilterRun:
    """Feed one estimator a simulated run's sensors (joint state first, then the IMU sample of the same stamp)."""
    est = SkidSteerEstimator(config)
    mv = np.asarray(sim.motor_velocity, dtype=float).tolist()
    acc = np.asarray(sim.linear_acceleration, dtype=float).tolist()
    gyro = np.asarray(sim.angular_velocity, dtype=float).tolist()
    out = []
    start = time.process_time()
    for i, t in enumerate(np.asarray(sim.t, dtype=float).tolist()):
        est.add_joint_state(t, mv[i][0], mv[i][1])
        est.add_imu(t, acc[i][0], acc[i][1], gyro[i][2])
        out.extend(est.drain_estimates())
    cpu = time.process_time() - start
    c = est.counters
    return _FilterRun(
        t=np.array([e.t for e in out], dtype=float),
        state=np.array([(e.vx, e.vy, e.yaw_rate) for e in out], dtype=float).reshape(-1, 3),
        beta=np.array([e.body_sideslip for e in out], dtype=float),
        covariance=np.array([e.twist_covariance for e in out], dtype=float).reshape(-1, 3, 3),
        nis=np.array([e.nis if e.accepted else math.nan for e in out], dtype=float),
        cpu_s=cpu,
        steps=len(out),
        resets=int(c.limit_resets + c.divergences + c.recoveries + c.restarts),
    )


def score_run(sim: Any, run: _FilterRun, *, scenario: str, filter_name: str, window: tuple[float, float]) -> RunFigures:
    """The figures of one filter run against the plant's truth over ``window`` (s)."""
    t_sim = np.asarray(sim.t, dtype=float)
    index = np.searchsorted(t_sim, run.t)
    index = np.clip(index, 0, t_sim.size - 1)
    matched = np.abs(t_sim[index] - run.t) < 1e-6
    sel = matched & (run.t >= window[0] - 1e-9) & (run.t <= window[1] + 1e-9)
    if not np.any(sel):
        raise ValueError(f"{scenario}/{filter_name}: no estimate inside the scored window {window}")
    idx = index[sel]
    truth = np.column_stack(
        [np.asarray(sim.truth.vx)[idx], np.asarray(sim.truth.vy)[idx], np.asarray(sim.truth.yaw_rate)[idx]]
    )
    err = run.state[sel] - truth
    speed = np.hypot(truth[:, 0], truth[:, 1])
    moving = speed > BETA_MIN_SPEED
    beta_err = np.angle(np.exp(1j * (run.beta[sel] - np.asarray(sim.truth.body_sideslip)[idx])))
    rep = consistency_report(run.t[sel], err, run.covariance[sel], ("vx", "vy", "r"), nis=run.nis[sel], nis_dof=3)
    nis_windows = rep.nis_windows
    return RunFigures(
        scenario=scenario,
        filter=filter_name,
        seed=int(sim.seed),
        mean_abs_beta=float(np.mean(np.abs(beta_err[moving]))) if np.any(moving) else math.nan,
        rms_vy=float(np.sqrt(np.mean(err[:, 1] ** 2))),
        rms_vx=float(np.sqrt(np.mean(err[:, 0] ** 2))),
        rms_r=float(np.sqrt(np.mean(err[:, 2] ** 2))),
        mean_nees=rep.mean_nees,
        nees_share=rep.nees_windows.share,
        mean_nis=rep.mean_nis,
        nis_share=nis_windows.share if nis_windows is not None else math.nan,
        normalised_vx=rep.quantity("vx").mean_normalised,
        normalised_vy=rep.quantity("vy").mean_normalised,
        normalised_r=rep.quantity("r").mean_normalised,
        within_2sigma_vy=rep.quantity("vy").within_2sigma,
        cpu_per_step_us=1e6 * run.cpu_s / max(1, run.steps),
        steps=run.steps,
        resets=run.resets,
    )


@dataclass(frozen=True)
class Job:
    """One simulated run scored for several filters.

    Attributes:
        scenario: Name of the scenario.
        build: Zero-argument picklable callable returning the plant's scenario
            (a module-level function or ``functools.partial``).
        seed: Sensor-noise seed.
        filters: Filter name → estimator configuration.
        window: Scored window (s) of the run.
    """

    scenario: str
    build: Callable[[], Any]
    seed: int
    filters: Mapping[str, SkidSteerEstimatorConfig]
    window: tuple[float, float]


def _run_job(job: Job) -> list[RunFigures]:
    from vehicle_sim.plants.skid_steer import simulate_skid_steer

    sim = simulate_skid_steer(job.build(), job.seed)
    return [
        score_run(sim, run_filter_on(sim, config), scenario=job.scenario, filter_name=name, window=job.window)
        for name, config in job.filters.items()
    ]


def compare(
    jobs: Sequence[Job], *, workers: int = 1, progress: Callable[[int, int], None] | None = None
) -> list[RunFigures]:
    """Run every job (on ``workers`` processes) and return the figures, in job order."""
    results: list[list[RunFigures]] = []
    if workers <= 1:
        for i, job in enumerate(jobs):
            results.append(_run_job(job))
            if progress is not None:
                progress(i + 1, len(jobs))
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            for i, figures in enumerate(pool.map(_run_job, jobs)):
                results.append(figures)
                if progress is not None:
                    progress(i + 1, len(jobs))
    return [row for rows in results for row in rows]


def summarise(rows: Iterable[RunFigures]) -> dict[tuple[str, str], dict[str, float]]:
    """Mean of every figure over the seeds, per (scenario, filter); ``runs`` counts them."""
    groups: dict[tuple[str, str], list[RunFigures]] = {}
    for r in rows:
        groups.setdefault((r.scenario, r.filter), []).append(r)
    out: dict[tuple[str, str], dict[str, float]] = {}
    for key, members in groups.items():
        values = [asdict(m) for m in members]
        numeric = [k for k, v in values[0].items() if isinstance(v, (int, float)) and k != "seed"]
        out[key] = {k: float(np.nanmean([v[k] for v in values])) for k in numeric}
        out[key]["runs"] = float(len(members))
    return out
