"""Rover replay model of the sim-to-real attribution (issue 6): physics against the plant, errors, speed.

Short simulator runs (:func:`vehicle_sim.plants.rover.simulate_rover`, Table IV
noise, the plant's default wheel sinkage on) with one catalogue effect on: the
nominal replay must leave the residuals at the noise budget on a nominal run,
show a gap with the effect on, and close it again when the replay has the same
effect at the same value.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from terrain_analysis.sim2real.model import ReplayModel
from terrain_analysis.sim2real.rover import (
    RoverReplay,
    build_model,
    build_model_from_series,
    series_from_run,
)
from terrain_analysis.sim2real.rover_bag import WHEELS
from terrain_analysis.sim2real.rover_sinkage import START_WINDOW
from terrain_analysis.sim2real.where import Sim2RealError
from vehicle_sim.effects import effects_for
from vehicle_sim.plants.rover import RoverScenario, simulate_rover

REPO = Path(__file__).resolve().parents[1]
DURATION = 10.0


def _run(effects: dict[str, dict[str, float]], terrain: str = "rolling", seed: int = 5, **options: Any) -> Any:
    # The plant sinks each wheel by its Wong-Reece sinkage (wheel_sinkage, on by default since issue 21); the
    # replay models that sinkage with its own soil (rover_sinkage).
    scenario = RoverScenario(
        terrain=terrain, duration=DURATION, seed=seed, effects=effects_for("rover", effects), **options
    )
    return simulate_rover(scenario)


def _rms(model: RoverReplay, effects: dict[str, dict[str, float]], start: float = 0.0) -> dict[str, float]:
    """RMS of the normalised residual per channel after the warm-up (and after ``start`` s)."""
    pred = model.predict(effects, {})
    out = {}
    for ch in model.channels:
        t = model.times[ch.name]
        use = t >= t[0] + max(model.warmup, start)
        r = (model.measured[ch.name] - pred[ch.name])[use] / ch.noise_std
        out[ch.name] = float(np.sqrt(np.mean(r**2)))
    return out


@pytest.fixture(scope="module")
def nominal() -> tuple[Any, RoverReplay]:
    run = _run({})
    return run, build_model_from_series(series_from_run(run))


def test_nominal_residuals_at_noise_budget(nominal: tuple[Any, RoverReplay]) -> None:
    _, model = nominal
    assert isinstance(model, ReplayModel)
    rms = _rms(model, {})
    assert set(rms) == {
        "accel_x",
        "accel_z",
        "pitch_rate",
        "moment_body",
        "moment_bogie",
        "velocimeter",
        "vz_front_middle",
        "vz_middle_rear",
    }
    for name, value in rms.items():
        assert 0.5 < value < 1.3, (name, value)


def test_noise_budget_is_the_sensor_noise_propagated(nominal: tuple[Any, RoverReplay]) -> None:
    _, model = nominal
    sigma = {c.name: c.noise_std for c in model.channels}
    # The velocimeter's own noise (Table IV, 1 mm/s) dominates its channel.
    assert 0.9e-3 < sigma["velocimeter"] < 1.2e-3
    # Six load-cell readings of 0.0326 N over 15 kg dominate the accelerometer channels.
    assert 3.0e-3 < sigma["accel_x"] < 5.5e-3
    assert sigma["pitch_rate"] == pytest.approx(math.radians(0.56), rel=0.12)


def test_inferred_wheel_state_matches_the_plant(nominal: tuple[Any, RoverReplay]) -> None:
    run, model = nominal
    model.predict({}, {})
    state = model._last_state
    use = run.time >= model.warmup
    slip_error = state["slip"][use] - run.truth.slip[use]
    load_error = state["load"][use] - run.truth.normal_load[use]
    delta_error = state["delta"][use] - (run.truth.contact_angle - run.truth.carrier_angle)[use]
    assert np.max(np.std(slip_error, axis=0)) < 0.005
    assert np.max(np.abs(np.mean(slip_error, axis=0))) < 0.002
    assert np.max(np.std(load_error, axis=0)) < 0.06
    assert np.max(np.std(delta_error, axis=0)) < 0.003


CASES = {
    "load_cell_bias": {"load_cell_bias_rear": 1.5, "load_cell_bias_middle": -1.0, "load_cell_bias_front": 0.5},
    "load_cell_crosstalk": {"load_cell_crosstalk": 0.03},
    "imu_bias": {"imu_accel_bias_x": 0.05, "imu_accel_bias_z": -0.08, "imu_gyro_bias": 0.01},
    "slip_sinkage": {"slip_sinkage_coefficient": 1.5},
    "grousers": {"grouser_height": 0.008},
}


#: s, the plant's sinkage start-up: it starts each wheel at z* of its start solve (common steady slip), not of the
#: wheel's own first samples; with slip-sinkage c = 1.5 the front wheel sinks 0.35 mm further over 3 s (a lag from
#: a rate at the start) and comes back at the slow unloading rate by ≈ 6 s, which no replay of the bag can know
#: (measured against the plant's truth: the replay's z* of the true loads and slips repeats the plant's sinkage to
#: 0.01 mm from 6 s on). The effect cases are scored after it.
SINKAGE_START_UP = 6.0


@pytest.mark.parametrize("effect", sorted(CASES))
def test_replay_with_the_effect_closes_the_gap(effect: str) -> None:
    run = _run({effect: CASES[effect]})
    model = build_model_from_series(series_from_run(run))
    gap = _rms(model, {}, SINKAGE_START_UP)
    closed = _rms(model, {effect: CASES[effect]}, SINKAGE_START_UP)
    assert max(gap.values()) > 2.0, gap
    for name, value in closed.items():
        assert value < 1.3, (effect, name, value, gap[name])


SOIL_CHANGE = {
    "soil_change_distance": 0.42,
    "soil_change_cohesion_scale": 0.5,
    "soil_change_friction_angle_change": -0.05,
    "soil_change_modulus_scale": 0.7,
    "soil_change_shear_modulus_scale": 1.5,
}


@pytest.fixture(scope="module")
def rigid_config(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """config/rover.yaml with the wheels riding on the surface (plant.wheel_sinkage false): replay without sinkage."""
    text = (REPO / "config" / "rover.yaml").read_text()
    assert text.count("wheel_sinkage: true") == 1
    config = tmp_path_factory.mktemp("rigid") / "rover.yaml"
    config.write_text(text.replace("wheel_sinkage: true", "wheel_sinkage: false"))
    return config


@pytest.fixture(scope="module")
def soil_change_run(rigid_config: Path) -> tuple[Any, RoverReplay]:
    """A run with the soil changing at 0.42 m and its replay model (simulated once for the tests below).

    Plant and replay without the wheel sinkage: where a wheel enters the softer soil the plant sinks it 2–4 mm
    deeper within ≈ 0.3 s (a vertical transient of the body that the replay's 3 s pitch smoothing spreads over
    ±1.5 s, and inertial moments its quasi-static balance leaves out); these tests hold the soil change's own
    machinery (forces, location, inversion) to the plant without it (:func:`test_soil_change_with_sinkage`).
    """
    run = _run({"soil_change": SOIL_CHANGE}, wheel_sinkage=False)
    return run, build_model_from_series(series_from_run(run), config=rigid_config)


def test_sinkage_scale_is_a_nuisance_of_the_replay(nominal: tuple[Any, RoverReplay]) -> None:
    """The factor on the nominal soil's sinkage (uncertain soil moduli): 1 is the nominal replay; 0 (wheels on the
    surface, the replay before issue 21's plant) leaves the sinking rates in the ż0^R differences."""
    from terrain_analysis.sim2real.rover import NUISANCE
    from terrain_analysis.sim2real.rover_sinkage import START_OFFSET

    run, model = nominal
    # Not fitted unless asked for (a nominal tolerance); the sinkage's unknown start always is.
    assert [p.name for p in model.nuisance] == list(START_OFFSET)
    assert [p.name for p in RoverReplay(model.series, model.params, model.soil, nuisance=("sinkage_scale",)).nuisance][
        -1
    ] == "sinkage_scale"
    nominal_rms = _rms(model, {})
    pred = model.predict({}, {"sinkage_scale": 1.0})
    for ch in model.channels:
        assert np.array_equal(pred[ch.name], model.predict({}, {})[ch.name])
    rigid = model.predict({}, {"sinkage_scale": 0.0})
    sigma = {c.name: c.noise_std for c in model.channels}
    use = model.times["vz_middle_rear"] >= model.warmup
    r = (model.measured["vz_middle_rear"] - rigid["vz_middle_rear"])[use] / sigma["vz_middle_rear"]
    assert float(np.sqrt(np.mean(r**2))) > 2.0 * nominal_rms["vz_middle_rear"]
    assert NUISANCE["sinkage_scale"].off == 1.0
    with pytest.raises(ValueError, match="sinkage_scal"):
        RoverReplay(model.series, model.params, model.soil, nuisance=("sinkage_scal",))


