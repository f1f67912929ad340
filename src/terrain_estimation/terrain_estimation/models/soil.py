"""Soil stiffness from the series stiffness k_tot, terrain classes and change detection.

Three pieces the soil-stiffness estimator composes (MODELS.md A.2, A.9):

* conversion ``k_tot → k_s`` and its first-order variance (P-3 inverted);
* a classifier that names the nearest known soil and says how sure it is;
* a two-sided CUSUM change detector on a standardised scalar sequence.

numpy only; the soil table is data defined here (it does not import the
vehicle simulator).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "SoilClass",
    "SOIL_TABLE",
    "k_tot_from_k_s",
    "clamp_k_tot",
    "k_s_from_k_tot",
    "amplification_factor",
    "soil_stiffness_from_k_tot",
    "SoilClassification",
    "classify_soil",
    "CusumDetector",
]


@dataclass(frozen=True)
class SoilClass:
    """A known terrain and its equivalent soil stiffness.

    Attributes:
        name: identifier (snake_case, used as ``terrain_class`` on the wire).
        k_s: equivalent soil stiffness (N/m).
        label: human-readable name as printed in the source.
    """

    name: str
    k_s: float
    label: str = ""


#: Table 1 of [QC] (cross-country vehicle, W = 4905 N, D = 0.777 m, b = 0.265 m)
#: and the lunar regolith of section 5.3 (LRV wheel D = 1.016 m, b = 0.254 m,
#: Earth load W = 735 N). k_s depends on the wheel and the load, so the
#: regolith value is only comparable for an LRV-like wheel.
SOIL_TABLE: tuple[SoilClass, ...] = (
    SoilClass("upland_sandy_loam", 218.1e3, "Upland sandy loam"),
    SoilClass("lete_sand", 2283.0e3, "LETE sand"),
    SoilClass("rubicon_sandy_loam", 272.1e3, "Rubicon sandy loam"),
    SoilClass("north_gower_clayey_loam", 221.9e3, "North Gower clayey loam"),
    SoilClass("graneville_loam", 651.1e3, "Graneville loam"),
    SoilClass("lunar_regolith", 28.487e3, "Lunar regolith"),
)


def k_tot_from_k_s(k_s: float | np.ndarray, k_series: float) -> float | np.ndarray:
    """Series stiffness ``k_tot = k_s k_series / (k_s + k_series)`` (P-3), N/m."""
    k_s = np.asarray(k_s, dtype=float)
    out = k_s * k_series / (k_s + k_series)
    return float(out) if out.ndim == 0 else out


def clamp_k_tot(
    k_tot: float | np.ndarray,
    k_series: float,
    clamp_frac: float = 1e-3,
) -> float | np.ndarray:
    """Clip k_tot into ``[clamp_frac, 1 − clamp_frac] · k_series`` (A.2).

    The inverse of P-3 exists only for ``0 < k_tot < k_series`` and explodes at
    the upper end; the default range maps to ``k_s ∈ [0.001, 999] · k_series``,
    the same range the estimation models clamp their dynamics to. Non-finite
    values map to the lower bound.
    """
    if not (0.0 < clamp_frac < 0.5):
        raise ValueError("clamp_frac must be in (0, 0.5)")
    lo, hi = clamp_frac * k_series, (1.0 - clamp_frac) * k_series
    arr = np.asarray(k_tot, dtype=float)
    arr = np.where(np.isfinite(arr), arr, lo)
    out = np.clip(arr, lo, hi)
    return float(out) if out.ndim == 0 else out


def k_s_from_k_tot(
    k_tot: float | np.ndarray,
    k_series: float,
    clamp_frac: float = 1e-3,
) -> float | np.ndarray:
    """Soil stiffness ``k_s = k_tot k_series / (k_series − k_tot)`` (A.2), N/m.

    k_tot is clamped first (:func:`clamp_k_tot`), so the result is finite and
    positive for every input.
    """
    k = np.asarray(clamp_k_tot(k_tot, k_series, clamp_frac))
    out = k * k_series / (k_series - k)
    return float(out) if out.ndim == 0 else out


def amplification_factor(
    k_tot: float | np.ndarray,
    k_series: float,
    clamp_frac: float = 1e-3,
) -> float | np.ndarray:
    """Relative-error amplification ``k_series / (k_series − k_tot)`` (Table 1).

    ``dk_s/k_s = amplification · dk_tot/k_tot``: 4.72 for Graneville loam,
    14.05 for LETE sand (k_t = 175 kN/m).
    """
    k = np.asarray(clamp_k_tot(k_tot, k_series, clamp_frac))
    out = k_series / (k_series - k)
    return float(out) if out.ndim == 0 else out


def soil_stiffness_from_k_tot(
    k_tot: float, k_tot_variance: float, k_series: float, clamp_frac: float = 1e-3
) -> tuple[float, float]:
    """k_s and its variance from a k_tot estimate (A.2, first-order propagation).

    ``var(k_s) ≈ (dk_s/dk_tot)² var(k_tot) = (k_series/(k_series − k_tot))⁴ var(k_tot)``,
    evaluated at the clamped k_tot. A non-finite or negative k_tot variance
    means "unknown" and is replaced by ``k_series²`` (a k_tot spread over its
    whole range) so that the result stays finite.

    Args:
        k_tot: series stiffness estimate (N/m).
        k_tot_variance: its variance ((N/m)²).
        k_series: stiffness in series with the soil (tire ``k_t``, or the
            LRV's combined ``k``), N/m.
        clamp_frac: see :func:`clamp_k_tot`.

    Returns:
        ``(k_s, var_k_s)`` in N/m and (N/m)², both finite.
    """
    k = float(clamp_k_tot(k_tot, k_series, clamp_frac))
    var = float(k_tot_variance)
    if not np.isfinite(var) or var < 0.0:
        var = k_series**2
    k_s = k * k_series / (k_series - k)
    amp = k_series / (k_series - k)
    return k_s, amp**4 * var


@dataclass(frozen=True)
class SoilClassification:
    """Result of :func:`classify_soil`.

    Attributes:
        name: nearest known soil (in log k_s).
        confidence: posterior probability of that soil, 0..1.
        probabilities: posterior of every table entry, in table order; with
            ``unknown_weight > 0`` they sum to ``1 − P(unknown)``.
        unknown_probability: posterior of the "none of these" component.
    """

    name: str
    confidence: float
    probabilities: tuple[float, ...]
    unknown_probability: float


def classify_soil(
    k_s: float,
    k_s_variance: float,
    table: tuple[SoilClass, ...] = SOIL_TABLE,
    class_log_std: float = 0.1,
    unknown_weight: float = 0.05,
    log_ks_range: tuple[float, float] = (1e3, 1e8),
) -> SoilClassification:
    """Nearest known soil and a confidence from a k_s estimate.

    Model: in ``ℓ = ln k_s`` each class c is Gaussian,
    ``ℓ̂ | c ~ N(ln k_c, σ_ℓ² + σ_c²)``, with ``σ_ℓ² = var(k_s)/k_s²`` the
    estimate's own (first-order) log variance and ``σ_c = class_log_std`` the
    spread of a soil type (0.1 ≈ ±10 %; it keeps the confidence honest when the
    filter is over-confident). A background "unknown" component, uniform in ℓ
    over ``log_ks_range`` with prior weight ``unknown_weight``, absorbs
    estimates far from every class; the named classes share the remaining
    prior equally. The confidence is the posterior of the most likely named
    class, so it is near 1 only when the estimate is tight *and* close to one
    class, about 0.5 between two near-identical soils (Upland sandy loam and
    North Gower clayey loam differ by 1.7 %), and near 0 far from all classes.

    Args:
        k_s: soil stiffness estimate (N/m); non-positive or non-finite values
            give the first class with confidence 0.
        k_s_variance: its variance ((N/m)²).
        table: known soils.
        class_log_std: σ_c, standard deviation of ln k_s within a class.
        unknown_weight: prior weight of the background component, in [0, 1).
        log_ks_range: (min, max) k_s (N/m) spanned by the background.

    Returns:
        The classification; ``name`` is always a table entry.
    """
    if not table:
        raise ValueError("the soil table is empty")
    if not (0.0 <= unknown_weight < 1.0):
        raise ValueError("unknown_weight must be in [0, 1)")
    n = len(table)
    if not (math.isfinite(k_s) if type(k_s) is float else np.isfinite(k_s)) or not k_s > 0.0:
        return SoilClassification(table[0].name, 0.0, (0.0,) * n, 1.0)
    var_rel = float(k_s_variance) / (k_s * k_s)
    if not math.isfinite(var_rel) or var_rel < 0.0:
        var_rel = 1e6
    s2 = var_rel + class_log_std**2
    ell = math.log(k_s)
    if n >= _SUMMED_IN_ORDER or not s2 > 0.0:
        return _classify_arrays(ell, s2, table, unknown_weight, log_ks_range)
    # The numpy form's operations on floats, in its order (_classify_arrays; the classifier runs on every
    # filter step, where numpy's per-call cost on seven numbers was most of it): the same values, bit for bit.
    norm = 0.5 * math.log(2.0 * math.pi * s2)
    prior = math.log((1.0 - unknown_weight) / n)
    log_post = [-0.5 * ((ell - c) * (ell - c)) / s2 - norm + prior for c in _log_centre_list(table)]
    if unknown_weight > 0.0:
        width = math.log(log_ks_range[1]) - math.log(log_ks_range[0])
        log_post.append(math.log(unknown_weight) - math.log(width))
    top = max(log_post)
    post = np.exp([v - top for v in log_post]).tolist()  # numpy's exp: libm's may differ in the last bit
    total = post[0]
    for p in post[1:]:  # numpy's sum of fewer than 8 numbers: in order
        total += p
    named = [p / total for p in post[:n]]
    confidence = max(named)
    best = named.index(confidence)  # the first maximum, as argmax
    p_unknown = post[n] / total if unknown_weight > 0.0 else 0.0
    return SoilClassification(table[best].name, confidence, tuple(named), p_unknown)


#: Tables of fewer classes are classified on floats: at most 7 posterior terms with the unknown one, which numpy
#: sums one after the other (its pairwise sum unrolls from 8 terms).
_SUMMED_IN_ORDER = 7


def _classify_arrays(
    ell: float, s2: float, table: tuple[SoilClass, ...], unknown_weight: float, log_ks_range: tuple[float, float]
) -> SoilClassification:
    """:func:`classify_soil` on numpy arrays, from ``ℓ = ln k_s`` and ``s² = σ_ℓ² + σ_c²`` (large tables)."""
    n = len(table)
    log_post = np.empty(n + 1 if unknown_weight > 0.0 else n)
    log_post[:n] = -0.5 * (ell - _log_centres(tuple(table))) ** 2 / s2 - 0.5 * math.log(2.0 * math.pi * s2)
    log_post[:n] += math.log((1.0 - unknown_weight) / n)
    if unknown_weight > 0.0:
        width = math.log(log_ks_range[1]) - math.log(log_ks_range[0])
        log_post[n] = math.log(unknown_weight) - math.log(width)
    # log-sum-exp normalisation: no under/overflow for far-away estimates
    post = np.exp(log_post - log_post.max())
    post /= post.sum()
    named = post[:n]
    best = int(named.argmax())
    p_unknown = float(post[n]) if unknown_weight > 0.0 else 0.0
    return SoilClassification(table[best].name, float(named[best]), tuple(named.tolist()), p_unknown)


_centre_lists: dict[int, tuple[tuple[SoilClass, ...], list[float]]] = {}


def _log_centre_list(table: tuple[SoilClass, ...]) -> list[float]:
    """:func:`_log_centres` as floats, looked up by the table's identity (hashing a table of dataclasses on every
    step cost as much as the classification)."""
    hit = _centre_lists.get(id(table))
    if hit is not None and hit[0] is table:
        return hit[1]
    centres = _log_centres(tuple(table)).tolist()
    if len(_centre_lists) >= 16:
        _centre_lists.clear()
    _centre_lists[id(table)] = (table, centres)
    return centres


@functools.lru_cache(maxsize=16)
def _log_centres(table: tuple[SoilClass, ...]) -> np.ndarray:
    """``ln k_c`` of each class (read-only; cached: the estimator classifies every filter step)."""
    centres = np.log(np.array([c.k_s for c in table], dtype=float))
    centres.setflags(write=False)
    return centres


class CusumDetector:
    """Two-sided CUSUM on a standardised sequence ``e_k`` (Page 1954).

    ``g⁺ ← max(0, g⁺ + e_k − ν)``, ``g⁻ ← max(0, g⁻ − e_k − ν)``; an alarm is
    raised when either exceeds ``threshold`` h, after which both restart from 0.

    The plain statistic. The soil-stiffness estimator now uses
    :class:`~terrain_estimation.estimators.soil_change.SoilChangeDetector`
    (the same CUSUM on the same standardised correction, clipped, armed from
    the first update, with the innovation-implied jump that sizes the
    re-open); what follows is how this class was used before and still holds
    for the statistic. The estimator fed it the k_tot correction of each accepted update,
    normalised by its predicted standard deviation,
    ``e_k = Δk̂_tot / √(P⁻_kk − P⁺_kk)``: for a consistent filter the
    innovations are white with covariance S, so ``Δk̂_tot = W_k ν`` is white
    with variance ``W_k S W_kᵀ = P⁻_kk − P⁺_kk``, i.e. ``e_k ~ N(0, 1)``. After a
    soil change the corrections keep one sign until k̂_tot has moved, so e_k
    acquires a mean μ of many σ.

    False-alarm trade-off (N(0, 1) input, one side): the average run length
    to a false alarm is ``ARL₀ ≈ (e^{2ν b} − 2ν b − 1)/(2ν²)`` with
    ``b = h + 1.166`` (Siegmund), the detection delay ≈ ``b/(μ − ν)`` steps.
    For a consistent filter the defaults ν = 1, h = 50 never false-alarm
    (ARL₀ ≈ 10⁴⁴ steps); the large h is there because model mismatch makes
    e_k larger and correlated. Measured with the SCKF on the 2-DOF case
    (ISO D-like road, 10 m/s, accelerometer σ = 0.71 m/s², 12 s runs): the
    largest statistic of stationary runs was 2.9–4.8 (Graneville, Upland,
    LETE); with white noise on the 1 kHz profile it grew to 6 (σ_h = 0.2 mm),
    24 (0.5 mm) and 80 (1 mm, where profile smoothing is needed anyway).
    Graneville loam → Upland sandy loam was detected 0.19 s after the change,
    LETE sand → Upland 0.07 s after; Upland → North Gower clayey loam (k_s
    +1.7 %) is below what the detector (or the classifier) can resolve. A
    larger h buys robustness against an inconsistent filter at the price of
    delay and of missing smaller changes; ν sets the smallest sustained shift
    that is detected at all.

    Args:
        drift: ν, the allowance per sample (in σ).
        threshold: h, the alarm level (in σ).
    """

    def __init__(self, drift: float = 1.0, threshold: float = 50.0) -> None:
        if not (np.isfinite(drift) and drift >= 0.0):
            raise ValueError("drift must be finite and >= 0")
        if not (np.isfinite(threshold) and threshold > 0.0):
            raise ValueError("threshold must be finite and > 0")
        self.drift = float(drift)
        self.threshold = float(threshold)
        self.g_pos = 0.0
        self.g_neg = 0.0

    def reset(self) -> None:
        """Restart both statistics from 0."""
        self.g_pos = 0.0
        self.g_neg = 0.0

    @property
    def statistic(self) -> float:
        """``max(g⁺, g⁻)``, in σ."""
        return max(self.g_pos, self.g_neg)

    def update(self, e: float) -> bool:
        """Add one standardised sample; True when an alarm is raised.

        A non-finite sample is ignored (returns False).
        """
        if not np.isfinite(e):
            return False
        self.g_pos = max(0.0, self.g_pos + e - self.drift)
        self.g_neg = max(0.0, self.g_neg - e - self.drift)
        if self.g_pos > self.threshold or self.g_neg > self.threshold:
            self.reset()
            return True
        return False
