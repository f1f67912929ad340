"""``python -m terrain_analysis.tools.config_template VEHICLE``: print a
documented parameter file for a vehicle, generated from the parameter specs.

``config/<vehicle>.yaml`` is this output (a test keeps them equal), so every
parameter the nodes declare is in the file with its description, unit and
range, and the file never names a parameter the nodes do not know.

Sections: ``/**`` holds the vehicle's physical parameters, read by the
estimator and the simulator alike; then one section per node, and
``/**/sim2real``: the tolerances of the uncertain nominal parameters that the
sim-to-real diagnosis fits as nuisance (:mod:`terrain_analysis.sim2real.tolerance`). Each node
refuses a ``/**`` name it does not declare (:mod:`terrain_estimation.params`),
so a parameter of one node only belongs in that node's section.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from terrain_analysis.sim2real.tolerance import SECTION as SIM2REAL_SECTION
from terrain_analysis.sim2real.tolerance import SPECS as SIM2REAL_SPECS
from terrain_estimation.params import ParamSpec
from terrain_estimation.ros.framework import EstimatorNode, SimulatorNode
from terrain_estimation.vehicles import VEHICLES, get_vehicle

__all__ = ["render_config", "main"]

HEADER = """\
# Parameters of the {name} ({title}), in ROS 2 parameter-file format.
# Generated from the nodes' parameter specs by
#   python -m terrain_analysis.tools.config_template {name}
# Copy and edit this file for your robot; units are in brackets, ranges
# are enforced (an out-of-range value is rejected with the reason).
#   estimator:  terrain-estimator-node --vehicle {name} [--config FILE]
#   simulator:  terrain-sim-node --vehicle {name} [--config FILE]
#   offline:    terrain-estimate BAG --vehicle {name} -o OUT [--config FILE]
"""

TITLES = {
    "quarter_car": "2-DOF quarter car on deformable soil",
    "lrv": "1-DOF Lunar Roving Vehicle wheel",
    "skid_steer": "6-wheel skid-steered vehicle, one motor per side",
    "rover": "Kapvik rocker-bogie rover, one side in the vertical plane",
}


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        # YAML 1.1 (PyYAML) reads "1e-05" as a string: the mantissa needs a dot.
        mantissa, e, exponent = repr(value).partition("e")
        if "." not in mantissa and "inf" not in mantissa and "nan" not in mantissa:
            mantissa += ".0"
        return mantissa + e + exponent
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list):
        return "[" + ", ".join(_yaml_value(v) for v in value) + "]"
    return str(value)


def _section(name: str, specs: Sequence[ParamSpec]) -> list[str]:
    lines = [f"{name}:", "  ros__parameters:"]
    groups: dict[str, list[ParamSpec]] = {}
    for spec in specs:
        head = spec.name.split(".")[0] if "." in spec.name else ""
        groups.setdefault(head, []).append(spec)
    for head, group in groups.items():
        indent = "    "
        if head:
            lines.append(f"    {head}:")
            indent = "      "
        for spec in group:
            rng = spec.range_text()
            note = spec.description + (f"; {rng}" if spec.choices else f"; range {rng}" if rng else "")
            if spec.read_only:
                note += "; fixed at start"
            lines.append(f"{indent}# {note}")
            key = spec.name.split(".", 1)[1] if head else spec.name
            lines.append(f"{indent}{key}: {_yaml_value(spec.default)}")
    return lines


def render_config(vehicle: str) -> str:
    """The documented parameter file of ``vehicle``."""
    from vehicle_sim.ros.registry import get_simulator

    entry = get_vehicle(vehicle)
    sim = get_simulator(vehicle)
    est_specs = tuple(EstimatorNode.COMMON_SPECS) + tuple(entry.specs)
    sim_specs = tuple(SimulatorNode.COMMON_SPECS) + tuple(sim.specs)
    shared = [s for s in entry.specs if s.name.startswith("vehicle.")]
    shared_names = {s.name for s in shared}
    lines = [HEADER.format(name=vehicle, title=TITLES.get(vehicle, vehicle))]
    lines += _section('"/**"', shared)
    lines.append("")
    lines.append(f"# the estimator node ({entry.node_name})")
    # "/**/name" matches the node under any namespace (a bare "name" only in "/").
    lines += _section(f'"/**/{entry.node_name}"', [s for s in est_specs if s.name not in shared_names])
    lines.append("")
    lines.append(f"# the simulator node ({sim.node_name}); also read by terrain-simulate")
    lines += _section(f'"/**/{sim.node_name}"', [s for s in sim_specs if s.name not in shared_names])
    tolerance_specs = SIM2REAL_SPECS.get(vehicle, ())
    if tolerance_specs:
        lines.append("")
        lines.append(
            "# the sim-to-real diagnosis (terrain-sim2real): tolerances of the uncertain nominal parameters "
            "(terrain_analysis.sim2real.tolerance)"
        )
        lines += _section(f'"/**/{SIM2REAL_SECTION}"', tolerance_specs)
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1 or args[0] not in VEHICLES:
        print(f"usage: config_template VEHICLE  ({', '.join(VEHICLES)})", file=sys.stderr)
        return 2
    sys.stdout.write(render_config(args[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
