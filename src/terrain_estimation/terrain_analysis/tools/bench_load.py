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
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import functools
import json
import math
import os
import re
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.reporting import keep_sections
from terrain_estimation.cli import cli_main

__all__ = [
    "Case",
    "EXECUTORS",
    "FLOW_WINDOW_S",
    "cases",
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


def namespace_of(k: int) -> str:
    return f"/v{k}"


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


# ---------------------------------------------------------------------------
# Host: the estimator nodes' process
# ---------------------------------------------------------------------------


def sensor_qos(depth: int) -> Any:
    """The project's sensor QoS with another depth (0: unchanged)."""
    from rclpy.qos import QoSProfile

    from terrain_estimation.ros.qos import SENSOR_QOS

    if depth <= 0:
        return SENSOR_QOS
    return QoSProfile(
        history=SENSOR_QOS.history,
        depth=depth,
        reliability=SENSOR_QOS.reliability,
        durability=SENSOR_QOS.durability,
    )


def host_main(spec: dict[str, Any]) -> int:
    """Run ``spec["vehicles"]`` estimator nodes of ``spec["vehicle"]`` (quarter car by default) under
    ``/v0``… in one executor.

    Protocol on stdin/stdout: prints ``ready`` once the nodes exist; ``start`` (a line on
    stdin) starts the CPU count; ``stop`` ends the run (after the messages still queued are
    taken) and prints one JSON line with the CPU seconds and the messages each node consumed.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from terrain_estimation.nodes import make_estimator_node

    if spec.get("sensor_depth"):
        from terrain_estimation.ros import framework

        bench_depth = int(spec["sensor_depth"])
        default_qos_for = framework.qos_for

        def patched_qos_for(kind: str, depth: int = 0) -> Any:  # the bench's depth, not the node's
            return sensor_qos(bench_depth) if kind == "sensor" else default_qos_for(kind)

        framework.qos_for = patched_qos_for
    context = Context()
    rclpy.init(context=context)
    first = int(spec.get("first", 0))
    vehicle = spec.get("vehicle", "quarter_car")
    executor_kind = spec["executor"]
    nodes: list[Any] = [
        empty_callback_node(vehicle, namespace_of(k), context)
        if spec.get("empty_callbacks")
        else make_estimator_node(
            vehicle,
            namespace=namespace_of(k),
            context=context,
            overrides=({} if executor_kind == "events+take" else {"input.take_queued": 0})
            | ({} if spec.get("fast_decode", True) else {"input.fast_decode": False}),
        )
        for k in range(first, first + spec["vehicles"])
    ]
    if spec.get("bare_node"):  # the framework alone: checks and adapter that do nothing
        for node in nodes:
            node.guard.check = lambda key, msg, now: None
            node.adapter.handle = lambda key, msg: []
    executor: Any
    if executor_kind.startswith("events"):
        from rclpy.experimental import EventsExecutor

        executor = EventsExecutor(context=context)
    else:
        executor = SingleThreadedExecutor(context=context)
    for node in nodes:
        executor.add_node(node)

    stop = threading.Event()
    cpu0 = [time.process_time()]
    started = threading.Event()
    # The executor thread's own CPU (the callbacks, rclpy's take, the decoding): read in
    # that thread, from the first spin after "start".
    thread0: list[float | None] = [None]

    def read_commands() -> None:
        for line in sys.stdin:
            if line.strip() == "start":
                cpu0[0] = time.process_time()
                started.set()
            elif line.strip() == "stop":
                break
        stop.set()

    threading.Thread(target=read_commands, daemon=True).start()
    profiler = cProfile.Profile() if spec.get("profile") else None
    print("ready", flush=True)
    while not stop.is_set():
        if thread0[0] is None and started.is_set():
            thread0[0] = time.thread_time()
            if profiler is not None:
                profiler.enable()
        executor.spin_once(timeout_sec=0.05)
    if profiler is not None:
        profiler.disable()
        profiler.dump_stats(spec["profile"])
    # What is still queued was not lost: take it before counting (until 0.3 s pass without a message).
    handled = -1
    quiet_since = time.monotonic()
    while time.monotonic() - quiet_since < 0.3:
        executor.spin_once(timeout_sec=0.05)
        now_handled = sum(node.messages_handled for node in nodes)
        if now_handled != handled:
            handled = now_handled
            quiet_since = time.monotonic()
    cpu = time.process_time() - cpu0[0]
    report = {
        "cpu_s": cpu,
        "executor_cpu_s": time.thread_time() - (thread0[0] if thread0[0] is not None else 0.0),
        "handled": [node.messages_handled for node in nodes],
        "updates": [node.adapter.health.updates if hasattr(node, "adapter") else 0 for node in nodes],
        "published": [getattr(node, "published", {}) for node in nodes],
    }
    print(json.dumps(report), flush=True)
    executor.shutdown()
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown(context=context)
    return 0


def empty_callback_node(vehicle: str, namespace: str, context: Any) -> Any:
    """A node with the subscriptions (and estimate publishers) of ``vehicle``'s estimator node under
    ``namespace`` whose callbacks only decode the bytes as the node does (:mod:`~terrain_estimation.ros.cdr`)
    and count (``messages_handled``): what rclpy, the middleware and the decoding cost per message
    before any estimator code runs. The estimate publishers never publish; they let the collector's
    discovery finish."""
    from rclpy.node import Node

    from terrain_estimation.ros import framework
    from terrain_estimation.ros.cdr import decoder_for
    from terrain_estimation.vehicles import estimator_parameters, get_vehicle

    entry = get_vehicle(vehicle)
    values = estimator_parameters(entry)
    adapter = entry.make_adapter(values, namespace)
    node = Node("empty_callbacks", namespace=namespace, context=context)
    node.messages_handled = 0  # type: ignore[attr-defined]

    def counter(decode: Any) -> Any:
        def count(data: bytes) -> None:
            decode(data)
            node.messages_handled += 1  # type: ignore[attr-defined]

        return count

    # framework.qos_for and the node's depth parameter, as EstimatorNode subscribes (and as the
    # bench's deep-queue rows patch it).
    depth = int(values["qos.sensor_depth"])
    qos_for = framework.qos_for
    for spec in adapter.inputs:
        decode = decoder_for(spec.msg_type)
        assert decode is not None, spec.msg_type  # every input type has one (test_cdr)
        node.create_subscription(spec.msg_type, spec.topic, counter(decode), qos_for(spec.kind, depth), raw=True)
    for spec in adapter.outputs:
        node.create_publisher(spec.msg_type, spec.topic, qos_for(spec.kind))
    return node


def _profile_path(profile_dir: Path | None, label: str, first: int, processes: int) -> str:
    if profile_dir is None:
        return ""
    name = re.sub(r"[^A-Za-z0-9_.+-]+", "_", label).strip("_")
    return str(profile_dir / (name + (f".{first}" if processes > 1 else "") + ".pstats"))


class _Host:
    """The host subprocess, driven over its stdin/stdout."""

    def __init__(
        self,
        vehicles: int,
        executor: str,
        sensor_depth: int = 0,
        first: int = 0,
        vehicle: str = "quarter_car",
        empty_callbacks: bool = False,
        profile: str = "",
        fast_decode: bool = True,
        bare_node: bool = False,
    ) -> None:
        # The nodes' log (silent-input warnings once the player stops, …): shown only if the host fails.
        self.log = tempfile.TemporaryFile(mode="w+")
        env = dict(os.environ)
        env.setdefault("OPENBLAS_NUM_THREADS", "1")
        env.setdefault("OMP_NUM_THREADS", "1")
        spec = json.dumps(
            {
                "vehicles": vehicles,
                "executor": executor,
                "sensor_depth": sensor_depth,
                "first": first,
                "vehicle": vehicle,
                "empty_callbacks": empty_callbacks,
                "profile": profile,
                "fast_decode": fast_decode,
                "bare_node": bare_node,
            }
        )
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "terrain_analysis.tools.bench_load", "--host", spec],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.log,
            text=True,
            env=env,
        )
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if line.strip() != "ready":
            self.proc.kill()
            raise RuntimeError(f"estimator host did not start (said {line!r}):\n{self.log_tail()}")

    def log_tail(self, lines: int = 20) -> str:
        self.log.seek(0)
        return "".join(self.log.readlines()[-lines:])

    def send(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def finish(self) -> dict[str, Any]:
        self.send("stop")
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        self.proc.wait(timeout=30)
        if not line.strip():
            raise RuntimeError(f"estimator host ended without a report:\n{self.log_tail()}")
        return dict(json.loads(line))

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


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
        _Host(
            min(per_host, case.vehicles - first),
            case.executor,
            case.sensor_depth,
            first,
            case.vehicle,
            case.empty_callbacks,
            _profile_path(profile_dir, case.label, first, case.processes),
            case.fast_decode,
            case.bare_node,
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
                while (stamp - last_estimate[k]) * 1e-9 > flow_window:
                    if time.monotonic() - last_arrival[0] > 10.0:
                        raise RuntimeError("flow-controlled replay: no estimate for 10 s")
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
    }


# ---------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------

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
    import platform

    try:
        load: float | None = os.getloadavg()[0]
    except (AttributeError, OSError):
        load = None
    return {
        "cpu_count": os.cpu_count(),
        "load_avg_1min": load,
        "platform": f"{platform.system()} {platform.machine()}",
        "python": platform.python_version(),
        "rmw": os.environ.get("RMW_IMPLEMENTATION", "default"),
        "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "unset"),
    }


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


def _verdicts(rows: Sequence[dict[str, Any]], cpus: int | None = None) -> list[str]:
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
            )
    return out


def offline_ceiling(bags_dir: Path, repeats: int, vehicle: str = "quarter_car") -> dict[str, Any]:
    """The vehicle's bag (:data:`BAG_OF`) through the adapter and filter without ROS
    (``terrain-estimate``'s runner): the speed no executor can beat in one process."""
    from terrain_analysis.tools.bench import bench_bag

    row = bench_bag(bags_dir / BAG_OF[vehicle], vehicle, repeats)
    row["cpu_per_sim_s"] = 1.0 / row["x_real_time"]
    return row


def _ceiling_line(c: dict[str, Any]) -> str:
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
        *_verdicts(rows, machine["cpu_count"]),
        "",
        *("- " + _ceiling_line(c) for c in ceilings.values()),
        "",
        "## QoS and queue choices",
        "",
        QOS_TEXT,
        f"  Estimates in another vehicle's frame, over every row: {sum(r['foreign_frames'] for r in rows)}.",
        "",
    ]
    return "\n".join(lines)


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
    for line in _verdicts(rows, machine["cpu_count"]):
        print(line)
    for ceiling in ceilings.values():
        print(_ceiling_line(ceiling))
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