def test_a_segment_starting_mid_drive_starts_in_its_rut() -> None:
    """The shipped bag's second half (a bag cut at a time gap): the replay of the whole bag has the front wheel
    0.07 mm below its z* at the cut (a rut of the heavier load before), climbing out over ≈ 4 s; started at z*,
    the replay of the half leaves 4e-6 m/s of it in vz_front_middle after the warm-up (0.5 σ, read as a soil
    change). Started in that rut (the start-offset nuisance, mm), it repeats the whole bag's replay."""
    full = build_model(REPO / "bags" / "rover_terrain_2")
    s = full.series
    cut = s.t.size // 2
    half_series = dataclasses.replace(s, **{f.name: getattr(s, f.name)[cut:] for f in dataclasses.fields(s)})
    half = build_model_from_series(half_series)
    whole = full.predict({}, {})
    depth_full = full._last_state["sinkage"][cut:]
    zero = half.predict({}, {})
    # The offset is the rut at the end of the start window, where the replay's lag starts.
    first = int(np.searchsorted(half_series.t, half_series.t[0] + START_WINDOW))
    rut = depth_full[first] - half._last_state["sinkage"][first]
    assert rut[2] == pytest.approx(6e-5, abs=2e-5)  # the front wheel (WHEELS: rear, middle, front)
    assert np.all(np.abs(rut[:2]) < 1e-5)
    offsets = {f"sinkage_start_{w}": 1e3 * max(float(d), 0.0) for w, d in zip(WHEELS, rut, strict=True)}
    started = half.predict({}, offsets)
    late = half.times["vz_front_middle"] >= half.times["vz_front_middle"][0] + half.warmup
    reference = whole["vz_front_middle"][cut:][late]
    before = float(np.mean(zero["vz_front_middle"][late] - reference))
    after = float(np.mean(started["vz_front_middle"][late] - reference))
    assert abs(before) > 3e-6
    assert abs(after) < 0.25 * abs(before)  # the rut's rate at the cut is not known: 0.1 σ of the channel left
    sink = half._last_state["sinkage"]
    assert np.max(np.abs(sink[late] - depth_full[late])) < 0.2 * np.max(np.abs(rut))


