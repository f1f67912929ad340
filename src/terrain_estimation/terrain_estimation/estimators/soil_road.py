"""The road under the tire, reconstructed from the measured profile for each filter step (MODELS.md A.10).

:class:`ProfileRoad` is the part of
:class:`~terrain_estimation.estimators.soil_stiffness.SoilStiffnessEstimator`
that holds the buffered profile samples (stamps, elevations, distances) and
turns them into a step's input: the elevation on the sub-step grid (and the
largest gap in it), ḣ at the measurement time for a model with feed-through,
and the covariance ``Σ_ε`` of the errors of both, which the filter's
measurement noise takes in.

**Sub-step input (MODELS.md A.10).** The step ``[t_prev, t]`` is cut into
``N = ceil(dt · substep_rate_hz)`` equal sub-steps; the elevation is
evaluated on that grid by linear interpolation *in time* between the buffered
profile samples, and ``ḣ_j = (h(τ_{j+1}) − h(τ_j))/δ``. Holding ḣ_j over a
sub-step reproduces exactly the piecewise-linear road through the grid
points, so:

* a profile rate that is not a multiple of the filter rate (e.g. 750 Hz, or
  jittered stamps) needs nothing special: the samples are interpolated onto
  the grid wherever they fall, and the sub-step rate can differ from the
  profile rate. A profile slower than the grid gives the piecewise-linear
  road through its own samples (at 100 Hz that is the +2 % k_tot bias regime
  of A.10.1);
* noise on h does not accumulate: the ḣ_j of a step sum to
  ``h(t) − h(t_prev)``, so the elevation noise telescopes and enters the
  ``y − h`` state as the difference of two measured elevations. It still
  biases k_tot *downwards* (errors in the regressor: ÿ2 ∝ k_tot (y2 − h)).
  Measured on the end-to-end case (Graneville loam, ISO D-like road,
  10 m/s, white noise σ_h on a 1 kHz profile), mean k_s error over 2–12 s:
  σ_h = 0.1 mm +0.1 %, 0.5 mm −2.6 %, 1 mm −11 % (noise-free: +0.1 %).
  Adding 2σ_h² to the process noise of ``y − h`` made it worse (−15 % at
  0.5 mm), so the model does not do it. The remedy is
  ``profile_smoothing_s = w > 0``: each grid elevation is then the constant
  term of a local quadratic least-squares fit to the samples within ±w/2
  (Savitzky–Golay), which keeps the road's passband flat (a boxcar of the
  same width biased k_s by +2.4 % at w = 5 ms with no noise) and lowers the
  noise. Measured: no noise, w = 10 / 20 ms → +0.2 / +1.3 %; σ_h = 0.5 mm,
  w = 10 ms → −0.9 %; σ_h = 1 mm, w = 20 ms → −1.0 %. The price is a delay
  of w/2 per step (the profile must cover the window). Those numbers are for
  road content up to 3 cycles/m; on the simulator's ISO D road (content up to
  10 cycles/m, i.e. 100 Hz at 10 m/s; mean k_s error over 5–20 s, 12 seeds)
  no noise: +0.4 % for w = 0 and 5 ms, +2.0 % for 10 ms, +6.7 % for 20 ms;
  σ_h = 0.5 mm: −2.5 % (w = 0), −1.0 % (w = 5 ms). Hence the default w = 0
  (the contract's σ_h = 0.1 mm costs ≈ −0.1 %); use 5 ms at 0.5 mm there.

**Profile noise and the measurement.** The profile is an input, measured
with noise; the filter states live relative to the *reconstructed* road, so
profile errors reach the predicted accelerations in two ways, to first
order ``δz = C(x) B ε_h + D ε_ḣ``
(:meth:`~terrain_estimation.models.quarter_car.LRVModel.profile_error_gains`):

* ``ε_h``, the error of the reconstructed elevation at the measurement time
  (the ``y − h`` state is off by it). Gain ``k_tot/m_ns`` ≈ 3000 s⁻² on ÿ2
  of the quarter car (0.3 m/s² per 0.1 mm, against √R = 0.71 m/s²), and
  ``k_tot/m_s − (c/m_s)²`` ≈ −270 s⁻² on the LRV (relative damper).
* ``ε_ḣ``, the error of ḣ at the measurement time, which the LRV's relative
  damper feeds straight into ÿ1 with gain ``c/m_s`` = 20 s⁻¹ (Table 5).

Extrapolating ḣ(t) from the last two 1 ms differences (the model's fallback,
:func:`~terrain_estimation.models.quarter_car.hdot_at_end`) turns σ_h into
ḣ noise of 2.55 σ_h per ms: 0.25 m/s at σ_h = 0.1 mm, i.e. 5.1 m/s² rms
that the filter did not know of. Measured on the simulator (LRV, lunar
regolith, ISO G, 2 m/s, σ_h = 0.1 mm, 12 seeds): mean NIS 52 (predicted
(0.5 + 26)/0.5 = 53) and an rms k_s error of 48 / 100 / 68 / 54 % at
2 / 5 / 13 / 20 s; at 0.5 mm NIS 1300. Two changes fix it:

* ḣ(t) is the slope of a local least-squares polynomial (degree 5, lower if
  the window holds too few samples) fitted to the profile samples in a
  window centred on t that spans ``hdot_window_m`` of road: the time window
  is ``hdot_window_m / v`` (v from the profile's distance channel over the
  last 50 ms, capped at 0.1 s), so a step waits for the profile to cover
  ``t`` plus half the window (15 ms at 2 m/s). The window is set in metres
  because the road's content is spatial (ISO 8608, ≤ 10 cycles/m) and the
  gain error of the differentiator, which matters a lot here (the fed-
  through ``(c/m_s) ḣ`` is ≈ 20 m/s² rms against ≈ 3 m/s² for the k_tot
  term), depends on ``n_max · window`` only. Measured (LRV, accelerometer
  noise 1e-6 to expose the bias, 6–8 seeds): a fixed cubic window of 10 / 20
  / 40 ms biases k_s by +0.07 / +1.0 / +9 % at 2 m/s; a fixed quintic 30 ms
  window +0.03 % at 2 m/s but +4 % at 5 m/s; the quintic over 0.06 m
  +0.08 / +0.05 / +0.23 % at 1 / 2 / 5 m/s.
* Every update uses ``R_eff = R + G Σ_ε Gᵀ``, ``G = [C B, D]`` at the prior
  mean and ``Σ_ε`` the covariance of ``(ε_h, ε_ḣ)`` computed from the weights
  actually used (interpolation or local fit) and ``profile_noise_std``. With
  the quintic over 0.06 m at 2 m/s, σ_h = 0.1 mm adds ≈ 0.03 (m/s²)² to the
  LRV's R = 0.5; 0.5 mm adds ≈ 0.8. A wrong ``profile_noise_std`` only
  mis-scales the NIS (0.1 mm configured, 0.5 mm true: LRV NIS 2.5, quarter
  car 5.7; k_s errors as with the right value).

After (12 seeds, 20 s, ``profile_noise_std`` = σ_h): mean NIS 0.98 / 0.98 /
0.99 (LRV, χ²₁) and 1.95 / 1.96 / 2.00 (quarter car, χ²₂) at σ_h = 0 /
0.1 / 0.5 mm. What remains of the profile noise is the errors-in-variables
bias of the quarter car (above); augmenting the state with ``ε_h`` (a
correlated-noise filter) or adding its force on the wheel as process noise
did not reduce it (−2.5 % / −2.7 % at 0.5 mm).
"""

