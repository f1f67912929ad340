"""Argument checks for parameter dataclasses: a ValueError naming ``Owner.field`` and the value.

A leaf (it imports nothing of ours), used by the core's configs and by the
simulator's plants alike, so that every ``__post_init__`` refuses a bad value
with the same words.

Two conventions:

* :func:`check_finite`, :func:`check_positive`, :func:`check_non_negative`
  accept any real number (numpy scalars included).
* :func:`check_float_finite`, :func:`check_float_positive`,
  :func:`check_float_non_negative` and :func:`finite_tuple` accept Python
  ``int``/``float`` only (a numpy integer or a string is refused) and quote
  the value with ``repr``.

:func:`check_fields` applies one rule to several fields of a dataclass
instance, with the instance's class name as the owner.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import fields
from typing import Any, Literal

__all__ = [
    "check_fields",
    "check_finite",
    "check_float_finite",
    "check_float_non_negative",
    "check_float_positive",
    "check_int_at_least",
    "check_non_negative",
    "check_positive",
    "finite_tuple",
]

Rule = Literal["finite", "positive", "non_negative"]


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


def check_int_at_least(owner: str, name: str, value: object, minimum: int) -> None:
    """``value`` is an ``int`` (not a bool) of at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{owner}.{name} must be an int >= {minimum}, got {value!r}")


def finite_tuple(owner: str, name: str, value: Sequence[float], size: int) -> tuple[float, ...]:
    """``value`` as a tuple of ``size`` finite floats."""
    result = tuple(float(v) for v in value)
    if len(result) != size or not all(math.isfinite(v) for v in result):
        raise ValueError(f"{owner}.{name} must be {size} finite values, got {value!r}")
    return result


_RULES: dict[tuple[Rule, bool], Callable[[str, str, float], None]] = {
    ("finite", False): check_finite,
    ("positive", False): check_positive,
    ("non_negative", False): check_non_negative,
    ("finite", True): check_float_finite,
    ("positive", True): check_float_positive,
    ("non_negative", True): check_float_non_negative,
}


def check_fields(
    obj: Any, names: Iterable[str] | None = None, *, rule: Rule = "positive", strict_types: bool = False
) -> None:
    """Apply ``rule`` to the fields ``names`` of the dataclass instance ``obj`` (all its fields when None).

    The owner in the message is ``type(obj).__name__``. ``strict_types``
    selects the ``check_float_*`` convention (Python numbers only).
    """
    check = _RULES[(rule, strict_types)]
    owner = type(obj).__name__
    for name in names if names is not None else (f.name for f in fields(obj)):
        check(owner, name, getattr(obj, name))
