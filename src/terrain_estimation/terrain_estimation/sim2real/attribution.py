"""Which unmodelled effect explains the sim-to-real gap, and how far the gap shrinks.

Generic over vehicles: works on any :class:`~terrain_estimation.sim2real.model.ReplayModel`.

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
       starts at ± the parameter's typical size). Parameter uncertainties are
       the Gauss–Newton covariance s²(JᵀJ)⁻¹ inflated by (1 + ρ)/(1 − ρ) for
       the lag-1 autocorrelation ρ of the residuals (an effective sample
       count).
    4. **Score on held-out data.** χ² = Σ r² over the held-out samples
       (r = residual / σ), penalised like the BIC: J = χ² + p ln n with p the
       parameters the effect adds and n the held-out samples. The ranking is by J.
    5. **Gap and shrinkage.** The gap of a model on the held-out part is the
       mean normalised residual power above the noise, G = max(mean r² − 1, 0)
       (0: the residual is the noise budget). Shrinkage = 1 − G_effect / G_nominal,
       per channel and overall, with a percentile confidence interval from a
       bootstrap over held-out blocks (residual correlation stays inside blocks).
    6. **Pairs.** When the best single effect does not bring the held-out
       residual to the noise, it is combined with each of the next candidates
       that improved the held-out score significantly or shrank one channel's
       gap clearly (forward selection); the best pair replaces the single if
       it improves significantly on it.
    7. **Verdict.**
       * "no significant gap": the nominal model's residuals (all samples
         after the warm-up: only the nuisance is fitted) pass the noise tests
         of :mod:`~terrain_estimation.sim2real.where` (bias, power, octave
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
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, stats

from terrain_estimation.sim2real.model import Candidate, FitParameter, ReplayModel, usable_mask
from terrain_estimation.sim2real.where import ChannelReport, WhereSettings, _channel, _jsonable

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
    where: WhereSettings = field(default_factory=WhereSettings)
    seed: int = 0


@dataclass
class FittedModel:
    """The nominal model or the nominal model plus one or two effects, fitted and scored.

    Attributes:
        effects: Effect names (empty: the nominal model).
        parameters: Fitted effect parameters {effect: {parameter: value}}.
        std: Their standard errors (same layout).
        nuisance: Fitted nuisance parameters.
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
    kind: str  # "no_gap", "explained", "not_explained"
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
            }
        )


# ---------------------------------------------------------------------------
# Split
# ---------------------------------------------------------------------------


def held_out_mask(
    model: ReplayModel, settings: AttributionSettings
) -> tuple[dict[str, BoolArray], dict[str, BoolArray]]:
    """(train, test) masks per channel: interleaved blocks after the warm-up, inside the model's
    domain (:func:`~terrain_estimation.sim2real.model.usable_mask`)."""
    t0 = min(float(model.times[c.name][0]) for c in model.channels)
    train: dict[str, BoolArray] = {}
    test: dict[str, BoolArray] = {}
    for ch in model.channels:
        t = np.asarray(model.times[ch.name], dtype=float)
        use = usable_mask(model, ch.name, t0)
        block = np.floor((t - t0 - model.warmup) / settings.block).astype(int)
        is_test = (block % settings.test_every) == settings.test_every - 1
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
    _segments: NDArray[np.int_] | None = None

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


def _lag1(r: FloatArray) -> float:
    if r.size < 3:
        return 0.0
    c = r - r.mean()
    den = float(np.dot(c, c))
    return float(np.clip(np.dot(c[1:], c[:-1]) / den, -0.95, 0.95)) if den > 0 else 0.0


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

    def fun(x: FloatArray) -> FloatArray:
        effects, nuisance = _unpack(layout, x, candidates)
        return problem.stacked(problem.residuals(effects, nuisance), problem.train)

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
    # Standard errors (Gauss–Newton, inflated for residual autocorrelation).
    std: dict[str, dict[str, float]] = {c.name: {} for c in candidates}
    if len(layout):
        dof = max(1, r_train.size - len(layout))
        s2 = float(np.dot(r_train, r_train)) / dof
        rho = _lag1(r_train)
        try:
            cov = np.linalg.pinv(jac.T @ jac) * s2 * (1.0 + rho) / (1.0 - rho)
            sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        except (np.linalg.LinAlgError, UnboundLocalError):
            sd = np.full(len(layout), np.nan)
        for (owner, p), v in zip(layout, sd, strict=True):
            if owner is not None:
                std[owner][p.name] = float(v)
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
        idx = rng.integers(0, nb, size=(settings.bootstrap, nb))
        n = fitted.block_n[idx].sum(axis=1)
        g_e = np.maximum(fitted.block_chi2[idx].sum(axis=1) / n - 1.0, 0.0)
        g_0 = np.maximum(reference.block_chi2[idx].sum(axis=1) / n - 1.0, 0.0)
        shrink = np.where(g_0 > 0, 1.0 - g_e / np.where(g_0 > 0, g_0, 1.0), 0.0)
        a = (1.0 - settings.confidence) / 2.0
        fitted.shrinkage_ci = (float(np.quantile(shrink, a)), float(np.quantile(shrink, 1.0 - a)))
    fitted.p_better = _p_better(fitted, reference)
    rel = (reference.test_chi2 - fitted.test_chi2) / max(reference.test_chi2, 1e-12)
    fitted.significant = bool(
        fitted.p_better >= settings.significance and rel >= settings.min_improvement and fitted.score < reference.score
    )


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
    all_blocks = np.unique(np.concatenate([np.asarray(v, dtype=int) for v in test_blocks.values()]))
    problem = _Problem(
        model=model,
        sigma={c.name: float(c.noise_std) for c in model.channels},
        train=train,
        test=test,
        test_blocks=test_blocks,
        blocks=all_blocks.astype(float),
    )
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

    pairs: list[FittedModel] = []
    best: FittedModel | None = ranking[0] if ranking else None
    notes: list[str] = []
    kind = "no_gap"
    explained: tuple[str, ...] = ()
    indistinguishable: list[str] = []
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
                for m in ranking[1:]
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
                p.significant = p.significant and p_vs_single.significant
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
    if kind == "no_gap":
        verdict = "no significant gap"
    elif kind == "explained":
        assert best is not None
        if nominal.gap["overall"] > 0:
            verdict = f"explained by {best.name} (shrinks the gap by {100 * best.shrinkage['overall']:.0f} %)"
        else:  # the held-out residual is already inside the noise budget on average
            drop = 100.0 * (1.0 - best.test_chi2 / max(nominal.test_chi2, 1e-12))
            verdict = (
                f"explained by {best.name} (the nominal model's held-out residual is within the noise "
                f"budget on average; {best.name} lowers its χ² by {drop:.0f} %)"
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
        series=series,
        test_masks=dict(test),
    )
