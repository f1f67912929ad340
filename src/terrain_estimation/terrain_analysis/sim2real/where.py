"""Where the sim-to-real gap lies: the noise tests of a residual against its noise budget.

For one channel (measured against a replay's prediction at the same stamps):
residual bias and RMS against the noise budget, the ratio of residual to noise
power and of measured to simulated power per octave band, the coherence and
the delay between measured and simulated signals (:func:`_channel`, after
:func:`despike`); the residual RMS per time window or bin of an operating
variable (:func:`_regimes`); the estimator's NIS (mean against its χ² band and
autocorrelation at lags 1..10, :func:`_nis_report`). Every test is
Bonferroni-corrected over the channel's tests, with a model-error allowance
(:class:`WhereSettings`).

Used by the attribution (:mod:`~terrain_analysis.sim2real.attribution`), the
diagnosis (:mod:`~terrain_analysis.sim2real.diagnose`) and the quarter car's
open-loop replay (:mod:`~terrain_analysis.sim2real.open_loop`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal, stats

__all__ = [
    "BandStat",
    "ChannelReport",
    "NisReport",
    "RegimeStat",
    "Sim2RealError",
    "WhereSettings",
    "despike",
    "regime_gaps",
    "time_windows",
]

FloatArray = NDArray[np.float64]


class Sim2RealError(ValueError):
    """The bag cannot be diagnosed (a needed topic is missing, too short, ...)."""


@dataclass(frozen=True)
class WhereSettings:
    """Knobs of the analysis (the defaults are what the CLI uses).

    Attributes:
        warmup: Seconds at the start left out of every statistic (the replay
            starts at rest; a real vehicle may not).
        window: Length of the time windows of the regime table (s).
        speed_bin: Width of the speed bins (m/s).
        bands: Octave band edges (Hz), clipped to the accelerometer Nyquist.
        alpha: Family-wise false-alarm probability of the noise tests.
        bias_floor: Smallest bias reported as a gap, as a fraction of the
            channel's noise σ (a model-error allowance that holds in any unit:
            m/s², rad/s, N).
        power_floor: Smallest residual-to-budget power ratio reported as a gap
            (model-error allowance: the k_s estimate is not exact).
        coherence_floor: A band whose mean coherence is above this is coherent.
        profile_smoothing: Savitzky-Golay window (samples, odd) smoothing the
            measured elevation before it drives the plant.
        spike_sigma: A residual sample further than this many robust σ
            (1.4826 × the median absolute deviation of the channel's residual)
            from the residual's median, with both neighbours inside, is an
            isolated spike (a sensor glitch, one sample stamped a period late):
            it is replaced by the mean residual of its neighbours before any
            statistic and counted (:func:`despike`). Gaussian noise passes
            8 σ once in 10¹⁵ samples.
        spike_max_share: At most this share of a channel's samples (and at
            least one) is treated as spikes; more isolated excursions than that
            are the behaviour of the data, kept in the statistics (a gap).
    """

    warmup: float = 0.5
    window: float = 2.0
    speed_bin: float = 1.0
    bands: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 50.0)
    alpha: float = 0.01
    bias_floor: float = 0.2
    power_floor: float = 1.25
    coherence_floor: float = 0.5
    profile_smoothing: int = 5
    spike_sigma: float = 8.0
    spike_max_share: float = 1e-3


@dataclass
class BandStat:
    """One frequency band of one channel.

    Attributes:
        f_low, f_high: Band edges (Hz).
        residual_to_noise: Mean residual PSD / noise-budget PSD (1 when the
            residual is the sensor noise alone).
        measured_to_simulated: Mean measured PSD / (simulated PSD + noise PSD).
        coherence: Mean magnitude-squared coherence of measured and simulated.
        threshold: residual_to_noise above this is a gap.
        gap: residual_to_noise above threshold.
    """

    f_low: float
    f_high: float
    residual_to_noise: float
    measured_to_simulated: float
    coherence: float
    threshold: float
    gap: bool


@dataclass
class RegimeStat:
    """Residual RMS in one time window or speed bin."""

    label: str
    start: float
    end: float
    samples: int
    residual_rms: dict[str, float]
    gap: list[str] = field(default_factory=list)


@dataclass
class ChannelReport:
    """One accelerometer channel (``body`` or ``wheel``).

    Attributes:
        name: ``body`` or ``wheel``.
        topic: Its bag topic.
        samples: Samples in the statistics (after the warm-up).
        noise_std: Noise budget σ (m/s²): √R plus the profile-noise share.
        residual_rms: RMS of measured − simulated (m/s²).
        residual_std: Its standard deviation (bias removed).
        bias: Mean residual (m/s²); gravity is in both signals.
        bias_threshold: |bias| above this is a gap.
        rms_ratio: residual_std² / noise_std².
        rms_threshold: rms_ratio above this is a gap.
        measured_rms, simulated_rms: RMS of the measured and simulated
            signals with gravity removed (m/s²).
        delay: Lag of the measured signal behind the simulated one from the
            cross-correlation peak (s, parabolic sub-sample), in ±0.1 s.
        gain: Least-squares gain of measured on simulated (1: no scale error).
        bands: Per-band statistics.
        gaps: Human-readable list of what exceeded its threshold.
        unit: Unit of the channel's samples (and of bias, std, σ).
        spikes: Isolated residual spikes replaced before the statistics
            (:func:`despike`).
    """

    name: str
    topic: str
    samples: int
    noise_std: float
    residual_rms: float
    residual_std: float
    bias: float
    bias_threshold: float
    rms_ratio: float
    rms_threshold: float
    measured_rms: float
    simulated_rms: float
    delay: float
    gain: float
    bands: list[BandStat]
    gaps: list[str] = field(default_factory=list)
    unit: str = "m/s²"
    spikes: int = 0


@dataclass
class NisReport:
    """The estimator's normalised innovations squared over the bag.

    Only the NIS is exposed by the estimator core (not the innovation
    vectors), so whiteness is the autocorrelation of the centred NIS
    sequence (i.i.d. χ² values have autocorrelation ~N(0, 1/N) at lag ≥ 1).
    """

    updates: int
    dim: int
    mean: float
    band: tuple[float, float]
    in_band: bool
    autocorrelation: list[float]
    whiteness_bound: float
    white: bool
    k_s: float
    k_s_std: float
    converged: bool


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, float)):
        f = float(value)
        return f if math.isfinite(f) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


# ---------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------


def _band_stats(
    measured: FloatArray,
    simulated: FloatArray,
    fs: float,
    noise_var: float,
    settings: WhereSettings,
    n_tests: int,
) -> list[BandStat]:
    n = len(measured)
    nperseg = int(min(n, 2 ** int(round(math.log2(max(fs * 4.0, 16.0))))))
    resid = measured - simulated
    kw: dict[str, Any] = {"fs": fs, "nperseg": nperseg, "detrend": "constant"}
    f, p_res = signal.welch(resid, **kw)
    _, p_meas = signal.welch(measured, **kw)
    _, p_sim = signal.welch(simulated, **kw)
    with np.errstate(divide="ignore", invalid="ignore"):  # a channel simulated as all zeros
        _, coh = signal.coherence(measured, simulated, **kw)
    coh = np.nan_to_num(coh, nan=0.0)
    noise_psd = 2.0 * noise_var / fs  # one-sided white PSD
    n_seg = max(1, (n - nperseg) // (nperseg // 2) + 1)
    out = []
    edges = [e for e in settings.bands if e < fs / 2.0 + 1e-9]
    for lo, hi in zip(edges[:-1], edges[1:], strict=False):
        sel = (f >= lo) & (f < hi) if hi < fs / 2.0 else (f >= lo) & (f <= hi)
        if not np.any(sel):
            continue
        bins = int(np.sum(sel))
        # Welch with a Hann window and 50 % overlap: ~0.9 of 2 dof per bin and segment
        # survive the overlap, and neighbouring bins are correlated (their power
        # estimates share a quarter of their variance), so B bins average like ~B/1.5
        # independent ones. Checked by simulation on white noise (test_sim2real_where).
        dof = max(2.0, 2.0 * bins * n_seg * 0.9 / 1.5)
        chi = float(stats.chi2.ppf(1.0 - settings.alpha / n_tests, dof) / dof)
        threshold = max(chi, settings.power_floor)
        ratio = float(np.mean(p_res[sel]) / noise_psd)
        out.append(
            BandStat(
                f_low=float(lo),
                f_high=float(hi),
                residual_to_noise=ratio,
                measured_to_simulated=float(np.mean(p_meas[sel]) / (np.mean(p_sim[sel]) + noise_psd)),
                coherence=float(np.mean(coh[sel])),
                threshold=threshold,
                gap=ratio > threshold,
            )
        )
    return out


def _delay(measured: FloatArray, simulated: FloatArray, fs: float, max_lag: float = 0.1) -> float:
    m = measured - measured.mean()
    s = simulated - simulated.mean()
    n = len(m)
    lags = int(min(max_lag * fs, n // 4))
    if lags < 1 or not np.any(s):
        return 0.0
    xc = np.array([np.dot(m[j:], s[: n - j]) if j >= 0 else np.dot(m[:j], s[-j:]) for j in range(-lags, lags + 1)])
    i = int(np.argmax(xc))
    frac = 0.0
    if 0 < i < len(xc) - 1:
        y0, y1, y2 = xc[i - 1], xc[i], xc[i + 1]
        den = y0 - 2.0 * y1 + y2
        frac = 0.5 * (y0 - y2) / den if den != 0.0 else 0.0
    return float((i - lags + frac) / fs)


def despike(measured: FloatArray, simulated: FloatArray, settings: WhereSettings) -> tuple[FloatArray, int]:
    """``measured`` with its isolated residual spikes replaced, and how many (:class:`WhereSettings`).

    A spike is one sample whose residual ``measured − simulated`` lies beyond
    ``spike_sigma`` robust σ of the residual's median while both neighbours lie
    inside: one bad sample (an accelerometer glitch, a message stamped one
    period late on a rough road) must cost one sample, not turn a window's
    power ratio into a gap. It is replaced by the simulated value plus the mean
    residual of its neighbours. Excursions of two or more consecutive samples,
    and more isolated ones than ``spike_max_share`` of the channel, are left
    alone: they are the data's behaviour (an impact, a delay on a rough road),
    and the statistics must see them.
    """
    n = measured.size
    if n < 3 or settings.spike_sigma <= 0.0:
        return measured, 0
    resid = measured - simulated
    centred = resid - float(np.median(resid))
    scale = 1.4826 * float(np.median(np.abs(centred)))
    if not (scale > 0.0 and math.isfinite(scale)):
        return measured, 0
    out = np.abs(centred) > settings.spike_sigma * scale
    isolated = out.copy()
    isolated[1:] &= ~out[:-1]
    isolated[:-1] &= ~out[1:]
    isolated[0] = isolated[-1] = False
    count = int(np.count_nonzero(isolated))
    if count == 0 or count > max(1, int(settings.spike_max_share * n)):
        return measured, 0
    idx = np.flatnonzero(isolated)
    cleaned = measured.copy()
    cleaned[idx] = simulated[idx] + 0.5 * (resid[idx - 1] + resid[idx + 1])
    return cleaned, count


def _channel(
    name: str,
    topic: str,
    measured: FloatArray,
    simulated: FloatArray,
    fs: float,
    noise_var: float,
    settings: WhereSettings,
    n_channels: int,
    unit: str = "m/s²",
) -> ChannelReport:
    """The noise tests of one channel, after :func:`despike` (the spikes are counted in the report)."""
    measured, spikes = despike(measured, simulated, settings)
    n = len(measured)
    resid = measured - simulated
    bias = float(np.mean(resid))
    std = float(np.std(resid))
    noise_std = math.sqrt(noise_var)
    n_bands = max(1, len(settings.bands) - 1)
    n_tests = n_channels * (n_bands + 2)
    z = float(stats.norm.ppf(1.0 - settings.alpha / (2.0 * n_tests)))
    bias_threshold = max(settings.bias_floor * noise_std, z * noise_std / math.sqrt(n))
    chi = float(stats.chi2.ppf(1.0 - settings.alpha / n_tests, n - 1) / (n - 1))
    rms_threshold = max(chi, settings.power_floor)
    rms_ratio = std**2 / noise_var
    sim_ac = simulated - simulated.mean()
    meas_ac = measured - measured.mean()
    gain = float(np.dot(meas_ac, sim_ac) / np.dot(sim_ac, sim_ac)) if np.any(sim_ac) else float("nan")
    bands = _band_stats(measured, simulated, fs, noise_var, settings, n_tests)
    gaps = []
    if abs(bias) > bias_threshold:
        gaps.append(f"{name}: bias {bias:+.4g} {unit} (threshold ±{bias_threshold:.3g})")
    if rms_ratio > rms_threshold:
        gaps.append(
            f"{name}: residual std {std:.4g} {unit} = {math.sqrt(rms_ratio):.2f}× the noise σ {noise_std:.3g} "
            f"(power ratio {rms_ratio:.2f} > {rms_threshold:.2f})"
        )
    for b in bands:
        if b.gap:
            gaps.append(
                f"{name}: band {b.f_low:g}–{b.f_high:g} Hz residual power {b.residual_to_noise:.2f}× noise "
                f"(> {b.threshold:.2f}; measured/simulated {b.measured_to_simulated:.2f}, coherence {b.coherence:.2f})"
            )
    return ChannelReport(
        name=name,
        topic=topic,
        samples=n,
        noise_std=noise_std,
        residual_rms=float(np.sqrt(np.mean(resid**2))),
        residual_std=std,
        bias=bias,
        bias_threshold=bias_threshold,
        rms_ratio=rms_ratio,
        rms_threshold=rms_threshold,
        measured_rms=float(np.std(measured)),
        simulated_rms=float(np.std(simulated)),
        delay=_delay(measured, simulated, fs),
        gain=gain,
        bands=bands,
        gaps=gaps,
        unit=unit,
        spikes=spikes,
    )


def _regimes(
    labels: list[tuple[str, float, float, NDArray[np.bool_]]],
    residuals: dict[str, FloatArray],
    noise_vars: dict[str, float],
    settings: WhereSettings,
    n_tests: int,
) -> list[RegimeStat]:
    out = []
    for label, lo, hi, sel in labels:
        n = int(np.sum(sel))
        if n < 10:
            continue
        rms = {ch: float(np.sqrt(np.mean(r[sel] ** 2))) for ch, r in residuals.items()}
        chi = float(stats.chi2.ppf(1.0 - settings.alpha / max(1, n_tests), n) / n)
        threshold = max(chi, settings.power_floor)
        gap = [ch for ch, v in rms.items() if v**2 / noise_vars[ch] > threshold]
        out.append(RegimeStat(label, lo, hi, n, rms, gap))
    return out


def time_windows(
    t_ref: FloatArray, start: float, origin: float, window: float
) -> list[tuple[str, float, float, NDArray[np.bool_]]]:
    """Consecutive windows of ``window`` s from ``start`` over the stamps ``t_ref``, for :func:`_regimes`.

    Each is (label, from, to, mask of ``t_ref``), times relative to ``origin``.
    """
    n_win = max(1, int(math.ceil((t_ref[-1] - start + 1e-9) / window))) if t_ref.size else 0
    out = []
    for i in range(n_win):
        lo, hi = start + i * window, start + (i + 1) * window
        out.append((f"{lo - origin:.1f}–{hi - origin:.1f} s", lo - origin, hi - origin, (t_ref >= lo) & (t_ref < hi)))
    return out


def regime_gaps(prefix: str, rows: list[RegimeStat]) -> list[str]:
    """A line per row whose residual is above the noise, if some rows are and some are not."""
    bad = [r for r in rows if r.gap]
    if bad and len(bad) < len(rows):
        return [f"{prefix}{r.label}: residual above noise on {', '.join(r.gap)}" for r in bad]
    return []


def _nis_report(estimates: list[Any], dim: int, probability: float) -> NisReport | None:
    if not estimates:
        return None
    nis = np.array([float(m.nis) for m in estimates])
    nis = nis[nis > 0.0]  # 0: predict-only step
    last = estimates[-1]
    k_s_std = math.sqrt(max(float(last.k_s_variance), 0.0))
    if nis.size < 10:
        return NisReport(0, dim, float("nan"), (0.0, 0.0), False, [], 0.0, False, float(last.k_s), k_s_std, False)
    n = nis.size
    lo = float(stats.chi2.ppf((1.0 - probability) / 2.0, n * dim) / n)
    hi = float(stats.chi2.ppf(1.0 - (1.0 - probability) / 2.0, n * dim) / n)
    mean = float(np.mean(nis))
    centred = nis - nis.mean()
    var = float(np.dot(centred, centred))
    ac = [float(np.dot(centred[j:], centred[:-j]) / var) if var > 0 else 0.0 for j in range(1, 11)]
    bound = 2.0 / math.sqrt(n)
    # At 95 % per lag, about one lag in 10 exceeds the bound by chance: allow one.
    white = sum(abs(r) > bound for r in ac) <= 1
    return NisReport(
        updates=n,
        dim=dim,
        mean=mean,
        band=(lo, hi),
        in_band=lo <= mean <= hi,
        autocorrelation=ac,
        whiteness_bound=bound,
        white=white,
        k_s=float(last.k_s),
        k_s_std=k_s_std,
        converged=bool(last.converged),
    )
