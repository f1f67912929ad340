"""Wheel speeds at any rate for the skid-steer estimator: interpolation, hold, age limit (issue 20 item 5).

The IMU steps the filter (100 Hz); the side wheel speeds may come at another
rate (the simulator's 100 Hz, a Husky's 6.5 Hz). :class:`WheelSpeedBuffer`
keeps the newest samples and answers "the wheel speeds at the IMU stamp t":

* ``"linear"`` (default): between the two samples that bracket t, linear
  interpolation (a sample stamped exactly at t is taken as is); beyond the
  newest sample (or before the oldest) the nearest one is held;
* ``"hold"``: the newest sample stamped at or before t (else the oldest), the
  former zero-order hold.

Either way the answer is *stale* (None) when the nearest sample used is
further than the age limit from t. The age limit is ``max_age_s`` when given
(> 0); otherwise it follows the stream: ``age_periods`` times the running
median of the last ``period_window`` sample periods, floored at
``min_age_s`` (the floor before the period is known). With the defaults
(2.5 periods, 0.05 s) 100 Hz wheel speeds get 0.05 s, as before, and the
BorealTC Husky's 6.5 Hz (0.154 s) get 0.385 s, so every IMU sample between
two wheel-speed samples is used.

A live estimator sees a wheel-speed sample only after its stamp: an IMU
sample newer than the newest wheel speeds is held, not interpolated, unless
the caller waits for the next wheel-speed sample (the estimator's
``wheel_speed_wait_s``: the IMU sample is queued until a wheel-speed sample
at or after its stamp arrives or the wait runs out, at the cost of that
latency).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Literal

from terrain_estimation.checks import check_positive

__all__ = ["WheelSpeedBuffer", "Interpolation", "INTERPOLATIONS", "WheelSpeeds"]

Interpolation = Literal["linear", "hold"]
#: The wheel-speed lookup methods.
INTERPOLATIONS: tuple[str, ...] = ("linear", "hold")

#: (wheel speed left, right in rad/s, how: "interpolated" or "held")
WheelSpeeds = tuple[float, float, str]


class WheelSpeedBuffer:
    """The newest wheel-speed samples and their lookup at an IMU stamp (module docstring).

    Args:
        interpolation: ``"linear"`` or ``"hold"``.
        max_age_s: fixed age limit (s, > 0); None derives it from the measured period.
        age_periods: age limit in measured periods when ``max_age_s`` is None (> 0).
        min_age_s: floor of the derived age limit (s, > 0).
        capacity: samples kept (≥ 2).
        period_window: periods in the running median (≥ 1).

    Raises:
        ValueError: on an invalid argument, naming it.
    """

    def __init__(
        self,
        interpolation: Interpolation = "linear",
        *,
        max_age_s: float | None = None,
        age_periods: float = 2.5,
        min_age_s: float = 0.05,
        capacity: int = 64,
        period_window: int = 15,
    ) -> None:
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
        if max_age_s is not None and not (math.isfinite(max_age_s) and max_age_s > 0.0):
            raise ValueError(f"max_age_s must be None or finite and > 0, got {max_age_s}")
        check_positive("WheelSpeedBuffer", "age_periods", age_periods)
        check_positive("WheelSpeedBuffer", "min_age_s", min_age_s)
        if capacity < 2:
            raise ValueError(f"capacity must be >= 2, got {capacity}")
        if period_window < 1:
            raise ValueError(f"period_window must be >= 1, got {period_window}")
        self.interpolation = interpolation
        self.fixed_age_s = max_age_s
        self.age_periods = float(age_periods)
        self.min_age_s = float(min_age_s)
        self._samples: deque[tuple[float, float, float]] = deque(maxlen=capacity)
        self._periods: deque[float] = deque(maxlen=period_window)
        self._median: float | None = None

    def clear(self) -> None:
        """Forget every sample and the measured period."""
        self._samples.clear()
        self._periods.clear()
        self._median = None

    def __len__(self) -> int:
        return len(self._samples)

    @property
    def newest_time(self) -> float | None:
        """Stamp of the newest sample (s), None when empty."""
        return self._samples[-1][0] if self._samples else None

    @property
    def period_s(self) -> float | None:
        """Running median of the sample periods (s); None before two samples."""
        return self._median

    @property
    def max_age_s(self) -> float:
        """The age limit in force (s): fixed, or ``max(min_age_s, age_periods × period)``."""
        if self.fixed_age_s is not None:
            return self.fixed_age_s
        if self._median is None:
            return self.min_age_s
        return max(self.min_age_s, self.age_periods * self._median)

    def add(self, t: float, left: float, right: float) -> bool:
        """Append a sample (s, rad/s, rad/s); False (not stored) when not newer than the newest."""
        if self._samples:
            last = self._samples[-1][0]
            if t <= last:
                return False
            self._periods.append(t - last)
            ordered = sorted(self._periods)
            mid = len(ordered) // 2
            self._median = ordered[mid] if len(ordered) % 2 else 0.5 * (ordered[mid - 1] + ordered[mid])
        self._samples.append((t, left, right))
        return True

    def at(self, t: float) -> WheelSpeeds | None:
        """The wheel speeds at stamp ``t`` (s) and how they were obtained; None when stale or empty."""
        samples = self._samples
        if not samples:
            return None
        limit = self.max_age_s
        newest = samples[-1]
        if t >= newest[0]:
            # At or beyond the newest sample: held (the usual case live, where samples come after their stamp).
            if t - newest[0] > limit:
                return None
            return newest[1], newest[2], "interpolated" if t == newest[0] else "held"
        oldest = samples[0]
        if t < oldest[0]:
            if oldest[0] - t > limit:
                return None
            return oldest[1], oldest[2], "held"
        # oldest ≤ t < newest: the bracketing pair, searched from the newest end (IMU stamps are recent).
        after = newest
        for sample in reversed(samples):
            if sample[0] <= t:
                before = sample
                break
            after = sample
        if self.interpolation == "hold":
            if t - before[0] > limit:
                return None
            return before[1], before[2], "held" if t > before[0] else "interpolated"
        if min(t - before[0], after[0] - t) > limit:
            return None
        if t == before[0]:
            return before[1], before[2], "interpolated"
        w = (t - before[0]) / (after[0] - before[0])
        return (
            before[1] + w * (after[1] - before[1]),
            before[2] + w * (after[2] - before[2]),
            "interpolated",
        )
