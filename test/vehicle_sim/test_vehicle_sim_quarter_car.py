"""Truth plant: quarter car (MODELS.md A.1) and LRV (A.7) on a soil spring."""

import math
import time

import numpy as np
import pytest

from vehicle_sim.plants.quarter_car import (
    STANDARD_GRAVITY,
    LRVVehicle,
    QuarterCarSimulator,
    QuarterCarVehicle,
    Scenario,
    SpeedProfile,
    simulate,
)
from vehicle_sim.terrain.profiles import (
    RoadProfile,
    flat_profile,
    iso8608_profile,
    sinusoidal_profile,
)
from vehicle_sim.terrain.soils import (
    GRANEVILLE_LOAM,
    LETE_SAND,
    LUNAR_REGOLITH,
    UPLAND_SANDY_LOAM,
)

QC = QuarterCarVehicle()
LRV = LRVVehicle()


def quiet(**kwargs) -> Scenario:
    """Scenario without sensor noise."""
    return Scenario(accel_noise_variance=0.0, profile_noise_std=0.0, **kwargs)


def prony_eigenvalues(signal: np.ndarray, order: int, period: float) -> np.ndarray:
    """Continuous-time eigenvalues of a noise-free free response (linear prediction)."""
    rows = np.column_stack([signal[order - j - 1 : len(signal) - j - 1] for j in range(order)])
    coeffs, *_ = np.linalg.lstsq(rows, signal[order:], rcond=None)
    roots = np.roots(np.concatenate([[1.0], -coeffs]))
    return np.log(roots.astype(complex)) / period


# --- static equilibrium -----------------------------------------------------


@pytest.mark.parametrize("vehicle", [QC, LRV], ids=["quarter_car", "lrv"])
def test_at_rest_accelerometers_read_plus_g(vehicle):
    # At rest on a rough road the default initial state is static equilibrium.
    scenario = quiet(profile=iso8608_profile("D", seed=1), speed=0.0)
    result = simulate(vehicle, scenario, 1.0, seed=0)
    np.testing.assert_allclose(result.body_accel_z, STANDARD_GRAVITY, atol=1e-12)
    if vehicle.has_wheel_accelerometer:
        np.testing.assert_allclose(result.wheel_accel_z, STANDARD_GRAVITY, atol=1e-12)
    np.testing.assert_allclose(result.truth.contact_force, vehicle.total_mass * STANDARD_GRAVITY, rtol=1e-12)
    assert np.all(result.truth.in_contact)
    np.testing.assert_array_equal(result.distance, 0.0)


def test_accelerometer_noise_statistics():
    result = simulate(QC, Scenario(speed=0.0), 20.0, seed=3)
    for signal in (result.body_accel_z, result.wheel_accel_z):
        assert signal.mean() == pytest.approx(STANDARD_GRAVITY, abs=4 * np.sqrt(0.5 / signal.size))
        assert signal.var() == pytest.approx(0.5, rel=0.06)
    # Body and wheel noise are independent.
    assert abs(np.corrcoef(result.body_accel_z, result.wheel_accel_z)[0, 1]) < 0.05


# --- natural frequencies ----------------------------------------------------


@pytest.mark.parametrize("soil", [UPLAND_SANDY_LOAM, GRANEVILLE_LOAM, LETE_SAND], ids=lambda soil: soil.name)
def test_two_dof_free_response_eigenvalues(soil):
    scenario = quiet(speed=0.0, soil_path=soil)
    free = simulate(QC, scenario, 4.0, seed=0, initial_state=(0.01, 0.0, -0.005, 0.0))
    measured = prony_eigenvalues(free.truth.body_displacement, 4, scenario.sensor_period)
    expected = np.linalg.eigvals(QC.state_matrix(soil.k_s))
    key = np.abs
    np.testing.assert_allclose(sorted(measured, key=key), sorted(expected, key=key), rtol=1e-4)


