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
"""

from __future__ import annotations

import functools
import heapq
import math
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import rclpy
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.clock import JumpHandle, JumpThreshold, ROSClock, TimeJump
from rclpy.duration import Duration
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock

from terrain_estimation.filters.faults import DivergenceConfig
from terrain_estimation.params import ParameterError, ParamSpec, ParamValue
from terrain_estimation.ros import diagnostics as diag
from terrain_estimation.ros.cdr import Decoder, decoder_for
from terrain_estimation.ros.qos import CLOCK_QOS, qos_for
from terrain_estimation.ros.time import sec_to_stamp, stamp_to_ns
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

    Checks of an input (:class:`~terrain_estimation.ros.validation.InputGuard`;
    the defaults check nothing but the stamps):

    Attributes:
        frame_id: expected ``header.frame_id`` (namespace included); empty: any.
        fields: numeric fields the adapter reads, which must be finite
            (``"linear_acceleration.z"``; ``"velocity[wheel]"`` picks a
            JointState entry by joint name).
        covariances: 3x3 covariance arrays that must be symmetric positive
            semi-definite unless marked not measured.
        gravity_fields: specific-force components (REP 145, m/s²): each sample
            within ``input.max_acceleration``, their windowed mean of the
            magnitude ``gravity`` and, with a ``z`` among them, pointing up
            (REP 103) within ``input.gravity_max_tilt``.
        gravity: [m/s^2] the vehicle's gravity.
        timeout: [s] diagnostics WARN when the topic is silent for longer (0: never).
        on_timeout: what the estimator does meanwhile (shown in the warning).
    """

    key: str
    topic: str
    msg_type: type
    kind: str = "sensor"
    truth_fields: tuple[str, ...] = ()
    frame_id: str = ""
    fields: tuple[str, ...] = ()
    covariances: tuple[str, ...] = ()
    gravity_fields: tuple[str, ...] = ()
    gravity: float = 9.80665
    timeout: float = 0.0
    on_timeout: str = ""


def input_specs(key: str, topic: str, frame: str, timeout: float, on_timeout: str) -> tuple[ParamSpec, ParamSpec]:
    """The two parameters of one input topic: its expected frame and its timeout.

    ``frames.<key>``: expected ``header.frame_id`` (see :func:`input_frame`);
    ``timeouts.<key>``: silence after which diagnostics turn WARN.
    """
    return (
        ParamSpec(
            f"frames.{key}",
            frame,
            f"expected header.frame_id of {topic}, prefixed with the namespace (a leading '/': taken as is; "
            "empty: any); a message in another frame is rejected",
        ),
        ParamSpec(
            f"timeouts.{key}",
            timeout,
            f"[s] diagnostics WARN when {topic} is silent for longer (0: never); meanwhile {on_timeout}",
            0.0,
            3600.0,
        ),
    )


def input_frame(values: Mapping[str, ParamValue], namespace: str, key: str) -> str:
    """The full expected frame of input ``key`` from ``frames.<key>`` ('' = not checked)."""
    frame = str(values[f"frames.{key}"])
    if not frame:
        return ""
    if frame.startswith("/"):
        return frame.lstrip("/")
    ns = namespace.strip("/")
    return f"{ns}/{frame}" if ns else frame


def divergence_specs(check_low_note: str | None = None) -> tuple[ParamSpec, ...]:
    """The ``filter.divergence_*`` parameters of an estimator with a divergence monitor.

    (:class:`~terrain_estimation.filters.faults.DivergenceMonitor`; read back
    by :func:`divergence_config`, reported by :func:`divergence_errors`.)

    Args:
        check_low_note: None: no ``filter.divergence_check_low`` parameter
            (the NIS band is two-sided); else that parameter, default false,
            with this note on why in its description.
    """
    specs = (
        ParamSpec(
            "filter.divergence_window",
            0,
            "[updates] divergence monitor: windowed mean NIS against its chi2 band, covariance blow-up and gate "
            "lock-out; on a divergence the filter restarts from the last good estimate (diagnostic ERROR, then OK); "
            "0 disables (default: the reproductions run without it)",
            0,
            10000,
        ),
        ParamSpec(
            "filter.divergence_probability",
            0.999,
            "[-] two-sided probability of the windowed mean NIS band of the divergence monitor",
            0.5,
            0.999999,
        ),
        ParamSpec(
            "filter.divergence_persistence",
            10,
            "[updates] consecutive out-of-band windows that make a divergence",
            1,
            10000,
        ),
    )
    if check_low_note is None:
        return specs
    return (
        *specs,
        ParamSpec(
            "filter.divergence_check_low",
            False,
            f"a windowed mean NIS below its band (covariance far too large) is a divergence too; {check_low_note}",
        ),
    )