from __future__ import annotations

import bisect
import math
import operator
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from terrain_estimation.estimators.soil_road_fit import fit_weights, slope_weights
from terrain_estimation.filters.base import Array

if TYPE_CHECKING:
    from terrain_estimation.estimators.soil_stiffness_config import SoilStiffnessEstimatorConfig

__all__ = ["ProfileRoad"]

_EPS_T = 1e-9  # stamp comparison tolerance (s): stamps are float conversions
#: ḣ fit (feed-through): polynomial degree (lowered to fit fewer samples),
#: longest time window, and the span over which the speed is measured (s).
_HDOT_DEGREE = 5
_HDOT_MAX_WINDOW_S = 0.1
_SPEED_SPAN_S = 0.05


def _local_quadratic(pt: Array, ph: Array, grid: Array, half_w: float) -> Array:
    """Elevation at ``grid`` from a local quadratic least-squares fit (Savitzky–Golay).

    Each grid time τ takes the constant term of ``h ≈ a + b(t−τ) + c(t−τ)²``
    fitted to the samples with ``|t − τ| ≤ half_w``. A quadratic keeps the
    passband flat to second order (a boxcar of the same width attenuates
    the road by sinc(φw)), while the noise variance of the value falls to
    ≈ 9/(4M) of one sample for M samples. Windows with fewer than 3 samples
    fall back to linear interpolation.

    Args:
        pt: sample stamps ``(K,)`` (s), increasing.
        ph: elevations ``(K,)`` (m).
        grid: evaluation times ``(G,)`` (s).
        half_w: half window (s).

    Returns:
        ``(G,)`` elevations (m).
    """
    lo = np.searchsorted(pt, grid - half_w, side="left")
    hi = np.searchsorted(pt, grid + half_w, side="right")
    cnt = hi - lo
    out = np.interp(grid, pt, ph)
    width = int(cnt.max()) if cnt.size else 0
    if width < 3:
        return out
    idx = lo[:, None] + np.arange(width)[None, :]
    mask = idx < hi[:, None]
    idx = np.minimum(idx, pt.size - 1)
    # Times relative to τ and scaled by half_w keep the normal equations
    # well conditioned whatever the absolute stamp.
    s = np.where(mask, (pt[idx] - grid[:, None]) / half_w, 0.0)
    w = mask.astype(float)
    hv = np.where(mask, ph[idx], 0.0)
    v = np.stack([w, w * s, w * s * s], axis=-1)  # (G, W, 3)
    normal = np.einsum("gwi,gwj->gij", v, v * w[..., None])
    rhs = np.einsum("gwi,gw->gi", v, hv)
    ok = cnt >= 3
    if np.any(ok):
        normal[~ok] = np.eye(3)
        rhs[~ok] = 0.0
        sol = np.linalg.solve(normal, rhs[..., None])[..., 0]
        out = np.where(ok, sol[:, 0], out)
    return out


