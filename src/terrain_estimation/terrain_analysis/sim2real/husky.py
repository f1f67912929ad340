"""Real-data check of the skid-steer replay: BorealTC Husky A200 runs (issue 6).

``python -m terrain_analysis.sim2real.husky --data /work/shared/real_data/borealtc --out DIR``

What it does
    1. Imports every run (``imu_XX.csv`` + ``pro_XX.csv``) into a contract bag
       (:mod:`vehicle_sim.tools.borealtc`) under ``DIR/bags`` (or ``--bags``).
    2. Builds the replay model of :mod:`terrain_analysis.sim2real.skid_steer`
       for each bag with the 4-wheel Husky of ``config/husky.yaml`` (two axles
       at ±wheelbase/2, rigid chassis: no load-transfer-dynamics effect).
       Channels: yaw rate and lateral specific force (the longitudinal one
       would be a derivative of wheel speeds reported at 6.5 Hz). The side
       speeds are taken as instantaneous at their stamps and interpolated
       linearly to the 100 Hz IMU stamps.
    3. Noise budget per channel: the IMU's own high-frequency noise
       (robust σ of first differences / √2 of the 100 Hz signal: white sensor
       noise plus vibration, which no replay predicts) plus what the wheel-speed
       quantisation (0.0157 m/s steps) does through the replay.
    4. Fits the tire parameters the data set cannot give (scales of C_x, C_α
       and μ, nuisance parameters) on the *training* runs of one terrain
       (even run numbers) by least squares over all their samples, then scores
       the held-out runs of that terrain (odd numbers) and every run of the
       other terrain with the parameters fitted there and with the nominal
       (config) values, against the kinematic baseline (encoder yaw rate
       (v_R − v_L)/B, what a no-slip model predicts). Both directions
       (ASPHALT → SANDY_LOAM and back).
    5. Runs the attribution engine on a few held-out runs (nuisance started at
       the fitted values) and reports its verdicts as they are.

Writes ``DIR/husky.md`` (a Markdown section), ``DIR/husky.json`` and
``DIR/husky.png``.

The 6.5 Hz wheel speeds cost: yaw-rate content above their Nyquist
frequency (3.25 Hz) cannot be predicted, a step in the side speeds is smeared
over one report period (0.15 s), and linear interpolation lags a ramp by
nothing but misses its corners; residuals at those frequencies are model
error, not an effect.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from terrain_analysis.sim2real.husky_fit import (
    PhysicsFit,
    RunScore,
    cropped_model,
    encoder_yaw_rate,
    fit_effective_track,
    fit_physics,
    integrated_autocorrelation,
    score_run,
    split_of,
    verdict_baseline,
)
from terrain_analysis.sim2real.husky_flags import (
    DEFAULT_FRICTION,
    STIFFNESS_PER_LOAD,
    TERRAIN_FRICTION,
    flag_engine,
    flag_fit,
    flag_value,
    physical_ranges,
)
from terrain_analysis.sim2real.husky_model import (
    CHANNELS,
    NUISANCE_NAMES,
    build_husky_model,
    husky_vehicle,
    imu_noise_std,
)
from terrain_analysis.sim2real.husky_report import (
    baseline_comparison,
    baseline_figure,
    husky_markdown,
    interpretation,
    replay_figure,
)
from terrain_analysis.sim2real.skid_steer_replay import SkidSteerReplay
from terrain_estimation.cli import cli_main

__all__ = [
    "CHANNELS",
    "NUISANCE_NAMES",
    "PhysicsFit",
    "RunScore",
    "baseline_comparison",
    "build_husky_model",
    "encoder_yaw_rate",
    "fit_effective_track",
    "fit_physics",
    "flag_fit",
    "flag_value",
    "husky_vehicle",
    "imu_noise_std",
    "integrated_autocorrelation",
    "interpretation",
    "main",
    "physical_ranges",
    "score_run",
]


@cli_main("sim2real-husky")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m terrain_analysis.sim2real.husky", description=(__doc__ or "").splitlines()[0]
    )
    parser.add_argument("--data", required=True, help="BorealTC folder (<TERRAIN>/imu_XX.csv, pro_XX.csv)")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--config", help="Husky config (default config/husky.yaml)")
    parser.add_argument("--bags", help="where the imported contract bags go (default OUT/bags)")
    parser.add_argument("--overwrite", action="store_true", help="replace bags imported by an earlier run")
    parser.add_argument("--attribute", type=int, default=1, help="held-out runs per terrain given to the engine")
    parser.add_argument(
        "--attribute-seconds", type=float, default=30.0, help="first seconds of each such run given to the engine"
    )
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="re-write OUT/husky.md from OUT/husky.json of an earlier run (no fit, no figure)",
    )
    args = parser.parse_args(argv)
    from vehicle_sim.tools.borealtc import convert_run, find_runs, read_husky_config

    out = Path(args.out)
    if args.report_only:
        from terrain_analysis.reporting import write_section

        saved = json.loads((out / "husky.json").read_text())
        write_section(out / "husky.md", "husky", husky_markdown(saved, sorted(saved["effective_track"])))
        print(f"wrote {out / 'husky.md'} from {out / 'husky.json'}")
        return 0
    out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    cfg = read_husky_config(args.config)
    runs = find_runs(args.data)
    models: dict[str, SkidSteerReplay] = {}
    terrain_of: dict[str, str] = {}
    for run in runs:
        bag = convert_run(
            run,
            Path(args.bags) if args.bags else out / "bags",
            wheel_radius=cfg["vehicle.wheel_radius"],
            transmission_ratio=cfg["vehicle.transmission_ratio"],
            overwrite=args.overwrite,
            inputs=[args.data],
        )
        models[run.name] = build_husky_model(bag, args.config)
        terrain_of[run.name] = run.terrain
        print(f"{run.name}: {models[run.name].data.t[-1]:.1f} s", file=sys.stderr)
    terrains = sorted(set(terrain_of.values()))
    any_model = next(iter(models.values()))
    fits: dict[str, dict[str, Any]] = {}
    flags: list[dict[str, Any]] = []
    chi: dict[str, float] = {}
    for terrain in terrains:
        train = [models[n] for n in models if terrain_of[n] == terrain and split_of(n) == "train"]
        chi[terrain] = fit_effective_track(train)
        start: dict[str, float] = {}
        for kind, effect in (("physics", None), ("physics + turning resistance", "turning_resistance")):
            # The turning-resistance fit starts from the tire fit (it can only add to it).
            fit = fit_physics(train, effect, start=start)
            start = dict(fit.values)
            fits.setdefault(terrain, {})[kind] = vars(fit)
            flags += flag_fit(f"{kind} fitted on {terrain}", fit, any_model, terrain)
            print(
                f"{kind} fitted on {terrain}: {fit.values} {fit.effects} (σ corrected {fit.std_corrected}), "
                f"reduced χ² {fit.reduced_chi2:.2f}, τ {fit.tau:.0f} samples",
                file=sys.stderr,
            )
        print(f"effective track on {terrain}: χ = {chi[terrain]:.3f}", file=sys.stderr)
    nominal = {p.name: p.off for p in any_model.nuisance}
    physics: dict[str, tuple[Mapping[str, float], Mapping[str, Mapping[str, float]]]] = {
        "nominal (config)": (nominal, {})
    }
    for terrain in terrains:
        physics[f"physics ({terrain})"] = (fits[terrain]["physics"]["values"], {})
        tr = fits[terrain]["physics + turning resistance"]
        physics[f"physics + turning resistance ({terrain})"] = (tr["values"], tr["effects"])
    track = {"kinematic (χ = 1)": 1.0, **{f"effective track ({t})": chi[t] for t in terrains}}
    scores = [score_run(model, name, terrain_of[name], physics, track) for name, model in models.items()]
    attributions: dict[str, Any] = {}
    if args.attribute > 0:
        from terrain_analysis.sim2real.attribution import attribute

        for terrain in terrains:
            # The shortest held-out runs of at least 20 s (the engine's cost grows with the run's length).
            held = sorted(
                (
                    n
                    for n in models
                    if terrain_of[n] == terrain and split_of(n) == "test" and models[n].data.t[-1] >= 20.0
                ),
                key=lambda n: models[n].data.t[-1],
            )[: args.attribute]
            for name in held:
                t0 = time.monotonic()
                cropped = cropped_model(models[name], args.attribute_seconds)
                report = attribute(cropped, start_nuisance=fits[terrain]["physics"]["values"])
                engine_flags = flag_engine(name, cropped, terrain, report.best, report.ranking[:3])
                flags += engine_flags
                attributions[name] = {
                    "seconds_of_data": args.attribute_seconds,
                    "verdict": report.verdict,
                    "kind": report.kind,
                    "ranking": [
                        {"effect": m.name, "shrinkage": m.shrinkage.get("overall", 0.0), "parameters": m.parameters}
                        for m in report.ranking[:3]
                    ],
                    "nominal_gaps": report.nominal_gaps[:4],
                    "baseline": verdict_baseline(cropped, report, chi[terrain]),
                    "flags": len(engine_flags),
                    "seconds": time.monotonic() - t0,
                }
                print(f"{name}: {report.verdict}", file=sys.stderr)
    result = {
        "config": {k: v for k, v in cfg.items()},
        "effective_track": chi,
        "fits": fits,
        "runs": [vars(s) for s in scores],
        "attribution": attributions,
        "flags": flags,
        "physical_ranges": {
            "friction": {**TERRAIN_FRICTION, "default": DEFAULT_FRICTION},
            "stiffness_per_load": STIFFNESS_PER_LOAD,
        },
        "seconds": time.monotonic() - started,
    }
    (out / "husky.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    page = out / "husky.md"
    if page.exists() and "<!-- begin:" not in page.read_text():
        page.unlink()  # written whole by an earlier version of this command: replaced by its section
    from terrain_analysis.reporting import write_section

    write_section(page, "husky", husky_markdown(result, terrains))
    replay_figure(models, fits, chi, terrains, out / "husky.png")
    baseline_figure(result, terrains, out / "husky_baseline.png")
    print(f"wrote {page}, husky.json, husky.png, husky_baseline.png in {time.monotonic() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
