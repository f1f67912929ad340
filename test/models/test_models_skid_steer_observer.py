"""Skid-steer observer model (MODELS.md B.6–B.7): f, h, sub-steps, noise, derived outputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import fsolve

from terrain_estimation.filters.an_stukf import TireSideslipModel
from terrain_estimation.filters.base import StateSpaceModel
from terrain_estimation.models.skid_steer import SkidSteerParams, quasi_static_loads, wheel_positions
from terrain_estimation.models.skid_steer_observer import (
    DEFAULT_Q0_DIAG,
    DEFAULT_R0_DIAG,
    SkidSteerInput,
    SkidSteerObserverModel,
    derived_outputs,
    encoder_kinematics,
    relaxation_rate_per_speed,
    side_slips,
    tire_sideslips,
)

P = SkidSteerParams()
RAD = P.wheel_radius


def continuous_rates(model: SkidSteerObserverModel, x, u: SkidSteerInput) -> np.ndarray:
    """ẋ of B.6 at ``x`` from the model's forces."""
    fx, fy, mz = model.forces(np.asarray(x, dtype=float), u)
    return np.array([fx / P.mass + x[1] * x[2], fy / P.mass - x[0] * x[2], mz / P.yaw_inertia])


def steady_turn(model: SkidSteerObserverModel, wl: float, wr: float) -> tuple[np.ndarray, SkidSteerInput]:
    """Steady circular motion for constant wheel speeds, loads consistent with its accelerations."""
    vx0, r0 = encoder_kinematics(wl, wr, P)
    x = np.array([vx0, 0.0, 0.5 * r0])
    a = (0.0, 0.0)
    for _ in range(30):
        u = SkidSteerInput(wl, wr, *a)
        x = fsolve(lambda s, u=u: continuous_rates(model, s, u), x, xtol=1e-12)
        a_new = (-x[1] * x[2], x[0] * x[2])  # IMU a_x = v̇x − vy r, a_y = v̇y + vx r at v̇ = 0
        if np.allclose(a_new, a, rtol=0, atol=1e-14):
            break
        a = a_new
    return x, SkidSteerInput(wl, wr, *a)


def test_protocols():
    m = SkidSteerObserverModel()
    assert isinstance(m, StateSpaceModel) and isinstance(m, TireSideslipModel)
    assert (m.state_dim, m.measurement_dim) == (3, 3)


def test_stationary_at_rest_and_at_zero_slip():
    m = SkidSteerObserverModel()
    rest = SkidSteerInput(0.0, 0.0)
    np.testing.assert_array_equal(m.f(np.zeros(3), rest, 0.01), np.zeros(3))
    np.testing.assert_array_equal(m.h(np.zeros(3), rest), np.zeros(3))
    # Straight rolling without slip: vx = Rω, vy = r = 0 → no tire force, no acceleration.
    w = 3.0 / RAD
    u = SkidSteerInput(w, w, 0.0, 0.0)
    x = np.array([3.0, 0.0, 0.0])
    np.testing.assert_allclose(m.f(x, u, 0.01), x, atol=1e-12)
    np.testing.assert_allclose(m.h(x, u), np.zeros(3), atol=1e-12)


def test_traction_accelerates_and_lateral_velocity_decays():
    m = SkidSteerObserverModel()
    u = SkidSteerInput(2.2 / RAD, 2.2 / RAD)
    x1 = m.f(np.array([2.0, 0.1, 0.0]), u, 0.01)
    assert x1[0] > 2.0, "wheels faster than the vehicle drive it forward"
    assert 0.0 < x1[1] < 0.1, "the tires' lateral forces damp the lateral velocity"
    z = m.h(np.array([2.0, 0.1, 0.0]), u)
    assert z[0] > 0.0 and z[1] < 0.0


@pytest.mark.parametrize("v, dv", [(1.39, 0.35), (1.39, 0.6), (8.33, 0.3)])
def test_steady_circular_motion_is_consistent(v, dv):
    """A steady turn: fixed point of f, IMU = centripetal acceleration, the paper's slip/ICR signs."""
    m = SkidSteerObserverModel()
    wl, wr = (v - dv) / RAD, (v + dv) / RAD  # left turn: right side faster
    x, u = steady_turn(m, wl, wr)
    np.testing.assert_allclose(continuous_rates(m, x, u), 0.0, atol=1e-9)
    # Fixed point of the discrete map for any number of sub-steps.
    np.testing.assert_allclose(m.f(x, u, 0.01), x, atol=1e-10)
    np.testing.assert_allclose(SkidSteerObserverModel(max_euler_gain=None).f(x, u, 0.01), x, atol=1e-10)
    # The IMU measures the centripetal acceleration: a_y = vx r (= v²/ρ for the path radius ρ).
    z = m.h(x, u)
    np.testing.assert_allclose(z, [-x[1] * x[2], x[0] * x[2], x[2]], atol=1e-9)
    out = derived_outputs(x, wl, wr, P)
    assert 0.0 < x[2] < out.yaw_rate_encoder, "the encoder yaw rate overestimates r (skidding)"
    assert out.slip_right > 0.0 > out.slip_left, "outer side drives, inner side brakes"
    assert out.icr_valid and out.icr_y > 0.0, "ICR on the left in a left turn"
    # In this model the steady-turn ICR lies between the front and the rear
    # axle (the paper's ≈ 3 m ahead, D.2, needs physics it does not have).
    xa = wheel_positions(P)[0]
    assert xa.min() < out.icr_x < xa.max()


