"""Cases 1, 6, 7 and 8 of the quarter-car reproduction: the Graneville loam rides (ISO D, 10 m/s).

Page text and figures of :mod:`~terrain_analysis.tools.reproduce_qc` for the
realisations of seed group 1: SCKF against EKF (case 1), the posterior
Cramér–Rao bound of k_s (case 6), the two k_tot noise forms (case 7, with
the Table 4 rides) and the profile sampling rate (case 8).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.reporting import Report
from terrain_analysis.reporting import format_number as _fmt
from terrain_analysis.reporting import in_window as _window
from terrain_analysis.reporting import pyplot as _plt
from terrain_analysis.reporting import summary_stats as _stats
from terrain_analysis.tools.qc_runs import (
    _GROUP_GRANEVILLE,
    _QC_WALK,
    PROFILE_RATES,
    Counts,
    Results,
    Trace,
    _ms,
    _settle_stats,
    rmse,
    run_seeds,
    writes_runs,
)
from vehicle_sim.terrain.profiles import RoadProfile, iso8608_profile

__all__ = ["case1", "case6", "case7", "case8"]

FloatArray = NDArray[np.float64]


# -- case 1 -------------------------------------------------------------------


@writes_runs("case1")
def case1(rep: Report, runs: list[dict[str, Trace]], counts: Counts) -> None:
    n = len(runs)
    T = counts.case1_duration
    lines = [
        "## Case 1 — Graneville loam, ISO D, 10 m/s: SCKF vs EKF (paper §5.1, Fig. 3, Fig. 5)",
        "",
        f"Conditions: 2-DOF quarter car of Table 2, Graneville loam (k_s = 651.1 kN/m), ISO 8608 class D "
        f"(G_d(n0) = 1024·10⁻⁶ m³, band 0.05–10 cycles/m), 10 m/s, {T:g} s per run, **{n} runs** "
        "(independent road realisation and sensor noise per run, same ones for every filter). "
        "Start guess k_tot,0 = k_t/2 = 87.5 kN/m (k_s,0 = k_t = 175 kN/m; MODELS.md A.5), "
        "P0 = diag(1e-4, 1e-2, 1e-4, 1e-2, (50 kN/m)²), Q and R of the paper, "
        f"k_tot random walk {_QC_WALK:g} (N/m)² per 10 ms step (the default; the printed Q_k is in case 7), "
        "profile sampled at 1 kHz with σ_h = 0.1 mm, "
        "filter at 100 Hz with 1 ms road sub-steps, 4th-order Taylor discretisation, EKF with the exact "
        "Jacobian (the paper's Jacobian is in case 3). No soil-change re-open (the paper's filter).",
        "",
        "Metric. e(t) = 100 (k̂_s(t) − k_s)/k_s at every filter step (100 Hz). Per run, "
        "RMSE_[a,b] = √(mean of e² over a < t ≤ b). **RMSE 0–10 s** includes the start transient from the "
        "k_s,0 = 175 kN/m guess; **RMSE 2–12 s** is the steady state. The paper's 3.26 % / 3.33 % are "
        'compared with **RMSE 0–10 s**: the paper\'s "inspection window of 10 s" starts with the filter '
        "(Fig. 3 shows the transient from t = 0), and its small spread (σ 0.28 %) fits a number dominated by "
        "the nearly deterministic transient. Time to < 5 %: the first time from which |e| stays below 5 % "
        f"until the end of the run ({T:g} s).",
        "",
        "| filter | RMSE 0–10 s mean ± std (%) | median | RMSE 2–12 s mean ± std (%) | median | "
        "time to < 5 % median (s) | mean | paper |",
        "|---|---|---|---|---|---|---|---|",
    ]
    paper = {"sckf": (3.26, 0.28), "ekf": (3.33, 0.45)}
    lines[-3:-3] = [
        "Row **SCKF, ln k_s state**: the same SCKF, start guess (s_0 = ln(k_s,0/k_t) = 0 ⇔ k_tot,0 = k_t/2) "
        'and random walk, but with s = ln(k_s/k_t) as the augmented state (`stiffness_state="log_k_s"`, '
        "P0 of s = 1.5², walk 1e-6 per step): k_tot = k_t·logistic(s) stays inside (0, k_t) at every cubature "
        "point, so the overshoot of k̂_tot towards k_t described below cannot make k̂_s explode. It is not "
        "the paper's filter; it is the estimator node's default.",
        "",
    ]
    stats: dict[str, dict[str, dict[str, float]]] = {}
    paper["sckf_log"] = paper["sckf"]
    for label, name in (("sckf", "SCKF"), ("ekf", "EKF"), ("sckf_log", "SCKF, ln k_s state")):
        if label not in runs[0]:
            continue
        r010 = _stats([rmse(r[label], 0.0, 10.0) for r in runs])
        r212 = _stats([rmse(r[label], 2.0, T) for r in runs])
        st = _settle_stats(runs, label, 0.0, T, 5.0)
        stats[label] = {"r010": r010, "r212": r212, "settle": st}
        pm, ps = paper[label]
        lines.append(
            f"| {name} | {_ms(r010)} | {_fmt(r010['median'])} | {_ms(r212)} | {_fmt(r212['median'])} | "
            f"{_fmt(st['median'])} | {_fmt(st['mean'])} | {pm} ± {ps} %, ≈ 0.5 s |"
        )
        if label == "sckf_log":
            # Not the paper's filter: the same SCKF with the ln k_s state (the node's default).
            rep.row("1", f"{name} relative RMSE of k_s, 0–10 s, mean over runs (%)", r010["mean"], pm, "info")
            continue
        rep.row("1", f"{name} relative RMSE of k_s, 0–10 s, mean over runs (%)", r010["mean"], pm, "<=")
        rep.row("1", f"{name} relative RMSE of k_s, 0–10 s, std over runs (%)", r010["std"], ps, "info")
        rep.row(
            "1",
            f"{name} time until |e| stays < 5 %, median (s)",
            st["median"],
            0.5,
            "<=1.5x",
            censored=st["censored"] >= n / 2,
        )
    for label, name in (("sckf", "SCKF"), ("ekf", "EKF")):
        for key, window, stat in (("r010", "0–10", "median"), ("r212", f"2–{T:g}", "mean")):
            rep.row(
                "1",
                f"{name} relative RMSE of k_s, {window} s, {stat} over runs (%)",
                stats[label][key][stat],
                paper[label][0],
                "info",
            )
    cens = {k: int(v["settle"]["censored"]) for k, v in stats.items()}
    clamp = {
        lab: sum(bool(np.any(r[lab].k_tot >= r[lab].k_tot_max * (1 - 1e-9))) for r in runs) for lab in ("sckf", "ekf")
    }
    spikes = {lab: sum(bool(np.any(np.abs(r[lab].err) > 1000.0)) for r in runs) for lab in ("sckf", "ekf")}
    lines += [
        "",
        f"Runs whose error had not settled below 5 % by {T:g} s (counted at {T:g} s): "
        f"SCKF {cens['sckf']}, EKF {cens['ekf']}. Runs in which k̂_tot reached its upper clamp 0.999 k_t at some "
        f"step (k̂_s ≈ 1000 k_t there): SCKF {clamp['sckf']}, EKF {clamp['ekf']}; runs with |e| > 1000 % at some "
        f"step: SCKF {spikes['sckf']}, EKF {spikes['ekf']}. Such a step happens in the first tenths of a second, when "
        "the first updates overshoot k_tot towards k_t, where k_s = k_tot k_t/(k_t − k_tot) explodes (MODELS.md "
        "A.10.4): a single such step adds hundreds of % to a run's 0–10 s RMSE, so the mean and std over runs "
        "measure how often it happens, and the median is the typical run.",
        "",
    ]
    # figures: run 0 trajectory (Fig. 3) and per-run RMSE (Fig. 5)
    plt = _plt()
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    r0 = runs[0]
    for label, style, name in (("ekf", "-", "EKF"), ("sckf", "-", "SCKF")):
        tr = r0[label]
        ks = 651.1 * (1 + tr.err / 100)
        axes[0].plot(tr.t, ks, style, lw=1.0, label=name, color="0.6" if label == "ekf" else "k")
        axes[1].plot(tr.t, np.abs(tr.err), lw=1.0, label=name, color="0.6" if label == "ekf" else "k")
    axes[0].axhline(651.1, ls="--", color="tab:red", lw=1, label="true k_s")
    axes[0].set_ylabel("k_s (kN/m)")
    axes[0].set_ylim(0, 1000)
    axes[0].legend()
    axes[1].axhline(5.0, ls=":", color="tab:red", lw=1)
    axes[1].set_yscale("log")
    axes[1].set_ylabel("|error| (%)")
    axes[1].set_xlabel("time (s)")
    axes[0].set_title("Case 1, run 0: Graneville loam, ISO D, 10 m/s (cf. paper Fig. 3)")
    p1 = rep.save_figure(fig, "case1_trajectory.png")
    fig, ax = plt.subplots(figsize=(8, 4))
    idx = np.arange(n)
    for label, name, color in (("ekf", "EKF", "0.6"), ("sckf", "SCKF", "k")):
        vals = [rmse(r[label], 0.0, 10.0) for r in runs]
        ax.plot(idx, vals, "o-", ms=3, lw=0.8, color=color, label=f"{name} (0–10 s)")
        ax.plot(idx, [rmse(r[label], 2.0, T) for r in runs], "x", ms=3, color=color, label=f"{name} (2–12 s)")
    ax.axhline(3.26, ls="--", color="k", lw=0.8, label="paper SCKF 3.26 %")
    ax.axhline(3.33, ls="--", color="0.6", lw=0.8, label="paper EKF 3.33 %")
    ax.set_xlabel("Monte Carlo run")
    ax.set_ylabel("relative RMSE of k_s (%)")
    ax.set_yscale("log")
    ax.set_title("Case 1: RMSE per run (cf. paper Fig. 5)")
    ax.legend(fontsize=7, ncol=3)
    p2 = rep.save_figure(fig, "case1_rmse.png")
    lines += [rep.link(p1, "case 1 trajectory"), "", rep.link(p2, "case 1 RMSE per run"), ""]
    rep.add_section(lines)
    for label, name in (("sckf", "SCKF"), ("ekf", "EKF")):
        m = stats[label]["r010"]["mean"]
        if m > paper[label][0]:
            rep.not_reproduced.append(
                f"- **Case 1, {name} RMSE 0–10 s** {_fmt(m)} % vs the paper's {paper[label][0]} % (median over runs "
                f"{_fmt(stats[label]['r010']['median'])} %). "
                + (
                    f"The mean is pulled up by the {spikes[label]} runs whose first updates overshoot k̂_tot "
                    "towards k_t, where k̂_s explodes for a few steps (see the section). "
                    if spikes[label]
                    else ""
                )
                + "The typical run's 0–10 s value is set by the start transient (error ≈ 70 % at the start guess), "
                f"i.e. by how fast it is swept out, not by the accuracy. Over 2–{T:g} s the {name} reaches "
                f"{_fmt(stats[label]['r212']['mean'])} % (median {_fmt(stats[label]['r212']['median'])} %), "
                + ("below" if stats[label]["r212"]["mean"] <= paper[label][0] else "still above")
                + " the paper's number. The paper does not state P0, which sets the transient, nor whether its "
                "window starts at the filter's start."
            )


# -- case 6 (PCRLB) ---------------------------------------------------------------------


def _case1_road(seed_offset: int) -> RoadProfile:
    """Road of case-1 run ``seed_offset`` (the bound's ``road(seed + r)`` callable, with seed 0)."""
    return iso8608_profile("D", run_seeds(_GROUP_GRANEVILLE, seed_offset)[0])


def _call_pcrlb(fn: Callable[..., Any], n_runs: int, duration: float) -> tuple[FloatArray, FloatArray, str]:
    """Call ``pcrlb_quarter_car`` on the case-1 roads; (t, relative k_s bound in %, how it was called)."""
    import inspect

    params = inspect.signature(fn).parameters
    kwargs: dict[str, Any] = {}
    if "n_runs" in params:
        kwargs["n_runs"] = n_runs
    if "duration" in params:
        kwargs["duration"] = duration
    if "road" in params and "seed" in params:
        kwargs["seed"] = 0
        kwargs["road"] = _case1_road
    out = fn(**kwargs)
    if isinstance(out, tuple):
        t, bound = np.asarray(out[0], dtype=float), np.asarray(out[1], dtype=float)
        rel = 100.0 * bound / 651.1e3 if np.nanmedian(bound) > 50.0 else 100.0 * bound
    else:
        t = np.asarray(out.t, dtype=float)
        rel = 100.0 * np.asarray(out.k_s_relative_std, dtype=float)
    how = ", ".join(f"{k}={'case-1 roads' if k == 'road' else v}" for k, v in kwargs.items())
    return t, rel, how


@writes_runs("case1")
def case6(rep: Report, runs: list[dict[str, Trace]], counts: Counts) -> None:
    lines = ["## Case 6 — Posterior Cramér–Rao bound for k_s (case 1 conditions)", ""]
    try:
        import importlib

        fn = importlib.import_module("terrain_analysis.pcrlb").pcrlb_quarter_car
    except (ImportError, AttributeError) as exc:
        lines += [
            f"**Skipped**: `terrain_analysis.pcrlb.pcrlb_quarter_car` is not available at this revision "
            f"({type(exc).__name__}: {exc}). Re-run the command once it exists.",
            "",
        ]
        rep.add_section(lines)
        return
    n_bound = min(len(runs), 50)
    try:
        t_b, bound_pct, how = _call_pcrlb(fn, n_bound, counts.case1_duration)
    except Exception as exc:  # the module is owned elsewhere: report, do not crash the reproduction
        lines += [f"**Skipped**: calling `pcrlb_quarter_car` failed ({type(exc).__name__}: {exc}).", ""]
        rep.add_section(lines)
        return
    T = counts.case1_duration
    lines += [
        "Bound: `terrain_analysis.pcrlb.pcrlb_quarter_car` (Tichavský–Muravchik–Nehorai recursion of "
        "the filter's own stochastic model — per-step k_tot random walk, Q, R, the estimator's P0 — along the "
        f"simulator's truth; called with {how}: the first {n_bound} case-1 roads), reported as the relative "
        "std bound of k_s. Ratio = RMSE over the runs at each time, √(mean over runs of e(t)²), divided by the "
        "bound at that time; 1 would be an efficient estimator. The bound is that of the model, not a strict "
        "bound against this truth: the k_tot random walk gives it a floor, and a filter on a constant-k_s truth "
        "can come in below it (see the module's docstring).",
        "",
        "| filter | bound (%) at 1 s | ratio at 1 s | 2 s | 5 s | 10 s | median ratio over 2–12 s |",
        "|---|---|---|---|---|---|---|",
    ]
    plt = _plt()
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    axes[0].plot(t_b, bound_pct, "k--", lw=1, label=f"PCRLB ({n_bound} roads)")
    for label, name in (("sckf", "SCKF"), ("ekf", "EKF")):
        size = runs[0][label].err.size
        errs = np.array([r[label].err for r in runs if r[label].err.size == size])
        t = runs[0][label].t
        rms_t = np.sqrt(np.mean(errs**2, axis=0))
        b = np.interp(t, t_b, bound_pct)
        ratio = rms_t / np.maximum(b, 1e-12)
        axes[0].plot(t, rms_t, lw=0.9, label=f"{name} RMSE over {errs.shape[0]} runs")
        axes[1].plot(t, ratio, lw=0.9, label=name)
        pick = [float(np.interp(x, t, ratio)) for x in (1.0, 2.0, 5.0, 10.0)]
        med = float(np.median(ratio[t >= 2.0]))
        b1 = float(np.interp(1.0, t_b, bound_pct))
        lines.append(f"| {name} | {_fmt(b1)} | " + " | ".join(_fmt(v) for v in pick) + f" | {_fmt(med)} |")
    floor = float(np.median(bound_pct[t_b >= 2.0]))
    lines += ["", f"Bound over 2–{T:g} s (median): {_fmt(floor)} % of k_s.", ""]
    axes[0].set_yscale("log")
    axes[0].set_ylabel("k_s error (%)")
    axes[0].legend(fontsize=7)
    axes[0].set_title("Case 6: RMSE over runs vs PCRLB, Graneville loam, ISO D, 10 m/s", fontsize=9)
    axes[1].set_yscale("log")
    axes[1].axhline(1.0, color="k", lw=0.8)
    axes[1].set_ylabel("RMSE / bound")
    axes[1].set_xlabel("time (s)")
    axes[1].legend(fontsize=7)
    rep.add_section(lines, (fig, "pcrlb.png", "PCRLB"))


# -- case 7 (noise forms; case 1 part) ---------------------------------------------------


@writes_runs("case1")
def case7(rep: Report, runs: list[dict[str, Trace]], counts: Counts) -> None:
    T = counts.case1_duration
    lines = [
        "## Case 7 — The two k_tot noise forms (MODELS.md A.4)",
        "",
        "The printed Q_k ≈ Δt G_k Q G_kᵀ gives k_tot a random walk of Δt³σ5² = 0.1 (N/m)² per 10 ms step "
        f'(`ktot_noise_form="printed"`); the default (`"per_step"`) is {_QC_WALK:g} (N/m)² per step, the motion states '
        "keeping the printed form. **Every headline number of this report uses the default per-step form**; the "
        "printed form is shown here for case 1 and in the Table 4 block of case 2 (its rows are marked "
        "[printed Q_k] in the summary).",
        "",
        "| filter, noise form | RMSE 0–10 s mean ± std (%) | median | RMSE 2–12 s mean ± std (%) | median | "
        "time to < 5 % median (s) |",
        "|---|---|---|---|---|---|",
    ]
    for label, name in (
        ("sckf", "SCKF, per-step (default)"),
        ("sckf_printed", "SCKF, printed Q_k"),
        ("ekf", "EKF, per-step (default)"),
        ("ekf_printed", "EKF, printed Q_k"),
    ):
        r010 = _stats([rmse(r[label], 0.0, 10.0) for r in runs])
        r212 = _stats([rmse(r[label], 2.0, T) for r in runs])
        st = _settle_stats(runs, label, 0.0, T, 5.0)
        lines.append(
            f"| {name} | {_ms(r010)} | {_fmt(r010['median'])} | {_ms(r212)} | {_fmt(r212['median'])} | "
            f"{_fmt(st['median'])} |"
        )
        if label.endswith("printed"):
            filt = "SCKF" if label.startswith("sckf") else "EKF"
            paper = 3.26 if filt == "SCKF" else 3.33
            rep.row("7", f"Case 1 {filt} RMSE 0–10 s mean [printed Q_k] (%)", r010["mean"], paper, "<=")
    lines += ["", "On the 3-soil path the printed form cannot follow a soil change (case 2, rows [printed Q_k]).", ""]
    rep.add_section(lines)


# -- case 8 (profile rate) ----------------------------------------------------------------


def case8(rep: Report, res: Results, counts: Counts) -> None:
    if not res.get("case1"):
        return
    T = counts.case1_duration
    lines = [
        "## Case 8 — Road between filter steps: profile sampled at 1 kHz / 250 Hz / 100 Hz (MODELS.md A.10.1)",
        "",
        "Case 1 (same roads and sensor noise, paired), with only `Scenario.profile_rate` changed. The estimator "
        "always integrates on a 1 ms sub-step grid, interpolating the profile linearly between its samples: at "
        "100 Hz the filter sees the piecewise-linear road through the 10 ms samples, i.e. it misses the road "
        "between its steps (the truth rolls over road content up to 10 cycles/m = 100 Hz at 10 m/s). This is why "
        "the contract's profile topic runs at 1 kHz.",
        "",
        "| profile rate | runs | SCKF RMSE 2–12 s mean ± std (%) | median | SCKF mean signed error 2–12 s (%) | "
        "EKF RMSE 2–12 s mean ± std (%) | SCKF RMSE 0–10 s mean (median) (%) | EKF RMSE 0–10 s mean (median) (%) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    box: dict[str, list[float]] = {}
    for rate in PROFILE_RATES:
        runs = res["case1"] if rate == PROFILE_RATES[0] else res.get(f"rate_{rate:g}", [])
        if not runs:
            continue
        s = _stats([rmse(r["sckf"], 2.0, T) for r in runs])
        e = _stats([rmse(r["ekf"], 2.0, T) for r in runs])
        bias = float(np.mean([np.mean(r["sckf"].err[_window(r["sckf"].t, 2.0, T)]) for r in runs]))
        s010 = _stats([rmse(r["sckf"], 0.0, 10.0) for r in runs])
        e010 = _stats([rmse(r["ekf"], 0.0, 10.0) for r in runs])
        lines.append(
            f"| {rate:g} Hz | {len(runs)} | {_ms(s)} | {_fmt(s['median'])} | {bias:+.2f} | {_ms(e)} | "
            f"{_fmt(s010['mean'])} ({_fmt(s010['median'])}) | {_fmt(e010['mean'])} ({_fmt(e010['median'])}) |"
        )
        box[f"SCKF {rate:g} Hz"] = [rmse(r["sckf"], 2.0, T) for r in runs]
        box[f"EKF {rate:g} Hz"] = [rmse(r["ekf"], 2.0, T) for r in runs]
        rep.row(
            "8",
            f"Case 1 SCKF RMSE 2–{T:g} s mean, profile sampled at {rate:g} Hz (%) (paper's 0–10 s value beside)",
            s["mean"],
            3.26,
            "info",
        )
    lines.append("")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.boxplot(list(box.values()), orientation="horizontal")
    ax.set_yticks(range(1, len(box) + 1))
    ax.set_yticklabels(list(box), fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("relative RMSE of k_s over 2–12 s (%), all runs")
    ax.set_title("Case 8: profile sampling rate (Graneville loam, ISO D, 10 m/s)", fontsize=9)
    rep.add_section(lines, (fig, "profile_rate.png", "profile rate"))
