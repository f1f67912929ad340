"""Issue 20 item 5: wheel speeds at any rate. Interpolated between the samples that bracket the IMU stamp,
held beyond the newest within an age limit that follows the measured wheel-speed period, counted, and stated
in the offline summary. The BorealTC Husky's 6.5 Hz wheel speeds are used with the defaults."""

from __future__ import annotations

import math

import pytest

from terrain_estimation.estimators.skid_steer import SkidSteerEstimator, SkidSteerEstimatorConfig
from terrain_estimation.estimators.skid_steer_wheels import WheelSpeedBuffer
from terrain_estimation.models.skid_steer import SkidSteerParams

P = SkidSteerParams()
RATIO = P.transmission_ratio
WHEEL_PERIOD = 1.0 / 6.5


def _wheel(t: float) -> float:
    """Wheel-side speed (rad/s) of a ramp: 2 m/s + 0.5 m/s² t."""
    return (2.0 + 0.5 * t) / P.wheel_radius


def _feed(est: SkidSteerEstimator, seconds: float = 4.0) -> list:
    """100 Hz IMU, 6.5 Hz wheel speeds, each message at its stamp (a live stream)."""
    events = [(round(0.01 * k, 6), "imu") for k in range(1, int(seconds * 100) + 1)]
    events += [(round(k * WHEEL_PERIOD, 6), "joint") for k in range(int(seconds * 6.5) + 1)]
    for t, kind in sorted(events, key=lambda e: (e[0], e[1] == "imu")):  # a joint state first at equal stamps
        if kind == "joint":
            est.add_joint_state(t, _wheel(t) * RATIO, _wheel(t) * RATIO)
        else:
            est.add_imu(t, 0.5, 0.0, 0.0)
    return est.drain_estimates()


def test_buffer_interpolates_holds_and_measures_the_period():
    buf = WheelSpeedBuffer()
    assert buf.at(0.0) is None and buf.period_s is None and buf.max_age_s == 0.05
    for k in range(10):
        assert buf.add(k * 0.2, float(k), -float(k))
    assert not buf.add(1.0, 0.0, 0.0)  # not newer than the newest
    assert buf.period_s == pytest.approx(0.2) and buf.max_age_s == pytest.approx(0.5)
    assert buf.at(0.5) == pytest.approx((2.5, -2.5, "interpolated"))
    assert buf.at(0.4) == (2.0, -2.0, "interpolated")
    assert buf.at(1.8 + 0.3) == (9.0, -9.0, "held")
    assert buf.at(1.8 + 0.51) is None  # beyond 2.5 periods of the newest
    hold = WheelSpeedBuffer("hold")
    for k in range(3):
        hold.add(k * 0.2, float(k), float(k))
    assert hold.at(0.35) == (1.0, 1.0, "held")
    fixed = WheelSpeedBuffer(max_age_s=0.1)
    for k in range(3):
        fixed.add(k * 0.2, float(k), float(k))
    assert fixed.max_age_s == 0.1 and fixed.at(0.55) is None  # 0.15 s after the newest sample
    assert fixed.at(0.45) == (2.0, 2.0, "held")
    with pytest.raises(ValueError, match="interpolation"):
        WheelSpeedBuffer("cubic")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="max_age_s"):
        WheelSpeedBuffer(max_age_s=-1.0)


def test_wheel_speeds_at_6_5_hz_are_used_for_every_imu_sample():
    est = SkidSteerEstimator()
    out = _feed(est)
    c = est.counters
    # Only the start: before the second wheel-speed sample the period is unknown (0.05 s floor).
    assert c.stale_wheel_speeds <= int(WHEEL_PERIOD / 0.01)
    assert len(out) >= c.imu_samples - c.stale_wheel_speeds - c.no_wheel_speeds
    late = [e for e in out if e.t > 2 * WHEEL_PERIOD]
    assert len(late) == sum(1 for k in range(1, 401) if 0.01 * k > 2 * WHEEL_PERIOD)
    assert est.wheel_speed_period_s == pytest.approx(WHEEL_PERIOD, abs=1e-6)
    assert est.wheel_speed_max_age_s == pytest.approx(2.5 * WHEEL_PERIOD, abs=1e-5)
    # Live: the IMU sample comes before the next wheel speed, so the newest is held.
    assert c.wheel_speeds_held > 0.8 * c.steps
    # The former fixed 0.05 s limit dropped two thirds of them (issue 20: 1312 of 4092 on BorealTC).
    old = SkidSteerEstimator(SkidSteerEstimatorConfig(max_wheel_speed_age_s=0.05, wheel_speed_interpolation="hold"))
    _feed(old)
    assert old.counters.stale_wheel_speeds > 0.5 * old.counters.imu_samples


def test_waiting_for_the_next_wheel_speed_interpolates_every_imu_sample():
    est = SkidSteerEstimator(SkidSteerEstimatorConfig(wheel_speed_wait_s=0.2))
    out = _feed(est)
    c = est.counters
    assert c.wheel_speeds_interpolated > 0.9 * c.steps and c.stale_wheel_speeds == 0
    # The wheel speeds of each step are the ramp's at its stamp (linear in t: interpolation is exact).
    for e in out[1:]:
        assert e.wheel_speed_left == pytest.approx(_wheel(e.t), rel=1e-9)
    assert [e.t for e in out] == sorted(e.t for e in out)


def test_summary_states_method_rate_and_counts():
    from terrain_estimation.ros.skid_steer import SkidSteerAdapter
    from terrain_estimation.tools.estimate import config_values
    from terrain_estimation.vehicles import get_vehicle

    adapter = SkidSteerAdapter(config_values(get_vehicle("skid_steer")), "/skid_steer")
    _feed(adapter.estimator)
    text = "\n".join(adapter.summary_lines())
    assert "linear (6.5 Hz measured" in text and "age limit 0.385 s" in text
    c = adapter.estimator.counters
    assert f"{c.wheel_speeds_interpolated} interpolated, {c.wheel_speeds_held} held" in text
    assert f"{c.stale_wheel_speeds} IMU samples stale" in text
    assert not math.isnan(float(adapter._wheel_speed_values()["wheel_speed_rate_hz"]))
