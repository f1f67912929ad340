"""k_s without a measured profile against the profile-fed filter, on the Table 4 path (issue 21 item 5).

``python -m terrain_analysis.tools.reproduce_qc_profile_free [--seeds N] [--jobs 2] [--out PAGE.md] [--quick]``
(default page ``docs/results/quarter_car.md``, section ``qc-profile-free``)

Every ride is the Table 4 path of the reproduction (LETE sand → Upland sandy
loam → Graneville loam, 10 s each, the scenario helpers of
:mod:`terrain_analysis.tools.reproduce_qc`, seed group 2 as its Table 4
cells) at 10 m/s on ISO C, D, E and F roads, simulated by the project's truth
plant. Over the same accelerometer data run:

* **fed 1 kHz**: the profile-fed estimator with the node's defaults
  (``config/quarter_car.yaml``), profile at 1 kHz;
* **fed 100 Hz**: the same with the profile sampled at 100 Hz (a second
  simulation of the same road and noise seeds with ``profile_rate = 100``);
* **free**: the node's defaults with ``estimator.road_input = stochastic`` and
  ``estimator.road_class`` = the road's class (its geometric-mean level, which
  is the simulator's level), speed from the speed channel;
* **free, level ×2 / ×½**: the same with the assumed G_d(n0) at the edges of
  the class (what a user who knows only the class risks).

Figures, per road and soil stretch: the relative difference of k_tot (free
against fed 1 kHz) over the second half of the stretch; the k_s error of each
against the truth; the time after the start of the stretch until |k_tot
error| stays below 5 %; mean e²/σ² and the share of errors within 2σ of the
published variances (:func:`terrain_estimation.analysis.consistency.consistency_report`,
second halves, pooled over runs); the signed k_s bias with the 100 Hz profile.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from terrain_analysis.experiment import Runner
from terrain_analysis.reporting import Provenance, provenance_lines, reproduction_arguments, write_section
from terrain_analysis.reporting import format_number as fmt
from terrain_analysis.tools.qc_runs import (
    _GROUP_TABLE4,
    _PATH_SOILS,
    RunSpec,
    _profile,
    _soil_path,
    collect,
    node_default_config,
    run_seeds,
)
from terrain_estimation.analysis.consistency import consistency_report
from terrain_estimation.cli import cli_main
from terrain_estimation.estimators.soil_select import make_estimator
from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimatorConfig
from terrain_estimation.models.quarter_car_road import ISO8608_GD_N0
from vehicle_sim.plants.quarter_car import LRVVehicle, QuarterCarVehicle, Scenario, SpeedProfile, simulate

__all__ = ["ROADS", "SPEED", "run_ride", "summarise", "main"]

FloatArray = NDArray[np.float64]

ROADS = ("C", "D", "E", "F")
SPEED = 10.0
LRV_SOIL = "lunar_regolith"
LRV_SPEED = 2.0
_GROUP_LRV = 5
SECTION = "qc-profile-free"
_K_T = 175.0e3
_VARIANTS = ("fed", "fed100", "free", "free_x2", "free_half")
_LABELS = {
    "fed": "profile-fed, 1 kHz",
    "fed100": "profile-fed, 100 Hz profile",
    "free": "profile-free (class level)",
    "free_x2": "profile-free, level ×2",
    "free_half": "profile-free, level ×½",
}


@dataclass
class Series:
    """One estimator's output over one ride (arrays at the filter rate)."""

    t: FloatArray
    k_tot: FloatArray
    k_tot_var: FloatArray
    k_s: FloatArray
    k_s_var: FloatArray
    nis: FloatArray
    alarms: FloatArray


def _free_config(road: str, scale: float, vehicle: str = "quarter_car") -> SoilStiffnessEstimatorConfig:
    base = node_default_config(vehicle)
    level = ISO8608_GD_N0[road] * scale
    road_params = replace(base.road, iso_class=road, gd_n0=level, allow_lrv=vehicle == "lrv")
    return replace(base, road_input="stochastic", road=road_params)


