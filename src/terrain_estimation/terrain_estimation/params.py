"""Parameters: one specification serves the live node and the offline tools.

A :class:`ParamSpec` names a parameter, its default, unit, description and
valid range or choices. Nodes declare them with rclpy descriptors (so
``ros2 param describe`` shows the description and range) and validate every
update with them; offline tools validate the same values from the same YAML
file. Vehicle configs are ROS 2 parameter files::

    /**:
      ros__parameters:
        vehicle.sprung_mass: 455.0   # kg

Unknown names are errors wherever a name is resolved against specs (a
typo would otherwise leave the default in force): :func:`load_parameter_file`
with ``specs`` and :func:`resolve_parameters` with ``strict`` refuse them,
naming the source and the declared names closest to it. The ``/**`` section
applies to every node that reads the file (the estimator and the simulator of
a vehicle both read ``config/<vehicle>.yaml``), so a name there must be
declared by each of them: it holds the vehicle's physical parameters, and a
parameter of one node belongs in that node's ``/**/<node>`` section. rclpy's
own parameters (:data:`ROS_PARAMETERS`, e.g. ``use_sim_time``) are accepted
everywhere and ignored offline.

Parameter files and ``--param`` values are untrusted input with bounds: at
most :data:`MAX_FILE_BYTES` bytes, :data:`MAX_YAML_NODES` YAML nodes nested at
most :data:`MAX_YAML_DEPTH` deep, no anchors or aliases (a ROS 2 parameter
file has no use for them; nested aliases would expand a 1 kB file a billion
fold), and every error message quotes user input cut to :data:`MAX_QUOTE`
characters.

This module imports no rclpy: the node layer turns specs into descriptors.
"""

from __future__ import annotations

import difflib
import math
import os
import reprlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

__all__ = [
    "MAX_FILE_BYTES",
    "MAX_OVERRIDE_CHARS",
    "ROS_PARAMETERS",
    "ParamSpec",
    "ParameterError",
    "config_dir",
    "default_config_path",
    "load_parameter_file",
    "parse_override",
    "parse_value",
    "quote",
    "resolve_parameters",
    "unknown_parameter_error",
]

MAX_FILE_BYTES = 1_000_000
"""Largest parameter file read (the shipped ones are below 30 kB)."""
MAX_OVERRIDE_CHARS = 10_000
"""Longest ``--param`` value text."""
MAX_YAML_NODES = 20_000
"""Most scalars, lists and mappings in one file or value (the rover's config has 470)."""
MAX_YAML_DEPTH = 32
"""Deepest nesting of lists and mappings."""
MAX_QUOTE = 200
"""Longest quotation of user input in an error message."""
ROS_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})
"""Parameters every rclpy node declares itself: valid in any file, not the specs' business."""

# A parameter value: bool, int, float, str or a list of floats or strings,
# validated against its ParamSpec (so consumers may convert it directly).
ParamValue = Any


class ParameterError(ValueError):
    """A parameter that is unknown, missing, of the wrong type or out of range, or an unusable file."""


class _Repr(reprlib.Repr):
    def repr_int(self, x: int, level: int) -> str:
        try:
            return super().repr_int(x, level)
        except ValueError:  # beyond sys.get_int_max_str_digits()
            return f"<an integer of {x.bit_length()} bits>"


_REPR = _Repr()
_REPR.maxstring = _REPR.maxother = _REPR.maxlong = MAX_QUOTE
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = 8
_REPR.maxlevel = 3


def quote(value: Any, limit: int = MAX_QUOTE) -> str:
    """``repr(value)`` of at most ``limit`` characters, cut with ``...`` (bounded work for a huge value)."""
    return _cut(_REPR.repr(value), limit)


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
                raise ParameterError(f"{self.name}: expected a bool, got {quote(value)}")
            return value
        if kind is str:
            if not isinstance(value, str):
                raise ParameterError(f"{self.name}: expected a string, got {quote(value)}")
            if self.choices and value not in self.choices:
                raise ParameterError(f"{self.name}: {quote(value)} is not {self.range_text()}")
            return value
        if kind is list:
            if not isinstance(value, (list, tuple)):
                raise ParameterError(f"{self.name}: expected a list, got {quote(value)}")
            default = self.default
            assert isinstance(default, list)
            if default and isinstance(default[0], str):
                return [str(v) for v in value]
            return [self._number(v, float) for v in value]
        return self._number(value, kind)

    def _number(self, value: Any, kind: type) -> Any:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParameterError(f"{self.name}: expected a number, got {quote(value)}")
        try:
            as_float = float(value)
        except OverflowError:  # an int beyond the floats
            raise ParameterError(f"{self.name}: {quote(value)} outside {self.range_text()}") from None
        if kind is int and not as_float.is_integer():
            raise ParameterError(f"{self.name}: expected an integer, got {quote(value)}")
        number = kind(value)
        if not math.isfinite(as_float):
            raise ParameterError(f"{self.name}: {quote(value)} is not finite")
        if (self.min_value is not None and number < self.min_value) or (
            self.max_value is not None and number > self.max_value
        ):
            raise ParameterError(f"{self.name}: {quote(value)} outside {self.range_text()}")
        return number


