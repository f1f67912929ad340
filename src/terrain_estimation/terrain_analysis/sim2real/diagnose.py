"""One bag, one verdict: where the gap lies, which effect explains it, how far it shrinks.

:func:`diagnose` builds the vehicle's replay model of the bag
(:mod:`~terrain_analysis.sim2real.model`), runs the attribution
(:mod:`~terrain_analysis.sim2real.attribution`) and tabulates *where* the
nominal model (nuisance fitted) disagrees with the bag: per channel (bias,
power, gain, delay, octave bands), per time window and per operating regime
the replay model exposes. For the quarter car and the LRV the estimator runs
over the bag once: its final k_s starts the replay's ln k_s and its NIS
(against the χ² band, with whiteness) is reported with the rest.

The config's nominal tolerances (section ``/**/sim2real``,
:mod:`~terrain_analysis.sim2real.tolerance`) make the uncertain nominal
parameters nuisance parameters with a prior: a mismatch within them is not a gap.

Only the bag and the vehicle's config are read: nothing of how the bag was made.
The bag's inputs are checked first (:mod:`~terrain_analysis.sim2real.inputs`:
the estimators' input checks, plausibility bounds, time gaps); the replay and
the estimator read only the messages that pass, of one gap-free segment.

**Threads.** The diagnosis runs under one BLAS thread (threadpoolctl). Its
matrices are small (Jacobians of a few thousand rows by a few columns); with
OpenBLAS's threads the CPU of a 60 s skid-steer bag was 48 s against 25.5 s on
one thread (2 cores, loaded), the cost grew faster than the bag (×1.3 per
bag-second from 15 to 60 s, the threads' spinning charged to the process),
and the optimiser's evaluations depended on the core count (2624 against
2604). Dask's workers already run one BLAS thread each, so a verdict is the
same from ``terrain-sim2real``, ``terrain-batch`` and ``validate-sim2real``.
"""

from __future__ import annotations

import importlib
import math
import tempfile
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from terrain_analysis.sim2real.attribution import AttributionReport, AttributionSettings, attribute
from terrain_analysis.sim2real.inputs import GAP_MIN_S, InputReport, screen_bag
from terrain_analysis.sim2real.model import ReplayModel, usable_mask
from terrain_analysis.sim2real.tolerance import nuisance_names, tolerances, with_tolerances
from terrain_analysis.sim2real.where import (
    ChannelReport,
    NisReport,
    RegimeStat,
    Sim2RealError,
    WhereSettings,
    _channel,
    _jsonable,
    _nis_report,
    _regimes,
    despike,
    regime_gaps,
    time_windows,
)

__all__ = ["BUILDERS", "Diagnosis", "WhereTable", "build_model", "diagnose", "supported_vehicles", "where_table"]

FloatArray = NDArray[np.float64]

BUILDERS: dict[str, str] = {
    "quarter_car": "terrain_analysis.sim2real.quarter_car",
    "lrv": "terrain_analysis.sim2real.quarter_car",
    "skid_steer": "terrain_analysis.sim2real.skid_steer",
    "rover": "terrain_analysis.sim2real.rover",
}
"""vehicle → module with ``build_model(bag, *, config, namespace, progress)``."""


def supported_vehicles() -> tuple[str, ...]:
    """Vehicles whose replay model is installed."""
    out = []
    for vehicle, module in BUILDERS.items():
        try:
            mod = importlib.import_module(module)
        except ImportError:
            continue
        if hasattr(mod, "build_model"):
            out.append(vehicle)
    return tuple(out)


@dataclass
class WhereTable:
    """Where the fitted nominal model disagrees with the bag (all samples after the warm-up).

    Attributes:
        channels: Per-channel statistics (:class:`~terrain_analysis.sim2real.where.ChannelReport`).
        windows: Residual RMS per time window, flagged above the noise.
        regimes: Regime name → residual RMS per bin of that operating variable.
        gaps: Human-readable list of what exceeded its threshold.
    """

    channels: list[ChannelReport]
    windows: list[RegimeStat]
    regimes: dict[str, list[RegimeStat]]
    gaps: list[str]