def _run(config: SoilStiffnessEstimatorConfig, sim: Any, *, profile: bool) -> Series:
    est = make_estimator(config)
    pt, ps, ph = sim.profile.t.tolist(), sim.profile.distance.tolist(), sim.profile.elevation.tolist()
    rows: list[tuple[float, float, float, float, float, float, float]] = []
    j = 0
    for i, t in enumerate(sim.t.tolist()):
        if profile:
            while j < len(pt) and pt[j] <= t + 1e-9:
                est.add_profile_sample(pt[j], ps[j], ph[j])
                j += 1
        else:
            est.add_speed(t, float(sim.speed[i]))
        wheel = None if sim.wheel_accel_z is None else float(sim.wheel_accel_z[i])
        est.add_accelerations(t, float(sim.body_accel_z[i]), wheel)
        for e in est.drain_estimates():
            rows.append((e.t, e.k_tot, e.k_tot_variance, e.k_s, e.k_s_variance, e.nis, float(e.soil_change_detected)))
    a = np.asarray(rows, dtype=float).reshape(-1, 7)
    return Series(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5], a[a[:, 6] > 0.0, 0])


def run_ride(spec: RunSpec) -> tuple[RunSpec, dict[str, Series]]:
    """Simulate one Table 4 ride (and its 100 Hz-profile twin) and run every variant."""
    road_seed, noise_seed = run_seeds(spec.group, spec.run)
    out: dict[str, Series] = {}
    sims = {}
    vehicle: QuarterCarVehicle | LRVVehicle = QuarterCarVehicle() if spec.vehicle == "quarter_car" else LRVVehicle()
    for rate in (1000.0, 100.0):
        scenario = Scenario(
            profile=_profile(spec.road, road_seed),
            soil_path=_soil_path(spec),
            speed=SpeedProfile.constant(spec.speed),
            profile_rate=rate,
        )
        sims[rate] = simulate(vehicle, scenario, spec.duration, seed=noise_seed)
    fed = node_default_config(spec.vehicle)
    out["fed"] = _run(fed, sims[1000.0], profile=True)
    out["fed100"] = _run(fed, sims[100.0], profile=True)
    for key, scale in (("free", 1.0), ("free_x2", 2.0), ("free_half", 0.5)):
        out[key] = _run(_free_config(spec.road, scale, spec.vehicle), sims[1000.0], profile=False)
    return spec, out


def _truth_ktot(soil: str) -> float:
    from vehicle_sim.terrain.soils import soil_by_name

    k_s = soil_by_name(soil).k_s
    return k_s * _K_T / (k_s + _K_T)


def _settle(t: FloatArray, err: FloatArray, t0: float, t1: float, thr: float = 5.0) -> tuple[float, bool]:
    sel = (t > t0) & (t <= t1)
    tt, bad = t[sel], np.abs(err[sel]) >= thr
    if tt.size == 0 or bad[-1]:
        return t1 - t0, True
    if not bad.any():
        return float(tt[0] - t0), False
    return float(tt[int(np.flatnonzero(bad)[-1]) + 1] - t0), False


