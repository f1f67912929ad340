"""Wong–Reece rigid wheel ([RB] eqs. 1–11, MODELS.md C.1) and its polynomial surrogate (C.2, D.3)."""

import math

import numpy as np
import pytest
from scipy.integrate import quad

from vehicle_sim.terrain.terramechanics_surrogate import (
    fit_terramechanics_surrogate,
    surrogate_grid,
    terramechanics_surrogate,
)
from vehicle_sim.terrain.wong_reece import (
    DEFAULT_SIMPSON_POINTS,
    KAPVIK_WHEEL,
    TABLE_II_SOIL,
    ContactAngleConvergenceError,
    RigidWheel,
    WheelOverloadError,
    WongReeceSoil,
    contact_angle,
    drawbar_pull_and_resistive_torque,
    max_stress_angle,
    normal_load,
    normal_stress,
    shear_displacement,
    shear_stress,
    simpson_weights,
    slip_ratio,
    soil_shear_stress,
    wheel_forces,
    wheel_forces_from_motion,
    wheel_load_capacity,
)

# Ding et al.'s Bekker moduli behind Table II (SI: Pa/m^(n−1), Pa/m^n).
K_C = 15.6e3
K_PHI = 2407.4e3


def reference_integrals(theta0: float, slip: float) -> tuple[float, float, float]:
    """(W, DP, τ_R) of eqs. 7–9 by adaptive quadrature of the pointwise stresses, split at θ_m."""
    r, b = KAPVIK_WHEEL.radius, KAPVIK_WHEEL.width
    theta_m = float(max_stress_angle(theta0, slip))

    def integral(integrand):
        return quad(integrand, 0.0, theta0, points=[theta_m], epsabs=1e-13, epsrel=1e-13, limit=200)[0]

    def sigma(t):
        return float(normal_stress(t, theta0, slip))

    def tau(t):
        return float(shear_stress(t, theta0, slip))

    load = b * r * (integral(lambda t: sigma(t) * math.cos(t)) + integral(lambda t: tau(t) * math.sin(t)))
    drawbar_pull = b * r * (integral(lambda t: tau(t) * math.cos(t)) - integral(lambda t: sigma(t) * math.sin(t)))
    resistive_torque = b * r**2 * integral(tau)
    return load, drawbar_pull, resistive_torque


# ---------------------------------------------------------------------------
# Soil, slip and stresses
# ---------------------------------------------------------------------------


def test_table_ii_k1_k2_are_the_bekker_moduli_at_the_kapvik_width():
    soil = WongReeceSoil.from_bekker(cohesive_modulus=K_C, frictional_modulus=K_PHI, wheel_width=KAPVIK_WHEEL.width)
    # Table II prints k1, k2 to 3–5 significant figures.
    assert soil.pressure_sinkage_k1 == pytest.approx(TABLE_II_SOIL.pressure_sinkage_k1, rel=5e-3)
    assert soil.pressure_sinkage_k2 == pytest.approx(TABLE_II_SOIL.pressure_sinkage_k2, rel=1e-4)


