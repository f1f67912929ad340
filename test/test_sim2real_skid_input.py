"""The skid-steer replay's input band (sim2real.skid_steer_input): why the wheel speeds are low-passed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from test_sim2real_skid_steer import _data

from terrain_analysis.sim2real.skid_steer import (
    DIAGNOSIS_STEP,
    SkidSteerReplay,
    input_bandwidth,
    smooth_wheel_speeds,
    vehicle_from_config,
    with_vehicle,
)
from terrain_analysis.sim2real.skid_steer_bag import SkidSteerBagData
from vehicle_sim.effects import effects_for
from vehicle_sim.plants.skid_steer import MANOEUVRES, SkidSteerSensors, SkidSteerVehicle, simulate_skid_steer

VEHICLE = vehicle_from_config()


def test_bandwidth_is_where_the_replayed_report_noise_meets_the_accelerometer_noise():
    # 4096 counts/rev, 100 Hz reports, 0.02 rad/s motor noise, 0.05 m/s² accelerometer: ≈ 13.7 Hz.
    f_q = input_bandwidth(VEHICLE, 0.01, 0.01)
    assert f_q is not None and 12.0 < f_q < 15.5
    # A finer encoder or a noisier accelerometer moves it up; an exact drive needs no filter at all.
    finer = input_bandwidth(with_vehicle(VEHICLE, encoder_step=VEHICLE.encoder_step / 4), 0.01, 0.01)
    assert finer is not None and finer > f_q
    noisier = input_bandwidth(with_vehicle(VEHICLE, accel_noise_std=0.2), 0.01, 0.01)
    assert noisier is None or noisier > f_q
    exact = with_vehicle(VEHICLE, encoder_step=0.0, wheel_speed_noise_std=0.0, speed_step=0.0)
    assert input_bandwidth(exact, 0.01, 0.01) is None


def test_smoothing_is_zero_phase_and_leaves_slow_motion_alone():
    t = np.arange(0.0, 20.0, 0.01)
    slow = np.column_stack([np.sin(2 * np.pi * 1.0 * t), 2.0 + 0.5 * t])
    out = smooth_wheel_speeds(t, slow, 13.7)
    inner = slice(100, -100)
    np.testing.assert_allclose(out[inner], slow[inner], atol=2e-3)
    # No delay: the 1 Hz sine's cross-correlation peaks at lag 0.
    lags = range(-5, 6)
    xc = [np.dot(np.roll(out[inner, 0], k), slow[inner, 0]) for k in lags]
    assert list(lags)[int(np.argmax(xc))] == 0
    assert smooth_wheel_speeds(t, slow, None) is not None
    np.testing.assert_array_equal(smooth_wheel_speeds(t, slow, None), slow)
    np.testing.assert_array_equal(smooth_wheel_speeds(t, slow, 60.0), slow)  # above Nyquist: as is


def _launch(seed: int) -> SkidSteerBagData:
    # The nominal model's vehicle (brush tire) from rest; an exact IMU, so that only the encoder's
    # quantisation and report noise (and the replay's own error) stand between the bag and the replay.
    sensors = replace(SkidSteerSensors.noiseless(), encoder_counts_per_revolution=4096, motor_velocity_noise_std=0.02)
    scenario = MANOEUVRES["straight_acceleration"](vehicle=SkidSteerVehicle(), effects=effects_for("skid_steer", {}))
    return _data(simulate_skid_steer(replace(scenario, duration=4.0, sensors=sensors), seed))


@pytest.mark.parametrize("seed", [1, 2])
def test_low_passed_input_removes_the_launch_bias_towards_a_soft_tire(seed):
    # From rest the replay differentiates the reported speed: a softer tire (lower C_x) filters the report
    # noise and fits the launch better than the true one (errors in the input variables). Low-passed at the
    # input band, the true C_x fits best.
    data = _launch(seed)
    window = (data.t >= 1.0) & (data.t < 3.0)

    def sse(bandwidth: float | None, scale: float) -> float:
        model = SkidSteerReplay(
            data,
            VEHICLE,
            nuisance=("longitudinal_stiffness_scale",),
            warmup=1.0,
            integration_step=DIAGNOSIS_STEP,
            wheel_speed_bandwidth=bandwidth,
        )
        pred = model.predict({}, {"longitudinal_stiffness_scale": scale})["ax"]
        return float(np.sum((model.measured["ax"][window] - pred[window]) ** 2))

    assert sse(None, 0.7) < sse(None, 1.0)
    f_q = input_bandwidth(VEHICLE, 0.01, 0.01)
    assert sse(f_q, 1.0) < sse(f_q, 0.7)
    assert sse(f_q, 1.0) < 0.5 * sse(None, 1.0)
