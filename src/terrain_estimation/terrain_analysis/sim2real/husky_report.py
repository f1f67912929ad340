"""The Husky section of the results: reading, tables and figures (:mod:`terrain_analysis.sim2real.husky`).

Everything here is computed from the result of the check (its JSON): no number is typed in.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.sim2real.husky_fit import encoder_yaw_rate, split_of
from terrain_analysis.sim2real.husky_flags import (
    BOUND_TOLERANCE,
    DEFAULT_FRICTION,
    STIFFNESS_PER_LOAD,
    TERRAIN_FRICTION,
)
from terrain_analysis.sim2real.husky_model import NUISANCE_NAMES
from terrain_analysis.sim2real.skid_steer_replay import SkidSteerReplay

__all__ = ["BEAT_RATIO", "baseline_comparison", "interpretation", "model_labels"]

#: The physics "beats" a baseline on a run when its held-out yaw-rate RMS is below this fraction of the
#: baseline's, and is "worse" above its inverse (in between: equal).
BEAT_RATIO = 0.95


def model_labels(terrains: Sequence[str]) -> dict[str, list[str]]:
    """Model labels of the score tables: baselines and physics, per terrain of the fit."""
    return {
        "baselines": ["zero yaw rate", "kinematic (χ = 1)"] + [f"effective track ({t})" for t in terrains],
        "physics": ["nominal (config)"]
        + [f"physics ({t})" for t in terrains]
        + [f"physics + turning resistance ({t})" for t in terrains],
    }


def _compare(physics: float, baseline: float) -> str:
    if not (math.isfinite(physics) and math.isfinite(baseline)) or baseline <= 0.0:
        return "n/a"
    if physics < BEAT_RATIO * baseline:
        return "beats"
    if physics > baseline / BEAT_RATIO:
        return "worse"
    return "equal"


def baseline_comparison(result: Mapping[str, Any], terrains: Sequence[str]) -> dict[str, Any]:
    """Per terrain, the held-out runs' yaw-rate RMS of the physics fitted there against its baselines."""
    out: dict[str, Any] = {}
    for terrain in terrains:
        held = [r for r in result["runs"] if r["terrain"] == terrain and split_of(r["run"]) == "test"]
        rows = []
        for r in held:
            rms = {m: v["yaw_rate"] for m, v in r["rms"].items()}
            physics = rms[f"physics ({terrain})"]
            track = rms[f"effective track ({terrain})"]
            rows.append(
                {
                    "run": r["run"],
                    "zero": rms["zero yaw rate"],
                    "kinematic": rms["kinematic (χ = 1)"],
                    "track": track,
                    "nominal": rms["nominal (config)"],
                    "physics": physics,
                    "turning": rms[f"physics + turning resistance ({terrain})"],
                    "floor": r["rate_floor"],
                    "physics_vs_track": _compare(physics, track),
                    "turning_vs_track": _compare(rms[f"physics + turning resistance ({terrain})"], track),
                    "zero_vs_physics": _compare(rms["zero yaw rate"], physics),
                    "nominal_vs_physics": _compare(rms["nominal (config)"], physics),
                    "difference": physics - track,
                }
            )
        out[terrain] = rows
    return out


def _count(rows: Sequence[Mapping[str, Any]], key: str) -> dict[str, int]:
    return {k: sum(1 for r in rows if r[key] == k) for k in ("beats", "equal", "worse")}


