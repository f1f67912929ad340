"""``python -m terrain_analysis.tools.bench_load``: many vehicles and load (issue 7 item 5).

Each row runs the estimator nodes in a process of their own (the *host*,
``--host``, the way ``terrain-estimator-node`` runs them: one rclpy executor
spinning every node of the process) and feeds them from this process (the
*player*) over DDS, each vehicle under its own namespace ``/v0``, ``/v1``, …
with its own frames and its own input (its own soil, road seed and noise
seed). The player publishes the messages serialised, as ``ros2 bag play``
does, and its collector takes the estimates raw and reads only their header
(:func:`cdr_header`): on a 2-CPU machine every CPU second the player spends
is one the nodes cannot have. Rows:

(a) one quarter car at its nominal rates (accelerometers and joint states
    100 Hz, ``terrain/profile`` 1 kHz) at 1× real time;
(b) the same with the accelerometers and joint states at 1 kHz
    (``sensors.rate: 1000``; the filter still steps at 100 Hz and decimates);
(c) the recorded bag ``bags/quarter_car_graneville_iso_d_10ms`` replayed as
    fast as the node takes it (flow control: the player stays at most
    :data:`FLOW_WINDOW_S` of simulated time ahead of the last estimate it
    received, so no queue overflows; the row's "× real time" is what the
    node sustains) and open loop at 20× real time;
(d) N = 1, 5, 10 quarter cars in one host process at 1× real time, and the
    ten spread over two host processes (one Python process runs its callbacks
    on one core at a time);
(e) the skid-steer and rover estimators on their recorded bags
    (:data:`BAG_OF`), as fast as the node takes them and at 20× real time
    (events executor; the expected estimates and the flow-control window, two
    estimate periods at least, come from the same bag run offline).

Figures per row:

* **latency**: for each estimate, the time from the publication of the last
  sensor message of its instant (the player's wall clock just before
  ``publish``) to the publication of the estimate (the estimate's
  ``source_timestamp`` from the middleware, same system clock): median and
  99th percentile over every estimate of every vehicle, in ms;
* **dropped**: sensor messages published minus those the estimator nodes
  consumed (their callbacks ran), over all vehicles;
* **CPU**: CPU seconds of the host process (every thread: rclpy, DDS,
  filters) divided by the number of vehicles and by the simulated seconds;
  1.0 means one vehicle takes one core at real time;
* **executor thread CPU**: the part of it spent in the thread that spins the
  executor (every callback: input checks, filter, building and publishing the
  estimates, rclpy's take of each message and its decoding), per
  simulated second, for the busiest host process. Callbacks run there one at
  a time, so ``1 / this`` is the fastest replay one process can follow,
  whatever the number of cores;
* **× real time**: simulated seconds over wall seconds from the first
  publication to the last estimate (for open-loop rows: what the player
  offered, and whether the node followed).

Executors compared (``executor`` column; the host builds it, the nodes are the
project's own :class:`~terrain_estimation.ros.framework.EstimatorNode`):

* ``single``: rclpy's ``SingleThreadedExecutor`` with the node's
  ``input.take_queued`` set to 0. It waits, then takes *one* message per
  ready subscription per wait, rebuilding the wait set (every subscription,
  timer, service and guard condition of every node) in Python each time;
* ``events``: rclpy's ``EventsExecutor`` (``rclpy.experimental``, C++, in
  the Jazzy wheels), ``input.take_queued`` 0: the middleware's events drive
  the callbacks in arrival order, one message per callback, no wait set;
* ``events+take``: the same executor with the node's default
  ``input.take_queued`` (what ``terrain-estimator-node`` runs): after each
  delivered message the node takes what is already queued on its input
  subscriptions and handles it in stamp order
  (:meth:`~terrain_estimation.ros.framework.EstimatorNode._take_queued`),
  about half the executor-thread CPU per message under a backlog.

Every node subscribes to its inputs raw and decodes them itself
(:mod:`~terrain_estimation.ros.cdr`, ``input.fast_decode``, the default);
rows labelled ``rclpy-decode`` set ``input.fast_decode`` false, so rclpy's
``deserialize_message`` decodes them, for comparison in the same run.

QoS and queues (:mod:`terrain_estimation.ros.qos`, CONTRACT.md): sensor topics
best effort, keep last :data:`~terrain_estimation.ros.qos.SENSOR_DEPTH` on
both sides (publisher and subscription), so a subscriber takes best-effort and
reliable publishers alike and a burst is queued, not lost, while a callback
runs; a best-effort queue that overflows drops the oldest samples (counted
here as "dropped"). Estimates: reliable, keep last 10. Best effort is kept for
sensors (the contract; a reliable subscription would refuse a best-effort
IMU driver); what keeps the input lossless is that the node drains the queue
faster than it fills, and a depth that covers the longest stall.

Nothing here asserts a time: the figures depend on the machine (its CPU
count and load average are printed). ``--quick`` is a smoke run (short
drives, N = 1, 2, 3 instead of 1, 5, 10, ``events`` without the take in one row); ``--out FILE`` writes the Markdown
report (``make bench-load`` writes ``docs/results/robustness.md``).

The estimator host is :mod:`~terrain_analysis.tools.bench_load_host`, the
tables, verdicts and page :mod:`~terrain_analysis.tools.bench_load_report`.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import re
import struct
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.reporting import keep_sections
from terrain_analysis.tools.bench_load_host import Host, host_main, namespace_of, sensor_qos
from terrain_analysis.tools.bench_load_report import (
    HEADER,
    ceiling_line,
    format_markdown,
    format_table,
    machine_info,
    verdicts,
)
from terrain_estimation.cli import cli_main

__all__ = [
    "HEADER",
    "Case",
    "EXECUTORS",
    "FLOW_WINDOW_S",
    "cases",
    "cdr_header",
    "row_labels",
    "format_table",
    "main",
    "run_case",
]

BAGS_DIR = Path(__file__).resolve().parents[4] / "bags"
BAG = "quarter_car_graneville_iso_d_10ms"
BAG_OF: dict[str, str] = {
    "quarter_car": BAG,
    "skid_steer": "skid_steer_s_shape",
    "rover": "rover_terrain_1",
}
"""The recorded bag each vehicle's bag rows replay (``bags/``)."""
EXECUTORS: tuple[str, ...] = ("single", "events", "events+take")
FLOW_WINDOW_S = 0.1
"""Flow-controlled replay: simulated seconds the player may run ahead of the last estimate (130 messages
of the nominal quarter car, inside the sensor queue depth of 200)."""
SOILS = (
    "graneville_loam",
    "upland_sandy_loam",
    "lete_sand",
    "rubicon_sandy_loam",
    "north_gower_clayey_loam",
)
DEEP_QUEUE = 6000
"""Sensor queue depth of the deep-queue rows: the whole 4 s bag (5 201 messages, 4 001 of them profile)."""
TAIL_QUIET_S = 1.5
"""After the last publication, a row ends when every expected estimate arrived or none for this long."""
FLOW_STALL_S = 2.0
"""Flow-controlled replay: with no estimate for this long the player publishes the next message anyway (a
best-effort message, an input or an estimate, was lost: waiting for its estimate would wait for ever); the
row counts these releases (``flow_stalls``)."""
FLOW_SILENCE_S = 20.0
"""Flow-controlled replay: no estimate at all for this long, stall releases included, is an error (the
nodes are gone)."""


