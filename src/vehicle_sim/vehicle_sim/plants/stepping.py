"""What the stepping plants share: their sample clock and the stacking of per-sample dataclasses into runs."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, TypeVar

import numpy as np
from numpy.typing import DTypeLike

__all__ = ["FiniteRun", "SampleClock", "SensorTiming", "stack_fields"]

T = TypeVar("T")


class SampleClock:
    """Sample counter of a stepping simulator: one ``step()`` per sensor period ``_period`` (s)."""

    _step_index: int
    _period: float

    @property
    def t(self) -> float:
        """Current simulation time (s): step_index × period."""
        return self._step_index * self._period

    @property
    def step_index(self) -> int:
        """Number of sensor periods simulated so far."""
        return self._step_index


class FiniteRun(SampleClock):
    """A :class:`SampleClock` whose scenario lasts ``_n_samples`` periods."""

    _n_samples: int

    @property
    def done(self) -> bool:
        """True once the scenario's duration has been simulated."""
        return self._step_index >= self._n_samples


class SensorTiming:
    """Sensor period and RK4 sub-steps of a scenario with ``sensor_rate`` (Hz) and ``integration_step`` (s)."""

    sensor_rate: float
    integration_step: float

    @property
    def sensor_period(self) -> float:
        """1 / sensor_rate (s)."""
        return 1.0 / self.sensor_rate

    @property
    def substeps(self) -> int:
        """RK4 steps per sensor period: the fewest that make each step ≤ ``integration_step``."""
        return max(1, math.ceil(self.sensor_period / self.integration_step - 1e-9))


def stack_fields(cls: type[T], items: Sequence[Any], dtype: DTypeLike | None = None) -> T:
    """A ``cls`` (a dataclass) whose every field is the array of that attribute over ``items``."""
    fields = cls.__dataclass_fields__  # type: ignore[attr-defined]
    return cls(**{name: np.array([getattr(item, name) for item in items], dtype=dtype) for name in fields})
