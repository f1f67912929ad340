"""The plants' argument checks (re-exported from the core's :mod:`terrain_estimation.checks`, so a
plant and a config refuse a bad value with the same words), :func:`changed_fields`, the fields an
effects object switches on, and :func:`without_noise`.
"""

from __future__ import annotations

from typing import Any, TypeVar

from terrain_estimation.checks import (
    check_fields,
    check_finite,
    check_float_finite,
    check_float_non_negative,
    check_float_positive,
    check_non_negative,
    check_positive,
    finite_tuple,
)

T = TypeVar("T")

__all__ = [
    "changed_fields",
    "check_fields",
    "without_noise",
    "check_finite",
    "check_float_finite",
    "check_float_non_negative",
    "check_float_positive",
    "check_non_negative",
    "check_positive",
    "finite_tuple",
]


def changed_fields(value: Any, reference: Any) -> tuple[str, ...]:
    """Names of the dataclass fields of ``value`` that differ from ``reference``'s, in field order."""
    return tuple(name for name in value.__dataclass_fields__ if getattr(value, name) != getattr(reference, name))


def without_noise(cls: type[T]) -> T:
    """The defaults of the sensor-model dataclass ``cls`` with every noise σ (each field ``*_std``) zero."""
    fields = cls.__dataclass_fields__  # type: ignore[attr-defined]
    return cls(**{name: 0.0 for name in fields if name.endswith("_std")})
