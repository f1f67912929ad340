"""Soil-change detection for the soil-stiffness estimator: a CUSUM armed from the start, an innovation-sized re-open.

The soil-stiffness filter (:mod:`terrain_estimation.estimators.soil_stiffness`)
carries the stiffness as a slow random walk (``ln k_s`` or ``k_tot``). When the
vehicle rolls onto another soil the true stiffness jumps, and a random walk
sized for a constant soil would need seconds (ISO D) to tens of seconds (ISO B)
to walk there. :class:`SoilChangeDetector` watches every accepted update, says
when the stiffness has jumped, and sizes the re-open of the stiffness variance
from what the innovations say about the size of the jump.

**The statistic.** Each accepted update moves the stiffness state by
``Δŝ_k = W_s ν_k`` (the stiffness row of the gain times the innovation). For a
consistent filter ``ν_k`` is white with covariance ``S_k``, so ``Δŝ_k`` is
white with variance ``W_s S_k W_sᵀ = P⁻_ss − P⁺_ss`` and

    ``e_k = Δŝ_k / √(P⁻_ss − P⁺_ss)  ~ N(0, 1)``

is the whitened innovation ``S_k^{-1/2} ν_k`` projected on the one direction
a stiffness change moves it in. It needs nothing from the filter but the prior
and posterior mean and variance of the stiffness state, so it works for every
filter of the estimator. After a jump ``δ`` the corrections keep one sign:
``e_k`` acquires a mean ``≈ δ √I_k`` (``I_k`` the information one update
carries about the stiffness), whatever the filter's current variance is. This
is why the detector is **armed from the first update**, not once the estimate
has converged: on a smooth road (ISO B) the filter never reaches a tight
variance, but the corrections after a change are still one-signed.

**The test.** A two-sided CUSUM (Page 1954) on ``e_k`` clipped to
``±clip``: ``g⁺ ← max(0, g⁺ + e_k − ν)``, ``g⁻ ← max(0, g⁻ − e_k − ν)``,
alarm when either exceeds ``h``; both restart from 0 after an alarm. The clip
(default 5σ) bounds what a single outlier (a glitch of the IMU or of the
profile) can add to ``(clip − ν)``, so an alarm needs at least
``h/(clip − ν)`` one-signed steps. For a white N(0, 1) input the average run
length to a false alarm of one side is ``ARL₀ ≈ (e^{2νb} − 2νb − 1)/(2ν²)``
with ``b = h + 1.166`` (Siegmund): ν = 0.5, h = 20 gives ≈ 3·10⁹ steps
(≈ 9·10³ h at 100 Hz). The real ``e_k`` are neither exactly unit nor white
(the road between the samples, the profile noise, the start transient), so
the false-alarm rate is *measured* on long no-change runs
(:mod:`terrain_analysis.tools.reproduce_qc_change`, ``make reproduce-qc``),
not taken from the formula. The detection delay is ``≈ h/(μ − ν)`` steps for
a mean shift ``μ`` of ``e_k``.

**The size of the jump (re-open).** From one update alone, the stiffness
marginal behaves as if the filter had measured the stiffness directly, with
variance ``r_k = P⁻P⁺/(P⁻ − P⁺)``; the measured value implied by the
correction is ``y_k = ŝ⁻_k + Δŝ_k P⁻/(P⁻ − P⁺)`` (the scalar Kalman update
solved for its measurement). Over the CUSUM excursion that raises the alarm
(since that side last left 0, when the filter stood at ``s₀``) the onset is
taken where the generalised likelihood ratio of a step in the ``y_k`` is
largest, ``j* = argmax_j (Σ_{k≥j} (y_k − s₀)/r_k)² / Σ_{k≥j} 1/r_k`` (the
excursion usually starts with a few noise steps before the change), and the
information-weighted mean ``ŝ* = Σ_{k≥j*} y_k/r_k / Σ_{k≥j*} 1/r_k``
estimates the new soil's stiffness; ``d = ŝ* − ŝ⁺`` is the jump still to be
made. On an alarm the stiffness variance grows by ``σ_r²`` with

    ``σ_r = min(max(scale · |d|, σ_min), σ_max)``

around the mean moved by ``d`` (the estimator's ``change_jump_gain``, the
GLR correction of Willsky and Jones, moves it by at most ``σ_max``).
``σ_max``, the initial uncertainty of the stiffness state, caps a wild
estimate; ``σ_min`` keeps a floor. The estimate is a linearisation at the
old soil and rests on the few updates of the excursion: on the LETE sand →
Upland sandy loam change (``ln k_s`` jumps by −2.35) it ranged over −1.8 …
−9 in development runs (the slope ``∂k_tot/∂ln k_s`` is small near
``k_tot → k_series``), which the cap holds, and on Upland → Graneville
(+1.09) over 0.3 … 1.4. A re-open of the full ``|d|`` around the moved mean
let the filter overshoot to a k_s several times too large for a few updates
(the cubature points then span a factor e^{±2.2} of k_s); half of it
(``scale = 0.5``, the estimator's default), with the motion states'
variances re-opened as well (the estimator does that), gave the smallest
Table 4 errors on development seeds. A fixed 0.7 in ``ln k_s`` without a
move left the LETE → Upland change a 3.4σ event.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from terrain_estimation.checks import check_non_negative, check_positive

__all__ = ["ChangeAlarm", "SoilChangeDetector", "DEFAULT_CLIP"]

DEFAULT_CLIP = 20.0
"""Clip (σ) of the standardised correction before the CUSUM (bounds one outlier's weight)."""

_MAX_EVIDENCE = 2000
"""Most recent updates of an excursion kept for the jump estimate (20 s at 100 Hz)."""

_MIN_REL_GAIN = 1e-9
"""Updates whose variance reduction ``(P⁻ − P⁺)/P⁻`` is below this carry no information and are skipped."""


@dataclass(frozen=True)
class ChangeAlarm:
    """What a soil-change alarm says.

    Attributes:
        direction: +1 the stiffness state rose, −1 it fell.
        jump: innovation-implied jump still to be made, ``ŝ* − ŝ⁺`` (state units).
        jump_std: standard deviation of that estimate (state units).
        reopen_std: the standard deviation added to the stiffness state.
        run_length: updates in the CUSUM excursion that raised the alarm.
    """

    direction: int
    jump: float
    jump_std: float
    reopen_std: float
    run_length: int


class _Side:
    """One side of the two-sided CUSUM and the evidence gathered over its excursion."""

    __slots__ = ("g", "n", "s0", "w", "y")

    def __init__(self) -> None:
        self.g = 0.0
        self.n = 0
        self.s0 = 0.0
        self.w: deque[float] = deque(maxlen=_MAX_EVIDENCE)
        self.y: deque[float] = deque(maxlen=_MAX_EVIDENCE)

    def clear(self) -> None:
        self.g = 0.0
        self.n = 0
        self.w.clear()
        self.y.clear()

    def add(self, step: float, w: float, y: float, x_prior: float) -> None:
        g = self.g + step
        if g <= 0.0:
            self.clear()
            return
        if self.n == 0:
            self.s0 = x_prior  # the filter's estimate when the excursion began
        self.g = g
        self.n += 1
        self.w.append(w)
        self.y.append(y)

    def jump_estimate(self) -> tuple[float, float]:
        """``(ŝ*, std)``: the new level after the most likely onset inside the excursion (GLR)."""
        w = np.asarray(self.w, dtype=float)
        dy = np.asarray(self.y, dtype=float) - self.s0
        # Suffix sums: the evidence from each candidate onset j to now.
        sw = np.cumsum(w[::-1])[::-1]
        sy = np.cumsum((w * dy)[::-1])[::-1]
        j = int(np.argmax(sy * sy / sw))
        return self.s0 + float(sy[j] / sw[j]), float(1.0 / math.sqrt(sw[j]))


class SoilChangeDetector:
    """CUSUM on the whitened stiffness corrections, armed from the start; sizes the re-open (module docstring).

    Args:
        drift: ν, the CUSUM allowance per update (σ, ≥ 0).
        threshold: h, the alarm level (σ, > 0).
        reopen_scale: the re-open std is this multiple of the implied jump (> 0).
        reopen_min_std: floor of the re-open std (state units, ≥ 0; 0 with a
            zero ``reopen_scale`` disables the re-open).
        reopen_max_std: cap of the re-open std (state units, > 0).
        clip: standardised corrections are clipped to ±clip (σ, > drift).
    """

    def __init__(
        self,
        drift: float = 0.5,
        threshold: float = 20.0,
        *,
        reopen_scale: float = 0.5,
        reopen_min_std: float = 0.0,
        reopen_max_std: float = math.inf,
        clip: float = DEFAULT_CLIP,
    ) -> None:
        owner = type(self).__name__
        check_non_negative(owner, "drift", drift)
        check_positive(owner, "threshold", threshold)
        check_non_negative(owner, "reopen_scale", reopen_scale)
        check_non_negative(owner, "reopen_min_std", reopen_min_std)
        if not (reopen_max_std > 0.0 and reopen_max_std >= reopen_min_std):
            raise ValueError(f"reopen_max_std must be > 0 and >= reopen_min_std, got {reopen_max_std}")
        if not (math.isfinite(clip) and clip > drift):
            raise ValueError(f"clip must be finite and > drift, got {clip}")
        self.drift = float(drift)
        self.threshold = float(threshold)
        self.reopen_scale = float(reopen_scale)
        self.reopen_min_std = float(reopen_min_std)
        self.reopen_max_std = float(reopen_max_std)
        self.clip = float(clip)
        self._pos = _Side()
        self._neg = _Side()
        self.last_e = 0.0

    def reset(self) -> None:
        """Restart both CUSUM statistics from 0 and forget the gathered evidence."""
        self._pos.clear()
        self._neg.clear()
        self.last_e = 0.0

    @property
    def statistic(self) -> float:
        """``max(g⁺, g⁻)`` (σ)."""
        return max(self._pos.g, self._neg.g)

    def update(self, x_prior: float, var_prior: float, x_post: float, var_post: float) -> ChangeAlarm | None:
        """Add one accepted update of the stiffness state; the alarm, or None.

        Args:
            x_prior: prior mean ŝ⁻ of the stiffness state.
            var_prior: its prior variance P⁻.
            x_post: posterior mean ŝ⁺ (after any projection into the state's range).
            var_post: posterior variance P⁺.

        An update that carries no information about the stiffness (P⁺ ≈ P⁻)
        or has a non-finite argument is ignored (returns None).
        """
        if not (
            math.isfinite(x_prior) and math.isfinite(var_prior) and math.isfinite(x_post) and math.isfinite(var_post)
        ):
            return None
        dvar = var_prior - var_post
        if not (var_post > 0.0 and dvar > _MIN_REL_GAIN * var_prior):
            return None
        dx = x_post - x_prior
        e = dx / math.sqrt(dvar)
        self.last_e = e
        ec = min(max(e, -self.clip), self.clip)
        w = dvar / (var_prior * var_post)  # 1/r_k
        y = x_prior + dx * var_prior / dvar  # implied direct measurement of the stiffness
        self._pos.add(ec - self.drift, w, y, x_prior)
        self._neg.add(-ec - self.drift, w, y, x_prior)
        for side, direction in ((self._pos, 1), (self._neg, -1)):
            if side.g > self.threshold:
                alarm = self._alarm(side, direction, x_post)
                self.reset()
                return alarm
        return None

    def _alarm(self, side: _Side, direction: int, x_post: float) -> ChangeAlarm:
        level, jump_std = side.jump_estimate()
        jump = level - x_post
        size = self.reopen_scale * abs(jump) if math.isfinite(jump) else self.reopen_max_std
        reopen = min(max(size, self.reopen_min_std), self.reopen_max_std)
        return ChangeAlarm(direction, jump if math.isfinite(jump) else 0.0, jump_std, reopen, side.n)
