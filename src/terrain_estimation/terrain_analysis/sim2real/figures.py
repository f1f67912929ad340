"""The figures of the sim-to-real reports (PNG, matplotlib's Agg backend, imported only when drawn).

:func:`diagnosis_figures`: the held-out residuals of the nominal model and the
best candidate, the shrinkage of every candidate with its interval, the
nominal residual power per octave band. :func:`where_figures`: those of the
open-loop "where" report.
"""

from __future__ import annotations

from pathlib import Path

from terrain_analysis.sim2real.diagnose import Diagnosis
from terrain_analysis.sim2real.open_loop import WhereReport

__all__ = ["diagnosis_figures", "where_figures"]


def where_figures(report: WhereReport, out: Path) -> list[Path]:
    """The open-loop report's figures in ``out``: residual power per band, residual RMS per window, the replay."""
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


def diagnosis_figures(d: Diagnosis, out: Path) -> list[Path]:
    """The diagnosis figures in ``out``: shrinkage per candidate, held-out residuals, residual power per band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    a = d.attribution
    paths: list[Path] = []
    # 1. Shrinkage per candidate with its interval.
    fig, ax = plt.subplots(figsize=(8, 0.35 * (len(a.ranking) + len(a.pairs)) + 1.5))
    rows = a.ranking + a.pairs
    y = np.arange(len(rows))[::-1]
    s = np.array([100 * m.shrinkage.get("overall", 0.0) for m in rows])
    lo = np.array([100 * m.shrinkage_ci[0] for m in rows])
    hi = np.array([100 * m.shrinkage_ci[1] for m in rows])
    colors = ["tab:green" if m.significant else "tab:grey" for m in rows]
    ax.barh(y, np.clip(s, -100, 100), color=colors)
    ax.errorbar(
        np.clip(s, -100, 100), y, xerr=[np.clip(s - lo, 0, None), np.clip(hi - s, 0, None)], fmt="none", ecolor="k"
    )
    ax.set_yticks(y)
    ax.set_yticklabels([m.name for m in rows])
    ax.set_xlim(-100, 105)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("held-out gap shrinkage (%), green: significant")
    ax.set_title(a.verdict if len(a.verdict) < 90 else a.verdict[:87] + "…", fontsize=9)
    fig.tight_layout()
    paths.append(out / "shrinkage.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)
    # 2. Held-out residuals: nominal vs best, per channel.
    model = d.model
    if model is not None and a.best is not None and a.best.name in a.series:
        chans = list(model.channels)
        # At most about 9 in tall (the first screen of the report shows it beside the tables).
        height = max(3.0, min(2.4 * len(chans), 1.5 * len(chans) + 1.0, 9.0))
        fig, axes = plt.subplots(len(chans), 1, figsize=(9, height), squeeze=False, sharex=True)
        for ax, ch in zip(axes[:, 0], chans, strict=True):
            t = np.asarray(model.times[ch.name])
            m = a.test_masks.get(ch.name, np.ones(t.size, dtype=bool))
            meas = np.asarray(model.measured[ch.name])
            r0 = np.where(m, meas - a.series["nominal"][ch.name], np.nan)
            r1 = np.where(m, meas - a.series[a.best.name][ch.name], np.nan)
            ax.plot(t, r0, lw=0.6, label="nominal")
            ax.plot(t, r1, lw=0.6, label=a.best.name)
            ax.axhspan(-ch.noise_std, ch.noise_std, color="0.85", zorder=0)
            ax.set_ylabel(f"{ch.name} ({ch.unit})", fontsize=8)
        axes[0, 0].legend(loc="upper right", fontsize=8)
        axes[0, 0].set_title("held-out residual (measured − replay); grey band: ±1σ noise budget", fontsize=9)
        axes[-1, 0].set_xlabel("time (s from bag start)")
        fig.tight_layout()
        paths.append(out / "residuals.png")
        fig.savefig(paths[-1], dpi=100)
        plt.close(fig)
    # 3. Residual power per octave band (nominal).
    chans_b = [cr for cr in d.where.channels if cr.bands]
    if chans_b:
        fig, ax = plt.subplots(figsize=(8, 4))
        width = 0.8 / len(chans_b)
        for i, cr in enumerate(chans_b):
            x = np.arange(len(cr.bands)) + i * width
            ax.bar(x, [b.residual_to_noise for b in cr.bands], width, label=cr.name)
            ax.plot(x, [b.threshold for b in cr.bands], "k_", markersize=12)
        ax.set_xticks(np.arange(len(chans_b[0].bands)) + 0.4 - width / 2)
        ax.set_xticklabels([f"{b.f_low:g}–{b.f_high:g}" for b in chans_b[0].bands])
        ax.set_yscale("log")
        ax.axhline(1.0, color="grey", lw=0.8)
        ax.set_xlabel("band (Hz)")
        ax.set_ylabel("residual PSD / noise PSD (— threshold)")
        ax.legend(fontsize=8)
        ax.set_title("Nominal model: residual power per octave band")
        fig.tight_layout()
        paths.append(out / "bands.png")
        fig.savefig(paths[-1], dpi=100)
        plt.close(fig)
    return paths
