"""What a vehicle gives the sim-to-real attribution engine: a replay model of one bag.

The engine (:mod:`terrain_analysis.sim2real.attribution`) is generic. For
each vehicle a *replay model* is built from one bag (and the vehicle's config):
it holds the measured channels and can predict them with the nominal model or
with any catalogue effect added, for given parameter values. The engine fits
the parameters on a training part of the bag, scores them on a held-out part,
ranks the effects, tries pairs and computes the shrinkage of the gap.

A replay model must be cheap to evaluate: the engine calls :meth:`ReplayModel.predict`
a few hundred times per bag (least squares with a numerical Jacobian, several
starts, every effect, a few pairs), and a 60 s bag must be diagnosed in under
a minute on 2 cores.

Conventions
    * Every channel is a 1-D array of samples at its own times (s, from the
      start of the bag), fixed when the model is built. :meth:`predict` returns
      predictions at exactly those times, same shape, finite.
    * ``noise_std`` of a channel is the noise budget σ: what the residual
      measured − predicted would be with a perfect model (sensor noise plus
      what input noise does through the replay). Residuals are compared in
      units of σ, so channels of different units add up.
    * *Nuisance* parameters (e.g. the quarter car's ln k_s, which a real bag
      does not give) are fitted in every model, the nominal one included, so
      that an effect is never credited with what the nuisance explains.
    * A candidate effect has zero or more continuous parameters. Zero: a
      switch (e.g. unilateral wheel contact) that is simply turned on.
    * ``warmup`` seconds at the start are left out of every fit and score
      (replays start from rest or from a guessed state).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "Candidate",
    "Channel",
    "FitParameter",
    "ReplayModel",
    "StampOrigin",
    "candidates_from_catalogue",
]

FloatArray = NDArray[np.float64]


class StampOrigin:
    """Header stamps as float seconds from the first stamp seen, the difference taken in integer nanoseconds.

    A float64 resolves an epoch stamp (about 1.7e9 s) only to 2.4e-7 s: sample
    periods computed from such floats are off by up to 2e-4 of a 1 ms period,
    and a replay whose time base is built from them drifts by milliseconds
    over a bag (against a 25 m/s² ride signal a 1 ms drift is a gap of its
    own). Every replay reads its stamps through one of these.
    """

    def __init__(self) -> None:
        self.origin_ns: int | None = None

    def __call__(self, msg: Any) -> float:
        ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        if self.origin_ns is None:
            self.origin_ns = ns
        return (ns - self.origin_ns) * 1e-9

    @property
    def origin(self) -> float:
        """The origin in seconds of the bag clock (0 before the first stamp)."""
        return 0.0 if self.origin_ns is None else self.origin_ns * 1e-9


@dataclass(frozen=True)
class FitParameter:
    """A continuous parameter the engine fits.

    Attributes:
        name: Unique within its effect (for nuisance parameters: among them).
        unit: Physical unit ("–" dimensionless).
        off: Value of the nominal model (the effect is absent at this value);
            for a nuisance parameter: the starting value.
        bounds: (low, high), finite, containing ``off``.
        scale: Typical size of a change (the optimiser's variable scaling and
            the offsets of its extra starting points).
        prior_std: Optional. A Gaussian prior of this standard deviation about
            ``off``: the fit adds the term ((x − off) / prior_std)² to the
            training χ². The *nominal tolerance* of an uncertain nominal
            parameter (a mass, a rolling resistance): within it a mismatch is
            fitted as a nuisance, not reported as a gap (issue 22, item 2).
            None (default): no prior, the fit is bounded only.
        plausible: Optional (low, high) physically plausible range, inside or
            equal to ``bounds``. A best explanation that needs a value outside
            it (or at a bound of ``bounds`` other than ``off``) is reported as a
            structure gap, not as the effect (issue 22, item 3). None: the
            bounds are the plausible range.
        physical_bounds: The fit range's ends are the parameter's physical
            limits, each a valid model (a shape parameter running from one
            law of its family to another), not a search limit: a best fit at
            either end is no sign of a structure gap. Default False.
    """

    name: str
    unit: str
    off: float
    bounds: tuple[float, float]
    scale: float
    prior_std: float | None = None
    plausible: tuple[float, float] | None = None
    physical_bounds: bool = False

    def __post_init__(self) -> None:
        lo, hi = (float(v) for v in self.bounds)
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi and lo <= self.off <= hi):
            raise ValueError(f"FitParameter {self.name!r}: need finite low < high around off, got {self}")
        if not (self.scale > 0.0 and np.isfinite(self.scale)):
            raise ValueError(f"FitParameter {self.name!r}: scale must be positive, got {self.scale}")
        object.__setattr__(self, "bounds", (lo, hi))
        if self.prior_std is not None:
            if not (float(self.prior_std) > 0.0 and np.isfinite(float(self.prior_std))):
                raise ValueError(f"FitParameter {self.name!r}: prior_std must be positive, got {self.prior_std}")
            object.__setattr__(self, "prior_std", float(self.prior_std))
        if self.plausible is not None:
            a, b = (float(v) for v in self.plausible)
            if not (np.isfinite(a) and np.isfinite(b) and a < b):
                raise ValueError(f"FitParameter {self.name!r}: plausible range needs finite low < high, got {self}")
            object.__setattr__(self, "plausible", (a, b))

    @property
    def plausible_range(self) -> tuple[float, float]:
        """The plausible range (the bounds when none is stated)."""
        return self.plausible if self.plausible is not None else self.bounds


@dataclass(frozen=True)
class Candidate:
    """One effect the replay model can add to the nominal model.

    Attributes:
        name: Catalogue effect name (:data:`vehicle_sim.effects.CATALOGUE`).
        parameters: Its continuous parameters (empty: a switch).
        description: One line for the report.
        starts: Extra starting points of the fit, each ((parameter, value), ...)
            (the others at their off values): where one parameter does nothing while
            another is off (a window's shape at zero length), the fit's own
            starts, which move one parameter at a time from the nominal model,
            cannot reach that parameter's other laws. Default none.
    """

    name: str
    parameters: tuple[FitParameter, ...]
    description: str = ""
    starts: tuple[tuple[tuple[str, float], ...], ...] = ()

    @property
    def size(self) -> int:
        return len(self.parameters)


@dataclass(frozen=True)
class Channel:
    """One measured channel of a replay model.

    Attributes:
        name: Short name (``body``, ``yaw_rate``, ``load_front`` ...).
        topic: Bag topic (and field) it comes from, for the report.
        unit: Unit of its samples.
        noise_std: Noise budget σ (same unit), > 0.
    """

    name: str
    topic: str
    unit: str
    noise_std: float


@runtime_checkable
class ReplayModel(Protocol):
    """One bag, replayed through one vehicle's nominal model plus effects.

    Attributes:
        vehicle: Vehicle key (``quarter_car``, ``lrv``, ``skid_steer``, ``rover``).
        channels: The measured channels.
        times: Channel name → sample times (s from the bag start), increasing.
        measured: Channel name → measured samples.
        nuisance: Parameters fitted in every model.
        candidates: Effect name → :class:`Candidate`.
        regimes: Regime name (e.g. ``speed (m/s)``) → (times, values): operating
            variables the "where" table bins the residuals by.
        warmup: Seconds at the start left out of fits and scores.
        notes: Anything the report should say about how the model was built.
    """

    vehicle: str
    channels: Sequence[Channel]
    times: Mapping[str, FloatArray]
    measured: Mapping[str, FloatArray]
    nuisance: Sequence[FitParameter]
    candidates: Mapping[str, Candidate]
    regimes: Mapping[str, tuple[FloatArray, FloatArray]]
    warmup: float
    notes: list[str]

    def predict(
        self,
        effects: Mapping[str, Mapping[str, float]],
        nuisance: Mapping[str, float],
    ) -> dict[str, FloatArray]:
        """Predicted channels with ``effects`` ({effect: {parameter: value}}) added.

        ``{}`` is the nominal model. A switch effect is named with ``{}``.
        Must return every channel, at ``times[name]``, finite values.
        """
        ...


# Optional attribute of a replay model, used when present:
#
#     valid: Mapping[str, BoolArray]
#
# per channel, the samples inside the model's domain (same shape as times[name]);
# the others (e.g. a rover sliding backward, outside a quasi-static replay) are
# left out of every fit, score and where-test, like the warm-up (usable_mask).
#
# Optional method of a replay model, used when present:
#
#     def noise_std_for(self, effects, nuisance) -> dict[str, float]
#
# the noise budget σ per channel for the model with ``effects`` (when an effect
# feeds an input's noise through to a channel, e.g. a damper on the measured
# road rate). The engine fits with the fixed ``Channel.noise_std`` and uses
# this only in the noise tests ("no significant gap", "explained").
#
# Optional attributes of a replay model, used when present (issue 22):
#
#     unidentifiable: Mapping[str, str]
#
# effect → the measurement that would make it identifiable, for effects this replay cannot tell
# apart from its inputs whatever the bag (the rover's path undulation: a terrain measurement);
# reported as "not identifiable from this bag".
#
#     physics: Mapping[str, str]
#
# effect → its kind of physics ("sensor", "vehicle", ...; default from the name,
# attribution.SENSOR_WORDS): two effects of different kinds that explain a bag equally, neither
# to the noise, are a structure gap.
#
# Optional fields of FitParameter (defaults keep older replay models unchanged): ``prior_std``
# (a nominal tolerance, fitted as a Gaussian prior) and ``plausible`` (the physically plausible
# range; a best fit outside it is a structure gap). candidates_from_catalogue() takes the latter
# from the catalogue's EffectParameter when it states one (``physical_range``).


def usable_mask(model: Any, name: str, t0: float) -> NDArray[np.bool_]:
    """Samples of channel ``name`` that fits, scores and where-tests use: after the warm-up
    (``t0 + model.warmup``) and inside the model's domain (its optional ``valid`` masks)."""
    t = np.asarray(model.times[name], dtype=float)
    use: NDArray[np.bool_] = t >= t0 + float(model.warmup)
    valid = getattr(model, "valid", None)
    if valid is not None and name in valid:
        use = use & np.asarray(valid[name], dtype=bool)
    return use


def _plausible(p: Any) -> tuple[float, float] | None:
    """The catalogue parameter's physically plausible range, clipped to its fit range (None: not stated)."""
    for name in ("physical_range", "plausible", "plausible_range"):
        value = getattr(p, name, None)
        if value is None:
            continue
        try:
            lo, hi = (float(v) for v in value)
        except (TypeError, ValueError):
            continue
        lo, hi = max(lo, float(p.fit_range[0])), min(hi, float(p.fit_range[1]))
        if (lo, hi) == tuple(float(v) for v in p.fit_range):
            return None  # the fit range itself: nothing beyond the bounds
        if np.isfinite(lo) and np.isfinite(hi) and lo < hi:
            return (lo, hi)
    return None


def candidates_from_catalogue(
    vehicle: str,
    only: Sequence[str] | None = None,
    exclude: Sequence[str] = (),
) -> dict[str, Candidate]:
    """Candidates for ``vehicle`` from :data:`vehicle_sim.effects.CATALOGUE`.

    Fit bounds are the catalogue's fit ranges, the scale its typical deviation
    from the off value, the plausible range the catalogue's when it states one;
    switch parameters give a zero-parameter candidate.
    """
    from vehicle_sim.effects import CATALOGUE

    out: dict[str, Candidate] = {}
    for name, effect in CATALOGUE[vehicle].items():
        if (only is not None and name not in only) or name in exclude:
            continue
        params = []
        for p in effect.parameters:
            if p.switch:
                continue
            scale = abs(p.typical - p.off) or 0.1 * (p.fit_range[1] - p.fit_range[0])
            params.append(
                FitParameter(p.name, p.unit, float(p.off), p.fit_range, float(scale), plausible=_plausible(p))
            )
        out[name] = Candidate(name, tuple(params), effect.description)
    return out
