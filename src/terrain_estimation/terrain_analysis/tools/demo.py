"""``make demo``: simulate each vehicle, estimate live over ROS 2, summarise.

For every vehicle that exists so far, the vehicle's simulator node runs as a
process of its own (publishing ``/clock``, sensors and ground truth) and this
process runs its estimator node (``use_sim_time``) and a recorder, all
talking over ROS 2 topics through DDS on this host. The "estimates" column
says how many of the expected estimates arrived: fewer means messages were
lost (a loaded machine, or a real-time factor the estimator cannot keep).
Afterwards it prints one table per kind of estimate and writes plots under
``out/`` (``--out``; an existing non-empty directory no project tool made is
refused unless ``--overwrite``, and nothing there is deleted):

* soil stiffness (quarter car, LRV): final estimate against ground truth,
  time to converge, innovation consistency, the estimator's diagnostic level;
* skid-steer motion state: rms error of vx, vy, yaw rate and body sideslip
  against ground truth, the instantaneous centre of rotation (ICR) over the
  steady turn, the adaptive filter's fading factor and noise scale, the
  innovation consistency and diagnostic level from the node's diagnostics;
* rocker-bogie wheel terrain (the Kapvik rover, terrain 1): rms error of each
  wheel's slip, normal load W, drawbar pull DP and resistive torque τ_R
  against ground truth (mean over the rear, middle and front wheel), the
  online terrain models (``terrain_model``) received and how well the last
  one's DP(W, i) predicts the true DP inside its validity region, the
  innovation consistency and diagnostic level; the plot shows every wheel's W
  and DP with their ±2σ band against the truth.

Each :class:`DemoScenario` names its :class:`DemoKind`: what to record
(:class:`Recording`: message type, estimate topic, ground-truth topic, other
estimator outputs such as the rover's terrain models) and how to summarise,
plot and tabulate it. :func:`run_scenario` does the ROS 2 part the same way
for every kind.

A scenario also sets its real-time factor, the simulator's pace at most: 1
for all but the rover, which drives 40 s at 4x real time. Its estimator runs
at 5 Hz on 50 Hz sensors and keeps up with tens of times real time; the
simulator itself manages about 4.7x on an idle core
(``docs/results/rover.md``), so on a busy machine it runs slower (the
40 s took 18-33 s on a shared 2-core machine) and no estimate is lost.
``--realtime-factor`` runs every scenario at one factor instead.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from terrain_estimation.cli import EXIT_INPUT
from terrain_estimation.models.rover import WHEELS
from terrain_estimation.models.terrain_response import PolynomialModel2D, ValidityRegion
from terrain_estimation.outputs import OutputPathError, prepare_output_dir

__all__ = [
    "Recording",
    "DemoRun",
    "DemoKind",
    "DemoScenario",
    "SoilStiffnessResult",
    "SkidSteerResult",
    "RoverResult",
    "SOIL_STIFFNESS",
    "SKID_STEER",
    "ROVER",
    "SCENARIOS",
    "run_scenario",
    "main",
]


# ---------------------------------------------------------------------------
# What a scenario records, generically
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Recording:
    """The topics a scenario records, relative to the vehicle namespace, and their message type.

    Attributes:
        msg_type: ``"package.msg.Name"``, imported when the scenario runs (so
            this module imports without ROS 2).
        estimate_topic: the estimator's output.
        truth_topic: the simulator's ground truth of the same message type.
        other_sensors: ``(msg_type, topic)`` of simulated sensors the estimator
            does not subscribe to: the simulator starts only when every sensor
            topic has a subscriber, so the recorder subscribes to these (and
            drops what arrives).
        other_estimates: ``(msg_type, topic)`` of further estimator outputs to
            record (the rover's terrain models), kept in
            :attr:`DemoRun.other_estimates` by topic.
    """

    msg_type: str
    estimate_topic: str
    truth_topic: str
    other_sensors: tuple[tuple[str, str], ...] = ()
    other_estimates: tuple[tuple[str, str], ...] = ()

    def message_class(self) -> type:
        return _import_type(self.msg_type)


def _import_type(dotted: str) -> type:
    module, _, name = dotted.rpartition(".")
    cls: type = getattr(importlib.import_module(module), name)
    return cls


def _stamps_ns(messages: Sequence[Any]) -> np.ndarray:
    return np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in messages], dtype=np.int64)


@dataclass
class DemoRun:
    """What one scenario recorded: estimate and ground-truth messages, the estimator's diagnostics.

    Attributes:
        scenario: the scenario run.
        estimates: estimate messages, in arrival order.
        truth: ground-truth messages, in arrival order.
        diagnostic_level: the estimator's diagnostic level at the end (``"OK"``, ...).
        diagnostic_message: its message.
        diagnostic_values: its key/values (as published: strings).
        wall_time: wall-clock seconds from starting the simulator to the end of recording.
        other_estimates: messages of each of :attr:`Recording.other_estimates`, by topic, in arrival order.
    """

    scenario: DemoScenario
    estimates: list[Any]
    truth: list[Any]
    diagnostic_level: str
    diagnostic_message: str
    diagnostic_values: dict[str, str]
    wall_time: float
    other_estimates: dict[str, list[Any]] = field(default_factory=dict)

    @property
    def times(self) -> np.ndarray:
        """Estimate stamps (s)."""
        return _stamps_ns(self.estimates) * 1e-9

    @property
    def truth_times(self) -> np.ndarray:
        """Ground-truth stamps (s)."""
        return _stamps_ns(self.truth) * 1e-9

    def nis(self) -> tuple[float, int]:
        """Mean NIS over the estimator's diagnostics window and the window's length (NaN, 0: not reported)."""
        values = self.diagnostic_values
        mean = float(values["nis_mean"]) if "nis_mean" in values else math.nan
        return mean, int(values.get("nis_window", "0"))

    def truth_index(self) -> np.ndarray:
        """For each estimate, the index of the newest ground truth stamped at or before it."""
        t_est = _stamps_ns(self.estimates)
        t_truth = _stamps_ns(self.truth)
        return np.clip(np.searchsorted(t_truth, t_est, side="right") - 1, 0, len(self.truth) - 1)

    def estimate_field(self, name: str) -> np.ndarray:
        return np.array([getattr(m, name) for m in self.estimates], dtype=float)

    def truth_field(self, name: str, index: np.ndarray) -> np.ndarray:
        """Ground truth of ``name`` at the estimates (``index``: :meth:`truth_index`)."""
        return np.array([getattr(m, name) for m in self.truth], dtype=float)[index]


R = TypeVar("R")


@dataclass(frozen=True)
class DemoKind(Generic[R]):
    """A kind of estimate the demo knows: what to record and how to summarise it.

    Attributes:
        name: short name (``"soil_stiffness"``).
        recording: the topics and message type.
        summarise: recorded run → result.
        plot: (result, output directory) → path of the plot written.
        table: results of this kind → the printed table.
    """

    name: str
    recording: Recording
    summarise: Callable[[DemoRun], R]
    plot: Callable[[R, Path], Path]
    table: Callable[[Sequence[R]], str]


def _rms(error: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Root-mean-square of ``error`` over the rows where ``mask`` holds, per column (NaN: no row)."""
    if not np.any(mask):
        return np.full(error.shape[1:], math.nan)
    return np.asarray(np.sqrt(np.mean(error[mask] ** 2, axis=0)))


def _format_nis(mean: float, window: int) -> str:
    return "n/a" if math.isnan(mean) else f"{mean:.2f} (last {window})"


def _format_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(head)]
    fmt = " | ".join(f"{{:<{w}}}" for w in widths)
    lines = [fmt.format(*head), "-+-".join("-" * w for w in widths)]
    lines += [fmt.format(*row) for row in rows]
    return "\n".join(lines)


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ---------------------------------------------------------------------------
# Soil stiffness (quarter car, LRV)
# ---------------------------------------------------------------------------