def _fit_weights(pt: Array, t: float, half_w: float, degree: int) -> tuple[int, Array, Array] | None:
    """Weights of the value and the slope at ``t`` of a local polynomial least-squares fit.

    The fit of degree ``degree`` takes the samples with ``|t_i − t| ≤ half_w``;
    the value is ``w0 · h[lo:lo+M]`` and the slope ``w1 · h[lo:lo+M]``, so the
    variances under white noise σ² are ``σ²‖w0‖²`` and ``σ²‖w1‖²`` (their
    covariance ``σ² w0·w1`` vanishes for a symmetric window). The slope of a
    fit of odd degree d over a symmetric window (Savitzky–Golay
    differentiator) is flat to order d+1 in frequency: its gain error on a
    sinusoid of frequency f is ``O((π f w)^(d+1))``. For a uniform 1 kHz
    profile and a window w: degree 1/2 at w = 20 ms loses 16 % at 20 Hz,
    degree 3 0.55 %, degree 5 0.007 %; the price is noise, std(ḣ) =
    0.036 / 0.091 / 0.161 σ_h per ms for degree 1 / 3 / 5 (0.089 σ_h/ms for
    degree 5 at w = 30 ms), against 2.55 σ_h/ms for extrapolating the last
    two 1 ms differences.

    Returns:
        ``(lo, w0, w1)``, or None when the window holds fewer than
        ``degree + 2`` samples or does not reach at least half-way to each
        of its edges (the fit would extrapolate).

    Computed by the compiled :func:`~terrain_estimation.estimators.soil_road_fit.fit_weights`
    (the normal equations of ``h ≈ Σ c_k ((t_i − t)/half_w)^k``, equal to numpy's
    ``np.linalg.solve(VᵀV, Vᵀ)`` to rounding).
    """
    lo, w0, w1 = fit_weights(pt, t, half_w, degree)
    return None if lo < 0 else (lo, w0, w1)