def divergence_config(values: Mapping[str, ParamValue]) -> DivergenceConfig | None:
    """The monitor's settings from the parameters of :func:`divergence_specs`; None when disabled (window 0).

    Also reads ``filter.divergence_reinit_inflation`` and ``filter.divergence_max_variance_growth``
    where the node declares them.
    """
    window = int(values["filter.divergence_window"])
    if window <= 0:
        return None
    extra: dict[str, Any] = {}
    if "filter.divergence_check_low" in values:
        extra["check_low"] = bool(values["filter.divergence_check_low"])
    for name in ("reinit_inflation", "max_variance_growth"):
        if f"filter.divergence_{name}" in values:
            extra[name] = float(values[f"filter.divergence_{name}"])
    return DivergenceConfig(
        window=window,
        probability=float(values["filter.divergence_probability"]),
        persistence=int(values["filter.divergence_persistence"]),
        **extra,
    )


def divergence_errors(fault: str | None, divergences: int) -> list[str]:
    """:attr:`AdapterHealth.errors` of an estimator's divergence fault (empty when healthy)."""
    if not fault:
        return []
    return [f"filter diverged ({fault}): restarted from the last good estimate ({divergences} divergence(s) so far)"]


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


@runtime_checkable
class JudgedInputs(Protocol):
    """An adapter that withholds convergence until the input checks have judged its inputs.

    Runners (:class:`EstimatorNode`, the offline runner) set ``inputs_judged`` to
    :attr:`InputGuard.gravity_judged <terrain_estimation.ros.validation.InputGuard.gravity_judged>`
    before each message they pass to ``handle()``; while it is False no estimate claims to
    have converged (its input may still be found bad). An adapter used without input
    checks keeps True.
    """

    inputs_judged: bool


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
        if value is None and isinstance(default, list) and not default:
            value = []  # rcl gives an empty list of a parameter file ("name: []") as NOT_SET
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
        ParamSpec(
            "qos.sensor_depth",
            200,
            "[messages] queue depth of each sensor subscription (best effort): a replay faster than the "
            "filter drops messages beyond it (ros/qos.py)",
            1,
            1_000_000,
            read_only=True,
        ),
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
            "[-] two-sided probability of the chi-square band the windowed mean NIS is checked against (its sample "
            "count is the window's effective one, n / tau, tau the NIS autocorrelation time)",
            0.5,
            0.9999,
        ),
        ParamSpec(
            "input.take_queued",
            50,
            "[messages] after each input message the executor delivers, also take up to this many messages "
            "already queued on each input subscription and handle them in stamp order (0: one message per "
            "callback); under a backlog (a fast replay, many vehicles) this costs about half the CPU per message. "
            "Not with use_sim_time: there the inputs keep their arrival order with /clock",
            0,
            100_000,
        ),
        ParamSpec(
            "input.fast_decode",
            True,
            "decode the inputs' serialised bytes with the project's CDR decoder (ros/cdr.py: the same rclpy "
            "message objects, about 2 us instead of 9-17 us per message; anything it is unsure of goes to "
            "rclpy's deserialisation); false: rclpy's deserialize_message decodes every input",
            read_only=True,
        ),
        ParamSpec(
            "input.max_future_stamp",
            1.0,
            "[s] an input stamped further ahead of the node's clock (sim time: /clock) is rejected",
            1e-3,
            1e6,
        ),
        ParamSpec(
            "input.gravity_tolerance",
            0.7,
            "[-] an accelerometer whose mean specific force over input.gravity_window differs from gravity by "
            "more than this fraction is rejected (in g: 0.1 g; gravity removed: 0; ride vibration moves a "
            "1 s mean by up to 30 %)",
            0.01,
            0.95,
        ),
        ParamSpec(
            "input.gravity_window",
            2.0,
            "[s] window of the accelerometers' mean specific force (judged once half full; 0: no check)",
            0.0,
            60.0,
        ),
        ParamSpec(
            "input.gravity_max_tilt",
            60.0,
            "[deg] an accelerometer whose mean specific force over input.gravity_window is tilted further from +z "
            "(REP 103: z up; a vehicle at rest reads +g on z) is rejected; pointing down (z <= 0): upside down. A "
            "35 deg slope plus a sustained 0.4 g of acceleration tilts it about 57 deg; not checked without z",
            1.0,
            90.0,
        ),
        ParamSpec(
            "input.max_acceleration",
            50.0,
            "[g] an accelerometer sample with a specific-force component beyond this many standard g is a glitch "
            "(MEMS accelerometers saturate at 2-16 g; a hard wheel impact is tens of g) and is rejected alone, "
            "before it enters the gravity window",
            1.0,
            10000.0,
        ),
        ParamSpec(
            "input.restart_after_out_of_order",
            50,
            "[-] this many consecutive out-of-order samples of one topic, each later than the one before, are a "
            "source clock that went back (a bag looped without /clock): the estimator restarts on them (0: never)",
            0,
            1000000,
        ),
        ParamSpec(
            "input.log_throttle",
            5.0,
            "[s] at most one log line per rejection reason (and per silent topic) in this much wall time",
            0.0,
            3600.0,
        ),
        ParamSpec(
            "time.forward_jump",
            5.0,
            "[s] a forward jump of the node's clock (sim time: /clock) larger than this resets the estimator",
            1e-3,
            1e9,
        ),
        ParamSpec(
            "time.backward_jump",
            1e-3,
            "[s] a backward jump of the node's clock larger than this (a looping bag) resets the estimator",
            1e-9,
            1e9,
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
        # The NIS check of the diagnostics (scipy.special) is loaded now, not at the first diagnostics
        # message, where it would stall the executor once; the offline tool, which has none, never loads it.
        import terrain_estimation.analysis.consistency  # noqa: F401

        self._judged = self.adapter if isinstance(self.adapter, JudgedInputs) else None
        self.messages_handled = 0
        self.published: dict[str, int] = {}  # output key -> messages published
        self._output_publishers = {
            o.key: self.create_publisher(o.msg_type, o.topic, qos_for(o.kind)) for o in self.adapter.outputs
        }
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
        self.add_on_set_parameters_callback(self._on_set)
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
            # The sum of n independent NIS values is chi-square with n*dof degrees of freedom: a two-sided band
            # on their mean. On a real vehicle (or any plant richer than the model) the innovations are
            # coloured by the model error, and n correlated values carry only n/tau independent ones (tau: the
            # window's integrated autocorrelation time, Geyer's initial positive sequence); a band of n would
            # WARN on every healthy run. A fault (a sensor offset, a stuck input) moves the mean by far more.
            # Imported here, at the first diagnostics with NIS samples: the analysis package pulls scipy.special
            # and scipy.linalg in, which the offline replay and a node's start-up need not wait for (issue 23).
            from terrain_estimation.analysis.consistency import chi2_mean_band, integrated_autocorrelation_time

            tau = integrated_autocorrelation_time(list(health.nis)) if n >= 8 else 1.0
            lo, hi = chi2_mean_band(health.nis_dof, n / tau, p)
            values.update(nis_mean=mean_nis, nis_band_low=lo, nis_band_high=hi, nis_window=n, nis_tau=tau)
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
        level = self._input_diagnostics(level, notes, values, now)
        values.update(health.values)
        message = "; ".join(notes) if notes else (health.status or "estimating")
        return diag.make_status(
            f"{self.get_fully_qualified_name()}: estimator",
            self.get_namespace().strip("/") or self.get_name(),
            level,
            message,
            values,
        )

    def _input_diagnostics(self, level: bytes, notes: list[str], values: dict[str, Any], now: float) -> bytes:
        """Rejected input, dropped output, silent topics and clock jumps (part of :meth:`diagnostic_status`)."""
        guard = self.guard
        total = sum(guard.rejected.values())
        values["input_accepted"] = guard.accepted
        values["input_rejected"] = total
        for reason, count in guard.rejected.items():
            values[f"input rejected: {reason}"] = count
        new = total - self._rejected_reported
        self._rejected_reported = total
        if new > 0:
            level = diag.worst(level, diag.WARN)
            notes.append(f"{new} input messages rejected since the last report")
        for reason, count in self.restarts.items():
            values[f"estimator restarts: {reason}"] = count
        if self.outputs_dropped:
            level = diag.worst(level, diag.ERROR)
            notes.insert(0, f"{sum(self.outputs_dropped.values())} non-finite estimates not published")
            for reason, count in self.outputs_dropped.items():
                values[f"output dropped: {reason}"] = count
        values["clock_jumps_backward"] = self.clock_jumps["backward"]
        values["clock_jumps_forward"] = self.clock_jumps["forward"]
        if self.last_reset:
            values["last_reset"] = self.last_reset
        if self._jump_note and self.adapter.health.updates > self._updates_at_jump:
            self._jump_note = ""  # estimating again
        if self._jump_note:
            level = diag.worst(level, diag.WARN)
            notes.append(self._jump_note)
        if self._clock_s() is None:
            return level  # sim time before /clock: silence cannot be measured
        if self._watch_from is None:
            self._watch_from = now
        silent = []
        for spec in self.adapter.inputs:
            if spec.timeout <= 0.0:
                continue
            age = now - self._last_receipt.get(spec.key, self._watch_from)
            if age > spec.timeout:
                silent.append(spec.topic)
                level = diag.worst(level, diag.WARN)
                what = "silent" if spec.key in self._last_receipt else "never received"
                note = f"{spec.topic} {what} for {age:.3g} s (timeout {spec.timeout:g} s)"
                notes.append(note + (f": {spec.on_timeout}" if spec.on_timeout else ""))
                if spec.key not in self._silent:
                    self._silent.add(spec.key)
                    self._throttled(f"silent {spec.key}", note)
            elif spec.key in self._silent:
                self._silent.discard(spec.key)
                self.get_logger().info(f"{spec.topic} resumed")
        values["silent_topics"] = ", ".join(silent) if silent else "none"
        return level

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
