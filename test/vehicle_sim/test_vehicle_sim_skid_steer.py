"""Truth plant of the six-wheel skid-steered vehicle (MODELS.md B.2–B.6, B.11)."""

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq

from terrain_estimation.models.skid_steer import (
    SkidSteerParams,
    brush_tire_forces,
    quasi_static_loads,
)
from vehicle_sim.plants.skid_steer import (
    MANOEUVRES,
    Manoeuvre,
    SkidSteerDriver,
    SkidSteerEffects,
    SkidSteerScenario,
    SkidSteerSensors,
    SkidSteerSimulator,
    SkidSteerVehicle,
    constant_torque,
    simulate_skid_steer,
    small_radius_turn,
    straight_acceleration,
)

VEHICLE = SkidSteerVehicle()
P = VEHICLE.nominal
QUIET = SkidSteerSensors.noiseless()


def standstill(effects: SkidSteerEffects, duration: float = 0.2) -> SkidSteerScenario:
    return SkidSteerScenario(manoeuvre=Manoeuvre(name="standstill", duration=duration), effects=effects, sensors=QUIET)


def balancing_torque(vehicle: SkidSteerVehicle = VEHICLE) -> float:
    """Motor torque per side whose thrust equals the motion resistance f_rr m g (both sides)."""
    p = vehicle.nominal
    return (
        p.wheel_radius
        * vehicle.rolling_resistance
        * p.mass
        * p.gravity
        / (2.0 * vehicle.transmission_efficiency * p.transmission_ratio)
    )


def slip_for_side_thrust(thrust: float, side_loads: np.ndarray, p: SkidSteerParams = P) -> float:
    """Pure longitudinal slip σ_x at which the brush forces of one side's three wheels sum to ``thrust``."""

    def excess(sigma: float) -> float:
        fx, _ = brush_tire_forces(
            sigma,
            0.0,
            side_loads,
            longitudinal_stiffness=p.longitudinal_stiffness,
            cornering_stiffness=p.cornering_stiffness,
            friction=p.friction,
        )
        return float(np.sum(fx)) - thrust

    return brentq(excess, 0.0, 0.9, xtol=1e-15, rtol=1e-15)


def prony_eigenvalues(signal: np.ndarray, order: int, period: float) -> np.ndarray:
    """Continuous-time eigenvalues of a noise-free free response (linear prediction)."""
    rows = np.column_stack([signal[order - j - 1 : len(signal) - j - 1] for j in range(order)])
    coeffs, *_ = np.linalg.lstsq(rows, signal[order:], rcond=None)
    roots = np.roots(np.concatenate([[1.0], -coeffs]))
    return np.log(roots.astype(complex)) / period


@pytest.fixture(scope="module")
def turn():
    """The paper's small-radius turn, truth effects (roll/pitch dynamics, tire relaxation), noisy sensors."""
    return simulate_skid_steer(small_radius_turn(), seed=0)


@pytest.fixture(scope="module")
def straight():
    """0 → 30 km/h, truth effects, noise-free sensors."""
    return simulate_skid_steer(straight_acceleration(sensors=QUIET), seed=0)


# --- parameters ---------------------------------------------------------------


def test_default_suspension_modes_and_mass_split():
    assert 1.5 <= VEHICLE.roll_natural_frequency <= 2.0
    assert 1.5 <= VEHICLE.pitch_natural_frequency <= 2.0
    assert 0.3 <= VEHICLE.roll_damping_ratio <= 0.5
    assert 0.3 <= VEHICLE.pitch_damping_ratio <= 0.5
    # The sprung and unsprung masses keep the whole vehicle's CM at Table 1's H.
    total = VEHICLE.sprung_mass * VEHICLE.sprung_cg_height + VEHICLE.unsprung_mass * P.wheel_radius
    assert total == pytest.approx(P.mass * P.cg_height, rel=1e-12)
    # Reflected motor inertia i_g² J_m dominates the drive side.
    assert VEHICLE.side_inertia == pytest.approx(3 * 2.0 + 27.13**2 * 0.02, rel=1e-12)