@dataclass
class SoilStiffnessResult:
    scenario: DemoScenario
    times: np.ndarray
    k_s: np.ndarray
    k_s_std: np.ndarray
    true_k_s: np.ndarray
    terrain_class: str
    nis: np.ndarray
    diagnostic_level: str
    diagnostic_message: str
    wall_time: float
    sim_time: float
    expected_estimates: int

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
    t_est = run.times
    idx = run.truth_index()
    return SoilStiffnessResult(
        scenario=run.scenario,
        times=t_est,
        k_s=run.estimate_field("k_s"),
        k_s_std=np.sqrt(run.estimate_field("k_s_variance")),
        true_k_s=run.truth_field("k_s", idx),
        terrain_class=run.estimates[-1].terrain_class,
        nis=run.estimate_field("nis"),
        diagnostic_level=run.diagnostic_level,
        diagnostic_message=run.diagnostic_message,
        wall_time=run.wall_time,
        sim_time=float(t_est[-1]),
        expected_estimates=round(run.scenario.duration * 100.0) - 1,
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
    fig.tight_layout()
    path = out / f"{result.scenario.vehicle}_soil_stiffness.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _table_soil(results: Sequence[SoilStiffnessResult]) -> str:
    head = (
        "vehicle",
        "sim s",
        "wall s",
        "estimates",
        "final k_s kN/m",
        "true kN/m",
        "final err %",
        "median err % (last 5 s)",
        "t<5 % s",
        "class",
        "mean NIS",
        "diagnostics",
    )
    rows = []
    for r in results:
        last5 = r.times >= r.times[-1] - 5.0
        changes = np.nonzero(np.diff(r.true_k_s))[0]
        start = float(r.times[changes[-1] + 1]) if changes.size else 0.0
        t5 = r.time_below(0.05, start)
        rows.append(
            (
                r.scenario.vehicle,
                f"{r.sim_time:.1f}",
                f"{r.wall_time:.1f}",
                f"{r.times.size}/{r.expected_estimates}",
                f"{r.k_s[-1] / 1e3:.1f}",
                f"{r.true_k_s[-1] / 1e3:.1f}",
                f"{100 * r.rel_error[-1]:.2f}",
                f"{100 * float(np.median(r.rel_error[last5])):.2f}",
                "never" if math.isnan(t5) else f"{t5 - start:.2f}" + (" (after change)" if changes.size else ""),
                r.terrain_class,
                f"{float(np.mean(r.nis)):.2f}",
                f"{r.diagnostic_level}: {r.diagnostic_message}",
            )
        )
    return _format_table(head, rows)


SOIL_STIFFNESS: DemoKind[SoilStiffnessResult] = DemoKind(
    "soil_stiffness",
    Recording("terrain_msgs.msg.SoilStiffness", "soil_stiffness", "ground_truth/soil_stiffness"),
    _summarise_soil,
    _plot_soil,
    _table_soil,
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


@dataclass
class SkidSteerResult:
    """Skid-steer estimates against ground truth, aligned by stamp (angles in rad)."""

    scenario: DemoScenario
    times: np.ndarray
    estimate: dict[str, np.ndarray]
    std: dict[str, np.ndarray]
    truth: dict[str, np.ndarray]
    icr_valid: np.ndarray
    true_icr_valid: np.ndarray
    fading_factor: np.ndarray
    noise_scale: np.ndarray
    nis_mean: float
    nis_window: int
    diagnostic_level: str
    diagnostic_message: str
    wall_time: float
    sim_time: float
    expected_estimates: int

    def rms_error(self, name: str, start: float = SKID_STEER_SETTLE) -> float:
        """Root-mean-square error of ``name`` over the estimates stamped from ``start``."""
        return float(_rms(self.estimate[name] - self.truth[name], self.times >= start))

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
    t_est = run.times
    idx = run.truth_index()
    nis_mean, nis_window = run.nis()
    return SkidSteerResult(
        scenario=run.scenario,
        times=t_est,
        estimate={name: run.estimate_field(name) for name in _SKID_FIELDS},
        std={name: np.sqrt(run.estimate_field(f"{name}_variance")) for name in _SKID_VARIANCES},
        truth={name: run.truth_field(name, idx) for name in _SKID_FIELDS},
        icr_valid=run.estimate_field("icr_valid").astype(bool),
        true_icr_valid=run.truth_field("icr_valid", idx).astype(bool),
        fading_factor=run.estimate_field("fading_factor"),
        noise_scale=run.estimate_field("noise_scale"),
        nis_mean=nis_mean,
        nis_window=nis_window,
        diagnostic_level=run.diagnostic_level,
        diagnostic_message=run.diagnostic_message,
        wall_time=run.wall_time,
        sim_time=float(t_est[-1]),
        expected_estimates=round(run.scenario.duration * SKID_STEER_RATE),
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
    fig.tight_layout()
    path = out / f"{result.scenario.vehicle}_state.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _table_skid_steer(results: Sequence[SkidSteerResult]) -> str:
    head = (
        "vehicle",
        "sim s",
        "wall s",
        "estimates",
        "rms vx m/s",
        "rms vy m/s",
        "rms yaw rate rad/s",
        "rms sideslip deg",
        "ICR x m est/true",
        "ICR y m est/true",
        "mean fading",
        "mean noise scale",
        "mean NIS",
        "diagnostics",
    )
    rows = []
    for r in results:
        icr = r.mean_icr()
        rows.append(
            (
                r.scenario.vehicle,
                f"{r.sim_time:.1f}",
                f"{r.wall_time:.1f}",
                f"{r.times.size}/{r.expected_estimates}",
                f"{r.rms_error('vx'):.3f}",
                f"{r.rms_error('vy'):.3f}",
                f"{r.rms_error('yaw_rate'):.4f}",
                f"{math.degrees(r.rms_error('body_sideslip')):.2f}",
                f"{icr[0]:.2f} / {icr[2]:.2f}",
                f"{icr[1]:.2f} / {icr[3]:.2f}",
                f"{float(np.mean(r.fading_factor)):.3f}",
                f"{float(np.mean(r.noise_scale)):.3f}",
                _format_nis(r.nis_mean, r.nis_window),
                f"{r.diagnostic_level}: {r.diagnostic_message}",
            )
        )
    note = (
        f"(rms errors against ground truth from {SKID_STEER_SETTLE:g} s; ICR: mean over valid estimates and truth "
        f"from {SKID_STEER_STEADY_TURN:g} s, the steady turn; NIS: the estimator's diagnostics window, 3 dof)"
    )
    return _format_table(head, rows) + "\n" + note


SKID_STEER: DemoKind[SkidSteerResult] = DemoKind(
    "skid_steer",
    Recording(
        "terrain_msgs.msg.SkidSteerState",
        "skid_steer/state",
        "ground_truth/skid_steer/state",
        other_sensors=(("nav_msgs.msg.Odometry", "gnss/odom"),),  # the RTK-GNSS reference
    ),
    _summarise_skid_steer,
    _plot_skid_steer,
    _table_skid_steer,
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


def _wheel_field(messages: Sequence[Any], name: str) -> np.ndarray:
    """``name`` of each wheel of WheelTerrainArray ``messages``: shape (messages, 3), in :data:`WHEELS` order."""
    rows = []
    for m in messages:
        by_name = {w.wheel: w for w in m.wheels}
        rows.append([getattr(by_name[wheel], name) for wheel in WHEELS])
    return np.array(rows, dtype=float).reshape(len(rows), len(WHEELS))


@dataclass
class RoverResult:
    """Wheel-terrain estimates against ground truth; per-wheel arrays are (samples, 3), wheels rear, middle, front.

    Attributes:
        times: estimate stamps (s).
        estimate, std, truth: per quantity, the estimate, its σ and the ground
            truth at the estimates (the newest stamped at or before each).
        truth_times, truth_series: every ground-truth sample (50 Hz).
        model_times: stamps of the terrain models received (s).
        model_dp_rms: rms of the last model's DP(W, i) against the true DP at
            every ground-truth (i, W) inside its validity region (NaN: no model
            or no truth inside).
        model_coverage: share of the ground-truth (i, W) samples inside that region.
        model_dp_stated: the last model's own stated DP error over its region
            (``dp_prediction_rms``; NaN: no model).
    """

    scenario: DemoScenario
    times: np.ndarray
    estimate: dict[str, np.ndarray]
    std: dict[str, np.ndarray]
    truth: dict[str, np.ndarray]
    truth_times: np.ndarray
    truth_series: dict[str, np.ndarray]
    model_times: np.ndarray
    model_dp_rms: float
    model_coverage: float
    nis_mean: float
    nis_window: int
    diagnostic_level: str
    diagnostic_message: str
    wall_time: float
    sim_time: float
    expected_estimates: int
    model_dp_stated: float = math.nan

    def rms_error(self, name: str, start: float = ROVER_SETTLE) -> np.ndarray:
        """Root-mean-square error of ``name`` per wheel over the estimates stamped from ``start``."""
        return _rms(self.estimate[name] - self.truth[name], self.times >= start)


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
    t_est = run.times
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
    nis_mean, nis_window = run.nis()
    return RoverResult(
        scenario=run.scenario,
        times=t_est,
        estimate={name: _wheel_field(run.estimates, name) for name in _ROVER_QUANTITIES},
        std={name: np.sqrt(_wheel_field(run.estimates, f"{name}_variance")) for name in _ROVER_QUANTITIES},
        truth={name: values[idx] for name, values in truth_series.items()},
        truth_times=run.truth_times,
        truth_series=truth_series,
        model_times=_stamps_ns(models) * 1e-9,
        model_dp_rms=model_dp_rms,
        model_coverage=model_coverage,
        model_dp_stated=model_dp_stated,
        nis_mean=nis_mean,
        nis_window=nis_window,
        diagnostic_level=run.diagnostic_level,
        diagnostic_message=run.diagnostic_message,
        wall_time=run.wall_time,
        sim_time=float(t_est[-1]),
        # a step closes each 1/rate window after the first sample: none at t = 0
        expected_estimates=round(run.scenario.duration * ROVER_RATE) - 1,
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
    fig.tight_layout()
    path = out / f"{result.scenario.vehicle}_wheel_terrain.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _table_rover(results: Sequence[RoverResult]) -> str:
    head = (
        "vehicle",
        "sim s",
        "wall s",
        "estimates",
        "rms slip",
        "rms W N",
        "rms DP N",
        "rms τ_R N·m",
        "models (first s)",
        "last model DP rms N (stated; truth in region)",
        "mean NIS",
        "diagnostics",
    )
    rows = []
    for r in results:
        rms = {name: float(np.mean(r.rms_error(name))) for name in _ROVER_QUANTITIES}
        models = f"{r.model_times.size}" + (f" ({r.model_times[0]:.1f})" if r.model_times.size else "")
        model_dp = (
            "n/a"
            if math.isnan(r.model_dp_rms)
            else f"{r.model_dp_rms:.2f} ({r.model_dp_stated:.2f}; {100 * r.model_coverage:.0f} %)"
        )
        rows.append(
            (
                r.scenario.vehicle,
                f"{r.sim_time:.1f}",
                f"{r.wall_time:.1f}",
                f"{r.times.size}/{r.expected_estimates}",
                f"{rms['slip']:.4f}",
                f"{rms['normal_load']:.3f}",
                f"{rms['drawbar_pull']:.3f}",
                f"{rms['resistive_torque']:.5f}",
                models,
                model_dp,
                _format_nis(r.nis_mean, r.nis_window),
                f"{r.diagnostic_level}: {r.diagnostic_message}",
            )
        )
    note = (
        f"(rms errors against ground truth from {ROVER_SETTLE:g} s, mean of the rear, middle and front wheel's; "
        "models: terrain_model messages received, stamp of the first; last model: its DP(W, i) against the true DP "
        "at every ground-truth (i, W) inside its validity region, in brackets the error the model states "
        "(dp_prediction_rms) and the share of the truth inside; "
        "NIS: both filters summed, 20 dof, the estimator's diagnostics window)"
    )
    return _format_table(head, rows) + "\n" + note


ROVER: DemoKind[RoverResult] = DemoKind(
    "rover",
    Recording(
        "terrain_msgs.msg.WheelTerrainArray",
        "wheel_terrain",
        "ground_truth/wheel_terrain",
        other_estimates=(("terrain_msgs.msg.TerrainResponseModel", ROVER_MODEL_TOPIC),),
    ),
    _summarise_rover,
    _plot_rover,
    _table_rover,
)


# ---------------------------------------------------------------------------
# Scenarios and the ROS 2 run
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class DemoScenario:
    """One demo run: a vehicle, simulator overrides, how long to drive, what to record, and how fast.

    ``realtime_factor``: simulated seconds per wall second, unless the demo
    is given one for every scenario (``--realtime-factor``).
    """

    vehicle: str
    title: str
    duration: float
    sim_overrides: dict[str, Any] = field(default_factory=dict)
    kind: DemoKind[Any] = SOIL_STIFFNESS
    realtime_factor: float = 1.0


SCENARIOS: tuple[DemoScenario, ...] = (
    DemoScenario(
        "quarter_car",
        "quarter car, ISO D, 10 m/s: Graneville loam, then Upland sandy loam after 100 m",
        20.0,
        {
            "scenario.road": "D",
            "scenario.speed": 10.0,
            "scenario.soils": ["graneville_loam", "upland_sandy_loam"],
            "scenario.soil_starts": [0.0, 100.0],
        },
    ),
    DemoScenario(
        "lrv",
        "LRV, ISO G, 2 m/s, lunar regolith",
        20.0,
        {"scenario.road": "G", "scenario.speed": 2.0, "scenario.soils": ["lunar_regolith"]},
    ),
    DemoScenario(
        "skid_steer",
        "skid steer, small-radius turn: 5 km/h, 0.2 rad/s counter-clockwise from 8 s (R ≈ 7 m)",
        28.0,
        {"scenario.manoeuvre": "small_radius_turn", "scenario.duration": 28.0},
        SKID_STEER,
    ),
    DemoScenario(
        "rover",
        "Kapvik rocker-bogie, terrain 1 (rolling), 2 cm/s: Estimators 1 + 2, online terrain model",
        40.0,
        # the noise seed of bags/rover_terrain_1 (the same run, 10 s longer)
        {"scenario.terrain": "rolling", "seed": 51},
        ROVER,
        # 200 simulator steps (50 Hz sensors), 20 estimates a second; the simulator's limit is about 4.7x
        realtime_factor=4.0,
    ),
)


def _params_file(node_name: str, params: dict[str, Any], directory: Path) -> Path:
    """A ROS 2 parameter file giving ``params`` to ``node_name`` under any namespace.

    Passed after the vehicle's config file: for rcl, a node-specific entry of
    a file outranks a global ``-p name:=value``, so overrides of parameters the
    config sets per node must come as a later node-specific file.
    """
    import yaml

    path = directory / f"{node_name}_demo.yaml"
    path.write_text(yaml.safe_dump({f"/**/{node_name}": {"ros__parameters": params}}))
    return path


def run_scenario(scenario: DemoScenario, realtime_factor: float | None = None, progress: bool = True) -> DemoRun:
    """Run one scenario live over ROS 2 and record its estimate, ground-truth and other estimate topics.

    The simulator runs as its own process (``terrain-sim-node``), as on a
    robot; the estimator node and a recorder share this process. The
    simulator starts stepping once the estimator's subscriptions are matched.
    ``realtime_factor``: None runs at the scenario's own.
    """
    import subprocess
    import tempfile

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from terrain_estimation.nodes import make_estimator_node
    from terrain_estimation.ros.diagnostics import LEVEL_NAMES
    from terrain_estimation.ros.qos import ESTIMATE_QOS, SENSOR_QOS
    from vehicle_sim.ros.registry import get_simulator

    recording = scenario.kind.recording
    msg_type = recording.message_class()
    params = dict(scenario.sim_overrides)
    factor = scenario.realtime_factor if realtime_factor is None else realtime_factor
    params.update(realtime_factor=factor, duration=scenario.duration, wait_for_subscribers=1)
    tmp = Path(tempfile.mkdtemp(prefix="terrain-demo-"))
    overrides_file = _params_file(get_simulator(scenario.vehicle).node_name, params, tmp)
    command = [sys.executable, "-m", "vehicle_sim.ros.nodes", "--vehicle", scenario.vehicle]
    command += ["--ros-args", "--params-file", str(overrides_file)]

    context = Context()
    rclpy.init(context=context)
    sim = None
    try:
        est = make_estimator_node(scenario.vehicle, overrides={"use_sim_time": True}, context=context)
        recorder = Node("demo_recorder", context=context)
        ns = est.get_namespace()
        estimates: list[Any] = []
        truth: list[Any] = []
        recorder.create_subscription(msg_type, f"{ns}/{recording.estimate_topic}", estimates.append, ESTIMATE_QOS)
        recorder.create_subscription(msg_type, f"{ns}/{recording.truth_topic}", truth.append, ESTIMATE_QOS)
        others: dict[str, list[Any]] = {}
        for other_type, topic in recording.other_estimates:
            received = others.setdefault(topic, [])
            recorder.create_subscription(_import_type(other_type), f"{ns}/{topic}", received.append, ESTIMATE_QOS)
        for other_type, topic in recording.other_sensors:
            recorder.create_subscription(_import_type(other_type), f"{ns}/{topic}", lambda _msg: None, SENSOR_QOS)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(est)
        executor.add_node(recorder)
        sim = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        started = time.monotonic()
        last_report = started
        while sim.poll() is None:
            executor.spin_once(timeout_sec=0.05)
            if progress and time.monotonic() - last_report > 2.0:
                last_report = time.monotonic()
                t_now = est.get_clock().now().nanoseconds * 1e-9
                print(
                    f"  ... {scenario.vehicle}: {t_now:.1f} / {scenario.duration:.0f} s simulated, "
                    f"{len(estimates)} estimates",
                    file=sys.stderr,
                )
        if sim.returncode != 0:
            raise RuntimeError(
                f"{scenario.vehicle} simulator failed ({sim.returncode}): {sim.stderr.read() if sim.stderr else ''}"
            )
        # drain what is still queued
        drain_until = time.monotonic() + 1.0
        while time.monotonic() < drain_until:
            executor.spin_once(timeout_sec=0.01)
        wall = time.monotonic() - started
        status = est.diagnostic_status()
        executor.shutdown()
        for node in (est, recorder):
            node.destroy_node()
    finally:
        if sim is not None and sim.poll() is None:
            sim.terminate()
            sim.wait(timeout=10)
        rclpy.try_shutdown(context=context)

    if not estimates:
        raise RuntimeError(f"{scenario.vehicle}: the estimator published nothing on {recording.estimate_topic}")
    if not truth:
        raise RuntimeError(f"{scenario.vehicle}: no ground truth arrived on {recording.truth_topic}")
    return DemoRun(
        scenario=scenario,
        estimates=estimates,
        truth=truth,
        diagnostic_level=LEVEL_NAMES.get(status.level, "?"),
        diagnostic_message=status.message,
        diagnostic_values={kv.key: kv.value for kv in status.values},
        wall_time=wall,
        other_estimates=others,
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="terrain-demo", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", default="out/demo", help="directory for the plots (default: out/demo; its own, or a new one)"
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="write the plots into --out even if it holds files and was not made by a project tool",
    )
    parser.add_argument(
        "--realtime-factor",
        type=float,
        default=None,
        help=(
            "simulated seconds per wall second for every scenario (default: each scenario's own, "
            "1 for all but the rover's 4: a soil-stiffness node, one Python process, can fall behind "
            "the 1 kHz profile topic at 1.5x real time on a busy 2-core machine; its diagnostics "
            "then WARN of lost profile samples)"
        ),
    )
    parser.add_argument(
        "--vehicle",
        action="append",
        choices=[s.vehicle for s in SCENARIOS],
        help="only these vehicles (repeatable; default: all)",
    )
    args = parser.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    # The plots go into a directory a project tool made (or an empty one); other files are never touched.
    try:
        out = prepare_output_dir(args.out, overwrite=args.overwrite, tool="terrain-demo")
    except OutputPathError as exc:
        print(f"terrain-demo: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    # results per kind, kinds in the order of their first scenario
    by_kind: dict[str, tuple[DemoKind[Any], list[Any]]] = {}
    for scenario in SCENARIOS:
        if args.vehicle and scenario.vehicle not in args.vehicle:
            continue
        factor = scenario.realtime_factor if args.realtime_factor is None else args.realtime_factor
        print(
            f"{scenario.vehicle}: {scenario.title} — simulating {scenario.duration:.0f} s at "
            f"{factor:g}x real time, estimating live over ROS 2 ...",
            file=sys.stderr,
        )
        kind = scenario.kind
        result = kind.summarise(run_scenario(scenario, factor))
        by_kind.setdefault(kind.name, (kind, []))[1].append(result)
        print(f"  plot: {kind.plot(result, out)}", file=sys.stderr)
    for kind, results in by_kind.values():
        print()
        print(kind.table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
