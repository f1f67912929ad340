"""Are the soil-stiffness node's published variances held to its errors? Truth runs of the quarter car and LRV.

``python -m terrain_analysis.tools.qc_consistency [--out docs/results/quarter_car.md] [--jobs 2] [--seeds N]``

Issue 21, item 1 for the quarter car and the LRV. The estimator runs with the
node's parameter defaults (:func:`~terrain_analysis.tools.reproduce_qc.node_default_config`)
on truth runs of :mod:`vehicle_sim.plants.quarter_car` (RK4 at 1 ms over an
exact ISO 8608 road, accelerometers at 100 Hz, profile at 1 kHz with
σ_h = 0.1 mm):

* **nominal**: the plant the observer models, several soils, roads, speeds and
  seeds per vehicle;
* **model error**: one effect of the sim-to-real catalogue
  (:data:`vehicle_sim.effects.CATALOGUE`) switched on at its catalogue
  ``typical`` value — the plant has it, the observer does not. The plant is
  not changed to suit the observer.

Per published quantity of ``terrain_msgs/SoilStiffness`` with a variance
(``k_s``, ``k_tot``) and for the filter's stiffness state (``ln k_s`` with the
node defaults; ``k_s`` and ``k_tot`` are first-order transforms of that one
scalar, so their joint NEES has 1 dof and is this row): errors e = estimate −
truth (the plant's ``truth.k_s`` / ``truth.k_tot`` at the estimate's stamp),
pooled over every run after the settling time :data:`SETTLE_S` (excluded and
stated): mean e²/σ², share of |e| ≤ 2σ, and the share of 2 s NEES windows inside
their 95 % band with the effective sample count of
:func:`~terrain_estimation.analysis.consistency.window_share`. The published
NIS (accepted updates, χ² with 2 dof on the quarter car, 1 on the LRV) is
reported beside. The section goes into the page through
:func:`~terrain_analysis.reporting.write_section`.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from terrain_analysis.experiment import Runner
from terrain_analysis.reporting import Provenance, provenance_sentence, reproduction_arguments, write_section
from terrain_analysis.tools.qc_runs import node_default_config
from terrain_estimation.analysis.consistency import consistency_report, window_share
from terrain_estimation.cli import cli_main
from terrain_estimation.estimators.soil_stiffness import SoilStiffnessEstimator

__all__ = ["SETTLE_S", "Case", "QuantityStats", "build_plan", "run_case", "pool", "main"]

ROOT_SEED = 2121
"""Seeds: case ``(vehicle, i, seed)`` uses ``SeedSequence([2121, vehicle index, i, seed])`` → (road, noise)."""
SETTLE_S = 5.0
"""Settling time excluded from every figure (s): the LRV's median time to stay below 5 % is ≈ 4 s (case 5)."""
QUANTITIES = ("k_s", "k_tot", "ln k_s (state)")
NOMINAL_E2 = (0.5, 2.0)
NOMINAL_IN2 = (0.90, 0.98)

# (soil, ISO class, speed m/s) of the nominal cells; model-error runs use the first cell.
_CELLS: dict[str, tuple[tuple[str, str, float], ...]] = {
    "quarter_car": (
        ("graneville_loam", "D", 10.0),
        ("graneville_loam", "C", 5.0),
        ("upland_sandy_loam", "D", 10.0),
        ("upland_sandy_loam", "E", 5.0),
        ("lete_sand", "D", 10.0),
        ("north_gower_clayey_loam", "F", 10.0),
    ),
    "lrv": (
        ("lunar_regolith", "G", 2.0),
        ("lunar_regolith", "F", 2.0),
        ("lunar_regolith", "G", 1.0),
        ("lunar_regolith", "H", 1.0),
        ("lunar_regolith", "F", 4.0),
    ),
}
# Catalogue effects used as model error (those the LRV's simulator accepts for "lrv").
_EFFECTS: dict[str, tuple[str, ...]] = {
    "quarter_car": (
        "tire_damping",
        "nonlinear_soil",
        "sensor_delay",
        "sprung_mass_change",
        "tire_enveloping",
        "accel_scale",
        "accel_bias",
        "suspension_friction",
    ),
    "lrv": ("nonlinear_soil", "sensor_delay", "sprung_mass_change", "tire_enveloping", "accel_scale", "accel_bias"),
}


