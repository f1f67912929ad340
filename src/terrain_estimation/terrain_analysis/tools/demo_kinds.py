"""The kinds of estimate the demo summarises: soil stiffness, skid-steer motion state, rocker-bogie wheel terrain.

Part of :mod:`terrain_analysis.tools.demo`. Each :class:`~terrain_analysis.tools.demo_record.DemoKind`
says what to record and how to summarise a recorded run, plot it and tabulate
the results (the module docstring of :mod:`~terrain_analysis.tools.demo` lists
the figures of each).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.reporting import pyplot as _pyplot
from terrain_analysis.tools.demo_record import (
    DemoKind,
    DemoRun,
    Recording,
    RunSummary,
    StateSummary,
    format_nis,
    kind_table,
    save_plot,
    stamps_ns,
)
from terrain_estimation.models.rover import WHEELS
from terrain_estimation.models.terrain_response import PolynomialModel2D, ValidityRegion

__all__ = [
    "SoilStiffnessResult",
    "SkidSteerResult",
    "RoverResult",
    "SOIL_STIFFNESS",
    "SKID_STEER",
    "ROVER",
    "SKID_STEER_SETTLE",
    "SKID_STEER_STEADY_TURN",
    "ROVER_SETTLE",
    "ROVER_MODEL_TOPIC",
]


# ---------------------------------------------------------------------------
# Soil stiffness (quarter car, LRV)
# ---------------------------------------------------------------------------


#: What the kind records.
_SOIL_STIFFNESS_RECORDING = Recording("terrain_msgs.msg.SoilStiffness", "soil_stiffness", "ground_truth/soil_stiffness")
#: The soil-stiffness table's columns (after vehicle, times and estimates; before the diagnostics).
_SOIL_HEAD = (
    "final k_s kN/m",
    "true kN/m",
    "final err %",
    "median err % (last 5 s)",
    "t<5 % s",
    "class",
    "mean NIS",
)


@dataclass
class SoilStiffnessResult(RunSummary):
    k_s: np.ndarray
    k_s_std: np.ndarray
    true_k_s: np.ndarray
    terrain_class: str
    nis: np.ndarray

    @property
    def rel_error(self) -> np.ndarray:
        return np.abs(self.k_s - self.true_k_s) / self.true_k_s

    def time_below(self, threshold: float, start: float = 0.0) -> float:
        """First time after ``start`` from which the error stays below ``threshold`` (NaN: never)."""
        mask = self.times >= start
        err = self.rel_error[mask]
        t = self.times[mask]
        above = np.nonzero(err >= threshold)[0]
        if above.size == 0:
            return float(t[0]) if t.size else math.nan
        if above[-1] + 1 >= t.size:
            return math.nan
        return float(t[above[-1] + 1])


def _summarise_soil(run: DemoRun) -> SoilStiffnessResult:
    idx = run.truth_index()
    return SoilStiffnessResult(
        **run.summary(round(run.scenario.duration * 100.0) - 1),
        k_s=run.estimate_field("k_s"),
        k_s_std=np.sqrt(run.estimate_field("k_s_variance")),
        true_k_s=run.truth_field("k_s", idx),
        terrain_class=run.estimates[-1].terrain_class,
        nis=run.estimate_field("nis"),
    )


def _plot_soil(result: SoilStiffnessResult, out: Path) -> Path:
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    t = result.times
    ax1.plot(t, result.true_k_s / 1e3, "k-", lw=1.5, label="true k_s")
    ax1.plot(t, result.k_s / 1e3, "C0-", lw=1, label="estimate (SCKF)")
    ax1.fill_between(
        t,
        (result.k_s - 2 * result.k_s_std) / 1e3,
        (result.k_s + 2 * result.k_s_std) / 1e3,
        color="C0",
        alpha=0.2,
        label="±2σ",
    )
    top = 3 * float(np.max(result.true_k_s)) / 1e3
    ax1.set_ylim(0, top)
    ax1.set_ylabel("soil stiffness k_s (kN/m)")
    ax1.set_title(result.scenario.title)
    ax1.legend(loc="upper right")
    ax2.semilogy(t, np.maximum(result.rel_error * 100, 1e-3), "C3-", lw=1)
    ax2.axhline(5, color="gray", ls="--", lw=0.8)
    ax2.text(t[0], 5.5, "5 %", color="gray")
    ax2.set_ylabel("|error| (%)")
    ax2.set_xlabel("simulated time (s)")
    ax2.grid(True, which="both", alpha=0.3)
    return save_plot(fig, out, result, "soil_stiffness")


def _soil_cells(r: SoilStiffnessResult) -> tuple[str, ...]:
    last5 = r.times >= r.times[-1] - 5.0
    changes = np.nonzero(np.diff(r.true_k_s))[0]
    start = float(r.times[changes[-1] + 1]) if changes.size else 0.0
    t5 = r.time_below(0.05, start)
    return (
        f"{r.k_s[-1] / 1e3:.1f}",
        f"{r.true_k_s[-1] / 1e3:.1f}",
        f"{100 * r.rel_error[-1]:.2f}",
        f"{100 * float(np.median(r.rel_error[last5])):.2f}",
        "never" if math.isnan(t5) else f"{t5 - start:.2f}" + (" (after change)" if changes.size else ""),
        r.terrain_class,
        f"{float(np.mean(r.nis)):.2f}",
    )


SOIL_STIFFNESS: DemoKind[SoilStiffnessResult] = DemoKind(
    "soil_stiffness",
    _SOIL_STIFFNESS_RECORDING,
    _summarise_soil,
    _plot_soil,
    kind_table(_SOIL_HEAD, _soil_cells),
)


# ---------------------------------------------------------------------------
# Skid-steer motion state
# ---------------------------------------------------------------------------

#: The rms errors leave out the start (filter initialisation, standstill to 1 s).
SKID_STEER_SETTLE = 2.0
#: The ICR is averaged over the steady turn (small-radius turn: yaw rate ramped over 6–8 s).
SKID_STEER_STEADY_TURN = 10.0
#: One estimate per IMU message.
SKID_STEER_RATE = 100.0


#: What the kind records.
_SKID_STEER_RECORDING = Recording(
    "terrain_msgs.msg.SkidSteerState",
    "skid_steer/state",
    "ground_truth/skid_steer/state",
    other_sensors=(("nav_msgs.msg.Odometry", "gnss/odom"),),  # the RTK-GNSS reference
)
#: The skid-steer table's columns and note.
_SKID_STEER_HEAD = (
    "rms vx m/s",
    "rms vy m/s",
    "rms yaw rate rad/s",
    "rms sideslip deg",
    "ICR x m est/true",
    "ICR y m est/true",
    "mean fading",
    "mean noise scale",
    "mean NIS",
)
_SKID_STEER_NOTE = (
    f"(rms errors against ground truth from {SKID_STEER_SETTLE:g} s; ICR: mean over valid estimates and truth "
    f"from {SKID_STEER_STEADY_TURN:g} s, the steady turn; NIS: the estimator's diagnostics window, 3 dof)"
)


@dataclass
class SkidSteerResult(StateSummary):
    """Skid-steer estimates against ground truth, aligned by stamp (angles in rad)."""

    icr_valid: np.ndarray
    true_icr_valid: np.ndarray
    fading_factor: np.ndarray
    noise_scale: np.ndarray

    def rms_error(self, name: str, start: float = SKID_STEER_SETTLE) -> float:
        """Root-mean-square error of ``name`` over the estimates stamped from ``start``."""
        return float(self.error_rms(name, start))

    def mean_icr(self, start: float = SKID_STEER_STEADY_TURN) -> tuple[float, float, float, float]:
        """Mean (estimated x, y, true x, y) of the ICR (m) over valid samples from ``start``; NaN: none."""
        steady = self.times >= start
        est = steady & self.icr_valid
        tru = steady & self.true_icr_valid

        def mean(values: np.ndarray, mask: np.ndarray) -> float:
            return float(np.mean(values[mask])) if np.any(mask) else math.nan

        return (
            mean(self.estimate["icr_x"], est),
            mean(self.estimate["icr_y"], est),
            mean(self.truth["icr_x"], tru),
            mean(self.truth["icr_y"], tru),
        )


_SKID_FIELDS = ("vx", "vy", "yaw_rate", "body_sideslip", "icr_x", "icr_y")
_SKID_VARIANCES = ("vx", "vy", "yaw_rate", "body_sideslip")


def _summarise_skid_steer(run: DemoRun) -> SkidSteerResult:
    idx = run.truth_index()
    return SkidSteerResult(
        **run.summary(round(run.scenario.duration * SKID_STEER_RATE), with_nis=True),
        estimate={name: run.estimate_field(name) for name in _SKID_FIELDS},
        std={name: np.sqrt(run.estimate_field(f"{name}_variance")) for name in _SKID_VARIANCES},
        truth={name: run.truth_field(name, idx) for name in _SKID_FIELDS},
        icr_valid=run.estimate_field("icr_valid").astype(bool),
        true_icr_valid=run.truth_field("icr_valid", idx).astype(bool),
        fading_factor=run.estimate_field("fading_factor"),
        noise_scale=run.estimate_field("noise_scale"),
    )


def _plot_skid_steer(result: SkidSteerResult, out: Path) -> Path:
    plt = _pyplot()
    fig = plt.figure(figsize=(13, 8))
    grid = fig.add_gridspec(3, 2, width_ratios=(2.2, 1))
    t = result.times
    panels = (
        ("vx", 1.0, "vx (m/s)"),
        ("yaw_rate", 1.0, "yaw rate (rad/s)"),
        ("body_sideslip", 180.0 / math.pi, "body sideslip β (deg)"),
    )
    first = None
    for row, (name, scale, label) in enumerate(panels):
        ax = fig.add_subplot(grid[row, 0], sharex=first)
        first = first or ax
        est, std = result.estimate[name] * scale, result.std[name] * scale
        ax.plot(t, result.truth[name] * scale, "k-", lw=1.5, label="truth")
        ax.plot(t, est, "C0-", lw=1, label="estimate (AN-STUKF)")
        ax.fill_between(t, est - 2 * std, est + 2 * std, color="C0", alpha=0.2, label="±2σ")
        if name == "body_sideslip":
            # below the sideslip speed the estimate is 0 with variance π²: keep the band from hiding the truth
            settled = t >= SKID_STEER_SETTLE
            span = np.concatenate([result.truth[name][settled], result.estimate[name][settled]]) * scale
            if span.size:
                margin = max(1.0, 0.2 * float(np.ptp(span)))
                ax.set_ylim(float(np.min(span)) - margin, float(np.max(span)) + margin)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        if row == 0:
            ax.set_title(result.scenario.title)
            ax.legend(loc="lower right")
        if row == len(panels) - 1:
            ax.set_xlabel("simulated time (s)")
    ax_icr = fig.add_subplot(grid[:, 1])
    steady = t >= SKID_STEER_STEADY_TURN
    est_steady = result.icr_valid & steady
    for mask, data, color, label in (
        (result.true_icr_valid, result.truth, "k", "truth"),
        (result.icr_valid, result.estimate, "C0", "estimate"),
    ):
        ax_icr.plot(
            data["icr_x"][mask], data["icr_y"][mask], ".", color=color, ms=1.5, alpha=0.5, label=f"{label} (valid)"
        )
        m = mask & steady
        if np.any(m):
            ax_icr.plot(
                float(np.mean(data["icr_x"][m])),
                float(np.mean(data["icr_y"][m])),
                "X",
                color=color,
                ms=10,
                mec="white",
                label=f"{label}: mean from {SKID_STEER_STEADY_TURN:g} s",
            )
    ax_icr.set_xlabel("ICR x, body frame (m)")
    ax_icr.set_ylabel("ICR y, body frame (m; > 0: left of the vehicle)")
    ax_icr.set_title("instantaneous centre of rotation")
    ax_icr.grid(True, alpha=0.3)
    ax_icr.legend(loc="upper right", fontsize="small", markerscale=2)
    # The ICR runs off to infinity as the yaw rate falls to the validity threshold
    # (the turn-in): frame the steady turn, 1st to 99th percentile of both traces.
    xs = np.concatenate([result.truth["icr_x"][result.true_icr_valid & steady], result.estimate["icr_x"][est_steady]])
    ys = np.concatenate([result.truth["icr_y"][result.true_icr_valid & steady], result.estimate["icr_y"][est_steady]])
    if xs.size:
        for values, set_lim in ((xs, ax_icr.set_xlim), (ys, ax_icr.set_ylim)):
            lo, hi = (float(v) for v in np.percentile(values, (1.0, 99.0)))
            margin = max(0.25, 0.3 * (hi - lo))
            set_lim(lo - margin, hi + margin)
    return save_plot(fig, out, result, "state")


def _skid_steer_cells(r: SkidSteerResult) -> tuple[str, ...]:
    icr = r.mean_icr()
    return (
        f"{r.rms_error('vx'):.3f}",
        f"{r.rms_error('vy'):.3f}",
        f"{r.rms_error('yaw_rate'):.4f}",
        f"{math.degrees(r.rms_error('body_sideslip')):.2f}",
        f"{icr[0]:.2f} / {icr[2]:.2f}",
        f"{icr[1]:.2f} / {icr[3]:.2f}",
        f"{float(np.mean(r.fading_factor)):.3f}",
        f"{float(np.mean(r.noise_scale)):.3f}",
        format_nis(r.nis_mean, r.nis_window),
    )


SKID_STEER: DemoKind[SkidSteerResult] = DemoKind(
    "skid_steer",
    _SKID_STEER_RECORDING,
    _summarise_skid_steer,
    _plot_skid_steer,
    kind_table(_SKID_STEER_HEAD, _skid_steer_cells, _SKID_STEER_NOTE),
)


# ---------------------------------------------------------------------------
# Rocker-bogie wheel terrain (rover)
# ---------------------------------------------------------------------------

#: The rms errors leave out the filters' initialisation (as bags/expectations.yaml's settle_time).
ROVER_SETTLE = 2.0
#: One estimate per estimator step (estimator.rate).
ROVER_RATE = 5.0
#: The rover's online terrain-response models, recorded beside its wheel_terrain estimates.
ROVER_MODEL_TOPIC = "terrain_model"
#: Tabulated per wheel; W and DP are plotted.
_ROVER_QUANTITIES = ("slip", "normal_load", "drawbar_pull", "resistive_torque")


#: What the kind records.
_ROVER_RECORDING = Recording(
    "terrain_msgs.msg.WheelTerrainArray",
    "wheel_terrain",
    "ground_truth/wheel_terrain",
    other_estimates=(("terrain_msgs.msg.TerrainResponseModel", ROVER_MODEL_TOPIC),),
)
#: The rover table's columns and note.
_ROVER_HEAD = (
    "rms slip",
    "rms W N",
    "rms DP N",
    "rms τ_R N·m",
    "models (first s)",
    "last model DP rms N (stated; truth in region)",
    "mean NIS",
)
_ROVER_NOTE = (
    f"(rms errors against ground truth from {ROVER_SETTLE:g} s, mean of the rear, middle and front wheel's; "
    "models: terrain_model messages received, stamp of the first; last model: its DP(W, i) against the true DP "
    "at every ground-truth (i, W) inside its validity region, in brackets the error the model states "
    "(dp_prediction_rms) and the share of the truth inside; "
    "NIS: the channels the estimator's consistency test counts — slips, load cells and the side's force "
    "balance, 11 dof with two-axis cells — over its diagnostics window)"
)


def _wheel_field(messages: Sequence[Any], name: str) -> np.ndarray:
    """``name`` of each wheel of WheelTerrainArray ``messages``: shape (messages, 3), in :data:`WHEELS` order."""
    rows = []
    for m in messages:
        by_name = {w.wheel: w for w in m.wheels}
        rows.append([getattr(by_name[wheel], name) for wheel in WHEELS])
    return np.array(rows, dtype=float).reshape(len(rows), len(WHEELS))


@dataclass
class RoverResult(StateSummary):
    """Wheel-terrain estimates against ground truth; per-wheel arrays are (samples, 3), wheels rear, middle, front.

    Attributes:
        truth_times, truth_series: every ground-truth sample (50 Hz).
        model_times: stamps of the terrain models received (s).
        model_dp_rms: rms of the last model's DP(W, i) against the true DP at
            every ground-truth (i, W) inside its validity region (NaN: no model
            or no truth inside).
        model_coverage: share of the ground-truth (i, W) samples inside that region.
        model_dp_stated: the last model's own stated DP error over its region
            (``dp_prediction_rms``; NaN: no model).
    """

    truth_times: np.ndarray
    truth_series: dict[str, np.ndarray]
    model_times: np.ndarray
    model_dp_rms: float
    model_coverage: float
    model_dp_stated: float = math.nan

    def rms_error(self, name: str, start: float = ROVER_SETTLE) -> np.ndarray:
        """Root-mean-square error of ``name`` per wheel over the estimates stamped from ``start``."""
        return self.error_rms(name, start)


def _model_dp_error(model: Any, slip: np.ndarray, load: np.ndarray, pull: np.ndarray) -> tuple[float, float]:
    """(rms of a TerrainResponseModel's DP against ``pull`` inside its validity region, share of samples inside)."""
    region = ValidityRegion(
        slip_min=model.slip_min, slip_max=model.slip_max, load_min=model.load_min, load_max=model.load_max
    )
    inside = region.contains(slip, load)
    if not np.any(inside):
        return math.nan, 0.0
    dp = PolynomialModel2D.from_coefficients(model.dp_coefficients)
    return dp.residual_rms(slip[inside], load[inside], pull[inside]), float(np.mean(inside))


def _summarise_rover(run: DemoRun) -> RoverResult:
    idx = run.truth_index()
    truth_series = {name: _wheel_field(run.truth, name) for name in _ROVER_QUANTITIES}
    models = run.other_estimates.get(ROVER_MODEL_TOPIC, [])
    model_dp_rms, model_coverage, model_dp_stated = math.nan, 0.0, math.nan
    if models:
        model_dp_stated = float(getattr(models[-1], "dp_prediction_rms", math.nan))
        model_dp_rms, model_coverage = _model_dp_error(
            models[-1],
            truth_series["slip"].ravel(),
            truth_series["normal_load"].ravel(),
            truth_series["drawbar_pull"].ravel(),
        )
    return RoverResult(
        # a step closes each 1/rate window after the first sample: none at t = 0
        **run.summary(round(run.scenario.duration * ROVER_RATE) - 1, with_nis=True),
        estimate={name: _wheel_field(run.estimates, name) for name in _ROVER_QUANTITIES},
        std={name: np.sqrt(_wheel_field(run.estimates, f"{name}_variance")) for name in _ROVER_QUANTITIES},
        truth={name: values[idx] for name, values in truth_series.items()},
        truth_times=run.truth_times,
        truth_series=truth_series,
        model_times=stamps_ns(models) * 1e-9,
        model_dp_rms=model_dp_rms,
        model_coverage=model_coverage,
        model_dp_stated=model_dp_stated,
    )


def _plot_rover(result: RoverResult, out: Path) -> Path:
    plt = _pyplot()
    panels = (("normal_load", "W (N)"), ("drawbar_pull", "DP (N)"))
    # y not shared: each wheel's W varies by a few N about a different mean
    fig, axes = plt.subplots(len(panels), len(WHEELS), figsize=(14, 6.5), sharex=True, squeeze=False)
    t = result.times
    for row, (name, label) in enumerate(panels):
        for col, wheel in enumerate(WHEELS):
            ax = axes[row, col]
            est, std = result.estimate[name][:, col], result.std[name][:, col]
            ax.plot(result.truth_times, result.truth_series[name][:, col], "k-", lw=1.2, label="truth")
            ax.plot(t, est, "C0-", lw=1, label="estimate (UKF)")
            ax.fill_between(t, est - 2 * std, est + 2 * std, color="C0", alpha=0.2, label="±2σ")
            if name == "drawbar_pull":  # the terrain models fit DP(W, i) (and τ_R): mark their stamps
                for k, t_model in enumerate(result.model_times):
                    ax.axvline(t_model, color="C2", lw=0.6, alpha=0.5, label="terrain model" if k == 0 else None)
            ax.grid(True, alpha=0.3)
            if row == 0:
                ax.set_title(f"{wheel} wheel")
            if col == 0:
                ax.set_ylabel(label)
            if row == len(panels) - 1:
                ax.set_xlabel("simulated time (s)")
    axes[-1, 0].legend(loc="best", fontsize="small")
    fig.suptitle(result.scenario.title)
    return save_plot(fig, out, result, "wheel_terrain")


def _rover_cells(r: RoverResult) -> tuple[str, ...]:
    rms_of = {name: float(np.mean(r.rms_error(name))) for name in _ROVER_QUANTITIES}
    models = f"{r.model_times.size}" + (f" ({r.model_times[0]:.1f})" if r.model_times.size else "")
    model_dp = (
        "n/a"
        if math.isnan(r.model_dp_rms)
        else f"{r.model_dp_rms:.2f} ({r.model_dp_stated:.2f}; {100 * r.model_coverage:.0f} %)"
    )
    return (
        f"{rms_of['slip']:.4f}",
        f"{rms_of['normal_load']:.3f}",
        f"{rms_of['drawbar_pull']:.3f}",
        f"{rms_of['resistive_torque']:.5f}",
        models,
        model_dp,
        format_nis(r.nis_mean, r.nis_window),
    )


ROVER: DemoKind[RoverResult] = DemoKind(
    "rover",
    _ROVER_RECORDING,
    _summarise_rover,
    _plot_rover,
    kind_table(_ROVER_HEAD, _rover_cells, _ROVER_NOTE),
)
