"""Executable of the simulator nodes: ``terrain-sim-node --vehicle V``.

Publishes ``/clock`` and the vehicle's sensor and ``ground_truth/*`` topics at
the contract rates, with ``config/<vehicle>.yaml`` (or ``--config``) as the
first parameter file; see :mod:`terrain_estimation.ros.executable` for how
command-line parameters combine with it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from terrain_estimation.ros.executable import build_node, node_main
from terrain_estimation.ros.simulator_node import SimulatorNode
from vehicle_sim.ros.registry import SIMULATORS, get_simulator

__all__ = ["make_simulator_node", "main"]


def make_simulator_node(vehicle: str, **kwargs: Any) -> SimulatorNode:
    """The simulator node of ``vehicle``, in-process (arguments of :func:`build_node`)."""
    return build_node(SimulatorNode, get_simulator(vehicle), **kwargs)


def main(argv: Sequence[str] | None = None) -> int:
    return node_main("terrain-sim-node", __doc__.splitlines()[0], SIMULATORS, SimulatorNode, argv)


if __name__ == "__main__":
    sys.exit(main())
