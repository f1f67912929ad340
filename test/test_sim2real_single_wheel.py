"""Sim-to-real diagnosis on the CMU single-wheel rig (issue 6): the replay model's physics and the real data."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from scipy import integrate

from terrain_analysis.sim2real.attribution import AttributionSettings, attribute
from terrain_analysis.sim2real.model import ReplayModel
from terrain_analysis.sim2real.single_wheel import (
    NOMINAL,
    RigTrials,
    SingleWheelModel,
    WheelGeometry,
    WheelSoil,
    analyses,
    baseline_comparison,
    bulldozing_resistance,
    candidates,
    load_rig_trials,
    main,
    run,
    slip_binned_baseline,
    steady_state,
    strongest_stress_field,
    synthetic_trials,
    tip_slip,
)
from terrain_analysis.sim2real.single_wheel_model import _apply
from terrain_analysis.sim2real.single_wheel_physics import _rim_row, _simpson_weights, _soil_vector
from terrain_analysis.sim2real.where import Sim2RealError
from vehicle_sim.effects import effects_for
from vehicle_sim.terrain.wong_reece import RigidWheel, WongReeceSoil, wheel_forces

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "real_data" / "cmu_single_wheel"
needs_data = pytest.mark.skipif(
    not (DATA / "all_smooth_data.mat").is_file(),
    reason=f"CMU single-wheel data not found at {DATA} (the team's shared real_data folder)",
)

# The rig's design: 9 commanded slips, three repetitions each.
SLIPS = np.repeat([-1.0, -0.7, -0.5, -0.2, 0.0, 0.231, 0.5, 0.75, 0.9], 3)
NOISE = {"drawbar_pull": (0.34, 18), "sinkage": (0.66, 18)}


def _project_soil(p: WheelSoil = NOMINAL) -> tuple[WongReeceSoil, RigidWheel]:
    soil = WongReeceSoil.from_bekker(
        cohesive_modulus=p.k_c,
        frictional_modulus=p.k_phi,
        wheel_width=p.width,
        sinkage_exponent=p.n,
        cohesion=p.cohesion,
        friction_angle=p.friction_angle,
        shear_deformation_modulus=p.shear_modulus,
        max_stress_angle_c1=p.c1,
        max_stress_angle_c2=p.c2,
    )
    return soil, RigidWheel(radius=p.radius, width=p.width)


def _design(seed: int = 0) -> RigTrials:
    rng = np.random.default_rng(seed)
    zeros = np.zeros(SLIPS.size)
    return RigTrials(
        slip=SLIPS.copy(),
        load=rng.uniform(18.0, 26.0, SLIPS.size),
        drawbar_pull=zeros,
        drawbar_pull_ripple=zeros,
        sinkage=zeros,
        sinkage_ripple=zeros,
        trial=np.arange(SLIPS.size, dtype=float),
        group=np.repeat(np.arange(9), 3),
        total_trials=SLIPS.size,
        betas=(0.0,),
        source="design",
    )


# ---------------------------------------------------------------------------
# Physics (no data needed)
# ---------------------------------------------------------------------------


def test_nominal_is_the_project_wong_reece_wheel() -> None:
    soil, wheel = _project_soil()
    load, slip = np.meshgrid(np.linspace(2.0, 45.0, 12), np.linspace(-1.0, 1.0, 21))
    ref = wheel_forces(load, slip, soil, wheel, overload="saturate")
    dp, z = steady_state(load, slip)
    np.testing.assert_allclose(dp, ref.drawbar_pull, rtol=0, atol=1e-10)
    np.testing.assert_allclose(z, NOMINAL.radius * (1.0 - np.cos(ref.contact_angle)), rtol=0, atol=1e-12)
    # The rig's authors' soil carries ≈ 20 N at ≈ 17 mm: the scale of the measured sinkage (14 mm).
    assert 0.012 < float(steady_state(20.0, 0.0)[1]) < 0.020


@pytest.mark.parametrize(
    "effect",
    [
        {"slip_sinkage": {"slip_sinkage_coefficient": 1.3}},
        {
            "soil_change": {
                "soil_change_distance": 0.0,
                "soil_change_cohesion_scale": 2.0,
                "soil_change_friction_angle_change": -0.1,
                "soil_change_modulus_scale": 0.7,
                "soil_change_shear_modulus_scale": 1.7,
            }
        },
    ],
)
def test_catalogue_effects_are_the_rover_plants(effect: dict[str, dict[str, float]]) -> None:
    """slip_sinkage and soil_change reproduce the rover plant's terramechanics (full Wong–Reece) exactly."""
    from terrain_estimation.models.rover import RoverParams
    from vehicle_sim.plants.rover import RoverScenario
    from vehicle_sim.plants.rover_terramechanics import _Terramechanics

    soil, _ = _project_soil()
    scenario = RoverScenario(
        terramechanics="wong_reece",
        params=RoverParams(wheel_radius=NOMINAL.radius, wheel_width=NOMINAL.width),
        soil=soil,
        effects=effects_for("rover", effect, soil=soil),
    )
    load = np.linspace(4.0, 40.0, 25)
    slip = np.linspace(-1.0, 1.0, 25)
    changed = 1 if "soil_change" in effect else 0
    dp_ref, _, entry = _Terramechanics(scenario)(load, slip, np.full(load.shape, changed))
    if changed:
        values = {k: v for k, v in effect["soil_change"].items() if k != "soil_change_distance"}
        ours = {
            name: {k: values[k] for k in (p.name for p in cand.parameters)}
            for name, cand in candidates().items()
            if name.startswith("soil_change_")
        }
    else:
        ours = effect
    p, sensor = _apply(NOMINAL, ours)
    assert sensor == {"bias": 0.0, "crosstalk": 0.0, "offset": 0.0}
    dp, z = steady_state(load, slip, p)
    np.testing.assert_allclose(dp, dp_ref, rtol=0, atol=1e-10)
    np.testing.assert_allclose(z, NOMINAL.radius * (1.0 - np.cos(entry)), rtol=0, atol=1e-12)


