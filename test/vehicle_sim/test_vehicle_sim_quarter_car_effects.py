"""Quarter car / LRV unmodelled effects (issue 6 catalogue; CONTRACT.md "Nominal model and effects")."""

from dataclasses import fields, replace

import numpy as np
import pytest

from vehicle_sim.plants.quarter_car import (
    LRV_IGNORED_EFFECTS,
    QUARTER_CAR_EFFECTS,
    STANDARD_GRAVITY,
    LRVVehicle,
    QuarterCarEffects,
    QuarterCarSimulator,
    QuarterCarVehicle,
    Scenario,
    enveloped_profile,
    simulate,
)
from vehicle_sim.plants.quarter_car_dynamics import _bekker_chain_force
from vehicle_sim.terrain.profiles import RoadProfile, iso8608_profile, sinusoidal_profile
from vehicle_sim.terrain.soils import GRANEVILLE_LOAM, LETE_SAND, LUNAR_REGOLITH, SoilPath

QC = QuarterCarVehicle()
LRV = LRVVehicle()
ROAD_D = iso8608_profile("D", seed=1)


def quiet(**kwargs) -> Scenario:
    """Scenario without sensor noise."""
    return Scenario(accel_noise_variance=0.0, profile_noise_std=0.0, **kwargs)


def prony_eigenvalues(signal: np.ndarray, order: int, period: float) -> np.ndarray:
    """Continuous-time eigenvalues of a noise-free free response (linear prediction)."""
    rows = np.column_stack([signal[order - j - 1 : len(signal) - j - 1] for j in range(order)])
    coeffs, *_ = np.linalg.lstsq(rows, signal[order:], rcond=None)
    roots = np.roots(np.concatenate([[1.0], -coeffs]))
    return np.log(roots.astype(complex)) / period


def steady_amplitude(signal: np.ndarray, skip: int) -> float:
    tail = signal[skip:]
    return 0.5 * float(tail.max() - tail.min())


def assert_same_run(a, b, *, sensors=True, truth=True):
    """Profile, odometry (and optionally accelerometers and truth) identical bit for bit."""
    np.testing.assert_array_equal(a.profile.elevation, b.profile.elevation)
    np.testing.assert_array_equal(a.profile.distance, b.profile.distance)
    np.testing.assert_array_equal(a.wheel_angle, b.wheel_angle)
    np.testing.assert_array_equal(a.wheel_rate, b.wheel_rate)
    if sensors:
        np.testing.assert_array_equal(a.body_accel_z, b.body_accel_z)
        if a.wheel_accel_z is not None:
            np.testing.assert_array_equal(a.wheel_accel_z, b.wheel_accel_z)
    if truth:
        np.testing.assert_array_equal(a.truth.body_displacement, b.truth.body_displacement)
        np.testing.assert_array_equal(a.truth.contact_force, b.truth.contact_force)


# --- catalogue and nominal ----------------------------------------------------------


def test_catalogue_covers_every_field_once():
    names = [name for group in QUARTER_CAR_EFFECTS.values() for name in group]
    assert sorted(names) == sorted(f.name for f in fields(QuarterCarEffects))
    assert set(QUARTER_CAR_EFFECTS) == {
        "accel_bias",
        "accel_scale",
        "sensor_delay",
        "nonlinear_soil",
        "wheel_liftoff",
        "suspension_friction",
        "tire_damping",
        "tire_enveloping",
        "sprung_mass_change",
    }
    assert QuarterCarEffects().active == () == QuarterCarEffects.nominal().active
    assert QuarterCarEffects(soil_exponent=1.0).active == ()  # n = 1 is the linear soil
    effects = QuarterCarEffects(accel_bias_wheel=0.1, soil_exponent=0.8, tire_contact_length=0.2)
    assert effects.active == ("accel_bias_wheel", "soil_exponent", "tire_contact_length")
    assert effects.active_effects == ("accel_bias", "nonlinear_soil", "tire_enveloping")


