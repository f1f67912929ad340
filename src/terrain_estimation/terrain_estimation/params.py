"""Parameters: one specification serves the live node and the offline tools.

A :class:`ParamSpec` names a parameter, its default, unit, description and
valid range or choices. Nodes declare them with rclpy descriptors (so
``ros2 param describe`` shows the description and range) and validate every
update with them; offline tools validate the same values from the same YAML
file. Vehicle configs are ROS 2 parameter files::

    /**:
      ros__parameters:
        vehicle.sprung_mass: 455.0   # kg

This module imports no rclpy: the node layer turns specs into descriptors.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

__all__ = [
    "ParamSpec",
    "ParameterError",
    "config_dir",
    "default_config_path",
    "load_parameter_file",
    "resolve_parameters",
]

# A parameter value: bool, int, float, str or a list of floats or strings,
# validated against its ParamSpec (so consumers may convert it directly).
ParamValue = Any


class ParameterError(ValueError):
    """A parameter value that is missing, of the wrong type or out of range."""


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter.

    Attributes:
        name: dotted name, e.g. ``vehicle.sprung_mass``.
        default: default value; its Python type is the parameter's type.
        description: what it is, with the unit in brackets, e.g. ``"[kg] sprung mass"``.
        min_value, max_value: inclusive range for numbers (None: unbounded).
        choices: allowed values for strings.
        read_only: cannot change after the node starts.
    """

    name: str
    default: ParamValue
    description: str
    min_value: float | None = None
    max_value: float | None = None
    choices: tuple[str, ...] | None = None
    read_only: bool = False

    @property
    def kind(self) -> type:
        if isinstance(self.default, list):
            return list
        return type(self.default)

    def range_text(self) -> str:
        if self.choices:
            return "one of " + ", ".join(self.choices)
        lo = "-inf" if self.min_value is None else f"{self.min_value:g}"
        hi = "inf" if self.max_value is None else f"{self.max_value:g}"
        return f"[{lo}, {hi}]" if self.kind in (int, float, list) else ""

    def validate(self, value: Any) -> ParamValue:
        """Return ``value`` coerced to this parameter's type, or raise ParameterError.

        Ints are accepted for float parameters (YAML writes ``1000`` for 1000.0).
        Non-finite numbers are always rejected.
        """
        kind = self.kind
        if kind is bool:
            if not isinstance(value, bool):
                raise ParameterError(f"{self.name}: expected a bool, got {value!r}")
            return value
        if kind is str:
            if not isinstance(value, str):
                raise ParameterError(f"{self.name}: expected a string, got {value!r}")
            if self.choices and value not in self.choices:
                raise ParameterError(f"{self.name}: {value!r} is not {self.range_text()}")
            return value
        if kind is list:
            if not isinstance(value, (list, tuple)):
                raise ParameterError(f"{self.name}: expected a list, got {value!r}")
            default = self.default
            assert isinstance(default, list)
            if default and isinstance(default[0], str):
                return [str(v) for v in value]
            return [self._number(v, float) for v in value]
        return self._number(value, kind)

    def _number(self, value: Any, kind: type) -> Any:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(f"{self.name}: expected a number, got {value!r}")
        if kind is int and not float(value).is_integer():
            raise ParameterError(f"{self.name}: expected an integer, got {value!r}")
        number = kind(value)
        if not math.isfinite(float(number)):
            raise ParameterError(f"{self.name}: {value!r} is not finite")
        if (self.min_value is not None and number < self.min_value) or (
            self.max_value is not None and number > self.max_value
        ):
            raise ParameterError(f"{self.name}: {value!r} outside {self.range_text()}")
        return number


def config_dir() -> Path:
    """Directory of the vehicle configs: ``$TERRAIN_CONFIG_DIR`` or the repository's ``config/``."""
    env = os.environ.get("TERRAIN_CONFIG_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "config"


def default_config_path(vehicle: str) -> Path:
    return config_dir() / f"{vehicle}.yaml"


def load_parameter_file(path: str | os.PathLike[str], node_names: Iterable[str] = ()) -> dict[str, Any]:
    """Flat ``{dotted name: value}`` from a ROS 2 parameter YAML file.

    Sections ``/**`` apply to every node; a section named after one of
    ``node_names`` (with or without a leading ``/`` or namespace) is applied
    after it. Nested mappings under ``ros__parameters`` are flattened with dots,
    as rclpy does.

    Raises:
        ParameterError: the file is missing or not a ROS 2 parameter file.
    """
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except FileNotFoundError:
        raise ParameterError(f"parameter file {str(p)!r} does not exist") from None
    except yaml.YAMLError as exc:
        raise ParameterError(f"parameter file {str(p)!r} is not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ParameterError(f"parameter file {str(p)!r}: expected a mapping of node names")
    wanted = {n.strip("/").split("/")[-1] for n in node_names}
    sections: list[tuple[int, dict[str, Any]]] = []
    for key, body in data.items():
        if not isinstance(body, dict) or "ros__parameters" not in body:
            raise ParameterError(f"parameter file {str(p)!r}: section {key!r} has no ros__parameters")
        short = str(key).strip("/").split("/")[-1]
        if key in ("/**", "**"):
            sections.append((0, body["ros__parameters"] or {}))
        elif short in wanted:
            sections.append((1, body["ros__parameters"] or {}))
    values: dict[str, Any] = {}
    for _, params in sorted(sections, key=lambda s: s[0]):
        values.update(_flatten(params))
    return values


def _flatten(params: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def resolve_parameters(
    specs: Sequence[ParamSpec], overrides: Mapping[str, Any], *, strict: bool = False
) -> dict[str, ParamValue]:
    """Defaults of ``specs`` updated with validated ``overrides``.

    Args:
        strict: reject override names that no spec declares (a typo in a
            user's config is then an error, not silently ignored).
    """
    by_name = {s.name: s for s in specs}
    values: dict[str, ParamValue] = {s.name: s.default for s in specs}
    for name, value in overrides.items():
        spec = by_name.get(name)
        if spec is None:
            if strict:
                raise ParameterError(f"unknown parameter {name!r}")
            continue
        values[name] = spec.validate(value)
    return values