@dataclasses.dataclass(frozen=True)
class Case:
    """One row of the benchmark.

    Attributes:
        label: row label (printed first on its line).
        vehicles: number of quarter cars in the host process.
        source: ``"sim"`` (simulated drive, per vehicle its own soil and seeds) or ``"bag"``.
        factor: × real time of an open-loop replay; 0: as fast as the node takes it (flow control).
        duration: simulated seconds of a ``"sim"`` source (a bag plays whole).
        sensor_rate: accelerometer and joint-state rate (Hz) of a ``"sim"`` source.
        executor: ``single``, ``events`` or ``events+take`` (module docstring).
        sensor_depth: sensor queue depth on both sides; 0: the project's
            :data:`~terrain_estimation.ros.qos.SENSOR_DEPTH`.
        processes: host processes the vehicles are spread over (CPU: their sum).
        vehicle: the estimator (``quarter_car``, or for ``"bag"`` rows also
            ``skid_steer`` and ``rover``, replaying :data:`BAG_OF`).
        empty_callbacks: the host runs :func:`empty_callback_node` instead of
            the estimator: the same subscriptions (topics, types, QoS, raw) with
            callbacks that only decode and count, so the row measures what
            delivering the messages to Python costs, the floor under any estimator.
        bare_node: the host runs the estimator node with its input checks and
            adapter replaced by functions that do nothing: what the node
            framework (decoding, take, merge, bookkeeping) costs per message on
            top of the delivery floor, before any estimator work.
        fast_decode: the nodes' ``input.fast_decode`` (False: rclpy's
            ``deserialize_message`` decodes the inputs instead of
            :mod:`~terrain_estimation.ros.cdr`; rows labelled ``rclpy-decode``).
    """

    label: str
    vehicles: int
    source: str
    factor: float
    duration: float
    sensor_rate: float = 100.0
    executor: str = "single"
    sensor_depth: int = 0
    processes: int = 1
    vehicle: str = "quarter_car"
    empty_callbacks: bool = False
    bare_node: bool = False
    fast_decode: bool = True