def test_soil_change_replay_closes_the_gap_except_at_the_change(soil_change_run: tuple[Any, RoverReplay]) -> None:
    values = SOIL_CHANGE
    run, model = soil_change_run
    gap = _rms(model, {})
    assert max(gap.values()) > 3.0, gap
    changed = run.time[np.argmax(run.truth.soil_index[:, 2] > 0)]
    pred = model.predict({"soil_change": values}, {})
    t = model.times["velocimeter"]
    away = (t >= t[0] + model.warmup) & (np.abs(t - changed) > 1.0)
    for ch in model.channels:
        r = (model.measured[ch.name] - pred[ch.name])[away] / ch.noise_std
        assert float(np.sqrt(np.mean(r**2))) < 1.3, ch.name
    # Around the change the quasi-static pitch rate lags the plant's transient (module docstring): still far
    # below the nominal replay's residual there.
    near = np.abs(t - changed) <= 1.0
    pred0 = model.predict({}, {})
    for name in ("vz_front_middle", "velocimeter"):
        sigma = next(c.noise_std for c in model.channels if c.name == name)
        with_effect = np.mean(((model.measured[name] - pred[name])[near] / sigma) ** 2)
        without = np.mean(((model.measured[name] - pred0[name])[near] / sigma) ** 2)
        assert with_effect < without, name


