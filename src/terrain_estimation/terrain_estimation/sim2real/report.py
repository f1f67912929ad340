"""Write a :class:`~terrain_estimation.sim2real.where.WhereReport` as Markdown, JSON and PNG figures."""

from __future__ import annotations

import json
from pathlib import Path

from terrain_estimation.sim2real.where import WhereReport

__all__ = ["markdown", "write_report"]


def markdown(report: WhereReport) -> str:
    """The report as Markdown."""
    lines = [
        f"# Sim-to-real diagnosis: where — `{report.bag}`",
        "",
        f"**Verdict: {'no significant gap' if not report.gaps else 'gap'}**",
        "",
    ]
    lines += [f"- {g}" for g in report.gaps]
    lines += [
        "",
        f"Vehicle `{report.vehicle}`, namespace `{report.namespace}`, {report.duration:.1f} s, "
        f"mean speed {report.mean_speed:.2f} m/s.",
        f"Open-loop replay of the nominal plant on the measured profile with k_s = {report.k_s:.4g} N/m "
        f"({report.k_s_source}); accelerometer noise R = {report.noise_variance:g} (m/s²)² from the config; "
        f"first {report.settings.warmup:g} s left out (the replay starts at rest).",
        "",
        "## Channels",
        "",
        "| channel | samples | bias (m/s²) | bias threshold | residual std | noise σ | power ratio | threshold "
        "| gain | delay (ms) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for ch in report.channels:
        lines.append(
            f"| {ch.name} (`{ch.topic}`) | {ch.samples} | {ch.bias:+.3f} | ±{ch.bias_threshold:.3f} | "
            f"{ch.residual_std:.3f} | {ch.noise_std:.3f} | {ch.rms_ratio:.2f} | {ch.rms_threshold:.2f} | "
            f"{ch.gain:.3f} | {1000 * ch.delay:.1f} |"
        )
    for ch in report.channels:
        lines += [
            "",
            f"### {ch.name}: per octave band",
            "",
            "| band (Hz) | residual / noise power | threshold | measured / (simulated + noise) | coherence | gap |",
            "|---|---|---|---|---|---|",
        ]
        for b in ch.bands:
            lines.append(
                f"| {b.f_low:g}–{b.f_high:g} | {b.residual_to_noise:.2f} | {b.threshold:.2f} | "
                f"{b.measured_to_simulated:.2f} | {b.coherence:.2f} | {'**yes**' if b.gap else ''} |"
            )
    names = [ch.name for ch in report.channels]
    for title, rows in (("time window", report.windows), ("speed bin", report.speed_bins)):
        lines += ["", f"## Residual RMS per {title}", "", f"| {title} | samples | " + " | ".join(names) + " | gap |"]
        lines.append("|---|---|" + "---|" * len(names) + "---|")
        for r in rows:
            vals = " | ".join(f"{r.residual_rms[n]:.3f}" for n in names)
            lines.append(f"| {r.label} | {r.samples} | {vals} | {', '.join(r.gap)} |")
    lines += ["", "## Estimator innovations", ""]
    if report.nis is None or not report.nis.updates:
        lines.append("No NIS available (the estimator made no update).")
    else:
        n = report.nis
        lines += [
            f"- k_s = {n.k_s:.4g} ± {n.k_s_std:.3g} N/m (converged: {n.converged})",
            f"- mean NIS {n.mean:.3f} over {n.updates} updates, χ²({n.dim}) band [{n.band[0]:.3f}, {n.band[1]:.3f}]: "
            f"{'in band' if n.in_band else '**out of band**'}",
            "- whiteness (the core exposes the NIS, not the innovations: autocorrelation of the centred NIS), "
            f"lags 1..10 vs ±{n.whiteness_bound:.3f}: "
            + ", ".join(f"{a:+.2f}" for a in n.autocorrelation)
            + f" → {'white' if n.white else '**correlated**'}",
        ]
    if report.notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in report.notes]
    return "\n".join(lines) + "\n"


def _figures(report: WhereReport, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    paths = []
    fig, ax = plt.subplots(figsize=(8, 4))
    width = 0.8 / max(1, len(report.channels))
    for i, ch in enumerate(report.channels):
        x = np.arange(len(ch.bands)) + i * width
        ax.bar(x, [b.residual_to_noise for b in ch.bands], width, label=f"{ch.name} residual / noise")
        ax.plot(x, [b.threshold for b in ch.bands], "k_", markersize=14)
    if report.channels:
        ax.set_xticks(np.arange(len(report.channels[0].bands)) + 0.4 - width / 2)
        ax.set_xticklabels([f"{b.f_low:g}–{b.f_high:g}" for b in report.channels[0].bands])
    ax.set_yscale("log")
    ax.axhline(1.0, color="grey", lw=0.8)
    ax.set_xlabel("band (Hz)")
    ax.set_ylabel("residual PSD / noise PSD (— threshold)")
    ax.legend()
    ax.set_title("Residual power per octave band")
    fig.tight_layout()
    paths.append(out / "psd_ratio_per_band.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 4))
    for ch in report.channels:
        ax.plot(
            [0.5 * (w.start + w.end) for w in report.windows],
            [w.residual_rms[ch.name] for w in report.windows],
            "o-",
            label=f"{ch.name}",
        )
        ax.axhline(ch.noise_std, ls="--", lw=0.8, color=ax.lines[-1].get_color())
    ax.set_xlabel("window centre (s from bag start)")
    ax.set_ylabel("residual RMS (m/s²), -- noise σ")
    ax.legend()
    ax.set_title(f"Residual RMS per {report.settings.window:g} s window")
    fig.tight_layout()
    paths.append(out / "residual_per_window.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    fig, axes = plt.subplots(len(report.channels), 1, figsize=(9, 3 * len(report.channels)), squeeze=False)
    for ax, ch in zip(axes[:, 0], report.channels, strict=False):
        t = report.series[f"{ch.name}_t"]
        t = t - t[0] + report.settings.warmup
        ax.plot(t, report.series[f"{ch.name}_measured"], lw=0.6, label="measured")
        ax.plot(t, report.series[f"{ch.name}_simulated"], lw=0.6, label="nominal replay")
        ax.set_ylabel(f"{ch.name} (m/s²)")
        ax.legend(loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    paths.append(out / "replay.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    return paths


def write_report(report: WhereReport, out_dir: str | Path, *, figures: bool = True) -> list[Path]:
    """Write ``where.md``, ``where.json`` and (optionally) the figures into ``out_dir``; return the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    md = out / "where.md"
    js = out / "where.json"
    md.write_text(markdown(report), encoding="utf-8")
    js.write_text(json.dumps(report.to_dict(), indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    paths = [md, js]
    if figures:
        paths += _figures(report, out)
    return paths