def _quadrature(theta0: float, slip: float, p: WheelSoil) -> tuple[float, float]:
    """W and DP of eqs. 7–8 by adaptive quadrature, from the stress laws written out independently."""
    r, b = p.radius, p.width
    tm = theta0 * (p.c1 + p.c2 * max(slip, 0.0))
    tr = -p.rear_ratio * theta0

    def sigma(theta: float) -> float:
        eq = theta if theta >= tm else theta0 - (theta - tr) / (tm - tr) * (theta0 - tm)
        return (p.k_c / b + p.k_phi) * max(r * (math.cos(eq) - math.cos(theta0)), 0.0) ** p.n

    def tau(theta: float) -> float:
        j = r * ((theta0 - theta) - (1.0 - slip) * (math.sin(theta0) - math.sin(theta)))
        strength = p.cohesion + sigma(theta) * math.tan(p.friction_angle)
        return math.copysign(strength * (1.0 - math.exp(-abs(j) / p.shear_modulus)), j)

    def integral(f: object) -> float:
        return sum(integrate.quad(f, lo, hi, epsabs=1e-13, epsrel=1e-11, limit=200)[0]  # type: ignore[arg-type]
                   for lo, hi in ((tr, tm), (tm, theta0)))  # fmt: skip

    load = b * r * integral(lambda t: sigma(t) * math.cos(t) + tau(t) * math.sin(t))
    dp = b * r * integral(lambda t: tau(t) * math.cos(t) - sigma(t) * math.sin(t))
    return load, dp


@pytest.mark.parametrize(("rear", "slip"), [(0.0, 0.4), (0.35, 0.0), (0.35, 0.8), (0.2, -1.0), (0.0, -0.5)])
def test_rim_integrals_with_rear_contact_and_skid_against_quadrature(rear: float, slip: float) -> None:
    p = WheelSoil(rear_ratio=rear, skid_stresses=True)
    theta0 = 0.6
    load, dp, _ = _rim_row(theta0, slip, p.n, _soil_vector(p), _simpson_weights(2049))
    ref_load, ref_dp = _quadrature(theta0, slip, p)
    assert load == pytest.approx(ref_load, rel=1e-6)
    assert dp == pytest.approx(ref_dp, rel=1e-6, abs=1e-6)


