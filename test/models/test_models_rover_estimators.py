"""Estimators 1–3 of the rocker-bogie paper (MODELS.md C.5–C.6): process and measurement models.

Closed-form checks against the shared multibody model (models.rover): a rover
in equilibrium is a fixed point of the process model, the acceleration solve
satisfies eq. 32's rows, the measurement models reproduce the accelerometer,
load-cell and kinematic relations, and eqs. 86–88 give back the forces that
produced M_1fw and F_xfw.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_estimation.filters.base import StateSpaceModel
from terrain_estimation.models.rover import (
    RoverParams,
    carrier_angles,
    generalised_wheel_forces,
    gravity_gradient,
    load_cell_forces,
    mass_matrix,
    terrain_contact_force_world,
    wheel_centre_jacobian,
    wheel_centre_velocities,
    wheel_centres,
)
from terrain_estimation.models.rover_estimators import (
    GENERAL_MEASUREMENTS,
    GENERAL_STATES,
    WHEEL_FORCE_MEASUREMENTS,
    WHEEL_FORCE_STATES,
    GeneralEstimatorModel,
    GeneralIndex,
    GeneralInput,
    GeneralProcessNoise,
    MeasurementErrorFloors,
    SensorNoise,
    WheelForceModel,
    WheelForceProcessNoise,
    configuration,
    contact_angle_covariance,
    contact_angle_measurement,
    contact_angles_with_vertical_speed,
    general_measurement,
    general_measurement_variances,
    generalised_velocity,
    initial_general_state,
    initial_wheel_force_state,
    kinematic_terms,
    path_tangent_angles,
    pitch_from_gravity,
    propagate_covariance,
    slip_measurement,
    slip_measurement_jacobian,
    synthesised_perpendicular_forces,
    wheel_force_measurement_variances,
)

P = RoverParams()
G = GeneralIndex


def test_names_and_sizes() -> None:
    assert len(GENERAL_STATES) == 22 and len(set(GENERAL_STATES)) == 22
    assert len(GENERAL_MEASUREMENTS) == 11
    assert len(WHEEL_FORCE_STATES) == 9 and len(WHEEL_FORCE_MEASUREMENTS) == 9
    assert GENERAL_STATES[G.PITCH] == "pitch" and GENERAL_STATES[G.FORWARD_SPEED] == "forward_speed"
    assert GENERAL_STATES[G.SLIP][0] == "slip_rear" and GENERAL_STATES[G.BOGIE_MOMENT] == "bogie_moment"
    assert isinstance(GeneralEstimatorModel(P), StateSpaceModel)
    assert isinstance(WheelForceModel(), StateSpaceModel)


def test_equilibrium_is_a_fixed_point_of_the_process_model() -> None:
    """initial_general_state (Q_f = 0, τ_W = τ_R + b_d q̇) stays put under f1 (eqs. 48–61)."""
    pitch, bogie = 0.05, -0.03
    rates = np.array([0.3, 0.28, 0.31])
    tau_r = np.array([1.1, 0.9, 1.3])
    torque = tau_r + P.wheel_damping * rates
    x = initial_general_state(
        P, wheel_rates=rates, wheel_torque=torque, pitch=pitch, bogie_angle=bogie, forward_speed=0.02, slip=[0.1] * 3
    )
    np.testing.assert_allclose(x[G.RESISTIVE_TORQUE], tau_r)
    model = GeneralEstimatorModel(P)
    u = GeneralInput(torque, kinematic_terms(P, pitch, bogie))
    x_next = model.f(x, u, 0.2)
    np.testing.assert_allclose(x_next, x, atol=1e-10)
    # The net forces hold gravity: F_zfw = m g, and Q_f = 0 on the free coordinates.
    assert x[G.FORCE_Z] == pytest.approx(P.total_mass * P.gravity)


def test_free_accelerations_satisfy_the_rows_of_eq_32() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=22)
    x[G.PITCH], x[G.BOGIE] = 0.1, -0.2
    torque = rng.normal(size=3)
    terms = kinematic_terms(P, 0.1, -0.2)
    model = GeneralEstimatorModel(P)
    x_next = model.f(x, GeneralInput(torque, terms), 0.2)
    # Eq. 49 with the damping at the step's new rate (implicit Euler, models/rover_general_model.py "Wheel
    # damping": the encoders give window-mean rates): I q̈ = τ_W − τ_R − b_d q̇_new, q̇_new = q̇ + T q̈.
    new_rate = (x[G.WHEEL_RATE] + 0.2 * (torque - x[G.RESISTIVE_TORQUE]) / P.wheel_gear_inertia) / (
        1.0 + 0.2 * P.wheel_damping / P.wheel_gear_inertia
    )
    wheel_acc = (torque - x[G.RESISTIVE_TORQUE] - P.wheel_damping * new_rate) / P.wheel_gear_inertia
    g_ddot = np.zeros(7)
    g_ddot[[0, 1, 2, 3]] = x_next[list(G.FREE_ACC)]
    g_ddot[4:] = wheel_acc
    H = mass_matrix(P, configuration(0.1, -0.2))
    q = np.zeros(7)
    q[[0, 1, 2, 3]] = x[list(G.FREE_FORCE)]
    q += generalised_wheel_forces(P, configuration(0.1, -0.2), 0.0, 0.0, -x[G.RESISTIVE_TORQUE])
    q -= gravity_gradient(P, configuration(0.1, -0.2))
    np.testing.assert_allclose((H @ g_ddot)[:4], q[:4], atol=1e-10)
    # Wheel rates (eqs. 48–49), angles (51–54), forward speed (60).
    np.testing.assert_allclose(x_next[G.WHEEL_RATE], x[G.WHEEL_RATE] + 0.2 * wheel_acc)
    assert x_next[G.PITCH] == pytest.approx(x[G.PITCH] + 0.2 * x[G.PITCH_RATE] + 0.02 * x[G.PITCH_ACC])
    assert x_next[G.BOGIE_RATE] == pytest.approx(x[G.BOGIE_RATE] + 0.2 * x[G.BOGIE_ACC])
    along = x[G.X_ACC] * math.cos(0.1) - x[G.Z_ACC] * math.sin(0.1)
    assert x_next[G.FORWARD_SPEED] == pytest.approx(x[G.FORWARD_SPEED] + 0.2 * along)
    for s in (G.RESISTIVE_TORQUE, G.SLIP):
        np.testing.assert_array_equal(x_next[s], x[s])


def test_process_model_vectorises_and_per_point_kinematics_agree() -> None:
    rng = np.random.default_rng(4)
    X = rng.normal(scale=0.1, size=(5, 22))
    torque = np.array([1.0, 2.0, 3.0])
    model = GeneralEstimatorModel(P)
    per_point = model.f(X, GeneralInput(torque, None), 0.2)
    assert per_point.shape == (5, 22)
    for k in range(5):
        terms = kinematic_terms(P, float(X[k, G.PITCH]), float(X[k, G.BOGIE]))
        np.testing.assert_allclose(model.f(X[k], GeneralInput(torque, terms), 0.2), per_point[k], atol=1e-12)
    assert model.h(X).shape == (5, 11)
    with pytest.raises(ValueError, match="GeneralInput"):
        model.f(X[0], torque, 0.2)
    with pytest.raises(ValueError, match="wheel_torque"):
        GeneralInput(np.array([1.0, math.nan, 0.0]))


def test_accelerometer_model_eqs_72_73_and_pitch_from_gravity() -> None:
    model = GeneralEstimatorModel(P)
    x = np.zeros(22)
    x[G.PITCH] = 0.2
    y = model.h(x)
    assert y[5] == pytest.approx(-P.gravity * math.sin(0.2))
    assert y[6] == pytest.approx(P.gravity * math.cos(0.2))
    assert pitch_from_gravity(y[5], y[6]) == pytest.approx(0.2)  # eq. 64 inverts the static reading
    x[G.X_ACC], x[G.Z_ACC] = 0.3, -0.1
    y = model.h(x)
    assert y[5] == pytest.approx(0.3 * math.cos(0.2) - (P.gravity - 0.1) * math.sin(0.2))
    assert y[6] == pytest.approx(0.3 * math.sin(0.2) + (P.gravity - 0.1) * math.cos(0.2))


def test_generalised_velocity_moves_o_along_the_body_x_axis() -> None:
    g_dot = generalised_velocity(0.1, 0.02, 0.0, 0.0, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(g_dot[:2], 0.02 * np.array([math.cos(0.1), -math.sin(0.1)]))
    np.testing.assert_array_equal(g_dot[4:], [1.0, 2.0, 3.0])


@pytest.mark.parametrize("slip", [0.0, 0.15, -0.2])
def test_slip_measurement_on_a_slope(slip: float) -> None:
    """On a constant slope at θ with no pitch/bogie motion every wheel centre moves at ẋ^R (eq. 68)."""
    v = 0.02
    if slip >= 0.0:
        omega = v / (P.wheel_radius * (1.0 - slip))
    else:
        omega = v * (1.0 + slip) / P.wheel_radius
    for absolute in (True, False):
        got = slip_measurement(P, 0.12, 0.0, v, 0.0, 0.0, [omega] * 3, absolute_spin=absolute)
        np.testing.assert_allclose(got, slip, atol=1e-12)


def test_slip_measurement_uses_the_absolute_spin() -> None:
    v, q_rate, pitch_rate = 0.02, 0.3, 0.01
    joint = slip_measurement(P, 0.0, 0.0, v, pitch_rate, 0.0, [q_rate] * 3, absolute_spin=False)
    absolute = slip_measurement(P, 0.0, 0.0, v, pitch_rate, 0.0, [q_rate - pitch_rate] * 3, absolute_spin=True)
    np.testing.assert_allclose(joint, absolute, atol=1e-12)


def test_contact_angles_follow_the_wheel_centre_velocities() -> None:
    """eq. 79 against finite differences of the wheel-centre positions."""
    pitch, bogie, v, pitch_rate, bogie_rate = 0.08, -0.05, 0.02, 0.004, -0.003
    gamma = contact_angle_measurement(P, pitch, bogie, v, pitch_rate, bogie_rate)
    g = configuration(pitch, bogie)
    g_dot = generalised_velocity(pitch, v, pitch_rate, bogie_rate)
    h = 1e-4
    vel = (wheel_centres(P, g + h * g_dot) - wheel_centres(P, g - h * g_dot)) / (2 * h)
    np.testing.assert_allclose(gamma, np.arctan(-vel[:, 1] / vel[:, 0]), atol=1e-7)
    np.testing.assert_allclose(vel, wheel_centre_velocities(P, g, g_dot), atol=1e-9)
    # Without pitch or bogie motion all wheels move along the body axis: γ = θ.
    np.testing.assert_allclose(contact_angle_measurement(P, pitch, bogie, v, 0.0, 0.0), pitch, atol=1e-12)


def _net_forces(pitch: float, bogie: float, load: np.ndarray, pull: np.ndarray, gamma: np.ndarray):
    g = configuration(pitch, bogie)
    force = terrain_contact_force_world(load, pull, gamma)
    q = generalised_wheel_forces(P, g, force[:, 0], force[:, 1], 0.0)
    return q[3], q[0], carrier_angles(P, g)  # M_1fw, F_xfw, ε


def test_synthesised_perpendicular_forces_eqs_86_88() -> None:
    pitch, bogie = 0.1, -0.15
    load = np.array([50.0, 40.0, 55.0])
    gamma = np.array([0.02, -0.05, 0.12])
    pull = np.array([3.0, 2.4, -1.0])  # eq. 88 splits F_⊥12 like F_L, exact only if F_⊥1/F_L1 = F_⊥2/F_L2
    m1, fx, eps = _net_forces(pitch, bogie, load, pull, gamma)
    f_l, f_p = load_cell_forces(load, pull, gamma, eps)
    got = synthesised_perpendicular_forces(P, f_l, m1, fx, eps)
    assert got[0] + got[1] == pytest.approx(f_p[0] + f_p[1], abs=1e-9)  # eq. 86
    assert got[2] == pytest.approx(f_p[2], abs=1e-9)  # eq. 87
    assert got[0] / got[1] == pytest.approx(f_l[0] / f_l[1])  # eq. 88
    # Forces proportional on the bogie: exact per wheel.
    gamma = np.array([pitch + bogie, pitch + bogie, 0.07])
    m1, fx, eps = _net_forces(pitch, bogie, load, pull, gamma)
    f_l, f_p = load_cell_forces(load, pull, gamma, eps)
    np.testing.assert_allclose(synthesised_perpendicular_forces(P, f_l, m1, fx, eps), f_p, atol=1e-9)


def test_synthesised_split_with_an_unloaded_bogie() -> None:
    got = synthesised_perpendicular_forces(P, [0.0, 0.0, 50.0], -0.2, 1.0, [0.0, 0.0, 0.0])
    assert got[0] == got[1] == pytest.approx(0.5 * 0.2 / P.bogie_joint_height)
    with pytest.raises(ValueError, match="bogie_joint_height"):
        synthesised_perpendicular_forces(RoverParams(bogie_joint_height=0.0), [1, 1, 1], 0.0, 0.0, [0, 0, 0])


def test_wheel_force_model_matches_the_load_cell_relation() -> None:
    model = WheelForceModel()
    rng = np.random.default_rng(5)
    X = np.column_stack([rng.normal(0, 0.1, (4, 3)), rng.uniform(30, 60, (4, 3)), rng.normal(0, 3, (4, 3))])
    eps = np.array([0.05, 0.05, -0.02])
    Z = model.h(X, eps)
    assert Z.shape == (4, 9)
    f_l, f_p = load_cell_forces(X[:, 3:6], X[:, 6:9], X[:, 0:3], eps)
    np.testing.assert_allclose(Z[:, 3:6], f_l)
    np.testing.assert_allclose(Z[:, 6:9], f_p)
    np.testing.assert_array_equal(model.f(X, None, 0.2), X)
    x0 = initial_wheel_force_state(X[0, :3], f_l[0], f_p[0], eps)  # inverse rotation of eqs. 81–82
    np.testing.assert_allclose(x0, X[0])
    with pytest.raises(ValueError, match="carrier angles"):
        model.h(X[0], [0.0, 0.0])


def test_propagate_covariance_is_exact_for_a_linear_map() -> None:
    A = np.array([[1.0, 2.0, 0.0], [0.5, -1.0, 3.0]])
    cov = np.array([[1.0, 0.2, 0.0], [0.2, 2.0, 0.1], [0.0, 0.1, 0.5]])
    got = propagate_covariance(lambda v: A @ v, np.array([1.0, -2.0, 0.3]), cov)
    np.testing.assert_allclose(got, A @ cov @ A.T, rtol=1e-8)


def test_measurement_variances_follow_table_iv() -> None:
    noise, floors = SensorNoise(), MeasurementErrorFloors(pitch=0.0, specific_force=0.0, slip=0.0)
    r = general_measurement_variances(P, noise, floors, step_s=0.2, samples=10)
    assert r.shape == (11,)
    assert noise.wheel_angle == pytest.approx(math.radians(2.143e-5))
    assert r[0] == pytest.approx(2 * noise.wheel_angle**2 / 0.04)  # eq. 63
    assert r[3] == pytest.approx((noise.acceleration / P.gravity) ** 2 / 10)  # eq. 64
    assert r[4] == pytest.approx(noise.bogie_angle**2 / 10)
    assert r[5] == pytest.approx(noise.acceleration**2 / 10)
    assert r[7] == pytest.approx(noise.forward_speed**2 / 10)
    # Slip: mostly velocimeter noise over the rim speed (C.5: ≈ 0.04 per sample at 2 cm/s).
    velocimeter_only = noise.forward_speed / math.sqrt(10) / 0.02
    assert velocimeter_only < math.sqrt(r[8]) < 3 * velocimeter_only
    r2 = wheel_force_measurement_variances(
        contact_angle_cov=np.eye(3) * 1e-6, noise=noise, floors=floors, load_cell_samples=[10, 10, 5]
    )
    assert r2[5] == pytest.approx(noise.load_cell**2 / 5)
    assert r2[0] == pytest.approx(1e-6 + floors.contact_angle**2)


def test_general_measurement_assembles_y1() -> None:
    y = general_measurement(
        P,
        wheel_rates=[0.3, 0.3, 0.3],
        specific_force=[0.0, P.gravity],
        bogie_angle=0.01,
        forward_speed=0.02,
        slip_pitch_rate=0.0,
        slip_bogie_rate=0.0,
    )
    assert y.shape == (11,)
    assert y[3] == 0.0 and y[4] == 0.01 and y[7] == 0.02
    np.testing.assert_allclose(y[8:], 1.0 - 0.02 / (P.wheel_radius * 0.3), atol=1e-3)


def test_noise_parameters_are_validated_and_sized() -> None:
    assert GeneralProcessNoise().sigma().shape == (22,)
    assert WheelForceProcessNoise().sigma().shape == (9,)
    with pytest.raises(ValueError, match="SensorNoise.load_cell"):
        SensorNoise(load_cell=0.0)
    with pytest.raises(ValueError, match="GeneralProcessNoise.slip"):
        GeneralProcessNoise(slip=math.nan)
    with pytest.raises(ValueError, match="MeasurementErrorFloors.pitch"):
        MeasurementErrorFloors(pitch=-1.0)
    with pytest.raises(ValueError, match="r_diag"):
        GeneralEstimatorModel(P, r_diag=np.ones(10))
    with pytest.raises(ValueError, match="step_s"):
        WheelForceModel(step_s=0.0)


@pytest.mark.parametrize(("omega", "absolute"), [(0.32, True), (0.2, False), (0.25, True)])
def test_slip_jacobian_matches_finite_differences(omega: float, absolute: bool) -> None:
    """Slip (0.32 rad/s) and skid (0.2 rad/s) branches of eqs. 1–2."""
    inputs = np.array([0.02, 0.004, -0.002, omega, omega * 1.05, omega * 0.95])
    slip, jac = slip_measurement_jacobian(P, 0.05, -0.03, inputs, absolute_spin=absolute)
    np.testing.assert_allclose(slip, slip_measurement(P, 0.05, -0.03, *inputs[:3], inputs[3:], absolute_spin=absolute))
    numeric = np.zeros((3, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = 1e-7
        plus = slip_measurement_jacobian(P, 0.05, -0.03, inputs + d, absolute_spin=absolute)[0]
        minus = slip_measurement_jacobian(P, 0.05, -0.03, inputs - d, absolute_spin=absolute)[0]
        numeric[:, k] = (plus - minus) / 2e-7
    np.testing.assert_allclose(jac, numeric, rtol=1e-5, atol=1e-6)


def test_contact_angle_covariance_matches_numeric_propagation() -> None:
    inputs = np.array([0.08, -0.05, 0.02, 0.004, -0.003])
    cov = np.diag([1e-8, 1e-9, 1e-8, 1e-7, 1e-7])
    gamma, got = contact_angle_covariance(P, inputs, cov)
    np.testing.assert_allclose(gamma, contact_angle_measurement(P, *inputs))
    numeric = propagate_covariance(lambda v: contact_angle_measurement(P, *v), inputs, cov)
    np.testing.assert_allclose(got, numeric, rtol=1e-4)


def test_quasi_static_net_forces_follow_the_gravity_gradient() -> None:
    """Moving θ, q1 over a step shifts M_0fw, M_1fw by the change of ∂V/∂g (module docstring)."""
    pitch, bogie = 0.05, -0.03
    rates = np.array([0.3, 0.28, 0.31])
    tau_r = np.array([1.1, 0.9, 1.3])
    torque = tau_r + P.wheel_damping * rates
    x = initial_general_state(
        P, wheel_rates=rates, wheel_torque=torque, pitch=pitch, bogie_angle=bogie, forward_speed=0.02, slip=[0.1] * 3
    )
    x[G.PITCH_RATE], x[G.BOGIE_RATE] = 0.01, -0.02
    u = GeneralInput(torque, kinematic_terms(P, pitch, bogie))
    moved = GeneralEstimatorModel(P).f(x, u, 0.2)
    literal = GeneralEstimatorModel(P, quasi_static=False).f(x, u, 0.2)
    free = [0, 1, 2, 3]
    change = gravity_gradient(P, configuration(moved[G.PITCH], moved[G.BOGIE])) - gravity_gradient(
        P, configuration(pitch, bogie)
    )
    # First order in Δ(θ, q1) (the stiffness is taken at the start of the step).
    np.testing.assert_allclose(moved[list(G.FREE_FORCE)] - x[list(G.FREE_FORCE)], change[free], rtol=1e-2, atol=1e-9)
    np.testing.assert_array_equal(literal[list(G.FREE_FORCE)], x[list(G.FREE_FORCE)])  # eq. 59 as printed


def test_quasi_static_process_noise_couples_resistive_torques_into_the_moments() -> None:
    model = GeneralEstimatorModel(P)
    sigma = GeneralProcessNoise().sigma()
    L = model.process_noise_factor(sigma, 0.2)
    tau = GeneralProcessNoise().resistive_torque
    # A τ_R increment of wheel j moves M_0fw by +Δτ_R,j and M_1fw by +Δτ_R,j on the bogie wheels.
    np.testing.assert_allclose(L[G.BODY_MOMENT, 3:6], [tau, tau, tau])
    np.testing.assert_allclose(L[G.BOGIE_MOMENT, 3:6], [tau, tau, 0.0])
    np.testing.assert_allclose(L[[G.FORCE_X, G.FORCE_Z], 3:6], 0.0)
    np.testing.assert_allclose(np.diag(L), sigma)
    np.testing.assert_allclose(model.process_noise_factor(sigma, 0.8), 2.0 * L)
    literal = GeneralEstimatorModel(P, quasi_static=False).process_noise_sqrt(np.zeros(22), None, 0.2)
    np.testing.assert_allclose(literal, np.diag(sigma))


def test_terrain_frame_split_is_exact_for_a_common_pull_ratio() -> None:
    """DP/W equal on both bogie wheels but γ1 ≠ γ2: eq. 88 misplaces W sin δ, the terrain split does not."""
    pitch, bogie = 0.02, 0.1
    load = np.array([55.0, 42.0, 50.0])
    pull = 0.08 * load
    gamma = np.array([0.25, -0.05, 0.1])
    m1, fx, eps = _net_forces(pitch, bogie, load, pull, gamma)
    f_l, f_p = load_cell_forces(load, pull, gamma, eps)
    terrain = synthesised_perpendicular_forces(P, f_l, m1, fx, eps, gamma)
    np.testing.assert_allclose(terrain, f_p, atol=1e-8)
    eq88 = synthesised_perpendicular_forces(P, f_l, m1, fx, eps)
    assert np.max(np.abs(eq88[:2] - f_p[:2])) > 5.0
    # An unloaded bogie wheel falls back to eq. 88.
    np.testing.assert_allclose(
        synthesised_perpendicular_forces(P, [0.0, 40.0, 50.0], m1, fx, eps, gamma),
        synthesised_perpendicular_forces(P, [0.0, 40.0, 50.0], m1, fx, eps),
    )


def test_vertical_speed_is_exact_on_a_parabolic_path() -> None:
    """Three wheel centres always lie on a parabola; rates tangent to it give back ż0^R and its tangents."""
    pitch, bogie, speed = 0.06, -0.08, 0.02
    geo, weights = path_tangent_angles(P, pitch, bogie)
    assert weights.sum() > 0.0 and np.all(weights > 0.0)
    g = configuration(pitch, bogie)
    jac = wheel_centre_jacobian(P, g)
    slope = -np.tan(geo)

    def tangency(w: float, pitch_rate: float, bogie_rate: float) -> np.ndarray:
        v = jac @ generalised_velocity(pitch, speed, pitch_rate, bogie_rate, vertical_speed=w)
        return v[:, 1] - slope * v[:, 0]

    base = tangency(0.0, 0.0, 0.0)
    A = np.column_stack([tangency(*np.eye(3)[k]) - base for k in range(3)])
    w, pitch_rate, bogie_rate = np.linalg.solve(A, -base)
    assert abs(w) > 1e-4  # a case the paper's ż0^R = 0 gets wrong
    cov = np.diag([1e-9, 1e-10, 1e-8, 1e-8, 1e-8])
    got = contact_angles_with_vertical_speed(P, [pitch, bogie, speed, pitch_rate, bogie_rate], cov)
    assert got.vertical_speed == pytest.approx(w, rel=1e-6)
    np.testing.assert_allclose(got.contact_angle, geo, atol=1e-9)
    paper = contact_angle_measurement(P, pitch, bogie, speed, pitch_rate, bogie_rate)
    assert np.max(np.abs(paper - geo)) > 1e-3
    assert got.contact_angle_cov.shape == (3, 3) and got.vertical_speed_variance > 0.0
    # Its covariance is the first-order propagation (numeric check).
    numeric = propagate_covariance(
        lambda v: contact_angles_with_vertical_speed(P, v, cov).contact_angle,
        np.array([pitch, bogie, speed, pitch_rate, bogie_rate]),
        cov,
    )
    np.testing.assert_allclose(got.contact_angle_cov, numeric, rtol=0.05, atol=1e-12)
