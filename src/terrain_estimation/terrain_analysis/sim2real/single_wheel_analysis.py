"""The rig's analyses: train/held-out splits, the empirical baseline, the stresses at the measured sinkage,
identifiability on simulated trials (:mod:`terrain_analysis.sim2real.single_wheel`)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.single_wheel_data import RigTrials
from terrain_analysis.sim2real.single_wheel_model import PHYSICAL_RANGES, SingleWheelModel, candidates
from terrain_analysis.sim2real.single_wheel_physics import (
    NOMINAL,
    RIG_WHEEL,
    WheelGeometry,
    WheelSoil,
    bulldozing_resistance,
    contact_angle_of_sinkage,
    rim_stresses,
)

__all__ = [
    "BASELINE_BIN_WIDTH",
    "REGIMES",
    "Analysis",
    "analyses",
    "baseline_comparison",
    "consistency_at_measured_sinkage",
    "identifiability",
    "slip_binned_baseline",
    "strongest_stress_field",
    "synthetic_trials",
]

FloatArray = NDArray[np.float64]


def _regime(slip: float) -> str:
    if slip < -0.1:
        return "braking"
    if slip <= 0.3:
        return "low slip"
    return "high slip"


REGIMES = ("braking", "low slip", "high slip")
"""Slip regimes of the where-table: braking i < −0.1, low slip −0.1 ≤ i ≤ 0.3, high slip i > 0.3."""


@dataclass(frozen=True)
class Analysis:
    """One attribution run: which trials the model holds and which of them are held out.

    Attributes:
        name: Short key.
        description: The split in words.
        keep: Over all β = 0 trials: the trials of this run.
        held_out: Over the kept trials: True = scored, False = fitted.
    """

    name: str
    description: str
    keep: NDArray[np.bool_]
    held_out: NDArray[np.bool_]


def _slips_text(trials: RigTrials, groups: NDArray[np.int_]) -> str:
    return ", ".join(f"{trials.slip[trials.group == g].mean():+.2f}" for g in groups)


def analyses(trials: RigTrials) -> list[Analysis]:
    """The train/held-out splits of the driver.

    * ``alternate``: all trials; fit on every other commanded slip, score on the slips between.
    * ``drive_to_brake``: fit on i ≥ 0, score on braking (i < 0).
    * ``brake_to_drive``: fit on braking, score on i ≥ 0.
    * ``drive_only``: the i ≥ 0 trials alone (the regime the model is made for):
      fit on every other drive slip starting with the second, score on the rest
      (the engine's noise tests need ≥ 8 held-out trials per channel, so three of five slips are held out).
    """
    everything = np.ones(trials.size, dtype=bool)
    groups = np.unique(trials.group)
    brake = trials.slip < -0.01
    out = [
        Analysis(
            "alternate",
            f"all trials; fit on slips {_slips_text(trials, groups[0::2])}, "
            f"score on {_slips_text(trials, groups[1::2])}",
            everything,
            np.isin(trials.group, groups[1::2]),
        ),
        Analysis("drive_to_brake", "all trials; fit on drive (i ≥ 0), score on braking (i < 0)", everything, brake),
        Analysis("brake_to_drive", "all trials; fit on braking (i < 0), score on drive (i ≥ 0)", everything, ~brake),
    ]
    drive_groups = np.unique(trials.group[~brake])
    if drive_groups.size >= 4:
        held = drive_groups[0::2]
        out.append(
            Analysis(
                "drive_only",
                f"drive trials only; fit on slips {_slips_text(trials, drive_groups[1::2])}, "
                f"score on {_slips_text(trials, held)}",
                ~brake,
                np.isin(trials.group[~brake], held),
            )
        )
    return out


BASELINE_BIN_WIDTH = 0.25
"""Width of the slip bins of the empirical baseline (:func:`slip_binned_baseline`)."""


def slip_binned_baseline(
    slip: FloatArray, values: FloatArray, train: NDArray[np.bool_], width: float = BASELINE_BIN_WIDTH
) -> tuple[FloatArray, int]:
    """The field engineer's empirical model: per slip bin, the mean of the training trials in it.

    Bins of ``width`` over [−1, 1] (the last one closed). A trial whose bin
    has no training trial takes the mean of the nearest bins that have some
    (by bin index; both neighbours averaged on a tie): a flat extrapolation
    beyond the training slips, an average of the two sides between them.

    Returns:
        (prediction of every trial, number of bin means fitted).
    """
    if not np.any(train):
        raise ValueError("the baseline needs at least one training trial")
    edges = int(round(2.0 / width))
    index = np.clip(np.floor((np.asarray(slip, dtype=float) + 1.0) / width).astype(int), 0, edges - 1)
    means = {int(b): float(np.mean(values[train & (index == b)])) for b in np.unique(index[train])}
    filled = np.array(sorted(means))
    out = np.empty(slip.shape, dtype=float)
    for k, b in enumerate(index):
        if int(b) in means:
            out[k] = means[int(b)]
            continue
        distance = np.abs(filled - b)
        nearest = filled[distance == distance.min()]
        out[k] = float(np.mean([means[int(n)] for n in nearest]))
    return out, len(means)


def baseline_comparison(model: SingleWheelModel, held_out: NDArray[np.bool_], report: Any) -> dict[str, Any]:
    """Held-out χ² (Σ (r/σ)² over held-out trials and channels) of the nominal model, the verdict's model
    (the engine's best, fitted on the training trials) and the slip-binned mean baseline (fitted on the same
    training trials), with their parameter counts and penalised scores χ² + p ln n (the engine's score)."""
    train = ~held_out
    t = model.trials
    n = 2 * int(held_out.sum())
    rows: dict[str, Any] = {}
    best = report.best
    models = {"nominal": (model.predict({}, {}), 0)}
    if best is not None:
        models[best.name] = (model.predict(best.parameters, {}), int(best.added))
    baseline = {}
    bins = 0
    for ch in model.channels:
        baseline[ch.name], bins = slip_binned_baseline(t.slip, model.measured[ch.name], train)
    models["slip-binned mean"] = (baseline, 2 * bins)
    for name, (pred, params) in models.items():
        per_channel = {}
        chi2 = 0.0
        for ch in model.channels:
            r = (model.measured[ch.name] - pred[ch.name])[held_out] / ch.noise_std
            per_channel[ch.name] = float(np.sqrt(np.mean(r**2)))
            chi2 += float(np.sum(r**2))
        rows[name] = {
            "chi2": chi2,
            "parameters": params,
            "score": chi2 + params * math.log(max(n, 2)),
            "rms_sigma": per_channel,
        }
    physics = best.name if best is not None else "nominal"
    return {
        "models": rows,
        "physics": physics,
        "physics_beats_baseline": rows[physics]["score"] < rows["slip-binned mean"]["score"],
        "held_out_samples": n,
    }


def regime_table(model: SingleWheelModel, predictions: Mapping[str, Mapping[str, FloatArray]]) -> list[dict[str, Any]]:
    """Bias and RMS (also in σ) of the residuals rig − model per slip regime, channel and model."""
    rows = []
    labels = np.array([_regime(s) for s in model.trials.slip])
    for regime in REGIMES:
        sel = labels == regime
        if not np.any(sel):
            continue
        for ch in model.channels:
            row: dict[str, Any] = {
                "regime": regime,
                "channel": ch.name,
                "unit": ch.unit,
                "trials": int(sel.sum()),
                "slips": sorted({round(float(s), 2) for s in model.trials.slip[sel]}),
                "models": {},
            }
            for name, pred in predictions.items():
                r = model.measured[ch.name][sel] - pred[ch.name][sel]
                row["models"][name] = {
                    "bias": float(np.mean(r)),
                    "rms": float(np.sqrt(np.mean(r**2))),
                    "rms_sigma": float(np.sqrt(np.mean(r**2)) / ch.noise_std),
                }
            rows.append(row)
    return rows


def consistency_at_measured_sinkage(trials: RigTrials, p: WheelSoil = NOMINAL) -> list[dict[str, float]]:
    """Per commanded slip: the load and drawbar pull the model's rim stresses give at the *measured* sinkage.

    θ0 = acos(1 − z/r) from the group's mean sinkage, then eqs. 7–8 at the
    group's mean slip (skid: the stresses at the skid itself, as with
    ``skid_stresses``; the nominal anti-symmetry has no stress field in skid).
    This separates the two halves of the model: W_model/W_measured ≠ 1 says
    the pressure–sinkage law is off (the soil carries the load at another
    depth), DP/W of the model against the rig's says the stress distribution
    (θ_m, shear, rear contact) is, whatever the sinkage law.
    """
    q = dataclasses.replace(p, skid_stresses=True)
    rows = []
    for g in np.unique(trials.group):
        sel = trials.group == g
        slip = float(trials.slip[sel].mean())
        z = float(trials.sinkage[sel].mean()) / 1000.0
        theta0 = contact_angle_of_sinkage(z, q.radius)
        n = q.n + (q.n_skid if slip < 0.0 else q.n_slip) * abs(slip)
        load, dp, _ = rim_stresses(theta0, slip, n, q)
        w_meas = float(trials.load[sel].mean())
        dp_meas = float(trials.drawbar_pull[sel].mean())
        rows.append(
            {
                "slip": slip,
                "sinkage_mm": 1000.0 * z,
                "load_measured": w_meas,
                "load_model": float(load),
                "drawbar_pull_measured": dp_meas,
                "drawbar_pull_model": float(dp),
                "dp_over_w_measured": dp_meas / w_meas,
                "dp_over_w_model": float(dp / load) if load > 0 else 0.0,
            }
        )
    return rows


def strongest_stress_field(
    slip: float, sinkage_mm: float, load: float, base: WheelSoil = NOMINAL, points: int = 5
) -> dict[str, Any]:
    """Most negative DP/W the rim stresses can give at a measured (slip, sinkage, load) within the fit ranges.

    A grid (``points`` values per parameter) over the candidates' fit ranges of
    φ, cohesion, K, n, c1 and the rear-contact ratio λ, stresses at the skid
    itself (``skid_stresses``); for each combination the modulus k is the one
    that carries the measured load at the measured sinkage (W and DP are
    linear in k at fixed θ0), combinations needing k ≤ 0 are skipped. Bounds
    what any re-parameterised Wong–Reece wheel can resist with there.
    """
    theta0 = contact_angle_of_sinkage(sinkage_mm / 1000.0, base.radius)
    best: dict[str, Any] = {"dp_over_w": 0.0, "parameters": {}}
    grid = np.linspace(0.0, 1.0, points)
    for phi, cohesion, shear, n, c1, rear in itertools.product(
        base.friction_angle - 0.15 + 0.30 * grid,
        5.0 * base.cohesion * grid,
        base.shear_modulus * (0.25 + 3.75 * grid),
        0.6 + 1.6 * grid,
        0.02 + 0.58 * grid,
        grid,
    ):
        p = dataclasses.replace(
            base, friction_angle=float(phi), cohesion=float(cohesion), shear_modulus=float(shear), n=float(n),
            c1=float(c1), rear_ratio=float(rear), skid_stresses=True,
        )  # fmt: skip
        w0, d0, _ = rim_stresses(theta0, slip, p.n, dataclasses.replace(p, k_c=0.0, k_phi=0.0))
        w1, d1, _ = rim_stresses(theta0, slip, p.n, p)
        if w1 - w0 <= 0.0:
            continue
        scale = (load - w0) / (w1 - w0)
        if scale <= 0.0:
            continue
        ratio = (d0 + scale * (d1 - d0)) / load
        if ratio < best["dp_over_w"]:
            best = {
                "dp_over_w": float(ratio),
                "parameters": {
                    "friction_angle_deg": math.degrees(float(phi)),
                    "cohesion": float(cohesion),
                    "shear_modulus": float(shear),
                    "sinkage_exponent": float(n),
                    "max_stress_angle_c1": float(c1),
                    "rear_angle_ratio": float(rear),
                    "modulus_scale": float(scale),
                },
            }
    return best


def synthetic_trials(
    trials: RigTrials,
    effects: Mapping[str, Mapping[str, float]],
    noise: Mapping[str, float],
    seed: int,
    geometry: WheelGeometry = RIG_WHEEL,
) -> RigTrials:
    """The rig's slips and loads; channels from the model with ``effects`` plus Gaussian noise of std ``noise``."""
    rng = np.random.default_rng(seed)
    clean = SingleWheelModel(trials, geometry=geometry).predict(effects, {})
    return dataclasses.replace(
        trials,
        drawbar_pull=clean["drawbar_pull"] + rng.normal(0.0, noise["drawbar_pull"], trials.size),
        sinkage=clean["sinkage"] + rng.normal(0.0, noise["sinkage"], trials.size),
        source=f"synthetic (seed {seed})",
    )


def identifiability(
    trials: RigTrials,
    noise: Mapping[str, tuple[float, int]],
    seeds: Sequence[int] = (1, 2),
    *,
    settings: Any = None,
    progress: Any = None,
    geometry: WheelGeometry = RIG_WHEEL,
) -> list[dict[str, Any]]:
    """Can the rig's design tell the candidates apart? Simulated trials, one effect each, diagnosed blind.

    For every candidate (parameters at off + one typical change, inside the
    fit range) and a no-effect control: trials at the rig's slips and loads,
    channels from the model plus noise at the budget σ, then the ``alternate``
    split of :func:`analyses` through the engine. Returns one row per case and seed.
    """
    from terrain_analysis.sim2real.attribution import AttributionSettings, attribute

    settings = settings or AttributionSettings()
    sd = {name: value[0] for name, value in noise.items()}
    cases: list[tuple[str, dict[str, dict[str, float]]]] = [("nominal", {})]
    for name, cand in candidates(
        dataclasses.replace(NOMINAL, radius=geometry.radius, width=geometry.width), geometry
    ).items():
        values = {}
        for p in cand.parameters:
            up = p.off + p.scale
            values[p.name] = up if up <= p.bounds[1] else p.off - p.scale
        cases.append((name, {name: values}))
    split = analyses(trials)[0]
    rows = []
    for truth, effects in cases:
        for seed in seeds:
            model = SingleWheelModel(
                synthetic_trials(trials, effects, sd, seed, geometry), noise=noise, geometry=geometry
            )
            report = attribute(model, settings=settings, test_mask={ch.name: split.held_out for ch in model.channels})
            best = report.best.name if report.kind != "no_gap" and report.best is not None else ""
            row = {
                "truth": truth,
                "values": effects.get(truth, {}),
                "seed": seed,
                "kind": report.kind,
                "best": best,
                "correct": best == truth if truth != "nominal" else report.kind == "no_gap",
                "shrinkage": report.shrinkage if best else 0.0,
                "fitted": report.best.parameters.get(truth, {}) if report.best is not None and best == truth else {},
                "indistinguishable": report.indistinguishable,
                "verdict": report.verdict,
            }
            rows.append(row)
            if progress is not None:
                progress(f"identifiability: {truth} (seed {seed}) -> {report.verdict}")
    return rows


def bulldozing_at_measured_sinkage(trials: RigTrials, base: WheelSoil) -> float:
    """Wong's bulldozing resistance (κ = 1, N) at the most-braked slip's mean measured sinkage."""
    locked = trials.group == trials.group[int(np.argmin(trials.slip))]
    z = float(trials.sinkage[locked].mean()) / 1000.0
    slip = float(trials.slip[locked].mean())
    theta0 = math.acos(min(max(1.0 - z / base.radius, -1.0), 1.0))
    return float(bulldozing_resistance(np.array([z]), np.array([slip]), np.array([theta0]), base)[0])


def strongest_locked(trials: RigTrials, base: WheelSoil) -> dict[str, Any]:
    locked = trials.group == trials.group[int(np.argmin(trials.slip))]
    slip = float(trials.slip[locked].mean())
    sinkage = float(trials.sinkage[locked].mean())
    load = float(trials.load[locked].mean())
    return {"slip": slip, "sinkage_mm": sinkage, "load": load, **strongest_stress_field(slip, sinkage, load, base)}


def at_bounds(model: SingleWheelModel, report: Any) -> list[str]:
    """Fitted parameters of the ranked models that ended on a bound of their fit range or outside their
    physically plausible range (:data:`PHYSICAL_RANGES`): not a physical explanation, flagged."""
    out = []
    for fitted in list(report.ranking) + list(report.pairs):
        for effect, values in fitted.parameters.items():
            params = {p.name: p for p in model.candidates[effect].parameters}
            for name, v in values.items():
                lo, hi = params[name].bounds
                if v <= lo + 1e-6 * (hi - lo) and params[name].off != lo or v >= hi - 1e-6 * (hi - lo):
                    out.append(f"{fitted.name}: {name} = {v:.4g} at its bound [{lo:g}, {hi:g}]")
                elif name in PHYSICAL_RANGES and not PHYSICAL_RANGES[name][0] <= v <= PHYSICAL_RANGES[name][1]:
                    p_lo, p_hi = PHYSICAL_RANGES[name]
                    out.append(f"{fitted.name}: {name} = {v:.4g} outside its physical range [{p_lo:g}, {p_hi:g}]")
    return out