def summarise(results: dict[str, list[dict[str, Series]]], stretch: float) -> dict[str, Any]:
    """Per road and soil: the figures of the report (see the module docstring)."""
    table: dict[str, Any] = {}
    for key, runs in results.items():
        if not key.startswith("pf_qc_"):
            continue
        road = key.removeprefix("pf_qc_")
        for j, soil in enumerate(_PATH_SOILS):
            kt = _truth_ktot(soil)
            ks_true = kt * _K_T / (_K_T - kt)
            t0, t1 = j * stretch, (j + 1) * stretch
            half = t0 + 0.5 * stretch
            cell: dict[str, Any] = {"amplification": _K_T / (_K_T - kt)}
            diffs = []
            for r in runs:
                fed, free = r["fed"], r["free"]
                sel = (fed.t > half) & (fed.t <= t1)
                sel_f = (free.t > half) & (free.t <= t1)
                n = min(int(sel.sum()), int(sel_f.sum()))
                if n:
                    diffs.append(float(np.mean(free.k_tot[sel_f][:n] / fed.k_tot[sel][:n] - 1.0) * 100.0))
            cell["ktot_diff"] = diffs
            for key in _VARIANTS:
                ks_err, kt_err, settle, censored, delays, spurious = [], [], [], 0, [], 0
                t_all, e_kt, v_kt, e_ks, v_ks = [], [], [], [], []
                for r in runs:
                    s = r[key]
                    sel = (s.t > half) & (s.t <= t1)
                    ks_err.append(float(np.mean((s.k_s[sel] - ks_true) / ks_true) * 100.0))
                    kt_err.append(float(np.mean((s.k_tot[sel] - kt) / kt) * 100.0))
                    st, cens = _settle(s.t, 100.0 * (s.k_tot - kt) / kt, t0, t1)
                    settle.append(st)
                    censored += cens
                    hits = s.alarms[(s.alarms > t0 + 1e-6) & (s.alarms <= t1 + 1e-6)]
                    if j == 0:
                        spurious += int(np.count_nonzero(hits > 2.0))  # no change in the first stretch
                    else:
                        delays.append(float(hits[0] - t0) if hits.size else math.nan)
                        spurious += max(int(hits.size) - 1, 0)
                    t_all.append(s.t[sel])
                    e_kt.append(s.k_tot[sel] - kt)
                    v_kt.append(s.k_tot_var[sel])
                    e_ks.append(s.k_s[sel] - ks_true)
                    v_ks.append(s.k_s_var[sel])
                cons: dict[str, tuple[float, float, float]] = {}
                for name, e, v in (("k_tot", e_kt, v_kt), ("k_s", e_ks, v_ks)):
                    tt, ee, vv = np.concatenate(t_all), np.concatenate(e), np.concatenate(v)
                    ok = vv > 0.0  # a variance of 0 (a clamped stiffness) has no normalised error
                    rep = consistency_report(tt[ok], ee[ok][:, None], vv[ok][:, None, None], [name])
                    q = rep.quantity(name)
                    cons[name] = (q.mean_normalised, q.within_2sigma, q.rms_sigma)
                cell[key] = {
                    "ks_bias": ks_err,
                    "kt_bias": kt_err,
                    "settle": settle,
                    "censored": censored,
                    "consistency": cons,
                    "sigma_kt": 100.0 * cons["k_tot"][2] / kt,
                    "delays": delays,
                    "spurious": spurious,
                }
            table[f"{road}/{soil}"] = cell
    return table


def summarise_lrv(runs: Sequence[dict[str, Series]], duration: float) -> dict[str, Any]:
    """LRV rides (one soil): signed k_s bias and consistency of each variant over the second half."""
    from vehicle_sim.terrain.soils import soil_by_name

    ks_true = soil_by_name(LRV_SOIL).k_s
    out: dict[str, Any] = {}
    for key in _VARIANTS:
        bias, e_all, v_all, t_all = [], [], [], []
        for r in runs:
            s = r[key]
            sel = s.t > 0.5 * duration
            bias.append(float(np.mean((s.k_s[sel] - ks_true) / ks_true) * 100.0))
            e_all.append(s.k_s[sel] - ks_true)
            v_all.append(s.k_s_var[sel])
            t_all.append(s.t[sel])
        ee, vv, tt = np.concatenate(e_all), np.concatenate(v_all), np.concatenate(t_all)
        ok = vv > 0.0
        q = consistency_report(tt[ok], ee[ok][:, None], vv[ok][:, None, None], ["k_s"]).quantity("k_s")
        out[key] = {"bias": bias, "normalised": q.mean_normalised, "within": q.within_2sigma}
    return out


def _mean_sd(values: ArrayLike) -> str:
    a = np.asarray(values, dtype=float)
    if a.size == 0:
        return "—"
    return f"{fmt(float(np.mean(a)))} ± {fmt(float(np.std(a)))}"


def _median(values: Sequence[float]) -> str:
    return fmt(float(np.median(values))) if len(values) else "—"


