"""Argument checks shared by the plants' dataclasses (ValueError naming ``owner.name`` and the value), and
:func:`changed_fields`, the fields an effects object switches on.

Two conventions, kept as the plants had them:

* :func:`check_finite`, :func:`check_positive`, :func:`check_non_negative`
  accept any real number (numpy scalars included); the skid steer's.
* :func:`check_float_finite`, :func:`check_float_positive`,
  :func:`check_float_non_negative` and :func:`finite_tuple` accept Python
  ``int``/``float`` only (a numpy integer or a string is refused with a
  ValueError) and quote the value with ``repr``; the rover's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, TypeVar

T = TypeVar("T")

__all__ = [
    "changed_fields",
    "without_noise",
    "check_finite",
    "check_float_finite",
    "check_float_non_negative",
    "check_float_positive",
    "check_non_negative",
    "check_positive",
    "finite_tuple",
]


def check_finite(owner: str, name: str, value: float) -> None:
    if not math.isfinite(value):
        raise ValueError(f"{owner}.{name} must be finite, got {value}")


def check_positive(owner: str, name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{owner}.{name} must be finite and > 0, got {value}")


def check_non_negative(owner: str, name: str, value: float) -> None:
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"{owner}.{name} must be finite and ≥ 0, got {value}")


def check_float_finite(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value)):
        raise ValueError(f"{owner}.{name} must be finite, got {value!r}")


def check_float_positive(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
        raise ValueError(f"{owner}.{name} must be finite and > 0, got {value!r}")


def check_float_non_negative(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
        raise ValueError(f"{owner}.{name} must be finite and ≥ 0, got {value!r}")


def finite_tuple(owner: str, name: str, value: Sequence[float], size: int) -> tuple[float, ...]:
    """``value`` as a tuple of ``size`` finite floats."""
    result = tuple(float(v) for v in value)
    if len(result) != size or not all(math.isfinite(v) for v in result):
        raise ValueError(f"{owner}.{name} must be {size} finite values, got {value!r}")
    return result


def changed_fields(value: Any, reference: Any) -> tuple[str, ...]:
    """Names of the dataclass fields of ``value`` that differ from ``reference``'s, in field order."""
    return tuple(name for name in value.__dataclass_fields__ if getattr(value, name) != getattr(reference, name))


def without_noise(cls: type[T]) -> T:
    """The defaults of the sensor-model dataclass ``cls`` with every noise σ (each field ``*_std``) zero."""
    fields = cls.__dataclass_fields__  # type: ignore[attr-defined]
    return cls(**{name: 0.0 for name in fields if name.endswith("_std")})
