"""Which unmodelled effect explains the sim-to-real gap, and how far the gap shrinks.

Generic over vehicles: works on any :class:`~terrain_analysis.sim2real.model.ReplayModel`.

Method
    1. **Split.** The samples after the warm-up are cut into blocks of
       :attr:`AttributionSettings.block` seconds; every
       :attr:`~AttributionSettings.test_every`-th block is held out (the rest
       train). Interleaved blocks put every operating regime of the bag into
       both parts, which a single cut would not (an effect showing only at
       high speed would be fitted on one part and scored on the other).
       A caller may pass its own held-out mask (e.g. trials of a test rig).
    2. **Nominal model.** The nuisance parameters alone are fitted on the
       training part (weighted least squares, residuals in units of each
       channel's noise budget σ).
    3. **Each effect in turn.** Its parameters and the nuisance are fitted on
       the training part (bounded trust-region least squares,
       :func:`scipy.optimize.least_squares`, a start at the nominal value and
       starts at ± the parameter's typical size). Nominal parameters with a
       stated tolerance (:mod:`~terrain_analysis.sim2real.tolerance`) are
       nuisance parameters with a Gaussian prior (one more residual row
       each). Parameter uncertainties are a sandwich covariance whose middle
       term comes from batch means of the score contributions over stretches
       of ten integrated autocorrelation times of the residual
       (:func:`_parameter_std`); intervals use Student's t with the batches − 1
       degrees of freedom (until issue 22: Gauss–Newton inflated by the lag-1
       correlation, 3–16× too narrow on real data).
    4. **Score on held-out data.** χ² = Σ r² over the held-out samples
       (r = residual / σ), penalised like the BIC: J = χ² + p ln n with p the
       parameters the effect adds and n the held-out samples. The ranking is by J.
    5. **Gap and shrinkage.** The gap of a model on the held-out part is the
       mean normalised residual power above the noise, G = max(mean r² − 1, 0)
       (0: the residual is the noise budget). Shrinkage = 1 − G_effect / G_nominal,
       per channel and overall, with a percentile confidence interval from a
       moving-block bootstrap over held-out blocks (runs of consecutive blocks
       spanning five integrated autocorrelation times of the residual).
    6. **Pairs.** When the best single effect does not bring the held-out
       residual to the noise, it is combined with each of the next candidates
       that improved the held-out score significantly or shrank one channel's
       gap clearly (forward selection); the best pair replaces the single if
       it improves significantly on it.
    7. **Verdict.**
       * "no significant gap": the nominal model's residuals (all samples
         after the warm-up: only the nuisance is fitted) pass the noise tests
         of :mod:`~terrain_analysis.sim2real.where` (bias, power, octave
         bands; Bonferroni-corrected χ² and normal bounds with a model-error
         allowance) on every channel, and no effect improves the
         held-out score significantly;
       * "explained by X (shrinks the gap by N %)": the best effect (or pair)
         improves the held-out score significantly (the change it predicts is
         found in the held-out data by a one-sided matched-filter test with a
         block-robust variance, and it lowers the penalised held-out score by at
         least :attr:`~AttributionSettings.min_improvement`) and its held-out
         residuals pass the same noise tests, or the lower bound of its
         shrinkage interval reaches :attr:`~AttributionSettings.explained_shrinkage`;
       * otherwise "not explained by the catalogue (best candidate X leaves
         N % unexplained)", with the reason: X's improvement is not
         significant (a gap the noise tests flag that no candidate is shown to
         close on held-out data, however much it shrinks on average), or X's
         held-out residual still fails a noise test and its shrinkage interval
         starts below :attr:`~AttributionSettings.explained_shrinkage`.
       * "the model's structure differs here" (issue 22): the best significant
         explanation needs a parameter at a bound of its fit range or outside
         its plausible range, a tolerated nominal parameter beyond 3× its
         tolerance, leaves a held-out residual that fails the noise tests, or
         is matched by a runner-up of other physics (sensor vs vehicle): where,
         how big, the nearest catalogue description and why
         (:func:`_structure_reasons`); never "explained by X".
       An effect is also significant when the held-out *likelihood ratio*
       (:func:`_likelihood_ratio`: the residual's own level instead of the
       conservative budget, autocorrelation accounted for; for the most
       promising undecided candidates over every fold, :func:`_cross_fitted`)
       passes ``lr_significance``: small-signal effects (a rover delay) lower
       the held-out χ² by less than ``min_improvement``. Effects the bag
       cannot show are listed as "not identifiable from this bag" with what
       would identify them (:func:`_not_identifiable`).
       A significant runner-up is named as indistinguishable on this bag when
       the held-out data do not show the best one better (the change the best
       predicts over it is not found at the ``significance`` level, or their
       penalised scores are within :attr:`~AttributionSettings.ambiguity`):
       :func:`_indistinguishable`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, stats

from terrain_analysis.sim2real.model import Candidate, FitParameter, ReplayModel, usable_mask
from terrain_analysis.sim2real.where import ChannelReport, WhereSettings, _channel, _jsonable

__all__ = [
    "AttributionReport",
    "AttributionSettings",
    "FittedModel",
    "attribute",
    "fit",
    "held_out_mask",
]

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

    _INTERNAL = ("block_chi2", "block_n", "test_residual", "test_segment", "test_block")

    @property
    def name(self) -> str:
        return " + ".join(self.effects) if self.effects else "nominal"

    def to_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in asdict(self).items() if k not in self._INTERNAL}
        out["name"] = self.name
        return _jsonable(out)


@dataclass
class AttributionReport:
    """Result of :func:`attribute` (``to_dict()`` is JSON-serialisable)."""

    vehicle: str
    verdict: str
    kind: str  # "no_gap", "explained", "not_explained", "structure_differs"
    explained_by: tuple[str, ...]
    nominal: FittedModel
    ranking: list[FittedModel]
    pairs: list[FittedModel]
    best: FittedModel | None
    indistinguishable: list[str]
    nominal_gaps: list[str]
    channels: list[ChannelReport]
    settings: AttributionSettings
    train_samples: int
    test_samples: int
    seconds: float
    notes: list[str] = field(default_factory=list)
    structure: dict[str, Any] | None = None
    not_identifiable: list[dict[str, str]] = field(default_factory=list)
    tolerances: list[dict[str, Any]] = field(default_factory=list)
    # Held-out predictions for the figures: {model name: {channel: prediction}} (not in to_dict()).
    series: dict[str, dict[str, FloatArray]] = field(default_factory=dict, repr=False)
    test_masks: dict[str, BoolArray] = field(default_factory=dict, repr=False)

    @property
    def shrinkage(self) -> float:
        return float(self.best.shrinkage.get("overall", 0.0)) if self.best is not None else 0.0

    def to_dict(self) -> dict[str, Any]:
        return _jsonable(
            {
                "vehicle": self.vehicle,
                "verdict": self.verdict,
                "kind": self.kind,
                "explained_by": list(self.explained_by),
                "best": self.best.to_dict() if self.best is not None else None,
                "indistinguishable": self.indistinguishable,
                "nominal": self.nominal.to_dict(),
                "nominal_gaps": self.nominal_gaps,
                "ranking": [m.to_dict() for m in self.ranking],
                "pairs": [m.to_dict() for m in self.pairs],
                "channels": [asdict(c) for c in self.channels],
                "settings": asdict(self.settings),
                "train_samples": self.train_samples,
                "test_samples": self.test_samples,
                "seconds": self.seconds,
                "notes": self.notes,
                "structure": self.structure,
                "not_identifiable": self.not_identifiable,
                "tolerances": self.tolerances,
            }
        )


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
    h_inv = np.linalg.pinv(jac.T @ jac)
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
        return np.sqrt(white), np.full(white.size, np.inf), batches
    score = j_data * r_train[:, None]
    sums = np.zeros((batches, jac.shape[1]))
    np.add.at(sums, ids, score)
    meat = sums.T @ sums * batches / (batches - 1)
    sandwich = np.clip(np.diag(h_inv @ meat @ h_inv), 0.0, None)
    # Where the white value is the larger, it is the estimate (from every sample: normal quantile).
    dof = np.where(sandwich >= white, float(batches - 1), np.inf)
    return np.sqrt(np.maximum(sandwich, white)), dof, batches


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
        # A coarse scan of each new parameter over its whole range: local starts miss
        # the global minimum of periodic costs (a delay against a narrow-band signal, the
        # location of a soil change). Its best point, if better than the base, is one more start.
        known: dict[int, float] = {}  # start index -> cost already evaluated
        if free and settings.grid_points > 0:
            grid_best, grid_cost = None, _cost(base)
            for i in free:
                for v in np.linspace(lo[i], hi[i], settings.grid_points):
                    s = base.copy()
                    s[i] = v
                    c = _cost(s)
                    if c < grid_cost:
                        grid_best, grid_cost = s, c
            if grid_best is not None:
                known[len(starts)] = grid_cost
                starts.append(grid_best)
        # Screen the starts by their cost (one evaluation each) and run the optimiser from the
        # base and the best others only: 2p ± starts of a 5-parameter effect would cost 11 fits.
        if len(starts) > settings.max_starts:
            costs = [known[k] if k in known else _cost(starts[k]) for k in range(1, len(starts))]
            order = np.argsort(costs)[: max(settings.max_starts - 1, 0)]
            starts = [starts[0]] + [starts[1 + int(i)] for i in order]
        best_cost = math.inf
        for s in starts:
            # Keep the start strictly inside the bounds (least_squares requires it).
            span = hi - lo
            s = np.clip(s, lo + 1e-9 * span, hi - 1e-9 * span)
            try:
                sol = optimize.least_squares(
                    fun, s, bounds=(lo, hi), x_scale=scale, method="trf", max_nfev=settings.max_nfev, diff_step=1e-3
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


# ---------------------------------------------------------------------------
# Comparison
# ---------------------------------------------------------------------------


def _compare(
    fitted: FittedModel, reference: FittedModel, settings: AttributionSettings, rng: np.random.Generator
) -> None:
    """Shrinkage of ``fitted`` against ``reference`` (the nominal), with a block-bootstrap CI."""
    for key, g0 in reference.gap.items():
        g = fitted.gap.get(key, 0.0)
        fitted.shrinkage[key] = (1.0 - g / g0) if g0 > 0 else 0.0
    nb = len(fitted.block_chi2)
    if nb < 2:
        fitted.shrinkage_ci = (fitted.shrinkage.get("overall", 0.0),) * 2
    else:
        # Moving-block bootstrap over the held-out blocks: runs of ``run`` consecutive blocks (circular),
        # ``run`` covering five decorrelation times of the residual (1 when the blocks are independent).
        run = int(
            min(
                max(1, math.ceil(5.0 * reference.correlation_time / max(settings.block * settings.test_every, 1e-9))),
                max(1, nb // 2),
            )
        )
        starts = rng.integers(0, nb, size=(settings.bootstrap, math.ceil(nb / run)))
        idx = ((starts[:, :, None] + np.arange(run)[None, None, :]) % nb).reshape(settings.bootstrap, -1)[:, :nb]
        n = fitted.block_n[idx].sum(axis=1)
        g_e = np.maximum(fitted.block_chi2[idx].sum(axis=1) / n - 1.0, 0.0)
        g_0 = np.maximum(reference.block_chi2[idx].sum(axis=1) / n - 1.0, 0.0)
        shrink = np.where(g_0 > 0, 1.0 - g_e / np.where(g_0 > 0, g_0, 1.0), 0.0)
        a = (1.0 - settings.confidence) / 2.0
        fitted.shrinkage_ci = (float(np.quantile(shrink, a)), float(np.quantile(shrink, 1.0 - a)))
    fitted.p_better = _p_better(fitted, reference)
    fitted.lr, fitted.p_lr = _likelihood_ratio(fitted, reference)
    rel = (reference.test_chi2 - fitted.test_chi2) / max(reference.test_chi2, 1e-12)
    # A small-signal effect (a delay far below a conservative noise budget) lowers the held-out χ² by
    # little relative to it; the likelihood-ratio test against the residual's own level then decides.
    small_signal = fitted.p_lr >= settings.lr_significance and fitted.lr >= float(
        stats.chi2.ppf(settings.lr_significance, max(1, fitted.added - reference.added))
    )
    fitted.significant = bool(
        fitted.p_better >= settings.significance
        and (rel >= settings.min_improvement or small_signal)
        and fitted.score < reference.score
    )
    fitted.by_likelihood = fitted.significant and rel < settings.min_improvement


def _gap_key(gap: str) -> tuple[str, ...]:
    """(channel, test[, band]) of a noise-test finding (:func:`~terrain_analysis.sim2real.where._channel`)."""
    channel, _, rest = gap.partition(": ")
    words = rest.split()
    if not words:
        return (channel,)
    if words[0] == "band" and len(words) > 1:
        return (channel, "band", words[1])
    return (channel, words[0])


def _small_signal_ok(
    model: ReplayModel, problem: _Problem, m: FittedModel, nominal_gaps: Sequence[str], settings: AttributionSettings
) -> bool:
    """Whether an effect significant by the likelihood ratio alone may count.

    Its size must be material: some parameter at least ``lr_material`` of its
    typical deviation (the candidate's scale) from off. A coherent change far
    below a typical effect is what a replay's own small errors look like (a
    3 ms "delay" on a skid-steer control of the withheld suite).

    The likelihood-ratio path is for effects the noise tests cannot see. When
    they do flag a gap, an effect that counts only by the likelihood ratio
    must close every gap they flag (its held-out residual passes those tests);
    otherwise it is a small coherent piece of a larger mismatch (a replay's
    timing error next to an unmodelled force), not the explanation.
    """
    material = False
    for effect in m.effects:
        cand = model.candidates.get(effect)
        for p in cand.parameters if cand is not None else ():
            v = float(m.parameters.get(effect, {}).get(p.name, p.off))
            material = material or abs(v - p.off) >= settings.lr_material * p.scale
    if not material:
        return False
    if not nominal_gaps:
        return True
    gaps, _ = _noise_tests(model, problem, m, settings)
    return not ({_gap_key(g) for g in nominal_gaps} & {_gap_key(g) for g in gaps})


def _likelihood_ratio(fitted: FittedModel, reference: FittedModel) -> tuple[float, float]:
    """(statistic, confidence) of the held-out likelihood-ratio test of ``fitted`` against ``reference``.

    Item 4 of issue 22. The noise budget σ is conservative (it bounds the
    noise in every band, plus a model-error floor), so χ² in its units
    undercounts the information of a small, coherent change. Here the
    residual's own level s² = mean r_fit² (held out) replaces it, and the
    residual's autocorrelation is accounted for by the batch-means variance
    of the matched filter T = Σ r_ref δ (δ = r_ref − r_fit, the change the
    fitted parameters predict on held-out samples, :func:`_batch_means`):

    * confidence: one-sided Student's t of z = T / √max(Var_bm(T), s² Σ δ²)
      with (batches − 1) degrees of freedom (under "no effect", r_ref is the
      noise, independent of δ: E T = 0);
    * statistic: the held-out χ² drop Σ r_ref² − Σ r_fit² in units of s²,
      divided by the inflation Var(T) / (s² Σ δ²) ≥ 1 (white: 1) — a
      Δχ² of the likelihood of the fitted parameter against its off value,
      on data the fit never saw, with an effective sample size.
    """
    seg = fitted.test_segment if fitted.test_segment.size == fitted.test_residual.size else None
    block = fitted.test_block if fitted.test_block.size == fitted.test_residual.size else None
    return _lr_arrays(fitted.test_residual, reference.test_residual, seg, block)


def _lr_arrays(
    r_fit: FloatArray, r_ref: FloatArray, seg: NDArray[np.int_] | None, block: NDArray[np.int_] | None
) -> tuple[float, float]:
    """:func:`_likelihood_ratio` on held-out residual arrays (segments and blocks as :func:`_batch_means`)."""
    if r_fit.size < 2 or r_fit.size != r_ref.size:
        return 0.0, 0.0
    delta = r_ref - r_fit
    energy = float(np.dot(delta, delta))
    if energy <= 0.0:
        return 0.0, 0.5
    s2 = max(float(np.mean(r_fit * r_fit)), 1e-12)
    projection = float(np.dot(r_ref, delta))
    seg = seg if seg is not None else np.zeros(r_fit.size, dtype=int)
    block = block if block is not None else seg
    var_bm, batches = _batch_means(r_fit * delta, seg, block)
    white = s2 * energy
    var = max(var_bm, white)
    z = projection / math.sqrt(var)
    inflation = var / white
    statistic = (float(np.dot(r_ref, r_ref)) - float(np.dot(r_fit, r_fit))) / (s2 * inflation)
    confidence = float(stats.t.cdf(z, batches - 1)) if batches >= 2 else float(stats.norm.cdf(z))
    return float(statistic), confidence


def _p_better(fitted: FittedModel, reference: FittedModel) -> float:
    """Confidence that the held-out data contain the change ``fitted`` predicts over ``reference`` (one-sided).

    δ = r_ref − r_fit per held-out sample (normalised residuals) is the change
    the candidate, fitted on the training part, predicts there. The statistic
    is its matched filter on the held-out data, T = Σ r_ref δ = Σ δ² + Σ r_fit δ:
    under "the change is spurious" (r_ref is the noise, independent of δ, which
    came from other samples) E T = 0; when the change is there (r_fit is the
    noise) E T = Σ δ². Var T is estimated by batch means of x = r_fit δ
    (:func:`_batch_means`: batches of at least five times the lag at which x
    decorrelates, inside the held-out blocks, all channels of a batch
    together), never below the white-noise value Σ δ² (unit variance: the
    noise budget); z = T / √Var against Student's t with (batches − 1)
    degrees of freedom. Measured in simulation: false alarms ≤ 2 % at the
    0.99 level for white and AR(1) residuals up to ρ = 0.97 in 4–20 held-out
    blocks of 80 samples, where a Newey–West variance with the normal
    distribution gave up to 5.5 % (the test checks six blocks).

    Not the held-out χ² difference D = Σ r_ref² − Σ r_fit² = 2T − Σ δ² (used
    until session 6): for the same effect its z is half as large (E D = Σ δ²,
    sd 2√Σδ²), and a change the fit overestimates twofold has E D = 0 although
    it is plainly in the data. That the candidate also predicts better is asked
    separately (:func:`_compare`: penalised held-out score, ``min_improvement``).
    Unlike a bootstrap of whole held-out blocks, the test keeps its power when
    the gap lives in one or two blocks (a delay that only shows while
    accelerating): x is the noise times δ whatever δ's size.
    """
    r_fit, r_ref = fitted.test_residual, reference.test_residual
    if r_fit.size == 0 or r_fit.size != r_ref.size:
        return 1.0 if fitted.test_chi2 < reference.test_chi2 else 0.0
    delta = r_ref - r_fit
    energy = float(np.sum(delta * delta))
    if energy <= 0.0:
        return 0.5
    projection = energy + float(np.sum(r_fit * delta))
    seg = fitted.test_segment if fitted.test_segment.size == r_fit.size else np.zeros(r_fit.size, dtype=int)
    block = fitted.test_block if fitted.test_block.size == r_fit.size else seg
    var, batches = _batch_means(r_fit * delta, seg, block)
    var = max(var, energy)
    if batches < 2:
        return float(stats.norm.cdf(projection / math.sqrt(var)))
    return float(stats.t.cdf(projection / math.sqrt(var), batches - 1))


def _cross_fitted(
    model: ReplayModel,
    cand: Candidate,
    fitted: FittedModel,
    nominal: FittedModel,
    settings: AttributionSettings,
) -> tuple[float, float, float, int]:
    """Held-out likelihood ratio of ``cand`` over every fold: (statistic, confidence, χ² drop, samples).

    The default split scores a third of the data. For a small-signal
    effect that is a third of the information: a 60 ms rover delay whose
    full-bag Δχ² is ≈ 40 leaves ≈ 13 on one fold, at the edge of a 0.999
    test. Cross-fitting: each of the ``test_every`` interleaved sets is held
    out in turn, the nominal nuisance and the candidate are fitted on the
    others (one optimiser run from the full fit's values) and scored on it;
    every sample is then scored by a fit that never saw it, and the
    matched-filter statistics of :func:`_likelihood_ratio` are taken over
    all of them (batches inside each fold's held-out blocks).
    """
    r_fit = [fitted.test_residual]
    r_ref = [nominal.test_residual]
    seg = [fitted.test_segment]
    blk = [fitted.test_block]
    offset_seg = int(fitted.test_segment.max()) + 1 if fitted.test_segment.size else 0
    offset_blk = int(fitted.test_block.max()) + 1 if fitted.test_block.size else 0
    start = {cand.name: dict(fitted.parameters.get(cand.name, {}))}
    light = replace(settings, grid_points=0, max_starts=1)
    for fold in range(settings.test_every - 1):
        train, test = held_out_mask(model, settings, fold)
        if sum(int(np.sum(v)) for v in test.values()) < 10:
            continue
        sub = _problem(model, settings, train, test, _block_ids(model, settings, test))
        nom = fit(sub, [], nominal.nuisance, light)
        alt = fit(sub, [cand], nominal.nuisance, light, start_effects=start)
        r_fit.append(alt.test_residual)
        r_ref.append(nom.test_residual)
        seg.append(alt.test_segment + offset_seg)
        blk.append(alt.test_block + offset_blk)
        offset_seg += int(alt.test_segment.max()) + 1 if alt.test_segment.size else 0
        offset_blk += int(alt.test_block.max()) + 1 if alt.test_block.size else 0
    a, b = np.concatenate(r_fit), np.concatenate(r_ref)
    lr, confidence = _lr_arrays(a, b, np.concatenate(seg), np.concatenate(blk))
    return lr, confidence, float(np.dot(b, b) - np.dot(a, a)), int(a.size)


def _indistinguishable(
    best: FittedModel, other: FittedModel, nominal: FittedModel, settings: AttributionSettings
) -> bool:
    """Whether the held-out data cannot tell ``other`` (a significant runner-up) from ``best``.

    Either their penalised held-out scores are within ``ambiguity`` of the
    nominal model's excess χ², or the change ``best`` predicts over ``other``
    is not found in the held-out data at the ``significance`` level (the
    matched-filter test of :func:`_p_better` with ``other`` as the reference):
    a lower score that the noise could have made is no reason to prefer one
    explanation (e.g. an accelerometer bias b and a scale error s ≈ b/g, whose
    predictions differ only by s times the dynamic acceleration).
    """
    if not other.significant:
        return False
    excess = max(nominal.test_chi2 - best.test_chi2, 1e-12)
    if other.score - best.score < settings.ambiguity * excess:
        return True
    return _p_better(best, other) < settings.significance


def _decorrelation_lag(x: FloatArray, segment: NDArray[np.int_], max_lag: int = 500) -> int:
    """The first lag at which the autocorrelation of x (taken inside equal-``segment`` runs) is below 0.05."""
    gamma0 = float(np.dot(x, x))
    lag = 0
    while gamma0 > 0.0 and lag < min(max_lag, x.size - 1):
        lag += 1
        same = segment[lag:] == segment[:-lag]
        if not same.any() or float(np.dot(x[lag:][same], x[:-lag][same])) < 0.05 * gamma0:
            break
    return max(lag, 1)


def _batch_means(
    x: FloatArray, segment: NDArray[np.int_], block: NDArray[np.int_], per_lag: int = 5, shortest: int = 10
) -> tuple[float, int]:
    """(Var(Σ x) by non-overlapping batch means, number of batches).

    ``segment``: the (channel, held-out block) of each sample, consecutive in
    time inside; ``block``: its held-out block. Each block is cut into k
    batches of equal relative length, k from its shortest channel segment and
    the batch length max(per_lag × the decorrelation lag of x, shortest); a
    batch gathers the samples of every channel in that stretch of time
    (channels of one instant share the road, the wheel speeds: their noise
    may be correlated). Held-out blocks are separated by training blocks, so
    batches are treated as independent; Var = Σ over batches of (Σ x)².
    """
    length = max(per_lag * _decorrelation_lag(x, segment), shortest)
    starts = np.flatnonzero(np.r_[True, segment[1:] != segment[:-1]])
    ends = np.r_[starts[1:], x.size]
    sizes = ends - starts
    blocks = block[starts]
    shortest_in = {int(b): int(sizes[blocks == b].min()) for b in np.unique(blocks)}
    ids = np.empty(x.size, dtype=np.int64)
    offset: dict[int, int] = {}
    total = 0
    for b in shortest_in:
        offset[b] = total
        total += max(1, shortest_in[b] // length)
    for s, e, b in zip(starts, ends, blocks, strict=True):
        k = max(1, shortest_in[int(b)] // length)
        n = int(e - s)
        ids[s:e] = offset[int(b)] + (np.arange(n) * k) // n
    sums = np.bincount(ids, weights=x, minlength=total)
    return float(np.dot(sums, sums)), total


def _noise_tests(
    model: ReplayModel,
    problem: _Problem,
    fitted: FittedModel,
    settings: AttributionSettings,
    everything: bool = False,
) -> tuple[list[str], list[ChannelReport]]:
    """The where-tests on the held-out residuals of ``fitted`` (units of the channels).

    ``everything``: on all samples after the warm-up instead (for the nominal
    model, whose only fitted parameters are the few nuisance ones: the
    detection of a gap then uses all the data).
    """
    pred = model.predict(fitted.parameters, fitted.nuisance)
    problem.evaluations += 1
    budget = getattr(model, "noise_std_for", None)
    sigma = budget(fitted.parameters, fitted.nuisance) if callable(budget) else {}
    gaps: list[str] = []
    reports = []
    for ch in model.channels:
        sel = (problem.test[ch.name] | problem.train[ch.name]) if everything else problem.test[ch.name]
        t = np.asarray(model.times[ch.name], dtype=float)[sel]
        meas = np.asarray(model.measured[ch.name], dtype=float)[sel]
        sim = np.asarray(pred[ch.name], dtype=float)[sel]
        if meas.size < 8:
            continue
        dts = np.diff(t)
        uniform = dts.size > 0 and float(np.median(dts)) > 0 and meas.size >= 256
        fs = 1.0 / float(np.median(dts)) if uniform else 1.0
        w = settings.where if uniform else _no_bands(settings.where)
        # Held-out blocks are not contiguous: band tests run over the concatenation (block
        # edges add a little broadband power, well below the thresholds for 2 s blocks).
        noise = float(sigma.get(ch.name, ch.noise_std))
        rep = _channel(ch.name, ch.topic, meas, sim, fs, noise**2, w, len(model.channels), ch.unit)
        reports.append(rep)
        gaps += rep.gaps
    return gaps, reports


def _no_bands(where: WhereSettings) -> WhereSettings:
    from dataclasses import replace

    return replace(where, bands=(0.0,))


# ---------------------------------------------------------------------------
# Structure gaps, identifiability, tolerances (issue 22, items 2–4)
# ---------------------------------------------------------------------------

#: Words of an effect's name that make it a *sensor* effect (the measurement is wrong, not the vehicle):
#: two effects of different physics (one sensor, one vehicle) that explain a bag equally mean that the
#: model's structure differs (unless either brings the residual to the noise: then the bag cannot tell).
SENSOR_WORDS = ("bias", "scale", "delay", "crosstalk", "gain", "latency")

#: What would make an effect identifiable when a bag does not show it (by words of its name).
IDENTIFIABILITY_HINTS: tuple[tuple[str, str], ...] = (
    ("delay", "inputs that change faster than the delay (torque or speed steps, hard accelerations)"),
    ("bias", "a stretch at rest or on level ground (a calibration of the sensor)"),
    ("scale", "larger excitation of the channel (harder manoeuvres, rougher ground)"),
    ("crosstalk", "a load step on the other axis of the cell"),
    ("grade", "a run over the same ground in the opposite direction, or an attitude reference"),
    ("friction", "manoeuvres near the grip limit (hard turns, braking)"),
    ("stiffness", "manoeuvres with larger slip (turns at higher lateral acceleration)"),
    ("mass", "a vertical excitation with a known input (a bump of known height)"),
    ("soil_change", "a longer run that crosses the change (the path covered ends before it), or runs at other loads"),
    ("soil", "runs at other loads or slips on the same ground"),
)


def _physics_group(model: ReplayModel, effect: str) -> str:
    """ "sensor" or "vehicle" (or the model's own ``physics`` mapping, when it has one)."""
    own = getattr(model, "physics", None)
    if isinstance(own, Mapping) and effect in own:
        return str(own[effect])
    return "sensor" if any(w in effect for w in SENSOR_WORDS) else "vehicle"


def _structure_reasons(
    model: ReplayModel, best: FittedModel, others: Sequence[FittedModel], settings: AttributionSettings
) -> list[str]:
    """Why the best (significant) explanation is a structure gap rather than the effect; [] if it is not.

    * a parameter at a bound of its fit range (other than its off value),
      or outside its plausible range (:attr:`FitParameter.plausible`);
    * a nominal parameter with a tolerance (a prior) fitted beyond 3× it;
    * its held-out residual still fails the noise tests and its shrinkage
      interval starts below ``explained_shrinkage`` (a remainder the effect
      cannot shape);
    * a runner-up of other physics (sensor vs vehicle) explains as well, and
      neither brings the residual to the noise.
    """
    reasons: list[str] = []
    for effect in best.effects:
        cand = model.candidates.get(effect)
        if cand is None:
            continue
        for p in cand.parameters:
            v = float(best.parameters.get(effect, {}).get(p.name, p.off))
            lo, hi = p.bounds
            tol = settings.bound_tolerance * (hi - lo)
            if v <= lo + tol and lo != p.off:
                reasons.append(f"{effect}.{p.name} = {v:.4g} {p.unit} is at the lower bound {lo:g} of its fit range")
            elif v >= hi - tol and hi != p.off:
                reasons.append(f"{effect}.{p.name} = {v:.4g} {p.unit} is at the upper bound {hi:g} of its fit range")
            elif p.plausible is not None and not (p.plausible[0] <= v <= p.plausible[1]):
                reasons.append(
                    f"{effect}.{p.name} = {v:.4g} {p.unit} is outside its physically plausible range "
                    f"[{p.plausible[0]:g}, {p.plausible[1]:g}]"
                )
    for p in model.nuisance:
        if p.prior_std is None or p.name not in best.nuisance:
            continue
        v = float(best.nuisance[p.name])
        if abs(v - p.off) >= 3.0 * p.prior_std * (1.0 - settings.bound_tolerance):
            reasons.append(
                f"the nominal {p.name} needs {v:.4g} {p.unit}, beyond 3× its tolerance "
                f"({p.off:.4g} ± {p.prior_std:.3g})"
            )
    if best.residual_gaps and best.shrinkage_ci[0] < settings.explained_shrinkage:
        more = f" and {len(best.residual_gaps) - 1} more" if len(best.residual_gaps) > 1 else ""
        reasons.append(f"its held-out residual still fails the noise tests ({best.residual_gaps[0]}{more})")
    if not best.at_noise:
        mine = {_physics_group(model, e) for e in best.effects}
        for m in others:
            theirs = {_physics_group(model, e) for e in m.effects}
            if not m.at_noise and theirs.isdisjoint(mine):
                reasons.append(
                    f"{m.name} ({'/'.join(sorted(theirs))}) explains it as well as {best.name} "
                    f"({'/'.join(sorted(mine))}): effects of different physics"
                )
    return reasons


def _stability(model: ReplayModel, problem: _Problem, best: FittedModel, settings: AttributionSettings) -> list[str]:
    """Whether the best single effect's parameters depend on the operating regime (a structure gap).

    A catalogue effect is one number for the whole bag; a different law (a
    magic-formula tire instead of the brush tire, a drifting bias) fitted as
    that effect gives a parameter that moves with the operating point. For
    each of the first ``stability_regimes`` regimes of the replay model, the
    training samples are split at the regime variable's median and the effect
    (with the nuisance) is fitted on each half, from the full fit's values;
    a parameter whose halves differ by more than the normal quantile at
    ``lr_significance`` (Bonferroni over regimes and parameters) of their
    combined autocorrelation-honest standard error, and by more than
    ``stability_material`` of the effect's size, is a reason.
    """
    if len(best.effects) != 1 or settings.stability_regimes <= 0:
        return []
    cand = model.candidates.get(best.effects[0])
    if cand is None or not cand.parameters:
        return []
    regimes = list(model.regimes.items())[: settings.stability_regimes]
    tests = max(1, len(regimes) * len(cand.parameters))
    threshold = float(stats.norm.ppf(1.0 - (1.0 - settings.lr_significance) / (2.0 * tests)))
    light = replace(settings, grid_points=0, max_starts=1)
    start = {cand.name: dict(best.parameters[cand.name])}
    reasons: list[str] = []
    for regime, (t_var, values) in regimes:
        t_var, values = np.asarray(t_var, dtype=float), np.asarray(values, dtype=float)
        if t_var.size < 2 or not np.all(np.isfinite(values)):
            continue
        at = {c.name: np.interp(np.asarray(model.times[c.name], dtype=float), t_var, values) for c in model.channels}
        pooled = np.concatenate([at[c.name][problem.train[c.name]] for c in model.channels])
        if pooled.size < 20:
            continue
        median = float(np.median(pooled))
        halves = []
        for low in (True, False):
            train = {
                c.name: problem.train[c.name] & ((at[c.name] <= median) if low else (at[c.name] > median))
                for c in model.channels
            }
            if min(int(np.sum(v)) for v in train.values()) < 10:
                break
            sub = replace(problem, train=train, evaluations=0, _segments=None, _train_layout=None)
            halves.append(fit(sub, [cand], best.nuisance, light, start_effects=start))
            problem.evaluations += sub.evaluations
        if len(halves) != 2:
            continue
        lo_fit, hi_fit = halves
        for p in cand.parameters:
            a = lo_fit.parameters[cand.name][p.name]
            b = hi_fit.parameters[cand.name][p.name]
            sd = math.hypot(lo_fit.std[cand.name][p.name], hi_fit.std[cand.name][p.name])
            size = abs(best.parameters[cand.name][p.name] - p.off)
            if not (sd > 0.0 and math.isfinite(sd)):
                continue
            if abs(a - b) > threshold * sd and abs(a - b) > settings.stability_material * max(size, 1e-12):
                reasons.append(
                    f"the fitted {cand.name}.{p.name} depends on {regime}: {a:.4g} below its median "
                    f"{median:.3g}, {b:.4g} above ({abs(a - b) / sd:.1f} σ apart; one law would give one value)"
                )
    return reasons


def _structure_summary(
    model: ReplayModel, best: FittedModel, nominal: FittedModel, reasons: list[str]
) -> dict[str, Any]:
    """Where, how big, the nearest catalogue description and why it is implausible (JSON)."""
    gaps = {k: v for k, v in nominal.gap.items() if k != "overall"}
    top = sorted(gaps, key=lambda k: -gaps[k])
    where = [k for k in top if gaps[k] > 0.0][:3] or top[:1]
    description = "; ".join(model.candidates[e].description or e for e in best.effects if e in model.candidates)
    return {
        "where": where,
        "channel_gaps": {k: gaps[k] for k in where},
        "gap": nominal.gap.get("overall", 0.0),
        "residual_gaps": list(nominal.residual_gaps[:5]),
        "nearest": best.name,
        "description": description,
        "parameters": best.parameters,
        "shrinkage": best.shrinkage.get("overall", 0.0),
        "reasons": reasons,
    }


def _structure_verdict(structure: Mapping[str, Any]) -> str:
    where = ", ".join(f"{k} (gap {structure['channel_gaps'][k]:.3g})" for k in structure["where"])
    params = "; ".join(
        f"{e}: " + ", ".join(f"{k} = {v:.4g}" for k, v in ps.items()) for e, ps in structure["parameters"].items() if ps
    )
    return (
        f"the model's structure differs here: on {where}, held-out gap {structure['gap']:.3g} "
        f"(mean r² − 1); nearest catalogue description {structure['nearest']}"
        + (f" ({params})" if params else "")
        + f", which would shrink it by {100 * structure['shrinkage']:.0f} %, but "
        + "; ".join(structure["reasons"])
    )


def _not_identifiable(
    model: ReplayModel,
    problem: _Problem,
    nominal: FittedModel,
    ranking: Sequence[FittedModel],
    settings: AttributionSettings,
) -> list[dict[str, str]]:
    """Effects this bag cannot show, with the measurement that would make them identifiable.

    Those the replay model declares (optional attribute ``unidentifiable``:
    effect → what would identify it), and those whose predicted change at the
    catalogue's typical magnitude (every parameter at off + scale, within
    bounds) against the fitted nominal model is below
    ``identifiable_chi2`` on the held-out part (in units of the noise
    budget): the held-out tests could not detect such an effect here.
    Effects found significant are left out (the bag shows them).
    """
    out: list[dict[str, str]] = []
    declared = getattr(model, "unidentifiable", None) or {}
    for effect, needs in dict(declared).items():
        out.append({"effect": str(effect), "why": "the replay model cannot tell it apart", "needs": str(needs)})
    significant = {e for m in ranking if m.significant for e in m.effects}
    base = problem.residuals(nominal.parameters, nominal.nuisance)
    r0 = problem.stacked(base, problem.test)
    for name, cand in model.candidates.items():
        if name in significant or name in declared:
            continue
        values: dict[str, float] = {}
        for p in cand.parameters:
            v = p.off + p.scale
            values[p.name] = v if v <= p.bounds[1] else max(p.off - p.scale, p.bounds[0])
        try:
            res = problem.residuals({name: values}, nominal.nuisance)
        except (ValueError, ArithmeticError):
            continue
        chi = float(np.sum((problem.stacked(res, problem.test) - r0) ** 2))
        if chi < settings.identifiable_chi2:
            hint = next((h for w, h in IDENTIFIABILITY_HINTS if w in name), "a bag that excites it more")
            size = ", ".join(f"{k} = {v:.3g}" for k, v in values.items()) or "on"
            out.append(
                {
                    "effect": name,
                    "why": f"at a typical magnitude ({size}) it changes the held-out χ² by {chi:.2g} "
                    f"(< {settings.identifiable_chi2:g})",
                    "needs": hint,
                }
            )
    return out


def _tolerance_rows(model: ReplayModel, nominal: FittedModel) -> list[dict[str, Any]]:
    """The nominal parameters fitted within their stated tolerances (a prior): nominal, tolerance, fitted."""
    rows = []
    for p in model.nuisance:
        if p.prior_std is None:
            continue
        v = float(nominal.nuisance.get(p.name, p.off))
        rows.append(
            {
                "parameter": p.name,
                "unit": p.unit,
                "nominal": p.off,
                "tolerance": p.prior_std,
                "fitted": v,
                "std": float(nominal.nuisance_std.get(p.name, float("nan"))),
                "within": bool(abs(v - p.off) <= p.prior_std),
            }
        )
    return rows


# ---------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------


def attribute(
    model: ReplayModel,
    settings: AttributionSettings | None = None,
    test_mask: Mapping[str, BoolArray] | None = None,
    progress: Progress = None,
    start_nuisance: Mapping[str, float] | None = None,
) -> AttributionReport:
    """Rank the catalogue's effects as explanations of the gap between ``model``'s bag and its nominal model.

    Args:
        model: The bag's replay model.
        settings: Knobs (default :class:`AttributionSettings`).
        test_mask: Held-out samples per channel (True = held out); default:
            interleaved blocks (:func:`held_out_mask`). Samples before the
            model's warm-up are never used.
        progress: Called with one line per step (e.g. ``print`` to stderr).
        start_nuisance: Starting values of the nuisance parameters (default: their ``off``).
    """
    settings = settings or AttributionSettings()
    t_start = time.perf_counter()

    def say(text: str) -> None:
        if progress is not None:
            progress(text)

    for ch in model.channels:
        if not (ch.noise_std > 0 and math.isfinite(ch.noise_std)):
            raise ValueError(f"channel {ch.name!r} ({ch.topic}): noise budget must be positive, got {ch.noise_std}")
    train, test = held_out_mask(model, settings)
    if test_mask is not None:
        t0 = min(float(model.times[c.name][0]) for c in model.channels)
        for ch in model.channels:
            use = usable_mask(model, ch.name, t0)
            held = np.asarray(test_mask[ch.name], dtype=bool)
            test[ch.name] = use & held
            train[ch.name] = use & ~held
        blocks_of = {c.name: np.flatnonzero(test[c.name]) for c in model.channels}
        # A caller-given split: every held-out sample is its own bootstrap unit.
        test_blocks = {c.name: blocks_of[c.name] for c in model.channels}
    else:
        test_blocks = _block_ids(model, settings, test)
    n_train = int(sum(int(np.sum(v)) for v in train.values()))
    n_test = int(sum(int(np.sum(v)) for v in test.values()))
    if n_train < 10 or n_test < 10:
        raise ValueError(f"too little data to fit and score: {n_train} training and {n_test} held-out samples")
    problem = _problem(model, settings, train, test, test_blocks)
    rng = np.random.default_rng(settings.seed)
    start = dict(start_nuisance or {})

    say(
        f"fitting the nominal model ({len(model.nuisance)} nuisance parameters; "
        f"{n_train} training, {n_test} held-out samples)"
    )
    nominal = fit(problem, [], start, settings)
    nominal.shrinkage = {k: 0.0 for k in nominal.gap}
    nominal_gaps, channel_reports = _noise_tests(model, problem, nominal, settings, everything=True)
    nominal.residual_gaps = nominal_gaps
    nominal.at_noise = not nominal_gaps
    say(
        f"nominal: held-out gap {nominal.gap['overall']:.3g} (mean r² − 1); "
        + ("no significant gap" if not nominal_gaps else f"{len(nominal_gaps)} test(s) flag a gap")
    )

    ranking: list[FittedModel] = []
    names = list(model.candidates)
    for i, name in enumerate(names):
        cand = model.candidates[name]
        f = fit(problem, [cand], nominal.nuisance, settings)
        _compare(f, nominal, settings, rng)
        ranking.append(f)
        say(
            f"[{i + 1}/{len(names)}] {name}: held-out shrinkage {100 * f.shrinkage['overall']:.1f} % "
            f"({f.evaluations} evaluations, {f.seconds:.1f} s)"
        )
    ranking.sort(key=lambda m: m.score)
    if test_mask is None and settings.cross_fit > 0:
        # Small-signal effects: the most promising candidates the one-fold test leaves undecided get the
        # likelihood-ratio test over every fold (cross-fitting, :func:`_cross_fitted`).
        promising = [
            m
            for m in ranking
            if not m.significant and m.added > 0 and m.p_lr >= 0.9 and m.test_chi2 < nominal.test_chi2
        ][: settings.cross_fit]
        for m in promising:
            lr, conf, drop, n_all = _cross_fitted(model, model.candidates[m.effects[0]], m, nominal, settings)
            m.lr, m.p_lr, m.cross_fitted = lr, conf, True
            m.significant = bool(
                conf >= settings.lr_significance
                and lr >= float(stats.chi2.ppf(settings.lr_significance, m.added))
                and drop > m.added * math.log(max(n_all, 2))
            )
            m.by_likelihood = m.significant
            say(
                f"{m.name}: cross-fitted held-out likelihood ratio {lr:.1f} (confidence {conf:.5f}) over "
                f"{n_all} samples: {'significant' if m.significant else 'not significant'}"
            )

    pairs: list[FittedModel] = []
    for m in ranking:
        if m.significant and m.by_likelihood and not _small_signal_ok(model, problem, m, nominal_gaps, settings):
            m.significant = False
            say(f"{m.name}: significant by the likelihood ratio alone but leaves the gaps the noise tests flag")
    # The best-scoring significant candidate (a small-signal effect found by the likelihood ratio may score
    # below a runner-up whose larger but insignificant held-out change is not in the data).
    best: FittedModel | None = next((m for m in ranking if m.significant), ranking[0] if ranking else None)
    notes: list[str] = []
    kind = "no_gap"
    explained: tuple[str, ...] = ()
    indistinguishable: list[str] = []
    structure: dict[str, Any] | None = None
    gap_found = bool(nominal_gaps) or any(m.significant for m in ranking)
    if gap_found and best is not None:
        best.residual_gaps, _ = _noise_tests(model, problem, best, settings)
        best.at_noise = not best.residual_gaps

        def explains(m: FittedModel) -> bool:
            return m.significant and (m.at_noise or m.shrinkage_ci[0] >= settings.explained_shrinkage)

        if not best.at_noise:
            # Forward selection: the best single plus each partner. Partners: the runners-up
            # that improved the held-out score (penalised, by at least min_improvement of the
            # χ²; significance alone is too strict a screen: next to the best effect's unmodelled
            # signal a second, smaller effect's improvement is not significant on its own), and
            # those that shrink some channel's gap clearly while worsening another
            # (complementary effects: one fixes one channel, the other the rest). The pair
            # itself must then beat the single significantly.
            def improves(m: FittedModel) -> bool:
                rel = (nominal.test_chi2 - m.test_chi2) / max(nominal.test_chi2, 1e-12)
                return m.significant or (m.score < nominal.score and rel >= settings.min_improvement)

            partners = [
                m
                for m in ranking
                if m is not best
                if improves(m)
                or max((v for k, v in m.shrinkage.items() if k != "overall"), default=0.0) > settings.channel_partner
            ][: settings.pair_candidates]
            first = model.candidates[best.effects[0]]
            for m in partners:
                second = model.candidates[m.effects[0]]
                start_fx = {first.name: best.parameters[first.name], second.name: m.parameters[second.name]}
                p = fit(problem, [first, second], best.nuisance, settings, start_effects=start_fx)
                _compare(p, nominal, settings, rng)
                # The pair must also beat the single significantly.
                p_vs_single = FittedModel((), {}, {}, {}, 0, 0.0, p.test_chi2, p.score, {})
                p_vs_single.block_chi2, p_vs_single.block_n = p.block_chi2, p.block_n
                p_vs_single.test_residual, p_vs_single.test_segment = p.test_residual, p.test_segment
                p_vs_single.test_block = p.test_block
                _compare(p_vs_single, best, settings, rng)
                # A pair must beat the single by the relative rule (the likelihood-ratio path is for singles).
                p.significant = p.significant and p_vs_single.significant and not p_vs_single.by_likelihood
                pairs.append(p)
                say(f"pair {p.name}: held-out shrinkage {100 * p.shrinkage['overall']:.1f} %")
            pairs.sort(key=lambda m: m.score)
            if pairs and pairs[0].significant:
                # Significantly better than the single on held-out data: the pair is the explanation.
                pairs[0].residual_gaps, _ = _noise_tests(model, problem, pairs[0], settings)
                pairs[0].at_noise = not pairs[0].residual_gaps
                best = pairs[0]
        if explains(best):
            kind = "explained"
            explained = best.effects
        else:
            kind = "not_explained"
        indistinguishable = [
            m.name for m in ranking if m is not best and _indistinguishable(best, m, nominal, settings)
        ]
        if best.significant:
            others = [m for m in ranking if m.name in indistinguishable]
            reasons = _structure_reasons(model, best, others, settings)
            if not reasons:
                reasons = _stability(model, problem, best, settings)
            if reasons:
                kind = "structure_differs"
                explained = ()
                structure = _structure_summary(model, best, nominal, reasons)
    not_identifiable = _not_identifiable(model, problem, nominal, ranking, settings)
    if kind == "no_gap":
        verdict = "no significant gap"
        if not_identifiable:
            verdict += "; not identifiable from this bag: " + ", ".join(x["effect"] for x in not_identifiable)
    elif kind == "structure_differs":
        assert structure is not None
        verdict = _structure_verdict(structure)
    elif kind == "explained":
        assert best is not None
        if nominal.gap["overall"] > 0:
            verdict = f"explained by {best.name} (shrinks the gap by {100 * best.shrinkage['overall']:.0f} %)"
        else:  # the held-out residual is already inside the noise budget on average
            drop = 100.0 * (1.0 - best.test_chi2 / max(nominal.test_chi2, 1e-12))
            verdict = (
                f"explained by {best.name} (the nominal model's held-out residual is within the noise "
                f"budget on average; {best.name} lowers its χ² by {drop:.2g} %, held-out likelihood ratio "
                f"{best.lr:.0f})"
            )
        if indistinguishable:
            verdict += f"; indistinguishable on this bag from {', '.join(indistinguishable)}"
    else:
        assert best is not None
        left = 100.0 * (1.0 - best.shrinkage["overall"])
        verdict = f"not explained by the catalogue (best candidate {best.name} leaves {left:.0f} % unexplained"
        if not best.significant:  # the noise tests see a gap; no candidate's held-out change is shown to close it
            rel = 100.0 * (1.0 - best.test_chi2 / max(nominal.test_chi2, 1e-12))
            why = (
                f"confidence {best.p_better:.3f} < {settings.significance:g}"
                if best.p_better < settings.significance
                else f"held-out χ² lowered by {rel:.1f} %, penalised score {best.score:.1f} vs {nominal.score:.1f}"
            )
            verdict += f"; its held-out improvement is not significant: {why}"
        else:  # significant, but what is left is not the noise and the shrinkage is not clearly near-complete
            low, high = (100.0 * x for x in best.shrinkage_ci)
            if best.residual_gaps:
                more = " …" if len(best.residual_gaps) > 1 else ""
                verdict += f"; its held-out residual still fails the noise tests ({best.residual_gaps[0]}{more})"
            verdict += (
                f"; its shrinkage interval {low:.0f}–{high:.0f} % starts below "
                f"{100.0 * settings.explained_shrinkage:.0f} %"
            )
        verdict += ")"
    series: dict[str, dict[str, FloatArray]] = {"nominal": model.predict(nominal.parameters, nominal.nuisance)}
    if best is not None:
        series[best.name] = model.predict(best.parameters, best.nuisance)
    return AttributionReport(
        vehicle=model.vehicle,
        verdict=verdict,
        kind=kind,
        explained_by=explained,
        nominal=nominal,
        ranking=ranking,
        pairs=pairs,
        best=best if kind != "no_gap" else (ranking[0] if ranking else None),
        indistinguishable=indistinguishable,
        nominal_gaps=nominal_gaps,
        channels=channel_reports,
        settings=settings,
        train_samples=n_train,
        test_samples=n_test,
        seconds=time.perf_counter() - t_start,
        notes=notes + list(model.notes),
        structure=structure,
        not_identifiable=not_identifiable,
        tolerances=_tolerance_rows(model, nominal),
        series=series,
        test_masks=dict(test),
    )