def config_dir() -> Path:
    """Directory of the vehicle configs: ``$TERRAIN_CONFIG_DIR`` or the repository's ``config/``."""
    env = os.environ.get("TERRAIN_CONFIG_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "config"


def default_config_path(vehicle: str) -> Path:
    return config_dir() / f"{vehicle}.yaml"


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader without anchors and aliases, with at most MAX_YAML_NODES nodes MAX_YAML_DEPTH deep."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._nodes = 0
        self._depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        problem = None
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
            problem = "YAML anchors and aliases (&name, *name) are not accepted in parameters"
        elif self._nodes >= MAX_YAML_NODES:
            problem = f"more than {MAX_YAML_NODES} values"
        elif self._depth >= MAX_YAML_DEPTH:
            problem = f"nested more than {MAX_YAML_DEPTH} levels deep"
        if problem:
            raise yaml.MarkedYAMLError(problem=problem, problem_mark=event.start_mark)
        self._nodes += 1
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _cut(text: str, limit: int = MAX_QUOTE) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _load_yaml(text: str, where: str) -> Any:
    """``text`` parsed by :class:`_BoundedLoader`; a ParameterError naming ``where`` and the line if unusable."""
    loader = _BoundedLoader(text)
    try:
        return loader.get_single_data()
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        at = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        what = "; ".join(str(t) for t in (exc.context, exc.problem) if t)
        raise ParameterError(f"{where}: {at}{_cut(what)}") from None
    except yaml.YAMLError as exc:
        raise ParameterError(f"{where}: not valid YAML: {_cut(str(exc))}") from None
    finally:
        loader.dispose()


def parse_value(text: str, source: str = "--param") -> ParamValue:
    """A parameter value written as YAML (``3``, ``ekf``, ``[1.0, 2.0]``), bounded as a parameter file is.

    Raises:
        ParameterError: longer than MAX_OVERRIDE_CHARS, anchors or aliases, or not YAML (message names ``source``).
    """
    if len(text) > MAX_OVERRIDE_CHARS:
        raise ParameterError(f"{source}: a value of {len(text)} characters (at most {MAX_OVERRIDE_CHARS})")
    return _load_yaml(text, source)


def parse_override(item: str) -> tuple[str, ParamValue]:
    """``(name, value)`` of a command line's ``--param NAME=VALUE`` (the value by :func:`parse_value`).

    The name is not checked here: :func:`resolve_parameters` (``strict``) does so against the specs.
    """
    name, sep, text = item.partition("=")
    name = name.strip()
    if not sep or not name:
        raise ParameterError(f"--param {quote(item)}: expected NAME=VALUE")
    return name, parse_value(text, f"--param {quote(name)}")


def unknown_parameter_error(name: object, known: Iterable[str], source: str, hint: str = "") -> ParameterError:
    """The error for ``name``, declared by no spec: ``source``, the closest of the ``known`` names
    (difflib's, and those of the same last component: ``seed`` for ``scenario.seed``) and, when few,
    the other names under its prefix (``filter.typ``: ``filter.*``)."""
    names = sorted(set(known))
    text = str(name)
    message = f"unknown parameter {quote(text)} in {source}"
    if len(text) <= MAX_QUOTE:
        close = difflib.get_close_matches(text, names, 3, 0.8) or difflib.get_close_matches(text, names, 3, 0.6)
        prefix, dot, leaf = text.rpartition(".")
        close += [n for n in names if n.rpartition(".")[2] == leaf and n not in close][:3]
        if close:
            message += "; did you mean " + " or ".join(close) + "?"
        family = [n for n in names if dot and n.startswith(prefix + ".") and n not in close]
        if 0 < len(family) <= 8:
            message += f"; {'other ' if close else ''}parameters under {prefix}.: " + ", ".join(family)
        elif family:
            message += f" ({len(family)} {'other ' if close else ''}parameters under {prefix}.)"
    return ParameterError(message + hint)


def load_parameter_file(
    path: str | os.PathLike[str], node_names: Iterable[str] = (), *, specs: Sequence[ParamSpec] | None = None
) -> dict[str, Any]:
    """Flat ``{dotted name: value}`` from a ROS 2 parameter YAML file.

    Sections ``/**`` apply to every node; a section named after one of
    ``node_names`` (with or without a leading ``/`` or namespace) is applied
    after it. Nested mappings under ``ros__parameters`` are flattened with dots,
    as rclpy does. Files over MAX_FILE_BYTES, with anchors or aliases, or
    beyond MAX_YAML_NODES / MAX_YAML_DEPTH are refused.

    Args:
        specs: the reading node's specs. Given, every name of the sections
            read (``/**`` included) must be one of them (or of
            :data:`ROS_PARAMETERS`) with a valid value: the error names the
            file, the section and the closest declared names.

    Raises:
        ParameterError: the file is missing, too large or not a ROS 2 parameter
            file, or (``specs``) holds an unknown name or an invalid value.
    """
    p = Path(path)
    where = f"parameter file {quote(str(p))}"
    try:
        with p.open("rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise ParameterError(f"{where} does not exist") from None
    except OSError as exc:
        raise ParameterError(f"{where} cannot be read: {_cut(exc.strerror or type(exc).__name__)}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ParameterError(f"{where} is larger than {MAX_FILE_BYTES} bytes: not a parameter file")
    try:
        data = _load_yaml(raw.decode("utf-8"), where)
    except UnicodeDecodeError as exc:
        raise ParameterError(f"{where}: not UTF-8 text (byte {exc.start})") from None
    if not isinstance(data, dict):
        raise ParameterError(f"{where}: expected a mapping of node names")
    wanted = {n.strip("/").split("/")[-1] for n in node_names}
    sections: list[tuple[int, str, dict[str, Any]]] = []
    for key, body in data.items():
        section = f"{where}, section {quote(key)}"
        if not isinstance(body, dict) or "ros__parameters" not in body:
            raise ParameterError(f"{section} has no ros__parameters")
        params = body["ros__parameters"] or {}
        if not isinstance(params, dict):
            raise ParameterError(f"{section}: ros__parameters is not a mapping")
        if key in ("/**", "**"):
            sections.append((0, section, _flatten(params)))
        elif str(key).strip("/").split("/")[-1] in wanted:
            sections.append((1, section, _flatten(params)))
    declared = {s.name for s in specs or ()}
    values: dict[str, Any] = {}
    for rank, section, params in sorted(sections, key=lambda s: s[0]):
        if specs is not None:
            for name in params:
                if name not in declared and name not in ROS_PARAMETERS:
                    raise unknown_parameter_error(name, declared, section, "" if rank else _SHARED_HINT)
            resolve_parameters(specs, params, source=section)
        values.update(params)
    return values


_SHARED_HINT = (
    " (the '/**' section applies to every node that reads the file: a parameter of one node belongs in"
    " that node's section)"
)


def _flatten(params: Mapping[Any, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def resolve_parameters(
    specs: Sequence[ParamSpec], overrides: Mapping[str, Any], *, strict: bool = False, source: str = "overrides"
) -> dict[str, ParamValue]:
    """Defaults of ``specs`` updated with validated ``overrides``.

    Names of :data:`ROS_PARAMETERS` are ignored (rclpy's business).

    Args:
        strict: reject override names that no spec declares (a typo in a
            user's config is then an error, not silently ignored).
        source: where ``overrides`` come from (``--param``, a file's section), for the error messages.
    """
    by_name = {s.name: s for s in specs}
    values: dict[str, ParamValue] = {s.name: s.default for s in specs}
    for name, value in overrides.items():
        spec = by_name.get(name)
        if spec is None:
            if strict and name not in ROS_PARAMETERS:
                raise unknown_parameter_error(name, by_name, source)
            continue
        try:
            values[name] = spec.validate(value)
        except ParameterError as exc:
            raise ParameterError(f"{source}: {exc}") from None
    return values
