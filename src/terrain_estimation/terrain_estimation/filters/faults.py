"""Filter faults: divergence detection and recovery from the last good estimate.

Innovation gating (a Mahalanobis bound on the NIS) is a parameter of every
filter (``gate_threshold``, :func:`~.base.nis_gate`): it protects the state
from *one* bad measurement. This module protects a *run* from a filter that
has gone wrong, whatever the cause (a wrong noise model, a huge unmodelled
disturbance, a fault of the model, rounding):

* **Divergence detection** (:class:`DivergenceMonitor`), one observation per
  filter step, a divergence as soon as any of:

  - a non-finite mean or covariance, a negative variance, or a square-root
    factor that is not lower-triangular with a non-negative finite diagonal
    (:func:`sqrt_factor_fault`);
  - a covariance blow-up: a variance above ``max_variance_growth`` times its
    reference (the covariance the monitor was started with, or the filter
    last re-initialised with by :meth:`DivergenceMonitor.recover`), or above
    ``max_variance``;
  - the mean NIS over the last ``window`` accepted updates outside its
    two-sided χ² band (probability ``probability``) for ``persistence``
    consecutive updates. The sum of ``N`` independent NIS values of
    dimensions ``p_i`` is χ² with ``Σ p_i`` degrees of freedom, so the band
    of the mean is ``[χ²((1−P)/2, Σp)/N, χ²((1+P)/2, Σp)/N]`` (the band the
    node diagnostics use, :mod:`terrain_estimation.ros.framework`). Above
    the band, the filter is overconfident or its model wrong; below it, its
    covariance is far too large (``check_low`` switches this side off);
  - ``max_rejections`` consecutive measurements rejected by the gate (gate
    lock-out: a diverged filter rejects every measurement and never comes
    back on its own).

* **Recovery** (:meth:`DivergenceMonitor.recover`): re-initialisation from the
  last good estimate, i.e. its mean with the reference covariance
  (``reinit_covariance="initial"``, re-opens the uncertainty so the filter
  re-converges) or with its own covariance (``"last_good"``), times
  ``reinit_inflation`` (the last good estimate is at least ``persistence``
  updates old: where the reference covariance is tight, e.g. pinned by the
  measurements of a fresh start, it would hold the filter there). The last good
  estimate is the newest state observed while the window of NIS values was
  full and inside its band (and nothing else was wrong), or the state the
  monitor was started with.

* **Status**: :attr:`DivergenceMonitor.fault` holds the reason from the
  divergence until the recovered filter has filled a new window inside its
  band (a node shows ERROR over that span, then OK).

:func:`guarded_step` runs one predict + update of any filter of this package
under a monitor: a filter exception (non-finite model output, a broken
factor) counts as a divergence, a non-finite measurement is skipped, and the
returned state is always finite. An estimator that runs its own steps hands
each step's outcome to :meth:`DivergenceMonitor.supervise` (fail or observe,
then recover), as the soil-stiffness, skid-steer and rover estimators do.
"""

# ruff: noqa: N803, N806 - matrix symbols (P, S, Q, R, W, ...) of the papers

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Literal

import numpy as np

from .base import Array, SqrtGaussianState, UpdateInfo
from .chi2 import chi2_ppf

__all__ = [
    "DivergenceConfig",
    "DivergenceCheck",
    "DivergenceMonitor",
    "guarded_step",
    "nis_band",
    "sqrt_factor_fault",
]


