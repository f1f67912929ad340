"""Rover results page, section "Consistency": every published variance against its error on the truth runs (issue 21).

For each terrain of Fig. 10 (all nominal plants), estimator variant and
published quantity of ``terrain_msgs/WheelTerrain`` (slip, W, DP, τ_R, γ),
pooled over the three wheels and the sensor-noise runs, with the estimates
the estimator flags ``settled`` (``WheelTerrainArray.settled``) against the
truth at their stamps:

* mean e²/σ² (1 when the variance is right; < 1 cautious, > 1 over-confident)
  and the share of errors within 2σ (95.4 % for a Gaussian error), the
  criteria of issue 21 being [0.5, 2] and 90–98 %;
* the NEES of the five quantities of one wheel with the published (diagonal)
  variances, its mean against the χ²₅ band of the mean with the effective
  sample count (:func:`~terrain_estimation.analysis.consistency.consistency_report`,
  Geyer's autocorrelation time: estimation errors at 5 Hz are far from white).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.tools.rover_runs import stamp_indices
from terrain_estimation.analysis.consistency import consistency_report

__all__ = ["QUANTITIES", "consistency_figures", "criteria_hold", "section_consistency"]

#: Published quantities, in WheelTerrain order of the report, with symbol and unit.
QUANTITIES: tuple[tuple[str, str, str], ...] = (
    ("slip", "i", "–"),
    ("normal_load", "W", "N"),
    ("drawbar_pull", "DP", "N"),
    ("resistive_torque", "τ_R", "N·m"),
    ("contact_angle", "γ", "rad"),
)
#: Issue 21's criteria: mean e²/σ² and share within 2σ.
E2S2_BAND = (0.5, 2.0)
WITHIN_BAND = (0.90, 0.98)


def consistency_figures(res: Any, terrains: Sequence[int], variant: str) -> dict[str, Any]:
    """Pooled figures of one variant over ``terrains``: per quantity (e²/σ², within 2σ, samples), NEES, band, τ."""
    errors: list[NDArray[np.float64]] = []
    variances: list[NDArray[np.float64]] = []
    times: list[NDArray[np.float64]] = []
    offset = 0.0
    for n in terrains:
        data = res.terrains[n]
        for i in range(len(data.seeds)):
            s = data.series.get((i, variant))
            if s is None or not s.variances or s.t.size == 0:
                continue
            idx, ok = stamp_indices(data.time, s.t)
            keep = ok & s.settled
            if not np.any(keep):
                continue
            k = idx[keep]
            for j in range(3):
                e = np.column_stack([s.values[q][keep, j] - data.truth[q][k, j] for q, *_ in QUANTITIES])
                v = np.column_stack([s.variances[q][keep, j] for q, *_ in QUANTITIES])
                errors.append(e)
                variances.append(v)
                times.append(s.t[keep] + offset)
                offset += float(data.time[-1]) + 10.0
    if not errors:
        return {}
    e = np.vstack(errors)
    v = np.vstack(variances)
    t = np.concatenate(times)
    cov = np.zeros((v.shape[0], v.shape[1], v.shape[1]))
    idx = np.arange(v.shape[1])
    cov[:, idx, idx] = v
    report = consistency_report(t, e, cov, [q for q, *_ in QUANTITIES])
    return {
        "quantities": {q.name: q for q in report.quantities},
        "mean_nees": report.mean_nees,
        "nees_band": report.nees_band,
        "samples": int(e.shape[0]),
    }


def criteria_hold(mean_normalised: float, within: float) -> bool:
    """Issue 21: mean e²/σ² in [0.5, 2] and 90–98 % within 2σ."""
    return E2S2_BAND[0] <= mean_normalised <= E2S2_BAND[1] and WITHIN_BAND[0] <= within <= WITHIN_BAND[1]


def _terrain_misses(
    rr: Any, per_terrain: dict[tuple[int, str], dict[str, Any]], terrains: Sequence[int], variant: str, name: str
) -> list[str]:
    """One claim (cells meeting the criteria, of the terrain × quantity cells of ``variant``) and the misses,
    grouped by terrain into cautious (e²/σ² below the band or too many within 2σ) and over-confident."""
    met, total = 0, 0
    lines: list[str] = []
    for n in terrains:
        fig = per_terrain.get((n, variant))
        if not fig:
            continue
        cautious: list[str] = []
        confident: list[str] = []
        for q, sym, _ in QUANTITIES:
            qc = fig["quantities"][q]
            if not math.isfinite(qc.mean_normalised):
                continue
            total += 1
            if criteria_hold(qc.mean_normalised, qc.within_2sigma):
                met += 1
                continue
            cell = f"{sym} {qc.mean_normalised:.2g} / {100 * qc.within_2sigma:.0f} %"
            too_wide = qc.mean_normalised < E2S2_BAND[0] or qc.within_2sigma > WITHIN_BAND[1]
            (cautious if too_wide and qc.mean_normalised <= E2S2_BAND[1] else confident).append(cell)
        parts = [
            f"{kind}: {', '.join(cells)}"
            for kind, cells in (("cautious", cautious), ("over-confident", confident))
            if cells
        ]
        if parts:
            lines.append(f"- {name}, terrain {n}: {'; '.join(parts)}.")
    if total:
        rr.claim(
            f"consistency, {name}",
            "terrain × quantity cells meeting both criteria",
            met / total,
            "— (issue 21)",
            "every cell (each terrain is a nominal scenario)",
            met == total,
        )
    return lines


def _cell(fig: dict[str, Any], q: str) -> str:
    if not fig:
        return "—"
    qc = fig["quantities"][q]
    if not math.isfinite(qc.mean_normalised):
        return "—"
    mark = "" if criteria_hold(qc.mean_normalised, qc.within_2sigma) else " ✗"
    return f"{qc.mean_normalised:.2g} / {100 * qc.within_2sigma:.0f} %{mark}"


def section_consistency(rr: Any, res: Any, variants: Sequence[str], defaults: Sequence[str]) -> None:
    """Append the section to the report (``rr.rep.sections``) and one claim per default variant and quantity."""
    terrains = sorted(res.terrains)
    if not terrains:
        return
    names = {"e2": "E1+E2", "e3": "E1+E3", "e2p": "E1+E2, paper's choices", "e3p": "E1+E3, paper's choices"}
    lines = [
        "## Consistency: published variances against the errors (issue 21)",
        "",
        "Each cell: mean e²/σ² / share of errors within 2σ, pooled over the three wheels and the noise runs, "
        "estimates flagged `settled` only (the first `estimator.settle_steps` = 10 updates after a start are "
        "flagged unsettled), against the truth at the estimate's stamp. A consistent variance gives 1 and 95 %; "
        f"the criterion is e²/σ² in [{E2S2_BAND[0]:g}, {E2S2_BAND[1]:g}] and "
        f"{100 * WITHIN_BAND[0]:.0f}–{100 * WITHIN_BAND[1]:.0f} % within 2σ (✗ where not met). All six terrains "
        "are nominal plants (no sim-to-real effect). NEES: the five quantities of one wheel with the published "
        "(diagonal) variances, mean against 5 and the 95 % band of the mean with the effective sample count "
        "(errors at 5 Hz are strongly correlated in time).",
        "",
        "| terrain | estimators | " + " | ".join(f"{sym} ({unit})" for _, sym, unit in QUANTITIES) + " | NEES (band) |",
        "|---|---|" + "---|" * len(QUANTITIES) + "---|",
    ]
    per_terrain: dict[tuple[int, str], dict[str, Any]] = {}
    for n in terrains:
        for v in variants:
            fig = consistency_figures(res, [n], v)
            if not fig:
                continue
            per_terrain[n, v] = fig
            lo, hi = fig["nees_band"]
            cells = " | ".join(_cell(fig, q) for q, *_ in QUANTITIES)
            lines.append(
                f"| {n} ({res.terrains[n].name}) | {names.get(v, v)} | {cells} | "
                f"{fig['mean_nees']:.2g} ({lo:.2g}–{hi:.2g}) |"
            )
    lines += ["", "Pooled (terrains 1–5: curvature below 1/l_w; all six):", ""]
    lines += [
        "| estimators | " + " | ".join(f"{sym}" for _, sym, _ in QUANTITIES) + " | NEES |",
        "|---|" + "---|" * len(QUANTITIES) + "---|",
    ]
    misses: list[str] = []
    gentle = [n for n in terrains if n != 6]
    for v in variants:
        if gentle and len(gentle) < len(terrains):
            part = consistency_figures(res, gentle, v)
            if part:
                cells = " | ".join(_cell(part, q) for q, *_ in QUANTITIES)
                lines.append(f"| {names.get(v, v)}, terrains 1–5 | {cells} | {part['mean_nees']:.2g} |")
        fig = consistency_figures(res, terrains, v)
        if not fig:
            continue
        cells = " | ".join(_cell(fig, q) for q, *_ in QUANTITIES)
        lines.append(f"| {names.get(v, v)}, all terrains | {cells} | {fig['mean_nees']:.2g} |")
        if v not in defaults:
            continue
        for q, sym, _ in QUANTITIES:
            qc = fig["quantities"][q]
            holds = criteria_hold(qc.mean_normalised, qc.within_2sigma)
            rr.claim(
                f"consistency, {names.get(v, v)}",
                f"{sym}: mean e²/σ² (within 2σ {100 * qc.within_2sigma:.0f} %)",
                qc.mean_normalised,
                "— (issue 21)",
                "e²/σ² in [0.5, 2] and 90–98 % within 2σ",
                holds,
            )
            if not holds:
                misses.append(
                    f"- {names.get(v, v)}, {sym}: e²/σ² {qc.mean_normalised:.2g}, "
                    f"{100 * qc.within_2sigma:.0f} % within 2σ "
                    f"(RMS error {qc.rms_error:.3g}, RMS σ {qc.rms_sigma:.3g})."
                )
    for v in defaults:
        misses += _terrain_misses(rr, per_terrain, terrains, v, names.get(v, v))
    lines += [
        "",
        "Where the defaults miss, and why (pooled over the six terrains, then terrain by terrain: each terrain is "
        "a nominal scenario, and a pooled figure can meet the criterion by averaging a cautious terrain with an "
        "over-confident one):",
        "",
        *(misses or ["- Nowhere: every quantity meets both criteria on every terrain."]),
        "",
        "Known causes. (1) γ, W and DP carry the geometric contact angle's slow error, considered at σ_b: the "
        "larger of `filter.contact_angle_bias` (0.01 rad, sized a priori for the path beyond the parabola and ≈ 5 mm "
        "of differential sinkage over 0.35 m, not fitted to these runs) and the repeat-pass measure (a wheel reaches "
        "the place its leader passed 0.35 m earlier: half the mean square difference of their γ estimates, less "
        "their variances; estimators/rover_noise.py, a lower bound). The plant sinks each wheel by its own "
        "Wong–Reece sinkage (≈ 4–5 mm spread across the wheels on terrains 1, 2, 4–6, ≈ 2 mm on 3; section "
        '"sinkage", `python -m terrain_analysis.tools.rover_sinkage`): where γ̌ is better than σ_b (the straight '
        "slopes of terrains 2–3, the wide step 4) they are cautious, where it is worse (the steps of terrains 5–6, "
        "whose curvature reaches and passes 1/l_w, the limit [RB] sets for the method and beyond which it excludes "
        "terrain 6) over-confident, less so with the repeat-pass measure. (2) τ_R is "
        "published for the window just observed (`P_k|k − Q_k`) plus eq. 49's neglected wheel coupling "
        "I_wg (θ̈ + q̈1), now estimated without counting Estimator 1's acceleration noise (I_wg² (â² − P_â) "
        "averaged, floored at 0; it was I_wg² â², 5× too cautious), plus the applied torque's swing inside the "
        "window (the estimate is the window's mean, the truth is read at the stamp: the squared deviation of the "
        "sample nearest the stamp from the window mean, averaged over 5 s). The rear wheel's τ_R was over-confident "
        "until eq. 48 took the wheel damping at the step's new rate (the encoders give window-mean rates; the "
        "explicit step put ≈ 0.46 q̈ N·m into τ_R; models/rover_general_model.py). (3) Estimators 1 + 3 "
        "synthesise F_⊥ for the bogie wheels by splitting F_⊥12 at one DP/W; the split errs by "
        "F_L1 F_L2/(F_L1 + F_L2) · k · (i1 − i2) (k = `filter.split_traction_slope`, the nominal soil's DP/W slope "
        "in slip), slow and opposite on the two wheels: it enters R and the published W and DP variances. "
        "The paper's choices (ż0^R = 0, "
        "load-proportional split) leave a contact-angle error of 1–2° that no variance here covers.",
    ]
    rr.rep.add_section(lines)
