"""Node diagnostics of a filter fault (issue 7): ERROR while the filter has diverged and is
re-converging from the last good estimate, OK again once it is consistent.

The adapter is a test double around a scalar random-walk UKF under a
:class:`~terrain_estimation.filters.faults.DivergenceMonitor`; it puts the
monitor's fault into ``AdapterHealth.errors`` (the framework hook) and starts
a new NIS window for the node's own consistency check on a recovery.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped

from terrain_estimation.filters import DivergenceMonitor, UnscentedKalmanFilter, guarded_step
from terrain_estimation.ros.framework import AdapterHealth, EstimatorNode, TopicSpec
from terrain_estimation.ros.time import stamp_to_sec


@dataclass(frozen=True)
class RandomWalk:
    state_dim: int = 1
    measurement_dim: int = 1

    def f(self, x: Any, u: Any, dt: float) -> Any:
        return x

    def h(self, x: Any, u: Any) -> Any:
        return x

    def process_noise_sqrt(self, x: Any, u: Any, dt: float) -> Any:
        return np.array([[0.05]])

    def measurement_noise_sqrt(self) -> Any:
        return np.array([[0.5]])


class GuardedAdapter:
    def __init__(self, values, namespace):
        self.inputs = [TopicSpec("value", "value", PointStamped, "sensor")]
        self.outputs = [TopicSpec("level", "level", PointStamped, "estimate")]
        self.health = AdapterHealth(nis_dof=1)
        self.filt = UnscentedKalmanFilter()
        self.model = RandomWalk()
        self.reset()

    def reset(self):
        self.monitor = DivergenceMonitor()
        self.state = self.filt.initial_state(np.zeros(1), np.eye(1))
        self.monitor.start(self.state)

    def handle(self, key, msg):
        self.state, info, check = guarded_step(
            self.filt, self.monitor, self.state, self.model, None, 0.1, np.array([msg.point.z])
        )
        h = self.health
        h.updates += 1
        h.last_update_time = stamp_to_sec(msg.header.stamp)
        if check.diverged:
            h.nis.clear()  # a re-initialised filter starts a new consistency window
        elif info is not None and info.accepted:
            h.nis.append(info.nis)
        fault = self.monitor.fault
        h.errors = [f"filter diverged, re-initialised from the last good estimate: {fault}"] if fault else []
        out = PointStamped(header=msg.header)
        out.point.z = float(self.state.x[0])
        return [("level", out)]


def test_divergence_turns_the_diagnostic_error_then_ok(rclpy_context):
    node = EstimatorNode("guarded", (), GuardedAdapter, namespace="/veh", context=rclpy_context)
    handle = node._callback_for("value", lambda msg: msg)  # fed messages, not their bytes
    rng = np.random.default_rng(3)
    truth = 0.0
    levels: list[bytes] = []
    messages: list[str] = []
    try:
        for k in range(200):
            truth += 0.05 * rng.standard_normal()
            msg = PointStamped()
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.point.z = truth + 0.5 * rng.standard_normal() + (1e4 if k == 100 else 0.0)
            handle(msg)
            status = node.diagnostic_status()
            levels.append(status.level)
            messages.append(status.message)
        assert set(levels[30:100]) == {DiagnosticStatus.OK}
        first = levels.index(DiagnosticStatus.ERROR)
        last = len(levels) - 1 - levels[::-1].index(DiagnosticStatus.ERROR)
        assert 100 < first <= 120
        assert set(levels[first : last + 1]) == {DiagnosticStatus.ERROR}
        assert "filter diverged" in messages[first] and "chi-square band" in messages[first]
        assert levels[-1] == DiagnosticStatus.OK and last < 199
        assert abs(node.adapter.state.x[0] - truth) < 2.0
    finally:
        node.destroy_node()
