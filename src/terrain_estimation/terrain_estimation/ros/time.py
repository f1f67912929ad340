"""Conversions between ROS time stamps and float seconds."""

from __future__ import annotations

import math
from typing import Any

from builtin_interfaces.msg import Time

__all__ = ["stamp_to_sec", "stamp_to_ns", "sec_to_stamp", "stamp_parts", "ns_to_stamp"]


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds of a ``builtin_interfaces/Time`` (rclpy or rosbags object)."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def stamp_to_sec(stamp: Any) -> float:
    """Seconds (float) of a ``builtin_interfaces/Time``."""
    return stamp_to_ns(stamp) * 1e-9


def ns_to_stamp(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def sec_to_stamp(t: float) -> Time:
    """``Time`` nearest to ``t`` seconds (rounded to the nanosecond).

    Raises:
        ValueError: for a non-finite or negative time (ROS time is unsigned).
    """
    sec, nanosec = stamp_parts(t)
    return Time(sec=sec, nanosec=nanosec)


def stamp_parts(t: float) -> tuple[int, int]:
    """``(sec, nanosec)`` of :func:`sec_to_stamp`'s ``Time``.

    Raises:
        ValueError: for a non-finite or negative time (ROS time is unsigned).
    """
    if not math.isfinite(t) or t < 0.0:
        raise ValueError(f"time {t!r} s cannot be a ROS stamp")
    return divmod(round(t * 1e9), 1_000_000_000)