def cases(quick: bool = False) -> list[Case]:
    """The rows, in print order (``quick``: short drives, N = 1, 2, 3, ``events`` without the take once)."""
    d = 0.5 if quick else 10.0
    fleet = (1, 2, 3) if quick else (1, 5, 10)
    rows = [
        *(Case(f"(a) nominal 1x {ex}", 1, "sim", 1.0, d, executor=ex) for ex in ("single", "events+take")),
        *(Case(f"(b) 1 kHz IMU 1x {ex}", 1, "sim", 1.0, d, 1000.0, ex) for ex in EXECUTORS),
        *(Case(f"(c) bag max {ex}", 1, "bag", 0.0, 0.0, executor=ex) for ex in EXECUTORS),
        Case("(c) bag max events+take rclpy-decode", 1, "bag", 0.0, 0.0, executor="events+take", fast_decode=False),
        *(Case(f"(c) bag 20x {ex}", 1, "bag", 20.0, 0.0, executor=ex) for ex in EXECUTORS),
        *(
            Case(f"(c) bag 20x {ex} depth {DEEP_QUEUE}", 1, "bag", 20.0, 0.0, executor=ex, sensor_depth=DEEP_QUEUE)
            for ex in EXECUTORS[1:]
        ),
        *(Case(f"(d) N={n} 1x single", n, "sim", 1.0, d) for n in fleet),
        Case(f"(d) N={fleet[1]} 1x events+take", fleet[1], "sim", 1.0, d, executor="events+take"),
        *(Case(f"(d) N={fleet[-1]} 1x {ex}", fleet[-1], "sim", 1.0, d, executor=ex) for ex in EXECUTORS[1:]),
        Case(
            f"(d) N={fleet[-1]} 1x events+take, 2 processes",
            fleet[-1],
            "sim",
            1.0,
            d,
            executor="events+take",
            processes=2,
        ),
        # The other estimators on their recorded bags, as the node runs (events+take); the skid
        # steer's 20x also without the take.
        *(
            Case(f"(e) {v} bag {'max' if x == 0 else f'{x:g}x'} {ex}", 1, "bag", x, 0.0, executor=ex, vehicle=v)
            for v in ("skid_steer", "rover")
            for x in (0.0, 20.0)
            for ex in (("events", "events+take") if (v, x) == ("skid_steer", 20.0) else ("events+take",))
        ),
        Case(
            "(e) skid_steer bag max events+take rclpy-decode",
            1,
            "bag",
            0.0,
            0.0,
            executor="events+take",
            vehicle="skid_steer",
            fast_decode=False,
        ),
        # The floor: the same inputs into callbacks that only decode them.
        *(
            Case(
                f"(f) {'' if v == 'quarter_car' else v + ' '}bag 20x events, empty callbacks",
                1,
                "bag",
                20.0,
                0.0,
                executor="events",
                vehicle=v,
                empty_callbacks=True,
            )
            for v in ("quarter_car", "skid_steer")
        ),
        Case(
            "(f) bag 20x events+take depth 6000, node without checks and estimator",
            1,
            "bag",
            20.0,
            0.0,
            executor="events+take",
            sensor_depth=DEEP_QUEUE,
            bare_node=True,
        ),
        Case(
            f"(f) N={fleet[-1]} 1x events, empty callbacks",
            fleet[-1],
            "sim",
            1.0,
            d,
            executor="events",
            empty_callbacks=True,
        ),
    ]
    if quick:  # the events executor without the take once (bag max): every host start costs seconds
        rows = [c for c in rows if c.executor != "events" or c.label.startswith(("(c) bag max", "(f)"))]
    return rows


