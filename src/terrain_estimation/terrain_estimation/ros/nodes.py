"""Executable of the estimator nodes: ``terrain-estimator-node --vehicle V``.

Loads ``config/<vehicle>.yaml`` (or ``--config``) as parameter overrides,
under the vehicle's default namespace unless ``--ros-args -r __ns:=/x`` says
otherwise; any ``--ros-args`` (``-p name:=value``, ``--params-file``) apply on
top, as for every ROS 2 node.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import rclpy
from rclpy.parameter import Parameter

from terrain_estimation.params import ParameterError, load_parameter_file
from terrain_estimation.ros.framework import EstimatorNode, spin_node
from terrain_estimation.vehicles import VEHICLES, get_vehicle

__all__ = ["make_estimator_node", "main"]


def make_estimator_node(
    vehicle: str,
    *,
    namespace: str | None = None,
    config: str | None = None,
    overrides: dict[str, object] | None = None,
    use_config: bool = True,
    **node_kwargs: object,
) -> EstimatorNode:
    """Build the estimator node of ``vehicle`` in-process.

    With ``use_config`` the config file (default ``config/<vehicle>.yaml``) and
    then ``overrides`` become the node's parameter overrides (they win over the
    command line; the executable passes the file to rcl instead).
    """
    entry = get_vehicle(vehicle)
    path = config or entry.config_path()
    values = {}
    if use_config and (config or entry.config_path().exists()):
        values = load_parameter_file(path, [entry.node_name])
    values.update(overrides or {})
    params = [Parameter(name, value=value) for name, value in values.items()]
    return EstimatorNode(
        entry.node_name,
        entry.specs,
        entry.make_adapter,
        namespace=namespace if namespace is not None else entry.namespace,
        parameter_overrides=params,
        **node_kwargs,
    )


def main(argv: Sequence[str] | None = None) -> int:
    args_in = list(sys.argv[1:] if argv is None else argv)
    ros_args = args_in[args_in.index("--ros-args") :] if "--ros-args" in args_in else []
    own = args_in[: len(args_in) - len(ros_args)]
    parser = argparse.ArgumentParser(prog="terrain-estimator-node", description=__doc__.splitlines()[0])
    parser.add_argument("--vehicle", required=True, choices=sorted(VEHICLES))
    parser.add_argument("--config", help="parameter file (default: config/<vehicle>.yaml)")
    args = parser.parse_args(own)
    config = args.config or str(get_vehicle(args.vehicle).config_path())
    # The config file goes to rcl first: the user's own --ros-args (-p name:=value,
    # --params-file) come later and win. (Node parameter_overrides would win
    # over the command line, so the file is not passed that way here.)
    rcl_args = ["--ros-args", "--params-file", config] if Path(config).exists() else []
    rclpy.init(args=["terrain-estimator-node", *rcl_args, *ros_args])
    try:
        node = make_estimator_node(args.vehicle, config=None, use_config=False)
    except (ParameterError, ValueError) as exc:
        print(f"terrain-estimator-node: error: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    spin_node(node)
    return 0


if __name__ == "__main__":
    sys.exit(main())
