"""Reproduce the skid-steer motion-state results of the AN-STUKF paper (MODELS.md Part B, D.2).

``python -m terrain_analysis.tools.reproduce_skid [--runs N] [--out docs/results] [--jobs 2] [--quick]``

Every number the report shows is computed here, when the command runs, by the
project's own truth plant (:func:`vehicle_sim.plants.skid_steer.simulate_skid_steer`,
the paper's three manoeuvres of :data:`~vehicle_sim.plants.skid_steer.MANOEUVRES`
with roll/pitch load-transfer dynamics and tire relaxation on) and its own
estimator (:class:`~terrain_estimation.estimators.skid_steer.SkidSteerEstimator`
with ``filter="ukf"``, ``"stukf"`` and ``"an_stukf"``, fed the same sensor
data). The paper's numbers appear only as the comparison column (DESIGN.md);
the truth plant, its noise and the seeds are never tuned towards the paper.

Cases (as in the report):

1. Table 2: small-radius turn (≈ 5 km/h, 0.2 rad/s, counter-clockwise), errors
   of the body sideslip angle β over 20–40 s.
2. Table 3: S-shaped path at 30 km/h, errors of β over 20–25 s.
3. Straight acceleration 0 → 30 km/h: tracking lag and error of v̂x.
4. ICR in the small-radius turn (truth and filters, front axle beside), and
   its forward shift on the S-shape (4–10 s).
5. The paper's other observations in the turn (per-side slip, encoder yaw
   rate, tire sideslip angles).
6. Sensitivity (not in the paper): the turn with a truth whose tires differ
   from the observer's (C_α and μ changed).

The experiment is a plan of seeded runs (:mod:`~terrain_analysis.tools.skid_runs`)
run on the shared runner (:mod:`terrain_analysis.experiment`) and reduced in
the workers to their figures (:mod:`~terrain_analysis.tools.skid_metrics`);
the sections (:mod:`~terrain_analysis.tools.skid_tables`,
:mod:`~terrain_analysis.tools.skid_turn`) write the page through
:func:`terrain_analysis.reporting.write_page`; this module has the command and
the page's own text.

Seeds: run ``i`` of manoeuvre group ``g`` uses the sensor-noise seed
``SeedSequence([ROOT_SEED, g, i]).generate_state(1)[0]``. The truth plant is
deterministic for a given scenario (the seed drives only the sensor noise),
which the report checks by comparing a digest of the truth of every run.
"""

from __future__ import annotations

import functools
import math
import sys
from pathlib import Path

from terrain_analysis.experiment import Reproduction, reproduction_main
from terrain_analysis.reporting import Claim, Provenance, Report, claims_table, write_page
from terrain_analysis.tools.skid_metrics import (
    Results,
    SideslipErrors,
    collect,
    icr_statistics,
    score_one,
    sideslip_errors,
    tracking_lag,
    values_at,
)
from terrain_analysis.tools.skid_runs import (
    FILTERS,
    MARGIN,
    REL_FLOOR,
    ROOT_SEED,
    Counts,
    RunData,
    RunSpec,
    build_plan,
    run_one,
    run_seed,
)
from terrain_analysis.tools.skid_tables import _diag, _r, section_straight, section_tables
from terrain_analysis.tools.skid_turn import not_reproduced, section_icr, section_mismatch, section_turn_obs
from terrain_estimation.estimators.skid_steer import SkidSteerEstimatorConfig
from vehicle_sim.plants.skid_steer import SkidSteerSensors

__all__ = [
    "ROOT_SEED",
    "FILTERS",
    "Claim",
    "Counts",
    "RunSpec",
    "RunData",
    "SideslipErrors",
    "run_seed",
    "run_one",
    "sideslip_errors",
    "values_at",
    "tracking_lag",
    "icr_statistics",
    "build_plan",
    "claims_table",
    "main",
]

SECTION_WRITERS = (section_tables, section_straight, section_icr, section_turn_obs, section_mismatch)
"""The sections' writers, in the order of the page."""


