"""The skid-steer truth plant's own physics (issue 20, item 1): magic-formula tire, terrain patches, slope.

The truth plant must not be the observer: its tire law differs from the brush
beyond small slips and depends on the load, each wheel reads the surface under
its own contact point, and gravity on an inclined plane reaches the body, the
loads and the IMU. The brush option still reproduces the plant recorded before
the change (numbers below, taken from the previous code).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from terrain_estimation.models.skid_steer import (
    brush_tire_forces,
    contact_velocities,
    theoretical_slips,
    tire_sideslip_angles,
    wheel_positions,
)
from vehicle_sim.plants.skid_steer import (
    MANOEUVRES,
    Manoeuvre,
    SkidSteerEffects,
    SkidSteerScenario,
    SkidSteerSensors,
    SkidSteerSimulator,
    SkidSteerVehicle,
    constant_torque,
    simulate_skid_steer,
    small_radius_turn,
)
from vehicle_sim.plants.skid_steer_ground import (
    SURFACES,
    GroundContact,
    SkidSteerGround,
    Surface,
    TerrainPatch,
)
from vehicle_sim.plants.skid_steer_scenarios import (
    MISMATCH_SCENARIOS,
    REPRODUCTION_SCENARIO_NAMES,
    reproduction_scenarios,
)
from vehicle_sim.plants.tire_laws import (
    MagicFormulaTire,
    brush_forces,
    magic_formula_forces,
    magic_formula_slips,
)

BRUSH = SkidSteerVehicle()
TRUTH = SkidSteerVehicle.truth_default()
P = BRUSH.nominal
FZ0 = BRUSH.nominal_wheel_load
MF = MagicFormulaTire()
QUIET = SkidSteerSensors.noiseless()
G = P.gravity


def mf(kappa, slip_y, fz, friction=P.friction, scale=1.0):
    return magic_formula_forces(
        kappa,
        slip_y,
        fz,
        tire=MF,
        nominal_load=FZ0,
        longitudinal_stiffness=P.longitudinal_stiffness,
        cornering_stiffness=P.cornering_stiffness,
        friction=friction,
        stiffness_scale=scale,
    )


def brush(sigma_x, sigma_y, fz):
    return brush_forces(
        sigma_x,
        sigma_y,
        fz,
        longitudinal_stiffness=P.longitudinal_stiffness,
        cornering_stiffness=P.cornering_stiffness,
        friction=P.friction,
    )


def wheel_state_forces(rolling, v_x, v_y, fz=FZ0):
    """(MF, brush) forces of a wheel in a given physical state: tread speed R ω, contact velocity (m/s)."""
    kappa, slip_y = magic_formula_slips(rolling, v_x, v_y, MF.low_speed)
    omega = np.broadcast_to(np.asarray(rolling, dtype=float) / P.wheel_radius, np.shape(kappa))
    sigma_x, sigma_y = theoretical_slips(omega, v_x, v_y, P)
    return mf(kappa, slip_y, fz), brush(sigma_x, sigma_y, fz)


# --- the tire law ------------------------------------------------------------------


def test_small_slip_stiffness_is_the_datasheet_and_the_shape_differs_beyond():
    # Same stiffness at small slip at the nominal load (a real tire matched to its datasheet) ...
    fx, _ = mf(1e-5, 0.0, FZ0)
    assert float(fx) / 1e-5 == pytest.approx(P.longitudinal_stiffness, rel=1e-4)
    _, fy = mf(0.0, 1e-5, FZ0)
    assert float(fy) / 1e-5 == pytest.approx(P.cornering_stiffness, rel=1e-4)
    small = np.radians(np.linspace(0.01, 0.1, 10))  # the brush is already 3 % lower at 0.5° (its γ²/3μF_z)
    (_, fy_mf), (_, fy_brush) = wheel_state_forces(2.0, 2.0, -2.0 * np.tan(small))
    np.testing.assert_allclose(fy_mf, fy_brush, rtol=0.01)
    # ... then the brush saturates flat at μ F_z, the magic formula peaks at a finite slip and falls.
    alpha = np.radians(np.linspace(0.5, 80.0, 400))
    (_, fy_mf), (_, fy_brush) = wheel_state_forces(2.0, 2.0, -2.0 * np.tan(alpha))
    mu_fz = P.friction * FZ0
    assert np.all(np.diff(fy_brush) >= -1e-9) and fy_brush[-1] == pytest.approx(mu_fz, rel=1e-12)
    peak = int(np.argmax(fy_mf))
    assert 0.15 < alpha[peak] < 0.35  # ≈ 13°
    assert fy_mf[peak] == pytest.approx(mu_fz, rel=1e-4)
    assert fy_mf[-1] < 0.95 * fy_mf[peak]  # falls after the peak (E curvature)
    assert np.max(np.abs(fy_mf / fy_brush - 1.0)) > 0.05
    kappa = np.linspace(0.005, 1.0, 400)
    (fx_mf, _), (fx_brush, _) = wheel_state_forces(2.0 * (1.0 + kappa), 2.0, 0.0)
    peak = int(np.argmax(fx_mf))
    assert 0.2 < kappa[peak] < 0.5
    assert fx_mf[-1] < 0.92 * fx_mf[peak]
    assert fx_brush[-1] == pytest.approx(mu_fz, rel=1e-12)
    assert fx_mf[-1] / fx_brush[-1] < 0.92
    # Beyond the fit's slip range (ρ_max = 4 peak slips) the force is held at a sliding level, not the
    # formula's asymptote D sin(C π/2) = 0.56 D: a wheel spinning at standstill keeps 0.82 of its peak.
    spinning = mf(np.array([1.5, 3.0, 30.0]), 0.0, FZ0)[0]
    np.testing.assert_allclose(spinning, spinning[-1], rtol=1e-12)
    assert 0.8 * mu_fz < spinning[-1] < 0.85 * mu_fz


def test_load_sensitivity():
    loads = np.array([0.5, 1.0, 2.0]) * FZ0
    eps = 1e-6
    cornering = mf(0.0, eps, loads)[1] / eps
    longitudinal = mf(eps, 0.0, loads)[0] / eps
    assert cornering[1] == pytest.approx(P.cornering_stiffness, rel=1e-4)
    # Degressive cornering stiffness: more per newton of load at light load, less at heavy load.
    assert cornering[0] / loads[0] > cornering[1] / loads[1] > cornering[2] / loads[2]
    assert cornering[2] > cornering[1]  # still rising at twice the load (max at p_Ky2 = 1.72 F_z0)
    np.testing.assert_allclose(cornering, MF.cornering_stiffness_at(loads, FZ0, P.cornering_stiffness), rtol=1e-4)
    # Longitudinal stiffness grows with the load (slightly faster than it).
    assert longitudinal[0] < longitudinal[1] < longitudinal[2]
    assert longitudinal[2] > 2.0 * longitudinal[1]
    # The friction coefficient falls with the load: peak force per unit load.
    slips = np.linspace(0.0, 2.0, 2001)
    peaks = np.array([np.max(mf(0.0, slips, fz)[1]) / fz for fz in loads])
    assert peaks[0] > peaks[1] > peaks[2]
    assert peaks[1] == pytest.approx(P.friction, rel=1e-5)
    np.testing.assert_allclose(peaks, MF.friction_at(loads, FZ0, P.friction), rtol=1e-5)
    # The brush has none of it: stiffness independent of the load, peak μ F_z at every load.
    brush_cornering = brush(0.0, eps, loads)[1] / eps
    assert np.ptp(brush_cornering) < 1e-4 * P.cornering_stiffness


def test_combined_slip_stays_in_the_friction_circle_and_keeps_the_slip_signs():
    rng = np.random.default_rng(4)
    kappa = rng.uniform(-1.0, 3.0, 5000)
    slip_y = np.tan(rng.uniform(-1.5, 1.5, 5000))
    fz = rng.uniform(0.2, 2.5, 5000) * FZ0
    fx, fy = mf(kappa, slip_y, fz)
    limit = MF.friction_at(fz, FZ0, P.friction) * fz
    assert np.all(np.hypot(fx, fy) <= limit * (1.0 + 1e-12))
    assert np.all(fx * kappa >= 0.0) and np.all(fy * slip_y >= 0.0)
    # Pure slip gives the pure curves; combined slip reduces each component.
    pure_x = mf(kappa, 0.0, fz)[0]
    assert np.all(np.abs(fx) <= np.abs(pure_x) + 1e-9)
    assert not np.allclose(fx, pure_x, rtol=0.05)
    # No load, no force.
    for fz in (0.0, -10.0):
        assert [float(f) for f in mf(0.3, 0.2, fz)] == [0.0, 0.0]


def test_brush_option_is_the_papers_law():
    rng = np.random.default_rng(2)
    sx, sy = rng.normal(0.0, 0.3, (2, 500))
    fz = rng.uniform(-100.0, 9000.0, 500)
    ours = brush_forces(sx, sy, fz, longitudinal_stiffness=3e4, cornering_stiffness=4e4, friction=0.7)
    paper = brush_tire_forces(sx, sy, fz, longitudinal_stiffness=3e4, cornering_stiffness=4e4, friction=0.7)
    np.testing.assert_array_equal(ours[0], paper[0])
    np.testing.assert_array_equal(ours[1], paper[1])


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: SkidSteerVehicle(tire_law="pacejka"), r"tire_law.*pacejka"),
        (lambda: MagicFormulaTire(shape_lateral=2.3), r"shape_lateral.*2\.3"),
        (lambda: MagicFormulaTire(curvature_longitudinal=1.0), r"curvature_longitudinal.*1\.0"),
        (lambda: MagicFormulaTire(low_speed=0.0), r"low_speed.*0\.0"),
        (lambda: Surface(name="ice", friction=0.0), r"ice.*friction.*0\.0"),
        (lambda: Surface(name="bog", friction=0.2, rolling_resistance=1.5), r"rolling_resistance.*1\.5"),
        (lambda: TerrainPatch(surface=SURFACES["mud"], x_min=5.0, x_max=1.0), r"x_min.*5\.0.*1\.0"),
        (lambda: SkidSteerGround(cross_slope=1.0), r"cross_slope.*1\.0"),
        (lambda: SkidSteerGround(transition=0.0), r"transition.*0\.0"),
        (lambda: SkidSteerScenario(manoeuvre=Manoeuvre(name="m", duration=1.0), ground=0.1), r"ground.*0\.1"),
    ],
)
def test_invalid_values_name_field_and_value(make, match):
    with pytest.raises(ValueError, match=match):
        make()


# --- the plant with its own tire ------------------------------------------------------


def test_truth_forces_are_the_plants_own_law_of_the_true_parameters():
    effects = SkidSteerEffects(friction_change=0.5, cornering_stiffness_change=1.3)
    scenario = constant_torque(-60.0, 120.0, duration=2.0, vehicle=TRUTH, effects=effects, sensors=QUIET)
    truth = simulate_skid_steer(scenario, 0).truth
    true = effects.true_params(P)
    cvx, cvy = contact_velocities(truth.vx, truth.vy, truth.yaw_rate, P)
    np.testing.assert_allclose(truth.tire_sideslip, tire_sideslip_angles(cvx, cvy), rtol=1e-12, atol=1e-15)
    rolling = P.wheel_radius * np.repeat(truth.wheel_speed, 3, axis=1)
    kappa, slip_y = magic_formula_slips(rolling, cvx, cvy, MF.low_speed)
    fx, fy = magic_formula_forces(
        kappa,
        slip_y,
        truth.normal_load,
        tire=MF,
        nominal_load=FZ0,
        longitudinal_stiffness=true.longitudinal_stiffness,
        cornering_stiffness=true.cornering_stiffness,
        friction=true.friction,
    )
    np.testing.assert_allclose(truth.tire_force_x, fx, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(truth.tire_force_y, fy, rtol=1e-9, atol=1e-6)
    np.testing.assert_array_equal(truth.friction, true.friction)
    # Not the brush of the same state: the observer's law would be wrong by far more than noise.
    sigma_x, sigma_y = theoretical_slips(truth.wheel_speed, cvx, cvy, true)
    bx, by = brush_tire_forces(
        sigma_x,
        sigma_y,
        truth.normal_load,
        longitudinal_stiffness=true.longitudinal_stiffness,
        cornering_stiffness=true.cornering_stiffness,
        friction=true.friction,
    )
    assert np.max(np.abs(by - fy)) > 0.05 * true.friction * FZ0
    # Turning on the spot saturates the tires at their load-dependent friction, never beyond.
    utilisation = np.hypot(fx, fy) / (MF.friction_at(truth.normal_load, FZ0, true.friction) * truth.normal_load)
    assert 0.95 < utilisation.max() <= 1.0 + 1e-12
    # The force sums drive the body.
    net = truth.tire_force_x - truth.motion_resistance
    np.testing.assert_allclose(truth.specific_force_x * P.mass, net.sum(axis=1), rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(truth.specific_force_y * P.mass, truth.tire_force_y.sum(axis=1), rtol=1e-9, atol=1e-6)


def test_coasting_never_gains_energy():
    """Tire and rolling-resistance forces only dissipate: kinetic energy of body and drive line never grows."""
    scenario = constant_torque(0.0, 0.0, initial_speed=5.0, duration=3.0, vehicle=TRUTH, sensors=QUIET)
    simulator = SkidSteerSimulator(scenario, 0)
    state = simulator.state
    state[4], state[5] = 0.4, 0.6  # vy (m/s), r (rad/s): a skidding, yawing start
    simulator._state = state
    energies = []
    while not simulator.done:
        tr = simulator.step().truth
        energies.append(
            0.5 * P.mass * (tr.vx**2 + tr.vy**2)
            + 0.5 * P.yaw_inertia * tr.yaw_rate**2
            + 0.5 * TRUTH.side_inertia * float(np.sum(tr.wheel_speed**2))
        )
    energies = np.array(energies)
    assert np.all(np.diff(energies) <= 1e-9 * energies[0])
    assert energies[-1] < 0.8 * energies[0]


@pytest.mark.parametrize(
    "effects", [SkidSteerEffects.nominal(), SkidSteerEffects.truth_default()], ids=["nominal", "truth"]
)
def test_default_step_is_converged_with_the_magic_formula(effects):
    # The worst case of the brush test (differential torques from rest, slips saturating at once).
    base = constant_torque(-40.0, 120.0, duration=1.0, vehicle=TRUTH, effects=effects, sensors=QUIET)
    coarse = simulate_skid_steer(base, 0).truth
    fine = simulate_skid_steer(replace(base, integration_step=0.5e-3), 0).truth
    np.testing.assert_allclose(coarse.vx, fine.vx, atol=1e-4)
    np.testing.assert_allclose(coarse.yaw_rate, fine.yaw_rate, atol=5e-5)
    np.testing.assert_allclose(coarse.vy, fine.vy, atol=2e-5)
    np.testing.assert_allclose(coarse.wheel_speed, fine.wheel_speed, rtol=1e-3, atol=1e-2)
    np.testing.assert_allclose(coarse.normal_load, fine.normal_load, atol=1.0)
    assert np.abs(fine.yaw_rate).max() > 0.04


# --- the brush option reproduces the previous plant --------------------------------------

# Final sample of three runs recorded with the plant before the magic formula, patches and slope (seed 7).
_RECORDED = {
    "turn_truth_12s": {
        "vx": 1.3821005228426249,
        "vy": 0.007359415837102772,
        "yaw_rate": 0.19981662779331302,
        "x": 12.212210587666569,
        "y": 3.1509152167336714,
        "yaw": 0.9853037002383049,
        "wheel_speed": [2.458207247597895, 5.174639486216239],
        "normal_load": [
            4696.455418347524,
            4841.129021703395,
            4922.764017932526,
            4862.873113025226,
            5007.546716381097,
            5089.181712610229,
        ],
        "tire_force_y": [
            -3212.377593786976,
            784.1986996315089,
            3083.4754846162677,
            -2933.4074173112494,
            514.3210294148191,
            2595.1282899824196,
        ],
        "roll": 0.001525783580134322,
        "pitch": 3.6396089110949006e-07,
        "accel": [0.04526539823053823, 0.1958076607896469, 9.87298094011278],
        "gyro": [0.0019269128853787107, 0.0008010465050128481, 0.1991509938230657],
        "motor_position": [798.855776849569, 1162.4414371750115],
    },
    "straight_grade_nominal_4s": {
        "vx": 2.967939484655673,
        "x": 4.443307062873468,
        "wheel_speed": [8.160752655548386, 8.160752655548386],
        "normal_load": [
            4278.712637681649,
            5002.292189857773,
            5410.586534114017,
            4278.712637681649,
            5002.292189857773,
            5410.586534114017,
        ],
        "accel": [1.441196428165515, 0.007743929672549662, 9.807593716776369],
        "motor_position": [331.48404437735974, 331.48404437735974],
    },
    "torque_nominal_2s": {
        "vx": 6.709069881846048,
        "vy": -0.05964488648175866,
        "yaw_rate": 0.09669557508820326,
        "x": 6.703185930634002,
        "y": 0.30024692609572123,
        "yaw": 0.09762448618819032,
        "wheel_speed": [18.389671533789578, 20.258401251639018],
        "normal_load": [
            3497.5752456626524,
            4952.79283830044,
            5773.928691226772,
            3821.360728869404,
            5276.5783215071915,
            6097.714174433523,
        ],
        "tire_force_y": [
            -462.375062026645,
            430.7511059852486,
            944.5232091881527,
            -341.5571234959472,
            336.310166148958,
            763.1259629259345,
        ],
        "accel": [3.360441910863196, 0.5774302393980904, 9.82063105347082],
        "motor_position": [498.98554252974446, 550.3570251352467],
    },
}


def _recorded_scenario(name: str) -> SkidSteerScenario:
    if name == "turn_truth_12s":  # the old default truth: brush tire, roll/pitch dynamics, relaxation
        return replace(MANOEUVRES["small_radius_turn"](vehicle=BRUSH), duration=12.0)
    if name == "straight_grade_nominal_4s":  # no relaxation (stiff steps), the helical grade, μ changed
        effects = SkidSteerEffects(terrain_grade=0.05, friction_change=0.7)
        return replace(MANOEUVRES["straight_acceleration"](vehicle=BRUSH, effects=effects), duration=4.0)
    return constant_torque(60.0, 120.0, duration=2.0)


@pytest.mark.parametrize("name", list(_RECORDED))
def test_brush_option_reproduces_the_previous_plant(name):
    scenario = _recorded_scenario(name)
    assert scenario.vehicle.tire_law == "brush"
    result = simulate_skid_steer(scenario, seed=7)
    measured = {
        "accel": result.linear_acceleration[-1],
        "gyro": result.angular_velocity[-1],
        "motor_position": result.motor_position[-1],
    }
    for key, expected in _RECORDED[name].items():
        value = measured[key] if key in measured else getattr(result.truth, key)[-1]
        np.testing.assert_allclose(value, expected, rtol=1e-10, atol=1e-9, err_msg=f"{name}: {key}")
    # The magic-formula truth of the same run differs (the test can fail).
    other = simulate_skid_steer(replace(scenario, vehicle=TRUTH), seed=7)
    assert abs(other.truth.vx[-1] - _RECORDED[name]["vx"]) + abs(other.truth.x[-1] - _RECORDED[name]["x"]) > 1e-4


# --- terrain patches ---------------------------------------------------------------------


def contact_points(truth, wheel: int) -> tuple[np.ndarray, np.ndarray]:
    xw, yw = wheel_positions(P)
    c, s = np.cos(truth.yaw), np.sin(truth.yaw)
    return truth.x + c * xw[wheel] - s * yw[wheel], truth.y + s * xw[wheel] + c * yw[wheel]


@pytest.mark.parametrize("vehicle", [TRUTH, BRUSH], ids=["magic_formula", "brush"])
def test_each_wheel_enters_a_patch_where_it_reaches_it(vehicle):
    mud = SURFACES["mud"]
    edge = 6.0
    # Mud on the left half of the lane from x = 6 m: only the left wheels reach it, front first.
    ground = SkidSteerGround(patches=(TerrainPatch(surface=mud, x_min=edge, y_min=0.0),), transition=0.3)
    scenario = replace(
        constant_torque(10.0, 10.0, initial_speed=3.0, duration=4.0, vehicle=vehicle, sensors=QUIET), ground=ground
    )
    result = simulate_skid_steer(scenario, 0)
    truth = result.truth
    base = P.friction
    for wheel in range(6):  # off the patch: the vehicle's own surface; well on it: mud
        x, y = contact_points(truth, wheel)
        np.testing.assert_array_equal(truth.friction[(x < edge - 0.15) | (y < -0.15), wheel], base)
        np.testing.assert_array_equal(truth.friction[(x > edge + 0.15) & (y > 0.15), wheel], mud.friction)
    np.testing.assert_array_equal(truth.friction[:, 3:], base)  # the right wheels never reach it
    entries = []
    for wheel in range(3):
        x, _ = contact_points(truth, wheel)
        mu = truth.friction[:, wheel]
        # Halfway across the edge when the contact point is on it (blend 3u² − 2u³, u = ½ + d/0.3).
        crossing = np.flatnonzero(np.diff(np.sign(x - edge)))[0]
        t_edge = np.interp(edge, x[crossing : crossing + 2], result.t[crossing : crossing + 2])
        assert np.interp(t_edge, result.t, mu) == pytest.approx(0.5 * (base + mud.friction), abs=0.02)
        entries.append(t_edge)
        # Rolling resistance of the surface under the wheel.
        on = x > edge + 0.15
        cvx = truth.vx[on] - truth.yaw_rate[on] * 0.5 * P.track
        expected = mud.rolling_resistance * truth.normal_load[on, wheel] * np.tanh(cvx / BRUSH.rolling_resistance_speed)
        np.testing.assert_allclose(truth.motion_resistance[on, wheel], expected, rtol=1e-9)
    # Front, then middle, then rear: one axle spacing / speed apart.
    xw, _ = wheel_positions(P)
    speed = float(np.mean(truth.vx[(result.t > entries[0]) & (result.t < entries[2])]))
    np.testing.assert_allclose(np.diff(entries), -np.diff(xw[:3]) / speed, rtol=0.03)
    # The mud drags the left side: the vehicle yaws left and slows more than on its own surface.
    plain = simulate_skid_steer(replace(scenario, ground=SkidSteerGround()), 0).truth
    assert truth.yaw[-1] > plain.yaw[-1] + 0.01
    assert truth.vx[-1] < plain.vx[-1] - 0.1


def test_patches_blend_in_order_and_scale_the_stiffness():
    wheel_x, wheel_y = (np.array([0.0]), np.array([0.0]))
    base = Surface(name="base", friction=0.8, rolling_resistance=0.02)
    ground = SkidSteerGround(
        patches=(
            TerrainPatch(surface=SURFACES["grass"], x_max=10.0),
            TerrainPatch(surface=SURFACES["mud"], x_min=5.0, x_max=8.0, y_min=-1.0, y_max=1.0),
        ),
        transition=0.4,
    )
    contact = GroundContact(ground, base, 0.5, wheel_x, wheel_y, G, 0.0)
    at = {x: contact.surfaces(x, 0.0, 1.0, 0.0) for x in (2.0, 6.5, 9.0, 12.0)}
    assert [float(v[0][0]) for v in at.values()] == pytest.approx([0.2, 0.125, 0.2, 0.8])  # friction_change 0.5
    assert float(at[6.5][1][0]) == SURFACES["mud"].stiffness_scale
    assert float(at[12.0][2][0]) == base.rolling_resistance
    # Beside the mud strip (y = 1.2, 0.2 m past its edge) only the grass counts.
    assert float(contact.surfaces(6.5, 1.2, 1.0, 0.0)[0][0]) == pytest.approx(0.2)
    # A softer surface lowers the magic formula's slip stiffness by its factor.
    eps = 1e-6
    soft = mf(0.0, eps, FZ0, scale=SURFACES["mud"].stiffness_scale)[1] / eps
    assert soft == pytest.approx(SURFACES["mud"].stiffness_scale * P.cornering_stiffness, rel=1e-4)


# --- slope -------------------------------------------------------------------------------


def parked(vehicle, ground, effects=None, duration=3.0):
    manoeuvre = Manoeuvre(name="parked", duration=duration, motor_torque=(0.0, 0.0))
    scenario = SkidSteerScenario(
        manoeuvre=manoeuvre,
        vehicle=vehicle,
        effects=SkidSteerEffects() if effects is None else effects,
        sensors=QUIET,
        ground=ground,
    )
    return simulate_skid_steer(scenario, 0)


@pytest.mark.parametrize("vehicle", [TRUTH, BRUSH], ids=["magic_formula", "brush"])
def test_parked_on_a_bank_the_imu_reads_gravity_and_the_vehicle_stays(vehicle):
    bank = math.radians(5.0)
    result = parked(vehicle, SkidSteerGround(cross_slope=bank))
    truth = result.truth
    late = result.t > 1.0
    # At rest on the bank (left side up) the accelerometer reads the slope's gravity components.
    np.testing.assert_allclose(result.linear_acceleration[late, 1], G * math.sin(bank), rtol=1e-4)
    np.testing.assert_allclose(result.linear_acceleration[late, 2], G * math.cos(bank), rtol=1e-9)
    # Along x only what the creeping yaw (below 1e-4 rad) turns of the slope's pull.
    assert np.all(np.abs(truth.yaw) < 1e-4)
    np.testing.assert_allclose(result.linear_acceleration[late, 0], 0.0, atol=1e-4)
    # Normal loads: m g cos γ in all, moved to the downhill (right) side by m g sin γ H / B per side.
    loads = truth.normal_load[late]
    np.testing.assert_allclose(loads.sum(axis=1), P.mass * G * math.cos(bank), rtol=1e-9)
    transfer = loads[:, 3:].sum(axis=1) - loads[:, :3].sum(axis=1)
    np.testing.assert_allclose(transfer, 2.0 * P.mass * G * math.sin(bank) * P.cg_height / P.track, rtol=1e-4)
    # Friction holds it: the slip-velocity tire creeps downhill at millimetres per second at most.
    assert abs(truth.y[-1]) < 0.01
    assert np.all(np.abs(truth.vy[late]) < 0.005)
    assert truth.vy[-1] <= 0.0


def test_on_a_bank_steeper_than_the_friction_allows_it_slides():
    bank = math.radians(5.0)
    ice = TerrainPatch(surface=Surface(name="ice", friction=0.05))  # tan 5° = 0.087 > μ
    result = parked(TRUTH, SkidSteerGround(cross_slope=bank, patches=(ice,)))
    truth = result.truth
    late = result.window(1.0, 3.0)
    accel = np.polyfit(result.t[late], truth.vy[late], 1)[0]
    # Downhill (−y) at g (sin γ − μ_eff cos γ), μ_eff ≤ μ(F_z) (the magic formula slides below its peak).
    mu_max = float(np.max(MF.friction_at(truth.normal_load[late], FZ0, 0.05)))
    assert -G * math.sin(bank) < accel < -G * (math.sin(bank) - mu_max * math.cos(bank))
    assert truth.vy[-1] < -0.5


def test_truth_effects_on_a_bank_hold_with_the_body_rolled_downhill():
    bank = math.radians(5.0)
    result = parked(TRUTH, SkidSteerGround(cross_slope=bank), SkidSteerEffects.truth_default(), duration=5.0)
    truth = result.truth
    late = result.t > 3.0
    assert abs(truth.y[-1]) < 0.03
    # The sprung mass leans downhill (right side down, left up: roll > 0, REP 103) and the IMU sees it.
    assert np.all(truth.roll[late] > 0.0)
    # The lateral force holds the vehicle on average; the relaxed tire at standstill (a damper, V/L = 0.6/s
    # lag) leaves a lightly damped ≈ 2.7 Hz sway of ±1 %, a known low-speed limit of that relaxation model.
    f_y = truth.specific_force_y[late]
    assert np.mean(f_y) == pytest.approx(G * math.sin(bank), rel=3e-3)
    assert np.max(np.abs(f_y / (G * math.sin(bank)) - 1.0)) < 0.03
    expected_y = np.cos(truth.roll[late]) * f_y + np.sin(truth.roll[late]) * G * math.cos(bank)
    np.testing.assert_allclose(result.linear_acceleration[late, 1], expected_y, atol=5e-3)
    assert np.mean(result.linear_acceleration[late, 1] - f_y) > 5e-3  # the roll's share of gravity


def test_gravity_on_the_slope_turns_with_the_heading():
    """A turn on a 5° cross slope: v̇x − vy r − f_x = −g sin γ sin ψ and v̇y + vx r − f_y = −g sin γ cos ψ."""
    slope = math.radians(5.0)
    effects = SkidSteerEffects(tire_relaxation=True)  # no body tilt: the IMU reads the specific force itself
    scenario = replace(
        small_radius_turn(vehicle=TRUTH, effects=effects, sensors=QUIET, speed=3.0, yaw_rate=0.6, duration=20.0),
        ground=SkidSteerGround(cross_slope=slope),
    )
    result = simulate_skid_steer(scenario, 0)
    truth, t = result.truth, result.t
    window = result.window(9.0, 19.5)
    gx = np.gradient(truth.vx, t) - truth.vy * truth.yaw_rate - truth.specific_force_x
    gy = np.gradient(truth.vy, t) + truth.vx * truth.yaw_rate - truth.specific_force_y
    psi = truth.yaw[window]
    np.testing.assert_allclose(gx[window], -G * math.sin(slope) * np.sin(psi), atol=0.01)
    np.testing.assert_allclose(gy[window], -G * math.sin(slope) * np.cos(psi), atol=0.01)
    assert np.ptp(psi) > 2.0 * math.pi  # a whole revolution: every direction of the slope
    # The IMU reads the specific force (no body tilt without load-transfer dynamics) and g cos γ normal to it.
    np.testing.assert_allclose(result.linear_acceleration[window, 0], truth.specific_force_x[window], atol=1e-12)
    np.testing.assert_allclose(result.linear_acceleration[window, 2], G * math.cos(slope), rtol=1e-12)
    np.testing.assert_allclose(truth.normal_load[window].sum(axis=1), P.mass * G * math.cos(slope), rtol=1e-9)


def test_helical_grade_and_plane_grade_agree_heading_uphill():
    """Heading +x, a plane rising along x is the catalogue's helical grade: the same run to rounding."""
    grade = 0.05
    base = replace(MANOEUVRES["straight_acceleration"](vehicle=TRUTH, sensors=QUIET), duration=6.0)
    helical = simulate_skid_steer(replace(base, effects=replace(base.effects, terrain_grade=grade)), 0)
    plane = simulate_skid_steer(replace(base, ground=SkidSteerGround(grade=grade)), 0)
    np.testing.assert_allclose(plane.truth.vx, helical.truth.vx, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(plane.linear_acceleration, helical.linear_acceleration, rtol=1e-9, atol=1e-9)
    assert helical.truth.vx[-1] < simulate_skid_steer(base, 0).truth.vx[-1]


# --- scenarios of the reproduction --------------------------------------------------------


def test_reproduction_scenarios_are_the_issues_set_on_the_independent_plant():
    scenarios = reproduction_scenarios()
    assert tuple(scenarios) == REPRODUCTION_SCENARIO_NAMES
    assert set(MISMATCH_SCENARIOS) <= set(scenarios)
    for name, scenario in scenarios.items():
        assert scenario.vehicle.tire_law == "magic_formula", name
        assert scenario.effects.load_transfer_dynamics and scenario.effects.tire_relaxation, name
    changes = {name: s.effects.cornering_stiffness_change for name, s in scenarios.items()}
    assert changes["cornering_stiffness_plus_30"] == 1.3 and changes["cornering_stiffness_minus_30"] == 0.7
    assert scenarios["bank_5deg"].ground.cross_slope == pytest.approx(math.radians(5.0))
    (patch,) = scenarios["friction_patch"].ground.patches
    assert patch.surface.friction == pytest.approx(0.5 * P.friction)
    sharp = scenarios["sharp_turn"].manoeuvre
    assert sharp.speeds[-1] == 3.0 and sharp.yaw_rates[-1] == 0.6
    assert {scenarios[n].manoeuvre.name for n in ("s_shape", "straight_acceleration")} == {
        "s_shape",
        "straight_acceleration",
    }
    idealised = reproduction_scenarios(vehicle=BRUSH)
    assert all(s.vehicle.tire_law == "brush" for s in idealised.values())


def test_friction_patch_is_entered_mid_turn_wheel_by_wheel():
    scenario = replace(reproduction_scenarios(sensors=QUIET)["friction_patch"], duration=18.0)
    result = simulate_skid_steer(scenario, 0)
    truth = result.truth
    half = 0.5 * P.friction
    entries = [result.t[np.argmax(truth.friction[:, w] < 0.5 * (P.friction + half))] for w in range(6)]
    assert all(12.0 < t < 17.0 for t in entries), entries
    assert len(set(entries)) > 1  # not all at once
    on = truth.friction[-1]
    np.testing.assert_allclose(on, half)
    at_entry = result.window(min(entries), min(entries))
    assert truth.yaw_rate[at_entry][0] == pytest.approx(0.2, abs=0.01)  # mid-turn


def test_sharp_turn_reaches_3_m_s_and_0_6_rad_s():
    scenario = replace(reproduction_scenarios(sensors=QUIET)["sharp_turn"], duration=14.0)
    result = simulate_skid_steer(scenario, 0)
    window = result.window(11.0, 14.0)
    truth = result.truth
    assert truth.vx[window].mean() == pytest.approx(3.0, rel=0.025)  # the speed integrator is slow (0.5/s)
    assert truth.yaw_rate[window].mean() == pytest.approx(0.6, rel=0.005)
    assert np.abs(truth.body_sideslip[window]).mean() > 0.05  # a real sideslip for the filters to estimate


# --- the simulator node --------------------------------------------------------------------


def test_simulator_node_defaults_to_the_truth_and_builds_slope_and_patches():
    registry = pytest.importorskip("vehicle_sim.ros.registry")
    node = pytest.importorskip("vehicle_sim.ros.skid_steer")
    entry = registry.get_simulator("skid_steer")
    default = node.make_scenario(registry.simulator_parameters(entry, None, {}))
    assert default.vehicle == SkidSteerVehicle.truth_default(nominal=default.vehicle.nominal)
    assert default.ground == SkidSteerGround()
    overrides = {
        "plant.tire_law": "brush",
        "ground.cross_slope": 0.05,
        "ground.patch_friction": [0.3, 0.2],
        "ground.patch_stiffness_scale": [0.5, 0.4],
        "ground.patch_rolling_resistance": [0.1, 0.15],
        "ground.patch_x_min": [10.0, -1e9],
        "ground.patch_x_max": [1e9, 0.0],
        "ground.patch_y_min": [-1e9, -1e9],
        "ground.patch_y_max": [1e9, 1e9],
    }
    scenario = node.make_scenario(registry.simulator_parameters(entry, None, overrides))
    assert scenario.vehicle.tire_law == "brush"
    assert scenario.ground.cross_slope == 0.05
    first, second = scenario.ground.patches
    assert (first.x_min, first.x_max, first.y_min) == (10.0, math.inf, -math.inf)
    assert (second.surface.friction, second.x_min, second.x_max) == (0.2, -math.inf, 0.0)
    bad = registry.simulator_parameters(entry, None, {**overrides, "ground.patch_x_min": [10.0]})
    with pytest.raises(ValueError, match=r"ground\.patch_x_min 1"):
        node.make_scenario(bad)
