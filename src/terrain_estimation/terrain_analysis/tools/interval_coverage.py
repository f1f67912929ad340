"""Coverage of the attribution's parameter intervals on simulated bags (issue 22, item 5).

``python -m terrain_analysis.tools.interval_coverage [--runs N] [--seed S] [--duration T] [--toy]``

For each run: one catalogue effect of the skid steer, drawn at random (effect,
magnitude between 0.5 and 1.5 times its typical deviation, either sign where
the fit range allows), a manoeuvre drawn from the simulator's
(:data:`vehicle_sim.plants.skid_steer.MANOEUVRES`), its own sensor-noise seed;
the truth plant (:func:`vehicle_sim.plants.skid_steer.simulate_skid_steer`)
makes the data, the replay (:class:`terrain_analysis.sim2real.skid_steer.SkidSteerReplay`)
fits that effect alone on the training part
(:func:`terrain_analysis.sim2real.attribution.attribute`), and the tool
counts how often the ``confidence`` (90 %) interval of each fitted parameter
holds the true value. The target is 85–95 %. The replay's own model error
(module docstring of the replay) is part of what the interval must cover.

``--toy``: the same on the engine's one-channel toy (a sine with a bias, white
noise plus a slowly wandering AR(1) component of correlation ``--rho`` per
sample), where nothing but the residual's autocorrelation can break coverage.

Prints one line per run and the coverage with its binomial 90 % interval.
Nothing is tuned to the result: the seed only draws the runs.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from terrain_analysis.sim2real.attribution import AttributionSettings, attribute
from terrain_analysis.sim2real.model import Candidate, Channel, FitParameter, ReplayModel

__all__ = ["coverage_interval", "main", "skid_steer_runs", "toy_runs"]

FloatArray = NDArray[np.float64]

#: Effects of the skid steer whose parameters are continuous and whose size the replay can fit alone.
SKID_EFFECTS = ("gyro_bias", "accel_bias", "wheel_radius_error", "cornering_stiffness_change", "terrain_grade")


def coverage_interval(hits: int, total: int, level: float = 0.9) -> tuple[float, float]:
    """Clopper–Pearson interval of a coverage ``hits / total``."""
    if total == 0:
        return (math.nan, math.nan)
    a = (1.0 - level) / 2.0
    lo = float(stats.beta.ppf(a, hits, total - hits + 1)) if hits > 0 else 0.0
    hi = float(stats.beta.ppf(1.0 - a, hits + 1, total - hits)) if hits < total else 1.0
    return lo, hi


def _draw(rng: np.random.Generator, effect: Any) -> dict[str, float]:
    values = {}
    for p in effect.parameters:
        if p.switch:
            continue
        size = abs(p.typical - p.off) * float(rng.uniform(0.5, 1.5))
        sign = 1.0 if p.off - size < p.fit_range[0] else float(rng.choice([-1.0, 1.0]))
        if p.off + sign * size > p.fit_range[1]:
            sign = -1.0
        values[p.name] = p.off + sign * size
    return values


def skid_steer_runs(runs: int, seed: int, duration: float, out: Any = sys.stdout) -> tuple[int, int]:
    """(covered, total) parameter intervals over ``runs`` simulated skid-steer bags."""
    from terrain_analysis.sim2real.skid_steer import SkidSteerReplay, bag_data_from_arrays, vehicle_from_config
    from vehicle_sim.effects import CATALOGUE, effects_for
    from vehicle_sim.plants.skid_steer import MANOEUVRES, SkidSteerVehicle, simulate_skid_steer

    vehicle = vehicle_from_config()
    rng = np.random.default_rng(seed)
    names = [e for e in SKID_EFFECTS if e in CATALOGUE["skid_steer"]]
    manoeuvres = sorted(MANOEUVRES)
    covered = total = 0
    settings = AttributionSettings(bootstrap=50, cross_fit=0)
    for i in range(runs):
        effect = names[int(rng.integers(len(names)))]
        values = _draw(rng, CATALOGUE["skid_steer"][effect])
        manoeuvre = manoeuvres[int(rng.integers(len(manoeuvres)))]
        scenario = MANOEUVRES[manoeuvre](
            vehicle=SkidSteerVehicle(), effects=effects_for("skid_steer", {effect: values})
        )
        result = simulate_skid_steer(replace(scenario, duration=duration), int(rng.integers(1 << 30)))
        data = bag_data_from_arrays(
            result.t,
            result.linear_acceleration,
            result.angular_velocity[:, 2],
            result.t,
            result.motor_velocity,
            transmission_ratio=vehicle.transmission_ratio,
        )
        model = SkidSteerReplay(data, vehicle, warmup=1.0)
        model.candidates = {effect: model.candidates[effect]}
        started = time.perf_counter()
        fit = attribute(model, settings).ranking[0]
        line = []
        for name, truth in values.items():
            if name not in fit.interval.get(effect, {}):
                continue
            lo, hi = fit.interval[effect][name]
            inside = lo <= truth <= hi
            covered += int(inside)
            total += 1
            line.append(
                f"{name} true {truth:.4g} fit {fit.parameters[effect][name]:.4g} [{lo:.4g}, {hi:.4g}] "
                f"{'in' if inside else 'OUT'}"
            )
        print(
            f"{i + 1:3d} {manoeuvre:>10s} {effect}: " + "; ".join(line) + f" ({time.perf_counter() - started:.1f} s, "
            f"τ {fit.correlation_time:.2f} s, {fit.batches} batches)",
            file=out,
            flush=True,
        )
    return covered, total


class _Toy:
    """One channel, y = A sin(2π·1.7 t) + sin(2π·0.3 t) + b; the amplitude A a nuisance, the bias b the effect."""

    vehicle = "toy"
    warmup = 0.5

    def __init__(self, t: FloatArray, y: FloatArray, sigma: float) -> None:
        self.channels = [Channel("y", "toy/y", "m", sigma)]
        self.times = {"y": t}
        self.measured = {"y": y}
        self.nuisance = [FitParameter("amplitude", "m", 1.0, (0.2, 5.0), 0.2)]
        self.candidates = {"bias": Candidate("bias", (FitParameter("b", "m", 0.0, (-1.0, 1.0), 0.05),))}
        self.regimes: dict[str, tuple[FloatArray, FloatArray]] = {}
        self.notes: list[str] = []

    def predict(self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]) -> dict[str, Any]:
        t = self.times["y"]
        a = float(nuisance.get("amplitude", 1.0))
        b = float(effects.get("bias", {}).get("b", 0.0))
        return {"y": a * np.sin(2 * math.pi * 1.7 * t) + np.sin(2 * math.pi * 0.3 * t) + b}


def toy_runs(runs: int, seed: int, duration: float, rho: float, share: float) -> tuple[int, int]:
    """(covered, total) on the toy: white noise σ plus ``share`` σ of AR(1) noise with correlation ``rho``."""
    sigma, truth = 0.1, 0.05
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 0.01)
    covered = 0
    for _ in range(runs):
        e = rng.standard_normal(t.size)
        slow = np.empty(t.size)
        slow[0] = e[0]
        for k in range(1, t.size):
            slow[k] = rho * slow[k - 1] + math.sqrt(1.0 - rho * rho) * e[k]
        y = 1.3 * np.sin(2 * math.pi * 1.7 * t) + np.sin(2 * math.pi * 0.3 * t) + truth
        y = y + sigma * (rng.standard_normal(t.size) + share * slow)
        fit = attribute(cast(ReplayModel, _Toy(t, y, sigma)), AttributionSettings(bootstrap=50)).ranking[0]
        lo, hi = fit.interval["bias"]["b"]
        covered += int(lo <= truth <= hi)
    return covered, runs


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="interval-coverage", description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=40, help="simulated bags (default 40)")
    parser.add_argument("--seed", type=int, default=2026, help="seed of the draws (default 2026)")
    parser.add_argument("--duration", type=float, default=12.0, help="bag length (s, default 12; toy: 60)")
    parser.add_argument("--toy", action="store_true", help="the engine's toy instead of the skid-steer plant")
    parser.add_argument("--rho", type=float, default=0.99, help="toy: AR(1) correlation per sample (default 0.99)")
    parser.add_argument("--share", type=float, default=0.7, help="toy: AR(1) noise in units of σ (default 0.7)")
    args = parser.parse_args(argv)
    if args.runs < 1 or args.duration <= 2.0:
        parser.error("need --runs ≥ 1 and --duration > 2 s")
    if args.toy:
        covered, total = toy_runs(args.runs, args.seed, args.duration, args.rho, args.share)
        what = f"toy, ρ = {args.rho:g}, slow share {args.share:g}"
    else:
        covered, total = skid_steer_runs(args.runs, args.seed, args.duration)
        what = f"skid steer, {args.duration:g} s bags"
    lo, hi = coverage_interval(covered, total)
    print(
        f"coverage of the 90 % parameter intervals ({what}): {covered}/{total} = "
        f"{100.0 * covered / max(total, 1):.0f} % (90 % binomial interval {100 * lo:.0f}–{100 * hi:.0f} %)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