@pytest.mark.parametrize(
    ("factory", "field", "value"),
    [
        (SkidSteerVehicle, "wheel_inertia", -1.0),
        (SkidSteerVehicle, "transmission_efficiency", 1.5),
        (SkidSteerVehicle, "rolling_resistance", float("nan")),
        (SkidSteerVehicle, "roll_stiffness", 1000.0),
        (SkidSteerVehicle, "roll_centre_height", 0.9),
        (SkidSteerVehicle, "unsprung_mass_per_wheel", 600.0),
        (SkidSteerEffects, "friction_change", 0.0),
        (SkidSteerEffects, "wheel_radius_error", 0.7),
        (SkidSteerEffects, "sensor_delay", -0.01),
        (SkidSteerEffects, "terrain_grade", 1.0),
        (SkidSteerSensors, "accel_noise_std", -0.1),
        (SkidSteerSensors, "encoder_counts_per_revolution", 0),
        (SkidSteerSensors, "gnss_rate", -10.0),
        (SkidSteerDriver, "yaw_rate_gain", -1.0),
    ],
)
def test_invalid_parameters_name_field_and_value(factory, field, value):
    with pytest.raises(ValueError, match=rf"{factory.__name__}\.{field}.*{value}"):
        factory(**{field: value})


def test_invalid_scenario_and_manoeuvre_values():
    manoeuvre = Manoeuvre(name="m", duration=1.0)
    with pytest.raises(ValueError, match=r"gnss_rate.*30\.0"):
        SkidSteerScenario(manoeuvre=manoeuvre, sensors=SkidSteerSensors(gnss_rate=30.0))
    with pytest.raises(ValueError, match=r"SkidSteerScenario\.integration_step.*0\.0"):
        SkidSteerScenario(manoeuvre=manoeuvre, integration_step=0.0)
    with pytest.raises(ValueError, match=r"Manoeuvre\.duration.*-1\.0"):
        Manoeuvre(name="m", duration=-1.0)
    with pytest.raises(ValueError, match=r"Manoeuvre\.speed_times.*\(1\.0,\)"):
        Manoeuvre(name="m", duration=1.0, speed_times=(1.0,), speeds=(0.0,))
    with pytest.raises(ValueError, match=r"accel_bias"):
        SkidSteerEffects(accel_bias=(1.0, 2.0))  # type: ignore[arg-type]


def test_effect_sets():
    assert SkidSteerEffects.nominal().active == ()
    assert SkidSteerEffects.truth_default().active == ("load_transfer_dynamics", "tire_relaxation")
    assert SkidSteerScenario(manoeuvre=Manoeuvre(name="m", duration=1.0)).effects == SkidSteerEffects.nominal()
    assert SkidSteerScenario(manoeuvre=Manoeuvre(name="m", duration=1.0)).vehicle.tire_law == "brush"
    for name, build in MANOEUVRES.items():
        scenario = build()
        assert scenario.manoeuvre.name == name
        assert scenario.effects == SkidSteerEffects.truth_default()
        # The truth runs the plant's own tire whatever the effects; the brush is asked for by name.
        assert scenario.vehicle == SkidSteerVehicle.truth_default()
        assert scenario.vehicle.tire_law == "magic_formula"
        assert build(effects=SkidSteerEffects.nominal()).vehicle.tire_law == "magic_formula"
        assert build(vehicle=SkidSteerVehicle(), effects=SkidSteerEffects.nominal()).vehicle.tire_law == "brush"
    assert {name: build().run_duration for name, build in MANOEUVRES.items()} == {
        "straight_acceleration": 20.0,
        "small_radius_turn": 45.0,
        "s_shape": 30.0,
    }


# --- statics ------------------------------------------------------------------