@pytest.mark.parametrize("width", [0.05, 0.07, 0.12])
def test_eq4_with_converted_k1_k2_is_bekkers_pressure_sinkage(width):
    soil = WongReeceSoil.from_bekker(cohesive_modulus=K_C, frictional_modulus=K_PHI, wheel_width=width)
    wheel = RigidWheel(radius=0.075, width=width)
    theta0, slip = 0.6, 0.3
    theta_m = float(max_stress_angle(theta0, slip, soil))
    n = soil.sinkage_exponent
    front = np.linspace(theta_m, theta0, 7)
    bekker = (K_C / width + K_PHI) * (wheel.radius * (np.cos(front) - np.cos(theta0))) ** n
    np.testing.assert_allclose(normal_stress(front, theta0, slip, soil, wheel), bekker, rtol=1e-12, atol=1e-9)
    # Eq. 5: the rear region is the front profile at θ* = θ0 − (θ/θ_m)(θ0 − θ_m).
    rear = np.linspace(0.0, theta_m, 7, endpoint=False)
    mapped = theta0 - rear / theta_m * (theta0 - theta_m)
    bekker_rear = (K_C / width + K_PHI) * (wheel.radius * (np.cos(mapped) - np.cos(theta0))) ** n
    np.testing.assert_allclose(normal_stress(rear, theta0, slip, soil, wheel), bekker_rear, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize(("theta0", "slip"), [(0.2, 0.0), (math.radians(45), 0.25), (1.2, 1.0)])
def test_normal_stress_is_continuous_and_maximal_at_theta_m(theta0, slip):
    theta_m = float(max_stress_angle(theta0, slip))
    assert theta_m == pytest.approx(theta0 * (0.18 + 0.32 * slip), rel=1e-15)  # eq. 3
    peak = float(normal_stress(theta_m, theta0, slip))
    eps = 1e-9
    assert float(normal_stress(theta_m - eps, theta0, slip)) == pytest.approx(peak, rel=1e-7)
    assert float(normal_stress(theta_m + eps, theta0, slip)) == pytest.approx(peak, rel=1e-7)
    profile = normal_stress(np.linspace(0.0, theta0, 401), theta0, slip)
    assert peak > 0.0
    assert profile.max() <= peak * (1 + 1e-12)
    # Zero at exit and entry (eqs. 4–5), and outside the contact.
    assert profile[0] == 0.0
    assert profile[-1] == 0.0
    assert float(normal_stress(theta0 + 0.1, theta0, slip)) == 0.0
    assert float(normal_stress(-0.1, theta0, slip)) == 0.0


def test_shear_stress_vanishes_at_entry_and_at_zero_shear_displacement():
    theta0 = np.array([0.3, 0.8, 1.4])
    for slip in (0.0, 0.4, 1.0):
        assert np.all(shear_displacement(theta0, theta0, slip) == 0.0)
        assert np.all(shear_stress(theta0, theta0, slip) == 0.0)
    sigma = np.array([0.0, 1e3, 5e4])
    np.testing.assert_array_equal(soil_shear_stress(sigma, 0.0), 0.0)
    # Fully mobilised far along the rim: τ → c + σ tan φ (eq. 6).
    limit = TABLE_II_SOIL.cohesion + sigma * math.tan(TABLE_II_SOIL.friction_angle)
    np.testing.assert_allclose(soil_shear_stress(sigma, 1.0), limit, rtol=1e-15)
    # Eq. 6 with r_w/K_s: at full slip j = r (θ0 − θ).
    j = shear_displacement(0.0, 0.8, 1.0)
    assert float(j) == pytest.approx(KAPVIK_WHEEL.radius * 0.8, rel=1e-15)


def test_slip_ratio_follows_eqs_1_and_2():
    r = 0.075
    omega = np.array([2.0, 2.0, 1.0, 0.0, 4.0, 0.0, -2.0])
    v = np.array([0.15, 0.075, 0.15, 0.1, 0.0, 0.0, -0.075])
    expected = np.array([0.0, 0.5, 0.075 / 0.15 - 1.0, -1.0, 1.0, 0.0, 0.5])
    np.testing.assert_allclose(slip_ratio(omega, r, v), expected, rtol=1e-15, atol=1e-15)


def test_invalid_parameters_are_rejected():
    with pytest.raises(ValueError):
        WongReeceSoil(max_stress_angle_c1=0.8, max_stress_angle_c2=0.32)
    with pytest.raises(ValueError):
        RigidWheel(width=0.0)
    with pytest.raises(ValueError):
        simpson_weights(4)
    with pytest.raises(ValueError):
        wheel_forces(-1.0, 0.1)
    with pytest.raises(ValueError):
        wheel_forces(50.0, 1.2)
    with pytest.raises(ValueError):
        contact_angle(50.0, -0.1)


# ---------------------------------------------------------------------------
# Contact angle (eq. 7)
# ---------------------------------------------------------------------------


def test_normal_load_is_monotone_in_contact_angle():
    theta0 = np.linspace(0.0, math.pi / 2, 400)
    for slip in np.linspace(0.0, 1.0, 11):
        load = normal_load(theta0, slip)
        assert load[0] == 0.0
        assert np.all(np.diff(load) > 0.0)


def test_contact_angle_solves_eq7_and_is_the_smallest_root():
    loads = np.array([0.1, 1.0, 35.0, 50.0, 70.0, 200.0, 400.0])
    slips = np.array([0.0, 0.05, 0.25, 0.5, 0.75, 1.0])
    load, slip = np.meshgrid(loads, slips)
    theta0 = contact_angle(load, slip)
    assert theta0.shape == load.shape
    assert np.all((theta0 > 0.0) & (theta0 < math.pi / 2))
    np.testing.assert_allclose(normal_load(theta0, slip), load, rtol=1e-11)
    # Smallest: no smaller angle carries the load.
    fractions = np.linspace(0.0, 1.0, 200, endpoint=False)
    below = normal_load(theta0[..., None] * fractions, slip[..., None])
    assert np.all(below < load[..., None])
    # The discretised eq. 7 is the continuous one up to the quadrature error.
    for t, i, w in [(theta0[2, 3], 0.25, 50.0), (theta0[5, 5], 1.0, 200.0)]:
        assert reference_integrals(t, i)[0] == pytest.approx(w, rel=2e-3)


def test_contact_angle_handles_zero_load_and_overload():
    assert float(contact_angle(0.0, 0.3)) == 0.0
    zero = wheel_forces(0.0, 0.3)
    assert float(zero.drawbar_pull) == 0.0
    assert float(zero.resistive_torque) == 0.0
    capacity = float(wheel_load_capacity(0.5))
    assert float(contact_angle(capacity * (1 - 1e-9), 0.5)) == pytest.approx(math.pi / 2, abs=1e-6)
    with pytest.raises(WheelOverloadError):
        contact_angle([50.0, capacity * 1.01], 0.5)
    saturated = contact_angle([50.0, capacity * 1.01], 0.5, overload="saturate")
    assert saturated[1] == math.pi / 2
    assert saturated[0] == pytest.approx(float(contact_angle(50.0, 0.5)), abs=0.0)
    assert np.isnan(contact_angle(capacity * 1.01, 0.5, overload="nan"))


def test_contact_angle_reports_non_convergence():
    with pytest.raises(ContactAngleConvergenceError):
        contact_angle(50.0, 0.3, max_iterations=1)


# ---------------------------------------------------------------------------
# DP and τ_R (eqs. 8–11)
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(("theta0", "slip"), [(0.15, 0.0), (math.radians(45), 0.25), (0.9, 0.7), (1.3, 1.0)])
def test_simpson_converges_to_reference_quadrature(theta0, slip):
    reference = np.array(reference_integrals(theta0, slip))
    scale = np.array([float(normal_load(theta0, slip)), 10.0, 1.0])  # N, N, N·m

    def error(points):
        load = normal_load(theta0, slip, simpson_points=points)
        dp, tau = drawbar_pull_and_resistive_torque(theta0, slip, simpson_points=points)
        return np.abs(np.array([float(load), float(dp), float(tau)]) - reference) / scale

    errors = [error(p) for p in (3, 5, 9, 17, 33, 65)]
    # Default: ≤ 0.05 % of W, ≤ 0.015 N of DP, ≤ 0.002 N·m of τ_R (θ0 = 1.3 rad is ≈ 400 N, twice the
    # surrogate's range); O(h^2.1) convergence (σ ∝ (θ0 − θ)^1.1 at the entry).
    assert np.all(error(DEFAULT_SIMPSON_POINTS) <= np.array([5e-4, 1.5e-3, 2e-3]))
    assert np.all(errors[-1] <= np.array([5e-6, 2e-5, 2e-5]))
    # Halving the step divides the error by ≈ 2^2.1 ≈ 4.3 asymptotically.
    for coarse, fine in zip(errors[1:], errors[2:], strict=False):
        assert np.all((fine <= coarse / 2.5) | (fine < 1e-9))
    assert np.all((errors[-1] <= errors[2] / 40.0) | (errors[-1] < 1e-9))


def test_skid_is_antisymmetric_about_zero_slip():
    load = np.array([5.0, 50.0, 150.0])[:, None]
    slip = np.array([0.05, 0.3, 1.0])[None, :]
    slipping = wheel_forces(load, slip)
    skidding = wheel_forces(load, -slip)
    at_zero = wheel_forces(load, 0.0 * slip)
    # Eqs. 10–11 (up to one rounding of the sum).
    np.testing.assert_allclose(
        skidding.drawbar_pull, -slipping.drawbar_pull + 2 * at_zero.drawbar_pull, rtol=0, atol=1e-13
    )
    np.testing.assert_allclose(
        skidding.resistive_torque, -slipping.resistive_torque + 2 * at_zero.resistive_torque, rtol=0, atol=1e-13
    )
    np.testing.assert_array_equal(skidding.contact_angle, slipping.contact_angle)
    # Skidding brakes: less pull and torque than at i = 0.
    assert np.all(skidding.drawbar_pull < at_zero.drawbar_pull)
    assert np.all(skidding.resistive_torque < at_zero.resistive_torque)


def test_drawbar_pull_and_torque_increase_with_slip():
    load = np.linspace(0.1, 200.0, 40)[:, None]
    slip = np.linspace(0.0, 1.0, 101)[None, :]
    forces = wheel_forces(load, slip)
    # τ_R rises with slip everywhere; DP up to i = 0.4 at every load, and over
    # the whole range 0 ≤ i ≤ 1 for light wheels (W ≤ 25 N).
    assert np.all(np.diff(forces.resistive_torque, axis=1) > 0.0)
    assert np.all(np.diff(forces.drawbar_pull[:, slip[0] <= 0.4], axis=1) > 0.0)
    assert np.all(np.diff(forces.drawbar_pull[load[:, 0] <= 25.0], axis=1) > 0.0)
    assert np.all(forces.drawbar_pull[:, 0] < 0.0)  # a towed wheel (i = 0) meets net resistance
    # Heavy wheels (Table II soil): slip sinkage moves θ_m forward and deepens
    # the rut, so DP peaks (≈ 10 N near W = 120 N, i ≈ 0.6; [RB]'s range ends at
    # 10.195 N) and falls again towards i = 1.
    heavy = wheel_forces(200.0, np.array([0.0, 0.4, 1.0]))
    assert heavy.drawbar_pull[2] < heavy.drawbar_pull[1]
    assert heavy.contact_angle[2] > heavy.contact_angle[0]


def test_grid_evaluation_matches_pointwise_evaluation():
    slip, load = surrogate_grid(100)
    grid = wheel_forces(load, slip)
    assert grid.drawbar_pull.shape == (100, 100)
    rng = np.random.default_rng(7)
    for row, col in rng.integers(0, 100, size=(5, 2)):
        single = wheel_forces(load[row, col], slip[row, col])
        assert float(single.drawbar_pull) == pytest.approx(grid.drawbar_pull[row, col], abs=1e-11)
        assert float(single.resistive_torque) == pytest.approx(grid.resistive_torque[row, col], abs=1e-12)


def test_algorithm_1_from_wheel_motion():
    omega, v = 2.0, 0.1  # r ω = 0.15 m/s: slip 1/3
    from_motion = wheel_forces_from_motion(50.0, omega, v)
    direct = wheel_forces(50.0, 1.0 / 3.0)
    assert float(from_motion.drawbar_pull) == pytest.approx(float(direct.drawbar_pull), rel=1e-12)
    skid = wheel_forces_from_motion(50.0, 1.0, 0.1)  # r ω = 0.075 < v: skid −0.25
    assert float(skid.drawbar_pull) == pytest.approx(float(wheel_forces(50.0, -0.25).drawbar_pull), rel=1e-12)


# ---------------------------------------------------------------------------
# 4th-order surrogate (C.2, D.3)
# ---------------------------------------------------------------------------


def test_surrogate_fits_the_full_model():
    surrogate = terramechanics_surrogate()
    assert terramechanics_surrogate() is surrogate  # cached in memory
    slip, load = surrogate_grid()
    truth = wheel_forces(load, slip)
    dp, tau = surrogate.wheel_forces(load, slip)
    dp_rms = float(np.sqrt(np.mean((dp - truth.drawbar_pull) ** 2)))
    tau_rms = float(np.sqrt(np.mean((tau - truth.resistive_torque) ** 2)))
    assert dp_rms == pytest.approx(surrogate.drawbar_pull_rms, rel=1e-9)
    assert tau_rms == pytest.approx(surrogate.resistive_torque_rms, rel=1e-9)
    # Bound: 1 % of the span of the fitted values. A smooth response over this
    # grid needs no more from a 4th-order polynomial; a wrong term order,
    # scaling or unscaling of the fit breaks it by orders of magnitude.
    dp_span = surrogate.drawbar_pull_range[1] - surrogate.drawbar_pull_range[0]
    tau_span = surrogate.resistive_torque_range[1] - surrogate.resistive_torque_range[0]
    assert 0.0 < dp_rms < 0.01 * dp_span
    assert 0.0 < tau_rms < 0.01 * tau_span
    # Span of the physics itself (paper: −9.406…10.195 N, 0…7.874 N·m): towed
    # resistance and full-slip pull of ≈ 10 N at 200 N load, τ_R from 0 to ≈ 8 N·m.
    assert -11.0 < surrogate.drawbar_pull_range[0] < -8.0
    assert 9.0 < surrogate.drawbar_pull_range[1] < 11.5
    assert 0.0 <= surrogate.resistive_torque_range[0] < 1e-3
    assert 7.0 < surrogate.resistive_torque_range[1] < 8.5
    # Largest errors at the edges of the parameter space ([RB] Fig. 5).
    edge = np.zeros(load.shape, dtype=bool)
    edge[[0, -1], :] = True
    edge[:, [0, -1]] = True
    dp_error = np.abs(dp - truth.drawbar_pull)
    assert dp_error[edge].max() > dp_error[~edge].max()


def test_surrogate_skid_and_lifted_wheel():
    surrogate = terramechanics_surrogate()
    load = np.array([20.0, 80.0])
    dp_slip, tau_slip = surrogate.wheel_forces(load, 0.4)
    dp_skid, tau_skid = surrogate.wheel_forces(load, -0.4)
    dp_zero, tau_zero = surrogate.wheel_forces(load, 0.0)
    np.testing.assert_allclose(dp_skid, -dp_slip + 2 * dp_zero, rtol=0, atol=1e-12)
    np.testing.assert_allclose(tau_skid, -tau_slip + 2 * tau_zero, rtol=0, atol=1e-12)
    dp_lifted, tau_lifted = surrogate.wheel_forces([0.0, -5.0], 0.4)
    np.testing.assert_array_equal(dp_lifted, 0.0)
    np.testing.assert_array_equal(tau_lifted, 0.0)


def test_firmer_soil_sinks_less_and_gets_its_own_surrogate():
    firm = WongReeceSoil(pressure_sinkage_k2=5000e3)
    load = np.array([10.0, 50.0, 200.0])
    assert np.all(contact_angle(load, 0.2, firm) < contact_angle(load, 0.2))
    soft_fit = fit_terramechanics_surrogate(grid_points=20)
    firm_fit = fit_terramechanics_surrogate(firm, grid_points=20)
    assert firm_fit.soil is firm
    assert firm_fit.drawbar_pull.coefficients != soft_fit.drawbar_pull.coefficients
    slip, grid_load = surrogate_grid(20)
    truth = wheel_forces(grid_load, slip, firm)
    dp, _ = firm_fit.wheel_forces(grid_load, slip)
    assert float(np.sqrt(np.mean((dp - truth.drawbar_pull) ** 2))) == pytest.approx(firm_fit.drawbar_pull_rms)
