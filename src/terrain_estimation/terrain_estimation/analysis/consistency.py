"""Is a published variance a claim that holds? NEES, NIS and normalised errors against their χ² bands.

A filter's covariance says how large its errors are. On truth runs this is
checked with the standard statistics (Bar-Shalom, Li, Kirubarajan,
*Estimation with Applications to Tracking and Navigation*, 2001, §5.4):

* the normalised estimation error squared ``NEES_k = e_kᵀ P_k⁻¹ e_k`` of the
  estimated quantities (χ² with ``n`` degrees of freedom when the filter is
  consistent), per quantity ``e²/σ²`` (mean 1) and the share of errors within
  ``2σ`` (95.4 % for a Gaussian error);
* the normalised innovation squared ``NIS_k = νᵀ S⁻¹ ν`` (χ² with ``m`` dof),
  which needs no truth and is what ``/diagnostics`` watches on a robot.

**Windows.** The share of time windows (default 2 s) whose mean lies inside
the two-sided ``probability`` band of a mean of χ² values. The band of a
mean of ``N`` independent χ²ₙ values is ``χ²_{Nn}(p)/N``. Innovations of a
consistent filter are white, so the NIS uses ``N`` = the window's samples.
Estimation errors are not: consecutive errors of a filter running at 100 Hz
share most of their cause, so the NEES of a window holds far fewer than ``N``
independent values. Its band uses the effective count
``N_eff = N / τ`` with ``τ`` the integrated autocorrelation time of the
run's NEES sequence (Geyer's initial positive sequence estimator, Statistical
Science 7(4), 1992). Treating correlated NEES as independent would give a
band so narrow that even the true posterior fails it; ``τ`` is reported
beside every figure so that a reader can judge the band.

Everything here is numpy plus :func:`scipy.special.chdtri` (no
``scipy.stats``: that import alone costs 0.8 s of start-up).
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S) of the literature

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import chdtri

__all__ = [
    "ConsistencyReport",
    "QuantityConsistency",
    "WindowShare",
    "chi2_mean_band",
    "consistency_report",
    "integrated_autocorrelation_time",
    "nees",
    "window_share",
]

FloatArray = NDArray[np.float64]


def chi2_mean_band(dof: float, samples: float, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` band of the mean of ``samples`` independent χ²_dof values.

    ``samples`` may be fractional (an effective count); it is floored at 1.
    """
    if not (dof > 0 and math.isfinite(dof)):
        raise ValueError(f"dof must be finite and > 0, got {dof}")
    if not (0.0 < probability < 1.0):
        raise ValueError(f"probability must be in (0, 1), got {probability}")
    n = max(1.0, float(samples))
    tail = 0.5 * (1.0 - probability)
    total = n * dof
    return float(chdtri(total, 1.0 - tail)) / n, float(chdtri(total, tail)) / n


def nees(errors: ArrayLike, covariances: ArrayLike) -> FloatArray:
    """``e_kᵀ P_k⁻¹ e_k`` per sample; errors (T, n), covariances (T, n, n) (or (T,) and (T,) for n = 1)."""
    e = np.asarray(errors, dtype=float)
    P = np.asarray(covariances, dtype=float)
    if e.ndim == 1:
        e = e[:, None]
        P = P.reshape(-1, 1, 1)
    if P.shape != (e.shape[0], e.shape[1], e.shape[1]):
        raise ValueError(f"covariances must have shape {(e.shape[0], e.shape[1], e.shape[1])}, got {P.shape}")
    solved = np.linalg.solve(P, e[..., None])[..., 0]
    return np.asarray(np.einsum("ti,ti->t", e, solved), dtype=float)