def test_soil_change_with_sinkage() -> None:
    """With the plant's sinkage the replay with the true soil change closes the gap from 2 s after the crossing.

    The crossing's sinkage transient (module docstring of the fixture above) leaves a few σ in the ż0^R
    differences for ≈ 2 s after the front wheel enters the changed soil; the replay's sinkage follows the plant's
    there (its depth within 0.2 mm of the truth after the crossing: the changed soil's depth is the nominal one
    times a 30 × 30 fit of their ratio; measured 0.16 mm).
    """
    run = _run({"soil_change": SOIL_CHANGE})
    model = build_model_from_series(series_from_run(run))
    changed = run.time[np.argmax(run.truth.soil_index[:, 2] > 0)]
    gap = _rms(model, {})
    assert max(gap.values()) > 3.0, gap
    closed = _rms(model, {"soil_change": SOIL_CHANGE}, float(changed) + 2.0)
    for name, value in closed.items():
        assert value < 1.3, (name, value, gap[name])
    after = model.times["velocimeter"] >= changed + 0.5
    depth = model._last_state["sinkage"][after]
    assert np.max(np.abs(depth - run.truth.sinkage[after])) < 2e-4


def test_soil_change_replay_is_right_at_the_crossing(soil_change_run: tuple[Any, RoverReplay]) -> None:
    """At the sample where a wheel enters the changed soil the replay with the true parameters is within a few σ.

    The plant's cells read the contact force that acts there (until session 7 they reported the normal load held
    from the previous step, computed with the old soil's forces: 2 N off here, 44 σ in moment_body). What is left
    is the straddle of the encoder differences over the switch of τ_R.
    """
    run, model = soil_change_run
    k = int(np.argmax(run.truth.soil_index[:, 2] > 0))
    assert k * model.dt > model.warmup
    pred = model.predict({"soil_change": SOIL_CHANGE}, {})
    for c in model.channels:
        if c.name in ("accel_x", "accel_z", "moment_body", "moment_bogie"):
            z = float(model.measured[c.name][k] - pred[c.name][k]) / c.noise_std
            assert abs(z) < 5.0, (c.name, z)


def test_soil_change_distance_starts_at_the_change(soil_change_run: tuple[Any, RoverReplay]) -> None:
    """The change-location scan puts the fit's start of the distance at the change (the gradient cannot walk there)."""
    _, model = soil_change_run
    distance = next(p for p in model.candidates["soil_change"].parameters if p.name == "soil_change_distance")
    assert distance.off == pytest.approx(SOIL_CHANGE["soil_change_distance"], abs=0.01)
    assert distance.bounds == (0.0, 10.0)