def row_labels(quick: bool = False) -> list[str]:
    return [c.label for c in cases(quick)]


# ---------------------------------------------------------------------------
# Inputs
# ---------------------------------------------------------------------------


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def cdr_header(data: bytes) -> tuple[int, str]:
    """``(stamp ns, frame_id)`` of a serialised message that begins with a ``std_msgs/Header``.

    The collector takes the estimates raw (``raw=True``) and reads only this: CDR puts the
    4-byte encapsulation first (its second byte 1 for little endian), then ``stamp.sec``
    (int32), ``stamp.nanosec`` (uint32) and ``frame_id`` (uint32 length with the
    terminating NUL, then the bytes). Every estimate type of the contract starts with
    its header (a test checks each against the full deserialisation).
    """
    order = "<" if data[1] == 1 else ">"
    sec, nanosec, length = struct.unpack_from(order + "iII", data, 4)
    frame = data[16 : 16 + max(length - 1, 0)].decode()
    return sec * 1_000_000_000 + nanosec, frame


@functools.lru_cache(maxsize=32)
def simulated_inputs(k: int, duration: float, sensor_rate: float, seed: int = 70) -> list[tuple[str, Any]]:
    """Vehicle ``k``'s sensor messages ``(relative topic, msg)`` in publication order: a quarter car on
    its own soil, road and noise seeds, frames under ``/vK`` (cached: rows share their drives)."""
    from vehicle_sim.ros.registry import get_simulator, simulator_parameters

    entry = get_simulator("quarter_car")
    values = simulator_parameters(
        entry,
        overrides={
            "scenario.soils": [SOILS[k % len(SOILS)]],
            "scenario.road_seed": seed + k,
            "seed": seed + 100 + k,
            "sensors.rate": float(sensor_rate),
        },
    )
    adapter = entry.make_adapter(values, namespace_of(k))
    topics = {o.key: o.topic for o in adapter.outputs if o.kind == "sensor"}
    out: list[tuple[str, Any]] = []
    t = 0.0
    while t < duration - 1e-9:
        t, messages = adapter.step()
        out.extend((topics[key], msg) for key, msg in messages if key in topics)
    return out


def bag_inputs(
    path: Path,
    namespace: str = "/quarter_car",
    into: str = "/v0",
    inputs: frozenset[str] = frozenset({"imu/body", "imu/wheel", "joint_states", "terrain/profile"}),
) -> list[tuple[str, Any]]:
    """The bag's sensor messages ``(relative topic, msg)`` in log order (the estimator's ``inputs``
    only), their frames moved from the bag's ``namespace`` into ``into`` (the nodes check the frames)."""
    from terrain_estimation.bag import read_bag

    prefix = namespace.rstrip("/") + "/"
    frame_from, frame_to = namespace.strip("/") + "/", into.strip("/") + "/"
    out = []
    for item in read_bag(path):
        if item.topic.startswith(prefix) and item.topic[len(prefix) :] in inputs:
            header = item.msg.header
            if header.frame_id.startswith(frame_from):
                header.frame_id = frame_to + header.frame_id[len(frame_from) :]
            out.append((item.topic[len(prefix) :], item.msg))
    return out


@functools.lru_cache(maxsize=8)
def _offline_estimates(bag: Path, vehicle: str, topic: str) -> tuple[int, float]:
    """(estimates on ``topic``, their median period in s) of the bag run offline through the same adapter
    (cached: the max and 20x rows share it)."""
    from terrain_estimation.tools.estimate import estimate_bag

    stamps = np.array([_stamp_ns(m) for m in estimate_bag(bag, vehicle).messages(topic)], dtype=float)
    if stamps.size < 2:
        raise RuntimeError(f"bench: {bag} gives {stamps.size} estimates on {topic} offline")
    return int(stamps.size), float(np.median(np.diff(stamps))) * 1e-9