def test_vectorised_f_and_h_equal_row_by_row():
    m = SkidSteerObserverModel()
    rng = np.random.default_rng(3)
    X = np.array([1.4, 0.02, 0.15]) + rng.normal(scale=[0.3, 0.1, 0.1], size=(7, 3))
    for u in (SkidSteerInput(3.2, 4.1, 0.3, 0.4), SkidSteerInput(0.1, -0.2, 0.0, 0.0, friction=0.5)):
        F, H = m.f(X, u, 0.01), m.h(X, u)
        assert F.shape == (7, 3) and H.shape == (7, 3)
        for i in range(7):
            np.testing.assert_allclose(F[i], m.f(X[i], u, 0.01), rtol=1e-14, atol=1e-15)
            np.testing.assert_allclose(H[i], m.h(X[i], u), rtol=1e-14, atol=1e-15)
        X_before = X.copy()
        m.f(X, u, 0.01)
        np.testing.assert_array_equal(X, X_before)  # the caller's points are not modified


def test_loads_come_from_the_input_accelerations():
    """h depends on a_x, a_y of the input only through the loads (saturation): check against a direct sum."""
    m = SkidSteerObserverModel()
    u = SkidSteerInput(1.0 / RAD, 3.0 / RAD, 0.5, 1.5, friction=0.3)  # strong slip, saturated tires
    x = np.array([1.9, -0.3, 0.4])
    from terrain_estimation.models.skid_steer import (
        body_forces,
        brush_tire_forces,
        contact_velocities,
        theoretical_slips,
    )

    v_x, v_y = contact_velocities(*x, P)
    sx, sy = theoretical_slips(np.array([u.omega_left, u.omega_right]), v_x, v_y, P)
    fx, fy = brush_tire_forces(
        sx,
        sy,
        quasi_static_loads(0.5, 1.5, P),
        longitudinal_stiffness=P.longitudinal_stiffness,
        cornering_stiffness=P.cornering_stiffness,
        friction=0.3,
    )
    sfx, sfy, _ = body_forces(fx, fy, P)
    np.testing.assert_allclose(m.h(x, u), [sfx / P.mass, sfy / P.mass, x[2]], rtol=1e-13)
    assert not np.allclose(m.h(x, SkidSteerInput(1.0 / RAD, 3.0 / RAD, 0.0, 0.0, friction=0.3)), m.h(x, u))


def test_relaxation_rate_bounds_the_jacobian():
    m = SkidSteerObserverModel()
    kappa_v = relaxation_rate_per_speed(P)
    assert 80.0 < kappa_v < 90.0  # ≈ 84.8 m/s² for Table 1
    rng = np.random.default_rng(7)
    for _ in range(20):
        v = rng.uniform(0.2, 8.0)
        wl, wr = v * rng.uniform(0.6, 1.0) / RAD, v * rng.uniform(1.0, 1.4) / RAD
        u = SkidSteerInput(wl, wr, rng.normal(scale=0.5), rng.normal(scale=0.5))
        x = np.array([v, rng.normal(scale=0.05), rng.normal(scale=0.05)])
        eps = 1e-7
        jac = np.column_stack(
            [(continuous_rates(m, x + eps * e, u) - continuous_rates(m, x - eps * e, u)) / (2 * eps) for e in np.eye(3)]
        )
        # Coriolis terms (∓vx r, ±vy r) do not relax; remove them for the bound.
        jac[0, 1] -= x[2]
        jac[0, 2] -= x[1]
        jac[1, 0] += x[2]
        jac[1, 2] += x[0]
        worst = max(-np.linalg.eigvals(jac).real)
        assert worst <= kappa_v / (RAD * min(wl, wr)) * (1 + 1e-6)