@dataclass(frozen=True)
class Case:
    """One truth run: ``effect`` "" is the nominal plant, else a catalogue effect at its typical value."""

    vehicle: str
    cell: int
    soil: str
    road: str
    speed: float
    seed: int
    duration: float
    effect: str = ""

    @property
    def label(self) -> str:
        base = f"{self.soil} ISO {self.road} {self.speed:g} m/s"
        return f"{self.effect} ({base})" if self.effect else base


def effect_values(vehicle: str, effect: str) -> dict[str, Any]:
    """The plant's effects fields of catalogue ``effect`` at its typical value."""
    from vehicle_sim.effects import CATALOGUE

    return {p.field: p.typical for p in CATALOGUE[vehicle][effect].parameters if p.index is None}


def build_plan(seeds: int, duration: float, *, effects: bool = True) -> list[Case]:
    """Nominal cells × ``seeds`` and (``effects``) every model-error effect × max(1, seeds − 1) per vehicle."""
    plan: list[Case] = []
    for vehicle, cells in _CELLS.items():
        for i, (soil, road, speed) in enumerate(cells):
            plan += [Case(vehicle, i, soil, road, speed, s, duration) for s in range(seeds)]
        if effects:
            soil, road, speed = cells[0]
            for j, effect in enumerate(_EFFECTS[vehicle]):
                plan += [
                    Case(vehicle, 100 + j, soil, road, speed, s, duration, effect) for s in range(max(1, seeds - 1))
                ]
    return plan


def run_case(case: Case) -> tuple[Case, dict[str, np.ndarray]]:
    """Simulate ``case`` and run the node-default estimator; arrays at the filter rate."""
    from vehicle_sim.plants.quarter_car import (
        LRVVehicle,
        QuarterCarEffects,
        QuarterCarVehicle,
        Scenario,
        SpeedProfile,
        simulate,
    )
    from vehicle_sim.terrain.profiles import iso8608_profile
    from vehicle_sim.terrain.soils import SoilPath, soil_by_name

    v_index = list(_CELLS).index(case.vehicle)
    road_seed, noise_seed = np.random.SeedSequence([ROOT_SEED, v_index, case.cell, case.seed]).generate_state(2)
    effects = QuarterCarEffects(**effect_values(case.vehicle, case.effect)) if case.effect else QuarterCarEffects()
    scenario = Scenario(
        profile=iso8608_profile(case.road, int(road_seed)),
        soil_path=SoilPath(soil_by_name(case.soil)),
        speed=SpeedProfile.constant(case.speed),
        effects=effects,
    )
    vehicle = QuarterCarVehicle() if case.vehicle == "quarter_car" else LRVVehicle()
    sim = simulate(vehicle, scenario, case.duration, seed=int(noise_seed))
    est = SoilStiffnessEstimator(node_default_config(case.vehicle))
    pt, ps, ph = sim.profile.t.tolist(), sim.profile.distance.tolist(), sim.profile.elevation.tolist()
    body = sim.body_accel_z.tolist()
    wheel = sim.wheel_accel_z.tolist() if sim.wheel_accel_z is not None else [None] * len(body)
    rows: list[tuple[float, ...]] = []
    j = 0
    for i, t in enumerate(sim.t.tolist()):
        while j < len(pt) and pt[j] <= t + 1e-9:
            est.add_profile_sample(pt[j], ps[j], ph[j])
            j += 1
        est.add_accelerations(t, body[i], wheel[i])
        for e in est.drain_estimates():
            nis = e.nis if e.accepted else math.nan
            rows.append((e.t, e.k_s, e.k_s_variance, e.k_tot, e.k_tot_variance, nis))
    a = np.asarray(rows, dtype=float)
    t = a[:, 0]
    return case, {
        "t": t,
        "k_s": a[:, 1],
        "k_s_var": a[:, 2],
        "k_tot": a[:, 3],
        "k_tot_var": a[:, 4],
        "nis": a[:, 5],
        "k_s_true": np.interp(t, sim.t, np.asarray(sim.truth.k_s, dtype=float)),
        "k_tot_true": np.interp(t, sim.t, np.asarray(sim.truth.k_tot, dtype=float)),
    }


