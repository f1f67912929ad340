"""Executable of the estimator nodes: ``terrain-estimator-node --vehicle V``.

Runs the vehicle's estimator under its default namespace (``--ros-args -r
__ns:=/x`` to change it) with ``config/<vehicle>.yaml`` (or ``--config``) as
the first parameter file; see :mod:`terrain_estimation.ros.executable` for how
command-line parameters combine with it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from terrain_estimation.ros.executable import build_node, node_main
from terrain_estimation.ros.framework import EstimatorNode
from terrain_estimation.vehicles import VEHICLES, get_vehicle

__all__ = ["make_estimator_node", "main"]


def make_estimator_node(vehicle: str, **kwargs: Any) -> EstimatorNode:
    """The estimator node of ``vehicle``, in-process (arguments of :func:`build_node`)."""
    return build_node(EstimatorNode, get_vehicle(vehicle), **kwargs)


def main(argv: Sequence[str] | None = None) -> int:
    return node_main("terrain-estimator-node", __doc__.splitlines()[0], VEHICLES, EstimatorNode, argv)


if __name__ == "__main__":
    sys.exit(main())
