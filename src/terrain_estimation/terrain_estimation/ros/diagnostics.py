"""Building ``/diagnostics`` messages (no diagnostic_updater wheel exists).

``DiagnosticStatus.level`` is a ``byte`` field: it must be set with the
``bytes`` constants of the message class (``DiagnosticStatus.OK`` …). A Python
int is accepted by rclpy and serialises to garbage.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

__all__ = ["OK", "WARN", "ERROR", "STALE", "LEVEL_NAMES", "make_status", "make_array", "worst"]

OK: bytes = DiagnosticStatus.OK
WARN: bytes = DiagnosticStatus.WARN
ERROR: bytes = DiagnosticStatus.ERROR
STALE: bytes = DiagnosticStatus.STALE
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}
_ORDER = {OK: 0, WARN: 1, ERROR: 2, STALE: 3}


def worst(*levels: bytes) -> bytes:
    """The most severe of ``levels`` (OK < WARN < ERROR < STALE)."""
    return max(levels, key=lambda lv: _ORDER[lv])


def _format(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def make_status(name: str, hardware_id: str, level: bytes, message: str, values: Mapping[str, Any]) -> DiagnosticStatus:
    if level not in _ORDER:
        raise ValueError(f"diagnostic level must be one of the DiagnosticStatus bytes constants, got {level!r}")
    return DiagnosticStatus(
        level=level,
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=k, value=_format(v)) for k, v in values.items()],
    )


def make_array(stamp: Any, statuses: list[DiagnosticStatus]) -> DiagnosticArray:
    msg = DiagnosticArray(status=statuses)
    msg.header.stamp = stamp
    return msg
