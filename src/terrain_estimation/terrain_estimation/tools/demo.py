"""``make demo``: simulate each vehicle, estimate live over ROS 2, summarise.

For every vehicle that exists so far, the vehicle's simulator node runs as a
process of its own (publishing ``/clock``, sensors and ground truth) and this
process runs its estimator node (``use_sim_time``) and a recorder, all
talking over ROS 2 topics through DDS on this host. The "estimates" column
says how many of the expected estimates arrived: fewer means messages were
lost (a loaded machine, or a real-time factor the estimator cannot keep). Afterwards it prints a table (final estimate
against ground truth, time to converge, innovation consistency, the
estimator's diagnostic level) and writes plots under ``out/``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["DemoScenario", "DemoResult", "SCENARIOS", "run_scenario", "main"]


@dataclass(frozen=True)
class DemoScenario:
    """One demo run: a vehicle, simulator overrides and how long to drive."""

    vehicle: str
    title: str
    duration: float
    sim_overrides: dict[str, Any] = field(default_factory=dict)
    estimate_topic: str = "soil_stiffness"


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
)


@dataclass
class DemoResult:
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


def run_scenario(scenario: DemoScenario, realtime_factor: float, progress: bool = True) -> DemoResult:
    """Run one scenario live over ROS 2.

    The simulator runs as its own process (``terrain-sim-node``), as on a
    robot; the estimator node and a recorder share this process. The
    simulator starts stepping once the estimator's subscriptions are matched.
    """
    import subprocess
    import tempfile

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from terrain_estimation.ros.diagnostics import LEVEL_NAMES
    from terrain_estimation.ros.nodes import make_estimator_node
    from terrain_estimation.ros.qos import ESTIMATE_QOS
    from terrain_msgs.msg import SoilStiffness
    from vehicle_sim.ros.registry import get_simulator

    params = dict(scenario.sim_overrides)
    params.update(realtime_factor=realtime_factor, duration=scenario.duration, wait_for_subscribers=1)
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
        recorder.create_subscription(SoilStiffness, f"{ns}/{scenario.estimate_topic}", estimates.append, ESTIMATE_QOS)
        recorder.create_subscription(
            SoilStiffness, f"{ns}/ground_truth/{scenario.estimate_topic}", truth.append, ESTIMATE_QOS
        )
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
        raise RuntimeError(f"{scenario.vehicle}: the estimator published nothing")
    t_est = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in estimates])
    t_truth = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in truth])
    k_truth = np.array([m.k_s for m in truth])
    idx = np.clip(np.searchsorted(t_truth, t_est, side="right") - 1, 0, len(truth) - 1)
    return DemoResult(
        scenario=scenario,
        times=t_est,
        k_s=np.array([m.k_s for m in estimates]),
        k_s_std=np.sqrt(np.array([m.k_s_variance for m in estimates])),
        true_k_s=k_truth[idx],
        terrain_class=estimates[-1].terrain_class,
        nis=np.array([m.nis for m in estimates]),
        diagnostic_level=LEVEL_NAMES.get(status.level, "?"),
        diagnostic_message=status.message,
        wall_time=wall,
        sim_time=float(t_est[-1]),
        expected_estimates=round(scenario.duration * 100.0) - 1,
    )


def _plot(result: DemoResult, out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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


def _table(results: Sequence[DemoResult]) -> str:
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
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(head)]
    fmt = " | ".join(f"{{:<{w}}}" for w in widths)
    lines = [fmt.format(*head), "-+-".join("-" * w for w in widths)]
    lines += [fmt.format(*row) for row in rows]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="terrain-demo", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out", help="directory for the plots (default: out)")
    parser.add_argument(
        "--realtime-factor",
        type=float,
        default=2.0,
        help=(
            "simulated seconds per wall second (default 2: one Python process keeps up with "
            "the 1 kHz profile topic up to about 2.5x)"
        ),
    )
    parser.add_argument("--vehicle", action="append", help="only these vehicles (default: all)")
    args = parser.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for scenario in SCENARIOS:
        if args.vehicle and scenario.vehicle not in args.vehicle:
            continue
        print(
            f"{scenario.vehicle}: {scenario.title} — simulating {scenario.duration:.0f} s at "
            f"{args.realtime_factor:g}x real time, estimating live over ROS 2 ...",
            file=sys.stderr,
        )
        result = run_scenario(scenario, args.realtime_factor)
        results.append(result)
        print(f"  plot: {_plot(result, out)}", file=sys.stderr)
    print()
    print(_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
