"""Effect catalogue (vehicle_sim.effects) and the rover's slip-sinkage, grouser and path-undulation effects."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vehicle_sim.effects import CATALOGUE, VEHICLES, Effect, effects_class, effects_for, parameter_count
from vehicle_sim.plants import quarter_car
from vehicle_sim.plants.rover import (
    RoverEffects,
    RoverScenario,
    RoverSensorNoise,
    simulate_rover,
    undulated_path,
)
from vehicle_sim.plants.rover_terramechanics import _Terramechanics
from vehicle_sim.plants.skid_steer import SkidSteerEffects
from vehicle_sim.terrain.terramechanics_surrogate import fit_terramechanics_surrogate
from vehicle_sim.terrain.wong_reece import TABLE_II_SOIL, RigidWheel

#: Issue 6's catalogue names per vehicle (the catalogue may add more).
ISSUE_NAMES = {
    "quarter_car": {
        "accel_bias",
        "accel_scale",
        "sensor_delay",
        "nonlinear_soil",
        "wheel_liftoff",
        "suspension_friction",
        "tire_damping",
        "tire_enveloping",
        "sprung_mass_change",
    },
    "lrv": {
        "accel_bias",
        "accel_scale",
        "sensor_delay",
        "nonlinear_soil",
        "wheel_liftoff",
        "tire_enveloping",
        "sprung_mass_change",
    },  # suspension_friction, tire_damping: rejected by the 1-DOF LRV (LRV_IGNORED_EFFECTS)
    "skid_steer": {
        "gyro_bias",
        "accel_bias",
        "sensor_delay",
        "wheel_radius_error",
        "friction_change",
        "cornering_stiffness_change",
        "load_transfer_dynamics",
        "tire_relaxation",
        "terrain_grade",
    },
    "rover": {
        "vertical_velocity",
        "load_cell_bias",
        "load_cell_crosstalk",
        "slip_sinkage",
        "soil_change",
        "grousers",
        "imu_bias",
        "sensor_delay",
    },
}

ALL_EFFECTS = [(vehicle, name) for vehicle in VEHICLES for name in CATALOGUE[vehicle]]


def _effect(vehicle: str, name: str) -> Effect:
    return CATALOGUE[vehicle][name]


# -- catalogue ---------------------------------------------------------------------------------


def test_vehicles_and_issue_names():
    assert set(VEHICLES) == {"quarter_car", "lrv", "skid_steer", "rover"}
    for vehicle, names in ISSUE_NAMES.items():
        assert names <= set(CATALOGUE[vehicle]), names - set(CATALOGUE[vehicle])
        for name, effect in CATALOGUE[vehicle].items():
            assert effect.vehicle == vehicle and effect.name == name
            assert effect.description and effect.physical_meaning and effect.parameters


def test_quarter_car_catalogue_matches_the_plant_mapping():
    for name, fields in quarter_car.QUARTER_CAR_EFFECTS.items():
        assert tuple(p.field for p in _effect("quarter_car", name).parameters) == fields
        lrv_fields = tuple(f for f in fields if f not in quarter_car.LRV_IGNORED_EFFECTS)
        if lrv_fields:
            assert tuple(p.field for p in _effect("lrv", name).parameters) == lrv_fields
        else:
            assert name not in CATALOGUE["lrv"]


@pytest.mark.parametrize(("vehicle", "name"), ALL_EFFECTS)
def test_parameters_have_units_and_finite_ranges_around_the_off_value(vehicle, name):
    effect = _effect(vehicle, name)
    assert len(set(effect.parameter_names)) == len(effect.parameters)
    for p in effect.parameters:
        low, high = p.fit_range
        assert p.unit and p.description
        assert math.isfinite(low) and math.isfinite(high) and low < high
        assert low <= p.off <= high and low <= p.typical <= high
    assert any(p.typical != p.off for p in effect.parameters)  # a typical effect is on
    assert parameter_count(effect) == sum(1 for p in effect.parameters if p.unit != "bool")


def test_every_field_belongs_to_one_effect_and_exists_in_the_plant():
    for vehicle in VEHICLES:
        cls = effects_class(vehicle)
        names = {f.name for f in dataclasses.fields(cls)}
        owner: dict[str, str] = {}
        for effect in CATALOGUE[vehicle].values():
            for field in {p.field for p in effect.parameters if p.field}:
                assert field in names, (vehicle, effect.name, field)
                assert owner.setdefault(field, effect.name) == effect.name, (vehicle, field)


def test_parameter_counts():
    assert parameter_count(_effect("skid_steer", "accel_bias")) == 3
    assert parameter_count(_effect("skid_steer", "tire_relaxation")) == 0
    assert parameter_count(_effect("quarter_car", "accel_bias")) == 2
    assert parameter_count(_effect("lrv", "accel_bias")) == 1
    assert parameter_count(_effect("rover", "imu_bias")) == 3
    assert parameter_count(_effect("rover", "vertical_velocity")) == 2
    assert parameter_count(_effect("rover", "soil_change")) == 5


# -- building ----------------------------------------------------------------------------------


@pytest.mark.parametrize(("vehicle", "name"), ALL_EFFECTS)
def test_off_values_build_the_nominal_plant(vehicle, name):
    effect = _effect(vehicle, name)
    built = effects_for(vehicle, {name: {p.name: p.off for p in effect.parameters}})
    assert isinstance(built, effects_class(vehicle))
    assert built.active == ()
    assert effects_for(vehicle, {}) == effects_class(vehicle)()


@pytest.mark.parametrize(("vehicle", "name"), ALL_EFFECTS)
def test_typical_values_set_the_fields(vehicle, name):
    effect = _effect(vehicle, name)
    values = effect.typical_values()
    built = effects_for(vehicle, {name: values})
    nominal = effects_class(vehicle)()
    assert built.active  # something switched on
    touched = {p.field for p in effect.parameters if p.field}
    for p in effect.parameters:
        if not p.field:
            continue
        got = getattr(built, p.field)
        if p.index is not None:
            got = got[p.index]
        assert got == (bool(values[p.name]) if p.unit == "bool" else pytest.approx(values[p.name])), p.name
    if vehicle == "rover" and name == "soil_change":
        touched = {"soil_change_distance", "soil_change_soil"}
    for f in dataclasses.fields(nominal):
        if f.name not in touched:
            assert getattr(built, f.name) == getattr(nominal, f.name), f.name


def test_combined_effects_and_tuple_components():
    skid = effects_for(
        "skid_steer",
        {"accel_bias": {"accel_bias_y": 0.2}, "tire_relaxation": {}, "friction_change": {"friction_change": 0.5}},
    )
    assert skid == SkidSteerEffects(accel_bias=(0.0, 0.2, 0.0), tire_relaxation=True, friction_change=0.5)
    switched_off = effects_for("skid_steer", {"load_transfer_dynamics": {"load_transfer_dynamics": False}})
    assert switched_off == SkidSteerEffects()
    rover = effects_for(
        "rover",
        {
            "load_cell_bias": {"load_cell_bias_middle": -2.0},
            "imu_bias": {"imu_accel_bias_z": 0.1, "imu_gyro_bias": 0.01},
            "grousers": {"grouser_height": 0.005},
        },
    )
    assert rover == RoverEffects(
        load_cell_bias=(0.0, -2.0, 0.0), imu_accel_bias=(0.0, 0.1), imu_gyro_bias=0.01, grouser_height=0.005
    )
    qc = effects_for("quarter_car", {"nonlinear_soil": {"soil_exponent": 1.5}, "wheel_liftoff": {}})
    assert qc == quarter_car.QuarterCarEffects(soil_exponent=1.5, wheel_liftoff=True)


def test_soil_change_scales_the_scenario_soil():
    values = {
        "soil_change_distance": 0.8,
        "soil_change_cohesion_scale": 0.5,
        "soil_change_friction_angle_change": -0.1,
        "soil_change_modulus_scale": 2.0,
        "soil_change_shear_modulus_scale": 1.5,
    }
    built = effects_for("rover", {"soil_change": values})
    soil = built.soil_change_soil
    assert built.soil_change_distance == 0.8
    assert soil.cohesion == pytest.approx(0.5 * TABLE_II_SOIL.cohesion)
    assert soil.friction_angle == pytest.approx(TABLE_II_SOIL.friction_angle - 0.1)
    assert soil.pressure_sinkage_k1 == pytest.approx(2.0 * TABLE_II_SOIL.pressure_sinkage_k1)
    assert soil.pressure_sinkage_k2 == pytest.approx(2.0 * TABLE_II_SOIL.pressure_sinkage_k2)
    assert soil.shear_deformation_modulus == pytest.approx(1.5 * TABLE_II_SOIL.shear_deformation_modulus)
    assert soil.sinkage_exponent == TABLE_II_SOIL.sinkage_exponent
    other = dataclasses.replace(TABLE_II_SOIL, cohesion=1000.0)
    assert effects_for("rover", {"soil_change": values}, soil=other).soil_change_soil.cohesion == 500.0


def test_softest_changed_soil_still_has_a_surrogate():
    """The fit range's softest corner still carries the surrogate's 200 N grid (no WheelOverloadError)."""
    effect = _effect("rover", "soil_change")
    values = {
        "soil_change_distance": 1.0,
        "soil_change_cohesion_scale": effect.parameter("soil_change_cohesion_scale").fit_range[0],
        "soil_change_friction_angle_change": effect.parameter("soil_change_friction_angle_change").fit_range[0],
        "soil_change_modulus_scale": effect.parameter("soil_change_modulus_scale").fit_range[0],
        "soil_change_shear_modulus_scale": effect.parameter("soil_change_shear_modulus_scale").fit_range[1],
    }
    soil = effects_for("rover", {"soil_change": values}).soil_change_soil
    fit_terramechanics_surrogate(soil, RigidWheel(radius=0.075, width=0.07), grid_points=30)


@pytest.mark.parametrize(
    ("vehicle", "effects", "words"),
    [
        ("tank", {}, ["tank"]),
        ("rover", {"wheel_liftoff": {}}, ["rover", "wheel_liftoff"]),
        ("lrv", {"tire_damping": {"tire_damping": 100.0}}, ["lrv", "tire_damping"]),
        ("skid_steer", {"gyro_bias": {"gyro_bais": 0.01}}, ["skid_steer", "gyro_bias", "gyro_bais", "0.01"]),
        ("rover", {"grousers": {"grouser_height": 0.5}}, ["rover", "grousers", "grouser_height", "0.5"]),
        ("quarter_car", {"sensor_delay": {"sensor_delay": -0.01}}, ["quarter_car", "sensor_delay", "-0.01"]),
        ("skid_steer", {"terrain_grade": {"terrain_grade": math.nan}}, ["skid_steer", "terrain_grade", "nan"]),
        ("skid_steer", {"tire_relaxation": {"tire_relaxation": 0.5}}, ["skid_steer", "tire_relaxation", "0.5"]),
        ("rover", {"imu_bias": {"imu_gyro_bias": "fast"}}, ["rover", "imu_bias", "imu_gyro_bias", "fast"]),
    ],
)
def test_errors_name_vehicle_effect_parameter_and_value(vehicle, effects, words):
    with pytest.raises(ValueError) as error:
        effects_for(vehicle, effects)
    for word in words:
        assert word in str(error.value)


# -- rover effects in the plant ----------------------------------------------------------------

_FLAT = RoverScenario(terrain="flat", duration=2.0, sensors=RoverSensorNoise.noiseless())


@pytest.fixture(scope="module")
def nominal_flat():
    return simulate_rover(_FLAT)


def _with(effects: RoverEffects, **changes: object) -> RoverScenario:
    return dataclasses.replace(_FLAT, effects=effects, **changes)


def test_new_effects_are_off_by_default_and_the_nominal_plant_is_unchanged(nominal_flat):
    effects = RoverEffects()
    assert (effects.slip_sinkage_coefficient, effects.grouser_height, effects.path_undulation_amplitude) == (0, 0, 0)
    assert _FLAT.path.description == "level ground"
    # Naming the new effects at their off values is the nominal plant, bit for bit.
    off = effects_for(
        "rover",
        {name: _effect("rover", name).off_values() for name in ("slip_sinkage", "grousers", "vertical_velocity")},
    )
    assert off == effects
    again = simulate_rover(_with(off))
    for name in ("configuration", "velocity", "slip", "normal_load", "drawbar_pull", "resistive_torque"):
        np.testing.assert_array_equal(getattr(again.truth, name), getattr(nominal_flat.truth, name))
    for name in ("acceleration", "load_axial", "pitch_rate", "forward_velocity"):
        np.testing.assert_array_equal(getattr(again.sensors, name), getattr(nominal_flat.sensors, name))


def test_slip_sinkage_scales_the_soil_forces():
    """Forces at W with k/(1 + c|i|) are the model's forces at W (1 + c|i|) divided by 1 + c|i|."""
    c = 1.0
    plain = _Terramechanics(_FLAT)
    sinking = _Terramechanics(_with(RoverEffects(slip_sinkage_coefficient=c)))
    load, slip, index = np.array([40.0, 50.0, 60.0]), np.array([0.1, 0.3, -0.2]), np.zeros(3, dtype=int)
    scale = 1.0 + c * np.abs(slip)
    dp, tau, _ = sinking(load, slip, index)
    dp0, tau0, _ = plain(load * scale, slip, index)
    np.testing.assert_allclose(dp, dp0 / scale, rtol=1e-12)
    np.testing.assert_allclose(tau, tau0 / scale, rtol=1e-12)