def test_two_dof_undamped_frequencies_vs_closed_form():
    undamped = QuarterCarVehicle(suspension_damping=0.0)
    scenario = quiet(speed=0.0, soil_path=GRANEVILLE_LOAM)
    free = simulate(undamped, scenario, 4.0, seed=0, initial_state=(0.01, 0.0, -0.005, 0.0))
    eig = prony_eigenvalues(free.truth.wheel_displacement, 4, scenario.sensor_period)
    measured = np.sort(np.abs(eig.imag))[::2] / (2 * np.pi)
    body, wheel = undamped.undamped_natural_frequencies(GRANEVILLE_LOAM.k_s)
    assert measured == pytest.approx([body, wheel], rel=1e-5)
    # MODELS.md A.1 "body ≈ 1.18 Hz" is the uncoupled sprung-mass frequency √(k/m_s);
    # the coupled body mode sits a little lower, the wheel hop in 8.2–10.2 Hz.
    assert np.sqrt(QC.suspension_stiffness / QC.sprung_mass) / (2 * np.pi) == pytest.approx(1.18, abs=0.005)
    assert 1.0 < body < 1.18
    assert 8.2 < wheel < 10.3


@pytest.mark.parametrize("damping", [0.0, 1.5e3])
def test_lrv_free_response(damping):
    vehicle = LRVVehicle(damping=damping)
    scenario = quiet(speed=0.0, soil_path=LUNAR_REGOLITH)
    free = simulate(vehicle, scenario, 3.0, seed=0, initial_state=(0.02, 0.0))
    eig = prony_eigenvalues(free.truth.body_displacement, 2, scenario.sensor_period)
    k_tot = vehicle.k_tot(LUNAR_REGOLITH.k_s)
    expected = np.roots([vehicle.sprung_mass, damping, k_tot])
    np.testing.assert_allclose(np.sort_complex(eig), np.sort_complex(expected), rtol=1e-5)
    if damping == 0.0:
        assert abs(eig[0].imag) / (2 * np.pi) == pytest.approx(1.82, abs=0.005)


# --- forced response and equations of motion ----------------------------------


def test_two_dof_sinusoidal_steady_state_matches_frequency_response():
    speed, wavelength, amplitude = 10.0, 10.0 / 3.0, 0.01  # 3 Hz excitation
    scenario = quiet(profile=sinusoidal_profile(amplitude, wavelength), speed=speed)
    result = simulate(QC, scenario, 8.0, seed=0)
    omega = 2 * np.pi * speed / wavelength
    k, c, kt = QC.suspension_stiffness, QC.suspension_damping, QC.k_tot(GRANEVILLE_LOAM.k_s)
    dynamic = np.array(
        [
            [-(omega**2) * QC.sprung_mass + 1j * omega * c + k, -(1j * omega * c + k)],
            [-(1j * omega * c + k), -(omega**2) * QC.unsprung_mass + 1j * omega * c + k + kt],
        ]
    )
    gains = np.linalg.solve(dynamic, [0.0, kt])
    late = result.t > 5.0
    t = result.t[late]
    basis = np.column_stack([np.cos(omega * t), -np.sin(omega * t)])
    for signal, gain in (
        (result.truth.body_displacement[late], gains[0]),
        (result.truth.wheel_displacement[late], gains[1]),
    ):
        fit, *_ = np.linalg.lstsq(basis, signal, rcond=None)
        assert complex(*fit) == pytest.approx(amplitude * gain, rel=1e-4, abs=1e-9)


def test_lrv_sinusoidal_steady_state_ground_damper():
    speed, wavelength, amplitude = 2.0, 1.0, 0.01  # 2 Hz excitation
    scenario = quiet(profile=sinusoidal_profile(amplitude, wavelength), speed=speed, soil_path=LUNAR_REGOLITH)
    result = simulate(LRV, scenario, 10.0, seed=0)
    omega = 2 * np.pi * speed / wavelength
    kt, c, m = LRV.k_tot(LUNAR_REGOLITH.k_s), LRV.damping, LRV.sprung_mass
    gain = (kt + 1j * omega * c) / (kt + 1j * omega * c - omega**2 * m)
    late = result.t > 6.0
    t = result.t[late]
    basis = np.column_stack([np.cos(omega * t), -np.sin(omega * t)])
    fit, *_ = np.linalg.lstsq(basis, result.truth.body_displacement[late], rcond=None)
    assert complex(*fit) == pytest.approx(amplitude * gain, rel=1e-4)


