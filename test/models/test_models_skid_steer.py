"""Shared skid-steer physics (MODELS.md B.2–B.5): geometry, kinematics, brush tire, loads, ICR."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from terrain_estimation.models.skid_steer import (
    WHEEL_NAMES,
    SkidSteerParams,
    axle_positions,
    body_forces,
    body_sideslip,
    brush_tire_forces,
    contact_velocities,
    instantaneous_centre_of_rotation,
    quasi_static_loads,
    side_slip_ratios,
    theoretical_slips,
    tire_sideslip_angles,
    wheel_positions,
)

P = SkidSteerParams()
CX, CA, MU = P.longitudinal_stiffness, P.cornering_stiffness, 0.8


def brush(sx, sy, fz, mu=MU):
    return brush_tire_forces(sx, sy, fz, longitudinal_stiffness=CX, cornering_stiffness=CA, friction=mu)


# -- geometry ---------------------------------------------------------------------


def test_geometry_of_table_1():
    np.testing.assert_allclose(axle_positions(P), [1.592, -0.244, -1.280], atol=1e-12)
    xw, yw = wheel_positions(P)
    assert WHEEL_NAMES == ("FL", "ML", "RL", "FR", "MR", "RR")
    np.testing.assert_allclose(xw, [1.592, -0.244, -1.280] * 2, atol=1e-12)
    np.testing.assert_allclose(yw, [1.03] * 3 + [-1.03] * 3, atol=1e-12)


@pytest.mark.parametrize("name", ["mass", "track", "wheel_radius", "friction", "rolling_speed_floor"])
def test_params_reject_non_positive(name):
    with pytest.raises(ValueError, match=name):
        dataclasses.replace(P, **{name: 0.0})
    with pytest.raises(ValueError, match=name):
        dataclasses.replace(P, **{name: math.nan})


# -- loads (B.5) ----------------------------------------------------------------------


@pytest.mark.parametrize("ax, ay", [(0.0, 0.0), (1.5, 0.0), (-2.0, 0.0), (0.0, 1.2), (1.0, -2.0), (-0.7, 2.5)])
def test_loads_balance_weight_pitch_and_roll(ax, ay):
    fz = quasi_static_loads(ax, ay, P)
    assert fz.shape == (6,)
    assert np.all(fz > 0.0), "these accelerations must not lift a wheel (else the floor breaks the balance)"
    xw, yw = wheel_positions(P)
    m, g, h = P.mass, P.gravity, P.cg_height
    assert fz.sum() == pytest.approx(m * g, rel=1e-12)
    # Pitch: the inertial force −m a_x at height H; a_x > 0 loads the rear.
    assert fz @ xw == pytest.approx(-m * ax * h, abs=1e-8 * m * g)
    # Roll: −m a_y at height H; a_y > 0 (left turn) loads the right side (y < 0).
    assert fz @ yw == pytest.approx(-m * ay * h, abs=1e-8 * m * g)


def test_loads_transfer_direction_and_static_share():
    static = quasi_static_loads(0.0, 0.0, P)
    np.testing.assert_allclose(static[:3], static[3:], rtol=1e-14)  # left = right at rest
    acc = quasi_static_loads(2.0, 0.0, P)
    assert acc[0] < static[0] and acc[2] > static[2], "acceleration moves load from the front to the rear axle"
    turn = quasi_static_loads(0.0, 2.0, P)
    assert np.all(turn[3:] > turn[:3]), "a left turn (a_y > 0) loads the right side"
    # Equal split of the lateral transfer between the axles: m a_y H / (3B) per wheel.
    np.testing.assert_allclose(turn[3:] - turn[:3], 2 * P.mass * 2.0 * P.cg_height / (3 * P.track), rtol=1e-12)


def test_loads_are_floored_and_broadcast():
    fz = quasi_static_loads(0.0, 40.0, P)  # absurd lateral acceleration lifts the left side
    np.testing.assert_array_equal(fz[:3], 0.0)
    batch = quasi_static_loads(np.array([0.0, 1.0]), np.array([0.5, -0.5]), P)
    assert batch.shape == (2, 6)
    np.testing.assert_allclose(batch[1], quasi_static_loads(1.0, -0.5, P), rtol=1e-15)


# -- brush tire (B.4) ----------------------------------------------------------------


@pytest.mark.parametrize("fz", [1000.0, 5000.0, 9000.0])
def test_brush_small_slip_slopes_are_the_stiffnesses(fz):
    s = 1e-6
    fx, fy = brush(s, 0.0, fz)
    assert fx / s == pytest.approx(CX, rel=1e-4) and fy == 0.0
    fx, fy = brush(0.0, -s, fz)
    assert fy / -s == pytest.approx(CA, rel=1e-4) and fx == 0.0


@pytest.mark.parametrize("fz, mu", [(5000.0, 0.8), (2000.0, 0.4), (8000.0, 1.0)])
def test_brush_pure_lateral_saturates_exactly_at_the_limit(fz, mu):
    limit = 3.0 * mu * fz / CA
    # Below the limit F = μF_z (1 − (1 − t)³), t = |σ_y|/limit: continuous and
    # tangent to μF_z at t = 1 (the whole patch slides).
    for t in (0.5, 0.9, 0.99):
        below = brush(0.0, t * limit, fz, mu)[1]
        assert below < mu * fz
        assert below == pytest.approx(mu * fz * (1 - (1 - t) ** 3), rel=1e-12)
    for s in (limit, 1.2 * limit, 5 * limit):
        fx, fy = brush(0.0, s, fz, mu)
        assert fy == pytest.approx(mu * fz, rel=1e-15) and fx == 0.0
        assert brush(0.0, -s, fz, mu)[1] == pytest.approx(-mu * fz, rel=1e-15)
    # Strictly increasing before the limit (adhesion region).
    s = np.linspace(0.0, limit, 200)
    assert np.all(np.diff(brush(0.0, s, fz, mu)[1]) > 0.0)
    # The longitudinal limit is at 3 μ F_z / C_x.
    assert brush(3.0 * mu * fz / CX, 0.0, fz, mu)[0] == pytest.approx(mu * fz, rel=1e-15)


def test_brush_combined_slip_never_exceeds_friction_on_a_dense_grid():
    sx, sy = np.meshgrid(np.linspace(-1.5, 1.5, 301), np.linspace(-1.5, 1.5, 301))
    for fz in (500.0, 5000.0):
        fx, fy = brush(sx, sy, fz)
        mag = np.hypot(fx, fy)
        assert np.all(mag <= MU * fz * (1 + 1e-12))
        assert mag.max() == pytest.approx(MU * fz, rel=1e-12), "full sliding reaches μ F_z"
        # The force points along (C_x σ_x, C_α σ_y) (isotropic brush, one μ).
        cross = fx * (CA * sy) - fy * (CX * sx)
        assert np.all(np.abs(cross) <= 1e-9 * (1 + np.abs(fx * CA * sy)))
        # And opposes sliding: same signs as the slips.
        assert np.all(fx * sx >= 0) and np.all(fy * sy >= 0)


@settings(max_examples=300, deadline=None)
@given(
    sx=st.floats(-50.0, 50.0, allow_nan=False),
    sy=st.floats(-50.0, 50.0, allow_nan=False),
    fz=st.floats(0.0, 2e4, allow_nan=False),
    mu=st.floats(0.05, 1.5, allow_nan=False),
)
def test_brush_combined_slip_bound_property(sx, sy, fz, mu):
    fx, fy = brush(sx, sy, fz, mu)
    assert math.isfinite(float(fx)) and math.isfinite(float(fy))
    assert math.hypot(float(fx), float(fy)) <= mu * fz * (1 + 1e-12) + 1e-12


def test_brush_zero_slip_and_zero_or_negative_load_give_no_force():
    assert brush(0.0, 0.0, 5000.0) == (0.0, 0.0)
    for fz in (0.0, -100.0):
        fx, fy = brush(0.3, -0.2, fz)
        assert fx == 0.0 and fy == 0.0
    # Tiny (denormal-range) loads and slips stay finite and linear, no 0/0.
    with np.errstate(all="raise"):
        fx, fy = brush(1e-176, 0.0, 1e-170)
    assert fx == pytest.approx(CX * 1e-176, rel=1e-9) and fy == 0.0


# -- kinematics (B.3) -------------------------------------------------------------------


@pytest.mark.parametrize("icr, r", [((3.0, 7.0), 0.2), ((-0.5, -4.0), -0.4), ((0.2, 0.0), 1.0)])
def test_contact_velocities_of_a_rotation_about_a_known_icr(icr, r):
    x0, y0 = icr
    vx, vy = r * y0, -r * x0  # v_CM = ω × (0 − p_ICR)
    v_x, v_y = contact_velocities(vx, vy, r, P)
    xw, yw = wheel_positions(P)
    np.testing.assert_allclose(v_x, -r * (yw - y0), atol=1e-12)
    np.testing.assert_allclose(v_y, r * (xw - x0), atol=1e-12)
    ix, iy, valid = instantaneous_centre_of_rotation(vx, vy, r)
    assert bool(valid)
    assert float(ix) == pytest.approx(x0, abs=1e-12) and float(iy) == pytest.approx(y0, abs=1e-12)


def test_icr_of_known_motions_and_validity():
    ix, iy, ok = instantaneous_centre_of_rotation(2.0, -0.6, 0.2)
    assert (float(ix), float(iy), bool(ok)) == pytest.approx((3.0, 10.0, True))
    ix, iy, ok = instantaneous_centre_of_rotation(2.0, 0.0, 0.01)  # below the 0.02 rad/s default
    assert (float(ix), float(iy), bool(ok)) == (0.0, 0.0, False)
    ix, iy, ok = instantaneous_centre_of_rotation(np.array([1.0, 1.0]), 0.0, np.array([0.0, 0.5]), 0.02)
    np.testing.assert_array_equal(ok, [False, True])
    assert np.all(np.isfinite(ix)) and np.all(np.isfinite(iy))


def test_tire_sideslip_and_body_sideslip_signs():
    # Left turn about an ICR ahead of the front axle: all contact points slide to the right.
    v_x, v_y = contact_velocities(0.2 * 7.0, -0.2 * 3.0, 0.2, P)
    alpha = tire_sideslip_angles(v_x, v_y)
    assert np.all(alpha < 0.0)
    np.testing.assert_allclose(alpha, np.arctan(v_y / v_x), rtol=1e-14)
    # Defined at v_x = 0 and keeps the forward-driving sign when reversing.
    assert float(tire_sideslip_angles(0.0, 1.0)) == pytest.approx(math.pi / 2)
    assert float(tire_sideslip_angles(-2.0, 0.5)) == pytest.approx(math.atan(0.25))
    assert float(body_sideslip(2.0, 0.2)) == pytest.approx(math.atan2(0.2, 2.0))


def test_theoretical_slips_and_rolling_floor():
    omega = np.array([4.0, 4.0])
    sx, sy = theoretical_slips(omega, np.full(6, 1.2), np.full(6, 0.15), P)
    vr = 4.0 * P.wheel_radius
    np.testing.assert_allclose(sx, (vr - 1.2) / vr, rtol=1e-14)
    np.testing.assert_allclose(sy, -0.15 / vr, rtol=1e-14)
    sx, _ = theoretical_slips(np.zeros(2), np.full(6, 0.01), np.zeros(6), P)
    np.testing.assert_allclose(sx, -0.01 / P.rolling_speed_floor, rtol=1e-14)
    # Per-side speeds expand to the three wheels of each side.
    per_side = theoretical_slips(np.array([2.0, 4.0]), np.ones(6), np.zeros(6), P)[0]
    per_wheel = theoretical_slips(np.array([2.0] * 3 + [4.0] * 3), np.ones(6), np.zeros(6), P)[0]
    np.testing.assert_array_equal(per_side, per_wheel)


def test_side_slip_ratios_sign_in_traction_and_braking():
    rad = P.wheel_radius
    # Traction: the wheel turns faster than the ground passes, κ = (Rω − v)/(Rω) ∈ (0, 1].
    k = side_slip_ratios([4.0, 4.0], [1.2, 0.0], P)
    assert k[0] == pytest.approx((4 * rad - 1.2) / (4 * rad)) and k[0] > 0
    assert k[1] == pytest.approx(1.0), "a spinning wheel on a standing side: full slip"
    # Braking: slower than the ground, κ = (Rω − v)/v ∈ [−1, 0).
    k = side_slip_ratios([2.0, 0.0], [1.2, 1.0], P)
    assert k[0] == pytest.approx((2 * rad - 1.2) / 1.2) and k[0] < 0
    assert k[1] == pytest.approx(-1.0), "a locked wheel: full braking slip"
    # Reversing mirrors the signs (traction backwards is still positive).
    assert side_slip_ratios([-4.0, -2.0], [-1.2, -1.2], P) == pytest.approx(side_slip_ratios([4.0, 2.0], [1.2, 1.2], P))
    np.testing.assert_array_equal(side_slip_ratios([0.0, 0.01], [0.0, 0.001], P), 0.0)


def test_body_forces_sum_and_yaw_moment():
    fx = np.array([100.0, 0.0, 0.0, 300.0, 0.0, 0.0])
    fy = np.array([0.0, 0.0, 50.0, 0.0, 0.0, 0.0])
    sx, sy, mz = body_forces(fx, fy, P)
    assert (float(sx), float(sy)) == (400.0, 50.0)
    # M_z = Σ x F_y − y F_x = (−1.28)(50) − (1.03)(100) − (−1.03)(300)
    assert float(mz) == pytest.approx(-1.28 * 50 - 1.03 * 100 + 1.03 * 300, rel=1e-12)
