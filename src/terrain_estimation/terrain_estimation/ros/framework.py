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
  ``/clock`` they drive;
* robustness (issue 7), the same for every estimator:

  - **bad input**: every message is checked before the adapter sees it
    (:class:`~terrain_estimation.ros.validation.InputGuard`: frame id,
    stamp ahead of the clock, duplicated or out of order, non-finite
    fields, covariance not PSD, an acceleration sample beyond any
    accelerometer's range, accelerations in g, without gravity, upside down
    or on their side, as declared by the adapter's :class:`TopicSpec`). A bad
    message is dropped whole, counted per reason in ``/diagnostics`` (``input
    rejected: <topic>: <field> <problem>``; WARN while new ones arrive) and
    logged with its value, at most once per ``input.log_throttle`` per reason.
    Until every accelerometer has been judged plausible, an adapter that
    reports convergence (:class:`JudgedInputs`) claims none;
  - **non-finite output**: an estimate holding a NaN or Inf is never
    published (counted, ERROR);
  - **clock jumps**: a jump of the node's clock backward by more than
    ``time.backward_jump`` (a looping bag under ``--clock``) or forward by
    more than ``time.forward_jump`` resets the adapter (``reset()``) and the
    input checks' stamp history, reported at once as WARN on
    ``/diagnostics`` and then counted (``clock_jumps_*``). The first
    ``/clock`` of a sim-time node only starts its clock;
  - **silent topics**: an input silent for longer than its
    ``timeouts.<key>`` (clock time: sim time under ``use_sim_time``) turns
    the diagnostics WARN, naming the topic and what the estimator does
    meanwhile (:attr:`TopicSpec.on_timeout`: each vehicle documents it;
    mostly it holds the last estimate and publishes nothing new); it clears
    when the topic resumes.

The offline runner (:mod:`terrain_estimation.tools.estimate`) drives the very
same adapter from a bag, so live and offline estimates are identical.

This module holds the estimator node (:class:`EstimatorNode`) and
:func:`spin_node`; the adapter contract is in
:mod:`~terrain_estimation.ros.adapters`, the parameter declaration and the
helpers the vehicles' specs share in :mod:`~terrain_estimation.ros.parameters`,
what both nodes share in :mod:`~terrain_estimation.ros.adapter_node`, the
estimator node's ``/diagnostics`` in :mod:`~terrain_estimation.ros.node_diagnostics`
and the simulator node in :mod:`~terrain_estimation.ros.simulator_node`. Their public
names are imported here too, where the vehicles and tools have always found them.
"""

from __future__ import annotations

import functools
import heapq
import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.clock import JumpHandle, JumpThreshold, ROSClock, TimeJump
from rclpy.duration import Duration
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message

from terrain_estimation.params import ParamSpec
from terrain_estimation.ros import diagnostics as diag
from terrain_estimation.ros.adapters import (
    AdapterHealth,
    EstimatorAdapter,
    JudgedInputs,
    SimulatorAdapter,
    TopicSpec,
)
from terrain_estimation.ros.cdr import Decoder, decoder_for
from terrain_estimation.ros.node_diagnostics import EstimatorDiagnostics
from terrain_estimation.ros.parameters import (
    ESTIMATOR_NODE_SPECS,
    declare_specs,
    divergence_config,
    divergence_errors,
    divergence_specs,
    input_frame,
    input_specs,
)
from terrain_estimation.ros.qos import qos_for
from terrain_estimation.ros.simulator_node import SimulatorNode
from terrain_estimation.ros.time import stamp_to_ns
from terrain_estimation.ros.validation import InputGuard, Rejection, first_nonfinite

__all__ = [
    "TopicSpec",
    "AdapterHealth",
    "EstimatorAdapter",
    "EstimatorNode",
    "JudgedInputs",
    "SimulatorAdapter",
    "SimulatorNode",
    "declare_specs",
    "input_specs",
    "input_frame",
    "divergence_specs",
    "divergence_config",
    "divergence_errors",
    "spin_node",
]


_wall_time = time.monotonic
"""The clock of the log throttle (wall time: a paused sim clock must not silence the logs)."""


def _ordered(msg: Any, info: Any, key: str) -> tuple[int, int, str, Any]:
    """``(stamp ns, reception ns, topic key, msg)`` of an input taken for :meth:`EstimatorNode._take_queued`
    (``info``: the middleware's MessageInfo of a taken message; None, the executor's delivered one,
    counts as received first)."""
    received = int(info["received_timestamp"]) if info is not None else 0
    return stamp_to_ns(msg.header.stamp), received, key, msg


def _order_key(item: tuple[int, int, str, Any]) -> tuple[int, int]:
    return item[0], item[1]


class EstimatorNode(EstimatorDiagnostics):
    """A thin rclpy wrapper around one vehicle's :class:`EstimatorAdapter`.

    Args:
        node_name: e.g. ``"soil_stiffness"``.
        specs: the vehicle's parameter specs (declared with the common ones).
        make_adapter: builds the adapter from validated parameter values and
            the node's namespace; called again after a parameter change.
        namespace: vehicle namespace (``"/quarter_car"``).
        parameter_overrides: values that win over the defaults (tests, tools).
    """

    COMMON_SPECS: tuple[ParamSpec, ...] = ESTIMATOR_NODE_SPECS

    def _start(self) -> None:
        # The NIS check of the diagnostics (scipy.special) is loaded now, not at the first diagnostics
        # message, where it would stall the executor once; the offline tool, which has none, never loads it.
        import terrain_estimation.analysis.consistency  # noqa: F401

        self._judged = self.adapter if isinstance(self.adapter, JudgedInputs) else None
        self.messages_handled = 0
        self.published: dict[str, int] = {}  # output key -> messages published
        self._held: dict[str, list[tuple[int, int, str, Any]]] = {}  # taken, not yet handled (_take_queued)
        # Wakes the executor for another _take_queued while messages are held: the events of
        # the messages taken early find nothing, so none of them would. A timer, reset when
        # needed and cancelled when it fires (rclpy's EventsExecutor has no guard conditions).
        self._held_wake = self.create_timer(1e-4, self._take_held)
        self._held_wake.cancel()
        # Every input subscription is raw: the node decodes the bytes itself (a message that does not
        # decode is rejected like any bad input, where rclpy's own take would stop the executor).
        fast = bool(self.values["input.fast_decode"])
        self._input_subscriptions: list[tuple[str, Any, Decoder]] = []
        for spec in self.adapter.inputs:
            decode = (decoder_for(spec.msg_type) if fast else None) or functools.partial(
                deserialize_message, message_type=spec.msg_type
            )
            sub = self.create_subscription(
                spec.msg_type,
                spec.topic,
                self._callback_for(spec.key, decode),
                qos_for(spec.kind, int(self.values["qos.sensor_depth"])),
                raw=True,
            )
            self._input_subscriptions.append((spec.key, sub, decode))
        self._diag_pub = self.create_publisher(diag.DiagnosticArray, "/diagnostics", 10)
        self._rate_window: deque[float] = deque(maxlen=100)  # stamps of recent updates
        self._last_updates = 0
        # Input validation, output check, silence and clock jumps (issue 7).
        self.guard = InputGuard(self.adapter.inputs, self.values)
        self.outputs_dropped: dict[str, int] = {}
        self.restarts: dict[str, int] = {}
        self._rejected_reported = 0
        self._last_log: dict[str, tuple[float, int]] = {}  # reason -> (wall time of last line, suppressed)
        self._last_receipt: dict[str, float] = {}
        self._watch_from: float | None = None  # clock time the silence of every topic is measured from
        self._silent: set[str] = set()
        self.clock_jumps: dict[str, int] = {"backward": 0, "forward": 0}
        self._jump_note = ""  # WARN from a reset until the estimator's first update after it
        self.last_reset = ""
        self._updates_at_jump = 0
        self._time_before_jump = 0
        self._jump_handle: JumpHandle | None = None
        self._register_jump_callback()
        self.create_timer(float(self.values["diagnostics.period"]), self.publish_diagnostics)
        self.add_post_set_parameters_callback(self._after_set)

    # -- input ------------------------------------------------------------------------
    def _clock_s(self) -> float | None:
        """The node's clock in seconds, None while it does not run (sim time before /clock).

        ``Clock.now()``'s reading without the ``Time`` object it wraps it in (a third of the
        cost, and this runs for every message the executor delivers).
        """
        handle = self.get_clock().handle
        with handle:
            ns = handle.get_now().nanoseconds
        return ns * 1e-9 if ns > 0 else None

    def _callback_for(self, key: str, decode: Decoder) -> Callable[[bytes], None]:
        def callback(data: bytes) -> None:
            msg = self._decoded(key, decode, data)
            if msg is None:
                return
            limit = self._take_limit()
            if not limit and not self._held:
                self._on_input(key, msg, self._clock_s())  # one message per callback
                return
            # The delivered message is the next of its topic: after what is held, merged with the
            # rest. No MessageInfo (rclpy's EventsExecutor cannot pass it): among equal stamps it
            # counts as received first, which it was (the executor serves events in arrival order).
            self._held.setdefault(key, []).append(_ordered(msg, None, key))
            self._take_queued(limit)

        return callback

    def _decoded(self, key: str, decode: Decoder, data: bytes) -> Any:
        """``decode(data)``, or None after rejecting the message when the bytes are not its type
        (rclpy raises for those; a node that let it through would stop on one corrupt sample)."""
        try:
            return decode(data)
        except RuntimeError as exc:
            spec = self.guard.inputs[key]
            rejection = Rejection(
                spec.topic,
                "(serialised message)",
                f"{len(data)} bytes ({exc})",
                f"does not decode as {spec.msg_type.__name__}",
            )
            self.guard.rejected[rejection.reason] = self.guard.rejected.get(rejection.reason, 0) + 1
            self._on_rejection(rejection)
            self.messages_handled += 1  # consumed, like any rejected input
            return None

    def _take_limit(self) -> int:
        """``input.take_queued``, or 0 under sim time (see :meth:`_take_queued`)."""
        return 0 if self._sim_time_active() else int(self.values["input.take_queued"])

    def _take_held(self) -> None:
        self._held_wake.cancel()
        if self._held:
            self._take_queued(self._take_limit())

    def _sim_time_active(self) -> bool:
        clock = self.get_clock()
        return isinstance(clock, ROSClock) and clock.ros_time_is_active

    def _on_input(self, key: str, msg: Any, now: float | None) -> None:
        """One input message: checks, then the adapter, then its estimates published.

        ``now``: the node's clock (s) when the message was taken (:meth:`_clock_s`).
        """
        try:
            if now is not None:
                self._last_receipt[key] = now
            rejection = self.guard.check(key, msg, now)
            if rejection is not None:
                self._on_rejection(rejection)
                return
            if self._judged is not None:
                self._judged.inputs_judged = self.guard.gravity_judged
            for out_key, out_msg in self.adapter.handle(key, msg):
                self._publish(out_key, out_msg)
        finally:
            self.messages_handled += 1

    def _take_queued(self, limit: int) -> None:
        """Handle the held messages (the one just delivered among them) and those already queued
        on the input subscriptions (up to ``limit`` taken from each per call; 0: none), oldest
        stamp first.

        Why: the executor hands a Python callback one message per event, and that costs
        more of the executor thread than the estimator's own work on a message of the
        1 kHz profile (``make bench-load``, empty-callback rows); taking a queued message
        directly costs about half. Under a backlog most messages then come this way; with
        no backlog each input subscription answers one empty take (about 1 µs).

        Order: the topics are merged by stamp (equal stamps in the order the middleware
        received them, as a recording would have logged them), each in its own arrival order (so the input
        checks still see a topic's stamps as they came). A topic handled ahead of the others
        would break the estimators' pairing of inputs (the quarter car's accelerometers ahead
        of the 1 kHz profile: filter steps without their road). So when a subscription gave
        ``limit`` messages (more may be queued), nothing stamped after its last one is handled
        yet: the rest waits in ``_held``, in order, for the next call (a timer wakes the
        executor for it; a message delivered meanwhile joins its topic's held
        ones, behind them). Under sim time nothing is taken: inputs taken ahead of the
        ``/clock`` messages queued with them would meet a clock that lags them (the
        future-stamp check).
        """
        horizon = math.inf
        sequences = []
        for key, sub, decode in self._input_subscriptions:
            taken = self._held.pop(key, [])
            fresh = 0
            try:
                with sub.handle:
                    while fresh < limit:
                        item = sub.handle.take_message(sub.msg_type, sub.raw)
                        if item is None:
                            break
                        fresh += 1
                        msg = self._decoded(key, decode, item[0])
                        if msg is not None:
                            taken.append(_ordered(msg, item[1], key))
            except InvalidHandle:  # the node is being destroyed
                return
            if limit and fresh == limit:  # (the last one taken may not have decoded: hold all if none did)
                horizon = min(horizon, taken[-1][0] if taken else -math.inf)
            if taken:
                sequences.append(taken)
        now = self._clock_s()  # after the takes: every message here was received before it
        holding = False
        for item in heapq.merge(*sequences, key=_order_key):
            stamp, _, key, msg = item
            holding = holding or stamp > horizon  # from here on, in merge order (each topic's order)
            if holding:
                self._held.setdefault(key, []).append(item)
            else:
                self._on_input(key, msg, now)
        if self._held:
            self._held_wake.reset()

    def _throttled(self, reason: str, line: str, level: str = "warn") -> None:
        """Log ``line`` unless ``reason`` was logged less than ``input.log_throttle`` ago (wall time)."""
        now = _wall_time()
        last, suppressed = self._last_log.get(reason, (-math.inf, 0))
        if now - last < float(self.values["input.log_throttle"]):
            self._last_log[reason] = (last, suppressed + 1)
            return
        if suppressed:
            line += f" ({suppressed} more since the last line)"
        self._last_log[reason] = (now, 0)
        getattr(self.get_logger(), level)(line)

    def _on_rejection(self, rejection: Rejection) -> None:
        self._throttled(rejection.reason, f"rejected {rejection.text}")
        if rejection.rebase:
            self.restarts[rejection.reason] = self.restarts.get(rejection.reason, 0) + 1
            self._reset_estimator()
            self._jump_note = f"{rejection.topic}: stamps went back to {rejection.value}: estimator reset"
            self.last_reset = self._jump_note
            self._updates_at_jump = self.adapter.health.updates
            self.get_logger().warn(self._jump_note)
        elif rejection.restart:
            # Input of this kind may already be inside the filter: start again without it.
            self.restarts[rejection.reason] = self.restarts.get(rejection.reason, 0) + 1
            self._reset_estimator()
            self.get_logger().warn(f"estimator restarted: {rejection.reason}")

    def _publish(self, key: str, msg: Any) -> None:
        """Publish ``msg`` unless a float in it is not finite (then count and log it: never published)."""
        bad = first_nonfinite(msg)
        if bad is not None:
            topic = next(o.topic for o in self.adapter.outputs if o.key == key)
            reason = f"{topic}: {bad[0]} not finite"
            self.outputs_dropped[reason] = self.outputs_dropped.get(reason, 0) + 1
            self._throttled(reason, f"not published: {topic}: {bad[0]} = {bad[1]!r} is not finite", "error")
            return
        self._output_publishers[key].publish(msg)
        self.published[key] = self.published.get(key, 0) + 1

    def _reset_estimator(self) -> None:
        self.adapter.reset()
        self._last_updates = 0

    # -- clock jumps ------------------------------------------------------------------------
    def _register_jump_callback(self) -> None:
        if self._jump_handle is not None:
            self._jump_handle.unregister()
        threshold = JumpThreshold(
            min_forward=Duration(nanoseconds=round(float(self.values["time.forward_jump"]) * 1e9)),
            min_backward=Duration(nanoseconds=-max(1, round(float(self.values["time.backward_jump"]) * 1e9))),
            on_clock_change=False,
        )
        self._jump_handle = self.get_clock().create_jump_callback(
            threshold, pre_callback=self._before_jump, post_callback=self._on_jump
        )

    def _before_jump(self) -> None:
        self._time_before_jump = self.get_clock().now().nanoseconds

    def _on_jump(self, jump: TimeJump) -> None:
        """Reset the estimator on a clock jump (a looping bag, a skipped stretch)."""
        delta = jump.delta.nanoseconds * 1e-9
        now = self._clock_s()
        self._last_receipt.clear()
        self._watch_from = now
        self._silent.clear()
        if self._time_before_jump <= 0:
            return  # the first /clock of a sim-time node: its clock starts, nothing to reset
        direction = "backward" if delta < 0 else "forward"
        self.clock_jumps[direction] += 1
        self._reset_estimator()
        self.guard.reset()
        self._updates_at_jump = self.adapter.health.updates
        self._jump_note = (
            f"clock jumped {direction} by {abs(delta):.6g} s (to {now if now is not None else 0.0:.6g} s): "
            "estimator reset"
        )
        self.last_reset = self._jump_note
        self.get_logger().warn(self._jump_note)
        self.publish_diagnostics()

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
        self._judged = self.adapter if isinstance(self.adapter, JudgedInputs) else None
        self._last_updates = 0
        self.guard = InputGuard(self.adapter.inputs, self.values)
        self._rejected_reported = 0
        self._register_jump_callback()
        self.get_logger().info("parameters " + ", ".join(p.name for p in changed) + " changed: estimator restarted")


def spin_node(node: Node, executor_kind: str = "events") -> None:
    """Spin ``node`` until Ctrl-C, shutdown or (a simulator) its end, then clean up.

    The ros2/demos pattern; a :class:`SimulatorNode` with a ``duration``
    returns when it has simulated it.

    ``executor_kind``: ``"events"`` (default) is rclpy's C++ ``EventsExecutor``
    (``rclpy.experimental``, in the Jazzy wheels), falling back to ``"single"``,
    rclpy's ``SingleThreadedExecutor``, where rclpy lacks it. The wait-based
    executor takes one message per ready subscription per wait and rebuilds the
    wait set in Python for each: about 0.3 ms per message, half a core for one
    quarter car at its nominal 1.3 kHz input; under a backlog its round robin
    over topics of different rates serves the 100 Hz accelerometers ten times
    faster than the 1 kHz profile, so filter steps outrun the road and are lost.
    The events executor runs the callbacks in arrival order at about a third of
    the CPU (``python -m terrain_analysis.tools.bench_load``).
    """
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    executor: Any
    try:
        if executor_kind != "events":
            raise ImportError(executor_kind)
        from rclpy.experimental import EventsExecutor

        executor = EventsExecutor(context=node.context)
    except ImportError:
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
