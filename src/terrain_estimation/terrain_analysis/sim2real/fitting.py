"""Fitting a replay model on the training part of a bag and scoring it on the held-out part.

The split (:func:`held_out_mask`: interleaved blocks after the warm-up), the
fitting problem of one split (:class:`_Problem`), the bounded least-squares
fit of the nuisance plus candidate effects (:func:`fit`) with its
autocorrelation-honest parameter intervals (:func:`_correlation_time`,
:func:`_parameter_std`), and the knobs of the whole attribution
(:class:`AttributionSettings`). The method is described in
:mod:`~terrain_analysis.sim2real.attribution`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, stats

from terrain_analysis.sim2real.model import Candidate, FitParameter, ReplayModel, usable_mask
from terrain_analysis.sim2real.where import WhereSettings, _jsonable

__all__ = ["AttributionSettings", "FittedModel", "fit", "held_out_mask"]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
Progress = Callable[[str], None] | None


@dataclass(frozen=True)
class AttributionSettings:
    """Knobs of the attribution (the defaults are what the CLI uses).

    Attributes:
        block: Length of the train/held-out blocks (s).
        test_every: Every n-th block is held out (3: a third of the data).
        max_nfev: Model evaluations per least-squares start.
        pair_candidates: Candidates combined with the best one in the pair stage.
        bootstrap: Bootstrap resamples of the held-out blocks.
        confidence: Level of the intervals.
        significance: Confidence that the change an effect (or a pair's
            second effect) predicts is in the held-out data, for it to count
            (one-sided matched-filter test, :func:`_p_better`); it must also
            lower the penalised held-out score, by ``min_improvement``.
        min_improvement: Smallest relative held-out χ² reduction that counts
            (guards against significant but negligible improvements).
        explained_shrinkage: An effect whose shrinkage interval's lower bound
            reaches this explains the gap even when a noise test still flags a
            remainder (a near-perfect but not exact model of the effect).
        max_starts: Optimiser runs per fit: the base start plus the best
            (lowest cost) of the ± and scan starts.
        grid_points: Points of the scan of each new parameter over its bounds
            that gives the fit one more start (0: no scan).
        channel_partner: A runner-up that shrinks some channel's held-out gap by
            more than this is tried in a pair even when not significant overall.
        ambiguity: Held-out penalised-score difference (relative to the
            nominal model's excess χ²) under which two candidates are reported
            as indistinguishable (as are those the held-out test cannot tell
            apart: :func:`_indistinguishable`).
        lr_significance: Level of the held-out likelihood-ratio test
            (:func:`_likelihood_ratio`) by which a small-signal effect counts
            although it lowers the held-out χ² by less than ``min_improvement``
            (a delay whose change is far below a conservative noise budget
            but plain against the residual's own level). Stricter than
            ``significance``: it replaces the relative-improvement guard.
        cross_fit: Candidates (the best-scoring ones the one-fold tests leave
            undecided, with a held-out likelihood-ratio confidence ≥ 0.9) whose
            likelihood ratio is taken over every fold (:func:`_cross_fitted`;
            0: never). Each costs ``test_every − 1`` more fits.
        lr_material: An effect significant by the likelihood ratio alone counts only
            when a parameter lies at least this fraction of its typical
            deviation (the candidate's scale) from off (:func:`_small_signal_ok`).
        stability_regimes: Regimes of the replay model (the first ones) in whose
            lower and upper halves the best single effect is refitted: a
            parameter that moves with the operating point names a structure
            gap (:func:`_stability`; 0: never). Costs two fits per regime.
        stability_material: Smallest difference between the halves' values,
            relative to the effect's size, that counts (with significance).
        bound_tolerance: A fitted parameter within this fraction of its range
            of a bound (other than its off value) is "at its bound": the best
            explanation then names a structure gap, not the effect.
        identifiable_chi2: An effect whose change at its typical magnitude
            (against the nominal model, on the held-out part, in units of
            the noise budget) is below this χ² cannot be identified from the
            bag: reported as "not identifiable from this bag" (16: a 4σ
            matched-filter signature, the level at which the held-out tests
            detect it with ≈ 90 % power at the 0.99–0.999 levels).
        chi2_step: The optimiser stops at an iteration that lowers the training χ²
            by less than about this (χ² units at the noise level: scipy's relative
            ``ftol`` = chi2_step / rows, ½χ² ≈ rows / 2 there), the same rule for a
            15 s and a 1 h bag. A thousandth of a χ² unit moves no test (their
            thresholds are χ² quantiles and p ln n penalties of several units); the
            fixed relative tolerance (10⁻⁸ of the cost) kept the optimiser crawling
            along flat valleys (nonlinear_soil's a–λ trade-off) to ``max_nfev`` on
            every start: 4 × 160 evaluations of the costliest replay for a χ²
            change of 0.02, and a cost that followed the bag's content, not its length.
        where: Noise tests used for "no significant gap" and "explained".
        seed: Seed of the bootstrap (analysis only; nothing of the data).
    """

    block: float = 1.0
    test_every: int = 3
    max_nfev: int = 40
    pair_candidates: int = 4
    bootstrap: int = 400
    confidence: float = 0.9
    significance: float = 0.99
    min_improvement: float = 0.02
    ambiguity: float = 0.02
    channel_partner: float = 0.25
    explained_shrinkage: float = 0.9
    grid_points: int = 11
    max_starts: int = 4
    lr_significance: float = 0.999
    cross_fit: int = 2
    lr_material: float = 0.25
    stability_regimes: int = 2
    stability_material: float = 0.2
    bound_tolerance: float = 1e-3
    identifiable_chi2: float = 16.0
    chi2_step: float = 0.001
    where: WhereSettings = field(default_factory=WhereSettings)
    seed: int = 0


@dataclass
class FittedModel:
    """The nominal model or the nominal model plus one or two effects, fitted and scored.

    Attributes:
        effects: Effect names (empty: the nominal model).
        parameters: Fitted effect parameters {effect: {parameter: value}}.
        std: Their standard errors (same layout): a sandwich (Huber–White)
            covariance whose middle term sums the training residual's score
            contributions over time batches longer than its correlation time
            (batch means), so autocorrelated residuals widen them; never below
            the white Gauss–Newton value.
        interval: Their ``confidence`` intervals (Student's t with the batches − 1
            degrees of freedom), {effect: {parameter: (low, high)}}.
        nuisance: Fitted nuisance parameters.
        nuisance_std: Their standard errors (as ``std``).
        batches: Time batches of the interval's variance (0: no fit).
        correlation_time: Integrated autocorrelation time of the training residual (s, the longest channel's).
        added: Parameters the effects add (p of the penalty).
        train_chi2: χ² on the training part.
        test_chi2: χ² on the held-out part.
        score: Penalised held-out score J = χ² + p ln n.
        gap: Held-out gap G per channel and ``"overall"``.
        shrinkage: 1 − G / G_nominal per channel and ``"overall"`` (nominal: 0).
        shrinkage_ci: Bootstrap interval of the overall shrinkage.
        p_better: Confidence that the held-out data contain the change this
            model predicts over the nominal (one-sided matched filter,
            batch-means variance; :func:`_p_better`).
        lr: Held-out likelihood-ratio statistic against the nominal: the held-out
            χ² drop in units of the residual's own level, divided by its
            autocorrelation inflation (:func:`_likelihood_ratio`).
        p_lr: Confidence of the held-out likelihood-ratio test.
        cross_fitted: ``lr`` and ``p_lr`` are over every fold (:func:`_cross_fitted`).
        cv_drop: Held-out χ² drop against the nominal model over every fold (cross-fitted only).
        cv_samples: Samples of that cross-fitted score (0: not cross-fitted).
        by_likelihood: Significant by the likelihood-ratio test alone (its relative
            held-out improvement is below ``min_improvement``).
        significant: Improvement over the nominal counts (p_better, min_improvement).
        at_noise: Its held-out residuals pass the noise tests on every channel.
        residual_gaps: What the noise tests still flag on the held-out part.
        evaluations: Model evaluations spent on the fit.
        seconds: Wall time of the fit.
    """

    effects: tuple[str, ...]
    parameters: dict[str, dict[str, float]]
    std: dict[str, dict[str, float]]
    nuisance: dict[str, float]
    added: int
    train_chi2: float
    test_chi2: float
    score: float
    gap: dict[str, float]
    shrinkage: dict[str, float] = field(default_factory=dict)
    shrinkage_ci: tuple[float, float] = (0.0, 0.0)
    p_better: float = 0.0
    lr: float = 0.0
    p_lr: float = 0.0
    cross_fitted: bool = False
    cv_drop: float = 0.0
    cv_samples: int = 0
    by_likelihood: bool = False
    interval: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    nuisance_std: dict[str, float] = field(default_factory=dict)
    batches: int = 0
    correlation_time: float = 0.0
    significant: bool = False
    at_noise: bool = False
    residual_gaps: list[str] = field(default_factory=list)
    evaluations: int = 0
    seconds: float = 0.0
    # Held-out block χ² sums (for the bootstrap), the stacked held-out residuals, their
    # (channel, block) segment ids and their block ids (for the held-out test); not in to_dict().
    block_chi2: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
    block_n: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
    test_residual: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
    test_segment: NDArray[np.int_] = field(default_factory=lambda: np.zeros(0, dtype=int), repr=False)
    test_block: NDArray[np.int_] = field(default_factory=lambda: np.zeros(0, dtype=int), repr=False)
    # The same over every fold once cross-fitted (:func:`~terrain_analysis.sim2real.significance._cross_fitted`):
    # this model's and the nominal model's held-out residuals, segments and blocks.
    cv_residual: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
    cv_reference: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
    cv_segment: NDArray[np.int_] = field(default_factory=lambda: np.zeros(0, dtype=int), repr=False)
    cv_block: NDArray[np.int_] = field(default_factory=lambda: np.zeros(0, dtype=int), repr=False)

    _INTERNAL = (
        "block_chi2",
        "block_n",
        "test_residual",
        "test_segment",
        "test_block",
        "cv_residual",
        "cv_reference",
        "cv_segment",
        "cv_block",
    )

    @property
    def name(self) -> str:
        return " + ".join(self.effects) if self.effects else "nominal"

    def to_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in asdict(self).items() if k not in self._INTERNAL}
        out["name"] = self.name
        return _jsonable(out)


# ---------------------------------------------------------------------------
# Split
# ---------------------------------------------------------------------------


def held_out_mask(
    model: ReplayModel, settings: AttributionSettings, fold: int | None = None
) -> tuple[dict[str, BoolArray], dict[str, BoolArray]]:
    """(train, test) masks per channel: interleaved blocks after the warm-up, inside the model's
    domain (:func:`~terrain_analysis.sim2real.model.usable_mask`). ``fold``: which of the
    ``test_every`` interleaved sets is held out (default the last; the others for cross-fitting)."""
    fold = settings.test_every - 1 if fold is None else int(fold)
    t0 = min(float(model.times[c.name][0]) for c in model.channels)
    train: dict[str, BoolArray] = {}
    test: dict[str, BoolArray] = {}
    for ch in model.channels:
        t = np.asarray(model.times[ch.name], dtype=float)
        use = usable_mask(model, ch.name, t0)
        block = np.floor((t - t0 - model.warmup) / settings.block).astype(int)
        is_test = (block % settings.test_every) == fold
        train[ch.name] = use & ~is_test
        test[ch.name] = use & is_test
    return train, test


def _block_ids(model: ReplayModel, settings: AttributionSettings, mask: Mapping[str, BoolArray]) -> dict[str, Any]:
    """Block index of every held-out sample (bootstrap unit)."""
    t0 = min(float(model.times[c.name][0]) for c in model.channels)
    out = {}
    for ch in model.channels:
        t = np.asarray(model.times[ch.name], dtype=float)[mask[ch.name]]
        out[ch.name] = np.floor((t - t0 - model.warmup) / settings.block).astype(int)
    return out


# ---------------------------------------------------------------------------
# Fitting
# ---------------------------------------------------------------------------


@dataclass
class _Problem:
    model: ReplayModel
    sigma: dict[str, float]
    train: dict[str, BoolArray]
    test: dict[str, BoolArray]
    test_blocks: dict[str, Any]
    blocks: FloatArray
    evaluations: int = 0
    shortest_batch: float = 1.0  # s, of the batch means of the parameter covariance
    _segments: NDArray[np.int_] | None = None
    _train_layout: tuple[FloatArray, NDArray[np.int_], list[tuple[int, int, float]]] | None = None

    def residuals(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, FloatArray]:
        self.evaluations += 1
        pred = self.model.predict(effects, nuisance)
        out = {}
        for ch in self.model.channels:
            r = (np.asarray(self.model.measured[ch.name], dtype=float) - pred[ch.name]) / self.sigma[ch.name]
            out[ch.name] = np.where(np.isfinite(r), r, 1e3)
        return out

    def stacked(self, res: Mapping[str, FloatArray], part: Mapping[str, BoolArray]) -> FloatArray:
        return np.concatenate([res[c.name][part[c.name]] for c in self.model.channels])

    def stacked_segments(self) -> NDArray[np.int_]:
        """Segment id of every sample of ``stacked(·, test)``: one per (channel, held-out block).

        Within a segment the samples are consecutive in time (the paired test's
        autocovariances are taken inside segments only). The same for every fit: computed once.
        """
        if self._segments is None:
            index = {int(b): i for i, b in enumerate(self.blocks)}
            nb = len(self.blocks)
            self._segments = np.concatenate(
                [
                    k * nb + np.array([index[int(b)] for b in self.test_blocks[c.name]], dtype=int)
                    for k, c in enumerate(self.model.channels)
                ]
            )
        return self._segments

    def train_layout(self) -> tuple[FloatArray, NDArray[np.int_], list[tuple[int, int, float]]]:
        """(time, segment id, per-channel (start, stop, sample step)) of ``stacked(·, train)``.

        A segment is one channel's contiguous training run (between held-out
        blocks); the same for every fit: computed once.
        """
        if self._train_layout is None:
            times, segs, spans = [], [], []
            start, next_seg = 0, 0
            for ch in self.model.channels:
                t = np.asarray(self.model.times[ch.name], dtype=float)
                sel = self.train[ch.name]
                idx = np.flatnonzero(sel)
                tt = t[idx]
                brk = np.r_[True, np.diff(idx) > 1] if idx.size else np.zeros(0, dtype=bool)
                seg = next_seg + np.cumsum(brk) - 1
                next_seg += int(np.sum(brk))
                dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
                times.append(tt)
                segs.append(seg.astype(int))
                spans.append((start, start + tt.size, dt))
                start += tt.size
            self._train_layout = (
                np.concatenate(times) if times else np.zeros(0),
                np.concatenate(segs).astype(int) if segs else np.zeros(0, dtype=int),
                spans,
            )
        return self._train_layout

    def block_sums(self, res: Mapping[str, FloatArray]) -> tuple[FloatArray, FloatArray]:
        chi = np.zeros(len(self.blocks))
        n = np.zeros(len(self.blocks))
        index = {int(b): i for i, b in enumerate(self.blocks)}
        for ch in self.model.channels:
            r = res[ch.name][self.test[ch.name]]
            ids = np.array([index[int(b)] for b in self.test_blocks[ch.name]], dtype=int)
            np.add.at(chi, ids, r**2)
            np.add.at(n, ids, 1.0)
        return chi, n


def _problem(
    model: ReplayModel,
    settings: AttributionSettings,
    train: dict[str, BoolArray],
    test: dict[str, BoolArray],
    test_blocks: dict[str, Any],
) -> _Problem:
    """The fitting problem of one train/test split (every held-out block of every channel)."""
    all_blocks = np.unique(np.concatenate([np.asarray(v, dtype=int) for v in test_blocks.values()]))
    return _Problem(
        model=model,
        sigma={c.name: float(c.noise_std) for c in model.channels},
        train=train,
        test=test,
        test_blocks=test_blocks,
        blocks=all_blocks.astype(float),
        shortest_batch=settings.block,
    )


def _layout(nuisance: Sequence[FitParameter], candidates: Sequence[Candidate]) -> list[tuple[str | None, FitParameter]]:
    out: list[tuple[str | None, FitParameter]] = [(None, p) for p in nuisance]
    for c in candidates:
        out += [(c.name, p) for p in c.parameters]
    return out


def _unpack(
    layout: list[tuple[str | None, FitParameter]], x: FloatArray, candidates: Sequence[Candidate]
) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
    effects: dict[str, dict[str, float]] = {c.name: {} for c in candidates}
    nuisance: dict[str, float] = {}
    for (owner, p), v in zip(layout, x, strict=True):
        if owner is None:
            nuisance[p.name] = float(v)
        else:
            effects[owner][p.name] = float(v)
    return effects, nuisance


def _correlation_time(problem: _Problem, r_train: FloatArray) -> float:
    """Integrated autocorrelation time (s) of the training residual: the longest over channels.

    τ = 1 + 2 Σ ρ_k (Geyer's initial positive sequence, as
    :func:`terrain_estimation.analysis.consistency.integrated_autocorrelation_time`),
    with ρ_k taken over every pair of training samples k apart on the
    channel's own sample grid (FFT of the residual and of the training mask:
    pairs straddle the held-out blocks, so a correlation longer than one
    training run is still seen), times the channel's sample step.
    """
    _, _, spans = problem.train_layout()
    longest = 0.0
    for ch, (a, b, dt) in zip(problem.model.channels, spans, strict=True):
        idx = np.flatnonzero(problem.train[ch.name])
        if b - a < 8 or idx.size != b - a:
            continue
        x = r_train[a:b] - float(np.mean(r_train[a:b]))
        grid = np.zeros(int(idx[-1] - idx[0]) + 1)
        mask = np.zeros_like(grid)
        grid[idx - idx[0]] = x
        mask[idx - idx[0]] = 1.0
        size = 1 << (2 * grid.size - 1).bit_length()
        fx, fm = np.fft.rfft(grid, size), np.fft.rfft(mask, size)
        cxx = np.fft.irfft(fx * np.conj(fx), size)[: grid.size]
        pairs = np.fft.irfft(fm * np.conj(fm), size)[: grid.size]
        if cxx[0] <= 0.0:
            continue
        usable = int(np.argmax(pairs < 0.25 * pairs[0])) if np.any(pairs < 0.25 * pairs[0]) else grid.size
        rho = (cxx[:usable] / np.maximum(pairs[:usable], 1.0)) / (cxx[0] / pairs[0])
        tau = -1.0
        for m in range(max(1, usable // 2)):
            pair = float(rho[2 * m] + rho[2 * m + 1]) if 2 * m + 1 < usable else 0.0
            if pair <= 0.0:
                break
            tau += 2.0 * pair
        longest = max(longest, max(1.0, tau) * dt)
    return longest


def _parameter_std(
    problem: _Problem, jac: FloatArray, r_train: FloatArray, corr: float
) -> tuple[FloatArray, FloatArray, int]:
    """(standard errors, degrees of freedom, batches) of the fitted parameters; ``corr``: the residual's
    integrated autocorrelation time (s, :func:`_correlation_time`).

    Sandwich covariance H⁻¹ M H⁻¹ with H = JᵀJ (prior rows included: a
    tolerance narrows its parameter) and M = B/(B − 1) Σ_b S_b S_bᵀ, S_b the
    sum over time batch b of the score contributions J_i r_i (r in units of
    the noise budget, so M carries the residual's own level, not the
    budget's). Batches are stretches of time of ten integrated
    autocorrelation times of the training residual (at most a quarter of the
    bag, at least one block of the split); all channels of a stretch go into the same batch.
    The interval uses Student's t with B − 1 degrees of freedom. Never below the white
    Gauss–Newton covariance s² H⁻¹ (s² the residual's mean square): a residual
    that looks less correlated than white noise on a few batches is chance.
    Returns also the degrees of freedom of each variance (B − 1 for the
    sandwich; infinite where the white value, from every sample, is used).
    """
    n = r_train.size
    t, _, _ = problem.train_layout()
    j_data = jac[:n]
    h_inv, unidentified = _information_inverse(jac.T @ jac)
    s2 = float(np.dot(r_train, r_train)) / max(1, n - jac.shape[1])
    white = np.clip(np.diag(h_inv) * s2, 0.0, None)
    span = float(t.max() - t.min()) if n else 0.0
    # Ten integrated autocorrelation times (the batch-means variance is then ≈ 10 % low), but at least four
    # batches: a residual correlated over much of the bag leaves few batches, whose variance Student's t
    # (batches − 1 degrees of freedom) then widens.
    length = max(problem.shortest_batch, min(10.0 * corr, span / 4.0))
    ids = np.floor((t - float(t.min())) / length).astype(int) if n else np.zeros(0, dtype=int)
    _, ids = np.unique(ids, return_inverse=True)
    batches = int(ids.max()) + 1 if n else 0
    if batches < 3:
        white[unidentified] = np.inf
        return np.sqrt(white), np.full(white.size, np.inf), batches
    score = j_data * r_train[:, None]
    sums = np.zeros((batches, jac.shape[1]))
    np.add.at(sums, ids, score)
    meat = sums.T @ sums * batches / (batches - 1)
    sandwich = np.clip(np.diag(h_inv @ meat @ h_inv), 0.0, None)
    # Where the white value is the larger, it is the estimate (from every sample: normal quantile).
    dof = np.where(sandwich >= white, float(batches - 1), np.inf)
    var = np.maximum(sandwich, white)
    var[unidentified] = np.inf
    return np.sqrt(var), dof, batches


#: A direction of the scaled information matrix whose eigenvalue is below this share of the largest
#: carries no information from the data (finite-difference noise and round-off sit far above it only
#: when the data do constrain it).
UNIDENTIFIED_RCOND = 1e-12
#: A parameter whose squared loading on such a direction exceeds this is not identified by the data.
UNIDENTIFIED_LOADING = 1e-6


def _information_inverse(h: FloatArray) -> tuple[FloatArray, BoolArray]:
    """(H⁻¹ on the identified subspace, which parameters are not identified) of an information matrix.

    A parameter the data do not constrain (a zero Jacobian column, or a combination of parameters the
    residual cannot tell apart) has an infinite variance. A plain pseudo-inverse gives such a direction
    zero variance instead, and with it a falsely tight interval. H is equilibrated by its diagonal
    first, so that the rank decision does not depend on the parameters' units.
    """
    d = np.sqrt(np.clip(np.diag(h), 0.0, None))
    zero = ~(d > 0.0)
    scale = np.where(zero, 1.0, d)
    hs = h / np.outer(scale, scale)
    hs[zero, :] = 0.0
    hs[:, zero] = 0.0
    lam, vec = np.linalg.eigh(0.5 * (hs + hs.T))
    top = float(lam.max()) if lam.size else 0.0
    keep = lam > UNIDENTIFIED_RCOND * top if top > 0.0 else np.zeros(lam.shape, dtype=bool)
    inv_s = (vec[:, keep] / lam[keep]) @ vec[:, keep].T
    unidentified = zero | (np.sum(vec[:, ~keep] ** 2, axis=1) > UNIDENTIFIED_LOADING)
    return inv_s / np.outer(scale, scale), unidentified


def fit(
    problem: _Problem,
    candidates: Sequence[Candidate],
    start_nuisance: Mapping[str, float],
    settings: AttributionSettings,
    start_effects: Mapping[str, Mapping[str, float]] | None = None,
) -> FittedModel:
    """Fit nuisance + the candidates' parameters on the training part; score on the held-out part."""
    t_start = time.perf_counter()
    n_eval0 = problem.evaluations
    model = problem.model
    layout = _layout(model.nuisance, candidates)
    lo = np.array([p.bounds[0] for _, p in layout], dtype=float)
    hi = np.array([p.bounds[1] for _, p in layout], dtype=float)
    scale = np.array([p.scale for _, p in layout], dtype=float)
    x0 = []
    for owner, p in layout:
        if owner is None:
            x0.append(float(start_nuisance.get(p.name, p.off)))
        elif start_effects and owner in start_effects and p.name in start_effects[owner]:
            x0.append(float(start_effects[owner][p.name]))
        else:
            x0.append(p.off)
    base = np.clip(np.array(x0, dtype=float), lo, hi)
    # Nominal tolerances (FitParameter.prior_std): a Gaussian prior about the nominal value, one
    # more residual row each, so that a mismatch inside the tolerance costs almost nothing.
    prior_idx = np.array([i for i, (_, p) in enumerate(layout) if p.prior_std is not None], dtype=int)
    prior_off = np.array([layout[i][1].off for i in prior_idx], dtype=float)
    prior_sd = np.array([float(layout[i][1].prior_std or 1.0) for i in prior_idx], dtype=float)

    def fun(x: FloatArray) -> FloatArray:
        effects, nuisance = _unpack(layout, x, candidates)
        r = problem.stacked(problem.residuals(effects, nuisance), problem.train)
        if prior_idx.size:
            r = np.concatenate([r, (x[prior_idx] - prior_off) / prior_sd])
        return r

    def _cost(x: FloatArray) -> float:
        return 0.5 * float(np.sum(fun(x) ** 2))

    best_x = base
    if len(layout):
        starts = [base]
        n_nuis = len(model.nuisance)
        free = [i for i in range(n_nuis, len(layout)) if not (start_effects and layout[i][0] in start_effects)]
        for i in free:
            for sign in (1.0, -1.0):
                s = base.copy()
                s[i] = np.clip(s[i] + sign * scale[i], lo[i], hi[i])
                if s[i] != base[i]:
                    starts.append(s)
        # The candidates' own extra starts (Candidate.starts): other laws of a shape family.
        position = {(owner, p.name): i for i, (owner, p) in enumerate(layout)}
        for cand in candidates:
            if start_effects and cand.name in start_effects:
                continue
            for point in cand.starts:
                s = base.copy()
                for name, value in point:
                    i = position[(cand.name, name)]
                    s[i] = np.clip(value, lo[i], hi[i])
                starts.append(s)
        # A coarse scan of each new parameter over its whole range: local starts miss
        # the global minimum of periodic costs (a delay against a narrow-band signal, the
        # location of a soil change). Its best point, if better than the base, is one more start.
        known: dict[int, float] = {}  # start index -> cost already evaluated

        def scan(start: FloatArray, indices: Sequence[int], below: float) -> tuple[FloatArray | None, float]:
            """The best point (and its cost) of ``start`` with one of ``indices`` moved over its range, if
            any costs less than ``below``."""
            found: FloatArray | None = None
            for i in indices:
                for v in np.linspace(lo[i], hi[i], settings.grid_points):
                    s = start.copy()
                    s[i] = v
                    c = _cost(s)
                    if c < below:
                        found, below = s, c
            return found, below

        if free and settings.grid_points > 0:
            grid_best, grid_cost = scan(base, free, _cost(base))
            if grid_best is not None:
                known[len(starts)] = grid_cost
                starts.append(grid_best)
        # A nuisance at a bound of its range in the start is a nominal fit that absorbed the gap into it
        # (a profile 0.23 s late drove the soil stiffness to its bound, 1/700 of the true one, and no
        # delay fit came back from there): each start once more with that nuisance at the best point of
        # a scan over its range.
        span_all = hi - lo
        stuck = [
            i for i in range(n_nuis) if min(base[i] - lo[i], hi[i] - base[i]) <= settings.bound_tolerance * span_all[i]
        ]
        if stuck and settings.grid_points > 0:
            for k in range(len(starts)):
                rescued, rescued_cost = scan(starts[k], stuck, math.inf)
                if rescued is not None:
                    known[len(starts)] = rescued_cost
                    starts.append(rescued)
        # Screen the starts by their cost (one evaluation each) and run the optimiser from the
        # base and the best others only: 2p ± starts of a 5-parameter effect would cost 11 fits.
        if len(starts) > settings.max_starts:
            costs = [known[k] if k in known else _cost(starts[k]) for k in range(1, len(starts))]
            order = np.argsort(costs)[: max(settings.max_starts - 1, 0)]
            starts = [starts[0]] + [starts[1 + int(i)] for i in order]
        best_cost = math.inf
        # The stopping rule in χ² units (AttributionSettings.chi2_step): relative to the rows' count.
        rows = sum(int(np.sum(problem.train[c.name])) for c in model.channels) + int(prior_idx.size)
        ftol = max(settings.chi2_step / max(rows, 1), 1e-14)
        for s in starts:
            # Keep the start strictly inside the bounds (least_squares requires it).
            span = hi - lo
            s = np.clip(s, lo + 1e-9 * span, hi - 1e-9 * span)
            try:
                sol = optimize.least_squares(
                    fun,
                    s,
                    bounds=(lo, hi),
                    x_scale=scale,
                    method="trf",
                    max_nfev=settings.max_nfev,
                    diff_step=1e-3,
                    ftol=ftol,
                )
            except (ValueError, FloatingPointError):  # pragma: no cover - defensive
                continue
            if sol.cost < best_cost:
                best_cost, best_x, jac = float(sol.cost), sol.x, sol.jac
    effects, nuisance = _unpack(layout, best_x, candidates)
    res = problem.residuals(effects, nuisance)
    r_train = problem.stacked(res, problem.train)
    r_test = problem.stacked(res, problem.test)
    n_test = r_test.size
    added = sum(c.size for c in candidates)
    # Standard errors: a sandwich covariance whose middle term comes from batch means of the
    # training residual's score contributions (autocorrelated residuals widen the intervals).
    std: dict[str, dict[str, float]] = {c.name: {} for c in candidates}
    interval: dict[str, dict[str, tuple[float, float]]] = {c.name: {} for c in candidates}
    nuisance_std: dict[str, float] = {}
    batches, corr_time = 0, _correlation_time(problem, r_train)
    if len(layout):
        try:
            sd, dof, batches = _parameter_std(problem, jac, r_train, corr_time)
        except (np.linalg.LinAlgError, UnboundLocalError, ValueError):
            sd, dof = np.full(len(layout), np.nan), np.full(len(layout), np.inf)
        quantile = stats.t.ppf(0.5 + 0.5 * settings.confidence, dof)
        for (owner, p), v, x, q in zip(layout, sd, best_x, quantile, strict=True):
            if owner is not None:
                std[owner][p.name] = float(v)
                interval[owner][p.name] = (float(x - q * v), float(x + q * v))
            else:
                nuisance_std[p.name] = float(v)
    gap = {}
    for ch in model.channels:
        r = res[ch.name][problem.test[ch.name]]
        gap[ch.name] = max(float(np.mean(r**2)) - 1.0, 0.0) if r.size else 0.0
    gap["overall"] = max(float(np.mean(r_test**2)) - 1.0, 0.0) if n_test else 0.0
    chi_test = float(np.dot(r_test, r_test))
    block_chi2, block_n = problem.block_sums(res)
    return FittedModel(
        effects=tuple(c.name for c in candidates),
        parameters={k: v for k, v in effects.items()},
        std=std,
        nuisance=nuisance,
        added=added,
        train_chi2=float(np.dot(r_train, r_train)),
        test_chi2=chi_test,
        score=chi_test + added * math.log(max(n_test, 2)),
        gap=gap,
        evaluations=problem.evaluations - n_eval0,
        seconds=time.perf_counter() - t_start,
        interval=interval,
        nuisance_std=nuisance_std,
        batches=batches,
        correlation_time=corr_time,
        block_chi2=block_chi2,
        block_n=block_n,
        test_residual=r_test,
        test_segment=problem.stacked_segments(),
        test_block=problem.stacked_segments() % max(len(problem.blocks), 1),
    )
