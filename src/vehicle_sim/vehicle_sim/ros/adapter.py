"""What the simulator adapters share: frame names, the step that turns a plant sample into messages, the kind check.

Each vehicle's adapter (:mod:`vehicle_sim.ros.quarter_car`,
:mod:`~vehicle_sim.ros.skid_steer`, :mod:`~vehicle_sim.ros.rover`) builds its
plant from validated parameters and defines ``messages(sample)``; the
simulator node (:class:`terrain_estimation.ros.framework.SimulatorNode`) and
``terrain-simulate`` call :meth:`SimAdapter.step`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from terrain_estimation.params import ParamSpec, ParamValue

__all__ = ["SimAdapter", "check_kind", "field_specs", "floats", "frame_id"]


def frame_id(namespace: str, frame: str) -> str:
    """``frame`` prefixed with the namespace (without its slashes); the bare frame in the root namespace."""
    ns = namespace.strip("/")
    return f"{ns}/{frame}" if ns else frame


def floats(values: Mapping[str, ParamValue], prefix: str, names: Iterable[str]) -> dict[str, Any]:
    """``{name: float(values["<prefix>.<name>"])}``: dataclass fields from validated parameters."""
    return {name: float(values[f"{prefix}.{name}"]) for name in names}


def field_specs(
    prefix: str, defaults: Any, fields: Sequence[tuple[str, str, str, float, float]], label: str = ""
) -> tuple[ParamSpec, ...]:
    """Read-only ``<prefix>.<field>`` specs, one per (field, unit, description, min, max); defaults of ``defaults``."""
    return tuple(
        ParamSpec(f"{prefix}.{name}", float(getattr(defaults, name)), f"[{unit}] {label}{text}", lo, hi, read_only=True)
        for name, unit, text, lo, hi in fields
    )


def check_kind(kind: str, expected: str, family: str) -> None:
    """ValueError unless ``kind`` is the one vehicle kind (``expected``) an adapter module serves."""
    if kind != expected:
        raise ValueError(f"unknown {family} vehicle kind {kind!r}")


class SimAdapter:
    """Base of the adapters: ``simulator.step()`` gives a sample with its time ``t``, ``messages`` its messages."""

    simulator: Any

    def messages(self, sample: Any) -> list[tuple[str, Any]]:
        raise NotImplementedError

    def step(self) -> tuple[float, list[tuple[str, Any]]]:
        """Advance the plant one sample; its time (s) and its messages in publication order."""
        sample = self.simulator.step()
        return sample.t, self.messages(sample)