def expected_estimates(stream: Sequence[tuple[str, Any]], filter_rate: float = 100.0) -> int:
    """Estimates a lossless run publishes: one per filter step after the first, the steps being the
    accelerometer samples at least half a filter period after the previous step (the estimator's
    decimation, ``filter.rate``)."""
    min_dt = 0.5 / filter_rate
    last = -math.inf
    steps = 0
    for topic, msg in stream:
        if topic == "imu/body":
            t = _stamp_ns(msg) * 1e-9
            if t - last >= min_dt:
                steps += 1
                last = t
    return max(0, steps - 1)


def _profile_path(profile_dir: Path | None, label: str, first: int, processes: int) -> str:
    if profile_dir is None:
        return ""
    name = re.sub(r"[^A-Za-z0-9_.+-]+", "_", label).strip("_")
    return str(profile_dir / (name + (f".{first}" if processes > 1 else "") + ".pstats"))


def offline_ceiling(bags_dir: Path, repeats: int, vehicle: str = "quarter_car") -> dict[str, Any]:
    """The vehicle's bag (:data:`BAG_OF`) through the adapter and filter without ROS
    (``terrain-estimate``'s runner): the speed no executor can beat in one process."""
    from terrain_analysis.tools.bench import bench_bag

    row = bench_bag(bags_dir / BAG_OF[vehicle], vehicle, repeats)
    row["cpu_per_sim_s"] = 1.0 / row["x_real_time"]
    return row


# ---------------------------------------------------------------------------
# Player: publishes the inputs, collects the estimates
# ---------------------------------------------------------------------------


