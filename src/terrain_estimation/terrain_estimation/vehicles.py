"""Registry of the vehicles the estimator tools know.

Each entry names the vehicle's default namespace, its estimator node, its
parameter specs and the factory of its adapter. Modules are imported on first
use so that a command-line tool starts quickly and a vehicle whose code is
missing fails with a clear error, not at import time.
"""

from __future__ import annotations

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

__all__ = ["VehicleEntry", "VEHICLES", "get_vehicle", "estimator_parameters"]


@dataclass(frozen=True)
class VehicleEntry:
    """How to build one vehicle's estimator.

    Attributes:
        name: vehicle name, also the config file's stem (``config/<name>.yaml``).
        namespace: default namespace of its topics.
        node_name: the estimator node's name (its section in the config file).
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


VEHICLES: dict[str, VehicleEntry] = {
    "quarter_car": VehicleEntry(
        "quarter_car", "/quarter_car", "soil_stiffness", "terrain_estimation.ros.soil_stiffness"
    ),
    "lrv": VehicleEntry("lrv", "/lrv", "soil_stiffness", "terrain_estimation.ros.soil_stiffness"),
    "skid_steer": VehicleEntry(
        "skid_steer", "/skid_steer", "skid_steer_estimator", "terrain_estimation.ros.skid_steer"
    ),
    "rover": VehicleEntry("rover", "/rover", "rover_terrain_estimator", "terrain_estimation.ros.rover"),
}


def get_vehicle(name: str) -> VehicleEntry:
    try:
        return VEHICLES[name]
    except KeyError:
        raise ValueError(f"unknown vehicle {name!r}: expected one of {', '.join(VEHICLES)}") from None


def estimator_parameters(
    vehicle: VehicleEntry,
    config: str | Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    *,
    source: str = "--param",
) -> dict[str, ParamValue]:
    """Validated estimator parameters: specs' defaults < config file < overrides.

    The same resolution the live node gets from ``--params-file``. Strict: a
    name the estimator does not declare, in the file (``/**`` included: see
    :mod:`terrain_estimation.params`) or in ``overrides`` (called ``source`` in
    the error), is a ParameterError naming the closest declared names.
    """
    from terrain_estimation.ros.framework import EstimatorNode

    specs = tuple(EstimatorNode.COMMON_SPECS) + tuple(vehicle.specs)
    path = Path(config) if config is not None else vehicle.config_path()
    values = load_parameter_file(path, [vehicle.node_name], specs=specs) if path.exists() or config else {}
    values.update(overrides or {})
    return resolve_parameters(specs, values, strict=True, source=source)
