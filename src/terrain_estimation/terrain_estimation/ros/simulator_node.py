"""The simulator node: a :class:`~terrain_estimation.ros.adapters.SimulatorAdapter`'s messages and ``/clock``.

The vehicles' plants and their adapters live in the simulator package
(``vehicle_sim.ros``); the node that runs them is here, beside the estimator
node, with the same parameter handling (:class:`~terrain_estimation.ros.adapter_node.AdapterNode`).
"""

from __future__ import annotations

import rclpy.clock
from rosgraph_msgs.msg import Clock

from terrain_estimation.params import ParamSpec
from terrain_estimation.ros.adapter_node import AdapterNode
from terrain_estimation.ros.adapters import SimulatorAdapter
from terrain_estimation.ros.qos import CLOCK_QOS
from terrain_estimation.ros.time import sec_to_stamp

__all__ = ["SimulatorNode"]


class SimulatorNode(AdapterNode[SimulatorAdapter]):
    """Publishes a :class:`SimulatorAdapter`'s sensors, ground truth and ``/clock``.

    The node owns simulated time: each step advances it by the adapter's
    period and publishes ``/clock`` first, then the step's messages, stamped
    with the simulated time. ``realtime_factor`` sets how fast simulated time
    runs against the wall clock (0: as fast as possible).
    """

    COMMON_SPECS: tuple[ParamSpec, ...] = (
        ParamSpec(
            "realtime_factor",
            1.0,
            "[-] simulated seconds per wall-clock second (0: as fast as possible)",
            0.0,
            1000.0,
            read_only=True,
        ),
        ParamSpec(
            "duration", 0.0, "[s] stop after this much simulated time (0: run forever)", 0.0, 1e7, read_only=True
        ),
        ParamSpec("publish_clock", True, "publish /clock with the simulated time", read_only=True),
        ParamSpec(
            "wait_for_subscribers",
            0,
            "[-] start simulating only when every sensor topic has this many subscribers (0: start at once); "
            "a best-effort sample published before discovery completes is lost",
            0,
            100,
            read_only=True,
        ),
    )

    def _start(self) -> None:
        self._clock_pub = self.create_publisher(Clock, "/clock", CLOCK_QOS) if self.values["publish_clock"] else None
        self.sim_time = 0.0
        self.steps = 0
        self.done = False
        self._wait_for = int(self.values["wait_for_subscribers"])
        self._sensor_topics = [o.key for o in self.adapter.outputs if o.kind == "sensor"]
        factor = float(self.values["realtime_factor"])
        self._duration = float(self.values["duration"])
        # A wall timer: simulated time must not wait on the /clock it drives.
        timer_period = self.adapter.period / factor if factor > 0 else 0.0
        self._timer = self.create_timer(max(timer_period, 1e-4), self._tick, clock=rclpy.clock.Clock())
        self._steps_per_tick = 1 if factor > 0 else 10

    def step_once(self) -> None:
        """Advance the simulation one period and publish (also driven by tests)."""
        t, messages = self.adapter.step()
        self.sim_time = t
        self.steps += 1
        if self._clock_pub is not None:
            self._clock_pub.publish(Clock(clock=sec_to_stamp(t)))
        for key, msg in messages:
            self._output_publishers[key].publish(msg)

    def _subscribers_ready(self) -> bool:
        if self._wait_for <= 0:
            return True
        ready = all(self._output_publishers[k].get_subscription_count() >= self._wait_for for k in self._sensor_topics)
        if ready:
            self._wait_for = 0
            self.get_logger().info("subscribers matched: simulating")
        return ready

    def _tick(self) -> None:
        if not self._subscribers_ready():
            return
        for _ in range(self._steps_per_tick):
            if self.done:
                return
            self.step_once()
            if self._duration > 0 and self.sim_time >= self._duration - 1e-9:
                self.done = True
                self._timer.cancel()
                self.get_logger().info(f"simulated {self.sim_time:.2f} s: done")
