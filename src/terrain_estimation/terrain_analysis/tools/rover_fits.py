"""The rover reproduction's model fits (Tables VI, VII): 2nd-order DP(W, i), τ_R(W, i) against the true model.

Part of :mod:`terrain_analysis.tools.reproduce_rover`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.tools.rover_model_error import FitError, pooled_error
from terrain_analysis.tools.rover_plan import ALL_VARIANTS, FIT_TERRAINS, GRID_POINTS, QUANTITIES
from terrain_analysis.tools.rover_runs import FloatArray, Results
from terrain_estimation.estimators.rover import TerrainResponseConfig
from terrain_estimation.models.terrain_response import PolynomialModel2D, ValidityRegion, fit_polynomial_2d
from terrain_estimation.models.terrain_response_error import ValidatedFit, validated_fit
from vehicle_sim.plants.rover import CONTROL_RATE
from vehicle_sim.terrain.terramechanics_surrogate import SURROGATE_LOAD_RANGE, TerramechanicsSurrogate

__all__ = [
    "ModelFit",
    "region_grid",
    "convex_hull",
    "inside_polygon",
    "true_forces",
    "fit_models",
    "pooled_samples",
    "truth_samples",
    "model_fits",
    "truth_fit_rms",
    "fit_bias",
]


def region_grid(region: ValidityRegion, n: int = GRID_POINTS) -> tuple[FloatArray, FloatArray]:
    """(slip, load) meshes, n × n, over a (i, W) rectangle."""
    slip = np.linspace(region.slip_min, region.slip_max, n)
    load = np.linspace(region.load_min, region.load_max, n)
    load_mesh, slip_mesh = np.meshgrid(load, slip, indexing="ij")
    return slip_mesh, load_mesh


def convex_hull(points: Any) -> FloatArray:
    """Vertices of the convex hull of (n, 2) points, counter-clockwise (Andrew's monotone chain)."""
    pts = sorted({(float(x), float(y)) for x, y in np.asarray(points, dtype=float)})
    if len(pts) < 3:
        return np.array(pts, dtype=float).reshape(-1, 2)

    def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0.0:
            lower.pop()
        lower.append(p)
    upper: list[tuple[float, float]] = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0.0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1], dtype=float)


def inside_polygon(polygon: FloatArray, x: Any, y: Any) -> NDArray[np.bool_]:
    """True where (x, y) lies inside or on a convex counter-clockwise polygon."""
    xs, ys = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    inside = np.ones(xs.shape, dtype=bool)
    if polygon.shape[0] < 3:
        return np.zeros(xs.shape, dtype=bool)
    for k in range(polygon.shape[0]):
        (x0, y0), (x1, y1) = polygon[k], polygon[(k + 1) % polygon.shape[0]]
        inside &= (x1 - x0) * (ys - y0) - (y1 - y0) * (xs - x0) >= -1e-12
    return inside


@dataclass
class ModelFit:
    """The 2nd-order fits of one seed and variant (terrains 1–5) with the local model and the errors."""

    samples: dict[str, FloatArray]
    region: ValidityRegion
    dp: PolynomialModel2D
    tau: PolynomialModel2D
    dp_local: PolynomialModel2D
    tau_local: PolynomialModel2D
    rms: dict[str, float]  # dp, tau, dp_local, tau_local, dp_mean, tau_mean (signed), dp_in, dp_out, tau_in, tau_out
    hull_fraction: float
    stated: dict[str, FitError] = field(default_factory=dict)  # dp, tau: stated error against the true error


def true_forces(surrogate: TerramechanicsSurrogate, slip: Any, load: Any) -> tuple[FloatArray, FloatArray]:
    """(DP, τ_R) of the true global model (the 4th-order surrogate, capped at 200 N as the plant does)."""
    capped = np.minimum(np.asarray(load, dtype=float), SURROGATE_LOAD_RANGE[1])
    return surrogate.wheel_forces(capped, slip)


