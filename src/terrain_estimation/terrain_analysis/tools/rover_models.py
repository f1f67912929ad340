"""The rover reproduction's terrain-response models: the true model (surrogate), Tables VI and VII, stated errors.

Part of :mod:`terrain_analysis.tools.reproduce_rover`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from terrain_analysis.reporting import format_number as _fmt
from terrain_analysis.reporting import pyplot as _plt
from terrain_analysis.tools.rover_fits import (
    ModelFit,
    convex_hull,
    fit_bias,
    model_fits,
    region_grid,
    true_forces,
    truth_fit_rms,
    truth_samples,
)
from terrain_analysis.tools.rover_model_error import online_lines, online_summary, stated_vs_true_lines
from terrain_analysis.tools.rover_plan import (
    ALL_VARIANTS,
    COEFFICIENT_NAMES,
    FIT_TERRAINS,
    PAPER_SURROGATE_RANGE,
    PAPER_SURROGATE_RMS,
    PAPER_TABLE6,
    PAPER_TABLE7,
    TERRAIN_IDS,
    VARIANT_BASE,
    VARIANT_NAMES,
    VARIANTS,
    Counts,
)
from terrain_analysis.tools.rover_report import RoverReport, mean_std, sig, terrain_label
from terrain_analysis.tools.rover_runs import FloatArray, Results
from terrain_estimation.estimators.rover import TerrainResponseConfig
from terrain_estimation.models.rover import RoverParams
from terrain_estimation.models.terrain_response import PolynomialModel2D
from vehicle_sim.terrain.terramechanics_surrogate import TerramechanicsSurrogate

__all__ = ["section_surrogate", "section_tables67"]


def section_surrogate(rr: RoverReport, surrogate: TerramechanicsSurrogate) -> None:
    lines = [
        "## The true model: 4th-order global surrogate of the Wong–Reece wheel",
        "",
        "`terramechanics_surrogate()`: Table II soil, Kapvik wheel (r_w = 75 mm, b_w = 70 mm), full model on a "
        "100×100 grid over 0 ≤ i ≤ 1, 0.1 ≤ W ≤ 200 N, 4th-order fits with equal weights (MODELS.md C.2).",
        "",
        "| quantity | RMS over the grid | paper | full-model range on the grid | paper |",
        "|---|---|---|---|---|",
        f"| DP (N) | {surrogate.drawbar_pull_rms:.4f} | {PAPER_SURROGATE_RMS['dp']:g} | "
        f"{surrogate.drawbar_pull_range[0]:.3f} … {surrogate.drawbar_pull_range[1]:.3f} | "
        f"{PAPER_SURROGATE_RANGE['dp'][0]:g} … {PAPER_SURROGATE_RANGE['dp'][1]:g} |",
        f"| τ_R (N·m) | {surrogate.resistive_torque_rms:.6f} | {PAPER_SURROGATE_RMS['tau']:g} | "
        f"{surrogate.resistive_torque_range[0]:.3f} … {surrogate.resistive_torque_range[1]:.3f} | "
        f"{PAPER_SURROGATE_RANGE['tau'][0]:g} … {PAPER_SURROGATE_RANGE['tau'][1]:g} |",
        "",
    ]
    rr.rep.add_section(lines)
    rr.claim(
        "surrogate",
        "4th-order surrogate RMS, DP (N)",
        surrogate.drawbar_pull_rms,
        f"{PAPER_SURROGATE_RMS['dp']:g}",
        "computed ≤ paper",
        surrogate.drawbar_pull_rms <= PAPER_SURROGATE_RMS["dp"],
    )
    rr.claim(
        "surrogate",
        "4th-order surrogate RMS, τ_R (N·m)",
        surrogate.resistive_torque_rms,
        f"{PAPER_SURROGATE_RMS['tau']:g}",
        "computed ≤ paper",
        surrogate.resistive_torque_rms <= PAPER_SURROGATE_RMS["tau"],
    )
    rr.claim(
        "surrogate",
        "full-model DP maximum on the grid (N)",
        surrogate.drawbar_pull_range[1],
        f"{PAPER_SURROGATE_RANGE['dp'][1]:g}",
        "—",
        None,
    )


def _coef_row(label: str, models: Sequence[PolynomialModel2D]) -> str:
    c = np.array([m.coefficients for m in models], dtype=float)
    return f"| {label} | " + " | ".join(mean_std(c[:, k]) for k in range(c.shape[1])) + " |"


def _paper_row(label: str, values: Sequence[float]) -> str:
    return f"| *{label}* | " + " | ".join(f"{x:g}" for x in values) + " |"


_PAPER_ROWS = {"local": "paper local model", "e2": "paper fit, E1+E2", "e3": "paper fit, E1+E3"}


def _coef_table(title: str, by_v: dict[str, list[ModelFit]], key: str, paper: Sequence[str]) -> list[str]:
    """Table VI for one quantity (``key``: dp | tau): the local model, every variant's fit, the paper's rows."""
    return [
        title,
        "",
        "| model | " + " | ".join(COEFFICIENT_NAMES) + " |",
        "|---|---|---|---|---|---|---|",
        _coef_row(
            "local model (true 4th-order model, 2nd-order fit)", [getattr(f, f"{key}_local") for f in by_v["e2"]]
        ),
        *(_coef_row(f"fit, {VARIANT_NAMES[v]}", [getattr(f, key) for f in by_v[v]]) for v in ALL_VARIANTS),
        *(_paper_row(_PAPER_ROWS[p], PAPER_TABLE6[f"{key}.{p}"]) for p in paper),
        "",
    ]


def section_tables67(rr: RoverReport, res: Results, counts: Counts, surrogate: TerramechanicsSurrogate) -> None:
    fits = model_fits(res, surrogate)
    rr.notes["fits"] = fits
    if not fits:
        rr.rep.sections.append("## Tables VI and VII\n\nNo fit: too few 2-s samples from terrains 1–5.\n")
        return
    by_v = {v: [fits[k] for k in sorted(fits) if k[1] == v] for v in ALL_VARIANTS}
    n_fits = min(len(f) for f in by_v.values())
    if n_fits == 0:
        rr.rep.sections.append("## Tables VI and VII\n\nNo fit for some variant: too few 2-s samples.\n")
        return
    acc_lines = [
        "| terrain | "
        + " | ".join(f"{VARIANT_NAMES[v]}: buckets / used / rejected κ ≥ 1/l_w / sparse / slow" for v in VARIANTS)
        + " | truth max \\|κ_t\\| (1/m) |",
        "|---|---|---|---|",
    ]
    for n in TERRAIN_IDS:
        if n not in res.terrains:
            continue
        d = res.terrains[n]
        cells = []
        for v in VARIANTS:
            c = [d.series[(i, v)].accumulator for i in range(len(d.seeds))]
            keys = ("buckets", "buckets_used", "rejected_curvature", "rejected_sparse", "rejected_speed")
            cells.append(" / ".join(f"{np.mean([x[k] for x in c]):.1f}" for k in keys))
        acc_lines.append(
            f"| {terrain_label(res, n)}{' (not fitted)' if n not in FIT_TERRAINS else ''} | "
            + " | ".join(cells)
            + f" | {_fmt(float(np.max(np.abs(d.truth['terrain_curvature']))), 2)} |"
        )
    regions = {v: [f.region for f in by_v[v]] for v in VARIANTS}
    truth_s = truth_samples(res, FIT_TERRAINS)
    lines = [
        "## Table VI — 2nd-order terrain-response models from the estimates (terrains 1–5)",
        "",
        f"Per run index (the same seed index on every terrain) and variant: the 5 Hz estimates of terrains 1–5 "
        "(initialisation dropped) go through a `TerrainResponseAccumulator` with its defaults per terrain run — "
        "one averaged sample per wheel per 2 s, a bucket rejected when its curvature estimate (|dγ/ds| from the "
        "estimated contact angles, the accumulator's own, no truth) is ≥ 1/l_w = "
        f"{1 / RoverParams().wheelbase:.2f} m⁻¹ — and the samples of the five terrains are pooled and fitted with "
        "`fit_polynomial_2d` (order 2, equal weights: the accumulator's own fit, applied to the pooled samples). "
        f"**{n_fits} fit(s) per variant**; coefficients mean ± std over runs. Terrain 6 is excluded as in the "
        "paper (its samples are also counted below).",
        "",
        "The **true model** is the 4th-order global surrogate the plant's soil runs on (`terramechanics_surrogate()`, "
        "Table II soil, Kapvik wheel); the **local model** is a 2nd-order fit to a 100×100 grid of the true model "
        "over the traversed region = the rectangle of the fitted samples' (i, W) (per run and variant; the row "
        "shows the E1+E2 region's). Term order p00, p10, p01, p20, p11, p02 of p_kl i^k W^l (i in –, W in N).",
        "",
        "Accumulator per terrain (mean over runs; the defaults' estimates): 2-s buckets / used / rejected by the "
        "curvature gate / too few estimates / too slow:",
        "",
        *acc_lines,
        "",
        "Traversed region (mean over runs): "
        + "; ".join(
            f"{VARIANT_NAMES[v]} i ∈ [{np.mean([r.slip_min for r in regions[v]]):.3f}, "
            f"{np.mean([r.slip_max for r in regions[v]]):.3f}], W ∈ [{np.mean([r.load_min for r in regions[v]]):.1f}, "
            f"{np.mean([r.load_max for r in regions[v]]):.1f}] N, "
            f"{np.mean([f.samples['slip'].size for f in by_v[v]]):.0f} samples"
            for v in VARIANTS
        )
        + (
            f". The truth averaged the same way spans i ∈ [{truth_s['slip'].min():.3f}, {truth_s['slip'].max():.3f}], "
            f"W ∈ [{truth_s['normal_load'].min():.1f}, {truth_s['normal_load'].max():.1f}] N."
            if truth_s["slip"].size
            else "."
        ),
        "",
        *_coef_table("**τ_R(W, i) (N·m)**", by_v, "tau", ("local", "e2")),
        *_coef_table("**DP(W, i) (N)**", by_v, "dp", ("local", "e2", "e3")),
        "Individual coefficients of a 2nd-order fit over a narrow W range are strongly correlated (p00, p01 and "
        "p02 trade off against each other), so they differ between fits that agree closely on the region; "
        "Table VII compares the models themselves.",
        "",
        _fig_fit_surfaces(rr, res, fits, surrogate),
        "",
    ]
    rr.rep.add_section(lines)
    for v, key in (("e2", "dp.e2"), ("e3", "dp.e3")):
        for k, name in ((1, "p10"), (3, "p20")):
            rr.claim(
                "Table VI",
                f"DP fit {VARIANT_NAMES[v]} {name}",
                float(np.mean([f.dp.coefficients[k] for f in by_v[v]])),
                f"{PAPER_TABLE6[key][k]:g}",
                "—",
                None,
            )
    rr.claim(
        "Table VI",
        "DP local model p10",
        float(np.mean([f.dp_local.coefficients[1] for f in by_v["e2"]])),
        f"{PAPER_TABLE6['dp.local'][1]:g}",
        "—",
        None,
    )
    rr.claim(
        "Table VI",
        "τ_R fit E1+E2 p10",
        float(np.mean([f.tau.coefficients[1] for f in by_v["e2"]])),
        f"{PAPER_TABLE6['tau.e2'][1]:g}",
        "—",
        None,
    )
    # Table VII.
    lines = [
        "## Table VII — RMS of the estimated 2nd-order models against the true model",
        "",
        "Over a 100×100 grid of the traversed region (the fitted samples' (i, W) rectangle, per run and variant); "
        "mean ± std over runs. The local model's RMS is the floor a 2nd-order model can reach over the same "
        "region. Inside / outside: grid points inside the convex hull of the fitted (i, W) samples and the rest "
        "of the rectangle ([RB]: errors largest at the edge of the traversed region, smallest near the data).",
        "",
        "| estimators | τ_R (N·m) | paper | DP (N) | paper | τ_R local model | DP local model | τ_R inside / outside "
        "hull | DP inside / outside hull | grid inside hull |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for v in ALL_VARIANTS:
        f = by_v[v]

        def r(key: str, fits_: list[ModelFit] = f) -> list[float]:
            return [x.rms[key] for x in fits_]

        paper7 = PAPER_TABLE7[VARIANT_BASE[v]]
        lines.append(
            f"| {VARIANT_NAMES[v]} | {mean_std(r('tau'))} | {paper7[0]:g} | {mean_std(r('dp'))} | "
            f"{paper7[1]:g} | {mean_std(r('tau_local'))} | {mean_std(r('dp_local'))} | "
            f"{sig(float(np.nanmean(r('tau_in'))))} / {sig(float(np.nanmean(r('tau_out'))))} | "
            f"{sig(float(np.nanmean(r('dp_in'))))} / {sig(float(np.nanmean(r('dp_out'))))} | "
            f"{100 * np.mean([x.hull_fraction for x in f]):.0f} % |"
        )
    truth_fit = truth_fit_rms(truth_s, by_v["e2"], surrogate)
    rr.notes["truth_fit"] = truth_fit
    if truth_fit is not None:
        lines.append(
            f"| *reference: fit to the true (i, W, DP, τ_R) averaged to 2 s (no estimation error), E1+E2 region* | "
            f"{sig(truth_fit[0])} | — | {sig(truth_fit[1])} | — | | | | | |"
        )
    bias = {v: fit_bias(res, v) for v in ALL_VARIANTS}
    rr.notes["fit_bias"] = bias
    lines += [
        "",
        "Mean error of the fitted 2-s samples against the truth averaged over the same buckets is not available "
        "from the accumulator (it keeps no truth); the mean 5 Hz estimate error over terrains 1–5 (all wheels, "
        "all runs) is: "
        + "; ".join(
            f"{VARIANT_NAMES[v]} DP {bias[v]['drawbar_pull']:+.3f} N, τ_R {bias[v]['resistive_torque']:+.4f} N·m, "
            f"W {bias[v]['normal_load']:+.3f} N, i {bias[v]['slip']:+.4f}"
            for v in ALL_VARIANTS
        )
        + " — a bias of the estimates moves the fitted surface by about as much.",
        "",
        _fig_fit_errors(rr, fits, surrogate),
        "",
    ]
    rr.rep.add_section(lines)
    for v in ALL_VARIANTS:
        f = by_v[v]
        tau_rms = float(np.mean([x.rms["tau"] for x in f]))
        dp_rms = float(np.mean([x.rms["dp"] for x in f]))
        paper7 = PAPER_TABLE7[VARIANT_BASE[v]]
        rr.claim(
            "Table VII",
            f"{VARIANT_NAMES[v]}: τ_R model RMS vs true model (N·m)",
            tau_rms,
            f"{paper7[0]:g}",
            "computed ≤ paper",
            tau_rms <= paper7[0],
        )
        rr.claim(
            "Table VII",
            f"{VARIANT_NAMES[v]}: DP model RMS vs true model (N)",
            dp_rms,
            f"{paper7[1]:g}",
            "computed ≤ paper",
            dp_rms <= paper7[1],
        )
    _section_model_error(rr, res, by_v, surrogate)
    for q, name in (("dp", "DP"), ("tau", "τ_R")):
        f = by_v["e2"]
        ratio = float(np.nanmean([x.rms[f"{q}_in"] for x in f]) / np.nanmean([x.rms[f"{q}_out"] for x in f]))
        rr.claim(
            "Table VII",
            f"E1+E2 {name} model RMS inside / outside the data hull",
            ratio,
            "< 1 (errors largest at the edge, smallest near the data)",
            "< 1",
            ratio < 1.0,
        )


def _section_model_error(
    rr: RoverReport, res: Results, by_v: dict[str, list[ModelFit]], surrogate: TerramechanicsSurrogate
) -> None:
    """Table VII's stated error against the true error, and the online models' error and jumps (issue 21, item 3)."""
    units = {"dp": "N", "tau": "N·m"}
    stated = {VARIANT_NAMES[v]: [f.stated for f in by_v[v]] for v in ALL_VARIANTS}
    blocks = TerrainResponseConfig().validation_blocks
    lines = [
        "### The models' stated error against their true error (Table VII fits)",
        "",
        "`TerrainResponseModel` states each model's error (`models/terrain_response_error.py`): the "
        f"coefficients' covariance Σ from a delete-a-block jackknife over {blocks} contiguous blocks of 2-s "
        "sample periods (each terrain's periods apart), the **held-out RMS** (every sample predicted by the fit "
        "that left its block out), the **estimate RMS** (√ of the mean variance the estimator states for the "
        "fitted 2-s samples: an error the samples share, e.g. a bias lasting a run, which no hold-out sees), the "
        "stated error of the model's value σ(i, W) = √(held-out² + estimate² + xᵀΣx) (Σ and held-out² scaled "
        "by ν/(ν − 2) for the ν = blocks − 1 degrees of freedom they rest on), and its RMS over the validity "
        "rectangle, the **stated** (`dp_prediction_rms`). True RMS: the model against the "
        "true model over the same 100×100 grid as Table VII; *within 2σ*: share of grid points with "
        "|model − true| ≤ 2 σ(i, W). The fit residual is what `dp_rms` stated alone before. Mean over runs.",
        "",
        *stated_vs_true_lines(stated, units),
        "",
    ]
    for v in ALL_VARIANTS:
        for key, name in (("dp", "DP"), ("tau", "τ_R")):
            e = [f.stated[key] for f in by_v[v] if key in f.stated]
            if not e:
                continue
            ratio = float(np.mean([x.true_rms / x.stated_rms for x in e]))
            rr.claim(
                "Table VII",
                f"{VARIANT_NAMES[v]}: {name} model true RMS / stated prediction RMS",
                ratio,
                "— (issue 21: the stated error covers the true error)",
                "≤ 1",
                ratio <= 1.0,
            )
            within = float(np.mean([x.within_2sigma for x in e]))
            rr.claim(
                "Table VII",
                f"{VARIANT_NAMES[v]}: {name} model, grid points with |error| ≤ 2 stated σ(i, W)",
                within,
                "—",
                "≥ 0.9",
                within >= 0.9,
            )

    def truth(slip: FloatArray, load: FloatArray) -> tuple[FloatArray, FloatArray]:
        return true_forces(surrogate, slip, load)

    online: dict[str, list[tuple[str, str, Any]]] = {"dp": [], "tau": []}
    overall: dict[tuple[str, str], Any] = {}
    for v in VARIANTS:
        for key in ("dp", "tau"):
            all_runs = []
            for n in FIT_TERRAINS:
                if n not in res.terrains:
                    continue
                d = res.terrains[n]
                runs = [d.series[(i, v)].fits for i in range(len(d.seeds))]
                all_runs += runs
                online[key].append((terrain_label(res, n), VARIANT_NAMES[v], online_summary(runs, truth, key)))
            overall[(v, key)] = online_summary(all_runs, truth, key)
            online[key].append(("all (1–5)", VARIANT_NAMES[v], overall[(v, key)]))
    lines += [
        "### The online models: stated error, true error, jumps",
        "",
        "Every model the accumulator publishes during each terrain run (defaults: a refit at each kept 2-s "
        "period as the node does with `fit_every = 1`, 10 blocks, `max_jump = 1`), against the true model over "
        "its own validity rectangle (30×30 grid), over all runs. *true / stated*: mean over the models; "
        "*jumps*: each model against the one before, relative to the previous model's stated uncertainty — per "
        "coefficient |Δp_k|/σ_k, and over the previous rectangle |ΔDP(i, W)|/σ_f with σ_f = √(xᵀΣx) (the "
        "coefficients' part only: the stricter test); *unbounded fit*: the Mahalanobis distance of the new "
        "least-squares fit from the previous model before the step is bounded; *bounded*: share of models "
        "whose step was shortened (the remaining offset then enters their covariance).",
        "",
        "**DP (N)**",
        "",
        *online_lines(online["dp"], "N"),
        "",
        "**τ_R (N·m)**",
        "",
        *online_lines(online["tau"], "N·m"),
        "",
    ]
    rr.rep.add_section(lines)
    rr.notes["online_model_error"] = overall
    for v in VARIANTS:
        s = overall.get((v, "dp"))
        if s is None:
            continue
        rr.claim(
            "model error",
            f"{VARIANT_NAMES[v]} online DP models: largest jump / previous stated σ (per coefficient)",
            s.jump_coefficient_max,
            "— (issue 21: p10 jumped −8.7 → −3.1 in 2 s)",
            "≤ 1",
            s.jump_coefficient_max <= 1.0 + 1e-9,
        )
        rr.claim(
            "model error",
            f"{VARIANT_NAMES[v]} online DP models: mean true RMS / stated prediction RMS",
            s.ratio_true_stated,
            "— (issue 21: true 0.61 N against a stated residual 0.167 N, 3.6×)",
            "≤ 1",
            s.ratio_true_stated <= 1.0,
        )
        rr.claim(
            "model error",
            f"{VARIANT_NAMES[v]} online DP models: mean true RMS / fit residual (the old statement)",
            s.ratio_true_residual,
            "—",
            "—",
            None,
        )


def _fig_fit_surfaces(
    rr: RoverReport, res: Results, fits: dict[tuple[int, str], ModelFit], surrogate: TerramechanicsSurrogate
) -> str:
    plt = _plt()
    f2 = fits.get((0, "e2")) or next(iter(fits.values()))
    gi, gw = region_grid(f2.region)
    dp_true, tau_true = true_forces(surrogate, gi, gw)
    fig, axes = plt.subplots(2, 3, figsize=(14, 8), sharex=True, sharey=True)
    for row, (key, true_vals, unit) in enumerate((("dp", dp_true, "DP (N)"), ("tau", tau_true, "τ_R (N·m)"))):
        panels: list[tuple[str, Any, dict[str, FloatArray] | None]] = [
            ("true model (4th-order surrogate)", true_vals, None)
        ]
        for v in VARIANTS:
            f = fits.get((0, v))
            if f is None:
                continue
            model = f.dp if key == "dp" else f.tau
            panels.append((f"2nd-order fit, {VARIANT_NAMES[v]}", model.evaluate(gi, gw), f.samples))
        levels = np.linspace(float(np.min(true_vals)), float(np.max(true_vals)), 13)
        for col, (title, vals, samples) in enumerate(panels[:3]):
            ax = axes[row, col]
            cs = ax.contourf(gw, gi, vals, levels=levels, cmap="viridis", extend="both")
            ax.contour(gw, gi, true_vals, levels=levels, colors="w", linewidths=0.5, alpha=0.6)
            if samples is not None:
                ax.scatter(samples["normal_load"], samples["slip"], s=5, c="k", alpha=0.6, label="2-s samples")
                ax.legend(fontsize=7, loc="upper right")
            ax.set_title(f"{unit}: {title}", fontsize=9)
            if row == 1:
                ax.set_xlabel("normal load W (N)")
            if col == 0:
                ax.set_ylabel("slip i")
            fig.colorbar(cs, ax=ax, shrink=0.85)
    fig.suptitle(
        "Run 0: fitted DP(W, i) and τ_R(W, i) over the traversed region (white lines: true model contours)", fontsize=10
    )
    return rr.figure(fig, "fit_surfaces.png", "fitted terrain-response surfaces", dpi=100)


def _fig_fit_errors(rr: RoverReport, fits: dict[tuple[int, str], ModelFit], surrogate: TerramechanicsSurrogate) -> str:
    plt = _plt()
    fig, axes = plt.subplots(2, 2, figsize=(11, 8), sharey=True)
    for col, v in enumerate(VARIANTS):
        f = fits.get((0, v)) or next(iter(fits.values()))
        gi, gw = region_grid(f.region)
        dp_true, tau_true = true_forces(surrogate, gi, gw)
        hull = convex_hull(np.column_stack([f.samples["slip"], f.samples["normal_load"]]))
        for row, (err, unit) in enumerate(
            ((f.dp.evaluate(gi, gw) - dp_true, "DP error (N)"), (f.tau.evaluate(gi, gw) - tau_true, "τ_R error (N·m)"))
        ):
            ax = axes[row, col]
            lim = float(np.max(np.abs(err))) or 1.0
            cs = ax.contourf(gw, gi, err, levels=np.linspace(-lim, lim, 21), cmap="RdBu_r")
            ax.scatter(f.samples["normal_load"], f.samples["slip"], s=4, c="k", alpha=0.5)
            if hull.shape[0] >= 3:
                closed = np.vstack([hull, hull[:1]])
                ax.plot(closed[:, 1], closed[:, 0], "k-", lw=0.8)
            ax.set_title(f"{VARIANT_NAMES[v]}: {unit}, fit − true model", fontsize=9)
            ax.set_xlabel("normal load W (N)")
            if col == 0:
                ax.set_ylabel("slip i")
            fig.colorbar(cs, ax=ax, shrink=0.85)
    fig.suptitle("Run 0: error of the 2nd-order models over the traversed region (line: hull of the data)", fontsize=10)
    return rr.figure(fig, "fit_errors.png", "model errors over the traversed region", dpi=100)
