"""Sensor inputs of the rover's terrain-response estimator: checked samples → 0.2 s windows of averages.

:class:`SensorWindows` is the input half of
:class:`~terrain_estimation.estimators.rover.RoverTerrainEstimator`: it checks
every sample (:func:`finite_input`, :func:`wheel_triple`), cuts time into
windows of T_e on a grid from the first stamp, sums each stream per window,
closes a window when every stream has passed it (or one is ``max_latency_s``
past it) and hands a complete window's averages (:class:`WindowMeans`) to the
estimator's step. The rules ("Windows", "Never NaN") are in the module
docstring of :mod:`terrain_estimation.estimators.rover`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from terrain_estimation.estimators.rover_config import RoverEstimatorConfig
from terrain_estimation.filters.base import Array
from terrain_estimation.models.rover import WHEELS

__all__ = ["SensorWindows", "WindowMeans", "finite_input", "wheel_triple"]

_STREAMS_BASE: tuple[str, ...] = ("imu", "joint_states", "velocimeter")
_CELL_STREAMS: tuple[str, ...] = tuple(f"load_cell_{w}" for w in WHEELS)
_STREAMS: tuple[str, ...] = _STREAMS_BASE + _CELL_STREAMS


# ---------------------------------------------------------------------------
# Input validation
# ---------------------------------------------------------------------------


def finite_input(where: str, name: str, value: Any) -> float:
    """``value`` as a finite float; else ValueError naming ``where``, ``name`` and the value."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {name} must be a finite number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{where}: {name} must be finite, got {value!r}")
    return v


def wheel_triple(where: str, name: str, value: Any) -> Array:
    """``value`` as 3 finite floats in WHEELS order (rear, middle, front); else ValueError as :func:`finite_input`."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {name} must be 3 finite numbers (rear, middle, front), got {value!r}") from None
    if arr.shape != (3,):
        raise ValueError(f"{where}: {name} must have 3 values (rear, middle, front), got {value!r}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{where}: {name} must be finite, got {value!r}")
    return arr


# ---------------------------------------------------------------------------
# Windows of averaged measurements
# ---------------------------------------------------------------------------


@dataclass
class _Window:
    """Sums of one window's samples (mutable, private).

    Plain floats, added one sample at a time: the same additions as numpy's on float64 arrays, without an
    array operation per sample (every message adds to a window; :class:`WindowMeans` makes the arrays).
    """

    index: int
    centre: float = math.nan  # the window's centre, where its estimate is stamped (s)
    imu_n: int = 0
    force_x_sum: float = 0.0
    force_z_sum: float = 0.0
    pitch_rate: float = 0.0
    joint_n: int = 0
    bogie_sum: float = 0.0
    torque_sum: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    joint_first: tuple[float, float, Array] | None = None  # (t, bogie, wheel angles)
    joint_last: tuple[float, float, Array] | None = None
    torque_centre: tuple[float, list[float]] | None = None  # (distance to the centre, torques) of the nearest sample
    speed_n: int = 0
    speed_sum: float = 0.0
    cell_n: list[int] = field(default_factory=lambda: [0, 0, 0])
    axial_sum: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    perpendicular_sum: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])

    def add_imu(self, fx: float, fz: float, rate: float) -> None:
        self.imu_n += 1
        self.force_x_sum += fx
        self.force_z_sum += fz
        self.pitch_rate += rate

    def add_joints(self, t: float, bogie: float, angles: Array, torques: Array) -> None:
        self.joint_n += 1
        self.bogie_sum += bogie
        total = self.torque_sum
        values = torques.tolist()
        for j, torque in enumerate(values):
            total[j] += torque
        gap = abs(t - self.centre)
        if self.torque_centre is None or gap < self.torque_centre[0]:
            self.torque_centre = (gap, values)
        sample = (t, bogie, angles)
        if self.joint_first is None:
            self.joint_first = sample
        self.joint_last = sample

    def add_speed(self, speed: float) -> None:
        self.speed_n += 1
        self.speed_sum += speed

    def add_cell(self, j: int, axial: float, perpendicular: float) -> None:
        self.cell_n[j] += 1
        self.axial_sum[j] += axial
        self.perpendicular_sum[j] += perpendicular


class WindowMeans:
    """One window's averaged measurements, and the joint rates of eq. 63 over it."""

    def __init__(self, w: _Window, wheel_rates: Array, bogie_rate: float, joint_dt: float) -> None:
        self.imu_n = w.imu_n
        self.joint_n = w.joint_n
        self.speed_n = w.speed_n
        self.cell_n = np.array(w.cell_n, dtype=float)
        self.specific_force = np.array([w.force_x_sum, w.force_z_sum]) / w.imu_n
        self.pitch_rate = w.pitch_rate / w.imu_n
        self.bogie_angle = w.bogie_sum / w.joint_n
        self.wheel_torque = np.array(w.torque_sum) / w.joint_n
        # The applied torques of the sample nearest the window's centre (the stamp), for τ_R's within-window swing.
        self.wheel_torque_at_stamp = (
            self.wheel_torque.copy() if w.torque_centre is None else np.array(w.torque_centre[1], dtype=float)
        )
        self.forward_speed = w.speed_sum / w.speed_n
        self.axial_force = np.array(w.axial_sum) / self.cell_n
        self.perpendicular_force = np.array(w.perpendicular_sum) / self.cell_n
        self.wheel_rates = wheel_rates
        self.bogie_rate = bogie_rate
        self.joint_dt = joint_dt


