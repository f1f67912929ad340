"""Skid-steer effects in their physical generality (issue 22): stream delays, a bank, turning resistance.

Each bag comes from the truth plant (its own implementation of the effect: buffered encoder
counts, a world-fixed ground plane, a lateral soil force) and is diagnosed by the replay model
(prediction shifts, its own plane and soil force). The engine is given a few competing candidates
only, so that each test runs in a few seconds; the competitor is the effect the bag could be
mistaken for.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from terrain_analysis.sim2real.attribution import attribute
from terrain_analysis.sim2real.model import candidates_from_catalogue
from terrain_analysis.sim2real.skid_steer import SkidSteerReplay, bag_data_from_arrays, vehicle_from_config
from vehicle_sim.effects import effects_for
from vehicle_sim.plants.skid_steer import MANOEUVRES, SkidSteerVehicle, simulate_skid_steer

VEHICLE = vehicle_from_config()


def _bag(manoeuvre: str, effects: dict, duration: float = 8.0, seed: int = 3):
    scenario = MANOEUVRES[manoeuvre](vehicle=SkidSteerVehicle(), effects=effects_for("skid_steer", effects))
    return simulate_skid_steer(replace(scenario, duration=duration), seed)


def _model(result, only: tuple[str, ...]) -> SkidSteerReplay:
    data = bag_data_from_arrays(
        result.t,
        result.linear_acceleration,
        result.angular_velocity[:, 2],
        result.t,
        result.motor_velocity,
        transmission_ratio=VEHICLE.transmission_ratio,
    )
    return SkidSteerReplay(data, VEHICLE, warmup=1.0, candidates=candidates_from_catalogue("skid_steer", only=only))


@pytest.mark.parametrize("stream", ["wheel_speed_delay", "sensor_delay"])
def test_a_single_stream_delay_of_0_2_s_is_recovered_on_its_stream(stream):
    # 0.2 s on one stream only (beyond the old 0.1 s cap, which also had no encoder-stream delay).
    result = _bag("s_shape", {stream: {stream: 0.2}})
    model = _model(result, ("sensor_delay", "wheel_speed_delay", "gyro_bias"))
    report = attribute(model)
    best = report.ranking[0]
    assert best.name == stream, report.verdict
    assert best.parameters[stream][stream] == pytest.approx(0.2, abs=0.01)
    other = "sensor_delay" if stream == "wheel_speed_delay" else "wheel_speed_delay"
    wrong = next(m for m in report.ranking if m.name == other)
    assert wrong.parameters[other][other] < 0.01  # the other stream's delay cannot explain it (wrong sign)


def test_a_5_degree_bank_is_fitted_as_a_bank_not_an_accelerometer_bias():
    bank = math.radians(5.0)
    result = _bag("s_shape", {"terrain_grade": {"terrain_bank": bank}})
    report = attribute(_model(result, ("terrain_grade", "accel_bias")))
    best, second = report.ranking[0], report.ranking[1]
    assert best.name == "terrain_grade", report.verdict
    assert best.parameters["terrain_grade"]["terrain_bank"] == pytest.approx(bank, rel=0.03)
    assert abs(best.parameters["terrain_grade"]["terrain_grade"]) < 0.005
    # Turning, the world-fixed slope turns in the body frame and a bias does not: the held-out data tell them apart.
    assert second.name == "accel_bias" and second.score - best.score > 100.0, (best.score, second.score)


def test_on_a_straight_run_a_bank_and_a_bias_read_the_same():
    # What physics does not allow: without a heading change the IMU sees g sin β on y, g (cos β − 1) on z, as a
    # bias would; the lateral tire forces and the load shift that hold the vehicle move the yaw rate by far less
    # than the gyro noise. The replay with the bank and with the equivalent bias agree within the noise budget.
    bank = math.radians(5.0)
    result = _bag("straight_acceleration", {"terrain_grade": {"terrain_bank": bank}}, duration=4.0)
    model = _model(result, ("terrain_grade", "accel_bias"))
    g = VEHICLE.gravity
    with_bank = model.predict({"terrain_grade": {"terrain_bank": bank}}, {})
    bias = {"accel_bias_x": 0.0, "accel_bias_y": g * math.sin(bank), "accel_bias_z": g * (math.cos(bank) - 1.0)}
    with_bias = model.predict({"accel_bias": bias}, {})
    use = model.data.t >= 1.0
    for c in model.channels:
        difference = np.sqrt(np.mean((with_bank[c.name] - with_bias[c.name])[use] ** 2))
        assert difference < 0.3 * c.noise_std, (c.name, difference, c.noise_std)


def test_turning_resistance_is_recovered_with_its_sign():
    c_b = 0.25
    result = _bag("s_shape", {"turning_resistance": {"turning_resistance": c_b}})
    model = _model(result, ("turning_resistance", "cornering_stiffness_change", "friction_change"))
    # The soil's lateral resistance is a resistive yaw moment: on the same wheel speeds the vehicle turns less.
    use = model.data.t >= 1.0
    nominal = model.predict({}, {})["yaw_rate"][use]
    resisted = model.predict({"turning_resistance": {"turning_resistance": c_b}}, {})["yaw_rate"][use]
    assert np.mean(np.abs(resisted)) < 0.97 * np.mean(np.abs(nominal))
    assert np.mean(np.abs(model.measured["yaw_rate"][use])) < 0.97 * np.mean(np.abs(nominal))
    report = attribute(model)
    best = report.ranking[0]
    assert best.name == "turning_resistance", report.verdict
    assert best.parameters["turning_resistance"]["turning_resistance"] == pytest.approx(c_b, rel=0.1)
