"""Cases 2 and 4 of the quarter-car reproduction: the 3-soil path of Table 4 and of the paper's Fig. 7.

Page text and figures of :mod:`~terrain_analysis.tools.reproduce_qc` for the
Table 4 rides (LETE sand → Upland sandy loam → Graneville loam, seed group 2),
the information bound of their Graneville stretch, and the same path on the
Meadow-c stand-in (case 4, seed group 4).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.reporting import Report
from terrain_analysis.reporting import format_number as _fmt
from terrain_analysis.reporting import pyplot as _plt
from terrain_analysis.reporting import summary_stats as _stats
from terrain_analysis.tools.qc_runs import (
    _GROUP_TABLE4,
    _HALF_STEP,
    _PATH_SOILS,
    _QC_WALK,
    TABLE4_CELLS,
    Counts,
    Results,
    Trace,
    _ms,
    _settle_stats,
    _t4_key,
    mean_abs,
    rmse,
    run_seeds,
    settle_time,
)
from vehicle_sim.plants.quarter_car import Scenario, SpeedProfile
from vehicle_sim.terrain.profiles import RoadProfile, iso8608_profile
from vehicle_sim.terrain.soils import SoilPath, soil_by_name

__all__ = ["T4_PAPER", "case2", "case4", "path_metrics", "table4_bound", "table4_bounds"]

FloatArray = NDArray[np.float64]


# -- case 2 and 7 (Table 4) ---------------------------------------------------------

T4_PAPER = {("B", 10.0): 9.18, ("D", 10.0): 2.28, ("F", 10.0): 1.06, ("D", 2.0): 5.83, ("D", 5.0): 2.60}
_ADAPT_PAPER = {"B": 5.54, "F": 0.51}


def path_metrics(runs: Sequence[dict[str, Trace]], label: str, stretch: float) -> dict[str, dict[str, float]]:
    """Per-stretch error and adaptation statistics on the 3-soil path."""
    out: dict[str, dict[str, float]] = {}
    for k, name in enumerate(("lete", "upland", "graneville")):
        # The estimate stamped exactly at a soil change is judged against the new soil by the truth;
        # it belongs to the next stretch, so each stretch is t0 < t < t1.
        t0, t1 = k * stretch, (k + 1) * stretch - _HALF_STEP
        out[f"{name}_mean"] = _stats([mean_abs(r[label], t0, t1) for r in runs])
        out[f"{name}_rmse"] = _stats([rmse(r[label], t0, t1) for r in runs])
        out[f"{name}_settle"] = _settle_stats(runs, label, t0, t1, 5.0)
        out[f"{name}_steady"] = _stats([mean_abs(r[label], 0.5 * (t0 + t1), t1) for r in runs])
    both = [
        0.5
        * (
            settle_time(r[label], stretch, 2 * stretch - _HALF_STEP, 5.0)[0]
            + settle_time(r[label], 2 * stretch, 3 * stretch - _HALF_STEP, 5.0)[0]
        )
        for r in runs
    ]
    out["adapt"] = _stats(both)
    out["adapt"]["censored"] = out["upland_settle"]["censored"] + out["graneville_settle"]["censored"]
    return out


def _plot_path(
    rep: Report,
    name: str,
    panels: Sequence[tuple[str, dict[str, Trace]]],
    labels: Sequence[tuple[str, str]],
    stretch: float,
    title: str,
) -> Path:
    plt = _plt()
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 2.6 * len(panels) + 0.6), sharex=True, squeeze=False)
    soils = [soil_by_name(s) for s in _PATH_SOILS]
    for ax, (panel_title, run) in zip(axes[:, 0], panels, strict=True):
        t_any = next(iter(run.values())).t
        truth = np.array([soils[min(int((t - 1e-9) // stretch), 2)].k_s for t in t_any]) / 1e3
        for label, legend in labels:
            tr = run[label]
            ax.plot(tr.t, truth * (1 + tr.err / 100), lw=0.9, label=legend)
        ax.plot(t_any, truth, "k--", lw=1.0, label="true k_s")
        for k in (1, 2):
            ax.axvline(k * stretch, color="tab:red", lw=0.8, ls=":")
        ax.set_yscale("log")
        ax.set_ylim(80, 1e4)
        ax.set_ylabel("k_s (kN/m)")
        ax.set_title(panel_title, fontsize=9)
    axes[0, 0].legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time (s); dotted: soil changes")
    fig.suptitle(title, fontsize=10)
    return rep.save_figure(fig, name)


def case2(rep: Report, res: Results, counts: Counts) -> None:
    stretch = counts.stretch_s
    cells = [(road, speed) for road, speed in TABLE4_CELLS if res.get(_t4_key(road, speed))]
    if not cells:
        return
    n = len(res[_t4_key(*cells[0])])
    lines = [
        "## Case 2 — Table 4: 3-soil path, ISO B / D / F at 10 m/s and ISO D at 2 / 5 / 10 m/s (paper §5.2, "
        "Fig. 8, Fig. 9, Table 4)",
        "",
        f"Path: LETE sand (2283 kN/m) → Upland sandy loam (218.1 kN/m) → Graneville loam (651.1 kN/m), three "
        f"**equal stretches of {stretch:g} s of travel each** (so {stretch:g}·v m: "
        + ", ".join(f"{stretch * v:g} m at {v:g} m/s" for v in sorted({s for _, s in cells}))
        + f"; the paper gives no lengths), soil changes at t = {stretch:g} s and {2 * stretch:g} s. "
        f"**{n} runs per cell** (the same road realisations, in space, for every cell: ISO classes differ only "
        "in amplitude), SCKF as in case 1 (per-step k_tot random walk, no soil-change re-open: the paper's "
        "filter). Same start guess as case 1 (k_s,0 = 175 kN/m) on LETE sand.",
        "",
        "Metrics. **Average % error on the Graneville stretch** = mean over runs of the mean |e| over the whole "
        f"Graneville stretch ({2 * stretch:g} < t ≤ {3 * stretch:g} s), re-adaptation after the change included "
        '(Table 4\'s caption says "average percentage error", the text "relative percentage RMSE"; the RMSE '
        "over the same stretch is shown beside it). **Adaptation window** = time after a soil change until |e| "
        "stays below 5 % up to the end of that stretch; if it never does, the stretch length is counted (a lower "
        'bound, reported as censored); the "average" is over the two changes and the runs. '
        "The issue's requirement: \"SCKF's mean error at or below the paper's in every Table 4 cell\".",
        "",
        "| cell | paper (%) | SCKF mean \\|e\\| Graneville (%) | median | RMSE Graneville (%) | "
        "mean \\|e\\| 2nd half of Graneville (%) | mean \\|e\\| Upland (%) | mean \\|e\\| LETE (%) | "
        "adaptation window mean (s) | censored changes | ≤ paper? |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    metrics: dict[tuple[str, float], dict[str, dict[str, dict[str, float]]]] = {}
    for road, speed in cells:
        runs = res[_t4_key(road, speed)]
        metrics[(road, speed)] = {lab: path_metrics(runs, lab, stretch) for lab in runs[0]}
    for label, title in (
        ("sckf", "SCKF, per-step k_tot noise (default; headline)"),
        ("sckf_printed", "SCKF, printed Q_k (case 7)"),
        ("sckf_log", "SCKF with the ln k_s state (stiffness_state = log_k_s), no re-open"),
        (
            "sckf_project",
            "project estimator (node defaults): ln k_s state + soil-change detector and innovation-sized re-open "
            "(case 2b)",
        ),
    ):
        lines.append(f"| **{title}** | | | | | | | | | | |")
        for road, speed in cells:
            m = metrics[(road, speed)][label]
            paper = T4_PAPER[(road, speed)]
            g = m["graneville_mean"]
            ok = g["mean"] <= paper
            lines.append(
                f"| ISO {road}, {speed:g} m/s | {paper} | {_fmt(g['mean'])} ± {_fmt(g['std'])} | "
                f"{_fmt(g['median'])} | {_fmt(m['graneville_rmse']['mean'])} | "
                f"{_fmt(m['graneville_steady']['mean'])} | "
                f"{_fmt(m['upland_mean']['mean'])} | "
                f"{_fmt(m['lete_mean']['mean'])} | {_fmt(m['adapt']['mean'])} | {int(m['adapt']['censored'])} of "
                f"{2 * int(g['n'])} | {'yes' if ok else 'no'} |"
            )
            if label in ("sckf", "sckf_printed"):
                form = "" if label == "sckf" else " [printed Q_k]"
                case = "2" if label == "sckf" else "7"
                rep.row(
                    case,
                    f"Table 4 ISO {road}, {speed:g} m/s: SCKF mean error, Graneville{form} (%)",
                    g["mean"],
                    paper,
                    "<=",
                )
                if road in _ADAPT_PAPER and speed == 10.0:
                    rep.row(
                        case,
                        f"ISO {road}, 10 m/s: average adaptation window{form} (s)",
                        m["adapt"]["mean"],
                        _ADAPT_PAPER[road],
                        "<=",
                        censored=m["adapt"]["censored"] > 0,
                    )
                if label == "sckf" and not ok:
                    rep.not_reproduced.append(
                        f"- **Table 4, ISO {road} at {speed:g} m/s**: SCKF {_fmt(g['mean'])} % on the Graneville "
                        f"stretch vs the paper's {paper} % (median over runs {_fmt(g['median'])} %; over the second "
                        f"half of the stretch, after re-adaptation, {_fmt(m['graneville_steady']['mean'])} %). The "
                        'cell fails the "at or below the paper" requirement.'
                    )
    lines.append("")
    per_cell = [
        f"ISO {road} {speed:g} m/s: Upland {_fmt(metrics[(road, speed)]['sckf']['upland_settle']['mean'])} s, "
        f"Graneville {_fmt(metrics[(road, speed)]['sckf']['graneville_settle']['mean'])} s"
        for road, speed in cells
    ]
    lines += ["Adaptation window per change (SCKF, default noise, mean over runs): " + "; ".join(per_cell) + ".", ""]
    failing = [c for c in cells if metrics[c]["sckf"]["graneville_mean"]["mean"] > T4_PAPER[c]]
    if failing:
        parts = []
        for road, speed in failing:
            mc = metrics[(road, speed)]
            parts.append(
                f"ISO {road} {speed:g} m/s: whole stretch {_fmt(mc['sckf']['graneville_mean']['mean'])} %, second "
                f"half {_fmt(mc['sckf']['graneville_steady']['mean'])} %, project estimator whole stretch "
                f"{_fmt(mc['sckf_project']['graneville_mean']['mean'])} % (median "
                f"{_fmt(mc['sckf_project']['graneville_mean']['median'])} %), second half "
                f"{_fmt(mc['sckf_project']['graneville_steady']['median'])} % (median)"
            )
        detail = "; ".join(parts)
        rep.not_reproduced.append(
            "- **Why the Table 4 cells fail**: the Graneville stretch starts with the re-adaptation from Upland sandy "
            f"loam (k_s 218 → 651 kN/m). With the per-step k_tot random walk of {_QC_WALK:g} (N/m)² (this project's "
            "reconstruction of a Q_k whose printed form cannot re-adapt, MODELS.md A.4) the filter walks k_tot "
            "there over seconds, and that walk dominates the stretch mean. The paper's effective k_tot noise, its "
            f"stretch lengths and its averaging window are not stated. Per cell: {detail}. The printed Q_k rows "
            "(case 7) never follow the change to Upland sandy loam (mean |e| on the Upland stretch "
            + ", ".join(f"{_fmt(metrics[c]['sckf_printed']['upland_mean']['mean'])} %" for c in cells)
            + " for the cells in table order), so their Graneville numbers say nothing about re-adaptation."
        )
    for road in _ADAPT_PAPER:
        if (road, 10.0) in metrics:
            a = metrics[(road, 10.0)]["sckf"]["adapt"]["mean"]
            if a > _ADAPT_PAPER[road]:
                rep.not_reproduced.append(
                    f"- **Adaptation window, ISO {road}**: {_fmt(a)} s vs the paper's {_ADAPT_PAPER[road]} s"
                    + (
                        f" ({int(metrics[(road, 10.0)]['sckf']['adapt']['censored'])} of "
                        f"{2 * int(metrics[(road, 10.0)]['sckf']['graneville_mean']['n'])} changes never settle below "
                        "5 % within their stretch: a lower bound)"
                        if metrics[(road, 10.0)]["sckf"]["adapt"]["censored"] > 0
                        else ""
                    )
                    + ". The window is set by the k_tot random walk (MODELS.md A.4): the paper's printed Q_k cannot "
                    f"re-adapt at all and the per-step value {_QC_WALK:g} (N/m)² is this project's reconstruction; the "
                    "paper's effective value is unknown."
                )
    runs_10 = {road: res[_t4_key(road, 10.0)][0] for road in ("B", "D", "F") if res.get(_t4_key(road, 10.0))}
    runs_d = {s: res[_t4_key("D", s)][0] for s in (2.0, 5.0, 10.0) if res.get(_t4_key("D", s))}
    labels = (("sckf", "SCKF (per-step)"), ("sckf_printed", "SCKF (printed Q_k)"))
    p1, p2 = (
        _plot_path(rep, name, runs, labels, stretch, title)
        for name, runs, title in (
            (
                "table4_profiles.png",
                [(f"ISO {road}, 10 m/s, run 0", run) for road, run in runs_10.items()],
                "Case 2: k_s on LETE sand → Upland sandy loam → Graneville loam (cf. paper Fig. 8)",
            ),
            (
                "table4_speeds.png",
                [(f"ISO D, {s:g} m/s, run 0", run) for s, run in runs_d.items()],
                "Case 2: k_s on the 3-soil path, ISO D at 2 / 5 / 10 m/s (cf. paper Fig. 9)",
            ),
        )
    )
    lines += [rep.link(p1, "Table 4 profiles"), "", rep.link(p2, "Table 4 speeds"), ""]
    rep.add_section(lines)


# -- case 3 (LETE sand, ISO F) ------------------------------------------------------


# -- case 4 (Meadow-c) ----------------------------------------------------------------


def case4(rep: Report, res: Results, counts: Counts) -> None:
    runs = res.get("meadow", [])
    if not runs:
        return
    stretch = counts.stretch_s
    m = path_metrics(runs, "sckf", stretch)
    lines = [
        "## Case 4 — Mixed path on the Meadow-c stand-in, 10 m/s (paper §5.2, Fig. 7)",
        "",
        "Profile: Ohmiya's Meadow-c PSD was not found (MODELS.md A.8); the **documented stand-in** "
        "`meadow_c_standin` is ISO 8608 class E at its geometric mean (G_d(n0) = 4096·10⁻⁶ m³, w = 2), between "
        f'the paper\'s D and F cases as its "harsh" suggests. Same path, stretches ({stretch:g} s each), SCKF and '
        f'metrics as case 2; **{len(runs)} runs**. The paper reports an adaptation window of "a few seconds" at '
        'both changes and an error "mostly well under 5 %".',
        "",
        "| stretch | mean \\|e\\| (%) mean ± std | median | RMSE (%) | adaptation window (s) mean | median | "
        "censored |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, title in (
        ("lete", "LETE sand (from the start guess)"),
        ("upland", "Upland sandy loam"),
        ("graneville", "Graneville loam"),
    ):
        e, r, s = m[f"{name}_mean"], m[f"{name}_rmse"], m[f"{name}_settle"]
        lines.append(
            f"| {title} | {_ms(e)} | {_fmt(e['median'])} | {_fmt(r['mean'])} | {_fmt(s['mean'])} | "
            f"{_fmt(s['median'])} | {int(s['censored'])} of {int(s['n'])} |"
        )
        holds = rep.row(
            "4",
            f"Meadow-c stand-in: SCKF mean |e| on {title}, median over runs (%) (paper: < 5)",
            e["median"],
            5.0,
            "<",
        )
        if holds is False:
            rep.not_reproduced.append(
                f"- **Meadow-c, {title}**: median over runs of the stretch's mean |e| is {_fmt(e['median'])} %, "
                f"not under 5 % (second half of the stretch: mean {_fmt(m[name + '_steady']['mean'])} %, median "
                f"{_fmt(m[name + '_steady']['median'])} %). "
                + (
                    "On LETE sand every k_tot error is amplified ×14 in k_s (MODELS.md A.2) and the stretch starts "
                    "from the start guess."
                    if name == "lete"
                    else "The stretch mean includes the re-adaptation after the soil change, which the per-step "
                    "k_tot random walk (MODELS.md A.4) makes take seconds."
                )
                + " The stand-in PSD is not Ohmiya's."
            )
    rep.row(
        "4",
        'Meadow-c stand-in: adaptation window, mean of the two changes (s) (paper: "a few")',
        m["adapt"]["mean"],
        3.0,
        "info",
    )
    lines.append("")
    p = _plot_path(
        rep,
        "meadow_c.png",
        [("Meadow-c stand-in (ISO E), 10 m/s, run 0", runs[0])],
        (("sckf", "SCKF"),),
        stretch,
        "Case 4: SCKF on the mixed path (cf. paper Fig. 7)",
    )
    # add the error panel like the paper's lower plot
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 2.8))
    tr = runs[0]["sckf"]
    ax.plot(tr.t, np.abs(tr.err), "k", lw=0.8)
    ax.axhline(5.0, color="tab:red", ls=":", lw=1)
    for k in (1, 2):
        ax.axvline(k * stretch, color="tab:red", lw=0.8, ls=":")
    ax.set_yscale("log")
    ax.set_ylabel("|error| (%)")
    ax.set_xlabel("time (s)")
    ax.set_title("Case 4, run 0: relative error of k_s (dotted: 5 % and soil changes)", fontsize=9)
    p2 = rep.save_figure(fig, "meadow_c_error.png")
    lines += [rep.link(p, "Meadow-c path"), "", rep.link(p2, "Meadow-c error"), ""]
    rep.add_section(lines)


_T4_BOUNDS: dict[tuple[str, float, int, float], tuple[float, float]] = {}


def table4_bound(road: str, speed: float, n_roads: int, stretch: float) -> tuple[float, float]:
    """PCRLB of a fresh start on Graneville loam for one Table 4 cell: (mean over the stretch, at its end), in %.

    ``pcrlb_quarter_car`` over one stretch, started with the estimator's P0,
    averaged over the first ``n_roads`` Table 4 roads (cached per process).
    """
    key = (road, speed, n_roads, stretch)
    if key not in _T4_BOUNDS:
        from terrain_analysis.pcrlb import pcrlb_quarter_car

        gran = SoilPath([(0.0, soil_by_name("graneville_loam"))])
        scenario = Scenario(profile=iso8608_profile(road, 0), soil_path=gran, speed=SpeedProfile.constant(speed))

        def road_of(seed_offset: int) -> RoadProfile:
            return iso8608_profile(road, run_seeds(_GROUP_TABLE4, seed_offset)[0])

        b = pcrlb_quarter_car(scenario=scenario, n_runs=n_roads, duration=stretch, seed=0, road=road_of)
        rel = 100.0 * np.asarray(b.k_s_relative_std)
        _T4_BOUNDS[key] = (float(np.mean(rel[1:])), float(rel[-1]))
    return _T4_BOUNDS[key]


def table4_bounds(rep: Report, res: Results, counts: Counts) -> None:
    """The information limit of each Table 4 cell: PCRLB of a fresh start on the Graneville stretch."""
    cells = [c for c in TABLE4_CELLS if _t4_key(*c) in res]
    if not cells:
        return
    n_roads = max(1, min(counts.table4, 8))
    stretch = counts.stretch_s
    lines = [
        "## Case 6b — The information limit of each Table 4 cell",
        "",
        "How small can the Graneville-stretch error be at all? Bound: `pcrlb_quarter_car` on Graneville loam alone "
        f"at the cell's road class and speed for one stretch ({stretch:g} s), started with the estimator's P0 "
        "(k_tot std 50 kN/m) as if the filter were re-started at the soil change — the most favourable reading "
        "of a re-adaptation — averaged over the first "
        f"{n_roads} Table 4 roads. Reported: the relative std bound of k_s at the end of the stretch and its mean "
        "over the stretch, which bounds the stretch RMSE of any estimator that believes the filter's model "
        "(per-step k_tot walk, Q, R). The bound uses the exact road (no profile noise), so the true limit is "
        "higher, most on the smoothest road (ISO B), where the 0.1 mm profile noise is largest relative to the "
        "road. A mean |e| of a Gaussian error is 0.8 of its RMSE.",
        "",
        "| cell | paper (%) | bound, mean over the stretch (%) | bound at its end (%) | SCKF RMSE Graneville "
        "(%) | project estimator RMSE Graneville, median over runs (%) | paper below the bound? |",
        "|---|---|---|---|---|---|---|",
    ]
    for road, speed in cells:
        mean_bound, end_bound = table4_bound(road, speed, n_roads, stretch)
        runs = res[_t4_key(road, speed)]
        t0, t1 = 2 * stretch + _HALF_STEP, 3 * stretch
        sckf = _stats([rmse(r["sckf"], t0, t1) for r in runs])
        proj = _stats([rmse(r["sckf_project"], t0, t1) for r in runs]) if "sckf_project" in runs[0] else None
        paper = T4_PAPER[(road, speed)]
        lines.append(
            f"| ISO {road}, {speed:g} m/s | {paper} | {_fmt(mean_bound)} | {_fmt(end_bound)} | {_fmt(sckf['mean'])} | "
            f"{_fmt(proj['median']) if proj else '—'} | {'yes' if paper < 0.8 * mean_bound else 'no'} |"
        )
        rep.row(
            "6b",
            f"Table 4 ISO {road}, {speed:g} m/s: PCRLB of the Graneville stretch, mean over it (%) (paper's value "
            "beside)",
            mean_bound,
            paper,
            "info",
        )
    lines += [
        "",
        "Read: where the paper's average error is close to 0.8 × the mean bound, the paper's filter re-adapted as "
        "fast as a fresh start with a perfect estimator would, from the first sample after the change. The "
        "SCKF here (no re-open) spends seconds walking k_tot to the new soil, which the bound does not charge.",
        "",
    ]
    rep.add_section(lines)
