"""The estimator-node and simulator-node framework every vehicle uses.

A vehicle provides an *adapter*: the one place that turns its messages into
arrays for a ROS-free core (estimator or plant) and the core's results back
into messages. The framework provides the rest, the same for every vehicle:

* parameters declared with descriptions and ranges, loaded from
  ``config/<vehicle>.yaml``, validated on every update;
* subscriptions and publishers with the contract's QoS under the node's
  namespace;
* ``/diagnostics`` (update rate, age of the last update, innovation
  consistency, rejected input; ERROR while the adapter reports a fault,
  e.g. a diverged filter re-converging, :attr:`AdapterHealth.errors`);
* ``use_sim_time`` (the standard rclpy parameter) and, for simulators, the
  ``/clock`` they drive.

The offline runner (:mod:`terrain_estimation.tools.estimate`) drives the very
same adapter from a bag, so live and offline estimates are identical.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import rclpy
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from scipy.stats import chi2

from terrain_estimation.params import ParameterError, ParamSpec, ParamValue
from terrain_estimation.ros import diagnostics as diag
from terrain_estimation.ros.qos import CLOCK_QOS, qos_for
from terrain_estimation.ros.time import sec_to_stamp

__all__ = [
    "TopicSpec",
    "AdapterHealth",
    "EstimatorAdapter",
    "EstimatorNode",
    "SimulatorAdapter",
    "SimulatorNode",
    "declare_specs",
    "spin_node",
]


@dataclass(frozen=True)
class TopicSpec:
    """A topic an adapter reads or writes.

    Attributes:
        key: the adapter's own name for it (``"imu_body"``).
        topic: name relative to the vehicle namespace (``"imu/body"``).
        msg_type: rclpy message class.
        kind: ``"sensor"`` (sensor-data QoS) or ``"estimate"`` (reliable, depth 10).
        truth_fields: for an estimate, the fields that ``ground_truth/<topic>``
            gives the true value of (compared by the tools' summaries).
    """

    key: str
    topic: str
    msg_type: type
    kind: str = "sensor"
    truth_fields: tuple[str, ...] = ()


@dataclass
class AdapterHealth:
    """What an adapter reports to diagnostics.

    Attributes:
        updates: filter updates done so far.
        last_update_time: stamp (s) of the last update, None before the first.
        nis: recent normalised innovation squared values.
        nis_dof: their degrees of freedom (measurement dimension).
        rejected: count of rejected inputs per reason (``"imu/body: non-finite"``).
        status: free text the adapter wants shown (``"converged"``).
        values: further key/values for the diagnostic.
        warnings: conditions the adapter currently sees as degraded (each
            turns the diagnostic WARN and is shown in its message); the
            adapter sets and clears them.
        errors: faults the adapter currently sees (e.g. the filter diverged
            and is re-converging from the last good estimate: each turns the
            diagnostic ERROR and is shown first in its message); the adapter
            sets them and clears them once recovered (back to OK).
    """

    updates: int = 0
    last_update_time: float | None = None
    nis: deque[float] = field(default_factory=lambda: deque(maxlen=200))
    nis_dof: int = 1
    rejected: dict[str, int] = field(default_factory=dict)
    status: str = ""
    values: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)

    def reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1


class EstimatorAdapter(Protocol):
    """One vehicle's bridge between topics and its ROS-free estimator core."""

    inputs: Sequence[TopicSpec]
    outputs: Sequence[TopicSpec]
    health: AdapterHealth

    def handle(self, key: str, msg: Any) -> list[tuple[str, Any]]:
        """Consume one input message; return ``(output key, message)`` to publish."""
        ...

    def reset(self) -> None: ...


class SimulatorAdapter(Protocol):
    """One vehicle's bridge between its plant and the topics it publishes."""

    outputs: Sequence[TopicSpec]
    period: float  # simulated seconds per step

    def step(self) -> tuple[float, list[tuple[str, Any]]]:
        """Advance one period; return the simulated time and the messages to publish."""
        ...


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    text = spec.description
    if spec.choices:
        text = f"{text} ({spec.range_text()})"
    desc = ParameterDescriptor(description=text, read_only=spec.read_only)
    if spec.kind is float and (spec.min_value is not None or spec.max_value is not None):
        desc.floating_point_range = [
            FloatingPointRange(
                from_value=float(spec.min_value if spec.min_value is not None else -1e308),
                to_value=float(spec.max_value if spec.max_value is not None else 1e308),
                step=0.0,
            )
        ]
    elif spec.kind is int and (spec.min_value is not None or spec.max_value is not None):
        desc.integer_range = [
            IntegerRange(
                from_value=int(spec.min_value if spec.min_value is not None else -(2**62)),
                to_value=int(spec.max_value if spec.max_value is not None else 2**62),
                step=1,
            )
        ]
    return desc


def declare_specs(node: Node, specs: Sequence[ParamSpec]) -> dict[str, ParamValue]:
    """Declare ``specs`` on ``node`` and return their validated values.

    Values come from the node's overrides (``--params-file``,
    ``parameter_overrides``) or the defaults.

    Raises:
        ParameterError: an override is out of range or of the wrong type.
    """
    values: dict[str, ParamValue] = {}
    for spec in specs:
        default = spec.default
        if isinstance(default, list) and not default:
            ptype = Parameter.Type.DOUBLE_ARRAY
            param = node.declare_parameter(spec.name, ptype, _descriptor(spec))
        else:
            param = node.declare_parameter(spec.name, default, _descriptor(spec))
        value = param.value
        if isinstance(value, tuple) or (hasattr(value, "tolist") and not isinstance(value, str)):
            value = list(value)
        values[spec.name] = spec.validate(value)
    return values


class _ParamsMixin:
    """Validation of parameter updates with the specs (an on-set callback)."""

    _specs: dict[str, ParamSpec]

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        for p in params:
            spec = self._specs.get(p.name)
            if spec is None:
                continue  # rclpy's own (use_sim_time …)
            if spec.read_only:
                return SetParametersResult(successful=False, reason=f"{p.name} is read-only")
            value = list(p.value) if isinstance(p.value, (list, tuple)) else p.value
            try:
                spec.validate(value)
            except ParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)