def test_slip_sinkage_deepens_the_rut_and_raises_the_torque():
    base = simulate_rover(_with(RoverEffects(), terramechanics="wong_reece", duration=1.0)).truth
    sunk = simulate_rover(
        _with(RoverEffects(slip_sinkage_coefficient=1.0), terramechanics="wong_reece", duration=1.0)
    ).truth
    tail = slice(-15, None)
    assert np.mean(sunk.entry_angle[tail]) > np.mean(base.entry_angle[tail]) + 0.01  # deeper (θ0 ≈ 0.64 rad)
    assert np.mean(sunk.resistive_torque[tail]) > 1.02 * np.mean(base.resistive_torque[tail])
    assert np.mean(sunk.wheel_torque[tail]) > np.mean(base.wheel_torque[tail])


def test_slip_sinkage_runs_with_the_surrogate(nominal_flat):
    sunk = simulate_rover(_with(RoverEffects(slip_sinkage_coefficient=1.0))).truth
    tail = slice(-25, None)
    assert np.mean(sunk.resistive_torque[tail]) > 1.02 * np.mean(nominal_flat.truth.resistive_torque[tail])
    assert np.all(np.isfinite(sunk.configuration))


def test_grousers_shear_at_the_tips():
    h = 0.01
    grousers = _Terramechanics(_with(RoverEffects(grouser_height=h)))
    radius = _FLAT.params.wheel_radius
    assert grousers.wheel.radius == pytest.approx(radius + h)
    # Rolling without slip at the rim is slipping at the grouser tips: traction at i = 0.
    dp0, _, _ = _Terramechanics(_FLAT)(np.array([50.0]), np.array([0.0]), np.zeros(1, dtype=int))
    dp, _, _ = grousers(np.array([50.0]), np.array([0.0]), np.zeros(1, dtype=int))
    assert dp[0] > dp0[0] + 1.0