def interpretation(result: Mapping[str, Any], terrains: Sequence[str]) -> list[str]:
    """The written reading of the Husky section, generated from the computed figures (no number typed in)."""
    comparison = baseline_comparison(result, terrains)
    lines: list[str] = []
    for terrain in terrains:
        rows = comparison[terrain]
        if not rows:
            continue
        fit = result["fits"][terrain]
        chi = result["effective_track"][terrain]
        phys = _count(rows, "physics_vs_track")
        turn = _count(rows, "turning_vs_track")
        med = {k: float(np.median([r[k] for r in rows])) for k in ("zero", "track", "physics", "turning", "nominal")}
        diffs = [abs(r["difference"]) for r in rows]
        track = float(result["config"]["vehicle.track"])
        c_b = fit["physics + turning resistance"]["effects"].get("turning_resistance", {}).get("turning_resistance")
        plural = "s" if len(rows) != 1 else ""
        lines.append(
            f"- **{terrain}** ({len(rows)} held-out run{plural}). The Husky turns at χ = {chi:.2f} of its encoder "
            f"yaw rate (effective track B/χ = {track / chi:.2f} m for a {track:.3g} m track, fitted on the "
            "training runs). "
            f"Median held-out yaw-rate RMS: effective track {med['track']:.3f} rad/s, fitted brush "
            f"physics {med['physics']:.3f}, with turning resistance {med['turning']:.3f}, unfitted nominal "
            f"{med['nominal']:.3f}, zero yaw rate {med['zero']:.3f}. The fitted physics beats the one-parameter "
            f"baseline (RMS below {BEAT_RATIO:g}×) on {phys['beats']} of {len(rows)} runs, equals it on "
            f"{phys['equal']}, is worse on {phys['worse']} (|physics − baseline| {min(diffs):.3f}–{max(diffs):.3f} "
            f"rad/s); with turning resistance (c_b = {c_b:.2f}) it beats it on {turn['beats']}, equals it on "
            f"{turn['equal']}, is worse on {turn['worse']}."
        )
        zero_wins = [r["run"] for r in rows if r["zero_vs_physics"] == "beats"]
        if zero_wins:
            lines.append(
                f"  Predicting zero yaw rate beats the fitted physics on {', '.join(zero_wins)}: the model has no "
                "mechanism that stops the vehicle turning there."
            )
        nominal_wins = [r["run"] for r in rows if r["nominal_vs_physics"] == "beats"]
        if nominal_wins:
            lines.append(
                f"  The unfitted nominal beats the fit on {', '.join(nominal_wins)}: the training fit does not "
                "transfer to these runs."
            )
        if phys["beats"] == 0:
            lines.append(
                "  Here the tire scales act as a yaw-rate gain: the physics adds nothing measurable to the "
                "effective-track factor, and its parameters cannot be read as tire properties."
            )
    flagged = result["flags"]
    if flagged:
        subjects = sorted({f["subject"] for f in flagged})
        lines.append(
            f"- **Flags.** {len(flagged)} fitted values are at a fit bound or outside their physical range "
            f"({len(subjects)} fits; table below). A fit that needs them says the model's structure differs from "
            "the Husky's on that ground, not that the tire has these properties."
        )
    else:
        lines.append("- **Flags.** No fitted value is at a fit bound or outside its physical range.")
    for name, a in result["attribution"].items():
        b = a["baseline"]["yaw_rate"]
        verdict = {"beats": "beats", "equal": "equals", "worse": "is worse than"}.get(
            _compare(b["physics"], b["effective track"]), "cannot be compared with"
        )
        lines.append(
            f"- **Engine on {name}** ({a['kind']}, model {a['baseline']['model']}): held-out yaw-rate RMS "
            f"{b['physics']:.3f} rad/s against {b['effective track']:.3f} for the effective track and "
            f"{b['zero']:.3f} for zero: the verdict's physics {verdict} the baseline"
            + (f"; {a['flags']} of its fitted values flagged." if a["flags"] else ".")
        )
    return lines