@dataclass(frozen=True, kw_only=True)
class DivergenceConfig:
    """Settings of :class:`DivergenceMonitor` (see the module docstring).

    Attributes:
        window: accepted-update NIS values in the windowed mean, ``[1, 10000]``
            (default 20). Checked only once the window is full.
        probability: two-sided probability of the χ² band of the windowed mean
            NIS, in ``(0, 1)`` (default 0.999: a consistent filter is outside
            the band at ≈ 0.1 % of the checks).
        persistence: consecutive out-of-band checks (one per accepted update)
            that make a divergence, ``[1, 10000]`` (default 10).
        check_low: also flag a mean NIS below the band (covariance too large).
        max_rejections: consecutive gate rejections that make a divergence
            (gate lock-out), ``≥ 1``; None disables (default 10).
        max_variance_growth: a variance above this multiple of its reference
            (the diagonal of the covariance at :meth:`DivergenceMonitor.start`,
            or of the re-initialised one after :meth:`DivergenceMonitor.recover`
            where larger) is a blow-up; ``> 1``, None disables (default 1e6: a standard
            deviation 1000 times the initial one). States with a zero
            reference variance are covered by ``max_variance`` only.
        max_variance: absolute bound on every variance (state units²); None
            disables (default).
        reinit_covariance: covariance of the re-initialised state:
            ``"initial"`` (the reference covariance) or ``"last_good"``.
        reinit_inflation: factor (≥ 1, default 1) on that covariance.
    """

    window: int = 20
    probability: float = 0.999
    persistence: int = 10
    check_low: bool = True
    max_rejections: int | None = 10
    max_variance_growth: float | None = 1e6
    max_variance: float | None = None
    reinit_covariance: Literal["initial", "last_good"] = "initial"
    reinit_inflation: float = 1.0

    def __post_init__(self) -> None:
        for name in ("window", "persistence"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 10_000:
                raise ValueError(f"{name} must be an integer in [1, 10000], got {value!r}")
        if not (math.isfinite(self.probability) and 0.0 < self.probability < 1.0):
            raise ValueError(f"probability must be in (0, 1), got {self.probability}")
        if self.max_rejections is not None and (
            isinstance(self.max_rejections, bool) or not isinstance(self.max_rejections, int) or self.max_rejections < 1
        ):
            raise ValueError(f"max_rejections must be None or an integer >= 1, got {self.max_rejections!r}")
        g = self.max_variance_growth
        if g is not None and not (math.isfinite(g) and g > 1.0):
            raise ValueError(f"max_variance_growth must be None or finite and > 1, got {g}")
        v = self.max_variance
        if v is not None and not (math.isfinite(v) and v > 0.0):
            raise ValueError(f"max_variance must be None or finite and > 0, got {v}")
        r = self.reinit_inflation
        if isinstance(r, bool) or not isinstance(r, int | float) or not (math.isfinite(r) and r >= 1.0):
            raise ValueError(f"reinit_inflation must be finite and >= 1, got {r!r}")
        if self.reinit_covariance not in ("initial", "last_good"):
            raise ValueError(f"reinit_covariance must be 'initial' or 'last_good', got {self.reinit_covariance!r}")


@dataclass(frozen=True)
class DivergenceCheck:
    """What one :meth:`DivergenceMonitor.observe` found.

    Attributes:
        diverged: this observation is a divergence (call
            :meth:`DivergenceMonitor.recover`).
        reason: why, empty when not diverged.
        mean_nis: windowed mean NIS (NaN until the window is full).
        band: its χ² band ``(low, high)`` (NaN until the window is full).
        good: the observed state became the last good estimate.
    """

    diverged: bool
    reason: str = ""
    mean_nis: float = math.nan
    band: tuple[float, float] = (math.nan, math.nan)
    good: bool = False


@lru_cache(maxsize=256)
def nis_band(dof: int, count: int, probability: float) -> tuple[float, float]:
    """Two-sided χ² band of the mean of ``count`` NIS values totalling ``dof`` degrees of freedom."""
    lo = chi2_ppf(0.5 * (1.0 - probability), dof) / count
    hi = chi2_ppf(0.5 * (1.0 + probability), dof) / count
    return lo, hi


def sqrt_factor_fault(S: Any) -> str:
    """Why ``S`` is not a valid square-root factor, or ``""`` if it is.

    Valid: a finite square ``(n, n)`` array, exactly zero above the diagonal,
    with a non-negative diagonal (what :func:`~.sigma_points.tria` returns).
    """
    S = np.asarray(S, dtype=float)
    if S.ndim != 2 or S.shape[0] != S.shape[1]:
        return f"square-root factor has shape {S.shape}, expected square"
    if not np.isfinite(S).all():
        return "square-root factor has non-finite entries"
    if np.triu(S, 1).any():
        return "square-root factor is not lower-triangular"
    d = np.diagonal(S)
    if (d < 0.0).any():
        return f"square-root factor has a negative diagonal entry ({float(d.min()):.3g})"
    return ""


def _state_fault(state: Any, ref_var: Array, cfg: DivergenceConfig) -> str:
    """Non-finite state, broken factor or covariance blow-up: the reason, or ``""``."""
    x = np.asarray(state.x, dtype=float)
    if not np.isfinite(x).all():
        return "non-finite state mean"
    if isinstance(state, SqrtGaussianState):
        reason = sqrt_factor_fault(state.S)
        if reason:
            return reason
    P = np.asarray(state.covariance, dtype=float)
    if P.shape != (x.size, x.size) or not np.isfinite(P).all():
        return "non-finite covariance"
    var = np.diagonal(P)
    if (var < 0.0).any():
        i = int(np.argmin(var))
        return f"negative variance of state {i} ({var[i]:.3g})"
    if cfg.max_variance is not None and (var > cfg.max_variance).any():
        i = int(np.argmax(var))
        return f"covariance blow-up: variance of state {i} is {var[i]:.3g} > max_variance {cfg.max_variance:.3g}"
    if cfg.max_variance_growth is not None:
        limit = cfg.max_variance_growth * ref_var
        over = (ref_var > 0.0) & (var > limit)
        if over.any():
            i = int(np.argmax(over))
            return (
                f"covariance blow-up: variance of state {i} is {var[i]:.3g} > "
                f"{cfg.max_variance_growth:.3g} x its reference {ref_var[i]:.3g}"
            )
    return ""


class DivergenceMonitor:
    """Watches one filter run for divergence and keeps the last good estimate.

    Usage (any filter of this package; :func:`guarded_step` does exactly this)::

        monitor = DivergenceMonitor(DivergenceConfig())
        state = filt.initial_state(x0, P0)
        monitor.start(state)
        ...                                   # each step:
        state = filt.predict(state, model, u, dt)
        state, info = filt.update(state, z, model, u)
        if monitor.observe(state, info).diverged:
            state = monitor.recover(filt)     # last good mean, reference covariance

    Args:
        config: the settings; None → :class:`DivergenceConfig` defaults.
    """

    def __init__(self, config: DivergenceConfig | None = None) -> None:
        self.config = config if config is not None else DivergenceConfig()
        self.divergences = 0
        self._nis: deque[tuple[float, int]] = deque(maxlen=self.config.window)
        self._out_of_band = 0
        self._rejections = 0
        self._ref_x: Array | None = None
        self._ref_P: Array | None = None
        self._ref_var: Array = np.zeros(0)
        self._last_good: Any = None
        self.fault: str | None = None

    @property
    def last_good(self) -> Any:
        """The last good state (None before :meth:`start`)."""
        return self._last_good

    def start(self, state: Any) -> None:
        """(Re)start on ``state``: it becomes the reference covariance and the last good estimate.

        Clears the NIS window, the counters of the current episode and the fault.

        Raises:
            ValueError: if ``state`` is itself non-finite or broken.
        """
        x = np.asarray(state.x, dtype=float).copy()
        P = np.asarray(state.covariance, dtype=float).copy()
        self._ref_var = np.zeros(x.size)
        reason = _state_fault(state, self._ref_var, DivergenceConfig(max_variance_growth=None))
        if reason:
            raise ValueError(f"cannot start the divergence monitor on a faulty state: {reason}")
        self._ref_x, self._ref_P = x, P
        self._ref_var = np.diagonal(P).copy()
        self._last_good = state
        self.fault = None
        self._clear_episode()

    def _clear_episode(self) -> None:
        self._nis.clear()
        self._out_of_band = 0
        self._rejections = 0

    def observe(self, state: Any, info: UpdateInfo | None = None) -> DivergenceCheck:
        """Check the state after one filter step (``info`` None for a predict-only step).

        Returns:
            The verdict. When ``diverged``, the state must not be used:
            :meth:`recover` gives the re-initialised one.

        Raises:
            RuntimeError: before :meth:`start`.
        """
        if self._ref_P is None:
            raise RuntimeError("DivergenceMonitor.observe before start()")
        cfg = self.config
        reason = _state_fault(state, self._ref_var, cfg)
        if reason:
            return self._diverge(reason)
        if info is None:
            return DivergenceCheck(diverged=False)
        if not info.accepted:
            self._rejections += 1
            if cfg.max_rejections is not None and self._rejections >= cfg.max_rejections:
                return self._diverge(f"{self._rejections} consecutive measurements rejected by the gate")
            return DivergenceCheck(diverged=False)
        self._rejections = 0
        nis = float(info.nis)
        if not math.isfinite(nis):
            return self._diverge("non-finite NIS of an accepted update")
        self._nis.append((nis, int(np.size(info.innovation))))
        if len(self._nis) < cfg.window:
            return DivergenceCheck(diverged=False)
        count = len(self._nis)
        mean = sum(v for v, _ in self._nis) / count
        dof = sum(d for _, d in self._nis)
        lo, hi = nis_band(dof, count, cfg.probability)
        if mean > hi or (cfg.check_low and mean < lo):
            self._out_of_band += 1
            if self._out_of_band >= cfg.persistence:
                side = "above" if mean > hi else "below"
                return self._diverge(
                    f"mean NIS {mean:.3g} {side} its chi-square band [{lo:.3g}, {hi:.3g}] "
                    f"for {self._out_of_band} updates",
                    mean,
                    (lo, hi),
                )
            return DivergenceCheck(diverged=False, mean_nis=mean, band=(lo, hi))
        self._out_of_band = 0
        self._last_good = state
        self.fault = None
        return DivergenceCheck(diverged=False, mean_nis=mean, band=(lo, hi), good=True)

    def fail(self, reason: str) -> DivergenceCheck:
        """Record a divergence found outside :meth:`observe` (e.g. the filter raised)."""
        if self._ref_P is None:
            raise RuntimeError("DivergenceMonitor.fail before start()")
        return self._diverge(reason)

    def _diverge(
        self, reason: str, mean: float = math.nan, band: tuple[float, float] = (math.nan, math.nan)
    ) -> DivergenceCheck:
        self.divergences += 1
        self.fault = reason
        return DivergenceCheck(diverged=True, reason=reason, mean_nis=mean, band=band)

    def recover(self, filt: Any) -> Any:
        """Re-initialise from the last good estimate: ``filt.initial_state(x_good, P)``.

        ``P`` is the reference covariance or the last good one
        (``reinit_covariance``), times ``reinit_inflation``. The NIS window restarts; :attr:`fault` stays
        set until the new window is full and inside its band.

        Args:
            filt: any filter of this package (it has ``initial_state(x0, P0)``).
        """
        if self._ref_P is None or self._last_good is None:
            raise RuntimeError("DivergenceMonitor.recover before start()")
        good = self._last_good
        x = np.asarray(good.x, dtype=float).copy()
        if self.config.reinit_covariance == "initial":
            P = self._ref_P
        else:
            P = np.asarray(good.covariance, dtype=float)
        P = 0.5 * (P + P.T) * self.config.reinit_inflation
        state = filt.initial_state(x, P)
        # Blow-up reference: the re-initialised variances, never tighter than the start's.
        self._ref_var = np.maximum(np.diagonal(self._ref_P), np.diagonal(P))
        fault = self.fault
        self._clear_episode()
        self.fault = fault
        return state

    def supervise(
        self,
        filt: Any,
        state: Any,
        info: UpdateInfo | None = None,
        *,
        failure: str | None = None,
    ) -> tuple[Any, DivergenceCheck]:
        """One filter step's outcome under the monitor: the state to keep and the verdict.

        For an estimator that runs its own steps (its own gating, noise,
        inputs) and reports what came out: :meth:`fail` when the step failed,
        else :meth:`observe`, then :meth:`recover` on a divergence.
        :func:`guarded_step` is this around a plain predict + update.

        Args:
            filt: the filter (its ``initial_state`` re-initialises on a divergence).
            state: the step's posterior (not looked at when ``failure`` is given).
            info: the update (None for a predict-only step).
            failure: why the step failed (the filter raised, ...), or None.

        Returns:
            ``(state, check)``: ``state`` itself, or the re-initialised state
            of :meth:`recover` when ``check.diverged``.
        """
        check = self.fail(failure) if failure is not None else self.observe(state, info)
        if check.diverged:
            return self.recover(filt), check
        return state, check


def guarded_step(
    filt: Any,
    monitor: DivergenceMonitor,
    state: Any,
    model: Any,
    u: Any,
    dt: float,
    z: Any = None,
) -> tuple[Any, UpdateInfo | None, DivergenceCheck]:
    """One predict (+ update when ``z`` is given) under ``monitor``; never a non-finite state.

    * a ``z`` with a non-finite entry (or of the wrong size) is skipped: the
      step is predict-only (a broken sensor sample is not a filter fault);
    * a filter exception (``ValueError``/``LinAlgError``/``FloatingPointError``:
      non-finite model output, a broken factor) and every divergence of
      :meth:`DivergenceMonitor.observe` return :meth:`DivergenceMonitor.recover`.

    Returns:
        ``(state, info, check)``; ``info`` is None when no update ran.
    """
    info: UpdateInfo | None = None
    zv = None
    if z is not None:
        zv = np.asarray(z, dtype=float)
        if zv.shape != (model.measurement_dim,) or not np.isfinite(zv).all():
            zv = None
    try:
        with np.errstate(all="ignore"):
            new = filt.predict(state, model, u, dt)
            if zv is not None:
                new, info = filt.update(new, zv, model, u)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
        state, check = monitor.supervise(filt, state, failure=f"filter step failed: {exc}")
        return state, None, check
    state, check = monitor.supervise(filt, new, info)
    return state, info, check
