"""What a demo scenario is, records and shares with every kind of estimate; its run over ROS 2.

Part of :mod:`terrain_analysis.tools.demo`: a :class:`DemoScenario` names its
:class:`DemoKind` (what to record, :class:`Recording`, and how to summarise,
plot and tabulate it; the kinds are in :mod:`~terrain_analysis.tools.demo_kinds`);
:func:`run_scenario` does the ROS 2 part the same way for every kind, and
:class:`RunSummary`, :func:`summary_table` and :func:`save_plot` are what the
kinds' results, tables and plots have in common.
"""

from __future__ import annotations

import functools
import importlib
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from terrain_analysis.reporting import pyplot as _pyplot

__all__ = [
    "Recording",
    "DemoRun",
    "DemoKind",
    "DemoScenario",
    "RunSummary",
    "StateSummary",
    "summary_table",
    "kind_table",
    "save_plot",
    "rms",
    "format_nis",
    "run_scenario",
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
        return import_type(self.msg_type)


def import_type(dotted: str) -> type:
    module, _, name = dotted.rpartition(".")
    cls: type = getattr(importlib.import_module(module), name)
    return cls


def stamps_ns(messages: Sequence[Any]) -> np.ndarray:
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
        return stamps_ns(self.estimates) * 1e-9

    @property
    def truth_times(self) -> np.ndarray:
        """Ground-truth stamps (s)."""
        return stamps_ns(self.truth) * 1e-9

    def nis(self) -> tuple[float, int]:
        """Mean NIS over the estimator's diagnostics window and the window's length (NaN, 0: not reported)."""
        values = self.diagnostic_values
        mean = float(values["nis_mean"]) if "nis_mean" in values else math.nan
        return mean, int(values.get("nis_window", "0"))

    def truth_index(self) -> np.ndarray:
        """For each estimate, the index of the newest ground truth stamped at or before it."""
        t_est = stamps_ns(self.estimates)
        t_truth = stamps_ns(self.truth)
        return np.clip(np.searchsorted(t_truth, t_est, side="right") - 1, 0, len(self.truth) - 1)

    def summary(self, expected_estimates: int, *, with_nis: bool = False) -> dict[str, Any]:
        """The :class:`RunSummary` fields of this run (``with_nis``: and :class:`StateSummary`'s NIS window),
        keyword arguments of a kind's result."""
        times = self.times
        nis = dict(zip(("nis_mean", "nis_window"), self.nis(), strict=True)) if with_nis else {}
        return nis | {
            "scenario": self.scenario,
            "times": times,
            "diagnostic_level": self.diagnostic_level,
            "diagnostic_message": self.diagnostic_message,
            "wall_time": self.wall_time,
            "sim_time": float(times[-1]),
            "expected_estimates": expected_estimates,
        }

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


def rms(error: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Root-mean-square of ``error`` over the rows where ``mask`` holds, per column (NaN: no row)."""
    if not np.any(mask):
        return np.full(error.shape[1:], math.nan)
    return np.asarray(np.sqrt(np.mean(error[mask] ** 2, axis=0)))


def format_nis(mean: float, window: int) -> str:
    return "n/a" if math.isnan(mean) else f"{mean:.2f} (last {window})"


def _format_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(head)]
    fmt = " | ".join(f"{{:<{w}}}" for w in widths)
    lines = [fmt.format(*head), "-+-".join("-" * w for w in widths)]
    lines += [fmt.format(*row) for row in rows]
    return "\n".join(lines)


@dataclass
class RunSummary:
    """What every kind's result holds besides its estimates: the scenario, stamps, diagnostics and timing.

    Attributes:
        scenario: the scenario run.
        times: estimate stamps (s).
        diagnostic_level, diagnostic_message: the estimator's diagnostics at the end.
        wall_time: wall-clock seconds of the run.
        sim_time: stamp of the last estimate (s).
        expected_estimates: the estimates a lossless run publishes.
    """

    scenario: DemoScenario
    times: np.ndarray
    diagnostic_level: str
    diagnostic_message: str
    wall_time: float
    sim_time: float
    expected_estimates: int


@dataclass
class StateSummary(RunSummary):
    """A result whose estimates are compared with the ground truth quantity by quantity.

    Attributes:
        estimate, std, truth: per quantity, the estimate, its σ and the ground truth at the estimates (the
            newest stamped at or before each).
        nis_mean, nis_window: the estimator's mean NIS over its diagnostics window and the window's length.
    """

    estimate: dict[str, np.ndarray]
    std: dict[str, np.ndarray]
    truth: dict[str, np.ndarray]
    nis_mean: float
    nis_window: int

    def error_rms(self, name: str, start: float) -> np.ndarray:
        """Root-mean-square error of ``name`` (per column) over the estimates stamped from ``start``."""
        return rms(self.estimate[name] - self.truth[name], self.times >= start)


def summary_table(
    head: Sequence[str], results: Sequence[Any], cells: Callable[[Any], Sequence[str]], note: str = ""
) -> str:
    """One kind's printed table: vehicle, times and estimates received, the kind's ``head`` and ``cells`` of a
    result, the diagnostics; ``note`` on a line below."""
    rows = [
        (
            r.scenario.vehicle,
            f"{r.sim_time:.1f}",
            f"{r.wall_time:.1f}",
            f"{r.times.size}/{r.expected_estimates}",
            *cells(r),
            f"{r.diagnostic_level}: {r.diagnostic_message}",
        )
        for r in results
    ]
    table = _format_table(("vehicle", "sim s", "wall s", "estimates", *head, "diagnostics"), rows)
    return table + "\n" + note if note else table


def kind_table(
    head: Sequence[str], cells: Callable[[Any], Sequence[str]], note: str = ""
) -> Callable[[Sequence[Any]], str]:
    """A kind's :attr:`DemoKind.table`: :func:`summary_table` with the kind's columns, cells and note."""
    return functools.partial(summary_table, head, cells=cells, note=note)


def save_plot(fig: Any, out: Path, result: RunSummary, what: str) -> Path:
    """Lay ``fig`` out, save it as ``out/<vehicle>_<what>.png`` and close it; the file written."""
    fig.tight_layout()
    path = out / f"{result.scenario.vehicle}_{what}.png"
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path


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
    kind: DemoKind[Any] = field(kw_only=True)
    realtime_factor: float = 1.0


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
            recorder.create_subscription(import_type(other_type), f"{ns}/{topic}", received.append, ESTIMATE_QOS)
        for other_type, topic in recording.other_sensors:
            recorder.create_subscription(import_type(other_type), f"{ns}/{topic}", lambda _msg: None, SENSOR_QOS)
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
