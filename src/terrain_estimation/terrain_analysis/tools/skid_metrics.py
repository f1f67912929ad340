"""The skid-steer reproduction's metrics: sideslip errors, tracking lag, ICR statistics, per-run figures.

Definitions stated in the report (MODELS.md D.2); :func:`run_metrics` turns
one :class:`~terrain_analysis.tools.skid_runs.RunData` into the flat figures
the sections read, and :class:`Results` holds them per manoeuvre.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.reporting import in_window as _window
from terrain_analysis.reporting import summary_stats as _stats
from terrain_analysis.tools.skid_runs import (
    _STATS,
    REL_FLOOR,
    Counts,
    RunData,
    RunSpec,
    run_one,
)
from terrain_estimation.models.skid_steer import WHEEL_NAMES

__all__ = [
    "Results",
    "ScoredRun",
    "collect",
    "score_one",
    "SideslipErrors",
    "icr_statistics",
    "run_metrics",
    "sideslip_errors",
    "tracking_lag",
    "values_at",
]

FloatArray = NDArray[np.float64]


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


@dataclass(frozen=True)
class ScoredRun:
    """What a worker sends back for one run: its figures, the truth digest, and the whole data of run 0."""

    spec: RunSpec
    metrics: dict[str, float]
    truth_digest: str
    seed: int
    data: RunData | None


def score_one(spec: RunSpec, counts: Counts) -> ScoredRun:
    """Simulate ``spec`` (:func:`~terrain_analysis.tools.skid_runs.run_one`) and reduce it to its figures.

    Runs in the worker, so that only the figures travel (and the data of run 0, for the figures).
    """
    run = run_one(spec)
    return ScoredRun(spec, run_metrics(run, counts), run.truth_digest, run.seed, run if spec.run == 0 else None)


def collect(plan: Sequence[RunSpec], runs: Sequence[ScoredRun]) -> Results:
    """The per-case results of the plan's scored runs (:func:`score_one`, in plan order): metrics in run order."""
    per_case: dict[str, dict[int, dict[str, float]]] = {}
    res = Results()
    for run in runs:
        case = run.spec.case
        per_case.setdefault(case, {})[run.spec.run] = run.metrics
        res.digests.setdefault(case, set()).add(run.truth_digest)
        res.seeds.setdefault(case, []).append(run.seed)
        if run.data is not None:
            res.first[case] = run.data
    res.metrics = {case: [runs_[i] for i in sorted(runs_)] for case, runs_ in per_case.items()}
    return res