def test_rear_contact_and_skid_stresses_physics() -> None:
    load = np.full(3, 22.0)
    slip = np.array([-1.0, 0.0, 0.6])
    dp0, z0 = steady_state(load, slip)
    dp_r, z_r = steady_state(load, slip, WheelSoil(rear_ratio=0.3))
    # Soil under the rear of the wheel carries part of the load: shallower, less compaction resistance.
    assert np.all(z_r < z0 - 1e-3)
    assert np.all(dp_r[1:] > dp0[1:] + 0.5)
    dp_s, z_s = steady_state(load, slip, WheelSoil(skid_stresses=True))
    np.testing.assert_array_equal(dp_s[1:], dp0[1:])  # drive untouched
    # A locked wheel: the reversed shear resists the whole sliding motion, and pushes the wheel down.
    assert dp_s[0] < dp0[0] - 3.0
    assert z_s[0] > z_s[1]


def test_strongest_stress_field_carries_the_load_it_is_given() -> None:
    best = strongest_stress_field(-1.0, 40.0, 20.0, points=3)
    assert -3.0 < best["dp_over_w"] < -0.3
    q = best["parameters"]
    p = WheelSoil(
        friction_angle=math.radians(q["friction_angle_deg"]),
        cohesion=q["cohesion"],
        shear_modulus=q["shear_modulus"],
        n=q["sinkage_exponent"],
        c1=q["max_stress_angle_c1"],
        rear_ratio=q["rear_angle_ratio"],
        k_phi=NOMINAL.k_phi * q["modulus_scale"],
        skid_stresses=True,
    )
    theta0 = math.acos(1.0 - 0.040 / p.radius)
    load, dp, _ = _rim_row(theta0, -1.0, p.n, _soil_vector(p), _simpson_weights(9))
    assert load == pytest.approx(20.0, rel=1e-9)
    assert dp / load == pytest.approx(best["dp_over_w"], rel=1e-9)
    # The 5-point grid contains the 3-point one: its bound can only be stronger.
    assert strongest_stress_field(-1.0, 40.0, 20.0, points=5)["dp_over_w"] <= best["dp_over_w"]


def test_crosstalk_uses_the_true_load() -> None:
    trials = _design()
    c = 0.08
    true_load = trials.load
    dp, z = steady_state(true_load, trials.slip)
    measured = RigTrials(**{**trials.__dict__, "load": true_load + c * dp})
    pred = SingleWheelModel(measured, noise=NOISE).predict({"load_cell_crosstalk": {"load_cell_crosstalk": c}}, {})
    np.testing.assert_allclose(pred["drawbar_pull"], dp + c * true_load, atol=1e-6)
    np.testing.assert_allclose(pred["sinkage"], 1000.0 * z, atol=1e-6)


def test_model_is_a_replay_model_and_finite_at_every_bound() -> None:
    model = SingleWheelModel(_design(), noise=NOISE)
    assert isinstance(model, ReplayModel)
    assert [ch.name for ch in model.channels] == ["drawbar_pull", "sinkage"]
    for name, cand in model.candidates.items():
        corners = [{}] if not cand.parameters else [
            {p.name: p.bounds[k] for p in cand.parameters} for k in (0, 1)
        ]  # fmt: skip
        for values in corners:
            pred = model.predict({name: values}, {})
            for ch in model.channels:
                assert pred[ch.name].shape == (SLIPS.size,)
                assert np.all(np.isfinite(pred[ch.name])), (name, values)
    with pytest.raises(ValueError, match="'grousers' does not apply: the wheel is smooth"):
        model.predict({"grousers": {"grouser_effective_height": 0.005}}, {})
    with pytest.raises(ValueError, match="unknown single-wheel effect"):
        model.predict({"tire_relaxation": {}}, {})


