"""Sim-to-real gap of the Wong–Reece wheel model on a real single-wheel rig (CMU, smooth wheel, granular soil).

Data
    ``all_smooth_data.mat`` of the Carnegie Mellon single-wheel testbed
    (``robomechanics/3d-terramechanics``, C. Pavlov 2022, MIT licence; see
    ``real_data/README.md``): 189 steady-state trials of a smooth rigid wheel
    (r = 58 mm, b = 50 mm) at 10 mm/s carriage speed, 9 slip ratios from −1
    (locked) to 0.9, slip angles β = 0…90°, three repetitions each. Only the
    27 trials at β = 0 are used: the model is planar (no lateral force, no
    side-wall bulldozing), and a trial at β ≠ 0 has a lateral slip velocity it
    cannot represent. Per trial: slip i = (V_ry − V_x)/max(V_x, V_ry) (the
    project's eqs. 1–2), normal load W = −avg_Fz (N), drawbar pull
    DP = −avg_Fy (N, the rig's "tractive" axis), sinkage z = −avg_Z (mm).

Replay model (:class:`SingleWheelModel`, a :class:`~terrain_analysis.sim2real.model.ReplayModel`)
    "Samples" are trials, ordered by slip (then trial number); the "time" of
    trial k is k (no physical time: each trial is a steady state). Inputs are
    the measured i and W of each trial; the predicted channels are DP (N) and
    z (mm). The engine's least squares compares them with the measured means
    in units of the noise budget σ.

    Noise budget σ per channel: the pooled standard deviation of the repeated
    trials (three per commanded slip) about their slip group's mean,
    √(Σ (x − x̄_group)² / (N − groups)). It contains what the model would
    also see with perfect physics: soil preparation from run to run, the load
    varying from run to run, and the error of each trial's time average. The
    per-trial ``std_*`` fields are the fluctuation *within* a trial (the
    force ripple as the wheel rolls, 1–6 N), not the error of its mean, so
    they are reported but not used as σ.

Nominal physics
    The project's Wong–Reece rigid wheel (:mod:`vehicle_sim.terrain.wong_reece`,
    [RB] eqs. 3–11, same discretisation: Simpson's rule on the rear and front
    flow regions, ``DEFAULT_SIMPSON_POINTS`` nodes each, contact angle the
    smallest root of eq. 7 by a bracketing scan and Illinois iteration, skid
    by the anti-symmetry eqs. 10–11) with the rig authors' soil:

    * pressure–sinkage σ = k z^n with one modulus k = 8e3 kN/m^(n+2) and
      n = 1.46 (their ``set_soil_params.m``: σ[kPa] = k[kN/m^(n+2)] z[m]^n).
      In Bekker's form σ = (k_c/b + k_φ) z^n this is k_c = 0, k_φ = 8e6 N/m^(n+2)
      (the cohesive term is folded into the one modulus; nothing is lost for a
      single wheel width), i.e. the model's k1 = 0, k2 = k_φ b^(n−1);
    * cohesion c = 1 kPa, friction angle φ = 29°, shear modulus K = 21 mm
      (the values their README gives; their own smooth-wheel tuning used
      K = 10 mm and n0 = 1.4, with a slip-dependent n, reported here as a
      candidate effect, not as the nominal);
    * θ_m = θ0 (c1 + c2 i) with the project's c1 = 0.18, c2 = 0.32 (Wong's
      loose sand; the authors fitted theirs, which is the candidate
      ``max_stress_angle``); no rear contact (exit angle 0).

    Their soil specific weight 13.0 kN/m³ enters only their side-wall
    bulldozing term at β ≠ 0, which the planar model does not have.

    Sinkage: z = r (1 − cos θ0) below the undisturbed surface, with θ0 of the
    trial's own slip for i ≥ 0 and of slip −i in skid (the state the
    anti-symmetry mirrors, as :func:`~vehicle_sim.terrain.wong_reece.wheel_forces` returns it).

Candidate effects (fitted on some trials, scored on others)
    From the rover catalogue (:data:`vehicle_sim.effects.CATALOGUE` ``["rover"]``),
    the effects that act on a single smooth wheel, with the catalogue's fit ranges:

    * ``slip_sinkage``: k_eff = k/(1 + c|i|), implemented as the rover plant
      does (forces at W (1 + c|i|), divided by 1 + c|i|; θ0 of the scaled load).
    * ``soil_change``: the soil differs from the authors' values. Its four
      parameters (cohesion scale, friction-angle change, scale of the moduli
      k_c and k_φ, scale of the shear modulus K) are offered one at a time,
      ``soil_change_cohesion``, ``soil_change_friction_angle``,
      ``soil_change_modulus``, ``soil_change_shear_modulus`` (the engine pairs
      them when one does not suffice; all four at once are not identifiable
      from two channels: standard errors of tens). The catalogue's change
      *distance* has no meaning for separate steady-state trials on one
      prepared soil and is left out.
    * ``load_cell_bias``: constant offset of the drawbar-pull axis (N).
    * ``load_cell_crosstalk``: each force axis reads c times the other:
      DP_meas = DP + c W, W_meas = W + c DP (the measured W is the model's input,
      so W = W_meas − c DP is solved by fixed-point iteration).

    * ``grousers`` (a grousered wheel only, :class:`WheelGeometry`): the
      soil between the grousers moves with the wheel and is sheared on the
      cylinder through the tips, r + h_e, at the tip slip (the rover plant's
      mechanism, :func:`tip_slip`); the effective height h_e is fitted in
      [0, h_g] (h_g the wheel's grouser height; sparse grousers trap less
      soil). The sinkage is the tip circle's (the rig zeroes it with the
      tips on the surface).

    Not applicable: ``grousers`` on a smooth wheel, ``vertical_velocity``,
    ``imu_bias``, ``sensor_delay`` (no body, no IMU, trial means).

    Added for the rig, each a physical mechanism of a smooth wheel in sand:

    * ``sinkage_exponent``: n of the pressure–sinkage law (k's numerical value
      in N/m^(n+2) kept, as the authors do).
    * ``slip_exponent``: slip-dependent sinkage exponent n = n0 + n1 i (drive)
      or n0 + n2 |i| (skid), the authors' and Ding et al.'s slip-sinkage.
    * ``rear_contact``: the soil rebounds behind the wheel: exit angle
      θ_r = −λ θ0 (λ ≥ 0), rear region [θ_r, θ_m] mapped onto the front profile
      by θ* = θ0 − (θ − θ_r)/(θ_m − θ_r) (θ0 − θ_m) (the project's eq. 5 for θ_r = 0).
    * ``max_stress_angle``: c1, c2 of θ_m = θ0 (c1 + c2 i).
    * ``sinkage_offset``: the rig's sinkage zero (the wheel touching the
      prepared surface) is off by a constant (mm).
    * ``bulldozing`` (issue 22: what the braking data call for): the soil
      wedge a skidding wheel pushes ahead, κ × Wong's bulldozing resistance
      b (0.67 c z K_pc + 0.5 γ z² K_pγ) at the model's sinkage z, mobilised
      by the skid like the Janosi–Hanamoto shear, 1 − exp(−|i| r θ0/K), zero
      in drive (:func:`bulldozing_resistance`); κ fitted in [0, 3], physically
      0–1.5 (1: the full passive wedge).

    Physical ranges (:data:`PHYSICAL_RANGES`): a fit outside them, or at a
    bound of its fit range, is flagged in the report.
    * ``skid_stresses`` (a switch): in braking, the stresses of eqs. 3–9
      evaluated at the skid itself, with the Janosi–Hanamoto shear odd in the
      shear displacement (τ opposes the rim's motion relative to the soil) and
      θ_m = c1 θ0 (Wong's θ_m law is for driven slip), instead of the
      anti-symmetry of eqs. 10–11; the sinkage is then that of the skidding
      wheel (eq. 7 at the skid, where the reversed shear pushes the wheel down).

Driver (``python -m terrain_analysis.sim2real.single_wheel --data DIR --out DIR [--file F] [--radius R]
[--width B] [--grousers N --grouser-height H]``): any trial file of the rig's layout (``all_results``
with the fields above), the wheel's geometry as options (default: the smooth wheel).
    Writes ``single_wheel.md`` (a section for ``docs/results/sim2real.md``),
    ``single_wheel.json`` and ``single_wheel_fit.png``:

    * *where*: residual rig − model per slip regime (braking i < −0.1, low
      slip, high slip i > 0.3) for the nominal model and each analysis' best;
    * the model's stresses at the *measured* sinkage
      (:func:`consistency_at_measured_sinkage`), and the strongest braking
      resistance any re-parameterised Wong–Reece wheel can give at the locked
      wheel's measured sinkage and load (:func:`strongest_stress_field`);
    * *which effect*: the engine (:func:`~terrain_analysis.sim2real.attribution.attribute`)
      on the splits of :func:`analyses` (alternate slips; drive → braking;
      braking → drive; drive trials alone), the held-out trials given as its
      test mask;
    * the baseline (issue 22): every verdict against a slip-binned mean
      fitted on the same training trials and scored on the same held-out
      trials (:func:`slip_binned_baseline`, :func:`baseline_comparison`);
    * identifiability on the rig's own design (:func:`identifiability`):
      simulated trials with one effect each, diagnosed blind (``--validate N``
      seeds, default 2; 0 skips it).

    A run takes about 1 min of CPU with the identifiability check (30 s without).

Units: SI inside the physics (m, rad, Pa, N); sinkage channel in mm.

Modules: the wheel's physics (:mod:`~terrain_analysis.sim2real.single_wheel_physics`), the trials
(:mod:`~terrain_analysis.sim2real.single_wheel_data`), the replay model and its candidates
(:mod:`~terrain_analysis.sim2real.single_wheel_model`), the analyses
(:mod:`~terrain_analysis.sim2real.single_wheel_analysis`) and the report
(:mod:`~terrain_analysis.sim2real.single_wheel_report`); this module runs them (:func:`run`, the command) and
re-exports their public names.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.single_wheel_analysis import (
    BASELINE_BIN_WIDTH,
    REGIMES,
    Analysis,
    analyses,
    at_bounds,
    baseline_comparison,
    bulldozing_at_measured_sinkage,
    consistency_at_measured_sinkage,
    identifiability,
    regime_table,
    slip_binned_baseline,
    strongest_locked,
    strongest_stress_field,
    synthetic_trials,
)
from terrain_analysis.sim2real.single_wheel_data import DATA_FILE, RigTrials, load_rig_trials, pooled_replicate_std
from terrain_analysis.sim2real.single_wheel_model import PHYSICAL_RANGES, SingleWheelModel, candidates
from terrain_analysis.sim2real.single_wheel_physics import (
    NOMINAL,
    RIG_WHEEL,
    RIG_WHEEL_RADIUS,
    RIG_WHEEL_WIDTH,
    WheelGeometry,
    WheelSoil,
    bearing_capacity_factors,
    bulldozing_resistance,
    steady_state,
    tip_slip,
)
from terrain_analysis.sim2real.single_wheel_report import fit_figure, jsonable, single_wheel_markdown
from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.cli import cli_main

__all__ = [
    "Analysis",
    "DATA_FILE",
    "NOMINAL",
    "REGIMES",
    "BASELINE_BIN_WIDTH",
    "PHYSICAL_RANGES",
    "RIG_WHEEL",
    "RIG_WHEEL_RADIUS",
    "RIG_WHEEL_WIDTH",
    "RigTrials",
    "SingleWheelModel",
    "WheelGeometry",
    "WheelSoil",
    "analyses",
    "baseline_comparison",
    "bearing_capacity_factors",
    "bulldozing_resistance",
    "candidates",
    "consistency_at_measured_sinkage",
    "identifiability",
    "load_rig_trials",
    "main",
    "pooled_replicate_std",
    "run",
    "steady_state",
    "strongest_stress_field",
    "slip_binned_baseline",
    "synthetic_trials",
    "tip_slip",
]

FloatArray = NDArray[np.float64]


def run(
    folder: str | Path,
    out: str | Path,
    *,
    progress: Any = None,
    settings: Any = None,
    only: Sequence[str] | None = None,
    validate: Sequence[int] = (),
    geometry: WheelGeometry = RIG_WHEEL,
    file: str | None = None,
) -> dict[str, Any]:
    """Diagnose the rig data and write ``single_wheel.md``, ``single_wheel.json`` and PNG figures to ``out``.

    Args:
        folder: Folder holding the trial file (or the file itself).
        geometry: The wheel's geometry (default: the smooth wheel of ``all_smooth_data.mat``).
        file: The trial file's name in ``folder`` (default :data:`DATA_FILE`).
        out: Output folder (created).
        progress: Called with one line per step, or None.
        settings: :class:`~terrain_analysis.sim2real.attribution.AttributionSettings` (default: the engine's).
        only: Names of the analyses to run (default: all of :func:`analyses`).
        validate: Seeds of the simulated identifiability check (:func:`identifiability`); empty: none.

    Returns:
        The JSON summary.
    """
    from terrain_analysis.sim2real.attribution import AttributionSettings, attribute

    trials = load_rig_trials(folder, file)
    full = SingleWheelModel(trials, geometry=geometry)
    noise = {ch.name: (ch.noise_std, full.noise_dof[ch.name]) for ch in full.channels}
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    settings = settings or AttributionSettings()
    results: dict[str, Any] = {}
    reports: dict[str, Any] = {}
    predictions: dict[str, dict[str, FloatArray]] = {"nominal": full.predict({}, {})}
    for analysis in analyses(trials):
        if only is not None and analysis.name not in only:
            continue
        if progress is not None:
            progress(f"analysis {analysis.name}: {analysis.description}")
        model = SingleWheelModel(trials.subset(analysis.keep), noise=noise, geometry=geometry)
        test_mask = {ch.name: analysis.held_out for ch in model.channels}
        report = attribute(model, settings=settings, test_mask=test_mask, progress=progress)
        reports[analysis.name] = report
        results[analysis.name] = {
            "description": analysis.description,
            "trials": int(analysis.keep.sum()),
            "held_out_trials": int(analysis.held_out.sum()),
            "at_bounds": at_bounds(model, report),
            "baseline": baseline_comparison(model, analysis.held_out, report),
            **report.to_dict(),
        }
        if report.best is not None:
            predictions[f"{report.best.name} [{analysis.name}]"] = full.predict(report.best.parameters, {})
        if analysis.name == "alternate":  # the baseline on the figure and in the where-table: the first analysis'
            predictions[f"slip-binned mean [{analysis.name}]"] = {
                ch.name: slip_binned_baseline(trials.slip, full.measured[ch.name], ~analysis.held_out)[0]
                for ch in full.channels
            }
    summary = {
        "data": {
            "source": trials.source,
            "trials_used": trials.size,
            "trials_total": trials.total_trials,
            "betas": list(trials.betas),
            "load_range": [float(trials.load.min()), float(trials.load.max())],
            "noise_std": {ch.name: ch.noise_std for ch in full.channels},
            "noise_dof": full.noise_dof,
            "median_within_trial_std": {
                "drawbar_pull": float(np.median(trials.drawbar_pull_ripple)),
                "sinkage": float(np.median(trials.sinkage_ripple)),
            },
        },
        "geometry": dataclasses.asdict(geometry),
        "identifiability": identifiability(
            trials, noise, validate, settings=settings, progress=progress, geometry=geometry
        )
        if validate
        else [],
        "nominal_soil": dataclasses.asdict(full.base),
        "at_measured_sinkage": consistency_at_measured_sinkage(trials, full.base),
        "strongest_locked_wheel": strongest_locked(trials, full.base),
        "bulldozing_at_measured_sinkage": bulldozing_at_measured_sinkage(trials, full.base),
        "regimes": regime_table(full, predictions),
        "analyses": results,
        "notes": full.notes,
    }
    (out_dir / "single_wheel.json").write_text(json.dumps(jsonable(summary), indent=1) + "\n")
    figures = fit_figure(full, predictions, out_dir)
    (out_dir / "single_wheel.md").write_text(single_wheel_markdown(full, summary, reports, figures))
    return summary


@cli_main("sim2real-single-wheel")
def main(argv: Sequence[str] | None = None) -> int:
    """``python -m terrain_analysis.sim2real.single_wheel --data DIR --out DIR``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="folder holding the trial file, or the trial file itself")
    parser.add_argument("--file", help=f"trial file of the rig's layout (all_results) in --data (default {DATA_FILE})")
    parser.add_argument("--radius", type=float, default=RIG_WHEEL_RADIUS, help="wheel rim radius (m)")
    parser.add_argument("--width", type=float, default=RIG_WHEEL_WIDTH, help="wheel width (m)")
    parser.add_argument("--grousers", type=int, default=0, metavar="COUNT", help="grousers on the rim (0: smooth)")
    parser.add_argument(
        "--grouser-height", type=float, default=0.0, metavar="M", help="grouser height above the rim (m)"
    )
    parser.add_argument("--out", required=True, help="output folder (Markdown, JSON, PNG)")
    parser.add_argument("--only", nargs="*", help="analyses to run (default: all)")
    parser.add_argument(
        "--validate", type=int, default=2, metavar="N", help="seeds of the simulated identifiability check (0: none)"
    )
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    try:
        geometry = WheelGeometry(args.radius, args.width, args.grousers, args.grouser_height)
        summary = run(
            args.data,
            args.out,
            progress=None if args.quiet else lambda s: print(s, file=sys.stderr),
            only=args.only,
            validate=tuple(range(1, args.validate + 1)),
            geometry=geometry,
            file=args.file,
        )
    except Sim2RealError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for name, res in summary["analyses"].items():
        print(f"{name}: {res['verdict']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
