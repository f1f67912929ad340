"""Lockstep driving of a live estimator node for the robustness tests (issue 7).

Extends :class:`integration.replay.LockstepReplay` with what those tests need:
``/clock`` (a sim-time node follows it, as under ``ros2 bag play --clock``),
a spy on what reaches the adapter, the estimates published, and the
``/diagnostics`` the node publishes.
"""

from __future__ import annotations

import array
import copy
import functools
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from integration.replay import LockstepReplay
from rosgraph_msgs.msg import Clock

from terrain_estimation.bag import read_bag
from terrain_estimation.nodes import make_estimator_node
from terrain_estimation.ros.framework import EstimatorNode
from terrain_estimation.ros.qos import CLOCK_QOS
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_sec
from terrain_estimation.tools.estimate import numeric_fields

BAGS = Path(__file__).resolve().parent.parent / "bags"
BAG = {
    "quarter_car": "quarter_car_graneville_iso_d_10ms",
    "lrv": "lrv_regolith_iso_g_2ms",
    "skid_steer": "skid_steer_s_shape",
    "rover": "rover_terrain_1",
}


@dataclass
class Item:
    """One message to publish (the fields of a BagMessage that LockstepReplay reads)."""

    topic: str
    msg: Any
    drives_clock: bool = True  # a sim-time replay's /clock follows this message's stamp

    @property
    def t(self) -> float:
        return stamp_to_sec(self.msg.header.stamp)


@functools.cache
def _bag_inputs(vehicle: str, seconds: float) -> tuple[tuple[str, Any], ...]:
    ns = f"/{vehicle}"
    inputs = {
        "quarter_car": ("imu/body", "imu/wheel", "terrain/profile", "joint_states"),
        "lrv": ("imu/body", "terrain/profile", "joint_states"),
        "skid_steer": ("imu", "joint_states"),
        "rover": ("imu", "joint_states", "velocimeter", "wheel/front/load", "wheel/middle/load", "wheel/rear/load"),
    }[vehicle]
    topics = [f"{ns}/{t}" for t in inputs]
    out = []
    for m in read_bag(BAGS / BAG[vehicle], topics):
        if stamp_to_sec(m.msg.header.stamp) > seconds:
            break
        out.append((m.topic, m.msg))
    return tuple(out)


def bag_items(vehicle: str, seconds: float) -> list[Item]:
    """Copies of the input messages of ``vehicle``'s bag stamped up to ``seconds``, in recorded order."""
    return [Item(topic, copy.deepcopy(msg)) for topic, msg in _bag_inputs(vehicle, seconds)]


def shifted(items: Iterable[Item], dt: float) -> list[Item]:
    """Copies of ``items`` stamped ``dt`` later."""
    out = []
    for item in items:
        msg = copy.deepcopy(item.msg)
        msg.header.stamp = sec_to_stamp(item.t + dt)
        out.append(Item(item.topic, msg))
    return out


class Harness(LockstepReplay):
    """A live estimator node, a player that publishes its inputs (and ``/clock``) one at a time, and spies."""

    def __init__(
        self,
        vehicle: str,
        context: Any,
        overrides: Mapping[str, object] | None = None,
        *,
        sim_time: bool = False,
        node: EstimatorNode | None = None,
    ) -> None:
        # No periodic diagnostics: each test asks for one report (a timer's would consume "rejected since the last").
        values: dict[str, object] = {"diagnostics.period": 60.0, **(overrides or {})}
        if sim_time:
            values["use_sim_time"] = True
        if node is None:
            node = make_estimator_node(vehicle, context=context, overrides=values)
        super().__init__(node, context)
        self.ns = node.get_namespace()
        self.sim_time = sim_time
        self.clock_publisher = self.player.create_publisher(Clock, "/clock", CLOCK_QOS)
        self.diagnostics: list[DiagnosticArray] = []
        self.player.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 50)
        self.received: list[tuple[str, Any]] = []  # what reached the adapter
        inner = node.adapter.handle

        def spy(key: str, msg: Any) -> list[tuple[str, Any]]:
            self.received.append((key, msg))
            return inner(key, msg)

        node.adapter.handle = spy  # type: ignore[method-assign]
        self.clock = 0.0
        if sim_time:
            for _ in range(400):
                if self.clock_publisher.get_subscription_count() > 0:
                    break
                self.executor.spin_once(timeout_sec=0.01)

    def set_clock(self, t: float) -> None:
        """Publish ``/clock`` = ``t`` and spin until the node's clock reads it."""
        target = round(t * 1e9)
        for _attempt in range(20):
            self.clock_publisher.publish(Clock(clock=sec_to_stamp(t)))
            for _ in range(100):
                if self.node.get_clock().now().nanoseconds == target:
                    self.clock = t
                    return
                self.executor.spin_once(timeout_sec=0.005)
        raise AssertionError(f"the node's clock did not reach {t} s")

    def feed(self, items: Iterable[Item], clock_step: float = 0.01) -> None:
        """Publish ``items`` in lockstep; with sim time, ``/clock`` follows their stamps every ``clock_step``."""
        for item in items:
            if self.sim_time and item.drives_clock and item.t >= self.clock + clock_step:
                self.set_clock(item.t)
            self.play([item])

    def estimates(self, topic: str) -> list[Any]:
        """Everything published on ``topic`` (relative to the namespace) so far (after a short spin)."""
        for _ in range(5):
            self.executor.spin_once(timeout_sec=0.005)
        return list(self.outputs.get(f"{self.ns}/{topic}", []))

    def diagnostic(self) -> tuple[bytes, str, dict[str, str]]:
        """Publish the node's diagnostics and return (level, message, values) as received on /diagnostics."""
        before = len(self.diagnostics)
        self.node.publish_diagnostics()
        for _ in range(400):
            if len(self.diagnostics) > before:
                break
            self.executor.spin_once(timeout_sec=0.01)
        else:
            raise AssertionError("no /diagnostics received")
        status = self.diagnostics[-1].status[0]
        assert isinstance(status.level, bytes)
        return status.level, status.message, {kv.key: kv.value for kv in status.values}

    def received_stamps(self, key: str) -> list[float]:
        return [stamp_to_sec(m.header.stamp) for k, m in self.received if k == key]

    def close(self) -> None:
        super().close()
        self.node.destroy_node()


def all_finite(msg: Any) -> bool:
    return all(math.isfinite(v) for v in numeric_fields(msg).values())


def float_paths(msg: Any, prefix: str = "") -> list[str]:
    """Every float field of ``msg`` as a dotted path, arrays by index (``a.b[3]``), nested message lists included."""
    paths = []
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        path = prefix + name
        if isinstance(value, float):
            paths.append(path)
        elif hasattr(value, "get_fields_and_field_types"):
            paths += float_paths(value, path + ".")
        elif isinstance(value, (np.ndarray, array.array)) and np.asarray(value).dtype.kind == "f":
            paths += [f"{path}[{i}]" for i in range(len(value))]
        elif isinstance(value, (list, tuple)):
            for i, item in enumerate(value):
                if isinstance(item, float):
                    paths.append(f"{path}[{i}]")
                elif hasattr(item, "get_fields_and_field_types"):
                    paths += float_paths(item, f"{path}[{i}].")
    return paths
