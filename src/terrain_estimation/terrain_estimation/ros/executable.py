"""What the estimator and simulator executables share: building a node from a
registry entry and the ``main`` that parses ``--vehicle``/``--config`` and
hands the config file to rcl.

Parameter precedence: in-process (:func:`build_node`) the config file and then
``overrides`` become the node's ``parameter_overrides``, which win over the
command line. The executables (:func:`node_main`) instead pass the config file
to rcl as the first ``--params-file``, so the user's own ``--ros-args`` come
later. Note that rcl ranks a node-specific file entry (the config's
``/**/<node>`` section) above a global ``-p name:=value``: override such a
parameter with ``--config`` or a later ``--params-file``.

Unknown names are refused (rcl would ignore them): both check the config file
against the node's specs (its ``/**`` section and the node's own; see
:mod:`terrain_estimation.params`) and :func:`build_node` the names of
``overrides``. A user's further ``--ros-args`` parameters are rcl's to apply.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol, TypeVar

import rclpy
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from terrain_estimation.config_sections import node_file_values
from terrain_estimation.params import (
    ROS_PARAMETERS,
    ParameterError,
    ParamSpec,
    unknown_parameter_error,
)
from terrain_estimation.ros.framework import spin_node

__all__ = ["RegistryEntry", "build_node", "node_main"]

N = TypeVar("N", bound=Node)


class RegistryEntry(Protocol):
    """A vehicle's estimator or simulator entry (terrain_estimation.vehicles, vehicle_sim.ros.registry)."""

    @property
    def name(self) -> str: ...

    @property
    def namespace(self) -> str: ...

    @property
    def node_name(self) -> str: ...

    @property
    def specs(self) -> Sequence[ParamSpec]: ...

    @property
    def make_adapter(self) -> Callable[[Mapping[str, Any], str], Any]: ...

    def config_path(self) -> Path: ...


def _node_specs(node_class: Callable[..., Node], entry: RegistryEntry) -> tuple[ParamSpec, ...]:
    """All the specs the node declares: its class's COMMON_SPECS and the entry's."""
    return tuple(getattr(node_class, "COMMON_SPECS", ())) + tuple(entry.specs)


def build_node(
    node_class: Callable[..., N],
    entry: RegistryEntry,
    *,
    namespace: str | None = None,
    config: str | None = None,
    overrides: Mapping[str, object] | None = None,
    use_config: bool = True,
    **node_kwargs: Any,
) -> N:
    """Build ``node_class`` (EstimatorNode or SimulatorNode) for ``entry`` in-process.

    Raises:
        ParameterError: the config file has a name or value the node does not
            accept, or ``overrides`` a name it does not declare.
    """
    specs = _node_specs(node_class, entry)
    values: dict[str, object] = {}
    if use_config and (config or entry.config_path().exists()):
        values = node_file_values(config or entry.config_path(), entry.node_name, specs)
    declared = {s.name for s in specs}
    for name in overrides or {}:
        if name not in declared and name not in ROS_PARAMETERS:
            raise unknown_parameter_error(name, declared, "overrides")
    values.update(overrides or {})
    return node_class(
        entry.node_name,
        entry.specs,
        entry.make_adapter,
        namespace=namespace if namespace is not None else entry.namespace,
        parameter_overrides=[Parameter(name, value=value) for name, value in values.items()],
        **node_kwargs,
    )


def node_main(
    prog: str,
    description: str,
    registry: Mapping[str, RegistryEntry],
    node_class: Callable[..., Node],
    argv: Sequence[str] | None = None,
) -> int:
    """``PROG --vehicle V [--config FILE] [--ros-args ...]``: run one node until Ctrl-C (or its end)."""
    args_in = list(sys.argv[1:] if argv is None else argv)
    ros_args = args_in[args_in.index("--ros-args") :] if "--ros-args" in args_in else []
    own = args_in[: len(args_in) - len(ros_args)]
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("--vehicle", required=True, choices=sorted(registry))
    parser.add_argument("--config", help="parameter file (default: config/<vehicle>.yaml)")
    args = parser.parse_args(own)
    entry = registry[args.vehicle]
    config = args.config or (str(entry.config_path()) if entry.config_path().exists() else None)
    if config is not None:
        try:
            node_file_values(config, entry.node_name, _node_specs(node_class, entry))
        except ParameterError as exc:
            print(f"{prog}: error: {exc}", file=sys.stderr)
            return 2
    rcl_args = ["--ros-args", "--params-file", config] if config is not None else []
    rclpy.init(args=[prog, *rcl_args, *ros_args])
    try:
        node = build_node(node_class, entry, use_config=False)
    except (ParameterError, InvalidParameterValueException, ValueError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    spin_node(node)
    return 0
