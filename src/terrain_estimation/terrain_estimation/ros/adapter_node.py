"""What the estimator and simulator nodes share: parameters, the adapter built from them, its publishers.

:class:`AdapterNode` declares the node's parameters (its class's
``COMMON_SPECS`` and the vehicle's specs), builds the vehicle's adapter from
their validated values and the node's namespace, creates a publisher for each
of the adapter's outputs with the contract's QoS, and refuses a parameter
update that is out of range or read-only. A subclass adds the rest in
:meth:`AdapterNode._start` (:class:`~terrain_estimation.ros.framework.EstimatorNode`,
:class:`~terrain_estimation.ros.simulator_node.SimulatorNode`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, Generic, Protocol, TypeVar

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from terrain_estimation.params import ParameterError, ParamSpec, ParamValue
from terrain_estimation.ros.adapters import TopicSpec
from terrain_estimation.ros.parameters import declare_specs
from terrain_estimation.ros.qos import qos_for

__all__ = ["AdapterNode"]


class _Publishing(Protocol):
    """An adapter with outputs (every estimator and simulator adapter)."""

    @property
    def outputs(self) -> Sequence[TopicSpec]: ...


A = TypeVar("A", bound=_Publishing)


class AdapterNode(Node, Generic[A]):
    """A node around one vehicle's adapter.

    Args:
        node_name: e.g. ``"soil_stiffness"``.
        specs: the vehicle's parameter specs (declared with the class's ``COMMON_SPECS``).
        make_adapter: builds the adapter from validated parameter values and
            the node's namespace.
        namespace: vehicle namespace (``"/quarter_car"``).
        parameter_overrides: values that win over the defaults (tests, tools).
    """

    COMMON_SPECS: tuple[ParamSpec, ...] = ()

    def __init__(
        self,
        node_name: str,
        specs: Sequence[ParamSpec],
        make_adapter: Callable[[Mapping[str, ParamValue], str], A],
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
        self._output_publishers = {
            o.key: self.create_publisher(o.msg_type, o.topic, qos_for(o.kind)) for o in self.adapter.outputs
        }
        self._start()
        self.add_on_set_parameters_callback(self._on_set)

    def _start(self) -> None:
        """The subclass's own subscriptions, publishers and timers (the adapter and its publishers exist)."""

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        """Validate a parameter update with the specs (rclpy's own parameters pass)."""
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