@pytest.mark.parametrize("vehicle", [QC, LRV], ids=["quarter_car", "lrv"])
def test_default_effects_are_the_nominal_plant_bit_for_bit(vehicle):
    soil = LUNAR_REGOLITH if vehicle is LRV else SoilPath([(0.0, GRANEVILLE_LOAM), (10.0, LETE_SAND)])
    nominal = simulate(vehicle, Scenario(profile=ROAD_D, soil_path=soil), 2.0, seed=4)
    for effects in (QuarterCarEffects(), QuarterCarEffects.nominal(), QuarterCarEffects(soil_exponent=1.0)):
        run = simulate(vehicle, Scenario(profile=ROAD_D, soil_path=soil, effects=effects), 2.0, seed=4)
        assert_same_run(nominal, run)
        np.testing.assert_array_equal(nominal.truth.body_acceleration, run.truth.body_acceleration)


def test_scenario_wheel_liftoff_is_the_effect_switch():
    old = Scenario(profile=ROAD_D, wheel_liftoff=True)
    new = Scenario(profile=ROAD_D, effects=QuarterCarEffects(wheel_liftoff=True))
    assert old == new
    assert old.wheel_liftoff and old.effects.wheel_liftoff
    assert new.wheel_liftoff and new.effects.wheel_liftoff
    assert not Scenario().wheel_liftoff and not Scenario().effects.wheel_liftoff
    # Switching it on keeps the other effects.
    both = Scenario(wheel_liftoff=True, effects=QuarterCarEffects(accel_bias_body=0.5))
    assert both.effects == QuarterCarEffects(accel_bias_body=0.5, wheel_liftoff=True)


# --- sensor effects ---------------------------------------------------------------


def test_accel_bias_shifts_the_readings_by_the_bias_only():
    scenario = Scenario(profile=ROAD_D)
    nominal = simulate(QC, scenario, 2.0, seed=1)
    biased = simulate(
        QC, replace(scenario, effects=QuarterCarEffects(accel_bias_body=0.3, accel_bias_wheel=-0.2)), 2.0, seed=1
    )
    np.testing.assert_allclose(biased.body_accel_z - nominal.body_accel_z, 0.3, atol=1e-12)
    np.testing.assert_allclose(biased.wheel_accel_z - nominal.wheel_accel_z, -0.2, atol=1e-12)
    assert biased.body_accel_z.mean() - nominal.body_accel_z.mean() == pytest.approx(0.3, abs=1e-12)
    assert_same_run(nominal, biased, sensors=False)


def test_accel_scale_scales_the_specific_force():
    scenario = quiet(profile=ROAD_D)
    nominal = simulate(QC, scenario, 2.0, seed=1)
    scaled = simulate(
        QC, replace(scenario, effects=QuarterCarEffects(accel_scale_body=0.1, accel_scale_wheel=-0.05)), 2.0, seed=1
    )
    np.testing.assert_allclose(scaled.body_accel_z, 1.1 * nominal.body_accel_z, rtol=1e-13)
    assert scaled.body_accel_z.var() == pytest.approx(1.1**2 * nominal.body_accel_z.var(), rel=1e-10)
    assert scaled.wheel_accel_z.var() == pytest.approx(0.95**2 * nominal.wheel_accel_z.var(), rel=1e-10)
    assert scaled.body_accel_z.mean() == pytest.approx(1.1 * nominal.body_accel_z.mean(), rel=1e-12)
    assert_same_run(nominal, scaled, sensors=False)


