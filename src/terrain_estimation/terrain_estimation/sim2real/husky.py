"""Real-data check of the skid-steer replay: BorealTC Husky A200 runs (issue 6).

``python -m terrain_estimation.sim2real.husky --data /work/shared/real_data/borealtc --out DIR``

What it does
    1. Imports every run (``imu_XX.csv`` + ``pro_XX.csv``) into a contract bag
       (:mod:`vehicle_sim.tools.borealtc`) under ``DIR/bags`` (or ``--bags``).
    2. Builds the replay model of :mod:`terrain_estimation.sim2real.skid_steer`
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
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from terrain_estimation.cli import cli_main
from terrain_estimation.sim2real.model import candidates_from_catalogue
from terrain_estimation.sim2real.skid_steer import (
    ReplayVehicle,
    SkidSteerReplay,
    read_skid_steer_bag,
)

__all__ = ["NUISANCE_NAMES", "husky_vehicle", "imu_noise_std", "build_husky_model", "main"]

FloatArray = NDArray[np.float64]

NUISANCE_NAMES = ("longitudinal_stiffness_scale", "cornering_stiffness_scale", "friction_scale")
CHANNELS = ("yaw_rate", "ay")


def imu_noise_std(x: FloatArray) -> float:
    """Robust white-noise σ of a 100 Hz signal: 1.4826 × MAD of first differences / √2."""
    d = np.diff(np.asarray(x, dtype=float))
    mad = float(np.median(np.abs(d - np.median(d))))
    return max(1.4826 * mad / math.sqrt(2.0), 1e-6)


def husky_vehicle(config: str | Path | None = None, *, accel_noise_std: float, gyro_noise_std: float) -> ReplayVehicle:
    """The Husky of ``config/husky.yaml`` as a :class:`ReplayVehicle` (rigid chassis, two axles)."""
    from vehicle_sim.tools.borealtc import read_husky_config

    c = read_husky_config(config)
    half = 0.5 * c["vehicle.wheelbase"]
    radius = c["vehicle.wheel_radius"]
    return ReplayVehicle(
        name="husky",
        mass=c["vehicle.mass"],
        yaw_inertia=c["vehicle.yaw_inertia"],
        gravity=c["vehicle.gravity"],
        axle_x=(half, -half),
        track=c["vehicle.track"],
        cg_height=c["vehicle.cg_height"],
        wheel_radius=radius,
        transmission_ratio=c["vehicle.transmission_ratio"],
        longitudinal_stiffness=c["vehicle.longitudinal_stiffness"],
        cornering_stiffness=c["vehicle.cornering_stiffness"],
        friction=c["vehicle.friction"],
        rolling_speed_floor=c["vehicle.rolling_speed_floor"],
        rolling_resistance=c["vehicle.rolling_resistance"],
        rolling_resistance_speed=c["vehicle.rolling_resistance_speed"],
        suspension=None,
        longitudinal_relaxation_length=c["vehicle.longitudinal_relaxation_length"],
        lateral_relaxation_length=c["vehicle.lateral_relaxation_length"],
        relaxation_speed_floor=c["vehicle.relaxation_speed_floor"],
        accel_noise_std=accel_noise_std,
        gyro_noise_std=gyro_noise_std,
        wheel_speed_noise_std=0.0,
        speed_step=c["sensors.wheel_speed_step"] / radius,
    )


def build_husky_model(
    bag: str | Path, config: str | Path | None = None, *, namespace: str = "/husky", warmup: float = 1.0
) -> SkidSteerReplay:
    """Replay model of one imported Husky bag (module docstring)."""
    from vehicle_sim.tools.borealtc import read_husky_config

    ratio = read_husky_config(config)["vehicle.transmission_ratio"]
    data = read_skid_steer_bag(bag, namespace=namespace, transmission_ratio=ratio, wheel_speed_timing="instantaneous")
    vehicle = husky_vehicle(
        config, accel_noise_std=imu_noise_std(data.accel[:, 1]), gyro_noise_std=imu_noise_std(data.yaw_rate)
    )
    # μ and C_α are nuisance parameters here (fitted in every model): their catalogue effects would duplicate them.
    duplicates = ("friction_change", "cornering_stiffness_change", "load_transfer_dynamics")
    candidates = candidates_from_catalogue("skid_steer", exclude=duplicates)
    model = SkidSteerReplay(
        data, vehicle, nuisance=NUISANCE_NAMES, channels=CHANNELS, warmup=warmup, candidates=candidates
    )
    model.notes.append(
        "Husky: friction_change and cornering_stiffness_change not offered (μ and C_α are fitted as nuisance); "
        "load_transfer_dynamics not offered (rigid chassis)"
    )
    model.notes.append(
        "Husky: side speeds at 6.5 Hz interpolated to the IMU; noise budget = IMU high-frequency σ + quantisation"
    )
    return model


@dataclass
class RunScore:
    run: str
    terrain: str
    seconds: float
    mean_speed: float
    mean_abs_encoder_yaw_rate: float
    gyro_over_encoder: float
    rate_floor: float
    sigma: dict[str, float]
    rms: dict[str, dict[str, float]]  # model → channel → residual RMS


def _residuals(model: SkidSteerReplay, nuisance: Mapping[str, float]) -> FloatArray:
    pred = model.predict({}, nuisance)
    use = model.data.t >= model.data.t[0] + model.warmup
    return np.concatenate([((model.measured[c.name] - pred[c.name]) / c.noise_std)[use] for c in model.channels])


def fit_nuisance(models: Sequence[SkidSteerReplay]) -> tuple[dict[str, float], dict[str, float], float]:
    """Least-squares nuisance over all samples of ``models``: (values, standard errors, reduced χ²)."""
    params = models[0].nuisance
    x0 = np.array([p.off for p in params])
    lo = np.array([p.bounds[0] for p in params])
    hi = np.array([p.bounds[1] for p in params])

    def fun(x: FloatArray) -> FloatArray:
        values = {p.name: float(v) for p, v in zip(params, x, strict=True)}
        return np.concatenate([_residuals(m, values) for m in models])

    best = optimize.least_squares(
        fun, np.clip(x0, lo * 1.0001, hi * 0.9999), bounds=(lo, hi), x_scale=0.3, diff_step=1e-3, max_nfev=40
    )
    r = best.fun
    dof = max(1, r.size - len(x0))
    s2 = float(np.dot(r, r)) / dof
    try:
        cov = np.linalg.pinv(best.jac.T @ best.jac) * s2
        sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        sd = np.full(len(x0), math.nan)
    values = {p.name: float(v) for p, v in zip(params, best.x, strict=True)}
    return values, {p.name: float(v) for p, v in zip(params, sd, strict=True)}, s2


def score_run(model: SkidSteerReplay, run: str, terrain: str, fitted: Mapping[str, Mapping[str, float]]) -> RunScore:
    data = model.data
    use = data.t >= data.t[0] + model.warmup
    vehicle = model.replay_vehicle
    encoder = vehicle.wheel_radius * (data.omega[:, 1] - data.omega[:, 0]) / vehicle.track
    speed = vehicle.wheel_radius * 0.5 * (data.omega[:, 0] + data.omega[:, 1])
    rms: dict[str, dict[str, float]] = {
        "kinematic (no slip)": {
            "yaw_rate": float(np.sqrt(np.mean((data.yaw_rate - encoder)[use] ** 2))),
            "ay": float(np.sqrt(np.mean((data.accel[:, 1] - speed * encoder)[use] ** 2))),
        }
    }
    for label, nuisance in fitted.items():
        pred = model.predict({}, nuisance)
        rms[label] = {c: float(np.sqrt(np.mean((model.measured[c] - pred[c])[use] ** 2))) for c in CHANNELS}
    denom = float(np.dot(encoder[use], encoder[use]))
    # What the wheel-speed rate costs: the gyro itself, sampled at the joint-report times and interpolated back,
    # misses the yaw-rate content the reports cannot carry (plus the gyro noise, removed in quadrature).
    resampled = np.interp(data.t, data.joint_t, np.interp(data.joint_t, data.t, data.yaw_rate))
    floor2 = float(np.mean((data.yaw_rate - resampled)[use] ** 2)) - model.replay_vehicle.gyro_noise_std**2
    return RunScore(
        run=run,
        terrain=terrain,
        seconds=float(data.t[-1]),
        mean_speed=float(np.mean(np.abs(speed[use]))),
        mean_abs_encoder_yaw_rate=float(np.mean(np.abs(encoder[use]))),
        gyro_over_encoder=float(np.dot(encoder[use], data.yaw_rate[use]) / denom) if denom > 0 else math.nan,
        rate_floor=math.sqrt(max(floor2, 0.0)),
        sigma={c.name: c.noise_std for c in model.channels},
        rms=rms,
    )


def _cropped(model: SkidSteerReplay, seconds: float) -> SkidSteerReplay:
    """The same run's model on its first ``seconds`` (the engine's cost grows with the length)."""
    from dataclasses import replace as dc_replace

    data = model.data
    keep = data.t <= seconds
    jkeep = data.joint_t <= seconds + 1.0
    cropped = dc_replace(
        data,
        t=data.t[keep],
        accel=data.accel[keep],
        yaw_rate=data.yaw_rate[keep],
        omega=data.omega[keep],
        joint_t=data.joint_t[jkeep],
        motor_velocity=data.motor_velocity[jkeep],
    )
    return SkidSteerReplay(
        cropped,
        model.replay_vehicle,
        nuisance=[p.name for p in model.nuisance],
        candidates=model.candidates,
        channels=CHANNELS,
        warmup=model.warmup,
    )


def _split(run: str) -> str:
    return "train" if int(run.rsplit("_", 1)[1]) % 2 == 0 else "test"


@cli_main("sim2real-husky")
def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m terrain_estimation.sim2real.husky", description=(__doc__ or "").splitlines()[0]
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
    args = parser.parse_args(argv)
    from vehicle_sim.tools.borealtc import convert_run, find_runs, read_husky_config

    out = Path(args.out)
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
    fits: dict[str, dict[str, Any]] = {}
    for terrain in terrains:
        train = [models[n] for n in models if terrain_of[n] == terrain and _split(n) == "train"]
        values, std, s2 = fit_nuisance(train)
        fits[terrain] = {"values": values, "std": std, "reduced_chi2": s2, "runs": len(train)}
        print(f"fitted on {terrain} training runs: {values} (σ {std}), reduced χ² {s2:.2f}", file=sys.stderr)
    nominal = {p.name: p.off for p in next(iter(models.values())).nuisance}
    scores = []
    for name, model in models.items():
        fitted = {"nominal (config)": nominal}
        for terrain in terrains:
            fitted[f"fitted on {terrain}"] = fits[terrain]["values"]
        scores.append(score_run(model, name, terrain_of[name], fitted))
    attributions: dict[str, Any] = {}
    if args.attribute > 0:
        from terrain_estimation.sim2real.attribution import attribute

        for terrain in terrains:
            # The shortest held-out runs of at least 20 s (the engine's cost grows with the run's length).
            held = sorted(
                (
                    n
                    for n in models
                    if terrain_of[n] == terrain and _split(n) == "test" and models[n].data.t[-1] >= 20.0
                ),
                key=lambda n: models[n].data.t[-1],
            )[: args.attribute]
            for name in held:
                t0 = time.monotonic()
                report = attribute(
                    _cropped(models[name], args.attribute_seconds), start_nuisance=fits[terrain]["values"]
                )
                attributions[name] = {
                    "seconds_of_data": args.attribute_seconds,
                    "verdict": report.verdict,
                    "ranking": [
                        {"effect": m.name, "shrinkage": m.shrinkage.get("overall", 0.0), "parameters": m.parameters}
                        for m in report.ranking[:3]
                    ],
                    "nominal_gaps": report.nominal_gaps[:4],
                    "seconds": time.monotonic() - t0,
                }
                print(f"{name}: {report.verdict}", file=sys.stderr)
    result = {
        "config": {k: v for k, v in cfg.items()},
        "fits": fits,
        "runs": [vars(s) for s in scores],
        "attribution": attributions,
        "seconds": time.monotonic() - started,
    }
    (out / "husky.json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    (out / "husky.md").write_text(_markdown(result, terrains))
    _figure(models, fits, terrains, out / "husky.png")
    print(f"wrote {out / 'husky.md'}, husky.json, husky.png in {time.monotonic() - started:.0f} s")
    return 0


def _markdown(result: Mapping[str, Any], terrains: Sequence[str]) -> str:
    lines = [
        "## Real data: Husky A200 (BorealTC)",
        "",
        "Computed by `python -m terrain_estimation.sim2real.husky --data ../shared/real_data/borealtc --out DIR`.",
        "Replay of the 4-wheel skid-steer model (brush tires, quasi-static loads) on the measured side wheel",
        "speeds (6.5 Hz, interpolated), predicting the gyro yaw rate and the lateral specific force at 100 Hz.",
        "Tire scales (C_x, C_α, μ) fitted on the even-numbered runs of one terrain; odd runs held out.",
        "",
        "| fitted on | runs | C_x scale | C_α scale | μ scale | reduced χ² |",
        "|---|---|---|---|---|---|",
    ]
    for terrain in terrains:
        f = result["fits"][terrain]
        v, s = f["values"], f["std"]
        lines.append(
            f"| {terrain} | {f['runs']} | "
            + " | ".join(f"{v[n]:.3g} ± {s[n]:.2g}" for n in NUISANCE_NAMES)
            + f" | {f['reduced_chi2']:.2f} |"
        )
    models = ["kinematic (no slip)", "nominal (config)"] + [f"fitted on {t}" for t in terrains]
    lines += [
        "",
        "Yaw-rate residual RMS (rad/s) per run (`split`: train/test for the terrain's own fit; gyro/enc: least-squares",
        "ratio of gyro to encoder yaw rate; σ: noise budget; 6.5 Hz floor: RMS of the gyro minus itself sampled at the",
        "wheel-speed times and interpolated back, noise removed: what no replay driven by these reports can predict):",
        "",
        "| run | split | s | speed m/s | gyro/enc | σ | 6.5 Hz floor | " + " | ".join(models) + " |",
        "|---|---|---|---|---|---|---|" + "---|" * len(models),
    ]
    for r in result["runs"]:
        lines.append(
            f"| {r['run']} | {_split(r['run'])} | {r['seconds']:.0f} | {r['mean_speed']:.2f} | "
            f"{r['gyro_over_encoder']:.2f} | {r['sigma']['yaw_rate']:.3f} | {r['rate_floor']:.3f} | "
            + " | ".join(f"{r['rms'][m]['yaw_rate']:.3f}" for m in models)
            + " |"
        )
    lines += [
        "",
        "Median yaw-rate RMS over runs (rad/s):",
        "",
        "| runs | " + " | ".join(models) + " |",
        "|---|" + "---|" * len(models),
    ]
    for terrain in terrains:
        for split in ("train", "test"):
            sel = [r for r in result["runs"] if r["terrain"] == terrain and _split(r["run"]) == split]
            if sel:
                lines.append(
                    f"| {terrain} {split} | "
                    + " | ".join(f"{np.median([r['rms'][m]['yaw_rate'] for r in sel]):.3f}" for m in models)
                    + " |"
                )
    if result["attribution"]:
        lines += ["", "Attribution engine on the first seconds of held-out runs (verdicts as computed):", ""]
        for name, a in result["attribution"].items():
            top = ", ".join(f"{x['effect']} ({100 * x['shrinkage']:.0f} %)" for x in a["ranking"])
            lines.append(f"- {name} (first {a['seconds_of_data']:g} s): {a['verdict']}; top: {top}")
    lines.append("")
    return "\n".join(lines)


def _figure(
    models: Mapping[str, SkidSteerReplay], fits: Mapping[str, Any], terrains: Sequence[str], path: Path
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(terrains), 1, figsize=(10, 3.2 * len(terrains)), squeeze=False)
    for ax, terrain in zip(axes[:, 0], terrains, strict=True):
        # The held-out run that turns most (straight runs show nothing of the skid-steer physics).
        held = sorted(
            (n for n in models if n.startswith(terrain) and _split(n) == "test"),
            key=lambda n: -float(np.mean(np.abs(models[n].data.omega[:, 1] - models[n].data.omega[:, 0]))),
        )
        if not held:
            continue
        model = models[held[0]]
        data = model.data
        v = model.replay_vehicle
        encoder = v.wheel_radius * (data.omega[:, 1] - data.omega[:, 0]) / v.track
        other = [t for t in terrains if t != terrain]
        ax.plot(data.t, data.yaw_rate, lw=0.6, color="0.6", label="gyro (measured)")
        ax.plot(data.t, encoder, lw=1.0, label="encoder yaw rate (no slip)")
        ax.plot(
            data.t, model.predict({}, fits[terrain]["values"])["yaw_rate"], lw=1.0, label=f"replay, fitted on {terrain}"
        )
        if other:
            pred = model.predict({}, fits[other[0]]["values"])["yaw_rate"]
            ax.plot(data.t, pred, lw=1.0, ls="--", label=f"replay, fitted on {other[0]}")
        ax.set_title(f"{held[0]} (held out)")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("yaw rate (rad/s)")
        ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