def _as_array(values: list[float]) -> Array:
    """``np.array(values)`` of a list of floats (the same float64 values; ``np.fromiter`` skips the
    type and shape discovery, a third of the conversion of a window's few tens of samples)."""
    return np.fromiter(values, float, len(values))


@lru_cache(maxsize=32)
def _grid_offsets(dt: float, n_sub: int) -> Array:
    """``dt · [0, 1, …, N] / N``, the sub-step grid of a step relative to its start (read-only).

    The same array ``t_prev + dt * np.arange(N + 1) / N`` adds to ``t_prev``
    (``+`` comes last); cached because a step's ``dt`` takes a handful of
    values (stamp differences in float seconds).
    """
    offsets = dt * np.arange(n_sub + 1) / n_sub
    offsets.setflags(write=False)
    return offsets


class ProfileRoad:
    """The profile buffer of the estimator and the road it reconstructs for a step (module docstring).

    The estimator fills ``_pt``/``_ph``/``_ps`` (stamps, elevations,
    distances; increasing stamps) and sets the window settings; the methods
    below read them.
    """

    config: SoilStiffnessEstimatorConfig
    _pt: list[float]
    _ph: list[float]
    _ps: list[float]
    _t_prev: float | None
    _keep_s: float
    _smooth_half_w: float
    _hdot_fit: bool
    _half_window_cache: tuple[float, float]
    # _sorted_gaps: the buffer list the sorted differences are of, how many of its
    # first stamps they cover, and the differences.
    _gaps_of: list[float] | None = None
    _gaps_count: int = 0
    _gaps: list[float]

    def _profile_window(self, t0: float, t1: float) -> tuple[int, Array]:
        """The stamps of the buffered samples a reconstruction over ``[t0, t1]`` can touch, as an array.

        Every sample within ``[t0, t1]``, two more on each side (the
        neighbours linear interpolation brackets with, the last two samples
        extrapolation uses) and nothing else: the buffer holds up to a few
        hundred samples (the profile runs ahead of the IMU, and the ḣ fit
        keeps 0.1 s behind), and converting all of them on every step cost
        more than the reconstruction itself. Interpolation, the local fits and
        the gap search only ever read samples inside this window, so their
        results are the same as on the whole buffer; the ends of the window
        are the buffer's ends whenever the reconstruction reaches them.

        Returns:
            ``(lo, pt)``: the buffer index of the window's first sample and the window's stamps.
        """
        lo = max(bisect.bisect_left(self._pt, t0) - 2, 0)
        hi = bisect.bisect_right(self._pt, t1, lo) + 2
        return lo, _as_array(self._pt[lo:hi])

    def _profile_on_grid(self, grid: Array) -> tuple[Array, float]:
        """Elevation on the sub-step grid and the largest profile gap over it."""
        w = self._smooth_half_w
        g0, g1 = float(grid[0]), float(grid[-1])
        # The window of _profile_window, kept as a list too for the gap search.
        lo = max(bisect.bisect_left(self._pt, g0 - w) - 2, 0)
        hi = bisect.bisect_right(self._pt, g1 + w, lo) + 2
        st = self._pt[lo:hi]
        pt, ph = _as_array(st), _as_array(self._ph[lo:hi])
        if w > 0.0:
            hg = _local_quadratic(pt, ph, grid, w)
        else:
            hg = np.interp(grid, pt, ph)
        last = st[-1]
        if g1 > last:  # the grid increases: some of it lies past the last sample
            slope = (ph[-1] - ph[-2]) / (pt[-1] - pt[-2]) if pt.size >= 2 else 0.0
            hg = np.where(grid > last, ph[-1] + slope * (grid - pt[-1]), hg)
        # The largest gap between the samples bracketing the grid: on the list
        # (bisect is searchsorted, and the max of the same differences).
        i0 = max(bisect.bisect_right(st, g0) - 1, 0)
        i1 = min(bisect.bisect_left(st, g1), len(st) - 1)
        seg = st[i0 : i1 + 1]
        max_gap = max(map(operator.sub, seg[1:], seg)) if len(seg) > 1 else 0.0
        if g1 > last:
            max_gap = max(max_gap, g1 - last)
        return hg, max_gap

    def _profile_spacing(self) -> float:
        """Median spacing (s) of the buffered profile samples (0 with fewer than two).

        The same value as ``np.median(np.diff(pt))`` (the same differences;
        for an even count the mean of the two middle ones, ``(a + b) / 2``
        as numpy forms it), from the differences kept sorted as the buffer
        changes: the buffer holds a hundred or more samples of which a step
        adds about ten, and numpy's median cost ≈ 10 µs of call overhead per
        step, sorting them all again ≈ 6 µs.
        """
        gaps = self._sorted_gaps()
        n = len(gaps)
        if n < 1:
            return 0.0
        mid = n // 2
        return gaps[mid] if n % 2 else (gaps[mid - 1] + gaps[mid]) / 2.0

    def _sorted_gaps(self) -> list[float]:
        """The differences of consecutive buffered stamps, sorted, kept up to date with the buffer.

        The buffer list only grows at its end (``add_profile_sample``) between
        the calls of :meth:`_prune`, which drop a third of it every few steps
        and have the differences sorted anew, as does a new list (``reset``).
        """
        pt = self._pt
        if self._gaps_of is not pt or self._gaps_count > len(pt):
            self._gaps_of, self._gaps_count = pt, len(pt)
            self._gaps = sorted(map(operator.sub, pt[1:], pt))
            return self._gaps
        gaps = self._gaps
        for i in range(max(self._gaps_count, 1), len(pt)):
            bisect.insort(gaps, pt[i] - pt[i - 1])
        self._gaps_count = len(pt)
        return gaps

    def _hdot_half_window(self, t: float) -> float:
        """Half the time window (s) of the ḣ fit at ``t``; 0 without the fit.

        ``hdot_window_m / v / 2``, v the mean speed over the profile samples
        of the last 50 ms up to ``t`` (from their distances), capped at half of
        0.1 s (also at standstill or without a usable distance channel).
        Only samples stamped at or before ``t`` are used, so the window does
        not depend on how far the profile has run ahead.
        """
        if not self._hdot_fit:
            return 0.0
        cached_t, cached = self._half_window_cache
        if t == cached_t:
            return cached
        half_max = 0.5 * _HDOT_MAX_WINDOW_S
        pt = self._pt
        i1 = bisect.bisect_right(pt, t) - 1
        i0 = bisect.bisect_left(pt, t - _SPEED_SPAN_S)
        if i1 <= i0:
            half = half_max
        else:
            v = abs(self._ps[i1] - self._ps[i0]) / (pt[i1] - pt[i0])
            half = min(0.5 * self.config.hdot_window_m / v, half_max) if math.isfinite(v) and v > 0.0 else half_max
        if pt and pt[-1] > t:
            # Final: every later sample is stamped after t (add_profile_sample),
            # and _prune keeps 0.1 s before the last step, which precedes t. A
            # waiting step asks again on every profile sample until it runs.
            self._half_window_cache = (t, half)
        return half

    def _road_at_measurement(self, t: float, u_sub: Array, delta: float) -> tuple[float | None, Array]:
        """ḣ at the measurement time and the covariance of the road errors there.

        Args:
            t: measurement time (s), the end of the step.
            u_sub: the step's sub-step slopes (m/s).
            delta: sub-step length (s).

        Returns:
            ``(ḣ(t) or None, Σ_ε)``: ḣ from the local quintic fit over
            ``hdot_window_m`` of road (None without feed-through, without a
            window, or when the window is not covered: the model then
            extrapolates the sub-step slopes), and the 2×2 covariance of the
            errors ``(ε_h, ε_ḣ)`` of the reconstructed elevation and of the ḣ
            used, for white profile noise ``profile_noise_std`` (m², m²/s,
            m²/s²).
        """
        half = self._hdot_half_window(t)
        w = self._smooth_half_w
        reach = max(w, half)
        var = self.config.profile_noise_std**2
        if reach == 0.0:
            # Neither fit: h(t) is interpolated (or extrapolated) between two samples (the quarter car's every step).
            w_h = self._interpolation_weights(t)[1]
            return None, self._extrapolated_road_cov(var * float(w_h @ w_h), u_sub.size, delta)
        # The window's stamps; sample indices below are relative to it (lo_h, lo_d alike).
        lo, pt = self._profile_window(t - reach, t + reach)
        # Weights of the elevation at t, as _profile_on_grid reconstructs it
        # (for the variance only: the local-fit case is approximated by the
        # fit over the same window).
        fit = _fit_weights(pt, t, w, 2) if w > 0.0 and t <= pt[-1] else None
        if fit is not None:
            lo_h, w_h = fit[0], fit[1]
        else:
            i_h, w_h = self._interpolation_weights(t)
            lo_h = i_h - lo
        var_h = var * float(w_h @ w_h)
        if half > 0.0:
            # The slope weights of the highest odd degree the window allows (fewer samples: lower).
            lo_d, w_d, norm2, cross = slope_weights(pt, t, half, _HDOT_DEGREE, lo_h, w_h)
            if lo_d >= 0:
                i_d = lo + lo_d
                hdot_end = float(w_d @ _as_array(self._ph[i_d : i_d + w_d.size]))
                var_d, cov = var * norm2, var * cross
                return hdot_end, np.array([[var_h, cov], [cov, var_d]])
        return None, self._extrapolated_road_cov(var_h, u_sub.size, delta)

    @staticmethod
    def _extrapolated_road_cov(var_h: float, n_sub: int, delta: float) -> Array:
        """Σ_ε when ḣ(t) is the model's extrapolation of the last sub-step slopes."""
        # 1.5 u_{N−1} − 0.5 u_{N−2} = (1.5 h_N − 2 h_{N−1} + 0.5 h_{N−2})/δ,
        # grid elevations about as noisy as the one at t.
        var_d = 6.5 * var_h / delta**2 if n_sub >= 2 else 2.0 * var_h / delta**2
        cov = (1.5 if n_sub >= 2 else 1.0) * var_h / delta
        return np.array([[var_h, cov], [cov, var_d]])

    def _interpolation_weights(self, t: float) -> tuple[int, Array]:
        """The samples ``_profile_on_grid`` reconstructs ``h(t)`` from without smoothing: the buffer index of the
        first and the weights of the two (or one).

        Read off the buffer list: the same samples and float operations as
        on a window's arrays (the window holds every sample the bisections
        below find, at the same positions relative to each other).
        """
        pt = self._pt
        last = pt[-1]
        if t > last:
            if len(pt) >= 2:
                beta = (t - last) / (last - pt[-2])
                return len(pt) - 2, np.array([-beta, 1.0 + beta])
            return 0, np.ones(1)
        i = bisect.bisect_right(pt, t)
        if i >= len(pt) or i == 0:
            return min(max(i - 1, 0), len(pt) - 1), np.ones(1)
        a = (t - pt[i - 1]) / (pt[i] - pt[i - 1])
        return i - 1, np.array([1.0 - a, a])

    def _prune(self) -> None:
        """Drop profile samples no step needs: keep the last one at or before t_prev − w/2."""
        if self._t_prev is None or len(self._pt) < 64:
            return
        keep_from = bisect.bisect_right(self._pt, self._t_prev - self._keep_s) - 1
        if keep_from > 32:
            self._gaps_of = None  # _sorted_gaps sorts them anew (cheaper than removing a third of them)
            del self._pt[:keep_from]
            del self._ph[:keep_from]
            del self._ps[:keep_from]