@pytest.mark.parametrize(
    "truth",
    [
        {},
        {"slip_sinkage": {"slip_sinkage_coefficient": 0.8}},
        {"rear_contact": {"rear_angle_ratio": 0.25}},
        {"skid_stresses": {}},
    ],
)
def test_engine_attributes_a_simulated_effect(truth: dict[str, dict[str, float]]) -> None:
    """Simulated trials on the rig's design, one effect: the engine names it (or no gap for the control)."""
    design = _design(1)
    model = SingleWheelModel(synthetic_trials(design, truth, {k: v[0] for k, v in NOISE.items()}, seed=5), noise=NOISE)
    split = analyses(model.trials)[0]
    report = attribute(model, AttributionSettings(), test_mask={c.name: split.held_out for c in model.channels})
    if not truth:
        assert report.kind == "no_gap", report.verdict
        return
    (name,) = truth
    assert report.kind == "explained", report.verdict
    assert report.best is not None and report.best.effects == (name,)
    assert report.shrinkage > 0.9
    for p, v in truth[name].items():
        assert report.best.parameters[name][p] == pytest.approx(v, abs=3 * report.best.std[name][p] + 1e-3)


# ---------------------------------------------------------------------------
# Loader
# ---------------------------------------------------------------------------


def _trial(slip: float, beta: float, **overrides: float) -> dict[str, float]:
    row = {"slip": slip, "beta": beta, "avg_Fy": 1.0, "std_Fy": 1.0, "avg_Fz": -20.0, "avg_Z": -15.0, "std_Z": 0.0}
    row.update(overrides)
    return row


def _write_mat(folder: Path, rows: list[dict[str, float]]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    records = np.empty(len(rows), dtype=object)
    for k, row in enumerate(rows):
        records[k] = row
    scipy.io.savemat(folder / "all_smooth_data.mat", {"all_results": records})
    return folder


def test_loader_keeps_beta_zero_and_groups_repeats(tmp_path: Path) -> None:
    design = [(0.5, 0), (0.501, 0), (-0.2, 0), (-0.2, 0), (0.0, 0), (0.0, 0), (0.3, 15), (0.9, 0)]
    rows = [_trial(s, b, avg_Z=-10.0 - k) for k, (s, b) in enumerate(design)]
    trials = load_rig_trials(_write_mat(tmp_path / "ok", rows))
    assert trials.size == 7 and trials.total_trials == 8 and trials.betas == (0.0, 15.0)
    np.testing.assert_allclose(trials.slip, [-0.2, -0.2, 0.0, 0.0, 0.5, 0.501, 0.9])
    np.testing.assert_array_equal(trials.group, [0, 0, 1, 1, 2, 2, 3])
    assert np.all(trials.load == 20.0) and np.all(trials.drawbar_pull == -1.0)
    np.testing.assert_allclose(trials.sinkage, [12.0, 13.0, 14.0, 15.0, 10.0, 11.0, 17.0])


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ([_trial(0.0, 0, avg_Fz=float("nan"))] * 6, "field 'avg_Fz' = nan is not finite"),
        ([_trial(0.0, 0, avg_Fz=5.0)] * 6, "field 'avg_Fz' = 5.0 N: the load must be < 0"),
        ([_trial(1.5, 0)] * 6, "field 'slip' = 1.5 outside"),
        ([_trial(0.0, 30)] * 6, "only 0 trials at beta = 0"),
        ([{"slip": 0.0, "beta": 0.0}] * 6, "trial 0 has no field 'avg_Fy'"),
    ],
)
def test_loader_refuses_bad_data(tmp_path: Path, rows: list[dict[str, float]], message: str) -> None:
    with pytest.raises(Sim2RealError, match=message.replace("(", r"\(")):
        load_rig_trials(_write_mat(tmp_path / "bad", rows))


def test_loader_missing_file(tmp_path: Path) -> None:
    with pytest.raises(Sim2RealError, match="no such file"):
        load_rig_trials(tmp_path)


# ---------------------------------------------------------------------------
# The real rig
# ---------------------------------------------------------------------------


@needs_data
def test_rig_data_and_its_noise_budget() -> None:
    trials = load_rig_trials(DATA)
    assert trials.size == 27 and trials.total_trials == 189
    assert np.unique(trials.group).size == 9
    model = SingleWheelModel(trials)
    sigma = {ch.name: ch.noise_std for ch in model.channels}
    assert 0.1 < sigma["drawbar_pull"] < 1.0 and 0.2 < sigma["sinkage"] < 2.0
    # The gap is real and largest in braking: a locked wheel resists with ≈ 2 W, the model with < 0.5 W.
    locked = trials.slip < -0.99
    nominal = model.predict({}, {})
    assert np.all(trials.drawbar_pull[locked] < -1.5 * trials.load[locked])
    assert np.all(nominal["drawbar_pull"][locked] > -0.5 * trials.load[locked])
    assert np.all(trials.sinkage[locked] > 40.0) and np.all(nominal["sinkage"][locked] < 25.0)