def test_soil_change_location_refinement_corrects_a_start_off_by_12_cm(
    soil_change_run: tuple[Any, RoverReplay],
) -> None:
    """The replay's own training cost, with the soil scales fitted at a wrong start, walks the location back.

    Withheld bag 1a648d392558 (a loose soil meeting a sharp step): the linearised scan put the change 12 cm late
    and the fit stayed there ("not explained, 6 % left"); the refinement brings it within 1 mm there.
    """
    from terrain_analysis.sim2real.attribution import AttributionSettings, held_out_mask
    from vehicle_sim.effects import CATALOGUE

    _, model = soil_change_run
    train, _ = held_out_mask(model, AttributionSettings())
    scales = [p for p in CATALOGUE["rover"]["soil_change"].parameters if p.name != "soil_change_distance"]
    truth = SOIL_CHANGE["soil_change_distance"]
    grid = np.arange(truth - 0.3, truth + 0.3, 5e-3)
    found = model._refine_location(truth + 0.12, grid, scales, train)
    assert found == pytest.approx(truth, abs=0.01)


def test_wheel_inversion_on_a_flat_torque_curve(nominal: tuple[Any, RoverReplay]) -> None:
    """A loose, high-friction changed soil: τ_R(i) rises by 3 % from i = 0.3 to 0.8 (withheld bag 1a648d392558).

    Started from the nominal soil's slip (the replay's warm start) or near the slip bounds, the safeguarded
    Newton finds the slip and load that produce the measured torque and cell forces; a plain Newton step
    overshot to the bounds there and the replay with the plant's own soil change left a gap 5000 times the
    nominal one.
    """
    from terrain_analysis.sim2real.rover_soil import _SoilVariant, _solve_wheels

    _, model = nominal
    changed = {
        "soil_change_distance": 0.0,
        "soil_change_cohesion_scale": 0.112,
        "soil_change_friction_angle_change": 0.137,
        "soil_change_modulus_scale": 0.673,
        "soil_change_shear_modulus_scale": 0.294,
    }
    soil = effects_for("rover", {"soil_change": changed}, soil=model.soil).soil_change_soil
    variants = [(_SoilVariant(soil, 0.0), 1.0)]
    slip = np.array([0.05, 0.3, 0.2, 0.3, 0.3, -0.2])
    load = np.array([36.0, 36.0, 36.0, 60.0, 20.0, 36.0])
    dp, tau = model.soil_model.forces(load, slip, variants=variants)

    def forces(rows: Any, w: np.ndarray, i: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return model.soil_model.forces(w, i, variants=variants)

    for start in (0.16, 0.9, 0.998, -0.9):
        guess = np.full(slip.size, start)
        found_slip, found_load, found_dp = _solve_wheels(
            forces, tau, load**2 + dp**2, guess, np.sqrt(load**2 + dp**2), ((2, 1), (1, 1))
        )
        np.testing.assert_allclose(found_slip, slip, atol=1e-4)
        np.testing.assert_allclose(found_load, load, atol=1e-3)
        np.testing.assert_allclose(found_dp, dp, atol=1e-3)


def test_sensor_delay_is_below_the_noise_tests_at_2_cm_s() -> None:
    """Only the effort is undelayed and it changes slowly at 2 cm/s: a 60 ms delay changes the mean r² of
    every channel by less than 0.1 (0.06 in vz_front_middle with the plant's sinkage, < 0.05 without), far
    below what the noise tests flag; only a likelihood ratio over the fitted delay finds it (next tests)."""
    run = _run({"sensor_delay": {"sensor_delay": 0.06}})
    model = build_model_from_series(series_from_run(run))
    gap = _rms(model, {})
    closed = _rms(model, {"sensor_delay": {"sensor_delay": 0.06}})
    assert max(gap.values()) < 1.3, gap
    for name in gap:
        assert abs(gap[name] ** 2 - closed[name] ** 2) < 0.1, (name, gap[name], closed[name])


def _delay_report(delay: float, duration: float, seed: int, only: tuple[str, ...] | None = None) -> Any:
    from terrain_analysis.sim2real.attribution import attribute

    effects = effects_for("rover", {"sensor_delay": {"sensor_delay": delay}} if delay > 0 else {})
    scenario = RoverScenario(terrain="rolling", duration=duration, seed=seed, effects=effects)
    model = build_model_from_series(series_from_run(simulate_rover(scenario)))
    if only is not None:
        model.candidates = {k: v for k, v in model.candidates.items() if k in only}
    return attribute(model)


def test_sensor_delay_is_attributed_by_the_held_out_likelihood_ratio() -> None:
    """The issue's case: 60 ms in a 30 s bag. The held-out χ² drops by ≈ 0.3 %, far under the 2 % the old
    rule asked for ("no significant gap" before); the held-out likelihood ratio attributes it. Two
    candidates only, to keep the test short (the whole catalogue: the slow test below)."""
    report = _delay_report(0.06, 30.0, 11, only=("sensor_delay", "imu_bias"))
    delay = next(m for m in report.ranking if m.name == "sensor_delay")
    assert 1.0 - delay.test_chi2 / report.nominal.test_chi2 < 0.02
    assert delay.significant and delay.lr > 10.8, (delay.lr, delay.p_lr)
    assert report.kind == "explained" and report.explained_by == ("sensor_delay",), report.verdict
    assert any(x["effect"] == "vertical_velocity" and "terrain" in x["needs"] for x in report.not_identifiable)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 16])