def fit_models(samples: dict[str, FloatArray], surrogate: TerramechanicsSurrogate) -> ModelFit:
    """2nd-order fits to the samples; local model and RMS over the samples' (i, W) rectangle (100×100).

    The fits are the accumulator's (:func:`validated_fit`, equal weights, 10 blocks of sample periods:
    ``samples["group"]`` keys the periods, runs of different terrains apart; the samples' stated
    variances when given), so each comes with its stated error, compared here with the true one.
    """
    i, w = samples["slip"], samples["normal_load"]
    groups = samples.get("group", samples["t"])
    blocks = TerrainResponseConfig().validation_blocks
    dp_fit: ValidatedFit = validated_fit(
        i,
        w,
        samples["drawbar_pull"],
        2,
        groups=groups,
        max_blocks=blocks,
        sample_variances=samples.get("drawbar_pull_variance"),
    )
    tau_fit = validated_fit(
        i,
        w,
        samples["resistive_torque"],
        2,
        groups=groups,
        max_blocks=blocks,
        sample_variances=samples.get("resistive_torque_variance"),
    )
    dp, tau = dp_fit.model, tau_fit.model
    region = dp.validity
    assert region is not None
    gi, gw = region_grid(region)
    dp_true, tau_true = true_forces(surrogate, gi, gw)
    dp_local = fit_polynomial_2d(gi, gw, dp_true, 2).model
    tau_local = fit_polynomial_2d(gi, gw, tau_true, 2).model
    # The hull in scaled coordinates (i and W have different units; the test is affine-invariant anyway).
    hull = convex_hull(np.column_stack([i, w]))
    inside = inside_polygon(hull, gi, gw)
    e_dp = dp.evaluate(gi, gw) - dp_true
    e_tau = tau.evaluate(gi, gw) - tau_true

    def rms(e: FloatArray, mask: Any = None) -> float:
        v = e if mask is None else e[mask]
        return float(np.sqrt(np.mean(v * v))) if v.size else math.nan

    return ModelFit(
        samples=samples,
        region=region,
        dp=dp,
        tau=tau,
        dp_local=dp_local,
        tau_local=tau_local,
        rms={
            "dp": rms(e_dp),
            "tau": rms(e_tau),
            "dp_local": rms(dp_local.evaluate(gi, gw) - dp_true),
            "tau_local": rms(tau_local.evaluate(gi, gw) - tau_true),
            "dp_mean": float(np.mean(e_dp)),
            "tau_mean": float(np.mean(e_tau)),
            "dp_in": rms(e_dp, inside),
            "dp_out": rms(e_dp, ~inside),
            "tau_in": rms(e_tau, inside),
            "tau_out": rms(e_tau, ~inside),
        },
        hull_fraction=float(np.mean(inside)),
        stated={
            "dp": pooled_error(dp_fit, dp_true.ravel(), gi.ravel(), gw.ravel()),
            "tau": pooled_error(tau_fit, tau_true.ravel(), gi.ravel(), gw.ravel()),
        },
    )


def pooled_samples(res: Results, seed: int, variant: str) -> dict[str, FloatArray]:
    """The 2-s samples of terrains 1–5 of one seed and variant, pooled."""
    terrains = [n for n in FIT_TERRAINS if n in res.terrains]
    parts = [res.terrains[n].series[(seed, variant)].samples for n in terrains]
    base = ("t", "slip", "normal_load", "drawbar_pull", "resistive_torque")
    keys = base + tuple(f"{k}_variance" for k in base[1:] if all(f"{k}_variance" in p for p in parts))
    out = {k: np.concatenate([p[k] for p in parts]) if parts else np.zeros(0) for k in keys}
    # Sample-period key, terrains apart (their clocks each start at 0): the blocks of the held-out validation.
    out["group"] = (
        np.concatenate([1e6 * n + p["t"] for n, p in zip(terrains, parts, strict=True)]) if parts else np.zeros(0)
    )
    return out


def truth_samples(res: Results, terrains: Sequence[int], period: float = 2.0) -> dict[str, FloatArray]:
    """The truth averaged to one sample per wheel per ``period`` over the given terrains (reference region)."""
    out: dict[str, list[FloatArray]] = {q: [] for q in QUANTITIES}
    for n in terrains:
        data = res.terrains.get(n)
        if data is None:
            continue
        per = int(round(period * CONTROL_RATE))
        m = data.time.size // per
        for q in QUANTITIES:
            out[q].append(data.truth[q][: m * per].reshape(m, per, 3).mean(axis=1).ravel())
    return {q: np.concatenate(v) if v else np.zeros(0) for q, v in out.items()}


def model_fits(res: Results, surrogate: TerramechanicsSurrogate) -> dict[tuple[int, str], ModelFit]:
    out: dict[tuple[int, str], ModelFit] = {}
    if not all(n in res.terrains for n in FIT_TERRAINS):
        return out
    for i in range(min(res.seeds(n) for n in FIT_TERRAINS)):
        for v in ALL_VARIANTS:
            samples = pooled_samples(res, i, v)
            try:
                out[(i, v)] = fit_models(samples, surrogate)
            except ValueError:
                continue  # too few samples for a 2nd-order fit (reported by count)
    return out


def truth_fit_rms(
    truth: dict[str, FloatArray], fits: Sequence[ModelFit], surrogate: TerramechanicsSurrogate
) -> tuple[float, float] | None:
    """(τ_R, DP) RMS vs the true model of 2nd-order fits to the 2-s averaged truth, over the fits' regions."""
    if truth["slip"].size < 12 or not fits:
        return None
    try:
        dp = fit_polynomial_2d(truth["slip"], truth["normal_load"], truth["drawbar_pull"], 2).model
        tau = fit_polynomial_2d(truth["slip"], truth["normal_load"], truth["resistive_torque"], 2).model
    except ValueError:
        return None
    out_tau, out_dp = [], []
    for f in fits:
        gi, gw = region_grid(f.region)
        dp_true, tau_true = true_forces(surrogate, gi, gw)
        out_dp.append(float(np.sqrt(np.mean((dp.evaluate(gi, gw) - dp_true) ** 2))))
        out_tau.append(float(np.sqrt(np.mean((tau.evaluate(gi, gw) - tau_true) ** 2))))
    return float(np.mean(out_tau)), float(np.mean(out_dp))


def fit_bias(res: Results, v: str) -> dict[str, float]:
    out = {}
    for q in QUANTITIES:
        errs = [
            (p.est[q] - p.truth[q]).ravel() for (n, _, vv), p in res.paired.items() if vv == v and n in FIT_TERRAINS
        ]
        out[q] = float(np.mean(np.concatenate(errs))) if errs else math.nan
    return out
