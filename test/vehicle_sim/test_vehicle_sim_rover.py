"""Kapvik rocker-bogie truth plant (MODELS.md C.1–C.4): constraints, control, loads, terrains, sensors."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from terrain_estimation.models.rover import RoverParams, bogie_joint_position, mass_point_positions, wheel_centres
from vehicle_sim.plants.rover import (
    CONTROL_RATE,
    TERRAIN_NUMBERS,
    TERRAINS,
    RoverEffects,
    RoverScenario,
    RoverSensorNoise,
    RoverSimulator,
    simulate_rover,
    slope_path,
    solve_configuration,
)
from vehicle_sim.plants.rover_paths import STEP_HEIGHT
from vehicle_sim.plants.rover_terramechanics import _Terramechanics
from vehicle_sim.terrain.wong_reece import WongReeceSoil

P = RoverParams()
WEIGHT = P.total_mass * P.gravity
CURVATURE_GATE = 1.0 / P.wheelbase  # [RB] C.7: κ < 1/l_w


@pytest.fixture(scope="module")
def flat_run():
    return simulate_rover(RoverScenario(terrain="flat", duration=6.0, seed=3))


@pytest.fixture(scope="module")
def rolling_run():
    # Start where the rolling path is curved and sloped, so every constraint term works.
    return simulate_rover(RoverScenario(terrain="rolling", duration=6.0, start_x=0.9, seed=1))


# -- terrains ------------------------------------------------------------------------


def test_terrain_registry():
    assert set(TERRAIN_NUMBERS.values()) <= set(TERRAINS)
    assert set(TERRAINS) == {"flat", *TERRAIN_NUMBERS.values()}
    for name, build in TERRAINS.items():
        path = build()
        assert path.name == name
        assert 10.0 <= path.duration <= 200.0
    assert TERRAINS["rolling"]().duration == 200.0  # [RB] Fig. 10


@pytest.mark.parametrize("name", sorted(TERRAINS))
def test_paths_are_smooth(name):
    path = TERRAINS[name]()
    x = np.linspace(-1.0, 5.0, 2001)
    h = 1e-6
    z, dz, d2z = path.evaluate(x)
    np.testing.assert_allclose(dz, (path.height(x + h) - path.height(x - h)) / (2 * h), atol=1e-7)
    np.testing.assert_allclose(d2z, (path.slope(x + h) - path.slope(x - h)) / (2 * h), atol=1e-5)
    assert np.all(np.isfinite(z))
    points = np.array([path.point(float(xi)) for xi in x])
    np.testing.assert_allclose(points, np.stack([z, dz, d2z], axis=1), rtol=1e-12, atol=1e-14)
    # C¹ (indeed C²): no jumps of the slope or curvature between neighbouring samples.
    assert np.max(np.abs(np.diff(dz))) < 0.01
    assert np.max(np.abs(np.diff(d2z))) < 0.2


def test_rolling_terrain_is_gentle():
    path = TERRAINS["rolling"]()
    x = np.linspace(-1.0, 4.0, 5001)
    assert path.height(0.0) == pytest.approx(0.0) and path.slope(0.0) == pytest.approx(0.0)
    assert np.max(np.abs(path.curvature(x))) < CURVATURE_GATE
    assert np.max(np.abs(path.terrain_curvature(x, P.wheel_radius))) < CURVATURE_GATE
    assert 0.15 < np.max(np.abs(path.slope(x))) < math.tan(math.radians(15.0))


@pytest.mark.parametrize("direction", [1, -1])
def test_slope_terrains(direction):
    path = slope_path(direction)
    for x, degrees in [(0.2, 0.0), (1.3, 4.0), (2.5, 8.0), (3.5, 8.0)]:
        assert path.slope(x) == pytest.approx(direction * math.tan(math.radians(degrees)), abs=1e-12)
        assert path.contact_angle(x) == pytest.approx(-direction * math.radians(degrees), abs=1e-12)
    x = np.linspace(-1.0, 4.0, 5001)
    assert np.max(np.abs(path.curvature(x))) < 0.4
    assert path.name == ("uphill" if direction == 1 else "downhill")


def test_step_terrains_have_shrinking_transitions():
    x = np.linspace(-1.0, 3.0, 40001)
    curvatures = []
    for number in (4, 5, 6):
        path = TERRAINS[TERRAIN_NUMBERS[number]]()
        assert path.height(-1.0) == pytest.approx(0.0, abs=1e-4)
        assert path.height(3.0) == pytest.approx(STEP_HEIGHT, abs=1e-4)  # half a wheel diameter
        assert STEP_HEIGHT == pytest.approx(P.wheel_radius)
        curvatures.append(np.max(np.abs(path.curvature(x))))
    assert curvatures[0] < curvatures[1] < curvatures[2]
    # Terrains 4 and 5 pass the paper's gate, terrain 6 does not (C.7).
    assert curvatures[1] < CURVATURE_GATE < curvatures[2]


def test_terrain_points_are_one_radius_from_the_path():
    path = TERRAINS["step_medium"]()
    x = np.linspace(0.3, 0.9, 61)
    xt, zt = path.terrain_points(x, P.wheel_radius)
    np.testing.assert_allclose(np.hypot(xt - x, zt - path.height(x)), P.wheel_radius)
    assert np.all(zt < path.height(x))


# -- configuration and constraints ------------------------------------------------------


@pytest.mark.parametrize("name, x0", [("rolling", 0.9), ("uphill", 1.9), ("step_sharp", 0.5)])
def test_initial_configuration_puts_all_wheels_on_the_path(name, x0):
    path = TERRAINS[name]()
    g = solve_configuration(P, path, x0)
    centres = wheel_centres(P, g)
    np.testing.assert_allclose(centres[:, 1], path.height(centres[:, 0]), atol=1e-12)
    assert g[0] == x0


def test_constraints_hold_over_a_run(rolling_run):
    truth = rolling_run.truth
    assert np.max(np.abs(truth.constraint_residual)) < 1e-4
    centres = truth.wheel_centre
    path = TERRAINS["rolling"]()
    # Each centre runs its sinkage below the path (issue 21).
    np.testing.assert_allclose(centres[..., 1], path.height(centres[..., 0]) - truth.sinkage, atol=1e-4)
    # The centre velocity is along the path up to the sinking rate: γ from the velocity (eq. 79) differs from
    # γ of the slope by atan(ṡ/v): ≈ 1e-2 rad in the first 0.1 s (the wheels settle from the start's sinkage
    # to the held loads'), then ≤ 2e-3 rad as the loads change along the path.
    velocity = truth.wheel_centre_velocity[50:]
    gamma_velocity = np.arctan(-velocity[..., 1] / velocity[..., 0])
    assert 1e-4 < np.max(np.abs(gamma_velocity - truth.contact_angle[50:])) < 3e-3
    assert np.all(np.isfinite(truth.acceleration))


def test_without_sinkage_the_centres_ride_on_the_path():
    run = simulate_rover(RoverScenario(terrain="rolling", duration=1.0, start_x=0.9, seed=1, wheel_sinkage=False))
    truth = run.truth
    np.testing.assert_array_equal(truth.sinkage, 0.0)
    path = TERRAINS["rolling"]()
    np.testing.assert_allclose(truth.wheel_centre[..., 1], path.height(truth.wheel_centre[..., 0]), atol=1e-9)
    velocity = truth.wheel_centre_velocity
    np.testing.assert_allclose(np.arctan(-velocity[..., 1] / velocity[..., 0]), truth.contact_angle, atol=1e-5)


def test_wheels_sink_by_their_own_wong_reece_sinkage(flat_run):
    # Issue 21: each wheel sinks r (1 - cos θ0(W, i)) of the plant's own Wong–Reece solution, so wheels under
    # different loads ride at different depths and the body pitches by the difference.
    from vehicle_sim.terrain.wong_reece import KAPVIK_WHEEL, contact_angle

    truth = flat_run.truth
    k = -1
    theta0 = contact_angle(truth.normal_load[k], truth.slip[k])
    expected = KAPVIK_WHEEL.radius * (1.0 - np.cos(theta0))
    np.testing.assert_allclose(truth.sinkage[k], expected, rtol=0.02)
    assert np.all((truth.sinkage[k] > 0.010) & (truth.sinkage[k] < 0.025))  # 10-25 mm at 40-60 N
    # The rear wheel carries most (the soil moments load it): it sinks deepest, and the body pitches.
    assert truth.sinkage[k][0] - truth.sinkage[k][2] > 1e-3
    np.testing.assert_allclose(truth.wheel_centre[k][:, 1], -truth.sinkage[k], atol=1e-6)
    assert abs(truth.pitch[k]) > 1e-3
    # Deeper with slip (dynamic sinkage): the same loads at a higher slip need a larger θ0.
    assert np.all(contact_angle(truth.normal_load[k], truth.slip[k] + 0.3) > theta0)


def test_sinkage_follows_a_rising_load_fast_and_a_falling_one_over_a_contact_length(rolling_run):
    # Rising loads are followed within ≈ 0.1 s, falling ones lag by a contact length of travel (the compacted
    # rut stays): the wheels run deeper than their steady sinkage, never much shallower.
    from vehicle_sim.terrain.wong_reece import KAPVIK_WHEEL, contact_angle

    truth = rolling_run.truth
    steady = KAPVIK_WHEEL.radius * (1.0 - np.cos(contact_angle(truth.normal_load, np.abs(truth.slip))))
    lag = (truth.sinkage - steady)[10:]  # after the start's settling
    assert np.all(np.isfinite(truth.sinkage))
    assert np.max(lag) > 1.5e-4  # measured 2.1e-4 m
    assert np.min(lag) > -0.3 * np.max(lag)  # measured -2.2e-5 m


def test_curved_terrain_moves_the_body_vertically(rolling_run):
    # The truth has the body z velocity that eq. 45 assumes zero.
    assert np.max(np.abs(rolling_run.truth.vertical_velocity)) > 1e-4


# -- flat ground: control, loads, slip ------------------------------------------------


def test_wheels_track_the_desired_speed(flat_run):
    truth = flat_run.truth
    rim_speed = P.wheel_radius * truth.velocity[:, 4:]
    np.testing.assert_allclose(rim_speed[-50:], 0.02, atol=2e-5)
    # The body is slower by the slip.
    np.testing.assert_allclose(truth.forward_velocity[-50:], 0.02 * (1 - truth.slip[-50:, 1]), rtol=1e-3)


def test_static_loads_sum_to_the_weight_and_split_by_the_geometry(flat_run):
    truth = flat_run.truth
    k = -1
    W, DP, tau = truth.normal_load[k], truth.drawbar_pull[k], truth.resistive_torque[k]
    np.testing.assert_allclose(W.sum(), WEIGHT, rtol=1e-6)
    # Free bodies: bogie + its wheels about the bogie joint, the whole rover about O; soil forces W, DP at
    # the wheel centres (MODELS.md C.3), the soil moments −τ_R on the wheels, gravity; M_y = r_z F_x − r_x F_z.
    g = truth.configuration[k]
    points = mass_point_positions(P, g)
    masses = np.array([P.body_mass, P.bogie_mass] + [P.wheel_mass] * 3)
    joint = bogie_joint_position(P, g)
    centres = wheel_centres(P, g)
    rows, rhs = [np.ones(3)], [WEIGHT]
    for origin, wheels, bodies in [(joint, [0, 1], [1, 2, 3]), (points[0], [0, 1, 2], [0, 1, 2, 3, 4])]:
        r = centres - origin
        row = np.zeros(3)
        row[wheels] = -r[wheels, 0]
        gravity_moment = np.sum((points[bodies, 0] - origin[0]) * masses[bodies]) * P.gravity
        rows.append(row)
        rhs.append(-(np.sum(r[wheels, 1] * DP[wheels]) - np.sum(tau[wheels]) + gravity_moment))
    predicted = np.linalg.solve(np.array(rows), np.array(rhs))
    np.testing.assert_allclose(W, predicted, atol=0.02)
    # The soil moments load the rear bogie wheel: W1 − W2 = (τ_R1 + τ_R2 + a ΣDP)/b on a level bogie (the
    # differential sinkage tilts it by a few mrad, which the exact free-body check above includes).
    assert W[0] - W[1] == pytest.approx((tau[0] + tau[1] + P.bogie_joint_height * (DP[0] + DP[1])) / 0.175, rel=0.05)


def test_slip_small_and_positive_on_flat_ground(flat_run):
    truth = flat_run.truth
    assert np.all((truth.slip > 0.1) & (truth.slip < 0.2))
    # Steady state: the drawbar pulls balance (no slope), the torques balance τ_R + b_d q̇.
    assert abs(truth.drawbar_pull[-1].sum()) < 0.05
    np.testing.assert_allclose(
        truth.wheel_torque[-1], truth.resistive_torque[-1] + P.wheel_damping * truth.velocity[-1, 4:], atol=0.01
    )
    np.testing.assert_allclose(truth.contact_angle, 0.0, atol=1e-12)
    # At rest in the body frame: gravity, tilted by the pitch the differential sinkage gives the body.
    pitch = truth.pitch[-1]
    np.testing.assert_allclose(
        np.abs(truth.specific_force[-1]), P.gravity * np.abs([np.sin(pitch), np.cos(pitch)]), atol=1e-4
    )


def test_truth_lies_on_the_terramechanics_model(rolling_run):
    # (W, i) → (DP, τ_R) of every sample is the soil model's own value: the estimators' fits can be compared
    # with it exactly.
    from vehicle_sim.terrain.terramechanics_surrogate import terramechanics_surrogate

    truth = rolling_run.truth
    dp, tau = terramechanics_surrogate().wheel_forces(truth.normal_load, truth.slip)
    np.testing.assert_allclose(truth.drawbar_pull, dp, atol=1e-9)
    np.testing.assert_allclose(truth.resistive_torque, tau, atol=1e-9)


def test_load_cells_read_the_normal_load_on_flat_ground():
    # Without sinkage, γ = 0 and ε = 0 on level ground: F_L = W, F_⊥ = DP (eqs. 81–82), W the normal load that
    # acts (the vertical reaction λ at the sample), which the soil model's W held over the step follows.
    truth = simulate_rover(RoverScenario(terrain="flat", duration=2.0, seed=3, wheel_sinkage=False)).truth
    np.testing.assert_allclose(truth.load_axial, truth.vertical_reaction, atol=1e-9)
    np.testing.assert_allclose(truth.load_perpendicular, truth.drawbar_pull, atol=1e-9)
    np.testing.assert_allclose(truth.load_axial, truth.normal_load, atol=0.05)


def test_load_cells_see_the_tilt_of_differential_sinkage(flat_run):
    # With sinkage the carriers tilt (ε ≠ 0) on level ground: the cells read W and DP rotated by γ − ε = −ε.
    from terrain_estimation.models.rover import load_cell_forces

    truth = flat_run.truth
    assert np.max(np.abs(truth.carrier_angle[-1])) > 1e-3
    axial, perp = load_cell_forces(
        truth.vertical_reaction, truth.drawbar_pull, truth.contact_angle, truth.carrier_angle
    )
    np.testing.assert_allclose(truth.load_axial, axial, atol=1e-9)
    np.testing.assert_allclose(truth.load_perpendicular, perp, atol=1e-9)


# -- sensors -------------------------------------------------------------------------------


def test_sensor_noise_matches_table_iv(flat_run):
    sensors, truth, noise = flat_run.sensors, flat_run.truth, RoverSensorNoise()
    errors = {
        "bogie_angle_std": sensors.bogie_angle - truth.bogie_angle,
        "pitch_rate_std": sensors.pitch_rate - truth.pitch_rate,
        "forward_velocity_std": sensors.forward_velocity - truth.forward_velocity,
        "acceleration_std": sensors.acceleration - truth.specific_force,
        "wheel_angle_std": sensors.wheel_angle - truth.configuration[:, 4:],
        "load_cell_std": np.concatenate(
            [sensors.load_axial - truth.load_axial, sensors.load_perpendicular - truth.load_perpendicular]
        ),
    }
    for name, error in errors.items():
        sigma = getattr(noise, name)
        n = error.size
        assert np.std(error) == pytest.approx(sigma, rel=0.2), name
        assert abs(np.mean(error)) < 5 * sigma / math.sqrt(n), name
    assert noise.load_cell_std == pytest.approx(200.0 / 1024 / 6, rel=1e-3)
    assert noise.wheel_angle_std == pytest.approx(2 * math.pi / (500 * 4 * 1400) / 6, rel=1e-3)
    np.testing.assert_array_equal(sensors.effort, truth.wheel_torque)
    assert flat_run.time[1] - flat_run.time[0] == pytest.approx(1.0 / CONTROL_RATE)


def test_seeds_reproducible():
    scenario = RoverScenario(terrain="flat", duration=0.5, seed=11)
    first, second = simulate_rover(scenario), simulate_rover(scenario)
    other = simulate_rover(dataclasses.replace(scenario, seed=12))
    for name in ("bogie_angle", "acceleration", "load_axial", "wheel_angle"):
        np.testing.assert_array_equal(getattr(first.sensors, name), getattr(second.sensors, name))
        assert not np.array_equal(getattr(first.sensors, name), getattr(other.sensors, name))
    np.testing.assert_array_equal(first.truth.configuration, other.truth.configuration)  # truth ignores the seed


def test_effects_bias_crosstalk_delay():
    base = RoverScenario(terrain="flat", duration=0.5, sensors=RoverSensorNoise.noiseless())
    clean = simulate_rover(base)
    effects = RoverEffects(
        load_cell_bias=(1.0, -2.0, 0.5),
        load_cell_crosstalk=0.01,
        imu_accel_bias=(0.05, -0.02),
        imu_gyro_bias=0.001,
        sensor_delay=0.04,
    )
    run = simulate_rover(dataclasses.replace(base, effects=effects))
    truth, sensors = run.truth, run.sensors
    np.testing.assert_array_equal(truth.configuration, clean.truth.configuration)
    d = 2  # 40 ms at 50 Hz
    expected_axial = truth.load_axial[:-d] + 0.01 * truth.load_perpendicular[:-d] + [1.0, -2.0, 0.5]
    np.testing.assert_allclose(sensors.load_axial[d:], expected_axial, atol=1e-12)
    np.testing.assert_allclose(sensors.acceleration[d:], truth.specific_force[:-d] + [0.05, -0.02], atol=1e-12)
    np.testing.assert_allclose(sensors.pitch_rate[d:], truth.pitch_rate[:-d] + 0.001, atol=1e-15)
    np.testing.assert_array_equal(sensors.effort, truth.wheel_torque)  # commands are not delayed
    assert set(effects.active) == {
        "load_cell_bias",
        "load_cell_crosstalk",
        "imu_accel_bias",
        "imu_gyro_bias",
        "sensor_delay",
    }


def test_quantised_sensors():
    run = simulate_rover(
        RoverScenario(terrain="flat", duration=0.2, sensors=dataclasses.replace(RoverSensorNoise(), quantise=True))
    )
    steps = 200.0 / 1024
    np.testing.assert_allclose(run.sensors.load_axial / steps, np.round(run.sensors.load_axial / steps), atol=1e-9)


def test_soil_change_switches_the_terramechanics():
    soft = WongReeceSoil(cohesion=100.0, friction_angle=math.radians(25.0))
    effects = RoverEffects(soil_change_distance=0.36, soil_change_soil=soft)
    run = simulate_rover(RoverScenario(terrain="flat", duration=2.0, effects=effects))
    index = run.truth.soil_index
    np.testing.assert_array_equal(index[0], [0, 0, 0])
    np.testing.assert_array_equal(index[-1], [0, 0, 1])  # only the front wheel crossed x = 0.36 m
    assert np.all(np.isfinite(run.truth.drawbar_pull))


def test_lifted_wheel_gets_no_soil_force():
    terramechanics = _Terramechanics(RoverScenario(terrain="flat"))
    dp, tau, _ = terramechanics(np.array([-5.0, 0.0, 40.0]), np.array([0.2, 0.2, 0.2]), np.zeros(3, dtype=int))
    np.testing.assert_array_equal(dp[:2], 0.0)
    np.testing.assert_array_equal(tau[:2], 0.0)
    assert tau[2] > 0.0
    full = _Terramechanics(RoverScenario(terrain="flat", terramechanics="wong_reece"))
    dp, tau, entry = full(np.array([-5.0, 1000.0]), np.array([0.2, 0.2]), np.zeros(2, dtype=int))
    assert dp[0] == 0.0 and np.all(np.isfinite(dp)) and entry[1] == pytest.approx(math.pi / 2)  # overload saturated


# -- models and robustness ---------------------------------------------------------------------


def test_surrogate_and_full_model_agree_on_flat_ground():
    base = RoverScenario(terrain="flat", duration=1.0, sensors=RoverSensorNoise.noiseless())
    surrogate = simulate_rover(base).truth
    full = simulate_rover(dataclasses.replace(base, terramechanics="wong_reece")).truth
    # The 4th-order fit's RMS errors are 0.11 N (DP) and 0.008 N·m (τ_R) over the grid.
    np.testing.assert_allclose(surrogate.slip, full.slip, atol=0.01)
    np.testing.assert_allclose(surrogate.normal_load, full.normal_load, atol=0.2)
    np.testing.assert_allclose(surrogate.resistive_torque, full.resistive_torque, atol=0.03)
    np.testing.assert_allclose(surrogate.drawbar_pull, full.drawbar_pull, atol=0.3)
    assert np.all(np.isnan(surrogate.entry_angle))
    assert np.all((full.entry_angle > 0.5) & (full.entry_angle < 0.8))  # θ0 ≈ 33–41°


def test_no_nan_on_the_sharp_step():
    scenario = RoverScenario(terrain="step_sharp", duration=6.0, start_x=0.22)
    run = simulate_rover(scenario)
    truth = run.truth
    for name in truth.__dataclass_fields__:
        if name != "entry_angle":
            assert np.all(np.isfinite(getattr(truth, name))), name
    assert np.max(np.abs(truth.constraint_residual)) < 1e-4
    assert np.max(truth.wheel_centre[:, 2, 1]) > 0.02  # the front wheel climbed onto the step
    assert np.max(np.abs(truth.path_curvature[:, 2])) > CURVATURE_GATE


def test_simulator_steps_and_stops():
    simulator = RoverSimulator(RoverScenario(terrain="flat", duration=0.1))
    samples = []
    while not simulator.done:
        samples.append(simulator.step())
    assert len(samples) == 5
    assert [s.t for s in samples] == pytest.approx([0.0, 0.02, 0.04, 0.06, 0.08])
    assert simulator.t == pytest.approx(0.1)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"terrain": "moon"}, "terrain"),
        ({"terramechanics": "bekker"}, "terramechanics"),
        ({"duration": -1.0}, "duration"),
        ({"slip_stencil": 0.5}, "slip_stencil"),
    ],
)
def test_scenario_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RoverScenario(**kwargs)


def test_effects_validation():
    with pytest.raises(ValueError, match="load_cell_bias"):
        RoverEffects(load_cell_bias=(1.0, 2.0))
    with pytest.raises(ValueError, match="soil_change"):
        RoverEffects(soil_change_distance=1.0)
