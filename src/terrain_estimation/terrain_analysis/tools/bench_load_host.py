"""The estimator host of ``bench_load``: the process that runs the estimator nodes, and its driver.

Part of :mod:`terrain_analysis.tools.bench_load` (its docstring describes the
rows and executors). :func:`host_main` runs in a subprocess started by
:class:`Host` (``python -m terrain_analysis.tools.bench_load --host SPEC``);
the player talks to it over stdin/stdout.
"""

from __future__ import annotations

import cProfile
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any

__all__ = ["Host", "empty_callback_node", "host_main", "namespace_of", "sensor_qos"]


def namespace_of(k: int) -> str:
    return f"/v{k}"


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


class Host:
    """The host subprocess, driven over its stdin/stdout."""

    def __init__(self, spec: dict[str, Any]) -> None:
        """Start ``host_main(spec)`` (JSON-serialisable: the keys :func:`host_main` reads) and wait until ready."""
        # The nodes' log (silent-input warnings once the player stops, …): shown only if the host fails.
        self.log = tempfile.TemporaryFile(mode="w+")
        env = dict(os.environ)
        env.setdefault("OPENBLAS_NUM_THREADS", "1")
        env.setdefault("OMP_NUM_THREADS", "1")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "terrain_analysis.tools.bench_load", "--host", json.dumps(spec)],
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