@needs_data
def test_driver_writes_the_report(tmp_path: Path) -> None:
    summary = run(DATA, tmp_path, only=["drive_only"])
    assert set(summary["analyses"]) == {"drive_only"}
    result = summary["analyses"]["drive_only"]
    assert result["kind"] in ("explained", "not_explained", "structure_differs")
    assert result["best"]["shrinkage"]["overall"] > 0.3
    data = json.loads((tmp_path / "single_wheel.json").read_text())
    assert data["data"]["trials_used"] == 27
    assert {r["regime"] for r in data["regimes"]} == {"braking", "low slip", "high slip"}
    text = (tmp_path / "single_wheel.md").read_text()
    assert "Where: residual rig − model per slip regime" in text and "drive_only" in text
    # Issue 22: the verdict against the slip-binned mean on the same held-out trials.
    baseline = result["baseline"]["models"]["slip-binned mean"]
    assert baseline["parameters"] > 0 and baseline["chi2"] > 0
    assert "Against the simplest empirical model: a slip-binned mean" in text
    assert (tmp_path / "single_wheel_fit.png").stat().st_size > 10_000


# ---------------------------------------------------------------------------
# Issue 22: wheel geometry, grousers, bulldozing, the empirical baseline
# ---------------------------------------------------------------------------

