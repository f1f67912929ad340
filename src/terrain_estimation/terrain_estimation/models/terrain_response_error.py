"""The terrain-response model's real error: coefficient covariance, held-out prediction error, bounded updates.

A least-squares fit's residual RMS (``PolynomialFit.rms``) says how closely
the polynomial passes through the samples it was fitted to. It is not the
model's error against the terrain: the rover's 2-s samples are strongly
correlated in time (consecutive periods on the same slope, the three wheels
of one period), a 2nd-order polynomial cannot follow the 4th-order
Wong–Reece response (lack of fit that depends on *which* (i, W) were
visited), and the validity rectangle holds corners no sample came near. On
the Kapvik truth runs the residual was 3–4× smaller than the model's true
error (issue 21). This module states the error from data the fit did not
see.

**Blocks.** The samples are cut into ``B`` contiguous blocks of their
sample periods (``groups``: samples of one period — the three wheels — stay
together), ``B = min(max_blocks, number of periods)``.

**Coefficient covariance Σ_p** — the delete-a-block jackknife (Künsch 1989;
Efron & Stein): refit with each block left out, p_(b), and
Σ_p = (B − 1)/B · Σ_b (p_(b) − p̄)(p_(b) − p̄)ᵀ. Leaving out whole blocks
keeps the correlation inside a block, so Σ_p carries the samples' noise
*with* its serial correlation, the scatter the estimated inputs (i, W)
put into the response (errors in variables: the residuals are taken at the
estimated (î, Ŵ), so their effect is in the data the jackknife resamples;
their attenuation bias, σ_i²/var(i) of 0.2–1.6 % on the Kapvik truth runs
with slip errors of 0.004–0.006 against a spread of 0.05–0.15, is left
uncorrected), and how the fit moves with the region visited (lack of fit).
When fewer than 3 blocks can be refitted, the classical
s²(XᵀWX)⁻¹ is used instead, inflated by (1 + ρ)/(1 − ρ) for the lag-1
correlation ρ of the residuals between consecutive periods; with fewer
refits than coefficients + 1 the jackknife spans only B − 1 directions of
the m coefficients (it would state the others exact) and the classical
covariance is added to it.

**Held-out error.** Every sample is predicted once by the fit without its
block: ``holdout_rms`` = √(mean r_ho²). It measures the model against
estimates it did not see, so it holds the samples' own estimation noise
too (conservative as an error against the true response).

**Error the samples share.** Errors common to all the samples of a wheel
(an estimator bias that lasts the whole run: on Kapvik's terrain 1 the 30-s
DP estimates were off by −0.84, −0.44, −0.41 N on the three wheels, about
their whole RMS error) are indistinguishable from the response itself — each
wheel runs in its own load band, so a per-wheel bias reads as a W
dependence — and no hold-out can see them. The only knowledge of them is
the estimator's own stated variance of the estimates:
``estimate_rms`` = √(mean of the samples' stated variances), given by the
caller (0 if not).

**Stated error of the model at (i, W)**:
σ(i, W)² = holdout_rms² + estimate_rms² + xᵀ Σ_p x, x = the terms i^k W^l.
The first part is the validated error at places like the data, the second
the estimates' shared error, the third grows where the data do not reach
(the corners of the rectangle). ``prediction_rms`` is √(mean σ²) over the
validity rectangle (a 20 × 20 grid). Both variance estimates rest on few
independent pieces (the blocks): Σ_p and holdout_rms² are scaled by
ν/(ν − 2), ν = blocks − 1 (n − m for the classical covariance), the
variance of a Student-t with ν degrees of freedom (1.29 for 10 blocks; 3
when ν ≤ 3). The estimates' random error is in both holdout_rms and
estimate_rms, so it is counted twice: the statement is conservative where
the estimates are unbiased (true / stated 0.2–0.45 on Kapvik terrains 2–5)
and about right where they carry a lasting bias (0.7–0.8 on terrain 1);
without estimate_rms, terrain 1 was understated (issue 21's figures).

**Bounded updates** (:func:`bounded_update`): a new fit may differ from the
previously published model by a Mahalanobis distance
d = √(Δᵀ P_prev⁻¹ Δ) of at most ``max_jump`` (1: one stated σ). By
Cauchy–Schwarz, |aᵀΔ| ≤ d·√(aᵀ P_prev a) for every a, so every coefficient
and the model's value at every (i, W) then move by at most ``max_jump`` of
the previous model's stated σ. A larger step is shortened to the boundary,
and the part not taken, o = p_fit − p_published, is added to the stated
covariance (P = Σ_p + o oᵀ): the published model is honestly that much
less certain, and the next step may close the gap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from terrain_estimation.models.terrain_response import (
    PolynomialModel2D,
    ValidityRegion,
    coefficient_count,
    design_matrix,
    fit_polynomial_2d,
)

Array = NDArray[np.float64]

__all__ = [
    "BoundedUpdate",
    "ValidatedFit",
    "block_labels",
    "bounded_update",
    "mahalanobis_distance",
    "model_variance",
    "region_mean_variance",
    "validated_fit",
]

#: Grid (per axis) over the validity rectangle for ``prediction_rms``.
REGION_GRID = 20
#: Jackknife refits needed before the jackknife covariance is trusted.
MIN_JACKKNIFE_BLOCKS = 3


def block_labels(groups: ArrayLike, blocks: int) -> NDArray[np.int_]:
    """Block index 0..B−1 of each sample: B contiguous runs of the sorted distinct ``groups`` values.

    Args:
        groups: (n,) group key per sample (e.g. the sample period's stamp);
            samples with equal keys share a block.
        blocks: wanted B ≥ 1 (capped at the number of distinct groups).
    """
    g = np.asarray(groups, dtype=float).ravel()
    distinct, inverse = np.unique(g, return_inverse=True)
    b = max(1, min(int(blocks), distinct.size))
    # Distinct group k (in sorted order) goes to block floor(k B / G): sizes differ by at most one group.
    return np.asarray((np.arange(distinct.size) * b) // max(distinct.size, 1), dtype=int)[inverse]


def model_variance(order: int, covariance: ArrayLike, slip: ArrayLike, load: ArrayLike) -> Array:
    """xᵀ Σ_p x at the broadcast (i, W): the variance of the model's value from its coefficients' covariance."""
    cov = np.asarray(covariance, dtype=float)
    x = design_matrix(slip, load, order)
    shape = np.broadcast_shapes(np.shape(slip), np.shape(load))
    return np.maximum(np.einsum("nk,kl,nl->n", x, cov, x), 0.0).reshape(shape)


def region_mean_variance(order: int, covariance: ArrayLike, region: ValidityRegion, n: int = REGION_GRID) -> float:
    """Mean of xᵀ Σ_p x over an n × n grid of the region."""
    slip = np.linspace(region.slip_min, region.slip_max, n)
    load = np.linspace(region.load_min, region.load_max, n)
    ii, ww = np.meshgrid(slip, load, indexing="ij")
    return float(np.mean(model_variance(order, covariance, ii, ww)))


def mahalanobis_distance(delta: ArrayLike, covariance: ArrayLike) -> float:
    """√(Δᵀ P⁻¹ Δ), computed on the correlation scale (P's diagonal normalised).

    Raw polynomial coefficients differ by orders of magnitude (W² terms), so P
    is first scaled to a correlation matrix; its eigenvalues are floored at
    1e-14 of the largest, so a step along a direction P states (almost)
    certain gives a very large but finite distance. Infinite only when a
    coefficient with zero stated variance moves.
    """
    d = np.asarray(delta, dtype=float).ravel()
    p = np.asarray(covariance, dtype=float)
    std = np.sqrt(np.maximum(np.diag(p), 0.0))
    if np.any((std == 0.0) & (d != 0.0)):
        return math.inf
    scale = np.where(std > 0.0, std, 1.0)
    z = d / scale
    r = p / np.outer(scale, scale)
    values, vectors = np.linalg.eigh(0.5 * (r + r.T))
    values = np.maximum(values, 1e-14 * max(float(values.max()), 1e-300))
    proj = vectors.T @ z
    return float(math.sqrt(float(np.sum(proj**2 / values))))


@dataclass(frozen=True)
class ValidatedFit:
    """A polynomial fit with its coefficient covariance and held-out error.

    Attributes:
        model: the least-squares fit to all samples (validity = their range).
        rms: its residual RMS on the fitted samples (weighted as the fit).
        covariance: (n, n) covariance Σ_p of ``model.coefficients``.
        holdout_rms: RMS of each sample's error predicted by the fit without
            its block (weighted as the fit); when no block could be left out
            (``validation_samples`` = 0), the residual RMS scaled by
            √(n/(n − m)) for the m fitted coefficients.
        estimate_rms: √(mean stated variance of the samples) (0 if none given).
        prediction_rms: √(holdout_rms² + estimate_rms² + mean_region xᵀΣ_p x),
            the stated RMS error of the model over its validity rectangle.
        validation_samples: samples predicted from fits that did not see them.
        blocks: blocks left out in turn.
        jackknife: whether Σ_p is the block jackknife (else the classical,
            correlation-inflated covariance).
    """

    model: PolynomialModel2D
    rms: float
    covariance: Array
    holdout_rms: float
    estimate_rms: float
    prediction_rms: float
    validation_samples: int
    blocks: int
    jackknife: bool

    def coefficient_std(self) -> Array:
        """√diag Σ_p, per coefficient."""
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    def std(self, slip: ArrayLike, load: ArrayLike) -> Array:
        """Stated error σ(i, W) = √(holdout_rms² + estimate_rms² + xᵀ Σ_p x) of the model's value (same units)."""
        base = self.holdout_rms**2 + self.estimate_rms**2
        return np.sqrt(base + model_variance(self.model.order, self.covariance, slip, load))


def _classical_covariance(
    slip: Array, load: Array, values: Array, weight: Array, groups: Array, model: PolynomialModel2D
) -> Array:
    """s² (XᵀWX)⁻¹ inflated by (1 + ρ)/(1 − ρ), ρ = lag-1 correlation of the period-mean residuals."""
    x = design_matrix(slip, load, model.order)
    residual = model.evaluate(slip, load) - values
    m = x.shape[1]
    dof = max(values.size - m, 1)
    s2 = float(np.sum(weight * residual**2) / dof)
    # Scale columns before inverting (W² terms are 10⁴ × the constant's).
    scale = np.sqrt(np.sum(weight[:, None] * x * x, axis=0))
    scale = np.where(scale > 0.0, scale, 1.0)
    xs = x / scale
    info = xs.T @ (weight[:, None] * xs)
    cov = np.linalg.pinv(info, rcond=1e-12) / np.outer(scale, scale) * s2
    order = np.argsort(groups, kind="stable")
    _, first = np.unique(groups[order], return_index=True)
    period_mean = np.add.reduceat(residual[order], first) / np.diff(np.append(first, residual.size))
    rho = 0.0
    if period_mean.size >= 3 and np.std(period_mean) > 0.0:
        rho = float(np.corrcoef(period_mean[:-1], period_mean[1:])[0, 1])
        rho = min(max(rho, 0.0), 0.95) if math.isfinite(rho) else 0.0
    return np.asarray(cov * (1.0 + rho) / (1.0 - rho), dtype=float)


def validated_fit(
    slip: ArrayLike,
    load: ArrayLike,
    values: ArrayLike,
    order: int,
    *,
    groups: ArrayLike,
    weights: ArrayLike | None = None,
    max_blocks: int = 10,
    sample_variances: ArrayLike | None = None,
) -> ValidatedFit:
    """Least-squares fit (:func:`fit_polynomial_2d`) with block-jackknife covariance and held-out error.

    Args:
        slip, load, values: (n,) samples (–, N, response units).
        order: polynomial order.
        groups: (n,) sample-period key per sample (e.g. its stamp); blocks
            are contiguous runs of the sorted keys.
        weights: w ≥ 0 per sample (as :func:`fit_polynomial_2d`), None = equal.
        max_blocks: at most this many blocks (≥ 2).
        sample_variances: (n,) stated variance of each sample's value (e.g.
            the estimator's variance of the averaged estimates); NaN entries
            are unknown and skipped; None: ``estimate_rms`` = 0.

    Raises:
        ValueError: as :func:`fit_polynomial_2d` for the fit to all samples.
    """
    i = np.asarray(slip, dtype=float).ravel()
    w = np.asarray(load, dtype=float).ravel()
    y = np.asarray(values, dtype=float).ravel()
    g = np.asarray(groups, dtype=float).ravel()
    weight = np.ones(y.shape) if weights is None else np.broadcast_to(np.asarray(weights, dtype=float), y.shape).ravel()
    if not (i.shape == w.shape == y.shape == g.shape):
        raise ValueError("slip, load, values and groups must have the same number of samples")
    if max_blocks < 2:
        raise ValueError(f"max_blocks must be ≥ 2, got {max_blocks}")
    full = fit_polynomial_2d(i, w, y, order, weight)
    used = weight > 0.0
    estimate = 0.0
    if sample_variances is not None:
        sv = np.broadcast_to(np.asarray(sample_variances, dtype=float), y.shape).ravel()[used]
        known = np.isfinite(sv) & (sv >= 0.0)
        if np.any(known):
            estimate = math.sqrt(float(np.sum(weight[used][known] * sv[known]) / np.sum(weight[used][known])))
    i, w, y, g, weight = i[used], w[used], y[used], g[used], weight[used]
    labels = block_labels(g, max_blocks)
    blocks = int(labels.max()) + 1
    m = coefficient_count(order)
    loo: list[tuple[float, ...]] = []
    sq, sw, n_held = 0.0, 0.0, 0
    for b in range(blocks):
        out = labels == b
        try:
            part = fit_polynomial_2d(i[~out], w[~out], y[~out], order, weight[~out]).model
        except ValueError:  # the rest is rank deficient (e.g. one slip value): no refit without this block
            continue
        loo.append(part.coefficients)
        r = part.evaluate(i[out], w[out]) - y[out]
        sq += float(np.sum(weight[out] * r**2))
        sw += float(np.sum(weight[out]))
        n_held += int(np.count_nonzero(out))
    jackknife = len(loo) >= MIN_JACKKNIFE_BLOCKS
    if jackknife:
        p = np.array(loo, dtype=float)
        dev = p - p.mean(axis=0)
        cov = (len(loo) - 1) / len(loo) * (dev.T @ dev)
        dof = len(loo) - 1
        if dof < m:
            # B refits span only B − 1 directions of the m coefficients: the jackknife states the others
            # certain. The classical covariance gives every direction its uncertainty.
            cov = cov + _classical_covariance(i, w, y, weight, g, full.model)
    else:
        cov = _classical_covariance(i, w, y, weight, g, full.model)
        dof = max(y.size - m, 1)
    if n_held > 0 and sw > 0.0:
        holdout = math.sqrt(sq / sw)
    else:  # nothing could be held out: the residual, corrected for the fitted degrees of freedom
        holdout = full.rms * math.sqrt(y.size / max(y.size - m, 1))
    # Both variances are estimated from few independent pieces (the blocks): the error they state is
    # Student-t with ν = dof, whose variance is ν/(ν − 2) times the estimate (3 for ν = 3, 1.29 for ν = 9).
    small = dof / (dof - 2.0) if dof > 2 else 3.0
    cov = cov * small
    holdout *= math.sqrt(small)
    region = full.model.validity
    assert region is not None
    prediction = math.sqrt(holdout**2 + estimate**2 + region_mean_variance(order, cov, region))
    return ValidatedFit(
        model=full.model,
        rms=full.rms,
        covariance=np.asarray(cov, dtype=float),
        holdout_rms=holdout,
        estimate_rms=estimate,
        prediction_rms=prediction,
        validation_samples=n_held,
        blocks=blocks,
        jackknife=jackknife,
    )


@dataclass(frozen=True)
class BoundedUpdate:
    """The published coefficients and covariance after :func:`bounded_update`.

    Attributes:
        coefficients: (n,) published coefficients.
        covariance: (n, n) their stated covariance (the fit's, plus o oᵀ of the step not taken).
        distance: Mahalanobis distance of the new fit from the previous model, in the previous covariance.
        limited: whether the step was shortened.
    """

    coefficients: Array
    covariance: Array
    distance: float
    limited: bool


def bounded_update(
    previous: ArrayLike | None,
    previous_covariance: ArrayLike | None,
    fit: ArrayLike,
    fit_covariance: ArrayLike,
    max_jump: float,
) -> BoundedUpdate:
    """Move from the previous published coefficients towards a new fit by at most ``max_jump`` stated σ.

    Args:
        previous, previous_covariance: the last published coefficients (n,) and covariance (n, n); None: first model.
        fit, fit_covariance: the new fit and its covariance.
        max_jump: largest Mahalanobis step in the previous covariance (> 0; ``math.inf``: no bound).
    """
    p_fit = np.asarray(fit, dtype=float).ravel()
    cov_fit = np.asarray(fit_covariance, dtype=float)
    if previous is None or previous_covariance is None:
        return BoundedUpdate(p_fit.copy(), cov_fit.copy(), 0.0, False)
    if not max_jump > 0.0:
        raise ValueError(f"max_jump must be > 0, got {max_jump!r}")
    p_prev = np.asarray(previous, dtype=float).ravel()
    if p_prev.shape != p_fit.shape:  # another order: nothing to compare
        return BoundedUpdate(p_fit.copy(), cov_fit.copy(), math.inf, False)
    delta = p_fit - p_prev
    distance = mahalanobis_distance(delta, previous_covariance)
    if distance <= max_jump:
        return BoundedUpdate(p_fit.copy(), cov_fit.copy(), distance, False)
    if not math.isfinite(distance):  # a coefficient stated exact moves: no step can be bounded, take the fit
        return BoundedUpdate(p_fit.copy(), cov_fit.copy(), distance, False)
    published = p_prev + delta * (max_jump / distance)
    offset = p_fit - published
    return BoundedUpdate(published, cov_fit + np.outer(offset, offset), distance, True)
