"""Registry of the vehicles the estimator tools know.

Each entry names the vehicle's default namespace, its estimator node, its
parameter specs and the factory of its adapter
(:class:`~terrain_estimation.ros.registry.NodeEntry`). Modules are imported
on first use so that a command-line tool starts quickly and a vehicle whose
code is missing fails with a clear error, not at import time.
"""

from __future__ import annotations

from collections.abc import Sequence

from terrain_estimation.params import ParamSpec
from terrain_estimation.ros.registry import NodeEntry, lookup

__all__ = ["VehicleEntry", "VEHICLES", "get_vehicle", "estimator_parameters"]


class VehicleEntry(NodeEntry):
    """How to build one vehicle's estimator.

    Attributes:
        name: vehicle name, also the config file's stem (``config/<name>.yaml``).
        namespace: default namespace of its topics.
        node_name: the estimator node's name (its section in the config file).
        module: module providing ``specs_for(name)`` (ParamSpec tuple) and
            ``make_adapter(values, namespace)``.
    """

    def common_specs(self) -> Sequence[ParamSpec]:
        from terrain_estimation.ros.framework import EstimatorNode

        return EstimatorNode.COMMON_SPECS


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
    return lookup(VEHICLES, name)


#: ``estimator_parameters(vehicle, config=None, overrides=None, *, source="--param")``: validated
#: estimator parameters, the specs' defaults < config file < overrides (:meth:`NodeEntry.parameters
#: <terrain_estimation.ros.registry.NodeEntry.parameters>`, strict about unknown names).
estimator_parameters = VehicleEntry.parameters