def test_truth_satisfies_equations_of_motion():
    scenario = quiet(profile=iso8608_profile("D", seed=2), speed=10.0)
    r = simulate(QC, scenario, 2.0, seed=0)
    tr = r.truth
    suspension = QC.suspension_stiffness * (tr.wheel_displacement - tr.body_displacement) + (
        QC.suspension_damping * (tr.wheel_velocity - tr.body_velocity)
    )
    np.testing.assert_allclose(QC.sprung_mass * tr.body_acceleration, suspension, atol=1e-9)
    ground = tr.k_tot * (tr.road_elevation - tr.wheel_displacement)
    np.testing.assert_allclose(QC.unsprung_mass * tr.wheel_acceleration, ground - suspension, atol=1e-9)
    np.testing.assert_allclose(r.body_accel_z, tr.body_acceleration + STANDARD_GRAVITY)
    road = scenario.profile
    np.testing.assert_allclose(tr.road_elevation, road.elevation(r.distance), atol=1e-14)
    np.testing.assert_allclose(tr.road_rate, 10.0 * road.slope(r.distance), atol=1e-12)


# --- integration ---------------------------------------------------------------


@pytest.mark.parametrize("vehicle", [QC, LRV], ids=["quarter_car", "lrv"])
def test_rk4_fourth_order_convergence(vehicle):
    """Halving the RK4 step divides the change of the result by ≈ 2⁴."""
    profile = iso8608_profile("D", seed=5)  # default band: content up to 100 Hz at 10 m/s
    states = []
    for step in (2.5e-3, 1.25e-3, 0.625e-3, 0.3125e-3):
        scenario = quiet(profile=profile, soil_path=LETE_SAND, speed=10.0, integration_step=step)
        simulator = QuarterCarSimulator(vehicle, scenario, seed=0)
        for _ in range(50):
            simulator.step()
        states.append(np.array(simulator.state))
    changes = [np.linalg.norm(a - b) for a, b in zip(states, states[1:], strict=False)]
    ratios = [a / b for a, b in zip(changes, changes[1:], strict=False)]
    for ratio in ratios:
        assert 14.0 < ratio < 19.0, ratios


def test_constant_speed_fast_path_equals_generic_evaluation():
    class Opaque(RoadProfile):
        """Wraps a profile so the simulator can only call elevation_and_slope."""

        def __init__(self, inner):
            self.inner = inner

        def elevation_and_slope(self, distance):
            return self.inner.elevation_and_slope(distance)

    profile = iso8608_profile("E", seed=8)
    fast = simulate(QC, Scenario(profile=profile), 1.0, seed=4)
    generic = simulate(QC, Scenario(profile=Opaque(profile)), 1.0, seed=4)
    np.testing.assert_allclose(fast.body_accel_z, generic.body_accel_z, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.profile.elevation, generic.profile.elevation, atol=1e-13)


# --- soil path, speed profile, sensors ---------------------------------------------


def test_soil_switch_at_the_right_distance():
    switch = 37.3
    speed = SpeedProfile.piecewise_linear([0.0, 2.0, 10.0], [4.0, 12.0, 8.0])
    scenario = Scenario(
        profile=iso8608_profile("D", seed=1),
        soil_path=[(0.0, LETE_SAND), (switch, UPLAND_SANDY_LOAM)],
        speed=speed,
    )
    r = simulate(QC, scenario, 8.0, seed=0)
    on_upland = r.truth.soil_name == "upland_sandy_loam"
    np.testing.assert_array_equal(on_upland, r.distance >= switch)
    assert 0 < on_upland.sum() < on_upland.size
    np.testing.assert_allclose(
        r.truth.k_tot, np.where(on_upland, QC.k_tot(UPLAND_SANDY_LOAM.k_s), QC.k_tot(LETE_SAND.k_s))
    )
    np.testing.assert_allclose(r.truth.k_s, np.where(on_upland, UPLAND_SANDY_LOAM.k_s, LETE_SAND.k_s))


def test_speed_profile_distance_is_exact_integral():
    speed = SpeedProfile.piecewise_linear([0.0, 1.0, 3.0], [2.0, 6.0, 0.0])
    t = np.linspace(0.0, 5.0, 5001)
    v = speed.speed(t)
    numeric = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    np.testing.assert_allclose(speed.distance(t), numeric, atol=1e-9)
    assert speed.distance(5.0) == pytest.approx(4.0 + 6.0)  # ramps of 4 m and 6 m, then stopped
    assert speed.is_constant_on(3.5, 4.0)
    assert not speed.is_constant_on(0.5, 0.6)
    with pytest.raises(ValueError):
        SpeedProfile.piecewise_linear([0.0, 1.0], [1.0, -1.0])


