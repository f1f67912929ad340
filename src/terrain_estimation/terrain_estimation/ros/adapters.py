"""The contract between a vehicle's adapter and the nodes that run it.

An adapter is the one place that turns a vehicle's messages into arrays for a
ROS-free core (estimator or plant) and the core's results back into messages.
It declares the topics it reads and writes (:class:`TopicSpec`, with the
checks :class:`~terrain_estimation.ros.validation.InputGuard` applies to an
input) and reports its health (:class:`AdapterHealth`). The live nodes
(:mod:`terrain_estimation.ros.framework`,
:mod:`terrain_estimation.ros.simulator_node`) and the offline runner
(:mod:`terrain_estimation.tools.estimate`) drive the same adapter.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

__all__ = ["TopicSpec", "AdapterHealth", "EstimatorAdapter", "JudgedInputs", "SimulatorAdapter"]


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
        bounds: (field, largest magnitude, what sets it) for fields with a physical range (a load
            cell's reading beyond what the vehicle's weight can put on it is a glitch, not a force):
            a sample beyond it is rejected alone. Every field named here must also be in ``fields``.
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
    bounds: tuple[tuple[str, float, str], ...] = ()
    timeout: float = 0.0
    on_timeout: str = ""


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
