"""Stationary detection and zero-velocity update for the skid-steer estimator (issue 20 item 3).

At rest the observer's tire model is at its worst: the slip denominator sits
at its floor ε, a tilted accelerometer (``g sin θ`` on a slope) or its bias is
read as a tire force, and the estimate creeps (a BorealTC Husky standing
still dead-reckoned 11 m). A vehicle whose wheels do not turn and whose IMU
is quiet is standing still; then a pseudo-measurement ``vx = vy = 0`` with a
small variance and ``r`` = the mean gyro over the window pins the estimate.

:class:`StationaryDetector` declares the vehicle stationary when, over the
last ``window_s`` of IMU samples (at least ``min_samples`` of them):

* both side rim speeds ``R|ω|`` are below ``wheel_speed`` (m/s) at every
  sample of the window (wheels stopped), and
* the sample standard deviations of ``a_x`` and ``a_y`` are below
  ``accel_std`` (m/s²) and that of the yaw rate below ``gyro_std`` (rad/s)
  (IMU quiet: an engine idling or a person leaning on the robot stays below,
  driving over any ground does not).

The thresholds sit well above the sensor noise at rest (MEMS accelerometer
0.005–0.05 m/s², gyro 0.001–0.01 rad/s at 100 Hz) and well below what
motion gives: a wheel turning at 1 cm/s is creeping, not standing.

:func:`zero_velocity_update` is the linear Kalman update with ``H = [I₃ 0]``
(the motion states; scale states, if any, move by their correlation), in
Joseph form so the covariance stays symmetric positive semi-definite.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, H, K, R) of the Kalman update

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from terrain_estimation.checks import check_fields, check_int_at_least
from terrain_estimation.filters.base import GaussianState

__all__ = ["ZuptConfig", "StationaryDetector", "zero_velocity_update"]


@dataclass(frozen=True)
class ZuptConfig:
    """Stationary detector and zero-velocity update.

    Attributes:
        enabled: apply zero-velocity updates.
        wheel_speed: rim speed ``R|ω|`` below which a side's wheels are stopped (m/s).
        window_s: IMU window over which the spreads are taken (s).
        min_samples: fewest IMU samples in the window before a decision.
        accel_std: largest standard deviation of ``a_x``, ``a_y`` over the window (m/s²).
        gyro_std: largest standard deviation of the yaw rate over the window (rad/s).
        velocity_std: standard deviation of the ``vx = vy = 0`` pseudo-measurement (m/s).
        yaw_rate_std: standard deviation of the ``r`` = mean-gyro pseudo-measurement (rad/s).
    """

    enabled: bool = True
    wheel_speed: float = 0.01
    window_s: float = 0.5
    min_samples: int = 10
    accel_std: float = 0.3
    gyro_std: float = 0.02
    velocity_std: float = 0.005
    yaw_rate_std: float = 0.005

    def __post_init__(self) -> None:
        if not isinstance(self.enabled, bool):
            raise ValueError(f"ZuptConfig.enabled must be a bool, got {self.enabled!r}")
        check_fields(self, ("wheel_speed", "window_s", "accel_std", "gyro_std", "velocity_std", "yaw_rate_std"))
        check_int_at_least("ZuptConfig", "min_samples", self.min_samples, 2)


class StationaryDetector:
    """Wheels stopped and IMU quiet over a short window (module docstring).

    Args:
        config: thresholds.
        wheel_radius: rolling radius R (m), to turn wheel speeds into rim speeds.
    """

    def __init__(self, config: ZuptConfig, wheel_radius: float) -> None:
        self.config = config
        self.wheel_radius = float(wheel_radius)
        self._window: deque[tuple[float, float, float, float, bool]] = deque()
        self._moving = 0  # samples of the window whose wheels turn

    def reset(self) -> None:
        """Forget the window."""
        self._window.clear()
        self._moving = 0

    def observe(self, t: float, ax: float, ay: float, yaw_rate: float, wheel_left: float, wheel_right: float) -> bool:
        """Add one IMU sample with the wheel speeds used at it (s, m/s², m/s², rad/s, rad/s, rad/s).

        Returns:
            Whether the vehicle is stationary over the window ending at ``t``.
        """
        cfg = self.config
        stopped = max(abs(wheel_left), abs(wheel_right)) * self.wheel_radius < cfg.wheel_speed
        window = self._window
        window.append((t, ax, ay, yaw_rate, stopped))
        self._moving += not stopped
        while window[0][0] < t - cfg.window_s:
            self._moving -= not window.popleft()[4]
        if self._moving or len(window) < cfg.min_samples:
            return False
        data = np.array([w[1:4] for w in window])
        spread = data.std(axis=0, ddof=1)
        return bool(spread[0] < cfg.accel_std and spread[1] < cfg.accel_std and spread[2] < cfg.gyro_std)

    def mean_yaw_rate(self) -> float:
        """Mean gyro yaw rate over the window (rad/s; 0 when empty)."""
        if not self._window:
            return 0.0
        return float(sum(w[3] for w in self._window) / len(self._window))


def zero_velocity_update(state: GaussianState, yaw_rate: float, config: ZuptConfig) -> GaussianState:
    """Kalman update with ``vx = 0, vy = 0, r = yaw_rate`` on the first three states (Joseph form).

    Args:
        state: ``x`` ``(n,)``, ``P`` ``(n, n)``, n ≥ 3 (motion states first).
        yaw_rate: the mean gyro over the stationary window (rad/s).
        config: the pseudo-measurement's standard deviations.

    Returns:
        The updated state (a new object).
    """
    x = np.asarray(state.x, dtype=float)
    P = np.asarray(state.P, dtype=float)
    n = x.size
    H = np.zeros((3, n))
    H[0, 0] = H[1, 1] = H[2, 2] = 1.0
    R = np.diag([config.velocity_std**2, config.velocity_std**2, config.yaw_rate_std**2])
    nu = np.array([0.0, 0.0, yaw_rate]) - x[:3]
    S = P[:3, :3] + R
    K = np.linalg.solve(S, P[:3, :]).T  # P Hᵀ S⁻¹ (S symmetric)
    x_new = x + K @ nu
    A = np.eye(n) - K @ H
    P_new = A @ P @ A.T + K @ R @ K.T
    return GaussianState(x=x_new, P=0.5 * (P_new + P_new.T))
