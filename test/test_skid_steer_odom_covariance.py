"""Issue 20 item 4 (odom): a full twist covariance and a dead-reckoned pose covariance that grows; large
variances, never −1 or zeros, for what is not estimated."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from terrain_estimation.estimators.skid_steer_odometry import DeadReckoning
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.models.skid_steer_observer import SkidSteerInput, SkidSteerObserverModel
from terrain_estimation.ros.skid_steer import UNESTIMATED_VARIANCE, estimate_to_odom_msg

P = SkidSteerParams()
DT = 0.01


def _drive(config: SkidSteerEstimatorConfig | None = None, seconds: float = 8.0, seed: int = 1):
    """A 2 m/s left turn of the observer's own model (finer Euler); returns (estimates, true poses)."""
    rng = np.random.default_rng(seed)
    truth = SkidSteerObserverModel(P, max_euler_gain=0.1)
    x = np.array([2.0, 0.0, 0.0])
    pose = np.zeros(3)
    a = (0.0, 0.0)
    est = SkidSteerEstimator(config)
    out = []
    for k in range(1, round(seconds / DT) + 1):
        t = k * DT
        dv = 0.3 if t > 2.0 else 0.0
        wl, wr = (2.0 - dv) / P.wheel_radius, (2.0 + dv) / P.wheel_radius
        u = SkidSteerInput(wl, wr, *a)
        x_new = truth.f(x, u, DT)
        v = 0.5 * (x + x_new)
        mid = pose[2] + 0.5 * DT * v[2]
        pose = pose + DT * np.array(
            [math.cos(mid) * v[0] - math.sin(mid) * v[1], math.sin(mid) * v[0] + math.cos(mid) * v[1], v[2]]
        )
        x = x_new
        z = truth.h(x, u)
        a = (float(z[0]), float(z[1]))
        est.add_joint_state(t - DT, wl * P.transmission_ratio, wr * P.transmission_ratio)
        e = est.add_imu(t, *(z + rng.normal(scale=[0.05, 0.05, 0.002])))
        out.append((e, pose.copy()))
    return out


def test_odom_covariances_are_psd_complete_and_never_minus_one():
    out = _drive()
    for e, _ in out[1::50]:
        odom = estimate_to_odom_msg(e, "o", "b")
        for cov in (np.asarray(odom.pose.covariance), np.asarray(odom.twist.covariance)):
            assert cov.shape == (36,) and np.all(np.isfinite(cov)) and not np.any(cov == -1.0)
            m = cov.reshape(6, 6)
            np.testing.assert_array_equal(m, m.T)
            assert np.linalg.eigvalsh(m).min() >= -1e-12 * np.abs(m).max()
            assert (m[2, 2], m[3, 3], m[4, 4]) == (UNESTIMATED_VARIANCE,) * 3  # z/vz, roll (rate), pitch (rate)
        twist = np.asarray(odom.twist.covariance).reshape(6, 6)
        np.testing.assert_array_equal(twist[np.ix_([0, 1, 5], [0, 1, 5])], np.reshape(e.twist_covariance, (3, 3)))
        assert twist[0, 0] > 0.0 and twist[1, 1] > 0.0 and twist[5, 5] > 0.0
    # The cross-covariances of the filter are there (not a diagonal).
    assert any(abs(e.twist_covariance[1]) > 0.0 and abs(e.twist_covariance[5]) > 0.0 for e, _ in out)


def test_pose_covariance_grows_and_covers_the_dead_reckoning_error():
    out = _drive()
    traces = [np.trace(np.reshape(e.pose_covariance, (3, 3))) for e, _ in out]
    assert traces[0] == 0.0 and all(b >= a for a, b in zip(traces, traces[1:], strict=False))
    assert traces[-1] > 2.0 * traces[len(traces) // 10]  # correlated twist error: faster than a random walk
    e, pose = out[-1]
    cov = np.reshape(e.pose_covariance, (3, 3))
    err = np.array([e.x - pose[0], e.y - pose[1], math.remainder(e.yaw - pose[2], 2 * math.pi)])
    assert all(abs(err[i]) < 3.0 * math.sqrt(cov[i, i]) for i in range(3)), (err, np.sqrt(np.diag(cov)))
    # A white twist error (correlation time 0) claims far less.
    white = _drive(SkidSteerEstimatorConfig(odom_correlation_time_s=0.0))[-1][0]
    assert np.trace(np.reshape(white.pose_covariance, (3, 3))) < 0.1 * traces[-1]


def test_pose_propagation_uses_the_jacobians_of_the_midpoint_step():
    rng = np.random.default_rng(4)
    for _ in range(20):
        prev, cur = tuple(rng.normal(size=3)), tuple(rng.normal(size=3))
        dt, yaw = float(rng.uniform(0.005, 0.2)), float(rng.uniform(-3.0, 3.0))

        def step(pose0, twist_shift, prev=prev, cur=cur, dt=dt):
            dr = DeadReckoning(0.0)
            dr.pose = tuple(pose0)
            c = tuple(np.add(cur, twist_shift))
            p = tuple(np.add(prev, twist_shift))
            dr.advance(dt, p, c, np.zeros((3, 3)), np.zeros((3, 3)))
            return np.array(dr.pose)

        base = np.array([0.3, -0.2, yaw])
        h = 1e-6
        F = np.column_stack([(step(base + h * e, 0.0) - step(base - h * e, 0.0)) / (2 * h) for e in np.eye(3)])
        G = np.column_stack([(step(base, h * e) - step(base, -h * e)) / (2 * h) for e in np.eye(3)])
        twist_cov = np.diag(rng.uniform(0.01, 0.1, size=3))
        pose_cov = np.diag(rng.uniform(0.0, 0.1, size=3))
        dr = DeadReckoning(0.0)
        dr.pose, dr.covariance = tuple(base), pose_cov
        dr.advance(dt, prev, cur, twist_cov, twist_cov)
        np.testing.assert_allclose(dr.covariance, F @ pose_cov @ F.T + G @ twist_cov @ G.T, rtol=1e-6, atol=1e-12)


def test_correlation_time_is_checked():
    with pytest.raises(ValueError, match="correlation_time_s"):
        DeadReckoning(-1.0)
    with pytest.raises(ValueError, match="odom_correlation_time_s"):
        SkidSteerEstimatorConfig(odom_correlation_time_s=math.nan)