def test_substeps_follow_the_rolling_speed_and_keep_euler_stable():
    m = SkidSteerObserverModel()  # max_euler_gain = 0.5
    assert m.substep_count(SkidSteerInput(8.0 / RAD, 8.0 / RAD), 0.01) == 1
    assert m.substep_count(SkidSteerInput(1.39 / RAD, 1.39 / RAD), 0.01) == 2
    assert m.substep_count(SkidSteerInput(0.0, 0.0), 0.01) == math.ceil(0.01 * m.relaxation_rate_per_speed / 0.05 / 0.5)
    assert m.substep_count(SkidSteerInput(0.0, 0.0), 0.02) > m.substep_count(SkidSteerInput(0.0, 0.0), 0.01)
    # At rest a perturbation decays (the tires hold the vehicle) with the sub-steps ...
    rest = SkidSteerInput(0.0, 0.0)
    x0 = x = np.array([0.3, 0.1, 0.05])  # sliding: decelerates at ≈ μ g
    for _ in range(5):
        x_new = m.f(x, rest, 0.01)
        assert np.linalg.norm(x_new) < np.linalg.norm(x) and x_new[0] >= 0.0
        x = x_new
    assert np.linalg.norm(x) < 0.2 * np.linalg.norm(x0)
    small = np.array([0.003, 0.001, 0.0005])  # linear range: fast relaxation
    assert np.linalg.norm(m.f(small, rest, 0.01)) < 1e-3 * np.linalg.norm(small)
    # ... while the literal single Euler step of B.6 (gain ≈ 17 at the rolling
    # floor) overshoots: vx flips sign every step and the motion does not decay
    # (the saturating tire bounds it to a limit cycle).
    literal = SkidSteerObserverModel(max_euler_gain=None)
    x = np.array([0.003, 0.001, 0.0005])
    norm0, signs = np.linalg.norm(x), []
    for _ in range(6):
        x = literal.f(x, rest, 0.01)
        signs.append(np.sign(x[0]))
    assert np.all(np.diff(signs) != 0)
    assert np.linalg.norm(x) > 5 * norm0


def test_substeps_converge_to_the_continuous_solution():
    fine = SkidSteerObserverModel(max_euler_gain=0.005, max_substeps=100_000)
    u = SkidSteerInput(1.0 / RAD, 1.8 / RAD, 0.1, 0.3)
    x0 = np.array([1.0, 0.1, 0.1])
    ref = fine.f(x0, u, 0.05)
    errors = [np.abs(SkidSteerObserverModel(max_euler_gain=g).f(x0, u, 0.05) - ref).max() for g in (1.0, 0.5, 0.25)]
    change = np.abs(ref - x0).max()
    assert errors[1] < 0.1 * change
    assert errors[0] > errors[1] > errors[2], "first-order convergence with the sub-step"


def test_too_many_substeps_raise():
    m = SkidSteerObserverModel(max_substeps=10)
    with pytest.raises(ValueError, match="sub-steps"):
        m.f(np.zeros(3), SkidSteerInput(0.0, 0.0), 0.01)
    with pytest.raises(ValueError, match="dt"):
        SkidSteerObserverModel().f(np.zeros(3), SkidSteerInput(1.0, 1.0), 0.0)
    with pytest.raises(ValueError, match="SkidSteerInput"):
        SkidSteerObserverModel().h(np.zeros(3), np.array([1.0, 1.0]))


def test_noise_defaults_and_scaling():
    m = SkidSteerObserverModel()
    q_10ms = np.diag(m.process_noise_sqrt(np.zeros(3), None, 0.01)) ** 2
    q_20ms = np.diag(m.process_noise_sqrt(np.zeros(3), None, 0.02)) ** 2
    np.testing.assert_allclose(q_10ms, DEFAULT_Q0_DIAG)
    np.testing.assert_allclose(q_20ms, 2 * np.array(DEFAULT_Q0_DIAG))
    Rs = m.measurement_noise_sqrt()
    np.testing.assert_allclose(Rs @ Rs.T, np.diag(DEFAULT_R0_DIAG))
    assert DEFAULT_Q0_DIAG == pytest.approx((4e-4, 4e-4, 2.5e-5))
    assert DEFAULT_R0_DIAG == pytest.approx((1e-2, 1e-2, 2.5e-5))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"q0_diag": (1.0, -1.0, 1.0)}, "q0_diag"),
        ({"r0_diag": (1.0, 0.0, 1.0)}, "r0_diag"),
        ({"q_step_dt": 0.0}, "q_step_dt"),
        ({"substeps": 0}, "substeps"),
        ({"max_euler_gain": 2.0}, "max_euler_gain"),
        ({"max_substeps": 0}, "max_substeps"),
    ],
)
def test_model_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SkidSteerObserverModel(**kwargs)