def run_case(case: Case, bags_dir: Path = BAGS_DIR, profile_dir: Path | None = None) -> dict[str, Any]:
    """Run one row: start the host, publish, collect, and return its figures.

    ``profile_dir``: each host process profiles its executor thread (``cProfile``, from the start
    of the publication) into ``<profile_dir>/<row label>[.<first vehicle>].pstats``.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.serialization import serialize_message

    from terrain_estimation.ros.qos import ESTIMATE_QOS
    from terrain_estimation.tools.estimate import topic_name
    from terrain_estimation.vehicles import estimator_parameters, get_vehicle

    entry = get_vehicle(case.vehicle)
    adapter = entry.make_adapter(estimator_parameters(entry), namespace_of(0))
    types = {spec.topic: spec.msg_type for spec in adapter.inputs}
    estimate = next(spec for spec in adapter.outputs if spec.kind == "estimate")  # the first: the one timed
    flow_window = FLOW_WINDOW_S
    if case.source == "bag":
        bag = bags_dir / BAG_OF[case.vehicle]
        streams = [bag_inputs(bag, entry.namespace, inputs=frozenset(types))]
        if case.vehicle == "quarter_car":
            expected = expected_estimates(streams[0])
        else:  # what the same adapter publishes offline (``terrain-estimate``), and at what period
            expected, period = _offline_estimates(bag, case.vehicle, topic_name(entry.namespace, estimate.topic))
            flow_window = max(FLOW_WINDOW_S, 2.0 * period)
    else:
        if case.vehicle != "quarter_car":
            raise ValueError(f"bench row {case.label!r}: simulated drives are quarter cars only, not {case.vehicle}")
        streams = [simulated_inputs(k, case.duration, case.sensor_rate) for k in range(case.vehicles)]
        expected = sum(expected_estimates(stream) for stream in streams)
    if case.empty_callbacks or case.bare_node:
        expected = 0  # nothing is estimated
    # One time-ordered stream over every vehicle: (stamp ns, vehicle, index, topic, serialised msg).
    # Published serialised, as a bag player does (``ros2 bag play``): the player's CPU goes to
    # the transport, not to converting Python messages, and the nodes receive the same bytes.
    merged = sorted(
        (_stamp_ns(msg), k, i, topic, serialize_message(msg))
        for k, stream in enumerate(streams)
        for i, (topic, msg) in enumerate(stream)
    )
    stamp0 = merged[0][0]
    sim_s = (merged[-1][0] - stamp0) * 1e-9

    per_host = -(-case.vehicles // case.processes)
    hosts = [
        Host(
            dataclasses.asdict(case)
            | {
                "vehicles": min(per_host, case.vehicles - first),
                "first": first,
                "profile": _profile_path(profile_dir, case.label, first, case.processes),
            }
        )
        for first in range(0, case.vehicles, per_host)
    ]
    context = Context()
    rclpy.init(context=context)
    player = Node("load_player", context=context)
    collector = Node("load_collector", context=context)
    publishers = {
        (k, topic): player.create_publisher(types[topic], f"{namespace_of(k)}/{topic}", sensor_qos(case.sensor_depth))
        for k in range(case.vehicles)
        for topic in types
    }
    lock = threading.Lock()
    estimates: list[tuple[int, int, int, str]] = []  # vehicle, stamp ns, source timestamp ns, frame
    last_estimate = [stamp0] * case.vehicles
    last_arrival = [time.monotonic()]

    # Two parameters: rclpy passes the MessageInfo (its source timestamp is the estimate's publication).
    # Raw: only the header is read (cdr_header), the player's process stays light.
    def collect(k: int) -> Any:
        def callback(data: bytes, info: Any) -> None:
            stamp, frame = cdr_header(data)
            with lock:
                estimates.append((k, stamp, int(info["source_timestamp"]), frame))
                last_estimate[k] = max(last_estimate[k], stamp)
                last_arrival[0] = time.monotonic()

        return callback

    subscriptions = [
        collector.create_subscription(
            estimate.msg_type, f"{namespace_of(k)}/{estimate.topic}", collect(k), ESTIMATE_QOS, raw=True
        )
        for k in range(case.vehicles)
    ]
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(collector)
    spinning = threading.Event()
    spinning.set()

    def spin() -> None:
        while spinning.is_set():
            executor.spin_once(timeout_sec=0.02)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    published_at: dict[tuple[int, int], int] = {}
    flow_stalls = 0
    try:
        deadline = time.monotonic() + 30.0
        while not (
            all(p.get_subscription_count() > 0 for p in publishers.values())
            and all(s.get_publisher_count() > 0 for s in subscriptions)
        ):
            if time.monotonic() > deadline:
                raise RuntimeError("the estimator nodes were not discovered within 30 s")
            time.sleep(0.02)
        time.sleep(0.2)  # both directions matched
        for host in hosts:
            host.send("start")
        t_start = time.perf_counter()
        player_cpu0 = time.process_time()
        for stamp, k, _, topic, msg in merged:
            if case.factor > 0:
                due = t_start + (stamp - stamp0) * 1e-9 / case.factor
                wait = due - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
            else:
                waited_from = time.monotonic()
                while (stamp - last_estimate[k]) * 1e-9 > flow_window:
                    now = time.monotonic()
                    if now - last_arrival[0] > FLOW_SILENCE_S:
                        raise RuntimeError(
                            f"flow-controlled replay of {case.label!r}: no estimate for {FLOW_SILENCE_S:g} s "
                            f"({len(estimates)} of {expected} arrived): the estimator nodes stopped"
                        )
                    if now - max(waited_from, last_arrival[0]) > FLOW_STALL_S:
                        flow_stalls += 1  # a lost message: release the next one
                        break
                    time.sleep(0.0002)
            published_at[(k, stamp)] = time.time_ns()
            publishers[(k, topic)].publish(msg)
        t_published = time.perf_counter()
        player_cpu_s = time.process_time() - player_cpu0
        last_arrival[0] = time.monotonic()
        while time.monotonic() - last_arrival[0] < TAIL_QUIET_S and len(estimates) < expected:
            time.sleep(0.02)
        reports = [host.finish() for host in hosts]
    finally:
        spinning.clear()
        spinner.join(timeout=5)
        for host in hosts:
            host.kill()
        executor.shutdown()
        player.destroy_node()
        collector.destroy_node()
        rclpy.try_shutdown(context=context)

    with lock:
        got = list(estimates)
    latencies_ms = [
        (source - published_at[(k, stamp)]) * 1e-6 for k, stamp, source, _ in got if (k, stamp) in published_at
    ]
    last_source_ns = max((source for _, _, source, _ in got), default=0)
    first_pub_ns = min(published_at.values())
    wall_s = max((last_source_ns - first_pub_ns) * 1e-9, t_published - t_start)
    foreign = sum(1 for k, _, _, frame in got if not frame.startswith(f"v{k}/"))
    published = len(merged)
    consumed = sum(sum(r["handled"]) for r in reports)
    cpu_s = sum(r["cpu_s"] for r in reports)
    executor_cpu_s = max(r["executor_cpu_s"] for r in reports)
    return {
        "row": case.label,
        "case": dataclasses.asdict(case),
        "vehicles": case.vehicles,
        "sim_s": sim_s,
        "published": published,
        "consumed": consumed,
        "dropped": published - consumed,
        "estimates": len(got),
        "expected_estimates": expected,
        "filter_updates": sum(sum(r["updates"]) for r in reports),
        # What the nodes published on the timed topic (``estimates``: what reached the collector).
        "node_estimates": sum(p.get(estimate.key, 0) for r in reports for p in r["published"]),
        "foreign_frames": foreign,
        "latency_median_ms": float(np.median(latencies_ms)) if latencies_ms else math.nan,
        "latency_p99_ms": float(np.percentile(latencies_ms, 99)) if latencies_ms else math.nan,
        "cpu_per_vehicle_per_sim_s": cpu_s / case.vehicles / sim_s,
        # The busiest host's executor thread alone, per simulated second: the part that cannot
        # spread over cores (the rest is the middleware's own threads).
        "executor_cpu_per_sim_s": executor_cpu_s / sim_s,
        "offered_x_real_time": sim_s / (t_published - t_start),
        # The player's own CPU while publishing (with its collector thread): it must not be the bottleneck.
        "player_cpu_per_sim_s": player_cpu_s / sim_s,
        "x_real_time": sim_s / wall_s,
        # Flow control only: the times the player went on after FLOW_STALL_S without an estimate.
        "flow_stalls": flow_stalls,
        "flow_stall_s": FLOW_STALL_S,
    }


@cli_main("make bench-load")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m terrain_analysis.tools.bench_load",
        description="Many vehicles and load: latency, dropped messages and CPU per vehicle (issue 7 item 5).",
    )
    parser.add_argument("--quick", action="store_true", help="smoke run: short drives, N = 1, 2, 3")
    parser.add_argument("--out", metavar="FILE", help="write the Markdown report here")
    parser.add_argument("--json", metavar="FILE", help="also write every figure as JSON")
    parser.add_argument("--only", metavar="PREFIX", help="run only the rows whose label starts with PREFIX")
    parser.add_argument("--bags", metavar="DIR", default=str(BAGS_DIR), help="directory of the recorded bags")
    parser.add_argument(
        "--profile",
        metavar="DIR",
        help="profile each row's executor thread(s) with cProfile into DIR/<row>.pstats "
        "(read with python -m pstats); the profiler slows the callbacks, so the row's figures are not comparable",
    )
    parser.add_argument("--host", metavar="SPEC", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.host:
        return host_main(json.loads(args.host))

    profile_dir = Path(args.profile) if args.profile else None
    if profile_dir is not None:
        profile_dir.mkdir(parents=True, exist_ok=True)
    selected = [c for c in cases(args.quick) if not args.only or c.label.startswith(args.only)]
    rows = []
    for case in selected:
        row = run_case(case, Path(args.bags), profile_dir)
        rows.append(row)
        print(format_table([row]).splitlines()[1], flush=True)
    ceilings = {
        v: offline_ceiling(Path(args.bags), 1 if args.quick else 3, v)
        for v in dict.fromkeys(["quarter_car", *(c.vehicle for c in selected)])
    }
    machine = machine_info()
    print()
    print(f"machine: {machine['cpu_count']} CPUs, load average {machine['load_avg_1min']}, {machine['platform']}")
    print(format_table(rows))
    for line in verdicts(rows, machine["cpu_count"]):
        print(line)
    for ceiling in ceilings.values():
        print(ceiling_line(ceiling))
    command = "python -m terrain_analysis.tools.bench_load" + (" --quick" if args.quick else "")
    if args.out:
        command += f" --out {args.out}"
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        page = Path(args.out)
        text = format_markdown(rows, ceilings, machine, command, args.quick)
        page.write_text(keep_sections(page.read_text(), text) if page.exists() else text)  # others' sections stay
    if args.json:
        Path(args.json).write_text(
            json.dumps({"machine": machine, "rows": rows, "offline_ceiling": ceilings}, indent=2) + "\n"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
