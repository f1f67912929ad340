"""Planar multibody model of one Kapvik side (MODELS.md C.3): kinematics, H, Coriolis, gravity, load cells."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from terrain_estimation.models.rover import (
    COORDINATES,
    PAPER_INDEX,
    WHEELS,
    RoverParams,
    body_specific_force,
    bogie_joint_position,
    carrier_angles,
    contact_angle_from_velocity,
    coriolis_forces,
    dynamics_terms,
    generalised_wheel_forces,
    gravity_gradient,
    kinetic_energy,
    load_cell_forces,
    mass_matrix,
    mass_point_positions,
    potential_energy,
    slip_from_motion,
    slip_from_motion_scalar,
    terrain_contact_force_world,
    wheel_angular_velocity_jacobian,
    wheel_centre_bias_acceleration,
    wheel_centre_jacobian,
    wheel_centre_velocities,
    wheel_centres,
    wheel_forces_from_load_cell,
)

P = RoverParams()
RNG = np.random.default_rng(20240605)
CONFIGS = [np.zeros(7), np.array([0.3, 0.1, 0.2, -0.3, 1.0, -2.0, 0.5]), RNG.uniform(-0.6, 0.6, 7)]
RATES = [np.array([0.02, 0.0, 0.0, 0.0, 0.27, 0.27, 0.27]), np.array([0.1, -0.2, 0.7, -1.1, 3.0, 0.5, -2.0])]


def numeric_jacobian(fun, x, step=1e-6):
    x = np.asarray(x, dtype=float)
    columns = []
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = step
        columns.append((np.asarray(fun(x + dx)) - np.asarray(fun(x - dx))) / (2 * step))
    return np.stack(columns, axis=-1)


# -- layout --------------------------------------------------------------------------


def test_names_and_indices():
    assert WHEELS == ("rear", "middle", "front")
    assert len(COORDINATES) == 7 and len(PAPER_INDEX) == 7
    assert PAPER_INDEX == (1, 3, 5, 7, 8, 9, 10)


def test_level_geometry():
    centres = wheel_centres(P, np.zeros(7))
    np.testing.assert_allclose(centres, [[-0.35, -0.2], [0.0, -0.2], [0.35, -0.2]], atol=1e-15)
    np.testing.assert_allclose(bogie_joint_position(P, np.zeros(7)), [-0.175, -0.1], atol=1e-15)
    np.testing.assert_allclose(P.level_wheel_offsets, centres)
    np.testing.assert_allclose(mass_point_positions(P, np.zeros(7))[1], [-0.175, -0.1 - 0.07322])
    assert P.total_mass == pytest.approx(12.49 + 1.562 + 3 * 0.3174)


def test_pitch_positive_is_nose_down():
    g = np.zeros(7)
    g[2] = 0.1
    centres = wheel_centres(P, g)
    assert centres[2, 1] < centres[0, 1]  # front below rear
    np.testing.assert_allclose(carrier_angles(P, g), [0.1, 0.1, 0.1])
    g[3] = -0.05
    np.testing.assert_allclose(carrier_angles(P, g), [0.05, 0.05, 0.1])


@pytest.mark.parametrize("name", ["body_mass", "wheel_mass", "bogie_inertia", "wheel_radius", "gravity"])
def test_params_reject_non_positive(name):
    with pytest.raises(ValueError, match=name):
        dataclasses.replace(P, **{name: 0.0})
    with pytest.raises(ValueError, match=name):
        dataclasses.replace(P, **{name: math.nan})


def test_params_reject_inconsistent_geometry():
    with pytest.raises(ValueError, match="wheel_gear_inertia"):
        dataclasses.replace(P, wheel_gear_inertia=0.001)
    with pytest.raises(ValueError, match="bogie_half_length"):
        dataclasses.replace(P, bogie_half_length=0.4)
    with pytest.raises(ValueError, match="wheel_damping"):
        dataclasses.replace(P, wheel_damping=-1.0)


def test_bad_shapes_rejected():
    with pytest.raises(ValueError, match="shape"):
        wheel_centres(P, np.zeros(10))


# -- kinematics vs finite differences ------------------------------------------------


@pytest.mark.parametrize("g", CONFIGS)
def test_wheel_centre_jacobian_matches_finite_differences(g):
    numeric = numeric_jacobian(lambda x: wheel_centres(P, x), g)
    np.testing.assert_allclose(wheel_centre_jacobian(P, g), numeric, atol=1e-9)


@pytest.mark.parametrize("g", CONFIGS)
@pytest.mark.parametrize("g_dot", RATES)
def test_bias_acceleration_matches_finite_differences(g, g_dot):
    # p̈ = J g̈ + J̇ ġ; with g̈ = 0 along g(t) = g + t ġ, p̈ = J̇ ġ = d²p/dt².
    h = 1e-4
    second = (wheel_centres(P, g + h * g_dot) - 2 * wheel_centres(P, g) + wheel_centres(P, g - h * g_dot)) / h**2
    np.testing.assert_allclose(wheel_centre_bias_acceleration(P, g, g_dot), second, atol=1e-6)
    np.testing.assert_allclose(wheel_centre_velocities(P, g, g_dot), wheel_centre_jacobian(P, g) @ g_dot)


def test_wheel_angular_velocity_rows():
    rows = wheel_angular_velocity_jacobian(P, CONFIGS[1])
    expected = np.zeros((3, 7))
    expected[:, 2] = 1.0
    expected[:2, 3] = 1.0
    expected[0, 4] = expected[1, 5] = expected[2, 6] = 1.0
    np.testing.assert_array_equal(rows, expected)


# -- dynamics ------------------------------------------------------------------------


@pytest.mark.parametrize("g", CONFIGS)
def test_mass_matrix_symmetric_positive_definite(g):
    H = mass_matrix(P, g)
    np.testing.assert_allclose(H, H.T, atol=0)
    assert np.all(np.linalg.eigvalsh(H) > 0.0)
    # Gear inertia on the wheel coordinates only (module docstring).
    np.testing.assert_allclose(np.diag(H)[4:], P.wheel_gear_inertia)
    assert H[0, 0] == pytest.approx(P.total_mass) and H[1, 1] == pytest.approx(P.total_mass)
    assert H[2, 4] == pytest.approx(P.wheel_inertia)


@pytest.mark.parametrize("g", CONFIGS)
@pytest.mark.parametrize("g_dot", RATES)
def test_coriolis_forces_match_the_lagrangian(g, g_dot):
    # c_i = Σ_jk ∂H_ij/∂g_k ġ_j ġ_k − ½ ġᵀ (∂H/∂g_i) ġ.
    dH = numeric_jacobian(lambda x: mass_matrix(P, x), g)  # (7, 7, 7): [i, j, k] = ∂H_ij/∂g_k
    expected = np.einsum("ijk,j,k->i", dH, g_dot, g_dot) - 0.5 * np.einsum("jki,j,k->i", dH, g_dot, g_dot)
    np.testing.assert_allclose(coriolis_forces(P, g, g_dot), expected, atol=1e-7)


@pytest.mark.parametrize("g", CONFIGS)
def test_gravity_gradient_matches_potential(g):
    numeric = numeric_jacobian(lambda x: potential_energy(P, x), g)
    np.testing.assert_allclose(gravity_gradient(P, g), numeric, atol=1e-7)


def test_gravity_gradient_on_vertical_translation_is_weight():
    assert gravity_gradient(P, CONFIGS[1])[1] == pytest.approx(P.total_mass * P.gravity)


def test_energy_conserved_by_the_unforced_chain():
    def acceleration(state):
        g, g_dot = state[:7], state[7:]
        rhs = -coriolis_forces(P, g, g_dot) - gravity_gradient(P, g)
        return np.concatenate([g_dot, np.linalg.solve(mass_matrix(P, g), rhs)])

    state = np.concatenate([np.array([0.0, 0.0, 0.1, -0.2, 0.0, 0.0, 0.0]), RATES[1]])
    energy0 = kinetic_energy(P, state[:7], state[7:]) + potential_energy(P, state[:7])
    dt = 1e-3
    for _ in range(300):
        k1 = acceleration(state)
        k2 = acceleration(state + 0.5 * dt * k1)
        k3 = acceleration(state + 0.5 * dt * k2)
        k4 = acceleration(state + dt * k3)
        state = state + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    energy = kinetic_energy(P, state[:7], state[7:]) + potential_energy(P, state[:7])
    assert abs(state[3] + 0.2) > 1e-3  # the bogie moved
    assert energy == pytest.approx(energy0, abs=1e-8)


@pytest.mark.parametrize("g", CONFIGS)
@pytest.mark.parametrize("g_dot", RATES)
def test_dynamics_terms_equal_the_separate_functions(g, g_dot):
    terms = dynamics_terms(P, g, g_dot)
    np.testing.assert_allclose(terms.mass_matrix, mass_matrix(P, g), atol=1e-14)
    np.testing.assert_allclose(terms.coriolis, coriolis_forces(P, g, g_dot), atol=1e-14)
    np.testing.assert_allclose(terms.gravity, gravity_gradient(P, g), atol=1e-12)
    np.testing.assert_allclose(terms.wheel_centres, wheel_centres(P, g), atol=1e-15)
    np.testing.assert_allclose(terms.wheel_jacobian, wheel_centre_jacobian(P, g), atol=1e-15)
    np.testing.assert_allclose(terms.wheel_bias, wheel_centre_bias_acceleration(P, g, g_dot), atol=1e-14)


def test_generalised_wheel_forces_are_virtual_work():
    g, g_dot = CONFIGS[1], RATES[1]
    fx, fz, moment, drive = np.array([1.0, -2.0, 0.5]), np.array([30.0, 40.0, 50.0]), np.array([-1, -2, 3.0]), 0.7
    Q = generalised_wheel_forces(P, g, fx, fz, moment, drive_torque=drive)
    velocities = wheel_centre_velocities(P, g, g_dot)
    spins = wheel_angular_velocity_jacobian(P, g) @ g_dot
    power = np.sum(velocities[:, 0] * fx + velocities[:, 1] * fz) + np.sum(moment * spins)
    power += drive * np.sum(g_dot[4:])  # internal torque: work on the relative rate only
    assert Q @ g_dot == pytest.approx(power)
    # Vertical wheel loads alone: a vertical force on z0 and moments on θ, q1.
    Q = generalised_wheel_forces(P, np.zeros(7), 0.0, [1.0, 1.0, 1.0], 0.0)
    assert Q[1] == pytest.approx(3.0) and Q[0] == 0.0
    np.testing.assert_allclose(Q[4:], 0.0)


def test_body_specific_force():
    g = np.zeros(7)
    np.testing.assert_allclose(body_specific_force(P, g, np.zeros(7)), [0.0, P.gravity])
    g[2] = 0.2
    f = body_specific_force(P, g, np.zeros(7))
    assert math.atan(-f[0] / f[1]) == pytest.approx(0.2)  # eq. 64


# -- wheel–terrain quantities -----------------------------------------------------------


def test_load_cell_at_gamma_equal_epsilon_reads_the_normal_load():
    W, DP = np.array([30.0, 45.0, 60.0]), np.array([1.0, -2.0, 3.0])
    eps = np.array([0.1, 0.1, -0.2])
    f_l, f_p = load_cell_forces(W, DP, eps, eps)
    np.testing.assert_allclose(f_l, W)
    np.testing.assert_allclose(f_p, DP)


def test_load_cell_is_the_projection_of_the_world_force():
    W, DP, gamma, eps = 50.0, 4.0, 0.15, -0.05
    force = terrain_contact_force_world(W, DP, gamma)
    f_l, f_p = load_cell_forces(W, DP, gamma, eps)
    assert f_l == pytest.approx(force @ [math.sin(eps), math.cos(eps)])
    assert f_p == pytest.approx(force @ [math.cos(eps), -math.sin(eps)])
    np.testing.assert_allclose(wheel_forces_from_load_cell(f_l, f_p, gamma, eps), [W, DP])


def test_contact_force_directions():
    # Downhill γ > 0: DP along (cos γ, −sin γ), W along (sin γ, cos γ).
    np.testing.assert_allclose(terrain_contact_force_world(0.0, 1.0, 0.3), [math.cos(0.3), -math.sin(0.3)])
    np.testing.assert_allclose(terrain_contact_force_world(1.0, 0.0, 0.3), [math.sin(0.3), math.cos(0.3)])
    assert contact_angle_from_velocity([1.0, -0.1]) == pytest.approx(math.atan(0.1))
    np.testing.assert_allclose(contact_angle_from_velocity([[0.0, 0.0], [0.0, 1.0]]), [0.0, -math.pi / 2])


def test_slip_from_motion():
    r = 0.075
    assert slip_from_motion(0.02 / r / 0.9, 0.02, r) == pytest.approx(0.1)  # eq. 1
    assert slip_from_motion(0.02 / r * 0.9, 0.02, r) == pytest.approx(-0.1)  # eq. 2
    np.testing.assert_allclose(slip_from_motion([0.0, 1.0, 0.0, -1.0], [0.0, 0.0, 0.1, 0.1], r), [0, 1, -1, -1])
    assert np.all(np.isfinite(slip_from_motion(np.zeros(3), np.zeros(3), r)))
    # Opposite signs: full slip in the direction the rim moves relative to the centre.
    np.testing.assert_allclose(slip_from_motion([0.3, 0.0, -0.3], [-0.05, -0.05, 0.0], r), [1, 1, -1])


def test_scalar_slip_matches_the_vectorised_one():
    rates = RNG.uniform(-0.5, 0.5, 200)
    speeds = RNG.uniform(-0.04, 0.04, 200)
    rates[:5] = 0.0
    speeds[3:8] = 0.0
    vector = slip_from_motion(rates, speeds, 0.075)
    scalar = [slip_from_motion_scalar(w, v, 0.075) for w, v in zip(rates, speeds, strict=True)]
    np.testing.assert_allclose(scalar, vector, atol=1e-15)