@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (``to_dict()`` is JSON-serialisable)."""

    bag: str
    vehicle: str
    duration: float
    where: WhereTable
    nis: NisReport | None
    attribution: AttributionReport
    seconds: float
    notes: list[str] = field(default_factory=list)
    model: ReplayModel | None = field(default=None, repr=False)
    inputs: InputReport | None = None

    @property
    def verdict(self) -> str:
        return self.attribution.verdict

    def to_dict(self) -> dict[str, Any]:
        return _jsonable(
            {
                "bag": self.bag,
                "vehicle": self.vehicle,
                "duration": self.duration,
                "verdict": self.verdict,
                "where": asdict(self.where),
                "nis": asdict(self.nis) if self.nis is not None else None,
                "attribution": self.attribution.to_dict(),
                "seconds": self.seconds,
                "notes": self.notes,
                "inputs": asdict(self.inputs) if self.inputs is not None else None,
            }
        )


def where_table(model: ReplayModel, prediction: Mapping[str, FloatArray], where: WhereSettings) -> WhereTable:
    """Where ``prediction`` (the fitted nominal model) and the bag disagree."""
    t0 = min(float(model.times[c.name][0]) for c in model.channels)
    start = t0 + model.warmup
    channels: list[ChannelReport] = []
    residuals: dict[str, FloatArray] = {}
    sigma = {c.name: float(c.noise_std) for c in model.channels}
    ref = model.channels[0].name
    t_ref = np.asarray(model.times[ref], dtype=float)
    t_ref = t_ref[usable_mask(model, ref, t0)]
    for ch in model.channels:
        t = np.asarray(model.times[ch.name], dtype=float)
        sel = usable_mask(model, ch.name, t0)
        meas = np.asarray(model.measured[ch.name], dtype=float)[sel]
        sim = np.asarray(prediction[ch.name], dtype=float)[sel]
        if meas.size < 8:
            continue
        dts = np.diff(t[sel])
        uniform = meas.size >= 256 and float(np.median(dts)) > 0
        fs = 1.0 / float(np.median(dts)) if uniform else 1.0
        w = where
        if not uniform:
            from dataclasses import replace

            w = replace(where, bands=(0.0,))
        channels.append(
            _channel(ch.name, ch.topic, meas, sim, fs, sigma[ch.name] ** 2, w, len(model.channels), ch.unit)
        )
        residuals[ch.name] = np.interp(t_ref, t[sel], despike(meas, sim, w)[0] - sim)
    win = time_windows(t_ref, start, t0, where.window)
    noise_vars = {name: s**2 for name, s in sigma.items()}
    windows = _regimes(win, residuals, noise_vars, where, len(residuals) * max(1, len(win)))
    regimes: dict[str, list[RegimeStat]] = {}
    for name, (t_var, values) in model.regimes.items():
        v = np.interp(t_ref, np.asarray(t_var, dtype=float), np.asarray(values, dtype=float))
        if not v.size or not np.all(np.isfinite(v)):
            continue
        lo_q, hi_q = np.quantile(v, [0.02, 0.98])
        if hi_q - lo_q <= 1e-12:
            continue
        edges = np.linspace(lo_q, hi_q, 5)
        edges[0], edges[-1] = -np.inf, np.inf
        labels = []
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            sel = (v >= a) & (v < b)
            lo_v = float(np.min(v[sel])) if np.any(sel) else float(a)
            hi_v = float(np.max(v[sel])) if np.any(sel) else float(b)
            labels.append((f"{lo_v:.3g}…{hi_v:.3g}", lo_v, hi_v, sel))
        regimes[name] = _regimes(labels, residuals, noise_vars, where, len(residuals) * len(labels))
    gaps = [g for ch in channels for g in ch.gaps] + regime_gaps("window ", windows)
    for name, rows in regimes.items():
        gaps += regime_gaps(f"{name} ", rows)
    return WhereTable(channels, windows, regimes, gaps)


def build_model(
    bag: str | Path,
    vehicle: str,
    *,
    config: str | Path | None = None,
    namespace: str | None = None,
    progress: Callable[[str], None] | None = None,
    **kwargs: Any,
) -> ReplayModel:
    """The vehicle's replay model of ``bag``."""
    if vehicle not in BUILDERS:
        raise Sim2RealError(f"no sim-to-real replay model for vehicle {vehicle!r}; known: {', '.join(BUILDERS)}")
    try:
        module = importlib.import_module(BUILDERS[vehicle])
    except ImportError as exc:
        raise Sim2RealError(f"the {vehicle} replay model is not available: {exc}") from exc
    if vehicle in ("quarter_car", "lrv"):
        kwargs["vehicle"] = vehicle
    model: ReplayModel = module.build_model(bag, config=config, namespace=namespace, progress=progress, **kwargs)
    return model