def test_sensor_delay_60_ms_in_a_30_s_bag_is_attributed(seed: int) -> None:
    """The issue's case (60 ms, 30 s) with the whole catalogue; the fit is biased low (≈ 40–45 ms)."""
    report = _delay_report(0.06, 30.0, seed)
    assert report.kind == "explained" and report.explained_by == ("sensor_delay",), report.verdict
    assert 0.025 < report.best.parameters["sensor_delay"]["sensor_delay"] < 0.08


def test_a_rover_sliding_backward_is_left_out(nominal: tuple[Any, RoverReplay]) -> None:
    """A stall and slide back (velocimeter < 0 under forward-turning wheels: slip beyond 1) is outside
    the quasi-static replay: that stretch and half the 3 s smoothing window either side leave every fit,
    score and test (the engine's masks), with a note; a run without one keeps every sample."""
    from terrain_analysis.sim2real.attribution import AttributionSettings, held_out_mask

    run, model = nominal
    assert all(np.all(v) for v in model.valid.values())
    assert not any("slid backward" in note for note in model.notes)
    series = series_from_run(run)
    t = series.t
    sliding = (t >= 6.0) & (t < 7.0)
    speed = np.where(sliding, -0.05, series.speed)
    slid = build_model_from_series(dataclasses.replace(series, speed=speed))
    valid = slid.valid["velocimeter"]
    assert not np.any(valid[(t >= 4.5 + 0.02) & (t <= 8.5 - 0.04)])
    assert np.all(valid[(t < 4.5 - 0.02) | (t > 8.5 + 0.02)])
    assert any("slid backward" in note and "6.0–7.0 s" in note for note in slid.notes)
    train, test = held_out_mask(slid, AttributionSettings())
    for ch in slid.channels:
        assert not np.any((train[ch.name] | test[ch.name]) & ~slid.valid[ch.name])


def test_predict_is_finite(nominal: tuple[Any, RoverReplay]) -> None:
    _, model = nominal
    for effects in ({}, {"soil_change": {"soil_change_distance": 0.4, "soil_change_modulus_scale": 0.7}}):
        pred = model.predict(effects, {})
        for ch in model.channels:
            assert pred[ch.name].shape == model.measured[ch.name].shape
            assert np.all(np.isfinite(pred[ch.name]))