def _errors(run: dict[str, np.ndarray], variance_scale: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(error, published variance × ``variance_scale``) per quantity; ln k_s from the published k_s and its variance."""
    ln_var = run["k_s_var"] / run["k_s"] ** 2
    return {
        "k_s": (run["k_s"] - run["k_s_true"], variance_scale * run["k_s_var"]),
        "k_tot": (run["k_tot"] - run["k_tot_true"], variance_scale * run["k_tot_var"]),
        "ln k_s (state)": (np.log(run["k_s"] / run["k_s_true"]), variance_scale * ln_var),
    }


@dataclass
class QuantityStats:
    """Pooled figures of one quantity over runs (after the settling time unless ``early``)."""

    n: int = 0
    sum_e2: float = 0.0
    inside: int = 0
    windows: int = 0
    windows_in: int = 0
    above: int = 0
    below: int = 0
    taus: list[float] | None = None
    rel_e2: float = 0.0
    rel_var: float = 0.0
    early_e2: float = 0.0
    early_n: int = 0
    zero_var: int = 0

    @property
    def mean_e2(self) -> float:
        return self.sum_e2 / self.n if self.n else math.nan

    @property
    def within_2sigma(self) -> float:
        return self.inside / self.n if self.n else math.nan

    @property
    def window_share(self) -> float:
        return self.windows_in / self.windows if self.windows else math.nan

    def meets(self) -> bool:
        return NOMINAL_E2[0] <= self.mean_e2 <= NOMINAL_E2[1] and NOMINAL_IN2[0] <= self.within_2sigma <= NOMINAL_IN2[1]


def pool(
    runs: Sequence[tuple[Case, dict[str, np.ndarray]]], variance_scale: float = 1.0
) -> tuple[dict[str, QuantityStats], tuple[float, float, int]]:
    """Per-quantity pooled figures, and (mean NIS, share of 2 s NIS windows in band, NIS windows)."""
    stats = {q: QuantityStats(taus=[]) for q in QUANTITIES}
    nis_sum, nis_n, nis_win, nis_in = 0.0, 0, 0, 0
    for case, run in runs:
        t = run["t"]
        late = t > SETTLE_S
        for name, (e, var) in _errors(run, variance_scale).items():
            s = stats[name]
            use = late & (var > 0.0)
            s.zero_var += int(np.count_nonzero(late & ~(var > 0.0)))  # σ² = 0 (stiffness at its clamp): not scored
            rep = consistency_report(t[use], e[use, None], var[use, None, None], [name])
            q = rep.quantity(name)
            if q.samples == 0:
                continue
            s.n += q.samples
            s.sum_e2 += q.mean_normalised * q.samples
            s.inside += round(q.within_2sigma * q.samples)
            w = rep.nees_windows
            s.windows += w.windows
            s.windows_in += w.inside
            s.above += w.above
            s.below += w.below
            assert s.taus is not None
            s.taus.append(w.tau)
            scale = run["k_s_true"] if name == "k_s" else run["k_tot_true"] if name == "k_tot" else 1.0
            s.rel_e2 += float(np.sum((e / scale)[use] ** 2))
            s.rel_var += float(np.sum((var / scale**2)[use]))
            early = ~late & (var > 0.0)
            s.early_e2 += float(np.sum(e[early] ** 2 / var[early]))
            s.early_n += int(np.count_nonzero(early))
        dof = 2 if case.vehicle == "quarter_car" else 1
        nis = run["nis"][late]
        ok = np.isfinite(nis)
        nis_sum += float(np.sum(nis[ok]))
        nis_n += int(np.count_nonzero(ok))
        ws = window_share(nis[ok], t[late][ok], dof)
        nis_win += ws.windows
        nis_in += ws.inside
    return stats, (nis_sum / max(nis_n, 1), nis_in / max(nis_win, 1), nis_win)


def _order(case: Case) -> tuple[str, str, int, int]:
    """The order of the runs in the section's tables: vehicle, effect, cell, seed."""
    return case.vehicle, case.effect, case.cell, case.seed


def _f(x: float, d: int = 2) -> str:
    return "—" if not math.isfinite(x) else (f"{x:.3g}" if x != 0 and abs(x) < 10**-d else f"{x:.{d}f}")


def quantity_table(stats: dict[str, QuantityStats], nis: tuple[float, float, int], dof: int, nominal: bool) -> str:
    """Markdown table of the pooled per-quantity figures."""
    lines = [
        f"| quantity | samples | mean e²/σ² | within 2σ | NEES windows in 95 % band (above / below) | τ median | "
        f"RMS rel. error | RMS rel. σ | mean e²/σ² 0–{SETTLE_S:g} s |" + (" meets? |" if nominal else ""),
        "|---|---|---|---|---|---|---|---|---|" + ("---|" if nominal else ""),
    ]
    for name, s in stats.items():
        rel = "—" if name.startswith("ln") else f"{100 * math.sqrt(s.rel_e2 / max(s.n, 1)):.2f} %"
        rsig = "—" if name.startswith("ln") else f"{100 * math.sqrt(s.rel_var / max(s.n, 1)):.2f} %"
        cells = [
            name,
            str(s.n) + (f" (+{s.zero_var} with σ² = 0, not scored)" if s.zero_var else ""),
            _f(s.mean_e2),
            f"{100 * s.within_2sigma:.1f} %",
            f"{100 * s.window_share:.0f} % of {s.windows} ({s.above} / {s.below})",
            _f(float(np.median(s.taus)) if s.taus else math.nan, 0),
            rel,
            rsig,
            _f(s.early_e2 / max(s.early_n, 1)),
        ]
        if nominal:
            cells.append("yes" if s.meets() else "**no**")
        lines.append("| " + " | ".join(cells) + " |")
    lines.append(
        f"| NIS (χ²_{dof}, accepted updates) | | mean {_f(nis[0])} (consistent: {dof}) | | "
        f"{100 * nis[1]:.0f} % of {nis[2]} 2 s windows in band | | | | |" + (" |" if nominal else "")
    )
    return "\n".join(lines)


def cell_table(runs: Sequence[tuple[Case, dict[str, np.ndarray]]]) -> str:
    """k_s figures per cell (scenario), pooled over its seeds."""
    lines = [
        "| scenario | runs | k_s mean e²/σ² | k_s within 2σ | k_s RMS rel. error | RMS rel. σ | mean NIS |",
        "|---|---|---|---|---|---|---|",
    ]
    for label in dict.fromkeys(c.label for c, _ in runs):
        sel = [r for r in runs if r[0].label == label]
        st, nis = pool(sel)
        s = st["k_s"]
        lines.append(
            f"| {label} | {len(sel)} | {_f(s.mean_e2)} | {100 * s.within_2sigma:.1f} % | "
            f"{100 * math.sqrt(s.rel_e2 / max(s.n, 1)):.2f} % | {100 * math.sqrt(s.rel_var / max(s.n, 1)):.2f} % | "
            f"{_f(nis[0])} |"
        )
    return "\n".join(lines)


def section(results: Sequence[tuple[Case, dict[str, np.ndarray]]], provenance: Provenance) -> str:
    """The page section (Markdown)."""
    text = [
        "## Consistency of the published variances (issue 21, item 1)",
        "",
        f"{provenance_sentence(provenance)} Estimator: the node's parameter defaults "
        "(`config/<vehicle>.yaml`: SCKF, state ln k_s, soil-change detector on). Truth: "
        "`vehicle_sim.plants.quarter_car.simulate` (RK4 1 ms, accelerometers 100 Hz with 0.5 (m/s²)², profile "
        f"1 kHz with σ_h = 0.1 mm). Seeds: `SeedSequence([{ROOT_SEED}, vehicle, cell, seed])` → (road, noise). "
        f"**The first {SETTLE_S:g} s of every run (settling from the start guess) are excluded** from every figure "
        "except the last column. Errors e = estimate − truth, truth = the plant's `truth.k_s` / `truth.k_tot`; "
        "`ln k_s (state)` is the filter's stiffness state (its σ² = var k_s / k̂_s²): k_s and k_tot are "
        "first-order transforms of this one scalar, so their joint NEES has 1 dof and is this row. NEES "
        "windows: 2 s windows whose mean e²/σ² lies inside the 95 % band of a mean of χ²₁ values with the "
        "effective count N/τ (τ the integrated autocorrelation time of the run's NEES, reported). Criterion "
        f"(issue 21): mean e²/σ² in [{NOMINAL_E2[0]:g}, {NOMINAL_E2[1]:g}] and {100 * NOMINAL_IN2[0]:.0f}–"
        f"{100 * NOMINAL_IN2[1]:.0f} % within 2σ, per quantity, nominal scenarios. Model error: one catalogue "
        "effect (`vehicle_sim.effects.CATALOGUE`) at its `typical` value in the plant, not in the observer; "
        "the nonlinear soil (n = 1.2) has tangent stiffness n·k_s at the static sinkage, and the error is "
        "still taken against the plant's k_s.",
    ]
    failing: list[str] = []
    for vehicle, name in (("quarter_car", "Quarter car"), ("lrv", "LRV")):
        dof = 2 if vehicle == "quarter_car" else 1
        nominal = [r for r in results if r[0].vehicle == vehicle and not r[0].effect]
        error = [r for r in results if r[0].vehicle == vehicle and r[0].effect]
        for kind, runs in (("nominal", nominal), ("model error", error)):
            if not runs:
                continue
            st, nis = pool(runs)
            text += ["", f"### {name}, {kind} ({len(runs)} runs of {runs[0][0].duration:g} s)", ""]
            text += [quantity_table(st, nis, dof, kind == "nominal"), "", cell_table(runs)]
            if kind == "nominal":
                failing += [
                    f"{name} {q} (e²/σ² {_f(s.mean_e2)}, {100 * s.within_2sigma:.1f} % within 2σ: "
                    + (
                        "cautious"
                        if s.within_2sigma > NOMINAL_IN2[1] or s.mean_e2 < NOMINAL_E2[0]
                        else "over-confident"
                    )
                    + ")"
                    for q, s in st.items()
                    if not s.meets()
                ]
    text += ["", "### Where the criterion is not met, and why", ""]
    text += [
        f"- Not met (nominal): {', '.join(failing)}." if failing else "- Every quantity meets it in the nominal runs."
    ]
    text += [WHY, *model_error_notes(results)]
    return "\n".join(text)


def model_error_notes(results: Sequence[tuple[Case, dict[str, np.ndarray]]]) -> list[str]:
    """Per model-error effect whose k_s misses the 2σ range: its bias, whether the NIS shows it, clamp hits."""
    notes = []
    for case0 in dict.fromkeys(c for c, _ in results if c.effect and c.seed == 0):
        sel = [r for r in results if r[0].vehicle == case0.vehicle and r[0].effect == case0.effect]
        st, nis = pool(sel)
        s, dof = st["k_s"], (2 if case0.vehicle == "quarter_car" else 1)
        if s.within_2sigma >= NOMINAL_IN2[0]:
            continue
        bias = np.concatenate([(r["k_s"] / r["k_s_true"] - 1.0)[r["t"] > SETTLE_S] for _, r in sel])
        shown = "the NIS shows it" if nis[1] < 0.8 else "the NIS does not show it (the innovations look nominal)"
        clamp = f"; k_tot's σ² = 0 at the clamp in {st['k_tot'].zero_var} samples" if st["k_tot"].zero_var else ""
        notes.append(
            f"  - {case0.vehicle} {case0.effect}: median k_s error {100 * float(np.median(bias)):+.1f} %, "
            f"{100 * s.within_2sigma:.0f} % within 2σ, mean NIS {_f(nis[0])} (dof {dof}), {100 * nis[1]:.0f} % of "
            f"NIS windows in band (nominal ≈ 95 %): {shown}{clamp}."
        )
    return notes


WHY = (
    "- Why the nominal figures sit on the cautious side: the filter models the stiffness as a random walk "
    "(`filter.q_log_ks_per_step`, so that it can follow a soil change) while the plant's soil is constant "
    "along a run. For a scalar random walk of gain K the posterior variance is P = K·R_eff but the error of a "
    "constant is only the filtered noise, K·R_eff/(2 − K) ≈ P/2; the rest of the error is a bias of the model "
    "(the road between the profile samples, profile noise in the regressor, MODELS.md A.10), which the walk's "
    "variance happens to cover. Pooled, the sum stays inside the e²/σ² band but a few per cent too many errors "
    "lie within 2σ (a Gaussian with e²/σ² = 0.6 puts 99 % there); per scenario e²/σ² spreads on both sides "
    "(tables above), so no single rescaling of σ would fix every scenario. The walk is not retuned to pass "
    "this check: a smaller walk narrows σ below the bias and slows the tracking of a soil change (issue 21, "
    "item 4).\n"
    "- Under model error the errors carry a bias that no variance of this model can know; e²/σ² measures "
    "that bias in σ. The nonlinear soil's error is taken against the plant's k_s (its tangent stiffness at the "
    "static sinkage is n·k_s). Effects whose k_s errors are not within 2σ in 90 % of the samples:"
)


@cli_main("qc-consistency")
def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    args, argv_list = reproduction_arguments(
        "python -m terrain_analysis.tools.qc_consistency",
        (__doc__ or "").splitlines()[0],
        argv,
        runs_flag="--seeds",
        runs_help="seeds per nominal cell (default 5; model-error effects use seeds − 1)",
        quick_help="smoke run: 1 seed, 12 s runs",
        extra=(("--duration", {"type": float, "default": 30.0, "help": "run length (s), default 30"}),),
    )
    seeds = args.seeds or (1 if args.quick else 5)
    duration = 12.0 if args.quick else args.duration
    out = Path(args.out)
    if out.suffix.lower() != ".md":
        out = out / "quarter_car.md"
    plan = build_plan(seeds, duration)
    print(f"qc_consistency: {len(plan)} runs of {duration:g} s on {args.jobs} process(es)", file=sys.stderr)
    with Runner(args.jobs, scheduler=args.scheduler, what="truth runs") as runner:
        results = runner.map(
            run_case, plan, weight=lambda c: c.duration, key=lambda c: f"{c.vehicle}-{c.cell}-{c.seed}"
        )
        results.sort(key=lambda r: _order(r[0]))
        text = section(results, Provenance.of("terrain_analysis.tools.qc_consistency", argv_list, runner))
    write_section(out, "qc-consistency", text)
    print(text)
    print(f"\nsection written to {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