@pytest.mark.parametrize("field", ["omega_left", "omega_right", "ax", "ay"])
def test_input_rejects_non_finite(field):
    values = {"omega_left": 1.0, "omega_right": 1.0, "ax": 0.0, "ay": 0.0, field: math.inf}
    with pytest.raises(ValueError, match=field):
        SkidSteerInput(**values)
    with pytest.raises(ValueError, match="friction"):
        SkidSteerInput(1.0, 1.0, friction=0.0)


def test_derived_outputs():
    wl, wr = 2.0, 4.5  # left side braking, right side driving
    x = np.array([1.2, -0.05, 0.3])
    out = derived_outputs(x, wl, wr, P)
    half = 0.5 * P.track * x[2]
    assert out.slip_left < 0.0 < out.slip_right
    assert out.slip_left == pytest.approx((RAD * wl - (x[0] - half)) / (x[0] - half))
    assert out.slip_right == pytest.approx((RAD * wr - (x[0] + half)) / (RAD * wr))
    np.testing.assert_allclose(side_slips(x, wl, wr, P), [out.slip_left, out.slip_right])
    xw, yw = wheel_positions(P)
    expected_alpha = np.arctan((x[1] + xw * x[2]) / (x[0] - yw * x[2]))
    np.testing.assert_allclose(out.tire_sideslip, expected_alpha, rtol=1e-14)
    np.testing.assert_allclose(tire_sideslips(x, P), expected_alpha, rtol=1e-14)
    assert out.body_sideslip == pytest.approx(math.atan2(-0.05, 1.2))
    assert (out.icr_x, out.icr_y, out.icr_valid) == pytest.approx((0.05 / 0.3, 1.2 / 0.3, True))
    assert (out.vx_encoder, out.yaw_rate_encoder) == pytest.approx((RAD * 3.25, RAD * 2.5 / P.track))
    straight = derived_outputs(np.array([1.0, 0.0, 0.01]), 2.0, 2.0, P)
    assert not straight.icr_valid and straight.icr_x == 0.0 and straight.icr_y == 0.0
    # Batch form of the helpers.
    assert side_slips(np.tile(x, (4, 1)), wl, wr, P).shape == (4, 2)
    assert tire_sideslips(np.tile(x, (4, 1)), P).shape == (4, 6)
    with pytest.raises(ValueError, match="shape"):
        derived_outputs(np.zeros(4), wl, wr, P)


def _random_cases(n: int = 200, seed: int = 3):
    """Random states (m, 3) and inputs over driving, braking, reversing, standstill, wheel lift-off."""
    rng = np.random.default_rng(seed)
    for k in range(n):
        x = rng.normal([1.0, 0.0, 0.0], [2.0, 0.3, 0.8], size=(7, 3))
        wl, wr = rng.normal(0.0, 8.0, size=2) if k % 5 else (0.0, 0.0)
        ax, ay = rng.normal(0.0, 3.0 if k % 7 else 40.0, size=2)  # large: some loads floored at 0
        friction = None if k % 2 else float(rng.uniform(0.2, 1.0))
        yield x, SkidSteerInput(float(wl), float(wr), float(ax), float(ay), friction)


def test_the_fused_forces_are_the_shared_models_composition_bit_for_bit():
    """f and h use a fused form of contact velocities → slips → brush forces → body forces
    (and of the quasi-static loads): the same floats as the shared module's functions."""
    model = SkidSteerObserverModel(P)
    for x, u in _random_cases():
        got = model.forces(x, u)
        ref = model.reference_forces(x, u)
        for a, b in zip(got, ref, strict=True):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(model._terms(u).normal_load, quasi_static_loads(u.ax, u.ay, P))
        # One point (h's and f's (3,) form) as well.
        for a, b in zip(model.forces(x[0], u), model.reference_forces(x[0], u), strict=True):
            np.testing.assert_array_equal(a, b)


def test_derived_outputs_agree_with_the_vectorised_helpers():
    from terrain_estimation.models.skid_steer import body_sideslip, instantaneous_centre_of_rotation

    for x, u in _random_cases(100, seed=4):
        for state in x:
            out = derived_outputs(state, u.omega_left, u.omega_right, P, 0.02)
            np.testing.assert_allclose(
                [out.slip_left, out.slip_right], side_slips(state, u.omega_left, u.omega_right, P), rtol=1e-15
            )
            np.testing.assert_allclose(out.tire_sideslip, tire_sideslips(state, P), rtol=1e-15, atol=1e-300)
            assert out.body_sideslip == pytest.approx(float(body_sideslip(state[0], state[1])), rel=1e-15)
            ix, iy, ok = instantaneous_centre_of_rotation(state[0], state[1], state[2], 0.02)
            assert (out.icr_x, out.icr_y, out.icr_valid) == (float(ix), float(iy), bool(ok))