def test_joint_states_and_profile_sampler():
    speed = SpeedProfile.piecewise_linear([0.0, 1.0], [5.0, 10.0])
    scenario = Scenario(profile=iso8608_profile("D", seed=2), speed=speed)
    simulator = QuarterCarSimulator(QC, scenario, seed=1)
    first = simulator.step()
    second = simulator.step()
    assert first.t == pytest.approx(0.01)
    assert first.profile.t.size == 11 and first.profile.t[0] == 0.0
    assert second.profile.t.size == 10
    np.testing.assert_allclose(second.profile.t, 0.011 + 0.001 * np.arange(10))
    r = simulate(QC, scenario, 2.0, seed=1)
    assert r.t.size == 200 and r.t[-1] == pytest.approx(2.0)
    np.testing.assert_allclose(r.profile.t, np.arange(2001) * 1e-3, atol=1e-12)
    np.testing.assert_allclose(r.profile.distance, speed.distance(r.profile.t), atol=1e-12)
    np.testing.assert_allclose(r.speed, speed.speed(r.t))
    np.testing.assert_allclose(r.wheel_rate, r.speed / QC.wheel_radius)
    np.testing.assert_allclose(r.wheel_angle, r.distance / QC.wheel_radius)
    error = r.profile.elevation - scenario.profile.elevation(r.profile.distance)
    assert error.std() == pytest.approx(1e-4, rel=0.1)
    assert abs(error.mean()) < 1e-5


def test_seeded_runs_are_reproducible():
    scenario = Scenario(profile=iso8608_profile("D", seed=2))
    a = simulate(QC, scenario, 0.5, seed=7)
    b = simulate(QC, scenario, 0.5, seed=7)
    c = simulate(QC, scenario, 0.5, seed=8)
    np.testing.assert_array_equal(a.body_accel_z, b.body_accel_z)
    np.testing.assert_array_equal(a.profile.elevation, b.profile.elevation)
    assert not np.array_equal(a.body_accel_z, c.body_accel_z)
    np.testing.assert_array_equal(a.truth.body_displacement, c.truth.body_displacement)


def test_lrv_has_no_wheel_accelerometer():
    scenario = Scenario(profile=iso8608_profile("G", seed=3), soil_path=LUNAR_REGOLITH, speed=2.0)
    sample = QuarterCarSimulator(LRV, scenario, seed=0).step()
    assert sample.wheel_accel_z is None
    assert sample.truth.wheel_displacement is None
    r = simulate(LRV, scenario, 5.0, seed=0)
    assert r.wheel_accel_z is None
    assert r.truth.wheel_velocity is None and r.truth.wheel_acceleration is None
    assert np.all(r.truth.soil_name == "lunar_regolith")
    np.testing.assert_allclose(r.truth.k_tot, 9826.04, rtol=1e-5)
    np.testing.assert_allclose(r.wheel_rate, 2.0 / 0.508)
    tr = r.truth
    dynamic = tr.k_tot * (tr.road_elevation - tr.body_displacement) + LRV.damping * (tr.road_rate - tr.body_velocity)
    np.testing.assert_allclose(LRV.sprung_mass * tr.body_acceleration, dynamic, atol=1e-9)


def test_lrv_inertial_damper_option():
    vehicle = LRVVehicle(damper_reference="inertial")
    scenario = quiet(profile=iso8608_profile("G", seed=3), soil_path=LUNAR_REGOLITH, speed=2.0)
    tr = simulate(vehicle, scenario, 2.0, seed=0).truth
    spring = tr.k_tot * (tr.road_elevation - tr.body_displacement)
    force = spring - vehicle.damping * tr.body_velocity
    np.testing.assert_allclose(vehicle.sprung_mass * tr.body_acceleration, force, atol=1e-9)


# --- energy ------------------------------------------------------------------


def _energy(result, vehicle):
    tr = result.truth
    k_tot = tr.k_tot
    return (
        0.5 * vehicle.sprung_mass * tr.body_velocity**2
        + 0.5 * vehicle.unsprung_mass * tr.wheel_velocity**2
        + 0.5 * vehicle.suspension_stiffness * (tr.body_displacement - tr.wheel_displacement) ** 2
        + 0.5 * k_tot * tr.wheel_displacement**2
    )


