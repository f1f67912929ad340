"""The figures of ``bench_load``: the printed and Markdown tables, the verdicts, the offline ceiling, the page.

Part of :mod:`terrain_analysis.tools.bench_load`.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from typing import Any

from terrain_analysis.tools import bench

__all__ = ["HEADER", "QOS_TEXT", "ceiling_line", "format_markdown", "format_table", "machine_info", "verdicts"]

HEADER = (
    "row",
    "vehicles",
    "sim s",
    "published",
    "dropped",
    "estimates",
    "latency median ms",
    "latency p99 ms",
    "CPU s/vehicle/sim s",
    "executor thread CPU s/sim s",
    "player CPU s/sim s",
    "offered x",
    "achieved x",
)


def _cells(r: dict[str, Any]) -> list[str]:
    return [
        r["row"],
        str(r["vehicles"]),
        f"{r['sim_s']:.2f}",
        str(r["published"]),
        f"{r['dropped']} ({100 * r['dropped'] / r['published']:.1f} %)",
        f"{r['estimates']}/{r['expected_estimates']}",
        _figure(r["latency_median_ms"], 2),
        _figure(r["latency_p99_ms"], 1),
        f"{r['cpu_per_vehicle_per_sim_s']:.3f}",
        f"{r['executor_cpu_per_sim_s']:.3f}",
        f"{r['player_cpu_per_sim_s']:.3f}",
        f"{r['offered_x_real_time']:.1f}",
        f"{r['x_real_time']:.2f}",
    ]


def _figure(value: float, decimals: int) -> str:
    """A figure, or ``n/a`` where there is none (latency of a row without estimates)."""
    return f"{value:.{decimals}f}" if math.isfinite(value) else "n/a"


def format_table(rows: Sequence[dict[str, Any]], markdown: bool = False) -> str:
    """The figures as an aligned text table (or a Markdown table)."""
    body = [_cells(r) for r in rows]
    if markdown:
        lines = ["| " + " | ".join(HEADER) + " |", "|" + "|".join("---" for _ in HEADER) + "|"]
        lines += ["| " + " | ".join(c) + " |" for c in body]
        return "\n".join(lines)
    widths = [max(len(h), *(len(c[i]) for c in body)) for i, h in enumerate(HEADER)]
    lines = [" | ".join(h.ljust(w) for h, w in zip(HEADER, widths, strict=True))]
    lines += [" | ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)) for cells in body]
    return "\n".join(lines)


def machine_info() -> dict[str, Any]:
    """:func:`terrain_analysis.tools.bench.machine_info` and the ROS middleware (``RMW_IMPLEMENTATION``)."""
    return bench.machine_info() | {"rmw": os.environ.get("RMW_IMPLEMENTATION", "default")}


def _cpu_demand(r: dict[str, Any], cpus: int | None) -> str:
    """What the offered rate asks of the CPUs, from the row's CPU per simulated second (a lower bound
    where input was dropped: the nodes spent nothing on what they never took)."""
    processes = int(r["case"].get("processes", 1))
    per_process = r["cpu_per_vehicle_per_sim_s"] * r["vehicles"] / processes * r["offered_x_real_time"]
    per_thread = r["executor_cpu_per_sim_s"] * r["offered_x_real_time"]
    total = per_process * processes + r["player_cpu_per_sim_s"] * r["offered_x_real_time"]
    if per_process < 0.8 and per_thread < 0.8 and (cpus is None or total < 0.8 * cpus):
        return ""
    at_least = "at least " if r["dropped"] else ""
    text = f"; the offered rate needs {at_least}{per_process:.2f} CPU s per wall s in each estimator process"
    text += f", {per_thread:.2f} of them in its executor thread (the callbacks run there, one at a time: 1.00 at most)"
    if cpus is not None:
        text += f", {total:.2f} with the player, on {cpus} CPUs"
    return text


def verdicts(rows: Sequence[dict[str, Any]], cpus: int | None = None) -> list[str]:
    """One line per target, computed from the figures (``cpus``: the machine's, for the CPU demand)."""
    out = []
    for r in rows:
        case = r["case"]
        if r["row"].startswith("(a)"):
            continue
        if case.get("empty_callbacks") or case.get("bare_node"):
            offered = r["offered_x_real_time"]
            per_message_us = 1e6 * r["executor_cpu_per_sim_s"] * r["sim_s"] / max(r["consumed"], 1)
            what = (
                "the node framework (decoding, take, merge; checks and estimator doing nothing)"
                if case.get("bare_node")
                else "message delivery alone (callbacks that only decode and count)"
            )
            floor = "the floor under any estimator"
            if case.get("bare_node"):
                floor = "the floor under this node's estimators"
            out.append(
                f"- {r['row']}: {what}, at {offered:.1f}x "
                f"offered: {r['dropped']} of {r['published']} dropped; the executor thread needs "
                f"{r['executor_cpu_per_sim_s'] * offered:.2f} CPU s per wall s ({per_message_us:.0f} us per "
                f"message), the process {r['cpu_per_vehicle_per_sim_s'] * r['vehicles'] * offered:.2f}, "
                f"the player {r['player_cpu_per_sim_s'] * offered:.2f}: {floor}"
            )
            continue
        if case["factor"] > 0:  # paced (simulated drives at 1x, bag replays at 20x): did the node follow?
            behind = r["x_real_time"] < 0.9 * r["offered_x_real_time"]
            if r["dropped"]:
                verdict = "did not keep up: dropped input"
            elif r["node_estimates"] < r["expected_estimates"] - 2 * r["vehicles"]:
                verdict = "no input dropped but filter steps lost (inputs served out of time order)"
            elif behind:
                verdict = "no input dropped (the queue held the burst) but fell behind"
            else:
                verdict = "kept up"
            lost = r["node_estimates"] - r["estimates"]
            if lost > 0:  # published by the nodes, not received (reliable, keep last 10: a busy reader loses some)
                verdict += f"; {lost} of the {r['node_estimates']} estimates published did not reach the collector"
            out.append(
                f"- {r['row']}: {verdict} ({r['dropped']} of {r['published']} sensor messages dropped, "
                f"{r['x_real_time']:.2f}x achieved of {r['offered_x_real_time']:.1f}x offered, "
                f"latency p99 {r['latency_p99_ms']:.0f} ms){_cpu_demand(r, cpus)}"
            )
        else:  # as fast as the node takes it
            out.append(
                f"- {r['row']}: sustained {r['x_real_time']:.2f}x real time, {r['dropped']} dropped, "
                f"{r['estimates']} of {r['expected_estimates']} estimates"
                + (
                    f"; the player went on {r['flow_stalls']} time(s) after {r['flow_stall_s']:g} s "
                    "without an estimate (a best-effort message lost)"
                    if r.get("flow_stalls")
                    else ""
                )
            )
    return out


def ceiling_line(c: dict[str, Any]) -> str:
    line = (
        f"offline ceiling, {c['vehicle']} (bag through adapter and filter, no ROS, one core): "
        f"{c['x_real_time']:.2f}x real time, {c['cpu_per_sim_s']:.3f} CPU s per sim s"
    )
    if c["vehicle"] == "quarter_car":  # one estimate per filter step
        line += f", {c['us_per_step']:.0f} us per filter step"
    return line


QOS_TEXT = """\
- Sensor topics (`imu/body`, `imu/wheel`, `joint_states`, `terrain/profile`): best effort, volatile,
  keep last 200 (`terrain_estimation.ros.qos.SENSOR_QOS`) on the publisher and on the subscription.
  Best effort is the contract's sensor-data profile (a best-effort subscription matches best-effort and
  reliable drivers); the depth of 200 holds 0.15 s of the nominal quarter car's 1.3 kHz input, so a
  stall of the estimator shorter than that loses nothing. An overflowing best-effort queue drops the
  oldest samples: the "dropped" column.
- Estimates (`soil_stiffness`): reliable, volatile, keep last 10 (`ESTIMATE_QOS`).
- Executor: one per process. `single` is rclpy's `SingleThreadedExecutor` with the node's
  `input.take_queued` at 0: one message per ready subscription per wait, the wait set rebuilt in
  Python each time. `events`: rclpy's C++ `EventsExecutor` (`rclpy.experimental`, in the Jazzy
  wheels), one message per callback in arrival order (`input.take_queued` 0). `events+take`: what
  `terrain-estimator-node` runs, the same executor with the node's default `input.take_queued` (50):
  after each delivered message the node takes what is already queued on its input subscriptions and
  handles it merged in stamp order (each topic in its own order). A topic drained on its own would run
  ahead of the others (the quarter car's accelerometers ahead of the 1 kHz profile, whose filter steps
  would then be dropped for want of road).
- Deep-queue rows (`depth 6000`): the sensor queues of both sides deep enough for the whole bag, to
  separate loss by overflow from loss by speed.
- The offline ceiling is the same adapter and filter fed from the bag without ROS: no executor makes
  one node faster than that; beyond it a queue only postpones the loss (it grows without bound at a
  sustained rate above the ceiling).
- Namespaces: every vehicle under `/vK`, frames `vK/...`; the collector checks the frame of every
  estimate against its topic's vehicle."""


def format_markdown(
    rows: Sequence[dict[str, Any]],
    ceilings: dict[str, dict[str, Any]],
    machine: dict[str, Any],
    command: str,
    quick: bool,
) -> str:
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    lines = [
        "# Robustness: many vehicles and load (issue 7 item 5)",
        "",
        f"Produced by `{command}` on {date}; machine: {machine['cpu_count']} CPUs, load average "
        f"{machine['load_avg_1min']:.2f} at the end (other jobs shared the machine), {machine['platform']}, "
        f"Python {machine['python']}, RMW {machine['rmw']}, OPENBLAS_NUM_THREADS={machine['OPENBLAS_NUM_THREADS']}."
        + (" **Quick run** (short drives): not the figures to quote." if quick else ""),
        "",
        "Estimator nodes (the project's `EstimatorNode`: quarter car, SCKF, in rows (a)-(d); skid steer and rover",
        "in (e)) run in a host process of their own, fed over DDS from a player process; each vehicle under its",
        "own namespace `/vK` with its own soil, road and noise seeds. Latency: publication of the last sensor",
        "message of an instant to publication of its estimate (middleware source timestamp; the skid steer's",
        "`odom`, the rover's `wheel_terrain`). Dropped: sensor messages published minus consumed by",
        "the nodes. CPU: host-process CPU seconds per vehicle per simulated second; executor thread: the part",
        "spent in the thread that runs every callback (one at a time: 1 / this is the fastest replay one process",
        "follows); player: the publishing process's own (it publishes serialised messages, as `ros2 bag play`).",
        "Offered/achieved x:",
        "simulated over wall seconds of the publication and of the estimates. No figure here is asserted",
        "by a test; `test/test_bench_load_smoke.py` only checks that every row prints.",
        "",
        format_table(rows, markdown=True),
        "",
        "## Targets (computed from the table)",
        "",
        *verdicts(rows, machine["cpu_count"]),
        "",
        *("- " + ceiling_line(c) for c in ceilings.values()),
        "",
        "## QoS and queue choices",
        "",
        QOS_TEXT,
        f"  Estimates in another vehicle's frame, over every row: {sum(r['foreign_frames'] for r in rows)}.",
        "",
    ]
    return "\n".join(lines)