def _angle_difference(a: Array | float, b: Array | float) -> Array:
    """a − b wrapped into (−π, π] (encoders that wrap their angle)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    return np.asarray(np.remainder(d + math.pi, 2.0 * math.pi) - math.pi, dtype=float)


class SensorWindows:
    """The sensor inputs of the rover estimator and their windows (module docstring).

    A subclass sets ``config`` and the counters ``_c`` (the sample and window
    counts of :class:`~terrain_estimation.estimators.rover_outputs.RoverCounters`),
    calls :meth:`_reset_windows` on reset and runs one step per complete
    window in :meth:`_step`.
    """

    config: RoverEstimatorConfig
    _c: dict[str, int]

    def _reset_windows(self) -> None:
        self._t_origin: float | None = None
        self._closed_upto = -1
        self._open: dict[int, _Window] = {}
        self._latest: dict[str, float] = {}
        self._last_joint: tuple[float, float, Array] | None = None

    def _step(self, t: float, m: WindowMeans) -> None:
        """One estimator step on a complete window's averages, stamped at the window's centre ``t``."""
        raise NotImplementedError

    # -- public API -----------------------------------------------------------------
    def add_imu(self, t: float, specific_force_x: float, specific_force_z: float, pitch_rate: float) -> None:
        """One IMU sample: body-frame specific force (m/s², eqs. 72–73) and pitch rate about +y (rad/s).

        Raises:
            ValueError: a non-finite argument or a stamp not after the previous IMU stamp.
        """
        where = "add_imu"
        tt = finite_input(where, "t", t)
        fx = finite_input(where, "specific_force_x", specific_force_x)
        fz = finite_input(where, "specific_force_z", specific_force_z)
        rate = finite_input(where, "pitch_rate", pitch_rate)
        self._record(where, "imu", "imu_samples", tt, lambda w: w.add_imu(fx, fz, rate))

    def add_joint_state(
        self, t: float, bogie_angle: float, wheel_angles: Sequence[float], wheel_torques: Sequence[float]
    ) -> None:
        """One joint-state sample: bogie angle q1, wheel angles q2..q4 (rad), applied wheel torques τ_W (N·m).

        Wheel angles are relative to their carriers, positive rolling forward,
        in WHEELS order (rear, middle, front); so are the torques.

        Raises:
            ValueError: a non-finite value, not 3 wheel values, or a stamp not
                after the previous joint-state stamp.
        """
        where = "add_joint_state"
        tt = finite_input(where, "t", t)
        bogie = finite_input(where, "bogie_angle", bogie_angle)
        angles = wheel_triple(where, "wheel_angles", wheel_angles)
        torques = wheel_triple(where, "wheel_torques", wheel_torques)
        self._record(where, "joint_states", "joint_samples", tt, lambda w: w.add_joints(tt, bogie, angles, torques))

    def add_velocimeter(self, t: float, forward_speed: float) -> None:
        """One velocimeter sample: speed along the body x axis (m/s).

        Raises:
            ValueError: a non-finite argument or a stamp not after the previous one.
        """
        where = "add_velocimeter"
        tt = finite_input(where, "t", t)
        speed = finite_input(where, "forward_speed", forward_speed)
        self._record(where, "velocimeter", "velocimeter_samples", tt, lambda w: w.add_speed(speed))

    def add_load_cell(self, t: float, wheel: str, axial_force: float, perpendicular_force: float | None = None) -> None:
        """One load-cell sample of ``wheel``: F_L along the sensing axis and, two-axis, F_⊥ (N).

        With ``load_cell_axes = 1`` a given F_⊥ is ignored.

        Raises:
            ValueError: unknown wheel, non-finite force, F_⊥ missing with
                two-axis cells, or a stamp not after this cell's previous one.
        """
        where = "add_load_cell"
        if wheel not in WHEELS:
            raise ValueError(f"{where}: wheel must be one of {WHEELS}, got {wheel!r}")
        tt = finite_input(where, "t", t)
        axial = finite_input(where, "axial_force", axial_force)
        perpendicular = 0.0
        if self.config.load_cell_axes == 2:
            if perpendicular_force is None:
                raise ValueError(f"{where}: perpendicular_force is required with load_cell_axes = 2 (wheel {wheel!r})")
            perpendicular = finite_input(where, "perpendicular_force", perpendicular_force)
        j = WHEELS.index(wheel)
        self._record(where, _CELL_STREAMS[j], "load_cell_samples", tt, lambda w: w.add_cell(j, axial, perpendicular))

    def add_load_cells(
        self, t: float, axial_forces: Sequence[float], perpendicular_forces: Sequence[float] | None = None
    ) -> None:
        """All three load cells at one stamp (WHEELS order); see :meth:`add_load_cell`."""
        where = "add_load_cells"
        axial = wheel_triple(where, "axial_forces", axial_forces)
        perp = (
            None if perpendicular_forces is None else wheel_triple(where, "perpendicular_forces", perpendicular_forces)
        )
        for j, wheel in enumerate(WHEELS):
            self.add_load_cell(t, wheel, float(axial[j]), None if perp is None else float(perp[j]))

    def flush(self) -> None:
        """Close every open window now (end of a log); complete ones run their step."""
        while self._open:
            self._close(min(self._open))

    # -- windows ------------------------------------------------------------------------
    def _record(self, where: str, stream: str, counter: str, t: float, add: Callable[[_Window], None]) -> None:
        """Count one checked sample of ``stream``, ``add`` it to its open window (if any) and close what is ready."""
        window = self._window_for(where, stream, t)
        self._c[counter] += 1
        if window is not None:
            add(window)
        self._close_ready()

    def _window_index(self, t: float) -> int:
        assert self._t_origin is not None
        return max(0, math.ceil((t - self._t_origin) / self.config.step_s - 1e-9))

    def _window_end(self, index: int) -> float:
        assert self._t_origin is not None
        return self._t_origin + index * self.config.step_s

    def _window_for(self, where: str, stream: str, t: float) -> _Window | None:
        """The open window of stamp ``t`` (None if already closed); checks the stream's order."""
        previous = self._latest.get(stream)
        if previous is not None and t <= previous:
            raise ValueError(f"{where}: t = {t!r} is not after the previous {stream} stamp {previous!r}")
        self._latest[stream] = t
        if self._t_origin is None:
            self._t_origin = t
        index = self._window_index(t)
        if index <= self._closed_upto:
            self._c["late_samples"] += 1
            return None
        window = self._open.get(index)
        if window is None:
            window = self._open[index] = _Window(index, self._window_end(index) - 0.5 * self.config.step_s)
        return window

    def _close_ready(self) -> None:
        """Close every window that all streams have passed, or one stream by ``max_latency_s``.

        The watermark is the oldest newest-stamp over the streams (once each
        has reported) or the newest stamp less ``max_latency_s``, whichever is
        later; every window ending before it is closed, empty ones included,
        so a sample that arrives behind the watermark is late.
        """
        latest = self._latest  # only the streams of _STREAMS are ever recorded (_window_for)
        if not latest:
            return
        seen = latest.values()
        watermark = max(seen) - self.config.max_latency_s
        if len(latest) == len(_STREAMS):
            watermark = max(watermark, min(seen))
        assert self._t_origin is not None
        last_closed = math.ceil((watermark - 1e-9 - self._t_origin) / self.config.step_s) - 1
        while self._open and min(self._open) <= last_closed:
            self._close(min(self._open))
        self._closed_upto = max(self._closed_upto, last_closed)

    def _close(self, index: int) -> None:
        window = self._open.pop(index)
        self._closed_upto = max(self._closed_upto, index)
        self._c["windows"] += 1
        previous_joint = self._last_joint
        if window.joint_last is not None:
            self._last_joint = window.joint_last
        need = self.config.min_window_samples
        counts = [window.imu_n, window.joint_n, window.speed_n, *window.cell_n]
        rates = self._joint_rates(window, previous_joint)
        if min(counts) < need or rates is None:
            self._c["incomplete_windows"] += 1
            return
        self._step(self._window_end(index) - 0.5 * self.config.step_s, WindowMeans(window, *rates))

    def _joint_rates(
        self, window: _Window, previous: tuple[float, float, Array] | None
    ) -> tuple[Array, float, float] | None:
        """(q̇2..4, q̇1, interval) by eq. 63 between the previous and this window's last samples."""
        if window.joint_last is None:
            return None
        t1, bogie1, wheels1 = window.joint_last
        if previous is not None and 0.0 < t1 - previous[0] <= self.config.max_gap_s:
            t0, bogie0, wheels0 = previous
        elif window.joint_first is not None and window.joint_first[0] < t1:
            t0, bogie0, wheels0 = window.joint_first
        else:
            return None
        dt = t1 - t0
        return _angle_difference(wheels1, wheels0) / dt, float(_angle_difference(bogie1, bogie0)) / dt, dt