class EstimatorNode(_ParamsMixin, Node):
    """A thin rclpy wrapper around one vehicle's :class:`EstimatorAdapter`.

    Args:
        node_name: e.g. ``"soil_stiffness"``.
        specs: the vehicle's parameter specs (declared with the common ones).
        make_adapter: builds the adapter from validated parameter values and
            the node's namespace; called again after a parameter change.
        namespace: vehicle namespace (``"/quarter_car"``).
        parameter_overrides: values that win over the defaults (tests, tools).
    """

    COMMON_SPECS: tuple[ParamSpec, ...] = (
        ParamSpec("diagnostics.period", 1.0, "[s] period of /diagnostics", 0.05, 60.0),
        ParamSpec(
            "diagnostics.stale_after",
            1.0,
            "[s] WARN when the last filter update is older than this",
            0.01,
            3600.0,
        ),
        ParamSpec(
            "diagnostics.nis_probability",
            0.95,
            "[-] two-sided probability of the chi-square band the mean NIS is checked against",
            0.5,
            0.9999,
        ),
    )

    def __init__(
        self,
        node_name: str,
        specs: Sequence[ParamSpec],
        make_adapter: Callable[[Mapping[str, ParamValue], str], EstimatorAdapter],
        *,
        namespace: str = "",
        parameter_overrides: Sequence[Parameter] | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(node_name, namespace=namespace, parameter_overrides=list(parameter_overrides or []), **kwargs)
        all_specs = tuple(self.COMMON_SPECS) + tuple(specs)
        self._specs = {s.name: s for s in all_specs}
        self.values = declare_specs(self, all_specs)
        self._make_adapter = make_adapter
        self.adapter = make_adapter(self.values, self.get_namespace())
        self.messages_handled = 0
        self._output_publishers = {
            o.key: self.create_publisher(o.msg_type, o.topic, qos_for(o.kind)) for o in self.adapter.outputs
        }
        for spec in self.adapter.inputs:
            self.create_subscription(spec.msg_type, spec.topic, self._callback_for(spec.key), qos_for(spec.kind))
        self._diag_pub = self.create_publisher(diag.DiagnosticArray, "/diagnostics", 10)
        self._rate_window: deque[float] = deque(maxlen=100)  # stamps of recent updates
        self._last_updates = 0
        self.create_timer(float(self.values["diagnostics.period"]), self.publish_diagnostics)
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._after_set)

    def _callback_for(self, key: str) -> Callable[[Any], None]:
        def callback(msg: Any) -> None:
            for out_key, out_msg in self.adapter.handle(key, msg):
                self._output_publishers[out_key].publish(out_msg)
            self.messages_handled += 1

        return callback

    def _after_set(self, params: list[Parameter]) -> None:
        changed = [p for p in params if p.name in self._specs]
        if not changed:
            return
        for p in changed:
            value = list(p.value) if isinstance(p.value, (list, tuple)) else p.value
            self.values[p.name] = self._specs[p.name].validate(value)
        # A parameter of the model or filter changed: rebuild from the new
        # values. The filter restarts; say so rather than mix two models.
        self.adapter = self._make_adapter(self.values, self.get_namespace())
        self.get_logger().info("parameters " + ", ".join(p.name for p in changed) + " changed: estimator restarted")

    def diagnostic_status(self) -> diag.DiagnosticStatus:
        """The node's health as one DiagnosticStatus (also used by tests)."""
        health = self.adapter.health
        now = self.get_clock().now().nanoseconds * 1e-9
        level = diag.OK
        notes: list[str] = []
        values: dict[str, Any] = {"updates": health.updates}
        if health.last_update_time is None:
            level = diag.WARN
            notes.append("no filter update yet")
        else:
            age = now - health.last_update_time
            values["last_update_age_s"] = age
            if age > float(self.values["diagnostics.stale_after"]):
                level = diag.WARN
                notes.append(f"last update {age:.2f} s ago")
        period = float(self.values["diagnostics.period"])
        rate = (health.updates - self._last_updates) / period
        self._last_updates = health.updates
        values["update_rate_hz"] = rate
        if health.nis:
            n = len(health.nis)
            mean_nis = sum(health.nis) / n
            p = float(self.values["diagnostics.nis_probability"])
            # The sum of n independent NIS values is chi-square with n*dof
            # degrees of freedom: a two-sided band on their mean.
            lo = chi2.ppf((1 - p) / 2, n * health.nis_dof) / n
            hi = chi2.ppf((1 + p) / 2, n * health.nis_dof) / n
            values.update(nis_mean=mean_nis, nis_band_low=lo, nis_band_high=hi, nis_window=n)
            if not math.isfinite(mean_nis) or mean_nis > hi or mean_nis < lo:
                level = diag.worst(level, diag.WARN)
                notes.append(f"innovations inconsistent (mean NIS {mean_nis:.2f} outside [{lo:.2f}, {hi:.2f}])")
        if health.warnings:
            level = diag.worst(level, diag.WARN)
            notes.extend(health.warnings)
        if health.errors:
            level = diag.worst(level, diag.ERROR)
            notes[:0] = health.errors
        for reason, count in health.rejected.items():
            values[f"rejected: {reason}"] = count
        values.update(health.values)
        message = "; ".join(notes) if notes else (health.status or "estimating")
        return diag.make_status(
            f"{self.get_fully_qualified_name()}: estimator",
            self.get_namespace().strip("/") or self.get_name(),
            level,
            message,
            values,
        )

    def publish_diagnostics(self) -> None:
        self._diag_pub.publish(diag.make_array(self.get_clock().now().to_msg(), [self.diagnostic_status()]))


class SimulatorNode(_ParamsMixin, Node):
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

    def __init__(
        self,
        node_name: str,
        specs: Sequence[ParamSpec],
        make_adapter: Callable[[Mapping[str, ParamValue], str], SimulatorAdapter],
        *,
        namespace: str = "",
        parameter_overrides: Sequence[Parameter] | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(node_name, namespace=namespace, parameter_overrides=list(parameter_overrides or []), **kwargs)
        all_specs = tuple(self.COMMON_SPECS) + tuple(specs)
        self._specs = {s.name: s for s in all_specs}
        self.values = declare_specs(self, all_specs)
        self.adapter = make_adapter(self.values, self.get_namespace())
        self._output_publishers = {
            o.key: self.create_publisher(o.msg_type, o.topic, qos_for(o.kind)) for o in self.adapter.outputs
        }
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
        self.add_on_set_parameters_callback(self._on_set)

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


def spin_node(node: Node) -> None:
    """Spin ``node`` until Ctrl-C, shutdown or (a simulator) its end, then clean up.

    The ros2/demos pattern; a :class:`SimulatorNode` with a ``duration``
    returns when it has simulated it.
    """
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        while rclpy.ok(context=node.context) and not getattr(node, "done", False):
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