def render_lrv(lrv: dict[str, Any], n_runs: int, duration: float) -> str:
    """The LRV part of the section."""
    lines = [
        "",
        f"**LRV (one accelerometer)** — lunar regolith, ISO G, {LRV_SPEED:g} m/s, {duration:g} s, {n_runs} rides "
        "(seed group 5 of `reproduce_qc`); the mode refuses the LRV unless `estimator.road_allow_lrv` is set, and "
        "this is why: signed k_s error (%) over the second half, mean ± sd over rides, and the consistency of the "
        "published k_s variance.",
        "",
        "| estimator | k_s bias (%) | k_s e²/σ² | k_s within 2σ |",
        "|---|---|---|---|",
    ]
    for key in _VARIANTS:
        c = lrv[key]
        lines.append(
            f"| {_LABELS[key]} | {_mean_sd(c['bias'])} | {fmt(c['normalised'])} | {fmt(100 * c['within'])} % |"
        )
    return "\n".join(lines) + "\n"


def render(table: dict[str, Any], header: list[str], n_runs: int) -> str:
    """The Markdown section."""
    lines = [
        "## k_s without a measured profile (issue 21 item 5)",
        "",
        *header,
        "",
        "The profile-free mode (`estimator.road_input: stochastic`, `estimators/soil_profile_free.py`, model "
        "`models/quarter_car_road.py`) drops the profile: the road is ISO 8608 shaped noise (slope white at "
        "`(2π n0)² G_d(n0) v`, Butterworth band edge at 10 cycles/m, low cut 0.05 cycles/m) and k_s comes from the "
        "two accelerometers through a bank of exact Kalman filters over a grid of ln k_s (a joint SCKF on the "
        "augmented state is biased: see the module). Speed from the speed channel; level G_d(n0) = the class mean "
        "(the simulator's level) unless stated. Path LETE sand → Upland sandy loam → Graneville loam, 10 s each, "
        f"10 m/s; **{n_runs} rides per road**. Windows: the second half of each stretch (5 s) unless stated.",
        "",
        "**k_tot, profile-free against profile-fed (1 kHz)** — mean over the second half of each stretch of "
        "k̂_tot,free / k̂_tot,fed − 1 (%), mean ± sd over rides [max |·|]; target |·| ≤ 5 %; k_s error then "
        "scales with the amplification k_t/(k_t − k_tot).",
        "",
        "| road | soil | amplification | k_tot free vs fed (%) | within 5 %? | k_s bias free (%) "
        "| k_s bias fed 1 kHz (%) |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, cell in table.items():
        road, soil = key.split("/")
        d = np.asarray(cell["ktot_diff"], dtype=float)
        worst = float(np.max(np.abs(d))) if d.size else math.nan
        ok = (
            "yes"
            if d.size and abs(float(np.mean(d))) <= 5.0 and worst <= 5.0
            else ("mean only" if d.size and abs(float(np.mean(d))) <= 5.0 else "**no**")
        )
        lines.append(
            f"| ISO {road} | {soil} | {fmt(cell['amplification'])} | {_mean_sd(d)} [{fmt(worst)}] | {ok} | "
            f"{_mean_sd(cell['free']['ks_bias'])} | {_mean_sd(cell['fed']['ks_bias'])} |"
        )
    lines += [
        "",
        "**Convergence and consistency.** Time after the start of the stretch (the start of the ride, or the soil "
        "change) until |k_tot error| stays below 5 % (median over rides; censored = never within the 10 s "
        "stretch); mean e²/σ² of k_tot and share of |e| ≤ 2σ over the second halves (consistent: ≈ 1 and ≈ 95 %).",
        "",
        "| road | soil | estimator | settle k_tot < 5 % median (s) | censored | change alarm delay median (s) "
        "[missed] | other alarms | rms σ(k_tot)/k_tot (%) | k_tot e²/σ² | k_tot within 2σ | k_s e²/σ² | "
        "k_s within 2σ |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, cell in table.items():
        road, soil = key.split("/")
        for var in ("fed", "free"):
            c = cell[var]
            (kt_n, kt_2, _), (ks_n, ks_2, _) = c["consistency"]["k_tot"], c["consistency"]["k_s"]
            d = np.asarray(c["delays"], dtype=float)
            found = d[np.isfinite(d)]
            delay = "—" if not d.size else f"{_median(list(found))} [{int(d.size - found.size)}]"
            lines.append(
                f"| ISO {road} | {soil} | {_LABELS[var]} | {_median(c['settle'])} | {c['censored']} | {delay} | "
                f"{c['spurious']} | {fmt(c['sigma_kt'])} | {fmt(kt_n)} | {fmt(100 * kt_2)} % | {fmt(ks_n)} | "
                f"{fmt(100 * ks_2)} % |"
            )
    lines += [
        "",
        "**Bias with a 100 Hz profile, and the road level.** Signed mean k_s error (%) over the second halves, "
        "mean ± sd over rides. The profile-free estimate needs no profile (its figure is the same data as above); "
        "the last two columns assume the road level at the edges of its ISO class (×2, ×½ G_d(n0)).",
        "",
        "| road | soil | fed 1 kHz | fed 100 Hz | free | free, level ×2 | free, level ×½ |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, cell in table.items():
        road, soil = key.split("/")
        lines.append(
            f"| ISO {road} | {soil} | {_mean_sd(cell['fed']['ks_bias'])} | {_mean_sd(cell['fed100']['ks_bias'])} | "
            f"{_mean_sd(cell['free']['ks_bias'])} | {_mean_sd(cell['free_x2']['ks_bias'])} | "
            f"{_mean_sd(cell['free_half']['ks_bias'])} |"
        )
    lines += ["", *_verdict(table)]
    return "\n".join(lines) + "\n"


def _span(values: Sequence[float]) -> str:
    return f"{fmt(min(values))}…{fmt(max(values))}" if values else "—"


def _verdict(table: dict[str, Any]) -> list[str]:
    """Where the 5 % target and the consistency are not met, and why (from the figures above)."""
    mean_out, ride_out, amp_ks = [], [], []
    norm_free, norm_fed, in_free, in_fed = [], [], [], []
    missed: dict[str, int] = {}
    changes = 0
    stiff_kt: list[float] = []
    elasticity: list[float] = []
    for key, cell in table.items():
        d = np.asarray(cell["ktot_diff"], dtype=float)
        if d.size and abs(float(np.mean(d))) > 5.0:
            mean_out.append(f"ISO {key} ({fmt(float(np.mean(d)))} %)")
        if d.size and float(np.max(np.abs(d))) > 5.0:
            ride_out.append(key)
        amp_ks.append((cell["amplification"], float(np.mean(cell["free"]["ks_bias"]))))
        norm_free.append(cell["free"]["consistency"]["k_tot"][0])
        norm_fed.append(cell["fed"]["consistency"]["k_tot"][0])
        in_free.append(100 * cell["free"]["consistency"]["k_tot"][1])
        in_fed.append(100 * cell["fed"]["consistency"]["k_tot"][1])
        delays = np.asarray(cell["free"]["delays"], dtype=float)
        soil = key.split("/")[1]
        missed[soil] = missed.get(soil, 0) + int(np.count_nonzero(~np.isfinite(delays)))
        changes += int(delays.size)
        if cell["amplification"] > 10.0 and d.size:
            stiff_kt.append(float(np.mean(d)))
        # d ln k_tot / d ln G_d from the ×2 rides (k_tot = k_t k_s/(k_t + k_s), k_s from its bias).
        kt_true = _K_T * (1.0 - 1.0 / cell["amplification"])
        ks_true = kt_true * cell["amplification"]
        ks_x2 = ks_true * (1.0 + float(np.mean(cell["free_x2"]["ks_bias"])) / 100.0)
        if ks_x2 > 0.0:
            elasticity.append(math.log((ks_x2 * _K_T / (ks_x2 + _K_T)) / kt_true) / math.log(2.0))
    stiff = [b for a, b in amp_ks if a > 10.0]
    n_missed = sum(missed.values())
    worst_soil = max(missed, key=lambda k: missed[k]) if n_missed else "—"
    e_mid = float(np.median(elasticity)) if elasticity else math.nan
    tolerance = 5.0 / abs(e_mid) if elasticity and e_mid != 0.0 else math.nan
    return [
        "**Where it is not met, and why.**",
        f"- k_tot within 5 % of the profile-fed estimate (mean over rides): not met in {len(mean_out)} of "
        f"{len(table)} cells ({', '.join(mean_out) or 'none'}); single rides exceed 5 % in {len(ride_out)} "
        "cells. The profile-free estimate carries the information of the accelerations alone: its posterior "
        "std is ≈ 3–4 % of k_tot (column rms σ), so a ride's mean scatters by a few %, and a bias of a few % "
        "remains where the road model differs from the road (Butterworth band edge and 100 Hz sampling against "
        "the simulator's brick-wall band at 10 cycles/m; first order instead of Butterworth: +11…13 %). Upland "
        "sandy loam, the softest soil, is also the last to settle after the LETE → Upland change: the 5 s "
        "memory still holds LETE evidence in the second half of the stretch.",
        f"- Soil changes: {n_missed} of {changes} changes not detected by the profile-free GLR test "
        f"({missed.get(worst_soil, 0)} of them onto {worst_soil}); those are followed by the forgetting alone, "
        "over seconds (settle times above).",
        f"- k_s: the amplification k_t/(k_t − k_tot) makes a k_tot difference of {_span(stiff_kt)} % on LETE sand "
        f"(×14) a k_s bias of {_span(stiff)} %: stiff soils are beyond this mode, as the amplification says.",
        f"- Variances: k_tot e²/σ² {_span(norm_free)} and {_span(in_free)} % within 2σ profile-free, against "
        f"{_span(norm_fed)} and {_span(in_fed)} % profile-fed: as consistent where the model fits, over-confident "
        f"(e²/σ² up to {fmt(max(norm_free)) if norm_free else '—'}) where the few-% bias above exceeds the std.",
        f"- Road level: from the ×2 rides, d ln k_tot / d ln G_d(n0) ≈ {fmt(e_mid)} (median over cells), so k_tot "
        f"within 5 % needs the level within about ±{fmt(tolerance)} %. The class alone (a factor 2 either way) is "
        "not enough: at the class edges k_s is off by tens to hundreds of % (last table). A measured or "
        "separately identified road level is a prerequisite of this mode on a real vehicle.",
    ]


@cli_main("reproduce-qc-profile-free")
def main(argv: Sequence[str] | None = None) -> int:
    """Run the comparison and write its section into the quarter-car results page."""
    args, given = reproduction_arguments(
        "reproduce_qc_profile_free",
        "profile-free k_s against the profile-fed filter on the Table 4 path",
        argv,
        runs_flag="--seeds",
        runs_help="rides per road (default 8)",
        quick_help="one ride per road, 3 s stretches (smoke test)",
    )
    out = args.out if str(args.out).endswith(".md") else f"{args.out.rstrip('/')}/quarter_car.md"
    seeds = args.seeds if args.seeds is not None else (1 if args.quick else 8)
    stretch = 3.0 if args.quick else 10.0
    roads = ("D",) if args.quick else ROADS
    plan = [
        RunSpec(f"pf_qc_{road}", _GROUP_TABLE4, i, "quarter_car", road, _PATH_SOILS, stretch, SPEED, 3 * stretch, ())
        for road in roads
        for i in range(seeds)
    ]
    lrv_duration = 2 * stretch
    plan += [
        RunSpec("pf_lrv", _GROUP_LRV, i, "lrv", "G", (LRV_SOIL,), lrv_duration, LRV_SPEED, lrv_duration, ())
        for i in range(seeds)
    ]
    with Runner(args.jobs, scheduler=args.scheduler, what="simulated rides") as runner:
        rides = runner.map(run_ride, plan, weight=lambda s: s.duration, key=lambda s: f"{s.key}-{s.run}")
        results = dict(sorted(collect(plan, rides).items()))
        table = summarise(results, stretch)
        lrv = summarise_lrv(results["pf_lrv"], lrv_duration)
        prov = Provenance.of("terrain_analysis.tools.reproduce_qc_profile_free", given, runner, quick=args.quick)
    header = [
        *provenance_lines(prov),
        f"- Seeds: run i uses `SeedSequence([8608, {_GROUP_TABLE4}, i])` (the Table 4 group of `reproduce_qc`).",
    ]
    text = render(table, header, seeds) + render_lrv(lrv, seeds, lrv_duration)
    write_section(out, SECTION, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
