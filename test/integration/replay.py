"""Lockstep replay of a bag into a live node, in-process, without launch files.

A burst into a sensor-data (best effort) subscription drops messages, so the
replay publishes one message and then spins until the node has consumed it
before publishing the next. Outputs are collected by a reliable subscriber.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from terrain_estimation.bag import BagMessage
from terrain_estimation.ros.framework import EstimatorNode
from terrain_estimation.ros.qos import qos_for
from terrain_estimation.tools.estimate import topic_name


class LockstepReplay:
    """Publishes bag messages into ``node``'s inputs and collects its outputs."""

    def __init__(self, node: EstimatorNode, context: Any) -> None:
        self.node = node
        ns = node.get_namespace()
        self.player = Node("bag_player", context=context)
        self.publishers = {
            topic_name(ns, s.topic): self.player.create_publisher(s.msg_type, topic_name(ns, s.topic), qos_for(s.kind))
            for s in node.adapter.inputs
        }
        self.outputs: dict[str, list[Any]] = {}
        for s in node.adapter.outputs:
            topic = topic_name(ns, s.topic)
            self.player.create_subscription(
                s.msg_type, topic, lambda m, t=topic: self.outputs.setdefault(t, []).append(m), qos_for(s.kind)
            )
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(node)
        self.executor.add_node(self.player)
        self._wait_for_discovery()

    def _wait_for_discovery(self, timeout_steps: int = 400) -> None:
        for _ in range(timeout_steps):
            if all(p.get_subscription_count() > 0 for p in self.publishers.values()):
                return
            self.executor.spin_once(timeout_sec=0.01)
        raise AssertionError("the estimator's subscriptions were not discovered")

    def play(self, messages: Iterable[BagMessage], max_spins: int = 2000) -> int:
        """Publish each input message and spin until the node consumed it."""
        count = 0
        for item in messages:
            publisher = self.publishers.get(item.topic)
            if publisher is None:
                continue
            before = self.node.messages_handled
            publisher.publish(item.msg)
            for _ in range(max_spins):
                self.executor.spin_once(timeout_sec=0.01)
                if self.node.messages_handled > before:
                    break
            else:
                raise AssertionError(f"message {count} on {item.topic} was not consumed")
            count += 1
        return count

    def collect(self, topic: str, expected: int, max_spins: int = 2000) -> list[Any]:
        """Spin until ``expected`` outputs arrived on ``topic`` (reliable QoS)."""
        for _ in range(max_spins):
            if len(self.outputs.get(topic, [])) >= expected:
                break
            self.executor.spin_once(timeout_sec=0.01)
        return self.outputs.get(topic, [])

    def close(self) -> None:
        self.executor.shutdown()
        self.player.destroy_node()
