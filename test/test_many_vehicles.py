"""Many vehicles, no cross-talk (issue 7 item 5).

Ten estimator nodes (quarter cars and LRVs alternating) in one process under
``/v0`` … ``/v9``, and three in separate processes (the project's executable
with ``--ros-args -r __ns:=/vK``), each fed its own input: its own soil, road
and noise seeds, and its own stretch of time (vehicle k's stamps start at
``10 (k + 1)`` s). Every estimate must arrive on its vehicle's own topic, carry
its vehicle's frame and a stamp of its vehicle's own input; in-process, every
node must consume exactly the messages published to its vehicle.

The namespaces are the protection: with the vehicles sharing one namespace
(``test_shared_namespace_is_detected_as_cross_talk``) the same checks report
cross-talk, so a node that ignored its namespace fails the fleet tests.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import pytest

pytest.importorskip("vehicle_sim")

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402

from terrain_estimation.nodes import make_estimator_node  # noqa: E402
from terrain_estimation.ros.qos import ESTIMATE_QOS, SENSOR_QOS  # noqa: E402
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_ns  # noqa: E402
from terrain_msgs.msg import SoilStiffness  # noqa: E402
from vehicle_sim.ros.registry import get_simulator, simulator_parameters  # noqa: E402

SOILS = ("graneville_loam", "lunar_regolith", "lete_sand", "upland_sandy_loam", "rubicon_sandy_loam")
DURATION = 0.2  # simulated seconds per vehicle: 20 filter steps


def vehicle_kind(k: int) -> str:
    return "quarter_car" if k % 2 == 0 else "lrv"


def time_offset(k: int) -> float:
    """Vehicle k's stamps start here: its estimates can only carry stamps of this stretch."""
    return 10.0 * (k + 1)


@dataclass
class VehicleInput:
    """One vehicle's sensor messages, in publication order, framed under its namespace."""

    k: int
    namespace: str
    messages: list[tuple[str, Any]]  # (relative topic, msg)
    imu_stamps: set[int] = field(default_factory=set)


def vehicle_input(k: int, frame_namespace: str, duration: float = DURATION) -> VehicleInput:
    kind = vehicle_kind(k)
    entry = get_simulator(kind)
    values = simulator_parameters(
        entry,
        overrides={"scenario.soils": [SOILS[k % len(SOILS)]], "scenario.road_seed": 40 + k, "seed": 60 + k},
    )
    adapter = entry.make_adapter(values, frame_namespace)
    topics = {o.key: o.topic for o in adapter.outputs if o.kind == "sensor"}
    out = VehicleInput(k, f"/v{k}", [])
    t = 0.0
    while t < duration - 1e-9:
        t, messages = adapter.step()
        for key, msg in messages:
            if key not in topics:
                continue
            msg.header.stamp = sec_to_stamp(stamp_to_ns(msg.header.stamp) * 1e-9 + time_offset(k))
            out.messages.append((topics[key], msg))
            if key == "imu_body":
                out.imu_stamps.add(stamp_to_ns(msg.header.stamp))
    return out


def cross_talk(inputs: list[VehicleInput], estimates: dict[int, list[Any]]) -> list[str]:
    """Every way vehicle k's estimates are not its own (empty: no cross-talk)."""
    problems = []
    for vi in inputs:
        got = estimates.get(vi.k, [])
        if len(got) < 10:
            problems.append(f"/v{vi.k}: only {len(got)} estimates")
        for msg in got:
            stamp = stamp_to_ns(msg.header.stamp)
            if msg.header.frame_id != f"v{vi.k}/base_link":
                problems.append(f"/v{vi.k}: estimate in frame {msg.header.frame_id!r}")
            if stamp not in vi.imu_stamps:
                owner = [o.k for o in inputs if stamp in o.imu_stamps]
                problems.append(f"/v{vi.k}: estimate stamped {stamp * 1e-9:.3f} s, an input of {owner or 'nobody'}")
    return problems