GROUSERED = WheelGeometry(radius=0.058, width=0.05, grouser_count=12, grouser_height=0.006)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"grouser_count": 12}, "grousers need both a count and a height"),
        ({"grouser_height": 0.005}, "grousers need both a count and a height"),
        ({"grouser_count": 12, "grouser_height": -0.001}, "grouser height must be a finite length >= 0 m"),
        ({"grouser_count": 12, "grouser_height": 0.03}, "below half the wheel radius"),
        ({"grouser_count": 2.5, "grouser_height": 0.005}, "grouser count must be a whole number"),
        ({"radius": 0.0}, "wheel radius must be in"),
        ({"width": float("nan")}, "wheel width must be in"),
    ],
)
def test_wheel_geometry_is_validated(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(Sim2RealError, match=message):
        WheelGeometry(**kwargs)  # type: ignore[arg-type]


def test_grousers_apply_to_a_grousered_wheel_only() -> None:
    assert "grousers" not in SingleWheelModel(_design(), noise=NOISE).candidates
    model = SingleWheelModel(_design(), noise=NOISE, geometry=GROUSERED)
    (height,) = model.candidates["grousers"].parameters
    assert height.bounds == (0.0, GROUSERED.grouser_height)
    # Tip slip: the rover plant's i_g = 1 − (1 − i) r/(r + h) in drive; a locked rim is a locked tip.
    i = np.array([0.0, 0.5, 0.9])
    np.testing.assert_allclose(tip_slip(i, 0.058, 0.006), 1.0 - (1.0 - i) * 0.058 / 0.064)
    assert tip_slip(np.array([-1.0]), 0.058, 0.006)[0] == -1.0
    nominal = model.predict({}, {})
    full = model.predict({"grousers": {"grouser_effective_height": 0.006}}, {})
    drive = SLIPS >= 0.0
    assert np.all(full["drawbar_pull"][drive] > nominal["drawbar_pull"][drive])  # more thrust from the lugs


def test_geometry_option_of_the_driver_is_checked(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code = main(["--data", str(tmp_path), "--out", str(tmp_path / "o"), "--grousers", "12", "--quiet"])
    assert code == 2
    assert "grousers need both a count and a height" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("geometry", "truth"),
    [
        (GROUSERED, {"grousers": {"grouser_effective_height": 0.004}}),
        (WheelGeometry(), {"bulldozing": {"bulldozing_coefficient": 0.6}}),
    ],
    ids=["grousers", "bulldozing"],
)
def test_new_rig_effects_are_fitted_back(geometry: WheelGeometry, truth: dict[str, dict[str, float]]) -> None:
    design = _design(2)
    sd = {k: v[0] for k, v in NOISE.items()}
    model = SingleWheelModel(
        synthetic_trials(design, truth, sd, seed=7, geometry=geometry), noise=NOISE, geometry=geometry
    )
    split = analyses(model.trials)[0]
    report = attribute(model, AttributionSettings(), test_mask={c.name: split.held_out for c in model.channels})
    (name,) = truth
    assert report.best is not None and report.best.effects[0] == name, report.verdict
    for p, v in truth[name].items():
        # Within 3 standard errors (the rig's 27 trials: s.e. ≈ 15 % of the grouser height).
        assert report.best.parameters[name][p] == pytest.approx(v, abs=3 * report.best.std[name][p] + 1e-4 * v)


def test_bulldozing_resists_only_a_skidding_wheel() -> None:
    z = np.full(5, 0.02)
    theta = np.full(5, 0.8)
    r = bulldozing_resistance(z, np.array([-1.0, -0.5, -0.1, 0.0, 0.5]), theta, NOMINAL)
    assert r[3] == 0.0 and r[4] == 0.0
    assert r[0] > r[1] > r[2] > 0.0
    # Wong's fully mobilised wedge at 20 mm (φ = 29°, c = 1 kPa, γ = 13 kN/m³, b = 50 mm): ≈ 21 N.
    full = bulldozing_resistance(np.array([0.02]), np.array([-1.0]), np.array([50.0]), NOMINAL)[0]
    assert 15.0 < full < 30.0


def test_slip_binned_baseline_fills_empty_bins_from_its_neighbours() -> None:
    slip = np.array([-1.0, -0.7, -0.5, 0.0, 0.1, 0.9])
    values = np.array([10.0, 99.0, 20.0, 1.0, 3.0, 7.0])
    train = np.array([True, False, True, True, True, True])
    pred, bins = slip_binned_baseline(slip, values, train, width=0.25)
    assert bins == 4  # [-1, -0.75), [-0.5, -0.25), [0, 0.25), [0.75, 1]
    np.testing.assert_allclose(pred, [10.0, 15.0, 20.0, 2.0, 2.0, 7.0])  # -0.7: between -1 and -0.5


def test_every_verdict_is_compared_with_the_baseline_on_held_out_trials() -> None:
    # A smooth trend in slip the slip-binned mean cannot follow between training slips, and a physical
    # model that has it (the truth): the physics beats the baseline; the nominal model does not.
    design = _design(3)
    truth = {"slip_sinkage": {"slip_sinkage_coefficient": 0.8}}
    model = SingleWheelModel(synthetic_trials(design, truth, {k: v[0] for k, v in NOISE.items()}, 4), noise=NOISE)
    split = analyses(model.trials)[0]
    report = attribute(model, AttributionSettings(), test_mask={c.name: split.held_out for c in model.channels})
    out = baseline_comparison(model, split.held_out, report)
    assert set(out["models"]) == {"nominal", report.best.name, "slip-binned mean"}  # type: ignore[union-attr]
    assert out["models"]["slip-binned mean"]["parameters"] > 0
    assert out["physics_beats_baseline"]
    assert out["models"]["nominal"]["chi2"] > out["models"][out["physics"]]["chi2"]


def test_any_trial_file_of_the_rig_layout_is_read(tmp_path: Path) -> None:
    rows = [_trial(s, 0.0) for s in (-1.0, -1.0, 0.0, 0.0, 0.5, 0.5)]
    folder = _write_mat(tmp_path / "grouser", rows)
    (folder / "all_smooth_data.mat").rename(folder / "all_grouser_data.mat")
    by_name = load_rig_trials(folder, "all_grouser_data.mat")
    by_path = load_rig_trials(folder / "all_grouser_data.mat")
    assert by_name.size == by_path.size == 6 and by_path.source.endswith("all_grouser_data.mat")
    with pytest.raises(Sim2RealError, match="no such file"):
        load_rig_trials(folder)  # the default file name is not there
