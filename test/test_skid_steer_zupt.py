"""Issue 20 item 3: a stationary detector (wheels stopped, IMU quiet) applies a zero-velocity update."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from terrain_estimation.estimators.skid_steer_zupt import StationaryDetector, ZuptConfig, zero_velocity_update
from terrain_estimation.filters.base import GaussianState
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.models.skid_steer_observer import SkidSteerInput, SkidSteerObserverModel

P = SkidSteerParams()
DT = 0.01


def _speed(t: float) -> float:
    """Rim speed (m/s): 1.5 m/s to 3 s, braking to rest at 4 s, at rest after."""
    return 1.5 if t < 3.0 else max(0.0, 1.5 * (4.0 - t))


def _run(config: SkidSteerEstimatorConfig, seconds: float = 7.0, seed: int = 3, slope: float = 0.15):
    """The observer's model as truth (finer Euler) while rolling, exactly at rest after 4 s; IMU with noise,
    a 0.15 m/s² accelerometer offset (a 0.9° slope) and a gyro bias; wheel speeds at 100 Hz."""
    rng = np.random.default_rng(seed)
    truth = SkidSteerObserverModel(P, max_euler_gain=0.2, max_substeps=100_000)
    x = np.array([1.5, 0.0, 0.0])
    a = (0.0, 0.0)
    est = SkidSteerEstimator(config)
    out = []
    for k in range(1, round(seconds / DT) + 1):
        t = k * DT
        w = _speed(t - DT) / P.wheel_radius
        u = SkidSteerInput(w, w, *a)
        x = truth.f(x, u, DT) if t < 4.0 else np.zeros(3)
        z = truth.h(x, u)
        a = (float(z[0]), float(z[1]))
        z = z + rng.normal(scale=[0.05, 0.05, 0.002]) + [slope, 0.0, 0.003]
        est.add_joint_state(t - DT, w * P.transmission_ratio, w * P.transmission_ratio)
        e = est.add_imu(t, *z)
        assert e is not None
        out.append((e, x.copy()))
    return est, out


def test_stationary_stretch_reads_zero_and_the_pose_stops():
    est, out = _run(SkidSteerEstimatorConfig())
    rest = [e for e, x in out if e.t > 5.0]
    assert all(e.stationary for e in rest)
    assert max(math.hypot(e.vx, e.vy) for e in rest) < 0.05
    assert max(math.hypot(e.vx, e.vy) for e in rest) < 0.01
    assert max(e.vx_variance for e in rest) < 0.005**2
    assert abs(rest[-1].yaw_rate) < 0.004  # between the truth (0) and the mean gyro (its 0.003 bias)
    assert math.hypot(rest[-1].x - rest[0].x, rest[-1].y - rest[0].y) < 0.01
    c = est.counters
    assert c.zero_velocity_updates >= len(rest)
    # Never while driving or braking: the wheels turn.
    assert not any(e.stationary for e, _ in out if e.t < 4.0)


def test_without_the_update_the_stationary_estimate_is_not_pinned():
    _, on = _run(SkidSteerEstimatorConfig(model="kinematic"), slope=1.0)
    _, off = _run(SkidSteerEstimatorConfig(model="kinematic", zupt=ZuptConfig(enabled=False)), slope=1.0)
    speed_on = max(math.hypot(e.vx, e.vy) for e, _ in on if e.t > 5.0)
    speed_off = max(math.hypot(e.vx, e.vy) for e, _ in off if e.t > 5.0)
    assert speed_on < 0.01 and speed_off > 2 * speed_on


def test_detector_needs_stopped_wheels_and_a_quiet_imu():
    rng = np.random.default_rng(0)
    cfg = ZuptConfig()
    det = StationaryDetector(cfg, wheel_radius=0.375)
    # At rest, quiet: stationary once the window holds min_samples.
    flags = [det.observe(0.01 * k, *rng.normal(0.0, 0.03, 2), rng.normal(0.0, 0.002), 0.0, 0.0) for k in range(60)]
    assert not any(flags[: cfg.min_samples - 1]) and all(flags[cfg.min_samples :])
    # Vibration (a motor idling hard, someone pushing): not quiet.
    det.reset()
    assert not any(det.observe(0.01 * k, *rng.normal(0.0, 1.0, 2), 0.0, 0.0, 0.0) for k in range(60))
    # A turning gyro: not quiet.
    det.reset()
    assert not any(det.observe(0.01 * k, 0.0, 0.0, 0.2 * math.sin(0.5 * k), 0.0, 0.0) for k in range(60))
    # Wheels creeping at 2 cm/s: not stopped.
    det.reset()
    assert not any(det.observe(0.01 * k, 0.0, 0.0, 0.0, 0.02 / 0.375, 0.02 / 0.375) for k in range(60))
    # One moving sample in the window is enough to say no.
    det.reset()
    for k in range(50):
        det.observe(0.01 * k, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert not det.observe(0.5, 0.0, 0.0, 0.0, 1.0, 1.0)


def test_zero_velocity_update_is_the_kalman_update_and_keeps_the_covariance_psd():
    cfg = ZuptConfig(velocity_std=0.01, yaw_rate_std=0.02)
    x = np.array([0.3, -0.1, 0.05, 0.2])  # with a scale state correlated with vx
    P_ = np.diag([0.04, 0.01, 0.001, 0.09])
    P_[0, 3] = P_[3, 0] = 0.03
    post = zero_velocity_update(GaussianState(x=x, P=P_), 0.01, cfg)
    H = np.hstack([np.eye(3), np.zeros((3, 1))])
    R = np.diag([1e-4, 1e-4, 4e-4])
    K = P_ @ H.T @ np.linalg.inv(H @ P_ @ H.T + R)
    np.testing.assert_allclose(post.x, x + K @ (np.array([0.0, 0.0, 0.01]) - x[:3]), rtol=1e-12)
    np.testing.assert_allclose(post.P, (np.eye(4) - K @ H) @ P_, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(post.P) > 0.0)
    assert post.x[3] != x[3]  # the correlated scale moved with vx


@pytest.mark.parametrize(
    "kwargs, name",
    [({"window_s": 0.0}, "window_s"), ({"accel_std": math.nan}, "accel_std"), ({"min_samples": 1}, "min_samples")],
)
def test_bad_settings_are_refused_naming_them(kwargs, name):
    with pytest.raises(ValueError, match=name):
        ZuptConfig(**kwargs)