def test_undamped_energy_is_conserved():
    vehicle = QuarterCarVehicle(suspension_damping=0.0)
    scenario = quiet(profile=flat_profile(), speed=10.0)
    r = simulate(vehicle, scenario, 10.0, seed=0, initial_state=(0.02, 0.1, -0.01, 0.3))
    energy = _energy(r, vehicle)
    # RK4 loses O((ωΔt)⁶) per step on an oscillator: ≈ 5e-6 over 10 s at the 10 Hz wheel hop.
    assert np.ptp(energy) < 2e-5 * energy[0]
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])


def test_damped_energy_decays_by_the_dissipated_work():
    scenario = quiet(profile=flat_profile(), speed=10.0, sensor_rate=1000.0)
    r = simulate(QC, scenario, 3.0, seed=0, initial_state=(0.02, 0.1, -0.01, 0.3))
    energy = _energy(r, QC)
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])  # passive: never gains energy
    relative = r.truth.body_velocity - r.truth.wheel_velocity
    dissipated = np.sum(0.5 * (relative[1:] ** 2 + relative[:-1] ** 2)) * 1e-3
    dissipated *= QC.suspension_damping
    assert energy[0] - energy[-1] == pytest.approx(dissipated, rel=2e-3)
    assert energy[-1] < 1e-3 * energy[0]


# --- lift-off ------------------------------------------------------------------


def test_wheel_liftoff_is_unilateral():
    profile = iso8608_profile("F", seed=3)
    linear = simulate(QC, Scenario(profile=profile, soil_path=LETE_SAND), 5.0, seed=0)
    lifting = simulate(QC, Scenario(profile=profile, soil_path=LETE_SAND, wheel_liftoff=True), 5.0, seed=0)
    # MODELS.md A.10: at ISO F, 10 m/s the tire would leave the ground 7–9 % of the time.
    assert linear.truth.contact_force.min() < 0.0
    assert 0.02 < 1.0 - linear.truth.in_contact.mean() < 0.3
    assert lifting.truth.contact_force.min() >= 0.0
    airborne = ~lifting.truth.in_contact
    assert airborne.any()
    np.testing.assert_array_equal(lifting.truth.contact_force[airborne], 0.0)
    np.testing.assert_array_equal(linear.truth.contact_force[linear.truth.in_contact] > 0, True)


# --- speed --------------------------------------------------------------------


def test_simulate_speed_is_reported(capsys):
    scenario = Scenario(profile=iso8608_profile("D", seed=1), soil_path=GRANEVILLE_LOAM)
    simulate(QC, scenario, 0.2, seed=0)  # warm caches
    start = time.perf_counter()
    simulate(QC, scenario, 10.0, seed=0)
    elapsed = time.perf_counter() - start
    with capsys.disabled():
        print(f"\n[vehicle_sim] simulate(): 10 s 2-DOF at 10 m/s, ISO D -> {elapsed:.3f} s wall")


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_speed_profile_of_one_time_is_the_array_forms_value_bit_for_bit() -> None:
    """The plant asks v(t) and s(t) of one time three times a step: answered on floats, the array form's
    arithmetic in its order, a numpy float64 as before; knots, extrapolation before 0, NaN and infinities."""
    rng = np.random.default_rng(7)
    profiles = [
        SpeedProfile.constant(10.0),
        SpeedProfile.piecewise_linear((0.0, 1.0, 2.5, 7.0), (0.0, 5.0, 3.0, 3.3)),
        SpeedProfile.piecewise_linear((0.0, 0.3), (1.7, 0.0)),
    ]
    times = [*rng.uniform(-2.0, 12.0, 3000).tolist(), 0.0, -0.0, 1.0, 2.5, 7.0, 0.3, 3, math.nan, math.inf, -math.inf]
    for profile in profiles:
        for t in [*times, *np.float64(rng.uniform(0.0, 9.0, 50))]:
            for method in (profile.speed, profile.distance):
                got, want = method(t), method(np.asarray(float(t)))
                assert type(got) is type(want) is np.float64
                assert np.asarray(got).tobytes() == np.asarray(want).tobytes(), (method.__name__, t, got, want)