def test_sensor_delay_shifts_the_accelerometers_against_profile_and_joints():
    scenario = quiet(profile=ROAD_D)
    nominal = simulate(QC, scenario, 3.0, seed=1)
    delayed = simulate(QC, replace(scenario, effects=QuarterCarEffects(sensor_delay=0.03)), 3.0, seed=1)
    # Whole periods: an exact shift (to rounding: the integrator's acceleration, not the truth's
    # arithmetic); the t = 0 reading fills the start.
    np.testing.assert_allclose(delayed.body_accel_z[3:], nominal.body_accel_z[:-3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(delayed.wheel_accel_z[3:], nominal.wheel_accel_z[:-3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(delayed.body_accel_z[:3], STANDARD_GRAVITY, atol=1e-12)
    assert_same_run(nominal, delayed, sensors=False)
    # The cross-correlation with the undelayed reading peaks at the delay.
    a = nominal.wheel_accel_z - nominal.wheel_accel_z.mean()
    b = delayed.wheel_accel_z - delayed.wheel_accel_z.mean()
    lags = np.arange(-10, 11)
    xcorr = [np.dot(a[max(0, -k) : a.size - max(0, k)], b[max(0, k) : b.size - max(0, -k)]) for k in lags]
    assert lags[int(np.argmax(xcorr))] == 3
    # A delay that is not a whole sensor period is a true time shift (on the 1 ms integration grid),
    # not an interpolation between sensor samples: 25 ms late at 100 Hz reads what a 200 Hz sensor
    # of the undelayed run reads 5 of its samples earlier.
    half = simulate(QC, replace(scenario, effects=QuarterCarEffects(sensor_delay=0.025)), 3.0, seed=1)
    fine = simulate(QC, replace(scenario, sensor_rate=200.0), 3.0, seed=1)
    for delayed_z, fine_z in ((half.body_accel_z, fine.body_accel_z), (half.wheel_accel_z, fine.wheel_accel_z)):
        # delayed sample i (t = 10 (i + 1) ms) ↔ fine sample 2 i − 4 (t = 5 (2 i − 3) ms, 25 ms earlier)
        np.testing.assert_allclose(delayed_z[3:], fine_z[2:-4:2], rtol=0, atol=1e-9)
    linear = 0.5 * (nominal.wheel_accel_z[1:-2] + nominal.wheel_accel_z[:-3])
    assert np.max(np.abs(half.wheel_accel_z[3:] - linear)) > 1e-3  # the sensor-rate interpolation was not this


# --- dynamic effects --------------------------------------------------------------


def test_suspension_friction_reduces_the_relative_suspension_motion():
    scenario = quiet(profile=ROAD_D)
    nominal = simulate(QC, scenario, 3.0, seed=1)
    rubbing = simulate(QC, replace(scenario, effects=QuarterCarEffects(suspension_friction=300.0)), 3.0, seed=1)
    travel = nominal.truth.wheel_displacement - nominal.truth.body_displacement
    travel_f = rubbing.truth.wheel_displacement - rubbing.truth.body_displacement
    assert np.std(travel_f) < 0.9 * np.std(travel)
    assert np.std(np.diff(travel_f)) < 0.9 * np.std(np.diff(travel))
    assert_same_run(nominal, rubbing, sensors=False, truth=False)
    # Same road under the tire: only the plant changed.
    np.testing.assert_array_equal(nominal.truth.road_elevation, rubbing.truth.road_elevation)


def test_suspension_friction_too_stiff_for_rk4_is_rejected():
    with pytest.raises(ValueError, match="suspension_friction"):
        QuarterCarSimulator(QC, Scenario(effects=QuarterCarEffects(suspension_friction=5000.0)), seed=0)
    QuarterCarSimulator(
        QC, Scenario(integration_step=1e-4, effects=QuarterCarEffects(suspension_friction=5000.0)), seed=0
    )


def test_tire_damping_reduces_the_wheel_hop_resonance():
    f_wheel = QC.undamped_natural_frequencies(GRANEVILLE_LOAM.k_s)[1]
    speed = 10.0
    road = sinusoidal_profile(0.003, speed / f_wheel)  # excites the wheel hop
    scenario = quiet(profile=road, speed=speed, soil_path=GRANEVILLE_LOAM)
    nominal = simulate(QC, scenario, 2.0, seed=0)
    damped = simulate(QC, replace(scenario, effects=QuarterCarEffects(tire_damping=1500.0)), 2.0, seed=0)
    hop, hop_damped = (steady_amplitude(r.truth.wheel_acceleration, 100) for r in (nominal, damped))
    assert hop_damped < 0.8 * hop
    assert_same_run(nominal, damped, sensors=False, truth=False)


def test_tire_enveloping_filters_short_wavelengths_only():
    length = 0.3
    effects = QuarterCarEffects(tire_contact_length=length)
    # Short: one contact length (cancelled exactly by the moving average).
    short = quiet(profile=sinusoidal_profile(0.005, length), speed=3.0, soil_path=GRANEVILLE_LOAM)
    nominal = simulate(QC, short, 2.0, seed=0)
    enveloped = simulate(QC, replace(short, effects=effects), 2.0, seed=0)
    assert steady_amplitude(nominal.wheel_accel_z, 100) > 1.0
    assert steady_amplitude(enveloped.wheel_accel_z, 100) < 1e-6
    # The profile sampler still measures the true road.
    assert_same_run(nominal, enveloped, sensors=False, truth=False)
    np.testing.assert_array_equal(nominal.truth.road_elevation, enveloped.truth.road_elevation)
    # Long: 10 m waves pass (sinc(0.03) = 0.9985).
    long = quiet(profile=sinusoidal_profile(0.02, 10.0), speed=10.0, soil_path=GRANEVILLE_LOAM)
    amp, amp_env = (
        steady_amplitude(simulate(QC, replace(long, effects=e), 3.0, seed=0).wheel_accel_z, 150)
        for e in (QuarterCarEffects(), effects)
    )
    assert amp_env == pytest.approx(amp * np.sinc(length / 10.0), rel=2e-3)


class _Opaque(RoadProfile):
    """A non-harmonic profile (forces the quadrature average)."""

    def __init__(self, inner: RoadProfile) -> None:
        self.inner = inner

    def elevation_and_slope(self, distance):
        return self.inner.elevation_and_slope(distance)


def test_enveloping_quadrature_matches_the_exact_harmonic_average():
    s = np.linspace(0.0, 20.0, 201)
    exact = enveloped_profile(ROAD_D, 0.25)
    generic = enveloped_profile(_Opaque(ROAD_D), 0.25)
    h_exact, dh_exact = exact.elevation_and_slope(s)
    h_generic, dh_generic = generic.elevation_and_slope(s)
    scale = np.std(h_exact)
    np.testing.assert_allclose(h_generic, h_exact, atol=1e-6 * scale)
    np.testing.assert_allclose(dh_generic, dh_exact, atol=1e-9)
    assert enveloped_profile(ROAD_D, 0.0) is ROAD_D


def test_sprung_mass_change_shifts_the_body_mode():
    change = 0.3
    undamped = QuarterCarVehicle(suspension_damping=0.0)
    scenario = quiet(speed=0.0, soil_path=GRANEVILLE_LOAM)
    heavier = replace(scenario, effects=QuarterCarEffects(sprung_mass_change=change))
    free = simulate(undamped, heavier, 4.0, seed=0, initial_state=(0.01, 0.0, -0.005, 0.0))
    eig = prony_eigenvalues(free.truth.wheel_displacement, 4, scenario.sensor_period)
    body = np.sort(np.abs(eig.imag))[0] / (2 * np.pi)
    expected = replace(undamped, sprung_mass=undamped.sprung_mass * (1 + change)).undamped_natural_frequencies(
        GRANEVILLE_LOAM.k_s
    )[0]
    nominal = undamped.undamped_natural_frequencies(GRANEVILLE_LOAM.k_s)[0]
    assert body == pytest.approx(expected, rel=1e-5)
    assert body / nominal == pytest.approx(expected / nominal, rel=1e-5)
    assert body / nominal < 0.95
    # The LRV's lumped mass: f ∝ 1/√m.
    lrv = LRVVehicle(damping=0.0)
    lrv_free = simulate(
        lrv,
        quiet(speed=0.0, soil_path=LUNAR_REGOLITH, effects=QuarterCarEffects(sprung_mass_change=change)),
        3.0,
        seed=0,
        initial_state=(0.02, 0.0),
    )
    lrv_eig = prony_eigenvalues(lrv_free.truth.body_displacement, 2, scenario.sensor_period)
    f = abs(lrv_eig[0].imag) / (2 * np.pi)
    assert f == pytest.approx(lrv.undamped_natural_frequency(LUNAR_REGOLITH.k_s) / np.sqrt(1 + change), rel=1e-5)
    # At rest the accelerometers still read g and the ground carries the new weight.
    rest = simulate(QC, quiet(profile=ROAD_D, speed=0.0, effects=QuarterCarEffects(sprung_mass_change=change)), 0.5, 0)
    np.testing.assert_allclose(rest.body_accel_z, STANDARD_GRAVITY, atol=1e-12)
    np.testing.assert_allclose(
        rest.truth.contact_force, (QC.sprung_mass * (1 + change) + QC.unsprung_mass) * STANDARD_GRAVITY, rtol=1e-12
    )


@pytest.mark.parametrize("n", [0.5, 1.0, 1.7])
def test_bekker_chain_inverts_the_series_law(n):
    k, k_s, load = 15.0e3, LUNAR_REGOLITH.k_s, 735.0
    z0 = load / k_s
    for deflection in (-0.2, -0.05, -0.001, 0.0, 0.001, 0.03, 0.2):
        f_d = _bekker_chain_force(deflection, k, k_s, load, n)
        x = (load + f_d) / load
        rebuilt = f_d / k + z0 * (np.sign(x) * abs(x) ** (1 / n) - 1)
        assert rebuilt == pytest.approx(deflection, abs=1e-12)
    if n == 1.0:
        assert _bekker_chain_force(0.01, k, k_s, load, n) == pytest.approx(0.01 * k * k_s / (k + k_s), rel=1e-12)


def test_nonlinear_soil_keeps_equilibrium_and_responds_asymmetrically():
    effects = QuarterCarEffects(soil_exponent=1.6)
    # Static equilibrium: at rest the readings are +g and the ground carries the weight.
    rest = simulate(LRV, quiet(profile=ROAD_D, speed=0.0, soil_path=LUNAR_REGOLITH, effects=effects), 0.5, seed=0)
    np.testing.assert_allclose(rest.body_accel_z, STANDARD_GRAVITY, atol=1e-9)
    np.testing.assert_allclose(rest.truth.contact_force, LRV.total_mass * STANDARD_GRAVITY, rtol=1e-12)
    # Small oscillations: the linearised soil stiffness is n k_s.
    free = simulate(
        LRVVehicle(damping=0.0),
        quiet(speed=0.0, soil_path=LUNAR_REGOLITH, effects=effects),
        3.0,
        seed=0,
        initial_state=(1e-5, 0.0),
    )
    eig = prony_eigenvalues(free.truth.body_displacement, 2, 0.01)
    k_lin = 1.0 / (1.0 / LRV.combined_stiffness + 1.0 / (1.6 * LUNAR_REGOLITH.k_s))
    assert abs(eig[0].imag) == pytest.approx(np.sqrt(k_lin / LRV.sprung_mass), rel=1e-4)

    # Large free oscillations: up and down are no longer mirror images (z0 = 2.6 cm here).
    def mirror_error(soil_effects: QuarterCarEffects) -> float:
        runs = [
            simulate(
                LRVVehicle(damping=0.0),
                quiet(speed=0.0, soil_path=LUNAR_REGOLITH, effects=soil_effects),
                1.0,
                seed=0,
                initial_state=(y0, 0.0),
            ).truth.body_displacement
            for y0 in (0.03, -0.03)
        ]
        return float(np.max(np.abs(runs[0] + runs[1])) / 0.03)

    assert mirror_error(QuarterCarEffects()) < 1e-12
    assert mirror_error(effects) > 0.02
    assert mirror_error(QuarterCarEffects(soil_exponent=0.6)) > 0.02
    # The 2-DOF car runs with it too.
    qc = simulate(QC, quiet(profile=ROAD_D, soil_path=GRANEVILLE_LOAM, effects=effects), 1.0, seed=0)
    assert np.all(np.isfinite(qc.wheel_accel_z))


def test_wheel_liftoff_effect_on_a_rough_road():
    profile = iso8608_profile("F", seed=3)
    lifting = simulate(
        QC, Scenario(profile=profile, soil_path=LETE_SAND, effects=QuarterCarEffects(wheel_liftoff=True)), 5.0, 0
    )
    old_switch = simulate(QC, Scenario(profile=profile, soil_path=LETE_SAND, wheel_liftoff=True), 5.0, seed=0)
    airborne = ~lifting.truth.in_contact
    assert 0.02 < airborne.mean() < 0.3
    assert lifting.truth.contact_force.min() >= 0.0
    np.testing.assert_array_equal(lifting.truth.contact_force[airborne], 0.0)
    assert_same_run(lifting, old_switch)


# --- validation -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("accel_bias_body", float("nan")),
        ("accel_bias_wheel", float("inf")),
        ("accel_scale_body", -1.0),
        ("accel_scale_wheel", 1.5),
        ("sensor_delay", -0.01),
        ("sensor_delay", 2.0),
        ("soil_exponent", 0.1),
        ("soil_exponent", -1.0),
        ("soil_exponent", 4.0),
        ("wheel_liftoff", "yes"),
        ("suspension_friction", -1.0),
        ("tire_damping", -5.0),
        ("tire_contact_length", -0.1),
        ("tire_contact_length", 10.0),
        ("sprung_mass_change", -1.0),
        ("sprung_mass_change", float("nan")),
    ],
)
def test_invalid_effects_name_the_field(name, value):
    with pytest.raises(ValueError, match=f"QuarterCarEffects.{name}"):
        QuarterCarEffects(**{name: value})


@pytest.mark.parametrize("name", LRV_IGNORED_EFFECTS)
def test_lrv_rejects_effects_that_do_not_apply(name):
    with pytest.raises(ValueError, match=name):
        QuarterCarSimulator(LRV, Scenario(effects=QuarterCarEffects(**{name: 0.1})), seed=0)


# --- ROS adapter ------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["quarter_car", "lrv"])
def test_sim_adapter_exposes_the_effects(kind):
    from vehicle_sim.ros.quarter_car import make_scenario, specs_for

    specs = {spec.name: spec for spec in specs_for(kind)}
    values = {name: spec.default for name, spec in specs.items()}
    assert make_scenario(values).effects == QuarterCarEffects()
    declared = {name.removeprefix("effects.") for name in specs if name.startswith("effects.")}
    expected = {f.name for f in fields(QuarterCarEffects)}
    assert declared == (expected - set(LRV_IGNORED_EFFECTS) if kind == "lrv" else expected)
    for name in declared:
        assert specs[f"effects.{name}"].description
    on = {
        "effects.accel_bias_body": 0.2,
        "effects.sensor_delay": 0.02,
        "effects.soil_exponent": 1.3,
        "effects.wheel_liftoff": True,
        "effects.tire_contact_length": 0.2,
        "effects.sprung_mass_change": 0.1,
    }
    if kind == "quarter_car":
        on |= {"effects.tire_damping": 100.0, "effects.suspension_friction": 50.0, "effects.accel_scale_wheel": 0.01}
    effects = make_scenario(values | on).effects
    for key, value in on.items():
        assert getattr(effects, key.removeprefix("effects.")) == value
    assert make_scenario(values | {"scenario.wheel_liftoff": True}).effects.wheel_liftoff