def diagnose(
    bag: str | Path,
    vehicle: str,
    *,
    namespace: str | None = None,
    config: str | Path | None = None,
    settings: AttributionSettings | None = None,
    progress: Callable[[str], None] | None = None,
    segment: int | None = None,
    min_gap: float = GAP_MIN_S,
) -> Diagnosis:
    """Where the gap lies, which catalogue effect explains it and how far it shrinks, for one bag.

    The inputs are checked first (:func:`~terrain_analysis.sim2real.inputs.screen_bag`);
    ``segment`` (1-based) and ``min_gap`` (s) choose the gap-free stretch analysed.

    Raises:
        Sim2RealError: unsupported vehicle, no usable input, too little data.
        BagError: unreadable bag, a missing input topic or one of another type.
    """
    if vehicle not in BUILDERS:
        raise Sim2RealError(f"no sim-to-real replay model for vehicle {vehicle!r}; known: {', '.join(BUILDERS)}")
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sim2real-") as scratch:
        screened = Path(scratch) / "checked"
        inputs = screen_bag(
            bag,
            vehicle,
            screened,
            namespace=namespace,
            config=config,
            segment=segment,
            min_gap=min_gap,
            progress=progress,
        )
        where = f"segment {inputs.analysed + 1} of {len(inputs.segments)}" if len(inputs.segments) > 1 else ""

        def said(text: str) -> None:  # the scratch bag is named as the bag it came from
            if progress is not None:
                progress(text.replace(str(screened), f"{bag}" + (f" ({where})" if where else "")))

        try:
            # One BLAS thread (module docstring, "Threads"): the same optimiser path on any core count.
            with threadpool_limits(limits=1, user_api="blas"):
                result = _diagnose(screened, vehicle, namespace, config, settings or AttributionSettings(), said)
        except ValueError as exc:  # Sim2RealError, or the engine's "too little data": say what the checks left
            raise Sim2RealError(
                f"{str(exc).replace(str(screened), str(bag))}; after the input checks, {inputs.summary()}"
            ) from exc
    result.bag, result.inputs, result.seconds = str(bag), inputs, time.perf_counter() - started
    if where:
        result.notes.insert(
            0,
            f"the bag has time gaps: {where} analysed ({inputs.why}; "
            + "; ".join(f"{i + 1}: {s}" for i, s in enumerate(inputs.segments))
            + "); choose another with --segment",
        )
    if inputs.rejected:
        result.notes.insert(0, f"{sum(inputs.rejected.values())} input messages rejected by the input checks")
    return result


def _diagnose(
    bag: Path,
    vehicle: str,
    namespace: str | None,
    config: str | Path | None,
    settings: AttributionSettings,
    progress: Callable[[str], None],
) -> Diagnosis:
    """:func:`diagnose` on a bag whose inputs passed the checks."""
    started = time.perf_counter()
    say = progress

    nis: NisReport | None = None
    notes: list[str] = []
    # Tolerances of the uncertain nominal parameters (config section /**/sim2real): fitted as nuisance.
    tolerance_values = tolerances(vehicle, config)
    if vehicle in ("quarter_car", "lrv"):
        from terrain_estimation.tools.estimate import estimate_bag, topic_name
        from terrain_estimation.vehicles import estimator_parameters, get_vehicle

        # Read the bag first (a missing topic is named before anything runs), then the estimator.
        model = build_model(bag, vehicle, config=config, namespace=namespace, progress=progress, k_s=1.0)
        entry = get_vehicle(vehicle)
        ns = namespace if namespace is not None else entry.namespace
        values = estimator_parameters(entry, config)
        say("running the estimator over the bag (innovations; starting k_s of the replay)")
        run = estimate_bag(bag, vehicle, namespace=ns, config=config)
        estimates = run.messages(topic_name(ns, "soil_stiffness"))
        nis = _nis_report(estimates, 2 if vehicle == "quarter_car" else 1, float(values["diagnostics.nis_probability"]))
        good = [m for m in estimates if m.converged and math.isfinite(float(m.k_s)) and float(m.k_s) > 0]
        if good:
            k_s = float(good[-1].k_s)
        elif estimates and math.isfinite(float(estimates[-1].k_s)) and float(estimates[-1].k_s) > 0:
            k_s = float(estimates[-1].k_s)
            notes.append("the estimator never converged on this bag; its last k_s only starts the replay's fit")
        else:
            raise Sim2RealError(
                f"the estimator produced no usable {topic_name(ns, 'soil_stiffness')} estimate on {bag}"
            )
        model.with_k_s(k_s)  # type: ignore[attr-defined]
        model = with_tolerances(model, tolerance_values)
    else:
        extra: dict[str, Any] = {}
        names = nuisance_names(tolerance_values)
        if vehicle in ("skid_steer", "rover") and names:
            extra["nuisance"] = names  # the replay fits them; their priors come from the tolerances
        model = build_model(bag, vehicle, config=config, namespace=namespace, progress=progress, **extra)
        model = with_tolerances(model, tolerance_values)
    report = attribute(model, settings, progress=progress)
    say("tabulating where the fitted nominal model disagrees")
    where = where_table(model, report.series["nominal"], settings.where)
    if nis is not None and nis.updates and not nis.in_band:
        where.gaps.append(
            f"estimator NIS: mean {nis.mean:.2f} outside its χ² band "
            f"[{nis.band[0]:.2f}, {nis.band[1]:.2f}] (dim {nis.dim})"
        )
    duration = max(float(np.asarray(model.times[c.name])[-1]) for c in model.channels) - min(
        float(np.asarray(model.times[c.name])[0]) for c in model.channels
    )
    return Diagnosis(
        bag=str(bag),
        vehicle=vehicle,
        duration=duration,
        where=where,
        nis=nis,
        attribution=report,
        seconds=time.perf_counter() - started,
        notes=notes,
        model=model,
    )