def test_candidates_are_the_catalogue_without_the_path_undulation(nominal: tuple[Any, RoverReplay]) -> None:
    _, model = nominal
    from vehicle_sim.effects import CATALOGUE

    assert set(model.candidates) == set(CATALOGUE["rover"]) - {"vertical_velocity"}
    assert any("vertical_velocity" in note for note in model.notes)
    distance = next(p for p in model.candidates["soil_change"].parameters if p.name == "soil_change_distance")
    assert distance.bounds == (0.0, 10.0)
    assert 0.0 < distance.off < 1.0  # starts among the wheels' positions of the run


def test_bag_without_ground_truth_use(tmp_path: Path) -> None:
    """The shipped bag (its plant sinks each wheel, issue 21): every channel of the nominal replay at the noise.

    Without the sinkage in the replay vz_front_middle read 1.65 σ here (the sinking rates of wheels whose
    loads change); with it every channel is below 1.3 σ.
    """
    model = build_model(REPO / "bags" / "rover_terrain_1")
    rms = _rms(model, {})
    for name, value in rms.items():
        assert value < 1.3, (name, value)


def test_single_axis_config_is_refused(tmp_path: Path, nominal: tuple[Any, RoverReplay]) -> None:
    run, _ = nominal
    text = (REPO / "config" / "rover.yaml").read_text().replace("load_cell_axes: 2", "load_cell_axes: 1")
    config = tmp_path / "rover.yaml"
    config.write_text(text)
    with pytest.raises(Sim2RealError, match="load_cell_axes"):
        build_model_from_series(series_from_run(run), config=config)


def test_missing_topic_is_named(tmp_path: Path) -> None:
    with pytest.raises(Sim2RealError, match="/elsewhere/imu"):
        build_model(REPO / "bags" / "rover_terrain_1", namespace="/elsewhere")


def _write_small_bag(path: Path, nan_at: int | None) -> None:
    """20 samples of every rover topic (level rover at rest), one accelerometer x NaN at ``nan_at``."""
    from geometry_msgs.msg import TwistStamped, WrenchStamped
    from sensor_msgs.msg import Imu, JointState

    from terrain_estimation.bag import AtomicBagWriter
    from terrain_estimation.ros.time import ns_to_stamp

    with AtomicBagWriter(path) as writer:
        for k in range(20):
            stamp_ns = 1_700_000_000_000_000_000 + k * 20_000_000
            imu = Imu()
            imu.linear_acceleration.x = math.nan if k == nan_at else 0.0
            imu.linear_acceleration.z = 9.81
            joints = JointState(
                name=["bogie", "rear_wheel", "middle_wheel", "front_wheel"],
                position=[0.0, 0.0, 0.0, 0.0],
                velocity=[0.0] * 4,
                effort=[0.0, 1.0, 1.0, 1.0],
            )
            twist = TwistStamped()
            messages: list[tuple[str, Any]] = [
                ("/rover/imu", imu),
                ("/rover/joint_states", joints),
                ("/rover/velocimeter", twist),
            ]
            for wheel in ("rear", "middle", "front"):
                cell = WrenchStamped()
                cell.wrench.force.z = 49.0
                messages.append((f"/rover/wheel/{wheel}/load", cell))
            for topic, msg in messages:
                msg.header.stamp = ns_to_stamp(stamp_ns)
                writer.write(topic, msg, stamp_ns)


def test_non_finite_value_names_topic_field_and_value(tmp_path: Path) -> None:
    from terrain_analysis.sim2real.rover import read_rover_bag

    _write_small_bag(tmp_path / "bad", nan_at=5)
    with pytest.raises(Sim2RealError, match=r"/rover/imu: field linear_acceleration.x is nan at message 5"):
        read_rover_bag(tmp_path / "bad")
    _write_small_bag(tmp_path / "good", nan_at=None)
    series = read_rover_bag(tmp_path / "good")
    assert series.t.size == 20 and series.t[0] == 0.0
    assert np.allclose(series.load_axial, 49.0) and np.allclose(series.effort, 1.0)
    with pytest.raises(Sim2RealError, match="50"):  # too short for the replay
        build_model(tmp_path / "good")
