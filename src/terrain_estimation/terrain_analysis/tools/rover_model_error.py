"""The terrain-response model's stated error against its true error (issue 21, item 3): figures for the rover report.

Used by :mod:`terrain_analysis.tools.reproduce_rover`. Two views:

* **online** — every model the accumulator publishes while a terrain run
  goes on (:attr:`Series.fits <terrain_analysis.tools.reproduce_rover.Series>`,
  one per kept 2-s sample period, as the node publishes them with
  ``terrain_model.fit_every = 1``), each compared with the true model over its
  own validity rectangle: stated prediction RMS against the true RMS, the
  share of grid points whose error is within 2 stated σ(i, W), and the jump
  from the previous model relative to that model's stated σ — per
  coefficient (|Δp_k|/σ_k) and over the previous model's region
  (max |ΔDP(i, W)| / √(xᵀΣx), the coefficients' part of σ only: the stricter
  test).
* **pooled** (Table VII) — :func:`pooled_error` for the fit to the pooled
  samples of terrains 1–5.

The truth is the plant's own soil (the 4th-order surrogate, capped at 200 N
as the plant caps it); nothing here feeds back into the estimators.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.estimators.rover import TerrainResponseFit
from terrain_estimation.models.terrain_response import PolynomialModel2D, ValidityRegion
from terrain_estimation.models.terrain_response_error import ValidatedFit, model_variance

FloatArray = NDArray[np.float64]
#: (slip, load) → (DP, τ_R) of the true model.
TruthFn = Callable[[FloatArray, FloatArray], tuple[FloatArray, FloatArray]]

__all__ = [
    "FitError",
    "JumpFigures",
    "OnlineSummary",
    "fit_error",
    "jump_figures",
    "online_lines",
    "online_summary",
    "pooled_error",
    "stated_vs_true_lines",
]

#: Grid per axis over a model's rectangle for the online figures (Table VII uses its own 100 × 100).
ONLINE_GRID = 30


def _grid(region: ValidityRegion, n: int) -> tuple[FloatArray, FloatArray]:
    slip = np.linspace(region.slip_min, region.slip_max, n)
    load = np.linspace(region.load_min, region.load_max, n)
    ii, ww = np.meshgrid(slip, load, indexing="ij")
    return ii.ravel(), ww.ravel()


@dataclass(frozen=True)
class FitError:
    """One model against the truth over its rectangle (per quantity: ``dp`` or ``tau``).

    Attributes:
        true_rms: RMS of model − truth over the grid.
        stated_rms: the model's prediction RMS (what it states).
        residual_rms: its fit residual (what the message stated before issue 21).
        within_2sigma: share of grid points with |model − truth| ≤ 2 σ(i, W).
        within_1sigma: the same with 1 σ.
    """

    true_rms: float
    stated_rms: float
    residual_rms: float
    within_2sigma: float
    within_1sigma: float


def _error(
    model: PolynomialModel2D,
    std: Callable[[FloatArray, FloatArray], FloatArray],
    truth: FloatArray,
    slip: FloatArray,
    load: FloatArray,
    stated: float,
    residual: float,
) -> FitError:
    e = model.evaluate(slip, load) - truth
    s = std(slip, load)
    return FitError(
        true_rms=float(np.sqrt(np.mean(e * e))),
        stated_rms=stated,
        residual_rms=residual,
        within_2sigma=float(np.mean(np.abs(e) <= 2.0 * s)),
        within_1sigma=float(np.mean(np.abs(e) <= s)),
    )


def fit_error(fit: TerrainResponseFit, truth: TruthFn, n: int = ONLINE_GRID) -> dict[str, FitError]:
    """DP and τ_R errors of one published model over its validity rectangle."""
    slip, load = _grid(fit.validity, n)
    dp_true, tau_true = truth(slip, load)
    return {
        "dp": _error(fit.drawbar_pull, fit.dp_std, dp_true, slip, load, fit.dp_prediction_rms, fit.dp_rms),
        "tau": _error(fit.resistive_torque, fit.tau_std, tau_true, slip, load, fit.tau_prediction_rms, fit.tau_rms),
    }


def pooled_error(fit: ValidatedFit, truth: FloatArray, slip: FloatArray, load: FloatArray) -> FitError:
    """One validated fit against the true values at the given grid points."""
    return _error(fit.model, fit.std, truth, slip, load, fit.prediction_rms, fit.rms)


@dataclass(frozen=True)
class JumpFigures:
    """Jump of a model from the previous one, relative to the previous model's stated uncertainty.

    Attributes:
        coefficient: max_k |Δp_k| / σ_k (σ_k = √Σ_kk of the previous model).
        function: max over the previous region of |Δf(i, W)| / √(xᵀΣx) (coefficients' σ only).
        mahalanobis: the new fit's distance before bounding (``TerrainResponseFit.dp_jump``).
    """

    coefficient: float
    function: float
    mahalanobis: float


def jump_figures(previous: TerrainResponseFit, fit: TerrainResponseFit, n: int = ONLINE_GRID) -> dict[str, JumpFigures]:
    """DP and τ_R jumps of ``fit`` from ``previous``."""
    slip, load = _grid(previous.validity, n)
    out = {}
    for key, old, new, cov, raw in (
        ("dp", previous.drawbar_pull, fit.drawbar_pull, previous.dp_covariance, fit.dp_jump),
        ("tau", previous.resistive_torque, fit.resistive_torque, previous.tau_covariance, fit.tau_jump),
    ):
        delta = np.asarray(new.coefficients) - np.asarray(old.coefficients)
        sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            coefficient = float(np.max(np.where(delta == 0.0, 0.0, np.abs(delta) / sigma)))
            df = np.abs(new.evaluate(slip, load) - old.evaluate(slip, load))
            sf = np.sqrt(model_variance(old.order, cov, slip, load))
            function = float(np.max(np.where(df == 0.0, 0.0, df / sf)))
        out[key] = JumpFigures(coefficient, function, raw)
    return out


@dataclass(frozen=True)
class OnlineSummary:
    """The online figures of one set of runs (e.g. one terrain and variant over seeds), per quantity.

    Attributes:
        fits: models published.
        true_rms, stated_rms, residual_rms: means over the models.
        ratio_true_stated: mean of true/stated over the models.
        share_covered: share of models with true RMS ≤ stated RMS.
        within_2sigma: mean share of grid points within 2 σ.
        ratio_true_residual: mean of true RMS / fit residual (the old statement).
        jump_coefficient_max, jump_function_max: largest jumps over the runs (in previous σ).
        jump_function_median: median of the function jumps.
        raw_jump_max: largest Mahalanobis distance of an unbounded fit (before bounding).
        limited: share of models whose step was bounded.
    """

    fits: int
    true_rms: float
    stated_rms: float
    residual_rms: float
    ratio_true_stated: float
    share_covered: float
    within_2sigma: float
    ratio_true_residual: float
    jump_coefficient_max: float
    jump_function_max: float
    jump_function_median: float
    raw_jump_max: float
    limited: float


def online_summary(runs: Sequence[Sequence[TerrainResponseFit]], truth: TruthFn, key: str) -> OnlineSummary | None:
    """Summary over runs (each the sequence of models one run published), for ``key`` = ``dp`` or ``tau``."""
    errors: list[FitError] = []
    jumps: list[JumpFigures] = []
    limited: list[bool] = []
    for fits in runs:
        for k, fit in enumerate(fits):
            errors.append(fit_error(fit, truth)[key])
            limited.append(fit.limited)
            if k > 0:
                jumps.append(jump_figures(fits[k - 1], fit)[key])
    if not errors:
        return None
    true = np.array([e.true_rms for e in errors])
    stated = np.array([e.stated_rms for e in errors])
    residual = np.array([e.residual_rms for e in errors])

    def biggest(values: list[float]) -> float:
        finite = [v for v in values if math.isfinite(v)]
        return max(finite) if finite else math.nan

    return OnlineSummary(
        fits=len(errors),
        true_rms=float(np.mean(true)),
        stated_rms=float(np.mean(stated)),
        residual_rms=float(np.mean(residual)),
        ratio_true_stated=float(np.mean(true / np.maximum(stated, 1e-300))),
        share_covered=float(np.mean(true <= stated)),
        within_2sigma=float(np.mean([e.within_2sigma for e in errors])),
        ratio_true_residual=float(np.mean(true / np.maximum(residual, 1e-300))),
        jump_coefficient_max=biggest([j.coefficient for j in jumps]),
        jump_function_max=biggest([j.function for j in jumps]),
        jump_function_median=float(np.median([j.function for j in jumps])) if jumps else math.nan,
        raw_jump_max=biggest([j.mahalanobis for j in jumps]),
        limited=float(np.mean(limited)),
    )


def _f(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}g}" if math.isfinite(x) else "—"


def stated_vs_true_lines(stated: dict[str, list[dict[str, FitError]]], units: dict[str, str]) -> list[str]:
    """Markdown table: per variant (label → per-run {dp, tau} errors), the stated error beside the true one."""
    head = "| estimators | " + " | ".join(
        f"{name} true RMS ({units[key]}) | {name} stated ({units[key]}) | true / stated | grid within 2σ / 1σ | "
        f"{name} fit residual (old statement)"
        for key, name in (("dp", "DP"), ("tau", "τ_R"))
    )
    lines = [head + " |", "|---|" + "---|" * 10]
    for label, runs in stated.items():
        cells = []
        for key in ("dp", "tau"):
            e = [r[key] for r in runs if key in r]
            if not e:
                cells.append(" — | — | — | — | —")
                continue
            true = np.array([x.true_rms for x in e])
            st = np.array([x.stated_rms for x in e])
            cells.append(
                f" {_f(float(np.mean(true)))} | {_f(float(np.mean(st)))} | {float(np.mean(true / st)):.2f} | "
                f"{100 * np.mean([x.within_2sigma for x in e]):.0f} % / "
                f"{100 * np.mean([x.within_1sigma for x in e]):.0f} % | "
                f"{_f(float(np.mean([x.residual_rms for x in e])))}"
            )
        lines.append(f"| {label} |" + " |".join(cells) + " |")
    return lines


def online_lines(rows: Sequence[tuple[str, str, OnlineSummary | None]], unit: str) -> list[str]:
    """Markdown table of :class:`OnlineSummary` rows (terrain label, variant label, summary)."""
    lines = [
        f"| terrain | estimators | models | fit residual ({unit}, old statement) | stated ({unit}) | true ({unit}) | "
        "true / stated | models with true ≤ stated | grid within 2σ | true / residual | "
        "max \\|Δp_k\\|/σ_k | max \\|Δf\\|/σ_f | median \\|Δf\\|/σ_f | unbounded fit: max distance | bounded |",
        "|---|---|" + "---|" * 13,
    ]
    for terrain, variant, s in rows:
        if s is None:
            lines.append(f"| {terrain} | {variant} | 0 |" + " — |" * 12)
            continue
        lines.append(
            f"| {terrain} | {variant} | {s.fits} | {_f(s.residual_rms)} | {_f(s.stated_rms)} | {_f(s.true_rms)} | "
            f"{s.ratio_true_stated:.2f} | {100 * s.share_covered:.0f} % | {100 * s.within_2sigma:.0f} % | "
            f"{s.ratio_true_residual:.2f} | {_f(s.jump_coefficient_max, 2)} | {_f(s.jump_function_max, 2)} | "
            f"{_f(s.jump_function_median, 2)} | {_f(s.raw_jump_max, 3)} | {100 * s.limited:.0f} % |"
        )
    return lines