def test_grousers_reduce_the_slip(nominal_flat):
    run = simulate_rover(_with(RoverEffects(grouser_height=0.005))).truth
    tail = slice(-25, None)
    base_slip = float(np.mean(nominal_flat.truth.slip[tail]))
    assert base_slip > 0.1
    assert np.mean(run.slip[tail]) < 0.7 * base_slip
    assert np.mean(run.forward_velocity[tail]) > np.mean(nominal_flat.truth.forward_velocity[tail])


def test_path_undulation_moves_the_body_vertically(nominal_flat):
    effects = RoverEffects(path_undulation_amplitude=0.004, path_undulation_wavelength=0.3)
    scenario = _with(effects)
    path = scenario.path
    x = np.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(path.height(x), 0.004 * (1.0 - np.cos(2.0 * math.pi * x / 0.3)), atol=1e-15)
    for value in (0.0, 0.137, 0.61):
        np.testing.assert_allclose(path.point(value), [a[0] for a in path.evaluate([value])], atol=1e-15)
    run = simulate_rover(scenario).truth
    # On flat ground the body moves vertically only as the wheels settle into their sinkage (issue 21: ≈ 4e-5
    # m/s in the first seconds; ż0^R also holds ẋ0 sin θ of the tilt the differential sinkage gives the body).
    nominal_vz = np.max(np.abs(nominal_flat.truth.velocity[:, 1]))
    assert nominal_vz < 1e-4
    undulated_vz = np.max(np.abs(run.velocity[:, 1]))
    assert undulated_vz > 3e-4 and undulated_vz > 5.0 * nominal_vz  # ≳ 1.5 % of the 2 cm/s forward speed
    assert np.max(np.abs(run.vertical_velocity)) > 1e-4
    assert np.max(np.abs(run.constraint_residual)) < 1e-8
    assert np.max(np.abs(run.path_curvature)) > 1.0


