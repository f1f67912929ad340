"""Registry of the simulators: name → node name, namespace, specs, adapter."""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from terrain_estimation.params import (
    ParamSpec,
    ParamValue,
    default_config_path,
    load_parameter_file,
    resolve_parameters,
)

__all__ = ["SimulatorEntry", "SIMULATORS", "get_simulator", "simulator_parameters"]


@dataclass(frozen=True)
class SimulatorEntry:
    """How to build one vehicle's simulator.

    Attributes:
        name: vehicle name (``config/<name>.yaml``).
        namespace: default namespace.
        node_name: the simulator node's name (its section of the config file).
        module: module with ``specs_for(kind)`` and ``make_adapter(values, ns, kind)``.
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
        return functools.partial(self._load().make_adapter, kind=self.name)

    def config_path(self) -> Path:
        return default_config_path(self.name)


SIMULATORS: dict[str, SimulatorEntry] = {
    "quarter_car": SimulatorEntry("quarter_car", "/quarter_car", "quarter_car_sim", "vehicle_sim.ros.quarter_car"),
    "lrv": SimulatorEntry("lrv", "/lrv", "quarter_car_sim", "vehicle_sim.ros.quarter_car"),
    "skid_steer": SimulatorEntry("skid_steer", "/skid_steer", "skid_steer_sim", "vehicle_sim.ros.skid_steer"),
    "rover": SimulatorEntry("rover", "/rover", "rover_sim", "vehicle_sim.ros.rover"),
}


def get_simulator(name: str) -> SimulatorEntry:
    try:
        return SIMULATORS[name]
    except KeyError:
        raise ValueError(f"unknown vehicle {name!r}: expected one of {', '.join(SIMULATORS)}") from None


def simulator_parameters(
    entry: SimulatorEntry,
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    *,
    source: str = "--param",
) -> dict[str, ParamValue]:
    """Validated simulator parameters: defaults < config file < overrides.

    Strict, as :func:`terrain_estimation.vehicles.estimator_parameters`: a name
    the simulator does not declare, in the file (``/**`` included) or in
    ``overrides`` (called ``source`` in the error), is a ParameterError.
    """
    from terrain_estimation.ros.framework import SimulatorNode

    specs = tuple(SimulatorNode.COMMON_SPECS) + tuple(entry.specs)
    path = Path(config) if config is not None else entry.config_path()
    values = load_parameter_file(path, [entry.node_name], specs=specs) if path.exists() or config else {}
    values.update(overrides or {})
    return resolve_parameters(specs, values, strict=True, source=source)