def integrated_autocorrelation_time(x: ArrayLike, max_lag: int | None = None) -> float:
    """τ = 1 + 2 Σ ρ_k, summed over Geyer's initial positive sequence (≥ 1; 1 for white data)."""
    v = np.asarray(x, dtype=float)
    v = v[np.isfinite(v)]
    n = v.size
    if n < 8:
        return 1.0
    c = v - v.mean()
    var = float(np.dot(c, c)) / n
    if var <= 0.0:
        return 1.0
    size = 1 << (2 * n - 1).bit_length()
    spectrum = np.fft.rfft(c, size)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), size)[:n] / (n * var)
    limit = min(n - 1, max_lag if max_lag is not None else n // 2)
    # τ = −1 + 2 Σ Γ_m with Γ_m = ρ_2m + ρ_2m+1 (ρ_0 = 1), summed while Γ_m > 0 (Geyer's initial positive sequence).
    tau = -1.0
    for m in range(max(1, limit // 2)):
        pair = float(acf[2 * m] + acf[2 * m + 1])
        if pair <= 0.0:
            break
        tau += 2.0 * pair
    return max(1.0, tau)


@dataclass(frozen=True)
class WindowShare:
    """Windowed means of a χ² statistic against their band.

    Attributes:
        windows: Complete windows with at least two samples.
        inside: How many lie inside their band.
        share: ``inside / windows`` (nan without windows).
        above, below: Windows above / below the band.
        tau: Integrated autocorrelation time used for the band (1: white).
        band: The band of a typical (median-length) window.
    """

    windows: int
    inside: int
    share: float
    above: int
    below: int
    tau: float
    band: tuple[float, float]


def window_share(
    values: ArrayLike,
    t: ArrayLike,
    dof: float,
    *,
    window: float = 2.0,
    probability: float = 0.95,
    correlated: bool = False,
) -> WindowShare:
    """Share of ``window``-second windows whose mean of ``values`` (χ²_dof each) lies inside its band.

    ``correlated``: the values are not independent (a NEES sequence): the
    band of a window of ``N`` samples uses ``N / τ`` (module docstring).
    """
    v = np.asarray(values, dtype=float)
    tt = np.asarray(t, dtype=float)
    if v.shape != tt.shape:
        raise ValueError(f"values and t must have the same shape, got {v.shape} and {tt.shape}")
    if not (window > 0 and math.isfinite(window)):
        raise ValueError(f"window must be finite and > 0 s, got {window}")
    keep = np.isfinite(v) & np.isfinite(tt)
    v, tt = v[keep], tt[keep]
    tau = integrated_autocorrelation_time(v) if correlated else 1.0
    if v.size == 0:
        return WindowShare(0, 0, float("nan"), 0, 0, tau, (float("nan"), float("nan")))
    index = np.floor((tt - tt[0]) / window).astype(np.int64)
    last_complete = int(np.floor((tt[-1] - tt[0]) / window + 1e-9))
    inside = above = below = windows = 0
    lengths = []
    for w in range(last_complete):
        sel = index == w
        n = int(np.count_nonzero(sel))
        if n < 2:
            continue
        lo, hi = chi2_mean_band(dof, n / tau, probability)
        mean = float(np.mean(v[sel]))
        windows += 1
        lengths.append(n)
        if mean < lo:
            below += 1
        elif mean > hi:
            above += 1
        else:
            inside += 1
    typical = chi2_mean_band(dof, float(np.median(lengths)) / tau, probability) if lengths else (math.nan, math.nan)
    return WindowShare(windows, inside, inside / windows if windows else float("nan"), above, below, tau, typical)


@dataclass(frozen=True)
class QuantityConsistency:
    """One published quantity: its errors against its variances.

    Attributes:
        name: The quantity.
        samples: Samples with a finite error and a variance > 0.
        rms_error: RMS of the error.
        rms_sigma: RMS of the published standard deviation.
        mean_normalised: Mean of e²/σ² (1 when consistent; < 1 cautious, > 1 over-confident).
        within_2sigma: Share of |e| ≤ 2σ (0.954 for Gaussian errors).
    """

    name: str
    samples: int
    rms_error: float
    rms_sigma: float
    mean_normalised: float
    within_2sigma: float


@dataclass(frozen=True)
class ConsistencyReport:
    """NEES of the joint state and the per-quantity figures of one or more truth runs.

    Attributes:
        dof: Dimension of the NEES.
        mean_nees: Mean NEES over all samples.
        nees_band: Band of that mean, with the effective sample count.
        nees_windows: Windowed NEES against their bands.
        quantities: Per-quantity figures.
        nis_windows: Windowed NIS against their bands (None without NIS).
        mean_nis: Mean NIS (nan without NIS).
        nis_dof: Dimension of the NIS (0 without NIS).
    """

    dof: int
    mean_nees: float
    nees_band: tuple[float, float]
    nees_windows: WindowShare
    quantities: list[QuantityConsistency] = field(default_factory=list)
    nis_windows: WindowShare | None = None
    mean_nis: float = float("nan")
    nis_dof: int = 0

    def quantity(self, name: str) -> QuantityConsistency:
        """The figures of quantity ``name``."""
        for q in self.quantities:
            if q.name == name:
                return q
        raise KeyError(f"no quantity {name!r}; have {[q.name for q in self.quantities]}")


def consistency_report(
    t: ArrayLike,
    errors: ArrayLike,
    covariances: ArrayLike,
    names: Sequence[str],
    *,
    nis: ArrayLike | None = None,
    nis_dof: int = 0,
    window: float = 2.0,
    probability: float = 0.95,
) -> ConsistencyReport:
    """The consistency figures of one run: ``errors`` (T, n) = estimate − truth, ``covariances`` (T, n, n).

    ``nis`` (T,) with ``nis_dof`` its dimension adds the windowed NIS (samples
    that are not finite, e.g. steps without an update, are left out).
    """
    e = np.asarray(errors, dtype=float)
    P = np.asarray(covariances, dtype=float)
    tt = np.asarray(t, dtype=float)
    if e.ndim != 2 or e.shape[1] != len(names):
        raise ValueError(f"errors must be (T, {len(names)}) for names {list(names)}, got {e.shape}")
    good = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(P.reshape(len(P), -1)), axis=1)
    e, P, tt = e[good], P[good], tt[good]
    values = nees(e, P)
    tau = integrated_autocorrelation_time(values)
    n = e.shape[1]
    quantities = []
    for i, name in enumerate(names):
        var = P[:, i, i]
        ok = var > 0.0
        ei, vi = e[ok, i], var[ok]
        quantities.append(
            QuantityConsistency(
                name=name,
                samples=int(ei.size),
                rms_error=float(np.sqrt(np.mean(ei**2))) if ei.size else math.nan,
                rms_sigma=float(np.sqrt(np.mean(vi))) if ei.size else math.nan,
                mean_normalised=float(np.mean(ei**2 / vi)) if ei.size else math.nan,
                within_2sigma=float(np.mean(np.abs(ei) <= 2.0 * np.sqrt(vi))) if ei.size else math.nan,
            )
        )
    report = ConsistencyReport(
        dof=n,
        mean_nees=float(np.mean(values)) if values.size else math.nan,
        nees_band=chi2_mean_band(n, values.size / tau, probability) if values.size else (math.nan, math.nan),
        nees_windows=window_share(values, tt, n, window=window, probability=probability, correlated=True),
        quantities=quantities,
    )
    if nis is None:
        return report
    s = np.asarray(nis, dtype=float)
    if s.shape != np.asarray(t).shape:
        raise ValueError(f"nis must have the shape of t {np.asarray(t).shape}, got {s.shape}")
    if nis_dof <= 0:
        raise ValueError(f"nis_dof must be > 0 with nis, got {nis_dof}")
    s = s[good]
    finite = np.isfinite(s)
    return ConsistencyReport(
        dof=report.dof,
        mean_nees=report.mean_nees,
        nees_band=report.nees_band,
        nees_windows=report.nees_windows,
        quantities=quantities,
        nis_windows=window_share(s[finite], tt[finite], nis_dof, window=window, probability=probability),
        mean_nis=float(np.mean(s[finite])) if np.any(finite) else math.nan,
        nis_dof=nis_dof,
    )
