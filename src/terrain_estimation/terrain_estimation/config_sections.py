"""A parameter file's values for one node, as rcl applies the file to it (issue 20 item 5).

:func:`~terrain_estimation.params.load_parameter_file` with ``specs`` holds the
``/**`` section to the reading node's names: ``/**`` applies to every node, so
a name there that the node does not declare is a typo or belongs in another
section. One kind of file is different: a file that describes *another model
of the vehicle* in ``/**`` and the node's own view in the node's section.
``config/husky.yaml`` is one: its ``/**`` section is the 4-wheel Husky of the
sim-to-real replay and the BorealTC importer (``vehicle.kind: husky``,
``vehicle.wheelbase``, relaxation lengths, sensor rates), its
``/**/skid_steer_estimator`` section the skid-steer estimator's view (two
axles, the BorealTC IMU's noise).

:func:`node_file_values` reads such a file (``/**`` sets ``vehicle.kind`` to
another kind than the node's, and the file has a section for the node) as rcl
applies it to the live node: the ``/**`` names the node declares, with valid
values, then the node's own section over them, checked strictly (an unknown
name there is still an error naming the closest declared ones); the other
``/**`` names are the other readers'. Any other file is read strictly, as
before.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from terrain_estimation.params import ParamSpec, load_parameter_file, resolve_parameters

__all__ = ["node_file_values", "describes_another_kind"]


def describes_another_kind(path: str | os.PathLike[str], node_name: str, specs: Sequence[ParamSpec]) -> bool:
    """Whether the file's ``/**`` section sets ``vehicle.kind`` to another kind than the node's and the file
    has a section for ``node_name`` (module docstring).

    Raises:
        ParameterError: the file is missing or not a parameter file.
    """
    kind = next((s.default for s in specs if s.name == "vehicle.kind"), None)
    shared = load_parameter_file(path)
    if kind is None or shared.get("vehicle.kind", kind) == kind:
        return False
    return load_parameter_file(path, [node_name]) != shared


def node_file_values(path: str | os.PathLike[str], node_name: str, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """The values the file gives the node ``node_name`` declaring ``specs``.

    :func:`~terrain_estimation.params.load_parameter_file` (strict), except for a file whose ``/**`` section
    describes another vehicle kind: then its declared ``/**`` names and the node's section over them (module
    docstring).

    Raises:
        ParameterError: the file is missing or not a parameter file, or holds an unknown name or an invalid
            value (in the node's section; in ``/**`` for any other file).
    """
    if not describes_another_kind(path, node_name, specs):
        return load_parameter_file(path, [node_name], specs=specs)
    shared = load_parameter_file(path)
    merged = load_parameter_file(path, [node_name])
    declared = {s.name for s in specs}
    # The node's section: the names it sets (where a value equals the '/**' one the result is the same).
    own = {k: v for k, v in merged.items() if k not in shared or shared[k] != v or k == "vehicle.kind"}
    base = {k: v for k, v in shared.items() if k in declared and k not in own}
    where = f"parameter file {str(Path(path))!r}, section"
    resolve_parameters(specs, base, source=f"{where} '/**'")  # valid values (the names are declared)
    resolve_parameters(specs, own, strict=True, source=f"{where} '{node_name}'")
    return {**base, **own}
