"""Registries of nodes by vehicle: an entry names a vehicle's node and the module of its adapter.

The estimators' registry is :data:`terrain_estimation.vehicles.VEHICLES`, the
simulators' ``vehicle_sim.ros.registry.SIMULATORS``; both hold
:class:`NodeEntry` values, look a vehicle up with :func:`lookup` and resolve
a node's parameters with :meth:`NodeEntry.parameters`. The adapter modules are
imported on first use, so that a command-line tool starts quickly and a
vehicle whose code is missing fails with a clear error, not at import time
(this module imports no ROS package).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from terrain_estimation.params import (
    ParamSpec,
    ParamValue,
    default_config_path,
    load_parameter_file,
    resolve_parameters,
)

__all__ = ["NodeEntry", "lookup"]


@dataclass(frozen=True)
class NodeEntry:
    """How to build one vehicle's node.

    Attributes:
        name: vehicle name, also the config file's stem (``config/<name>.yaml``).
        namespace: default namespace of its topics.
        node_name: the node's name (its section in the config file).
        module: module providing ``specs_for(name)`` (ParamSpec tuple) and
            ``make_adapter(values, namespace)``.
    """

    name: str
    namespace: str
    node_name: str
    module: str

    def _load(self) -> Any:
        return importlib.import_module(self.module)

    @property
    def specs(self) -> Sequence[ParamSpec]:
        return tuple(self._load().specs_for(self.name))

    @property
    def make_adapter(self) -> Callable[[Mapping[str, ParamValue], str], Any]:
        return self._load().make_adapter

    def config_path(self) -> Path:
        return default_config_path(self.name)

    def common_specs(self) -> Sequence[ParamSpec]:
        """The specs the node's class declares besides the vehicle's (its ``COMMON_SPECS``)."""
        return ()

    def parameters(
        self,
        config: str | Path | None = None,
        overrides: Mapping[str, Any] | None = None,
        *,
        source: str = "--param",
    ) -> dict[str, ParamValue]:
        """Validated parameters of the node: the specs' defaults < config file < overrides.

        The same resolution the live node gets from ``--params-file``. Strict: a
        name the node does not declare, in the file (``/**`` included: see
        :mod:`terrain_estimation.params`) or in ``overrides`` (called ``source`` in
        the error), is a ParameterError naming the closest declared names.
        """
        specs = tuple(self.common_specs()) + tuple(self.specs)
        path = Path(config) if config is not None else self.config_path()
        values = load_parameter_file(path, [self.node_name], specs=specs) if path.exists() or config else {}
        values.update(overrides or {})
        return resolve_parameters(specs, values, strict=True, source=source)


E = TypeVar("E")


def lookup(registry: Mapping[str, E], name: str) -> E:
    """The entry of vehicle ``name``.

    Raises:
        ValueError: no such vehicle (the message lists the known ones).
    """
    try:
        return registry[name]
    except KeyError:
        raise ValueError(f"unknown vehicle {name!r}: expected one of {', '.join(registry)}") from None
