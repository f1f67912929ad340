"""Skid-steer estimator core (MODELS.md Part B): feed, filter variants, outputs, robustness.

The data come from the observer's own model integrated finely with noise:
acceptable for a unit test of the plumbing and of convergence, not a
validation against the truth plant (that is the simulator's job).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from terrain_estimation.estimators.skid_steer import (
    SkidSteerEstimate,
    SkidSteerEstimator,
    SkidSteerEstimatorConfig,
)
from terrain_estimation.filters.base import GaussianState
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.models.skid_steer_observer import SkidSteerInput, SkidSteerObserverModel

P = SkidSteerParams()
RAD, RATIO = P.wheel_radius, P.transmission_ratio
DT = 0.01


def wheel_profile(t: float) -> tuple[float, float]:
    """Wheel-side speeds (rad/s): accelerate 0.5 → 2 m/s, left turn, right turn."""
    v = 0.5 + 0.75 * min(t, 2.0)
    dv = 0.35 if 2.0 <= t < 5.0 else (-0.35 if t >= 5.0 else 0.0)
    return (v - dv) / RAD, (v + dv) / RAD


def simulate(duration: float = 7.0, seed: int = 0, accel_std: float = 0.05, gyro_std: float = 0.002):
    """Truth by the observer's model with 20× finer Euler sub-steps, loads from the true accelerations.

    Returns rows ``(t, ω_l, ω_r, z, x_true)``; ω are the wheel speeds held over
    the step ending at ``t``.
    """
    rng = np.random.default_rng(seed)
    truth = SkidSteerObserverModel(P, max_euler_gain=0.025, max_substeps=100_000)
    x = np.array([0.5, 0.0, 0.0])
    a = (0.0, 0.0)
    rows = []
    for k in range(1, round(duration / DT) + 1):
        t = k * DT
        wl, wr = wheel_profile(t - DT)
        u = SkidSteerInput(wl, wr, *a)
        x = truth.f(x, u, DT) + rng.normal(scale=[0.002, 0.002, 0.0005])
        z_true = truth.h(x, u)
        a = (float(z_true[0]), float(z_true[1]))
        z = z_true + rng.normal(scale=[accel_std, accel_std, gyro_std])
        rows.append((t, wl, wr, z, x.copy()))
    return rows


DATA = simulate()


def feed(est: SkidSteerEstimator, rows, joint_lag: float = 0.0) -> list[tuple[SkidSteerEstimate, np.ndarray]]:
    out = []
    for t, wl, wr, z, x in rows:
        # The joint state of the step's wheel speeds, stamped at the step start (ZOH).
        est.add_joint_state(t - DT + joint_lag, wl * RATIO, wr * RATIO)
        e = est.add_imu(t, *z)
        if e is not None:
            out.append((e, x))
    return out


def all_floats_finite(e: SkidSteerEstimate) -> bool:
    values: list[float] = []
    for f in dataclasses.fields(e):
        v = getattr(e, f.name)
        values.extend(v if isinstance(v, tuple) else [v])
    return all(math.isfinite(float(v)) for v in values)


@pytest.mark.parametrize("variant", ["ukf", "stukf", "an_stukf"])
def test_converges_from_a_wrong_start(variant):
    cfg = SkidSteerEstimatorConfig.paper(filter=variant, initial_state=(1.0, 0.2, 0.05))  # truth starts at (0.5, 0, 0)
    est = SkidSteerEstimator(cfg)
    out = feed(est, DATA)
    assert len(out) == len(DATA)
    assert all(all_floats_finite(e) for e, _ in out)
    first = out[0][0]
    assert first.initialised and not first.accepted and (first.vx, first.vy) == (1.0, 0.2)
    late = [(e, x) for e, x in out if e.t >= 1.0]
    err = np.array([[e.vx - x[0], e.vy - x[1], e.yaw_rate - x[2]] for e, x in late])
    rms, worst = np.sqrt(np.mean(err**2, axis=0)), np.abs(err).max(axis=0)
    assert np.all(rms < [0.01, 0.01, 0.003]), rms
    assert np.all(worst < [0.04, 0.03, 0.01]), worst
    beta_err = np.array([e.body_sideslip - math.atan2(x[1], x[0]) for e, x in late])
    assert np.abs(beta_err).max() < 0.02
    c = est.counters
    assert (c.steps, c.updates_accepted, c.initialisations, c.recoveries) == (len(DATA) - 1, len(DATA) - 1, 1, 0)
    assert c.stale_wheel_speeds == 0 and c.no_wheel_speeds == 0
    # Variances shrink from the initial ones and stay positive.
    e_end = out[-1][0]
    assert 0.0 < e_end.vx_variance < 0.3**2 and 0.0 < e_end.vy_variance < 0.2**2
    assert 0.0 < e_end.yaw_rate_variance < 0.02**2
    if variant == "ukf":
        assert all(e.fading_factor == 1.0 and e.noise_scale == 1.0 for e, _ in out)
    if variant == "an_stukf":
        assert all(e.noise_scale == pytest.approx(1.0 + 5.0 * e.mean_abs_tire_sideslip) for e, _ in out[1:])
        straight = [e.noise_scale for e, _ in out if 0.5 < e.t < 1.9]
        turning = [e.noise_scale for e, _ in out if 2.5 < e.t < 4.9]
        assert max(straight) < 1.02 and min(turning) > 1.25, "Q grows with the tire sideslip of the turn"
    if variant != "ukf":
        # Consistent innovations on the model's own data: strong tracking stays (almost) off.
        assert np.mean([e.fading_factor > 1.0 for e, _ in late]) < 0.05


def test_outputs_match_the_message_fields_and_definitions():
    est = SkidSteerEstimator()
    out = feed(est, DATA[:400])
    e = out[-1][0]  # in the left turn, t = 4 s
    assert e.t == pytest.approx(4.0)
    assert e.slip_right > 0.0 > e.slip_left
    assert e.icr_valid and e.icr_y > 0.0
    assert len(e.tire_sideslip) == 6
    assert e.yaw_rate < e.yaw_rate_encoder
    wl, wr = wheel_profile(4.0 - DT)
    assert (e.wheel_speed_left, e.wheel_speed_right) == pytest.approx((wl, wr), rel=1e-12)
    assert e.vx_encoder == pytest.approx(0.5 * RAD * (wl + wr))
    assert e.body_sideslip == pytest.approx(math.atan2(e.vy, e.vx))
    cov = np.array(e.twist_covariance).reshape(3, 3)
    np.testing.assert_allclose(cov, cov.T)
    assert np.diag(cov) == pytest.approx([e.vx_variance, e.vy_variance, e.yaw_rate_variance])
    jac = np.array([-e.vy, e.vx]) / (e.vx**2 + e.vy**2)
    assert e.body_sideslip_variance == pytest.approx(jac @ cov[:2, :2] @ jac, rel=1e-12)
    # Straight driving: no ICR.
    straight = [e for e, _ in out if 1.0 < e.t < 2.0]
    assert not any(e.icr_valid for e in straight)
    assert all(e.icr_x == 0.0 and e.icr_y == 0.0 for e in straight)
    # The messages: the 3x3 covariance in rows/columns 0, 1, 5 of the twist's 6x6, the unestimated
    # vz, roll and pitch rates a large variance, the rest 0.
    from terrain_estimation.ros.skid_steer import UNESTIMATED_VARIANCE, estimate_to_odom_msg, estimate_to_state_msg

    odom = estimate_to_odom_msg(e, "v/odom", "v/base_link")
    twist_cov = np.asarray(odom.twist.covariance).reshape(6, 6)
    expected = np.diag([0.0, 0.0, UNESTIMATED_VARIANCE, UNESTIMATED_VARIANCE, UNESTIMATED_VARIANCE, 0.0])
    expected[np.ix_([0, 1, 5], [0, 1, 5])] = cov
    np.testing.assert_array_equal(twist_cov, expected)
    assert (odom.twist.twist.linear.x, odom.twist.twist.linear.y, odom.twist.twist.angular.z) == (
        e.vx,
        e.vy,
        e.yaw_rate,
    )
    pose_cov = np.asarray(odom.pose.covariance).reshape(6, 6)
    expected = np.diag([0.0, 0.0, UNESTIMATED_VARIANCE, UNESTIMATED_VARIANCE, UNESTIMATED_VARIANCE, 0.0])
    expected[np.ix_([0, 1, 5], [0, 1, 5])] = np.array(e.pose_covariance).reshape(3, 3)
    np.testing.assert_array_equal(pose_cov, expected)
    assert pose_cov[0, 0] > 0.0 and pose_cov[5, 5] > 0.0 and (pose_cov >= 0.0).all() is not None
    state = estimate_to_state_msg(e, "v/base_link")
    assert tuple(state.tire_sideslip) == e.tire_sideslip and state.header.frame_id == "v/base_link"


def test_dead_reckoning_follows_the_true_path():
    est = SkidSteerEstimator()
    out = feed(est, DATA)
    # Integrate the true twist the same way.
    px = py = yaw = 0.0
    prev = out[0][1]
    for _, x in out[1:]:
        v = 0.5 * (prev + x)
        mid = yaw + 0.5 * DT * v[2]
        px += DT * (math.cos(mid) * v[0] - math.sin(mid) * v[1])
        py += DT * (math.sin(mid) * v[0] + math.cos(mid) * v[1])
        yaw += DT * v[2]
        prev = x
    e = out[-1][0]
    assert math.hypot(px, py) > 8.0
    assert math.hypot(e.x - px, e.y - py) < 0.1
    assert e.yaw == pytest.approx(math.remainder(yaw, 2 * math.pi), abs=0.01)


def test_drain_and_last_estimate():
    est = SkidSteerEstimator()
    assert est.last_estimate is None and est.drain_estimates() == []
    out = feed(est, DATA[:10])
    drained = est.drain_estimates()
    assert drained == [e for e, _ in out] and est.drain_estimates() == []
    assert est.last_estimate is drained[-1]
    est.reset()
    assert est.last_estimate is None and est.counters.steps == 0 and not est.initialised


def test_stale_and_missing_wheel_speeds_are_counted():
    est = SkidSteerEstimator(SkidSteerEstimatorConfig(max_wheel_speed_age_s=0.045, max_step_s=0.1))
    t, wl, wr, z, _ = DATA[0]
    assert est.add_imu(t, *z) is None
    assert est.counters.no_wheel_speeds == 1 and not est.initialised
    feed(est, DATA[:100])  # IMU up to t = 1.00, last joint state stamped 0.99
    steps = est.counters.steps
    # Joint states stop; the IMU goes on. At t = 1.04 the wheel speeds are 0.05 s old: stale.
    produced = [est.add_imu(t, *z) for t, _, _, z, _ in DATA[100:120]]
    c = est.counters
    assert all(e is not None for e in produced[:3]) and all(e is None for e in produced[3:])
    assert c.stale_wheel_speeds == 17 and c.steps == steps + 3
    # Joint states resume: the gap is longer than max_step_s, so the filter restarts.
    feed(est, DATA[120:200])
    c = est.counters
    assert c.restarts == 1
    e = est.last_estimate
    assert e is not None and all_floats_finite(e)
    assert abs(e.vx - DATA[199][4][0]) < 0.05


def test_wheel_speeds_held_and_matched_to_the_imu_stamp():
    # Default: linear interpolation between the samples bracketing the IMU stamp, the newest held beyond it.
    est = SkidSteerEstimator()
    est.add_joint_state(0.00, 10.0 * RATIO, 10.0 * RATIO)
    est.add_joint_state(0.02, 20.0 * RATIO, 20.0 * RATIO)
    e = est.add_imu(0.015, 0.0, 0.0, 0.0)
    assert e is not None and e.wheel_speed_left == pytest.approx(17.5) and e.vx_encoder == pytest.approx(17.5 * RAD)
    e = est.add_imu(0.025, 0.0, 0.0, 0.0)
    assert e is not None and e.wheel_speed_left == pytest.approx(20.0)
    assert (est.counters.wheel_speeds_interpolated, est.counters.wheel_speeds_held) == (1, 1)
    # "hold": the zero-order hold of the newest sample not after the IMU stamp.
    est = SkidSteerEstimator(SkidSteerEstimatorConfig(wheel_speed_interpolation="hold"))
    est.add_joint_state(0.00, 10.0 * RATIO, 10.0 * RATIO)
    est.add_joint_state(0.02, 20.0 * RATIO, 20.0 * RATIO)
    e = est.add_imu(0.015, 0.0, 0.0, 0.0)  # uses the 0.00 sample (the newest not after the IMU)
    assert e is not None and e.wheel_speed_left == pytest.approx(10.0) and e.vx_encoder == pytest.approx(10 * RAD)
    e = est.add_imu(0.025, 0.0, 0.0, 0.0)
    assert e is not None and e.wheel_speed_left == pytest.approx(20.0)
    # A joint state slightly newer than the IMU (within the age limit) is used when nothing older is left.
    est2 = SkidSteerEstimator()
    est2.add_joint_state(0.012, 4.0 * RATIO, 4.0 * RATIO)
    e = est2.add_imu(0.010, 0.0, 0.0, 0.0)
    assert e is not None and e.wheel_speed_right == pytest.approx(4.0)
    # Out-of-order stamps are dropped and counted.
    est2.add_joint_state(0.011, 1.0, 1.0)
    assert est2.add_imu(0.005, 0.0, 0.0, 0.0) is None
    assert est2.counters.joint_out_of_order == 1 and est2.counters.imu_out_of_order == 1


@pytest.mark.parametrize(
    "call, field",
    [
        (lambda e: e.add_imu(1.0, 0.0, math.nan, 0.0), "ay"),
        (lambda e: e.add_imu(1.0, math.inf, 0.0, 0.0), "ax"),
        (lambda e: e.add_imu(1.0, 0.0, 0.0, -math.inf), "yaw_rate"),
        (lambda e: e.add_imu(math.nan, 0.0, 0.0, 0.0), "t"),
        (lambda e: e.add_joint_state(1.0, math.nan, 0.0), "motor_velocity_left"),
        (lambda e: e.add_joint_state(1.0, 0.0, math.inf), "motor_velocity_right"),
        (lambda e: e.set_friction(math.nan), "friction"),
    ],
)
def test_non_finite_input_raises_naming_field_and_value(call, field):
    est = SkidSteerEstimator()
    with pytest.raises(ValueError, match=rf"{field} must be finite, got (nan|inf|-inf)"):
        call(est)
    assert est.counters.imu_samples == 0 and est.counters.joint_states == 0


def test_failed_steps_recover_from_the_last_good_estimate():
    # At rest a 10 ms step needs 34 Euler sub-steps; allowing 2 makes every step fail.
    est = SkidSteerEstimator(SkidSteerEstimatorConfig(max_substeps=2, initial_state=(0.0, 0.0, 0.0)))
    for k in range(5):
        est.add_joint_state(k * DT, 0.0, 0.0)
        e = est.add_imu(k * DT, 0.0, 0.0, 0.0)
        assert e is not None and all_floats_finite(e)
    c = est.counters
    assert c.recoveries == 4 and c.updates_accepted == 0
    assert e.initialised and (e.vx, e.vy, e.yaw_rate) == (0.0, 0.0, 0.0)
    assert e.vx_variance == pytest.approx(0.3**2)


class NaNFilter:
    """Wraps the estimator's filter; its steps return a NaN mean (a filter gone bad)."""

    def __init__(self, inner):
        self.inner = inner

    def initial_state(self, x0, P0):
        return self.inner.initial_state(x0, P0)

    def step(self, state, z, model, u, dt, memory=None):
        post, res = self.inner.step(state, z, model, u, dt, memory)
        return GaussianState(x=np.array([np.nan, post.x[1], post.x[2]]), P=post.P), res