@pytest.mark.parametrize(
    "effects", [SkidSteerEffects.nominal(), SkidSteerEffects.truth_default()], ids=["nominal", "truth"]
)
def test_at_rest_imu_reads_plus_g_and_loads_carry_the_weight(effects):
    result = simulate_skid_steer(standstill(effects), seed=0)
    np.testing.assert_array_equal(result.linear_acceleration[:, :2], 0.0)
    np.testing.assert_allclose(result.linear_acceleration[:, 2], P.gravity, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(result.angular_velocity, 0.0)
    np.testing.assert_allclose(result.truth.normal_load.sum(axis=1), P.mass * P.gravity, rtol=1e-12)
    np.testing.assert_allclose(result.truth.normal_load, quasi_static_loads(0.0, 0.0, P)[None, :].repeat(20, 0))
    np.testing.assert_array_equal(result.truth.vx, 0.0)
    np.testing.assert_array_equal(result.motor_position, 0.0)


# --- longitudinal dynamics: closed forms with the effects off -------------------


def test_balanced_torque_steady_state_force_balance_and_brush_slip():
    torque = balancing_torque()
    result = simulate_skid_steer(constant_torque(torque, torque, initial_speed=5.0, duration=4.0, sensors=QUIET), 0)
    truth = result.truth
    late = result.t > 3.0
    # Traction equals motion resistance on every side ...
    thrust = truth.tire_force_x[late].reshape(-1, 2, 3).sum(axis=2)
    resistance = truth.motion_resistance[late].reshape(-1, 2, 3).sum(axis=2)
    np.testing.assert_allclose(thrust, resistance, rtol=1e-6)
    np.testing.assert_allclose(thrust, 0.5 * VEHICLE.rolling_resistance * P.mass * P.gravity, rtol=1e-6)
    # ... so the speed holds, ...
    assert np.ptp(truth.vx[late]) < 1e-7
    # ... and the wheels turn faster than the ground by the brush model's slip for that thrust.
    sigma = slip_for_side_thrust(thrust[-1, 0], quasi_static_loads(0.0, 0.0, P)[:3])
    assert 1e-3 < sigma < 1e-2
    np.testing.assert_allclose(truth.slip[late], sigma, rtol=1e-6)
    rolling = P.wheel_radius * truth.wheel_speed[late, 0]
    np.testing.assert_allclose(truth.vx[late], rolling * (1.0 - sigma), rtol=1e-9)


def test_excess_torque_accelerates_at_the_closed_form_rate():
    torque = balancing_torque() + 20.0
    scenario = constant_torque(torque, torque, initial_speed=2.0, duration=4.0, sensors=QUIET)
    result = simulate_skid_steer(scenario, seed=0)
    late = result.t > 1.0
    measured = np.polyfit(result.t[late], result.truth.vx[late], 1)[0]
    # m v̇ = 2 F_side − F_rr,  I_side ω̇ = η i_g T − R F_side,  v = R ω (1 − σ) with σ constant.
    resistance = VEHICLE.rolling_resistance * P.mass * P.gravity
    drive = 2.0 * VEHICLE.transmission_efficiency * P.transmission_ratio * torque / P.wheel_radius
    accel, sigma = (drive - resistance) / P.mass, 0.0
    for _ in range(30):
        side_thrust = 0.5 * (P.mass * accel + resistance)
        sigma = slip_for_side_thrust(side_thrust, quasi_static_loads(accel, 0.0, P)[:3])
        accel = (drive - resistance) / (P.mass + 2.0 * VEHICLE.side_inertia / (P.wheel_radius**2 * (1.0 - sigma)))
    assert measured == pytest.approx(accel, rel=1e-5)
    assert measured == pytest.approx(0.789, abs=0.01)
    np.testing.assert_allclose(result.truth.slip[late], sigma, rtol=1e-4)
    # Accelerometer on level ground, no tilt: the specific force is the acceleration.
    np.testing.assert_allclose(result.linear_acceleration[late, 0], accel, rtol=1e-5)


def test_pitch_step_response_has_the_suspension_eigenvalues():
    # Constant thrust from a steady roll: f_x steps and stays constant; the pitch answers as
    # I_θ θ̈ + C_θ θ̇ + (K_θ − m_s g (H_s − h_pc)) θ = −m_s f_x (H_s − h_pc).
    torque = balancing_torque() + 40.0
    effects = SkidSteerEffects(load_transfer_dynamics=True)
    result = simulate_skid_steer(constant_torque(torque, torque, initial_speed=3.0, duration=3.0, effects=effects), 0)
    pitch = result.truth.pitch[result.t > 0.05]
    eigenvalues = prony_eigenvalues(pitch, 3, 0.01)
    pair = eigenvalues[np.abs(eigenvalues.imag) > 1.0]
    v = VEHICLE
    expected = np.roots(
        [v.pitch_axis_inertia, v.pitch_damping, v.pitch_stiffness - v.sprung_mass * P.gravity * v.pitch_arm]
    )
    np.testing.assert_allclose(np.sort_complex(pair), np.sort_complex(expected), rtol=2e-3)
    f_x = result.truth.specific_force_x[-1]
    assert result.truth.pitch[-1] < 0.0  # squat: nose up under traction
    steady = brentq(
        lambda th: v.pitch_stiffness * th - v.sprung_mass * v.pitch_arm * (P.gravity * math.sin(th) - f_x), -0.1, 0.1
    )
    assert result.truth.pitch[-1] == pytest.approx(steady, rel=1e-4)


# --- load transfer --------------------------------------------------------------


def tilt_corrected_quasi_static_loads(truth, mask):
    """B.5 loads with the extra moment of the tilted sprung CM (gravity acting through the roll/pitch shift)."""
    v = VEHICLE
    m_h = P.mass * P.cg_height
    f_x = truth.specific_force_x[mask] - v.sprung_mass * P.gravity * v.pitch_arm * np.sin(truth.pitch[mask]) / m_h
    f_y = truth.specific_force_y[mask] + v.sprung_mass * P.gravity * v.roll_arm * np.sin(truth.roll[mask]) / m_h
    return quasi_static_loads(f_x, f_y, P)


def test_settled_dynamic_loads_reproduce_the_quasi_static_formula(turn):
    window = turn.window(20.0, 40.0)
    truth = turn.truth
    # The roll/pitch transient of the turn entry has decayed to ≤ 3e-7 of the loads by 20 s (magic-formula truth).
    np.testing.assert_allclose(truth.normal_load[window], tilt_corrected_quasi_static_loads(truth, window), rtol=5e-7)
    # The tilt term is real but small next to B.5.
    plain = quasi_static_loads(truth.specific_force_x[window], truth.specific_force_y[window], P)
    difference = np.abs(truth.normal_load[window] - plain).max()
    assert 1.0 < difference < 0.01 * P.mass * P.gravity / 6
    # Left turn: the outer (right) side carries more; the body rolls outward (left side up).
    assert np.all(truth.normal_load[window][:, 3:].sum(axis=1) > truth.normal_load[window][:, :3].sum(axis=1))
    roll = truth.roll[window]
    v = VEHICLE
    f_y = truth.specific_force_y[window]
    # I φ̈ + C φ̇ + K φ = m_s (H_s − h_rc)(f_y + g sin φ): the sprung-mass roll equation.
    roll_accel = np.gradient(truth.roll_rate, turn.t)[window]
    suspension = v.roll_axis_inertia * roll_accel + v.roll_damping * truth.roll_rate[window] + v.roll_stiffness * roll
    np.testing.assert_allclose(suspension, v.sprung_mass * v.roll_arm * (f_y + P.gravity * np.sin(roll)), rtol=1e-6)
    assert np.all(roll > 0.0)


def test_dynamic_loads_lag_the_acceleration(straight):
    truth = straight.truth
    quasi = tilt_corrected_quasi_static_loads(truth, slice(None))
    transfer_front = quasi[:, 0] - truth.normal_load[0, 0]
    actual_front = truth.normal_load[:, 0] - truth.normal_load[0, 0]
    # 50 ms after the acceleration starts the springs have passed on only part of the transfer ...
    early = np.argmin(np.abs(straight.t - 1.05))
    assert transfer_front[early] < -80.0
    assert abs(actual_front[early]) < 0.8 * abs(transfer_front[early])
    # ... in the steady acceleration they have caught up.
    steady = straight.window(4.0, 8.0)
    np.testing.assert_allclose(actual_front[steady], transfer_front[steady], rtol=5e-3)


def test_quasi_static_loads_follow_the_acceleration_without_load_dynamics():
    torque = balancing_torque() + 20.0
    result = simulate_skid_steer(constant_torque(torque, torque, initial_speed=2.0, duration=1.0, sensors=QUIET), 0)
    truth = result.truth
    late = result.t > 0.2
    np.testing.assert_allclose(
        truth.normal_load[late],
        quasi_static_loads(truth.specific_force_x[late], truth.specific_force_y[late], P),
        rtol=1e-9,
    )
    np.testing.assert_array_equal(truth.roll, 0.0)
    np.testing.assert_array_equal(truth.pitch, 0.0)


# --- tires ----------------------------------------------------------------------


def test_tire_relaxation_lags_the_steady_forces(turn):
    truth = turn.truth
    settled = turn.window(20.0, 40.0)
    np.testing.assert_allclose(truth.tire_force_y[settled], truth.steady_tire_force_y[settled], rtol=1e-4)
    entry = turn.window(6.0, 9.0)
    lag = np.abs(truth.tire_force_y[entry] - truth.steady_tire_force_y[entry]).max()
    assert lag > 50.0


def test_without_relaxation_the_forces_are_the_steady_ones():
    result = simulate_skid_steer(constant_torque(-60.0, 120.0, duration=1.0, sensors=QUIET), 0)
    np.testing.assert_array_equal(result.truth.tire_force_x, result.truth.steady_tire_force_x)
    np.testing.assert_array_equal(result.truth.tire_force_y, result.truth.steady_tire_force_y)


# --- the paper's manoeuvres -------------------------------------------------------


def test_small_radius_turn_matches_the_experiment_conditions(turn):
    window = turn.window(20.0, 40.0)
    truth = turn.truth
    yaw_rate = truth.yaw_rate[window]
    speed = np.hypot(truth.vx[window], truth.vy[window])
    assert yaw_rate.mean() == pytest.approx(0.2, abs=1e-3)
    assert speed.mean() == pytest.approx(5.0 / 3.6, abs=0.01)
    assert (speed / yaw_rate).mean() == pytest.approx(7.0, abs=0.1)
    # Outer (right) side slips positive, inner (left) negative (paper).
    assert np.all(truth.slip[window, 1] > 0.05)
    assert np.all(truth.slip[window, 0] < -0.05)
    # Encoder-only yaw rate R(ω_r − ω_l)/B from the motor encoders overestimates the true one (paper).
    wheel = turn.motor_velocity[window] / P.transmission_ratio
    encoder_yaw_rate = P.wheel_radius * (wheel[:, 1] - wheel[:, 0]) / P.track
    assert encoder_yaw_rate.mean() > 1.5 * yaw_rate.mean()
    # ICR on the left (paper).
    assert np.all(truth.icr_valid[window])
    assert np.all(truth.icr_y[window] > 5.0)
    # The counter-clockwise circle closes: heading grows by r per second.
    assert truth.yaw[window][-1] - truth.yaw[window][0] == pytest.approx(0.2 * 20.0, rel=5e-3)


def test_straight_acceleration_reaches_30_kmh_and_slip_falls_at_steady_speed(straight):
    truth = straight.truth
    held = straight.window(15.0, 20.0)
    np.testing.assert_allclose(truth.vx[held], 30.0 / 3.6, rtol=2e-3)
    np.testing.assert_allclose(truth.yaw_rate, 0.0, atol=1e-12)
    accelerating = straight.window(3.0, 8.0)
    assert truth.slip[accelerating].min() > 5.0 * truth.slip[held].max()
    assert truth.slip[held].max() < 0.01
    np.testing.assert_allclose(truth.slip[:, 0], truth.slip[:, 1], atol=1e-12)


# --- sensors --------------------------------------------------------------------


def test_imu_tilts_with_the_body_in_a_steady_turn(turn):
    # The specific force seen in the rolled and pitched IMU frame (noise averaged out over 20 s).
    window = turn.window(20.0, 40.0)
    truth = turn.truth
    roll, pitch = truth.roll[window], truth.pitch[window]
    f_x, f_y = truth.specific_force_x[window], truth.specific_force_y[window]
    g = P.gravity
    x_pitched = np.cos(pitch) * f_x - np.sin(pitch) * g
    z_pitched = np.sin(pitch) * f_x + np.cos(pitch) * g
    expected_y = np.cos(roll) * f_y + np.sin(roll) * z_pitched
    mean_noise = 5.0 * turn.scenario.sensors.accel_noise_std / math.sqrt(window.sum())
    assert abs(np.mean(turn.linear_acceleration[window, 0] - x_pitched)) < mean_noise
    assert abs(np.mean(turn.linear_acceleration[window, 1] - expected_y)) < mean_noise
    # Gravity through the roll adds g sin φ ≈ 0.015 m/s² to the lateral reading (model error of the observer).
    tilt = np.mean(turn.linear_acceleration[window, 1] - f_y)
    assert tilt == pytest.approx(g * np.mean(roll), rel=0.1)
    assert tilt > 10 * mean_noise / 5.0


def test_sensor_noise_levels_and_encoder_quantisation(turn):
    sensors = turn.scenario.sensors
    window = turn.window(20.0, 40.0)
    truth = turn.truth
    gyro_error = turn.angular_velocity[window, 2] - truth.yaw_rate[window]
    assert gyro_error.std() == pytest.approx(sensors.gyro_noise_std, rel=0.05)
    assert abs(gyro_error.mean()) < 4 * sensors.gyro_noise_std / math.sqrt(gyro_error.size)
    accel_error = turn.linear_acceleration[window, 0] - truth.specific_force_x[window]
    assert accel_error.std() == pytest.approx(sensors.accel_noise_std, rel=0.05)
    effort_error = turn.motor_effort[window] - truth.motor_torque[window]
    assert effort_error.std() == pytest.approx(sensors.motor_effort_noise_std, rel=0.05)
    step = 2 * math.pi / sensors.encoder_counts_per_revolution
    counts = turn.motor_position / step
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    # Velocity: differenced position over the period plus noise.
    velocity_error = turn.motor_velocity[1:] - np.diff(turn.motor_position, axis=0) / 0.01
    assert velocity_error.std() == pytest.approx(sensors.motor_velocity_noise_std, rel=0.05)


def test_gnss_reference_at_10_hz(turn):
    gnss = turn.gnss
    assert gnss.t.size == 450
    np.testing.assert_allclose(gnss.t, 0.1 * np.arange(1, 451), atol=1e-12)
    on_gnss = np.isin(np.round(turn.t, 6), np.round(gnss.t, 6))
    sensors = turn.scenario.sensors
    vx_error = gnss.vx - turn.truth.vx[on_gnss]
    assert vx_error.std() == pytest.approx(sensors.gnss_velocity_noise_std, rel=0.15)
    assert np.all(np.abs(gnss.yaw) <= math.pi)
    wrapped = np.angle(np.exp(1j * (gnss.yaw - turn.truth.yaw[on_gnss])))
    assert np.abs(wrapped).max() < 5 * sensors.gnss_yaw_noise_std


def test_reproducible_and_sensor_seed_leaves_the_truth_alone():
    scenario = replace(small_radius_turn(), duration=1.5)
    first = simulate_skid_steer(scenario, seed=5)
    again = simulate_skid_steer(scenario, seed=5)
    other = simulate_skid_steer(scenario, seed=6)
    for name in ("linear_acceleration", "angular_velocity", "motor_position", "motor_velocity", "motor_effort"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
    np.testing.assert_array_equal(first.gnss.x, again.gnss.x)
    assert not np.array_equal(first.linear_acceleration, other.linear_acceleration)
    for name in ("vx", "vy", "yaw_rate", "normal_load", "tire_force_y", "motor_torque"):
        np.testing.assert_array_equal(getattr(first.truth, name), getattr(other.truth, name))
    # Streams are separate: a different accelerometer noise level leaves the gyroscope noise unchanged.
    louder = replace(scenario, sensors=replace(scenario.sensors, accel_noise_std=0.5))
    loud = simulate_skid_steer(louder, seed=5)
    np.testing.assert_array_equal(loud.angular_velocity, first.angular_velocity)
    assert not np.array_equal(loud.linear_acceleration, first.linear_acceleration)


def test_stepping_simulator_matches_simulate():
    scenario = replace(small_radius_turn(), duration=0.5)
    simulator = SkidSteerSimulator(scenario, seed=3)
    samples = []
    while not simulator.done:
        samples.append(simulator.step())
    result = simulate_skid_steer(scenario, seed=3)
    assert len(samples) == 50 == result.t.size
    assert simulator.t == pytest.approx(0.5)
    np.testing.assert_array_equal(np.array([s.linear_acceleration for s in samples]), result.linear_acceleration)
    np.testing.assert_array_equal(np.array([s.truth.vx for s in samples]), result.truth.vx)
    assert [s.gnss is not None for s in samples] == [(k + 1) % 10 == 0 for k in range(50)]


# --- effects --------------------------------------------------------------------


def test_imu_biases_add_to_the_readings():
    scenario = replace(small_radius_turn(), duration=1.0)
    biased = replace(scenario, effects=replace(scenario.effects, gyro_bias=0.01, accel_bias=(0.1, -0.2, 0.3)))
    plain, shifted = simulate_skid_steer(scenario, 1), simulate_skid_steer(biased, 1)
    np.testing.assert_allclose(shifted.linear_acceleration - plain.linear_acceleration, [[0.1, -0.2, 0.3]] * 100)
    np.testing.assert_allclose(shifted.angular_velocity - plain.angular_velocity, [[0.0, 0.0, 0.01]] * 100, atol=1e-15)
    np.testing.assert_array_equal(shifted.truth.vx, plain.truth.vx)


def test_imu_delay_shifts_the_readings():
    scenario = replace(straight_acceleration(sensors=QUIET), duration=2.0)
    plain = simulate_skid_steer(scenario, 0)
    whole = simulate_skid_steer(replace(scenario, effects=replace(scenario.effects, sensor_delay=0.03)), 0)
    half = simulate_skid_steer(replace(scenario, effects=replace(scenario.effects, sensor_delay=0.015)), 0)
    np.testing.assert_allclose(whole.linear_acceleration[3:], plain.linear_acceleration[:-3], atol=1e-12)
    np.testing.assert_allclose(whole.linear_acceleration[:2], [[0.0, 0.0, P.gravity]] * 2, atol=1e-12)
    midpoint = 0.5 * (plain.linear_acceleration[1:-1] + plain.linear_acceleration[:-2])
    np.testing.assert_allclose(half.linear_acceleration[2:], midpoint, atol=1e-12)
    assert np.abs(plain.linear_acceleration[1:, 0] - plain.linear_acceleration[:-1, 0]).max() > 0.01


def test_wheel_radius_error_changes_speed_per_wheel_turn():
    torque = balancing_torque()
    effects = SkidSteerEffects(wheel_radius_error=0.05)
    scenario = constant_torque(torque, torque, initial_speed=5.0, duration=2.0, effects=effects, sensors=QUIET)
    truth = simulate_skid_steer(scenario, 0).truth
    ratio = truth.vx[-1] / (P.wheel_radius * truth.wheel_speed[-1, 0])
    assert ratio == pytest.approx(1.05 * (1.0 - truth.slip[-1, 0]), rel=1e-9)
    assert ratio > 1.04


def test_terrain_grade_needs_the_climbing_force():
    grade = 0.05
    effects = SkidSteerEffects(terrain_grade=grade)
    climbing = P.mass * P.gravity * math.sin(grade)
    resistance = VEHICLE.rolling_resistance * P.mass * P.gravity * math.cos(grade)
    torque = P.wheel_radius * (climbing + resistance) / (2.0 * VEHICLE.transmission_efficiency * P.transmission_ratio)
    scenario = constant_torque(torque, torque, initial_speed=4.0, duration=2.0, effects=effects, sensors=QUIET)
    result = simulate_skid_steer(scenario, 0)
    late = result.t > 1.0
    truth = result.truth
    # Thrust balances motion resistance and the climbing force: the speed holds.
    assert np.ptp(truth.vx[late]) < 1e-7
    np.testing.assert_allclose(truth.tire_force_x[late].sum(axis=1), climbing + resistance, rtol=1e-7)
    # The level accelerometer reads the gravity component along the slope; loads carry m g cos γ.
    np.testing.assert_allclose(result.linear_acceleration[late, 0], P.gravity * math.sin(grade), rtol=1e-7)
    np.testing.assert_allclose(result.linear_acceleration[late, 2], P.gravity * math.cos(grade), rtol=1e-12)
    np.testing.assert_allclose(truth.normal_load[late].sum(axis=1), P.mass * P.gravity * math.cos(grade), rtol=1e-12)
    # Uphill the rear axle carries more than on the level.
    level_rear = quasi_static_loads(0.0, 0.0, P)[2]
    assert np.all(truth.normal_load[late, 2] > level_rear + 100.0)


# --- integration ----------------------------------------------------------------


@pytest.mark.parametrize(
    "effects", [SkidSteerEffects.nominal(), SkidSteerEffects.truth_default()], ids=["nominal", "truth"]
)
def test_default_step_is_converged(effects):
    # Differential torques from rest: large slips, load transfer, stiff start without relaxation.
    base = constant_torque(-40.0, 120.0, duration=1.0, effects=effects, sensors=QUIET)
    coarse = simulate_skid_steer(base, 0).truth
    fine = simulate_skid_steer(replace(base, integration_step=0.5e-3), 0).truth
    # The torque step from rest saturates the slips within milliseconds (kinks of the brush model): the worst case.
    np.testing.assert_allclose(coarse.vx, fine.vx, atol=5e-5)
    np.testing.assert_allclose(coarse.yaw_rate, fine.yaw_rate, atol=5e-5)
    np.testing.assert_allclose(coarse.vy, fine.vy, atol=5e-5)
    np.testing.assert_allclose(coarse.wheel_speed, fine.wheel_speed, rtol=1e-3, atol=5e-4)
    np.testing.assert_allclose(coarse.normal_load, fine.normal_load, atol=20.0)
    assert np.abs(fine.yaw_rate).max() > 0.05