def test_undulated_path_adds_to_the_terrain():
    base = RoverScenario(terrain="rolling").path
    wavy = undulated_path(base, 0.002, 0.4)
    x = np.linspace(0.0, 2.0, 50)
    for a, b in zip(wavy.evaluate(x), base.evaluate(x), strict=True):
        assert np.max(np.abs(a - b)) > 0.0
    assert wavy.name == base.name and wavy.duration == base.duration


def test_rover_effect_validation():
    with pytest.raises(ValueError, match="slip_sinkage_coefficient"):
        RoverEffects(slip_sinkage_coefficient=-0.1)
    with pytest.raises(ValueError, match="grouser_height"):
        RoverEffects(grouser_height=-0.01)
    with pytest.raises(ValueError, match="path_undulation_wavelength"):
        RoverEffects(path_undulation_wavelength=0.0)
    with pytest.raises(ValueError, match="curvature"):
        RoverScenario(effects=RoverEffects(path_undulation_amplitude=0.05, path_undulation_wavelength=0.2))
    # The catalogue's extreme corner is a valid scenario.
    RoverScenario(effects=RoverEffects(path_undulation_amplitude=0.01, path_undulation_wavelength=0.3))


def test_rover_sim_node_exposes_the_plant_effects():
    """Every RoverEffects field the simulator node can set is a parameter that reaches the plant."""
    from vehicle_sim.plants.rover import RoverEffects
    from vehicle_sim.ros.rover import make_scenario, specs_for

    specs = {spec.name: spec for spec in specs_for("rover")}
    values = {name: spec.default for name, spec in specs.items()}
    assert make_scenario(values).effects == RoverEffects()
    on = {
        "effects.slip_sinkage_coefficient": 0.5,
        "effects.grouser_height": 0.005,
        "effects.path_undulation_amplitude": 0.003,
        "effects.path_undulation_wavelength": 0.8,
        "effects.load_cell_crosstalk": 0.02,
        "effects.imu_gyro_bias": 0.001,
    }
    effects = make_scenario(values | on).effects
    for key, value in on.items():
        assert specs[key].description
        assert getattr(effects, key.removeprefix("effects.")) == value