def test_non_finite_filter_state_recovers(monkeypatch):
    est = SkidSteerEstimator()
    feed(est, DATA[:50])
    good = est.last_estimate
    assert good is not None
    monkeypatch.setattr(est, "filter", NaNFilter(est.filter))
    out = feed(est, DATA[50:53])
    assert len(out) == 3 and all(all_floats_finite(e) for e, _ in out)
    assert est.counters.recoveries == 3
    e = out[0][0]
    assert e.initialised and (e.vx, e.vy, e.yaw_rate) == (good.vx, good.vy, good.yaw_rate)
    assert e.vx_variance == pytest.approx(0.3**2)


def test_friction_input_changes_the_saturated_model():
    est = SkidSteerEstimator()
    est.set_friction(0.2)
    assert est._input(1.0, 2.0, (0.0, 0.0)).friction == 0.2
    est.set_friction(None)
    assert est._input(1.0, 2.0, (0.0, 0.0)).friction is None
    with pytest.raises(ValueError, match="friction"):
        est.set_friction(-1.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"filter": "ekf"}, "filter"),
        ({"accel_cutoff_hz": 0.0}, "accel_cutoff_hz"),
        ({"max_wheel_speed_age_s": -1.0}, "max_wheel_speed_age_s"),
        ({"max_step_s": math.inf}, "max_step_s"),
        ({"min_yaw_rate": -0.1}, "min_yaw_rate"),
        ({"k_q": -1.0}, "k_q"),
        ({"friction": 0.0}, "friction"),
        ({"initial_state": (0.0, math.nan, 0.0)}, "initial_state"),
        ({"p0_diag": (1.0, 0.0, 1.0)}, "p0_diag"),
        ({"gate_threshold": 0.0}, "gate_threshold"),
        ({"ukf_alpha": 0.0}, "alpha"),
        ({"r0_diag": (0.01, 0.01, 0.0)}, "r0_diag"),
        ({"max_euler_gain": 3.0}, "max_euler_gain"),
    ],
)
def test_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SkidSteerEstimatorConfig(**kwargs)