def _write_report(rep: Report, res: Results, counts: Counts, provenance: Provenance) -> Path:
    deterministic = ", ".join(
        f"{case}: {'yes' if len(d) == 1 else f'NO ({len(d)} different)'}" for case, d in sorted(res.digests.items())
    )
    sensors = SkidSteerSensors()
    cfg = SkidSteerEstimatorConfig.paper()
    st = cfg.strong_tracking
    bullets = [
        f"- Run counts: small-radius turn {len(res.metrics.get('small_radius_turn', []))} runs "
        f"({counts.turn_duration:g} s), S-shape {len(res.metrics.get('s_shape', []))} runs ({counts.s_duration:g} s), "
        f"straight acceleration {len(res.metrics.get('straight_acceleration', []))} runs "
        f"({counts.straight_duration:g} s), tire-mismatch sensitivity {len(res.metrics.get('turn_mismatch', []))} "
        f"runs ({counts.turn_duration:g} s). Mean ± std are over runs.",
        f"- Seeds: run i of manoeuvre group g uses the sensor-noise seed "
        f"`numpy.random.SeedSequence([{ROOT_SEED}, g, i]).generate_state(1)[0]`; groups: 1 = straight "
        "acceleration, 2 = small-radius turn (and the mismatch sensitivity: paired), 3 = S-shape. The seed "
        "drives only the sensor noise (IMU, encoders, GNSS): the truth plant is deterministic for a given "
        f"scenario. Truth identical in every run (digest of v_x, v_y, r): {deterministic}.",
        "- Truth: `vehicle_sim.plants.skid_steer.simulate_skid_steer` on the scenarios of `MANOEUVRES` "
        "(RK4, 2 ms steps; the plant's magic-formula tire, wheel-side drive dynamics, motion resistance, "
        "roll/pitch load-transfer dynamics and tire relaxation on; a cascaded PI driver tracks the speed and "
        "yaw-rate references). Sensors at 100 Hz: "
        f"accelerometer σ = {sensors.accel_noise_std:g} m/s², gyro σ = {sensors.gyro_noise_std:g} rad/s, motor "
        f"encoders {sensors.encoder_counts_per_revolution} counts/rev with σ = {sensors.motor_velocity_noise_std:g}"
        f" rad/s on the velocity; RTK-GNSS reference at {sensors.gnss_rate:g} Hz with σ = "
        f"{sensors.gnss_velocity_noise_std:g} m/s on the body-frame v_x, v_y.",
        "- Estimator: `SkidSteerEstimator` with its defaults (MODELS.md B.7–B.10): α = "
        f"{cfg.ukf_alpha:g}, β = {cfg.ukf_beta:g}, κ = {cfg.ukf_kappa:g}; Q0 = diag({_diag(cfg.q0_diag)}) per "
        f"{cfg.q_step_dt * 1e3:g} ms, R0 = diag({_diag(cfg.r0_diag)}); strong tracking ρ = {st.rho:g}, "
        f"γ_th = {st.gamma_th}, λ_max = {st.lambda_max:g}; adaptive noise K_q = {cfg.k_q:g}, "
        f"K_r = {cfg.k_r:g} rad⁻¹. Each filter is "
        "fed the same samples: the motor speeds, then the IMU sample of the same stamp.",
        "- Error definitions (MODELS.md D.2): e = β̂ − β_ref; max |e|, max |e|/|β_ref|, mean |e|, mean "
        "|e|/|β_ref|, std of e (population). β_ref = β_GNSS = atan2(v_y,GNSS, v_x,GNSS) at the 10 Hz GNSS stamps "
        "(the estimate taken at the same stamp), as the paper; also against the simulator's truth β at 100 Hz. "
        "The paper's relative error explodes where |β_ref| ≈ 0; the column **mean rel, floor** uses "
        f"|e| / max(|β_ref|, {math.degrees(REL_FLOOR):g}° = {REL_FLOOR:.4f} rad), a round floor above the GNSS β "
        "noise at 5 km/h (std of β_GNSS − β truth in the turn: "
        f"{_r(res.mean('small_radius_turn', 'gnss.beta_noise_std'))} rad). Windows are t0 < t ≤ t1.",
    ]
    rep.not_reproduced = not_reproduced(rep, res, counts)
    return write_page(
        rep,
        title="# Skid-steer motion states — reproduction of the AN-STUKF paper (UKF, STUKF, AN-STUKF)",
        provenance=provenance,
        bullets=bullets,
        criteria=(
            "Criteria: the issue's requirements (AN-STUKF's mean |e_β| at most half the UKF's in the turn; no worse on "
            f"the S-shape, read as within {MARGIN:.0%}; faster tracking in the acceleration, read as a ≥ {MARGIN:.0%} "
            "smaller lag or error, so that numerically equal filters do not count as faster) and the paper's "
            'qualitative observations as stated in the "paper" column; "info" rows make no claim.'
        ),
        general_causes=(
            "General causes (MODELS.md B.1): every equation of the paper (1–41) was lost and is reconstructed from the "
            "literature; the paper's Q/R, gains, thresholds, μ, wheel inertia and the exact tire model are not given; "
            "its reference was a real RTK-GNSS on a real vehicle, where the model errors the adaptive stages address "
            "are large. Here the truth plant runs its own magic-formula tire (load-dependent stiffness and friction) "
            "and suspension-force loads against the observer's brush tire and quasi-static loads; they share only "
            "the geometry and kinematics (the plant adds wheel and suspension dynamics and tire relaxation). The "
            "filters are the paper's as reconstructed (`SkidSteerEstimatorConfig.paper()`: B.10's Q0/R0, brush "
            "model); the fair comparison with a consistently tuned UKF and the project's default is "
            "`docs/results/skid_steer_fair.md`."
        ),
    )


REPRODUCTION = Reproduction(
    module="terrain_analysis.tools.reproduce_skid",
    page="skid_steer",
    what="simulated runs",
    runs_help="seeded runs per manoeuvre (default 20)",
    quick_help="smoke run: one short run per case (< 1 min)",
    counts=Counts,
    plan=build_plan,
    job=lambda counts: functools.partial(score_one, counts=counts),
    weight=lambda spec: spec.duration,
    key=lambda spec: f"{spec.case}-{spec.run}",
    collect=collect,
    sections=SECTION_WRITERS,
    write=_write_report,
)
"""The reproduction as an experiment description (:func:`terrain_analysis.experiment.run_reproduction`)."""


main = reproduction_main(REPRODUCTION, "reproduce-skid", __doc__)
"""Command-line entry point; returns the exit status."""


if __name__ == "__main__":
    sys.exit(main())