def run_fleet_in_process(context: Any, n: int, shared_namespace: str | None = None) -> tuple[list[str], list[str]]:
    """Build n nodes (under /vK, or all under ``shared_namespace``), feed each its own input in lockstep,
    and return (cross-talk problems, consumption problems)."""
    inputs = [vehicle_input(k, shared_namespace or f"/v{k}") for k in range(n)]
    nodes = [
        make_estimator_node(vehicle_kind(k), namespace=shared_namespace or f"/v{k}", context=context) for k in range(n)
    ]
    player = Node("fleet_player", context=context)
    executor = SingleThreadedExecutor(context=context)
    try:
        publishers = {}
        estimates: dict[int, list[Any]] = {}
        for vi in inputs:
            ns = shared_namespace or vi.namespace
            for topic in {t for t, _ in vi.messages}:
                msg_type = type(next(m for t, m in vi.messages if t == topic))
                publishers[(vi.k, topic)] = player.create_publisher(msg_type, f"{ns}/{topic}", SENSOR_QOS)
            player.create_subscription(
                SoilStiffness,
                f"/v{vi.k}/soil_stiffness",
                lambda m, k=vi.k: estimates.setdefault(k, []).append(m),
                ESTIMATE_QOS,
            )
        for node in nodes:
            executor.add_node(node)
        executor.add_node(player)
        for _ in range(500):
            if all(p.get_subscription_count() > 0 for p in publishers.values()):
                break
            executor.spin_once(timeout_sec=0.01)
        else:
            raise AssertionError("the estimators' subscriptions were not discovered")

        # Lockstep, vehicles interleaved: publish one message, spin until its node consumed it.
        consumption = []
        cursor = [0] * n
        while any(cursor[k] < len(inputs[k].messages) for k in range(n)):
            for k in range(n):
                if cursor[k] >= len(inputs[k].messages):
                    continue
                topic, msg = inputs[k].messages[cursor[k]]
                cursor[k] += 1
                before = nodes[k].messages_handled
                publishers[(k, topic)].publish(msg)
                for _ in range(2000):
                    executor.spin_once(timeout_sec=0.01)
                    if nodes[k].messages_handled > before:
                        break
                else:
                    raise AssertionError(f"/v{k}: message on {topic} was not consumed")
        expected_estimates = {vi.k: len(vi.imu_stamps) - 1 for vi in inputs}
        for _ in range(500):
            if all(len(estimates.get(k, [])) >= e for k, e in expected_estimates.items()):
                break
            executor.spin_once(timeout_sec=0.01)
        for _ in range(20):  # anything still in flight (cross-talk) lands too
            executor.spin_once(timeout_sec=0.01)
        for vi, node in zip(inputs, nodes, strict=True):
            if node.messages_handled != len(vi.messages):
                consumption.append(
                    f"/v{vi.k}: consumed {node.messages_handled} messages, {len(vi.messages)} were published to it"
                )
        return cross_talk(inputs, estimates), consumption
    finally:
        executor.shutdown()
        player.destroy_node()
        for node in nodes:
            node.destroy_node()


def test_ten_vehicles_in_one_process_keep_to_their_namespaces(rclpy_context):
    problems, consumption = run_fleet_in_process(rclpy_context, 10)
    assert problems == []
    assert consumption == []


def test_shared_namespace_is_detected_as_cross_talk(rclpy_context):
    """The negative control: without a namespace per vehicle the fleet checks fail."""
    problems, consumption = run_fleet_in_process(rclpy_context, 3, shared_namespace="/fleet")
    assert problems, "nodes sharing one namespace must show cross-talk"
    assert consumption, "nodes sharing one namespace consume each other's input"


def test_vehicles_in_separate_processes_keep_to_their_namespaces(rclpy_context):
    n = 3
    inputs = [vehicle_input(k, f"/v{k}", duration=0.3) for k in range(n)]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "terrain_estimation.nodes",
                "--vehicle",
                vehicle_kind(k),
                "--ros-args",
                "-r",
                f"__ns:=/v{k}",
            ],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        for k in range(n)
    ]
    player = Node("fleet_player", context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(player)
    estimates: dict[int, list[Any]] = {}
    try:
        publishers = {}
        subscriptions = []
        for vi in inputs:
            for topic in {t for t, _ in vi.messages}:
                msg_type = type(next(m for t, m in vi.messages if t == topic))
                publishers[(vi.k, topic)] = player.create_publisher(msg_type, f"/v{vi.k}/{topic}", SENSOR_QOS)
            subscriptions.append(
                player.create_subscription(
                    SoilStiffness,
                    f"/v{vi.k}/soil_stiffness",
                    lambda m, k=vi.k: estimates.setdefault(k, []).append(m),
                    ESTIMATE_QOS,
                )
            )
        deadline = time.monotonic() + 60.0
        while not (
            all(p.get_subscription_count() > 0 for p in publishers.values())
            and all(s.get_publisher_count() > 0 for s in subscriptions)
        ):
            assert all(p.poll() is None for p in procs), "an estimator process exited"
            assert time.monotonic() < deadline, "the estimator processes were not discovered within 60 s"
            executor.spin_once(timeout_sec=0.05)
        executor.spin_once(timeout_sec=0.2)

        # All vehicles at once, at half real time (the node's sensor queues absorb the rest).
        merged = sorted(
            (stamp_to_ns(msg.header.stamp) - round(time_offset(vi.k) * 1e9), vi.k, i, topic, msg)
            for vi in inputs
            for i, (topic, msg) in enumerate(vi.messages)
        )
        start = time.perf_counter()
        for rel_ns, k, _, topic, msg in merged:
            wait = start + 2.0 * rel_ns * 1e-9 - time.perf_counter()
            if wait > 0:
                executor.spin_once(timeout_sec=wait)
            publishers[(k, topic)].publish(msg)
        expected = {vi.k: len(vi.imu_stamps) - 1 for vi in inputs}
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and not all(len(estimates.get(k, [])) >= e for k, e in expected.items()):
            executor.spin_once(timeout_sec=0.05)
        for _ in range(10):
            executor.spin_once(timeout_sec=0.02)
    finally:
        executor.shutdown()
        player.destroy_node()
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    assert cross_talk(inputs, estimates) == []
