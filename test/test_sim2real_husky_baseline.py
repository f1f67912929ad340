"""Husky real-data section (issue 22, items 6 and 8): the effective-track baseline and the parameter flags.

Synthetic runs with the Husky's geometry: a gyro that turns at a known fraction χ of the encoder
yaw rate, so the baseline's fitted χ and its residual are known; flags on values the issue names
(μ = 2.4 on ice, μ = 0.18 on flooring, a scale at its fit bound).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain_analysis.sim2real.husky import (
    CHANNELS,
    NUISANCE_NAMES,
    PhysicsFit,
    baseline_comparison,
    encoder_yaw_rate,
    fit_effective_track,
    flag_fit,
    flag_value,
    husky_vehicle,
    interpretation,
    physical_ranges,
    score_run,
)
from terrain_analysis.sim2real.model import candidates_from_catalogue
from terrain_analysis.sim2real.skid_steer import SkidSteerReplay, bag_data_from_arrays

VEHICLE = husky_vehicle(accel_noise_std=0.3, gyro_noise_std=0.005)


def _run(chi: float, seed: int, seconds: float = 20.0) -> SkidSteerReplay:
    """A turning run: side speeds at 6.5 Hz, a gyro at χ × the encoder yaw rate plus white noise."""
    rng = np.random.default_rng(seed)
    joint_t = np.arange(0.0, seconds, 1.0 / 6.5)
    mean = 0.4 + 0.1 * np.sin(0.3 * joint_t)
    diff = 0.3 * np.sin(0.5 * joint_t + seed)
    speeds = np.column_stack([mean - 0.5 * diff, mean + 0.5 * diff])  # m/s (left, right)
    motor = speeds / VEHICLE.wheel_radius * VEHICLE.transmission_ratio
    t = np.arange(0.0, joint_t[-1], 0.01)
    encoder = np.interp(t, joint_t, diff) / VEHICLE.track
    accel = np.zeros((t.size, 3))
    accel[:, 2] = VEHICLE.gravity
    accel[:, 1] = np.interp(t, joint_t, mean) * chi * encoder + 0.3 * rng.standard_normal(t.size)
    gyro = chi * encoder + 0.005 * rng.standard_normal(t.size)
    data = bag_data_from_arrays(
        t,
        accel,
        gyro,
        joint_t,
        motor,
        transmission_ratio=VEHICLE.transmission_ratio,
        wheel_speed_timing="instantaneous",
    )
    return SkidSteerReplay(
        data,
        VEHICLE,
        nuisance=NUISANCE_NAMES,
        channels=CHANNELS,
        candidates=candidates_from_catalogue("skid_steer", only=("turning_resistance", "gyro_bias")),
        noise_repeats=0,
    )


def test_effective_track_baseline_is_fitted_and_scored():
    train = [_run(0.55, seed) for seed in (0, 2)]
    chi = fit_effective_track(train)
    assert chi == pytest.approx(0.55, abs=0.005)
    held = _run(0.55, 1)
    nominal = {p.name: p.off for p in held.nuisance}
    score = score_run(held, "T/run_01", "T", {"physics (T)": (nominal, {})}, {"effective track (T)": chi})
    track = score.rms["effective track (T)"]["yaw_rate"]
    assert track == pytest.approx(0.005, rel=0.15)  # the gyro noise: χ explains everything else
    assert score.rms["zero yaw rate"]["yaw_rate"] > 10.0 * track
    assert score.gyro_over_encoder == pytest.approx(0.55, abs=0.01)
    np.testing.assert_allclose(encoder_yaw_rate(held)[held.data.t > 1.0].std(), 0.3 / math.sqrt(2) / 0.555, rtol=0.2)


def test_the_comparison_says_when_the_physics_beats_the_baseline_and_when_not():
    def row(run: str, physics: float, track: float, zero: float) -> dict:
        rms = {
            "zero yaw rate": zero,
            "kinematic (χ = 1)": 0.2,
            "effective track (T)": track,
            "nominal (config)": physics * 1.5,
            "physics (T)": physics,
            "physics + turning resistance (T)": physics,
        }
        return {"run": run, "terrain": "T", "rate_floor": 0.01, "rms": {m: {"yaw_rate": v} for m, v in rms.items()}}

    result = {
        "runs": [
            row("T/run_01", 0.050, 0.051, 0.3),
            row("T/run_03", 0.030, 0.060, 0.3),
            row("T/run_05", 0.1, 0.03, 0.02),
        ],
        "fits": {
            "T": {"physics + turning resistance": {"effects": {"turning_resistance": {"turning_resistance": 0.3}}}}
        },
        "effective_track": {"T": 0.5},
        "config": {"vehicle.track": 0.555},
        "flags": [],
        "attribution": {},
    }
    rows = {r["run"]: r for r in baseline_comparison(result, ["T"])["T"]}
    assert [rows[r]["physics_vs_track"] for r in ("T/run_01", "T/run_03", "T/run_05")] == ["equal", "beats", "worse"]
    assert rows["T/run_05"]["zero_vs_physics"] == "beats"  # the deep-snow case: zero yaw rate beats the model
    text = "\n".join(interpretation(result, ["T"]))
    assert "beats the one-parameter baseline (RMS below 0.95×) on 1 of 3 runs, equals it on 1, is worse on 1" in text
    assert "Predicting zero yaw rate beats the fitted physics on T/run_05" in text


@pytest.mark.parametrize(
    ("terrain", "mu", "flagged"),
    [("ICE", 2.4, True), ("FLOORING", 0.18, True), ("ASPHALT", 0.8, False), ("ICE", 0.12, False)],
)
def test_friction_outside_the_terrain_range_is_flagged(terrain, mu, flagged):
    ranges = physical_ranges(VEHICLE, terrain)
    scale = mu / VEHICLE.friction
    flags = flag_value("fit", "friction_scale", scale, (0.05, 10.0), physical=ranges["friction_scale"])
    assert bool(flags) == flagged, flags
    if flagged:
        assert "outside the physical range" in flags[0]["reason"] and flags[0]["value"] == pytest.approx(mu)


def test_values_at_a_fit_bound_are_flagged_but_an_effect_at_its_off_value_is_not():
    model = _run(0.55, 0)
    fit = PhysicsFit(
        values={"longitudinal_stiffness_scale": 1.0, "cornering_stiffness_scale": 0.05, "friction_scale": 1.0},
        effects={"turning_resistance": {"turning_resistance": 0.0}},
        std={},
        std_corrected={},
        reduced_chi2=1.0,
        tau=1.0,
        runs=1,
    )
    flags = flag_fit("physics fitted on ASPHALT", fit, model, "ASPHALT")
    reasons = {(f["parameter"], f["reason"].split(" ")[0]) for f in flags}
    # C_α scale 0.05: at its fit bound, and C_α/F_z = 0.05 × 1000 / 122.6 = 0.41 /rad below 1: not physical.
    assert reasons == {("cornering_stiffness_scale", "at"), ("cornering_stiffness_scale", "outside")}, flags
    # The lateral soil resistance beyond its plausible 0–1 (at 1.2) and at its fit bound (1.5): flagged; at 0 (its
    # off value, the fit's lower bound) it is only absent.
    for c_b, expected in ((1.2, {"outside"}), (1.5, {"at", "outside"})):
        changed = PhysicsFit(**{**vars(fit), "effects": {"turning_resistance": {"turning_resistance": c_b}}})
        got = {
            f["reason"].split(" ")[0]
            for f in flag_fit("x", changed, model, "ASPHALT")
            if f["parameter"] == "turning_resistance.turning_resistance"
        }
        assert got == expected, (c_b, got)
    # Its build-up speed at either end of its range is a law of the family (a Coulomb step, a lateral damping):
    # no flag, where the resistance's size at its fit bound still is one.
    both = {"turning_resistance": {"turning_resistance": 1.5, "turning_resistance_speed": 0.5}}
    flagged = {f["parameter"] for f in flag_fit("x", PhysicsFit(**{**vars(fit), "effects": both}), model, "ASPHALT")}
    assert "turning_resistance.turning_resistance" in flagged
    assert "turning_resistance.turning_resistance_speed" not in flagged
