"""Registry of the simulators: name → node name, namespace, specs, adapter."""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from terrain_estimation.params import ParamSpec, ParamValue
from terrain_estimation.ros.registry import NodeEntry, lookup

__all__ = ["SimulatorEntry", "SIMULATORS", "get_simulator", "simulator_parameters"]


class SimulatorEntry(NodeEntry):
    """How to build one vehicle's simulator.

    Attributes:
        name: vehicle name (``config/<name>.yaml``).
        namespace: default namespace.
        node_name: the simulator node's name (its section of the config file).
        module: module with ``specs_for(kind)`` and ``make_adapter(values, ns, kind)``.
    """

    @property
    def make_adapter(self) -> Callable[[Mapping[str, ParamValue], str], Any]:
        return functools.partial(self._load().make_adapter, kind=self.name)

    def common_specs(self) -> Sequence[ParamSpec]:
        from terrain_estimation.ros.simulator_node import SimulatorNode

        return SimulatorNode.COMMON_SPECS


SIMULATORS: dict[str, SimulatorEntry] = {
    "quarter_car": SimulatorEntry("quarter_car", "/quarter_car", "quarter_car_sim", "vehicle_sim.ros.quarter_car"),
    "lrv": SimulatorEntry("lrv", "/lrv", "quarter_car_sim", "vehicle_sim.ros.quarter_car"),
    "skid_steer": SimulatorEntry("skid_steer", "/skid_steer", "skid_steer_sim", "vehicle_sim.ros.skid_steer"),
    "rover": SimulatorEntry("rover", "/rover", "rover_sim", "vehicle_sim.ros.rover"),
}


def get_simulator(name: str) -> SimulatorEntry:
    return lookup(SIMULATORS, name)


#: ``simulator_parameters(entry, config=None, overrides=None, *, source="--param")``: validated simulator
#: parameters, defaults < config file < overrides, strict as the estimators' (:meth:`NodeEntry.parameters
#: <terrain_estimation.ros.registry.NodeEntry.parameters>`).
simulator_parameters = SimulatorEntry.parameters