def husky_markdown(result: Mapping[str, Any], terrains: Sequence[str]) -> str:
    labels = model_labels(terrains)
    lines = [
        "## Real data: Husky A200 (BorealTC)",
        "",
        "Computed by `python -m terrain_analysis.sim2real.husky --data ../shared/real_data/borealtc --out "
        "docs/results/sim2real/husky --bags out/husky_bags --overwrite` (`make sim2real-real-data`); figures "
        "`husky.png`, `husky_baseline.png` by the same command.",
        "Replay of the 4-wheel skid-steer model (brush tires, quasi-static loads) on the measured side wheel",
        "speeds (6.5 Hz, interpolated), predicting the gyro yaw rate and the lateral specific force at 100 Hz.",
        "Tire scales (C_x, C_α, μ) fitted on the even-numbered runs of one terrain, alone and with the",
        "catalogue's `turning_resistance` (lateral soil resistance c_b); odd runs held out. Baselines: zero yaw",
        "rate; the kinematic yaw rate (v_R − v_L)/B; the effective-track model χ (v_R − v_L)/B with χ fitted on",
        "the same training runs (least squares).",
        "",
        "### Reading",
        "",
        *interpretation(result, terrains),
        "",
        "### Fits on the training runs",
        "",
        "Standard errors: white (independent samples) and corrected for the residual's integrated",
        "autocorrelation τ (× √τ, effective sample size n/τ).",
        "",
        "| fitted on | model | runs | C_x scale | C_α scale | μ scale | c_b | reduced χ² | τ (samples) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for terrain in terrains:
        for kind, f in result["fits"][terrain].items():
            v, s, sc = f["values"], f["std"], f["std_corrected"]
            cb = f["effects"].get("turning_resistance", {}).get("turning_resistance")
            cells = [f"{v[n]:.3g} ± {s[n]:.2g} ({sc[n]:.2g})" for n in NUISANCE_NAMES]
            cb_cell = (
                f"{cb:.3g} ± {s['turning_resistance']:.2g} ({sc['turning_resistance']:.2g})" if cb is not None else "–"
            )
            lines.append(
                f"| {terrain} | {kind} | {f['runs']} | " + " | ".join(cells) + f" | {cb_cell} | "
                f"{f['reduced_chi2']:.2f} | {f['tau']:.0f} |"
            )
    lines += [
        "",
        "Effective track χ: " + ", ".join(f"{t} {result['effective_track'][t]:.3f}" for t in terrains) + ".",
        "",
        "### Flags: fitted values at a bound or outside their physical range",
        "",
    ]
    if result["flags"]:
        lines += ["| fit | parameter | value | why |", "|---|---|---|---|"]
        for f in result["flags"]:
            value = f"{f['value']:.3g} {f['unit']}"
            lines.append(f"| {f['subject']} | {f['parameter']} ({f['quantity']}) | {value} | {f['reason']} |")
    else:
        lines.append("None.")
    lines += [
        "",
        "Physical ranges: μ per terrain "
        + ", ".join(f"{k} {lo:g}–{hi:g}" for k, (lo, hi) in TERRAIN_FRICTION.items())
        + f" (other terrains {DEFAULT_FRICTION[0]:g}–{DEFAULT_FRICTION[1]:g}); slip stiffness per unit wheel load "
        f"C_x/F_z, C_α/F_z {STIFFNESS_PER_LOAD[0]:g}–{STIFFNESS_PER_LOAD[1]:g}; effect parameters: the catalogue's "
        "ranges (`vehicle_sim.effects`). At a bound: within "
        f"{100 * BOUND_TOLERANCE:g} % of the fit range's span (an effect's own off value excepted).",
        "",
        "### Held-out runs against the baselines (yaw-rate RMS, rad/s)",
        "",
        "| terrain | run | 6.5 Hz floor | zero | effective track | nominal | physics | + turning resistance | "
        "physics vs track |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for terrain, rows in baseline_comparison(result, terrains).items():
        for r in rows:
            lines.append(
                f"| {terrain} | {r['run']} | {r['floor']:.3f} | {r['zero']:.3f} | {r['track']:.3f} | "
                f"{r['nominal']:.3f} | {r['physics']:.3f} | {r['turning']:.3f} | {r['physics_vs_track']} |"
            )
    models = labels["baselines"] + labels["physics"]
    lines += [
        "",
        "![Held-out yaw-rate RMS per run and model](husky_baseline.png)",
        "",
        "![A held-out run: gyro, encoder yaw rate, effective track and replays](husky.png)",
        "",
        "### Appendix: every run, every model (yaw-rate RMS, rad/s)",
        "",
        "`split`: train/test for the terrain's own fit; gyro/enc: least-squares ratio of gyro to encoder yaw rate;",
        "σ: noise budget; 6.5 Hz floor: RMS of the gyro minus itself sampled at the wheel-speed times and",
        "interpolated back, noise removed: what no replay driven by these reports can predict.",
        "",
        "| run | split | s | speed m/s | gyro/enc | σ | 6.5 Hz floor | " + " | ".join(models) + " |",
        "|---|---|---|---|---|---|---|" + "---|" * len(models),
    ]
    for r in result["runs"]:
        lines.append(
            f"| {r['run']} | {split_of(r['run'])} | {r['seconds']:.0f} | {r['mean_speed']:.2f} | "
            f"{r['gyro_over_encoder']:.2f} | {r['sigma']['yaw_rate']:.3f} | {r['rate_floor']:.3f} | "
            + " | ".join(f"{r['rms'][m]['yaw_rate']:.3f}" for m in models)
            + " |"
        )
    if result["attribution"]:
        lines += ["", "Attribution engine on the first seconds of held-out runs (verdicts as computed):", ""]
        for name, a in result["attribution"].items():
            top = ", ".join(f"{x['effect']} ({100 * x['shrinkage']:.0f} %)" for x in a["ranking"])
            lines.append(f"- {name} (first {a['seconds_of_data']:g} s): {a['verdict']}; top: {top}")
    lines.append("")
    return "\n".join(lines)


def replay_figure(
    models: Mapping[str, SkidSteerReplay],
    fits: Mapping[str, Any],
    chi: Mapping[str, float],
    terrains: Sequence[str],
    path: Path,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(terrains), 1, figsize=(10, 3.2 * len(terrains)), squeeze=False)
    for ax, terrain in zip(axes[:, 0], terrains, strict=True):
        # The held-out run that turns most (straight runs show nothing of the skid-steer physics).
        held = sorted(
            (n for n in models if n.startswith(terrain) and split_of(n) == "test"),
            key=lambda n: -float(np.mean(np.abs(models[n].data.omega[:, 1] - models[n].data.omega[:, 0]))),
        )
        if not held:
            continue
        model = models[held[0]]
        data = model.data
        encoder = encoder_yaw_rate(model)
        fit = fits[terrain]
        ax.plot(data.t, data.yaw_rate, lw=0.6, color="0.6", label="gyro (measured)")
        ax.plot(data.t, encoder, lw=0.8, label="encoder yaw rate (no slip)")
        ax.plot(data.t, chi[terrain] * encoder, lw=1.0, label=f"effective track χ = {chi[terrain]:.2f}")
        ax.plot(data.t, model.predict({}, fit["physics"]["values"])["yaw_rate"], lw=1.0, label="replay, physics")
        tr = fit["physics + turning resistance"]
        ax.plot(
            data.t,
            model.predict(tr["effects"], tr["values"])["yaw_rate"],
            lw=1.0,
            ls="--",
            label="replay, physics + turning resistance",
        )
        ax.set_title(f"{held[0]} (held out; fits on {terrain} training runs)")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("yaw rate (rad/s)")
        ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def baseline_figure(result: Mapping[str, Any], terrains: Sequence[str], path: Path) -> None:
    """Grouped bars: held-out yaw-rate RMS per run of zero, effective track, physics, physics + turning resistance."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    comparison = baseline_comparison(result, terrains)
    keys = (
        ("zero", "zero yaw rate"),
        ("track", "effective track χ"),
        ("nominal", "nominal physics"),
        ("physics", "fitted physics"),
        ("turning", "physics + turning resistance"),
    )
    fig, axes = plt.subplots(len(terrains), 1, figsize=(10, 3.0 * len(terrains)), squeeze=False)
    for ax, terrain in zip(axes[:, 0], terrains, strict=True):
        rows = comparison[terrain]
        x = np.arange(len(rows))
        width = 0.8 / len(keys)
        for k, (key, label) in enumerate(keys):
            ax.bar(x + (k - 2) * width, [r[key] for r in rows], width, label=label)
        ax.plot(x, [r["floor"] for r in rows], "k_", ms=18, label="6.5 Hz floor")
        ax.set_xticks(x, [r["run"].split("/")[-1] for r in rows])
        ax.set_ylabel("yaw-rate RMS (rad/s)")
        ax.set_title(f"{terrain}: held-out runs (fits and χ on its training runs)")
        ax.legend(fontsize=7, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
