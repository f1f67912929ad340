"""Soil-stiffness estimator core: profile buffer, sub-step input, filter, soil reporting.

The ROS-free core that the quarter-car / LRV estimator node and the offline
bag runner both drive (MODELS.md Part A, CONTRACT.md "Quarter car"). It owns
one filter (SCKF by default) over :class:`~terrain_estimation.models.quarter_car.QuarterCarModel`
or :class:`~terrain_estimation.models.quarter_car.LRVModel`, and turns the
``k_tot`` state into ``k_s``, a terrain class and a soil-change flag.

Data flow (all times are the ``t`` arguments, in seconds; no wall clock):

* :meth:`SoilStiffnessEstimator.add_profile_sample` buffers the measured
  elevation under the tire (``terrain/profile``, 1 kHz by default).
* :meth:`SoilStiffnessEstimator.add_accelerations` queues one accelerometer
  sample (specific force, gravity included, REP 145) and runs every queued
  filter step whose road is known. A step from ``t_prev`` to ``t`` is
  predict (through the sub-steps of the road) + update.

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

**When a step cannot run yet.** A queued accelerometer sample at ``t`` waits
until the profile covers ``t`` plus the larger of w/2 and half the ḣ window.
If the profile lags by more than ``max_wait_s`` (measured against the newest
accelerometer stamp), the step
runs anyway when the last profile sample is at most ``max_extrapolation_s``
old (the elevation is extrapolated along the last profile segment);
otherwise the sample is dropped (``counters.dropped_no_profile``) and the next
step spans the gap. Gaps inside a step are interpolated linearly; a gap longer
than ``profile_max_gap_s`` makes the step predict-only (no update, the
estimate says ``accepted = False``). A step longer than ``max_step_s`` (e.g.
the profile or the IMU stopped for a while) restarts the motion states from
rest with their initial covariance and keeps the k_tot estimate. The very
first accelerometer sample only sets the time origin (there is no previous
step); samples older than the first profile sample are dropped. In all these
cases the call returns ``None`` unless an earlier queued step completed.
``max_wait_s`` defaults to 0.25 s: a live executor serves its subscriptions
round-robin and may hand over the accelerometer well ahead of a 1 kHz
profile backlog; a shorter wait would drop those steps (a drop is not a
delay: the next step spans the gap, the filter loses an update).

**Outputs.** Both ``add_*`` methods return the newest estimate their call
produced (None if none); every estimate also goes to an outbox read by
:meth:`SoilStiffnessEstimator.drain_estimates` — one call can complete several
queued steps, so a node or a bag runner should publish the drained list. k_s
and its variance come from k_tot by first-order propagation (MODELS.md A.2),
the class from :func:`~terrain_estimation.models.soil.classify_soil`, and
``soil_change_detected`` from
:class:`~terrain_estimation.estimators.soil_change.SoilChangeDetector`: a
two-sided CUSUM on the whitened stiffness correction of every accepted update,
armed from the first update (not only once the estimate has converged: on a
smooth road it never converges tightly, and a change must still be seen). On
an alarm the stiffness mean moves by the jump the innovations imply
(``change_jump_gain``), its variance is re-opened by a multiple of that
jump (``change_reopen_scale``, bounded by a floor and by P0) and the motion
states' variances grow by their P0 (they were estimated with the old soil's
stiffness since the change). Measured (``make reproduce-qc``, cases 2b and
2c, node defaults): on the Table 4 path all 400 changes detected, median delay
0.01 s (ISO F) to 0.12 s (ISO D, 2 m/s), 0.19 s on ISO B; no false alarm in
1.0 h of driving without a change (48 quarter-car and 16 LRV runs of 60 s;
one alarm in 64 starts, during the first 2 s of convergence).

**The stiffness state.** The model's last state is either k_tot itself (the
paper's P-5, ``stiffness_state="k_tot"``, the core's default and the one the
reproduction tables use) or ``s = ln(k_s/k_series)`` (``"log_k_s"``, the node's
default). With k_tot, the first updates sometimes overshoot k̂_tot towards
k_series, where ``k_s = k_tot k_series/(k_series − k_tot)`` explodes (2 runs in
100 of the paper's case 1 reach the clamp, k̂_s ≈ 1000 k_series for a few steps;
MODELS.md A.10.4). With ln k_s every cubature point maps to a k_tot inside
``(0, k_series)`` and k̂_s is always finite and positive; on case 1 (100 runs)
the mean RMSE over 0–10 s drops from 21.5 % to 4.8 % (median 4.6 → 4.5 %), the
steady state is unchanged (1.03 → 1.00 %). The soil-change re-open is then
in ln k_s (floor ``change_log_ks_std``).

**Never NaN.** Non-finite arguments are rejected at the entry (counted); the
filter's posterior mean of k_tot is projected into the model's clamp range
(a projection of the mean only, the covariance is kept); a non-finite
posterior (which the clamped model should never produce) restarts the motion
states as above and keeps the last finite k_tot (``counters.recoveries``).
Every float of an estimate is finite. With ``config.divergence`` set, a
:class:`~terrain_estimation.filters.faults.DivergenceMonitor` also watches
for a filter that stays finite but diverges (windowed NIS outside its χ²
band, covariance blow-up, gate lock-out) and, on any fault including the
non-finite one, re-initialises the filter from the last good estimate
(``counters.divergences``; :attr:`SoilStiffnessEstimator.fault` holds the
reason until the filter is consistent again).
"""

from __future__ import annotations

import bisect
import dataclasses
import importlib
import math
import operator
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from types import MappingProxyType
from typing import Any, Literal

import numpy as np
from scipy.linalg.lapack import dpotrf as _dpotrf

from terrain_estimation.estimators.soil_change import ChangeAlarm, SoilChangeDetector
from terrain_estimation.estimators.soil_stiffness_sckf import STATUS_OK, model_operands, run_step, warm_up
from terrain_estimation.filters.base import Array, SqrtGaussianState, UpdateInfo
from terrain_estimation.filters.faults import DivergenceConfig, DivergenceMonitor
from terrain_estimation.models.quarter_car import (
    LRVModel,
    LRVParams,
    QuarterCarModel,
    QuarterCarParams,
    StepInput,
)
from terrain_estimation.models.quarter_car_road import RoadInputParams
from terrain_estimation.models.soil import SOIL_TABLE, SoilClass, classify_soil

__all__ = [
    "SoilStiffnessEstimatorConfig",
    "SoilStiffnessEstimate",
    "EstimatorCounters",
    "SoilStiffnessEstimator",
    "make_filter",
    "FILTER_CLASSES",
]

#: Filter name → (module, class) of terrain_estimation.filters; imported lazily
#: so that the estimator module loads even where a filter is not installed.
FILTER_CLASSES: dict[str, tuple[str, str]] = {
    "sckf": ("terrain_estimation.filters.sckf", "SquareRootCubatureKalmanFilter"),
    "ckf": ("terrain_estimation.filters.ckf", "CubatureKalmanFilter"),
    "ukf": ("terrain_estimation.filters.ukf", "UnscentedKalmanFilter"),
    "ekf": ("terrain_estimation.filters.ekf", "ExtendedKalmanFilter"),
}

#: P0 used when ``p0_diag`` is None [recon, MODELS.md A.5]: motion states
#: loosely known about rest, k_tot std ≈ 0.29 of the series stiffness.
_P0_QUARTER_CAR = (1e-4, 1e-2, 1e-4, 1e-2, 50e3**2)
_P0_LRV = (1e-4, 1e-2, 4.3e3**2)
#: Last entry of P0 for the ``"log_k_s"`` state (ln units²): a std of 1.5 puts
#: the 2σ prior range at k_series·e^±3, 0.05…20 times k_series, which covers
#: every soil of Table 1 from the start guess k_s = k_series.
P0_LOG_KS = 1.5**2


def make_filter(name: str) -> Any:
    """Instantiate the filter ``name`` ("sckf" | "ckf" | "ukf" | "ekf") with its defaults.

    Raises:
        ValueError: unknown name.
        ImportError: the filter module is not available.
    """
    try:
        module_name, class_name = FILTER_CLASSES[name]
    except KeyError:
        known = sorted(FILTER_CLASSES)
        raise ValueError(f"unknown filter {name!r}; expected one of {known}") from None
    module = importlib.import_module(module_name)
    return getattr(module, class_name)()


@dataclass(frozen=True)
class SoilStiffnessEstimatorConfig:
    """Configuration of :class:`SoilStiffnessEstimator` (one frozen object).

    Attributes:
        vehicle: ``"quarter_car"`` (2-DOF, body + wheel accelerometers) or
            ``"lrv"`` (1-DOF, body accelerometer only).
        quarter_car: 2-DOF model parameters (used when vehicle is quarter_car).
        lrv: 1-DOF model parameters (used when vehicle is lrv).
        filter: ``"sckf"`` | ``"ckf"`` | ``"ukf"`` | ``"ekf"``.
        filter_rate_hz: nominal filter rate (Hz); accelerometer samples closer
            than half a period to the previous step are skipped (decimation).
        substep_rate_hz: rate of the sub-step grid the road is resampled on
            (Hz); ``N = ceil(dt · substep_rate_hz)`` sub-steps per step.
        k_tot0: initial k_tot (N/m); None → ``k_series / 2`` (the project's
            reading of "half the tire stiffness", MODELS.md A.5).
        p0_diag: initial covariance diagonal (SI², state order); None → 2-DOF
            ``(1e-4, 1e-2, 1e-4, 1e-2, (50 kN/m)²)``, LRV
            ``(1e-4, 1e-2, (4.3 kN/m)²)``; with the ``"log_k_s"`` stiffness
            state the last default entry is ``1.5²`` (ln units).
        gravity: subtracted from the specific forces (m/s²).
        convergence_rel_std: ``converged`` when ``√var(k_s)/k_s`` is below it.
        gate_threshold: NIS gate (χ²_p); None disables. A gated update leaves
            the prior and reports ``accepted = False``.
        soil_table: known soils for the classifier.
        class_log_std: within-class spread of ln k_s (see
            :func:`~terrain_estimation.models.soil.classify_soil`).
        unknown_weight: prior weight of "none of the known soils".
        change_drift: CUSUM allowance ν (σ units) of the soil-change detector
            (:mod:`~terrain_estimation.estimators.soil_change`), which runs on
            the whitened stiffness correction of every accepted update from
            the first one on. ν is about half the smallest shift of that
            correction worth detecting.
        change_threshold: CUSUM alarm level h (σ units). Larger: fewer false
            alarms, a longer delay (≈ h/(μ − ν) updates for a shift μ).
        change_clip: standardised corrections are clipped to ±clip (σ, >
            drift) before the CUSUM, so one outlier adds at most
            ``clip − drift``: with clip ≤ h no single update raises an alarm
            (defaults: two one-signed updates at least).
        change_reopen_scale: on an alarm the stiffness variance grows by
            ``σ_r²``, ``σ_r = scale · |d|`` with ``d`` the jump the
            innovations of the alarm's excursion imply, bounded below by the
            floor of the stiffness state (``change_ktot_std_frac`` /
            ``change_log_ks_std``) and above by its initial std (P0); the
            motion states' variances grow by their P0 at the same time (they
            were estimated with the old stiffness since the change). 0 with a
            zero floor disables the re-open (the paper's filter, for
            reproduction; the alarm is still reported).
        change_jump_gain: on an alarm the stiffness mean moves by
            ``gain · d``, ``d`` bounded by the initial std of the stiffness
            state (in [0, 1]; 1 = the GLR correction of Willsky and
            Jones: the filter restarts at the implied new soil, with the
            re-opened variance around it; 0 = re-open in place).
        change_ktot_std_frac: floor of the re-open for the ``"k_tot"`` state,
            as a fraction of k_series (std ``frac · k_series``).
        change_log_ks_std: floor of the re-open for the ``"log_k_s"`` state
            (std of ``ln k_s``).
        profile_smoothing_s: window w (s) of the local quadratic fit of the
            profile (see module docstring); 0 = plain linear interpolation.
            Use ≈ 0.01–0.02 s for σ_h ≈ 0.5–1 mm.
        profile_noise_std: standard deviation σ_h of the white noise on the
            profile elevations (m, ≥ 0; default 1e-4, the contract's
            simulated sensor). The measurement noise of every update is
            inflated by what this noise does to the predicted accelerations
            (module docstring, "Profile noise and the measurement"); 0 = a
            noise-free profile (R unchanged). Set it to the profile sensor's
            noise: too small a value only raises the NIS.
        hdot_window_m: length of road (m, ≥ 0; default 0.06) covered by the
            window of the local polynomial fit, centred on the measurement
            time, that gives ḣ(t) for a model with feed-through (LRV relative
            damper). The time window is ``hdot_window_m / v`` (v from the
            profile's distance channel), at most 0.1 s, and a step waits for
            the profile to cover half of it past ``t``. 0 = extrapolate the
            last two sub-step slopes (the noisy former behaviour). Ignored
            without feed-through. Longer windows lower the noise and bias ḣ
            (keep it well below a wavelength of the road's finest content:
            0.1 m at 10 cycles/m).
        profile_max_gap_s: a larger gap between profile samples inside a step
            makes the step predict-only (s).
        max_wait_s: how long a step waits for the profile, against the newest
            accelerometer stamp (s). A live executor may serve the IMU ahead
            of a 1 kHz profile backlog; the wait must cover that lag.
        max_extrapolation_s: how far past the last profile sample a timed-out
            step may extrapolate the elevation (s).
        max_step_s: a longer step restarts the motion states (s).
        max_pending: bound of the queue of waiting accelerometer samples (the
            oldest is dropped beyond it); must exceed ``max_wait_s`` times the
            accelerometer rate (raw, before decimation).
        divergence: divergence detection and recovery
            (:class:`~terrain_estimation.filters.faults.DivergenceConfig`):
            the windowed NIS against its χ² band, covariance blow-up, gate
            lock-out, non-finite or broken state; on a divergence the filter
            re-initialises from the last good estimate
            (``counters.divergences``, :attr:`SoilStiffnessEstimator.fault`
            until it is consistent again). None (default) keeps only the
            non-finite recovery of the module docstring.
        road_input: ``"profile"`` (default: the measured profile drives the
            model, this class) or ``"stochastic"`` (no profile: the road is
            ISO 8608 shaped noise, :mod:`.soil_profile_free`; build with
            :func:`~terrain_estimation.estimators.soil_select.make_estimator`).
        road: the stochastic road (``road_input = "stochastic"`` only).
    """

    vehicle: Literal["quarter_car", "lrv"] = "quarter_car"
    quarter_car: QuarterCarParams = field(default_factory=QuarterCarParams)
    lrv: LRVParams = field(default_factory=LRVParams)
    filter: Literal["sckf", "ckf", "ukf", "ekf"] = "sckf"
    filter_rate_hz: float = 100.0
    substep_rate_hz: float = 1000.0
    k_tot0: float | None = None
    p0_diag: tuple[float, ...] | None = None
    gravity: float = 9.80665
    convergence_rel_std: float = 0.05
    gate_threshold: float | None = None
    soil_table: tuple[SoilClass, ...] = SOIL_TABLE
    class_log_std: float = 0.1
    unknown_weight: float = 0.05
    change_drift: float = 0.5
    change_threshold: float = 20.0
    change_reopen_scale: float = 0.5
    change_clip: float = 20.0
    change_jump_gain: float = 1.0
    change_ktot_std_frac: float = 0.2
    change_log_ks_std: float = 0.3
    profile_smoothing_s: float = 0.0
    profile_noise_std: float = 1e-4
    hdot_window_m: float = 0.06
    profile_max_gap_s: float = 0.02
    max_wait_s: float = 0.25
    max_extrapolation_s: float = 0.005
    max_step_s: float = 0.5
    max_pending: int = 1000
    divergence: DivergenceConfig | None = None
    road_input: Literal["profile", "stochastic"] = "profile"
    road: RoadInputParams = field(default_factory=RoadInputParams)

    def __post_init__(self) -> None:
        if self.road_input not in ("profile", "stochastic"):
            raise ValueError(f"road_input must be 'profile' or 'stochastic', got {self.road_input!r}")
        if self.vehicle not in ("quarter_car", "lrv"):
            raise ValueError(f"vehicle must be 'quarter_car' or 'lrv', got {self.vehicle!r}")
        if self.filter not in FILTER_CLASSES:
            raise ValueError(f"filter must be one of {sorted(FILTER_CLASSES)}, got {self.filter!r}")
        positive = (
            "filter_rate_hz",
            "substep_rate_hz",
            "gravity",
            "convergence_rel_std",
            "class_log_std",
            "change_threshold",
            "profile_max_gap_s",
            "max_step_s",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        non_negative = (
            "change_drift",
            "profile_smoothing_s",
            "profile_noise_std",
            "hdot_window_m",
            "max_wait_s",
            "max_extrapolation_s",
            "change_ktot_std_frac",
            "change_log_ks_std",
            "change_reopen_scale",
        )
        for name in non_negative:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")
        if not (self.change_drift < self.change_clip and math.isfinite(self.change_clip)):
            raise ValueError(f"change_clip must be finite and > change_drift, got {self.change_clip}")
        if not (0.0 <= self.change_jump_gain <= 1.0):
            raise ValueError(f"change_jump_gain must be in [0, 1], got {self.change_jump_gain}")
        if not (0.0 <= self.unknown_weight < 1.0):
            raise ValueError("unknown_weight must be in [0, 1)")
        if self.max_pending < 1:
            raise ValueError("max_pending must be >= 1")
        if not self.soil_table:
            raise ValueError("soil_table must not be empty")
        k_series = self.k_series
        if self.k_tot0 is not None and not (0.0 < self.k_tot0 < k_series):
            raise ValueError(f"k_tot0 must be in (0, {k_series}), got {self.k_tot0}")
        if self.p0_diag is not None:
            n = 5 if self.vehicle == "quarter_car" else 3
            bad = [p for p in self.p0_diag if not (math.isfinite(p) and p > 0)]
            if len(self.p0_diag) != n or bad:
                raise ValueError(f"p0_diag must hold {n} finite positive variances")
        if self.gate_threshold is not None and not (self.gate_threshold > 0):
            raise ValueError("gate_threshold must be > 0 or None")
        if self.divergence is not None and not isinstance(self.divergence, DivergenceConfig):
            raise ValueError(f"divergence must be None or a DivergenceConfig, got {type(self.divergence).__name__}")

    @property
    def vehicle_params(self) -> QuarterCarParams | LRVParams:
        """The parameters of the selected vehicle."""
        return self.quarter_car if self.vehicle == "quarter_car" else self.lrv

    @property
    def k_series(self) -> float:
        """Stiffness in series with the soil of the selected vehicle (N/m)."""
        return self.vehicle_params.k_series


@dataclass(frozen=True)
class SoilStiffnessEstimate:
    """One filter step's result; every float is finite.

    Attributes:
        t: time of the step (s), the accelerometer sample's stamp.
        k_s: soil stiffness (N/m).
        k_s_variance: its first-order variance ((N/m)², MODELS.md A.2).
        k_tot: series stiffness state (N/m).
        k_tot_variance: its filter variance ((N/m)²).
        terrain_class: nearest known soil (``SoilClass.name``).
        class_confidence: 0..1.
        converged: relative k_s standard deviation below the threshold.
        soil_change_detected: the change detector raised an alarm at this step.
        nis: normalised innovation squared of the update (0 for a predict-only
            step).
        accepted: the measurement update was applied.
        state: the full state mean, in the model's state order.
        profile_gap_ratio: the largest gap between profile samples over the
            step divided by the median spacing of the profile buffer (≈ 1 for
            an intact stream; well above 1 when samples were lost, e.g. a node
            falling behind a 1 kHz profiler: the road between the steps is then
            interpolated and k_s is biased, MODELS.md A.10).
    """

    t: float
    k_s: float
    k_s_variance: float
    k_tot: float
    k_tot_variance: float
    terrain_class: str
    class_confidence: float
    converged: bool
    soil_change_detected: bool
    nis: float
    accepted: bool
    state: tuple[float, ...] = ()
    profile_gap_ratio: float = 1.0


@dataclass(frozen=True)
class EstimatorCounters:
    """Health counters since the last reset (for diagnostics)."""

    steps: int = 0
    updates_accepted: int = 0
    gated: int = 0
    predict_only: int = 0
    restarts: int = 0
    recoveries: int = 0
    divergences: int = 0
    soil_changes: int = 0
    decimated: int = 0
    dropped_nonfinite: int = 0
    dropped_out_of_order: int = 0
    dropped_no_profile: int = 0
    dropped_queue_full: int = 0
    profile_rejected: int = 0


class _BodyOnly:
    """View of the 2-DOF model that measures ÿ1 only (wheel accelerometer missing)."""

    def __init__(self, model: QuarterCarModel) -> None:
        self._m = model

    @property
    def state_dim(self) -> int:
        return self._m.state_dim

    @property
    def measurement_dim(self) -> int:
        return 1

    def f(self, x: Array, u: Any, dt: float) -> Array:
        return self._m.f(x, u, dt)

    def h(self, x: Array, u: Any = None) -> Array:
        return self._m.h(x, u)[..., :1]

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        return self._m.process_noise_sqrt(x, u, dt)

    def measurement_noise_sqrt(self) -> Array:
        return self._m.measurement_noise_sqrt()[:1, :1]

    def transition_jacobian(self, x: Array, u: Any, dt: float) -> Array:
        return self._m.transition_jacobian(x, u, dt)

    def measurement_jacobian(self, x: Array, u: Any = None) -> Array:
        return self._m.measurement_jacobian(x, u)[:1]


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
    """
    lo = int(pt.searchsorted(t - half_w, side="left"))
    hi = int(pt.searchsorted(t + half_w, side="right"))
    if hi - lo < degree + 2:
        return None
    s = (pt[lo:hi] - t) / half_w  # in [−1, 1]: a well-conditioned Vandermonde matrix
    if s[0] > -0.5 or s[-1] < 0.5:
        return None
    v = s[:, None] ** np.arange(degree + 1)
    # Rows 0 and 1 of the pseudo-inverse (VᵀV)⁻¹Vᵀ.
    rows = np.linalg.solve(v.T @ v, v.T)
    return lo, rows[0], rows[1] / half_w


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


class _NonFinite:
    """Stand-in posterior after a filter exception (triggers the recovery path)."""

    def __init__(self, n: int) -> None:
        self.x = np.full(n, np.nan)
        self.covariance = np.full((n, n), np.nan)


_EPS_T = 1e-9  # stamp comparison tolerance (s): stamps are float conversions
#: ḣ fit (feed-through): polynomial degree (lowered to fit fewer samples),
#: longest time window, and the span over which the speed is measured (s).
_HDOT_DEGREE = 5
_HDOT_MAX_WINDOW_S = 0.1
_SPEED_SPAN_S = 0.05


class SoilStiffnessEstimator:
    """Soil stiffness from ride vibration: the ROS-free core (see module docstring).

    Args:
        config: the configuration; defaults to the 2-DOF quarter car with SCKF.
        filter_impl: a filter object to use instead of ``make_filter(config.filter)``
            (tests, or a filter configured beyond its defaults).

    Example:
        >>> est = SoilStiffnessEstimator()                     # doctest: +SKIP
        >>> est.add_profile_sample(t, distance, elevation)     # 1 kHz
        >>> e = est.add_accelerations(t, f_body_z, f_wheel_z)  # 100 Hz
    """

    def __init__(
        self,
        config: SoilStiffnessEstimatorConfig | None = None,
        *,
        filter_impl: Any = None,
    ) -> None:
        self.config = config if config is not None else SoilStiffnessEstimatorConfig()
        cfg = self.config
        if cfg.vehicle == "quarter_car":
            self.model: QuarterCarModel | LRVModel = QuarterCarModel(cfg.quarter_car)
            self._body_only: _BodyOnly | None = _BodyOnly(self.model)
        else:
            self.model = LRVModel(cfg.lrv)
            self._body_only = None
        self.filter = filter_impl if filter_impl is not None else make_filter(cfg.filter)
        # The default SCKF runs as one compiled step (_sckf_step, with the
        # model's constants in _operands; not for the "expm" discretisation);
        # any other filter, a filter_impl, or a filter swapped in later through
        # the public predict/update (_filter_step).
        self._operands = model_operands(self.model)
        default_sckf = filter_impl is None and cfg.filter == "sckf" and self._operands is not None
        self._sckf: Any = self.filter if default_sckf else None
        if default_sckf:
            warm_up()
        n = self.model.state_dim
        k_series = self.model.k_series
        k_tot0 = cfg.k_tot0 if cfg.k_tot0 is not None else 0.5 * k_series
        self._stiffness0 = self.model.stiffness_state_of_ktot(k_tot0)
        p0 = cfg.p0_diag
        if p0 is None:
            p0 = _P0_QUARTER_CAR if cfg.vehicle == "quarter_car" else _P0_LRV
            if self.model.stiffness_state == "log_k_s":
                p0 = (*p0[:-1], P0_LOG_KS)
        self._p0 = np.asarray(p0, dtype=float)
        assert self._p0.shape == (n,)
        self._min_dt = 0.5 / cfg.filter_rate_hz
        # Feed-through of ḣ into the measurement (LRV relative damper)?
        self._feedthrough = bool(np.any(self.model.profile_error_gains(np.zeros(n))[1]))
        self._smooth_half_w = 0.5 * cfg.profile_smoothing_s
        self._hdot_fit = self._feedthrough and cfg.hdot_window_m > 0.0
        # How far before a step's start the profile is kept (see _prune).
        self._keep_s = max(self._smooth_half_w, _HDOT_MAX_WINDOW_S if self._hdot_fit else 0.0)
        # R = √R √Rᵀ of the first ``rows`` measurements and the gain matrix
        # [0, g_ḣ] (both constant), by rows.
        self._r_base: dict[int, tuple[Array, Array]] = {}
        self.reset()

    # -- public API -----------------------------------------------------------
    def reset(self) -> None:
        """Forget everything: state, buffers, queue, detector and counters."""
        self._state: Any = None
        self._t_prev: float | None = None
        self._pt: list[float] = []
        self._ph: list[float] = []
        self._ps: list[float] = []
        self._last_distance: float | None = None
        self._pending: deque[tuple[float, float, float | None]] = deque()
        self._newest_acc_t = -math.inf
        self._outbox: deque[SoilStiffnessEstimate] = deque(maxlen=10_000)
        self._last: SoilStiffnessEstimate | None = None
        self._detector = self._make_detector()
        self._jump_gain = self.config.change_jump_gain
        #: The last soil-change alarm (None before the first).
        self.last_change: ChangeAlarm | None = None
        self._c: dict[str, int] = {f.name: 0 for f in dataclasses.fields(EstimatorCounters)}
        self._counts = MappingProxyType(self._c)
        cfg_div = self.config.divergence
        self._monitor = DivergenceMonitor(cfg_div) if cfg_div is not None else None
        # (t, _hdot_half_window(t)) once no later sample can change it.
        self._half_window_cache: tuple[float, float] = (math.nan, 0.0)
        # Profile stamps below this cannot make the waiting queue head ready.
        self._profile_wait = -math.inf

    @property
    def change_statistic(self) -> float:
        """The soil-change CUSUM statistic ``max(g⁺, g⁻)`` now (σ; alarm above ``change_threshold``)."""
        return self._detector.statistic

    @property
    def counters(self) -> EstimatorCounters:
        """Health counters since the last reset."""
        return EstimatorCounters(**self._c)

    @property
    def counts(self) -> Mapping[str, int]:
        """The same counters as a live read-only mapping (field name → count).

        For a caller reading a few of them on every step (the node's
        diagnostics): it costs nothing to get, where :attr:`counters` builds
        an :class:`EstimatorCounters`.
        """
        return self._counts

    @property
    def fault(self) -> str | None:
        """Why the filter was last found diverged, until it is consistent again; None when healthy.

        Always None without ``config.divergence``.
        """
        return None if self._monitor is None else self._monitor.fault

    @property
    def last_estimate(self) -> SoilStiffnessEstimate | None:
        """The most recent estimate, or None."""
        return self._last

    @property
    def pending_steps(self) -> int:
        """Accelerometer samples waiting for profile coverage."""
        return len(self._pending)

    def drain_estimates(self) -> list[SoilStiffnessEstimate]:
        """Every estimate produced since the last drain, oldest first (≤ 10 000 kept)."""
        if not self._outbox:  # the common case: a node drains after every message
            return []
        out = list(self._outbox)
        self._outbox.clear()
        return out

    def add_profile_sample(
        self,
        t: float,
        distance: float,
        elevation: float,
    ) -> SoilStiffnessEstimate | None:
        """Buffer one profile sample and run the queued steps it completes.

        Args:
            t: stamp (s) of the elevation under the tire.
            distance: distance travelled (m), increasing; checked, kept for
                diagnostics (ḣ is derived in time, since the contract stamps the
                elevation under the tire at the stamp's time).
            elevation: terrain elevation h (m).

        Returns:
            The newest estimate produced by this call, or None.

        Non-finite values and stamps not after the previous profile sample
        are rejected (``counters.profile_rejected``).
        """
        t, s, h = float(t), float(distance), float(elevation)
        if not (math.isfinite(t) and math.isfinite(s) and math.isfinite(h)):
            self._c["profile_rejected"] += 1
            return None
        if self._pt and t <= self._pt[-1] + _EPS_T:
            self._c["profile_rejected"] += 1
            return None
        self._pt.append(t)
        self._ph.append(h)
        self._ps.append(s)
        self._last_distance = s
        if not self._pending or t < self._profile_wait:
            return None  # nothing queued, or the queued step still waits for the profile (see _process_pending)
        return self._process_pending()

    def add_accelerations(
        self, t: float, body_specific_force_z: float, wheel_specific_force_z: float | None = None
    ) -> SoilStiffnessEstimate | None:
        """Queue one accelerometer sample and run every step that is ready.

        Args:
            t: stamp (s).
            body_specific_force_z: sprung-mass accelerometer, specific force
                along z including gravity (m/s², ≈ +9.81 at rest, REP 145).
            wheel_specific_force_z: unsprung-mass accelerometer (2-DOF); None
                (or non-finite) → body-only update. Ignored for the LRV.

        Returns:
            The newest estimate produced by this call, or None when no step
            could run (first sample, waiting for the profile, dropped sample:
            see the module docstring and :attr:`counters`).
        """
        t, fb = float(t), float(body_specific_force_z)
        if not (math.isfinite(t) and math.isfinite(fb)):
            self._c["dropped_nonfinite"] += 1
            return None
        fw: float | None = None
        if wheel_specific_force_z is not None and self._body_only is not None:
            fw = float(wheel_specific_force_z)
            if not math.isfinite(fw):
                self._c["dropped_nonfinite"] += 1
                fw = None
        last_t = self._pending[-1][0] if self._pending else self._t_prev
        if last_t is not None and t <= last_t + _EPS_T:
            self._c["dropped_out_of_order"] += 1
            return None
        g = self.config.gravity
        zw = None if fw is None else fw - g
        self._pending.append((t, fb - g, zw))
        self._newest_acc_t = max(self._newest_acc_t, t)
        while len(self._pending) > self.config.max_pending:
            self._pending.popleft()
            self._c["dropped_queue_full"] += 1
        return self._process_pending()

    # -- internals ------------------------------------------------------------
    def _initial_state(self, stiffness: float, var: float | None) -> Any:
        """Motion states at rest with P0; the stiffness state (model units) and its variance."""
        n = self.model.state_dim
        x0 = np.zeros(n)
        x0[-1] = stiffness
        p0 = self._p0.copy()
        if var is not None and math.isfinite(var) and var > 0:
            p0[-1] = min(var, self.model.stiffness_state_max_variance)
        return self.filter.initial_state(x0, np.diag(p0))

    def _make_detector(self) -> SoilChangeDetector:
        """The soil-change detector of the configuration, re-open bounds in the stiffness state's units."""
        cfg = self.config
        floor = (
            cfg.change_log_ks_std
            if self.model.stiffness_state == "log_k_s"
            else cfg.change_ktot_std_frac * self.model.k_series
        )
        return SoilChangeDetector(
            cfg.change_drift,
            cfg.change_threshold,
            reopen_scale=cfg.change_reopen_scale,
            reopen_min_std=floor,
            # Never more uncertain than at the start.
            reopen_max_std=max(math.sqrt(float(self._p0[-1])), floor, 1e-300),
            clip=cfg.change_clip,
        )

    def _restart_motion(self) -> None:
        """Motion states back to rest with P0; keep the last finite stiffness estimate."""
        k, var = self._stiffness0, None
        if self._state is not None:
            x = np.asarray(self._state.x, dtype=float)
            p = np.asarray(self._state.covariance, dtype=float)
            if math.isfinite(x[-1]) and math.isfinite(p[-1, -1]):
                k, var = self.model.project_stiffness_state(x[-1]), float(p[-1, -1])
        self._state = self._initial_state(k, var)

    def _ready(self, t: float) -> str:
        """'ready' | 'wait' | 'extrapolate' | 'drop' for a step ending at ``t``."""
        need = t + max(self._smooth_half_w, self._hdot_half_window(t))
        if self._pt and self._pt[-1] >= need - _EPS_T:
            return "ready"
        if self._newest_acc_t - t <= self.config.max_wait_s + _EPS_T:
            return "wait"
        if self._pt and self._pt[-1] >= need - self.config.max_extrapolation_s:
            return "extrapolate"
        return "drop"

    def _process_pending(self) -> SoilStiffnessEstimate | None:
        produced: SoilStiffnessEstimate | None = None
        self._profile_wait = -math.inf
        while self._pending:
            t, zb, zw = self._pending[0]
            if self._t_prev is None:
                # First sample: the time origin; the road must be known from here on.
                if self._pt and self._pt[0] <= t + _EPS_T:
                    self._pending.popleft()
                    self._t_prev = t
                    self._state = self._initial_state(self._stiffness0, None)
                    if self._monitor is not None:
                        self._monitor.start(self._state)
                    continue
                if self._pt or self._ready(t) == "drop":
                    self._pending.popleft()
                    self._c["dropped_no_profile"] += 1
                    continue
                break
            dt = t - self._t_prev
            if dt < self._min_dt:
                self._pending.popleft()
                self._c["decimated"] += 1
                continue
            if dt > self.config.max_step_s:
                self._pending.popleft()
                self._restart_motion()
                self._c["restarts"] += 1
                self._t_prev = t
                self._prune()
                continue
            status = self._ready(t)
            if status == "wait":
                if self._pt and (not self._hdot_fit or self._pt[-1] > t):
                    # The coverage this step needs is final (the ḣ window's
                    # speed is read from samples up to t): until a profile
                    # sample reaches it, or an accelerometer sample (which may
                    # end the wait) arrives, _ready would say "wait" again, so
                    # add_profile_sample skips the queue below this stamp.
                    self._profile_wait = t + max(self._smooth_half_w, self._hdot_half_window(t)) - _EPS_T
                break
            self._pending.popleft()
            if status == "drop":
                self._c["dropped_no_profile"] += 1
                continue
            est = self._step(t, dt, zb, zw)
            produced = est
        return produced

    def _profile_window(self, t0: float, t1: float) -> tuple[Array, Array]:
        """The buffered samples a reconstruction over ``[t0, t1]`` can touch, as arrays.

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
            ``(pt, ph)``: the window's stamps and elevations.
        """
        lo = max(bisect.bisect_left(self._pt, t0) - 2, 0)
        hi = bisect.bisect_right(self._pt, t1, lo) + 2
        return np.array(self._pt[lo:hi]), np.array(self._ph[lo:hi])

    def _profile_on_grid(self, grid: Array) -> tuple[Array, float]:
        """Elevation on the sub-step grid and the largest profile gap over it."""
        w = self._smooth_half_w
        g0, g1 = float(grid[0]), float(grid[-1])
        # The window of _profile_window, kept as a list too for the gap search.
        lo = max(bisect.bisect_left(self._pt, g0 - w) - 2, 0)
        hi = bisect.bisect_right(self._pt, g1 + w, lo) + 2
        st = self._pt[lo:hi]
        pt, ph = np.array(st), np.array(self._ph[lo:hi])
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
        as numpy forms it), computed on the list: the buffer is short (tens
        to a few hundred samples) and numpy's median costs ≈ 10 µs of call
        overhead per step.
        """
        pt = self._pt
        n = len(pt) - 1
        if n < 1:
            return 0.0
        d = sorted(map(operator.sub, pt[1:], pt))
        mid = n // 2
        return d[mid] if n % 2 else (d[mid - 1] + d[mid]) / 2.0

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
        # Buffer indices below are relative to the window (lo_h, lo_d alike).
        reach = max(self._smooth_half_w, half)
        var = self.config.profile_noise_std**2
        if reach == 0.0:
            # Neither fit: h(t) is interpolated (or extrapolated) between two
            # samples, whose weights are read off the buffer list: the same
            # samples and float operations as on the window's arrays, without
            # converting them (the quarter car's every step).
            w_h = self._interpolation_weights(t)
            var_h = var * float(w_h @ w_h)
            return None, self._extrapolated_road_cov(var_h, u_sub.size, delta)
        pt, ph = self._profile_window(t - reach, t + reach)
        # Weights of the elevation at t, as _profile_on_grid reconstructs it
        # (for the variance only: the local-fit case is approximated by the
        # fit over the same window).
        if t > pt[-1]:
            if pt.size >= 2:
                beta = (t - pt[-1]) / (pt[-1] - pt[-2])
                lo_h, w_h = pt.size - 2, np.array([-beta, 1.0 + beta])
            else:
                lo_h, w_h = 0, np.ones(1)
        else:
            fit = _fit_weights(pt, t, self._smooth_half_w, 2) if self._smooth_half_w > 0.0 else None
            if fit is not None:
                lo_h, w_h = fit[0], fit[1]
            else:
                i = int(pt.searchsorted(t, side="right"))
                if i >= pt.size or i == 0:
                    lo_h, w_h = min(max(i - 1, 0), pt.size - 1), np.ones(1)
                else:
                    a = (t - pt[i - 1]) / (pt[i] - pt[i - 1])
                    lo_h, w_h = i - 1, np.array([1.0 - a, a])
        var_h = var * float(w_h @ w_h)
        hdot_end: float | None = None
        fit = None
        if half > 0.0:
            for degree in range(_HDOT_DEGREE, 0, -2):  # fewer samples: a lower (odd) degree
                fit = _fit_weights(pt, t, half, degree)
                if fit is not None:
                    break
        if fit is not None:
            lo_d, _, w_d = fit
            hdot_end = float(w_d @ ph[lo_d : lo_d + w_d.size])
            var_d = var * float(w_d @ w_d)
            a, b = max(lo_h, lo_d), min(lo_h + w_h.size, lo_d + w_d.size)
            cov = var * float(w_h[a - lo_h : b - lo_h] @ w_d[a - lo_d : b - lo_d]) if b > a else 0.0
        else:
            return None, self._extrapolated_road_cov(var_h, u_sub.size, delta)
        return hdot_end, np.array([[var_h, cov], [cov, var_d]])

    @staticmethod
    def _extrapolated_road_cov(var_h: float, n_sub: int, delta: float) -> Array:
        """Σ_ε when ḣ(t) is the model's extrapolation of the last sub-step slopes."""
        # 1.5 u_{N−1} − 0.5 u_{N−2} = (1.5 h_N − 2 h_{N−1} + 0.5 h_{N−2})/δ,
        # grid elevations about as noisy as the one at t.
        var_d = 6.5 * var_h / delta**2 if n_sub >= 2 else 2.0 * var_h / delta**2
        cov = (1.5 if n_sub >= 2 else 1.0) * var_h / delta
        return np.array([[var_h, cov], [cov, var_d]])

    def _interpolation_weights(self, t: float) -> Array:
        """Weights of the two samples (or one) that ``_profile_on_grid`` reconstructs ``h(t)`` from, without smoothing.

        Read off the buffer list; the values of the window-array form of
        :meth:`_road_at_measurement` (the window holds every sample the
        bisections below find, at the same positions relative to each other).
        """
        pt = self._pt
        last = pt[-1]
        if t > last:
            if len(pt) >= 2:
                beta = (t - last) / (last - pt[-2])
                return np.array([-beta, 1.0 + beta])
            return np.ones(1)
        i = bisect.bisect_right(pt, t)
        if i >= len(pt) or i == 0:
            return np.ones(1)
        a = (t - pt[i - 1]) / (pt[i] - pt[i - 1])
        return np.array([1.0 - a, a])

    def _measurement_noise_sqrt(self, x: Array, rows: int, sigma_eps: Array) -> Array:
        """``√R_eff``, ``R_eff = R + G Σ_ε Gᵀ`` with ``G`` the model's road-error gains.

        ``R`` of the first ``rows`` measurements is the model's constant
        ``√R √Rᵀ``, formed once per size. The factor is LAPACK ``dpotrf``
        called directly (the routine ``np.linalg.cholesky`` calls, at a
        fraction of its wrapper's cost); a matrix that is not positive
        definite raises ``numpy.linalg.LinAlgError`` as ``cholesky`` does.
        """
        base = self._r_base.get(rows)
        if base is None:
            rs = self.model.measurement_noise_sqrt()[:rows, :rows]
            # [g_h, g_ḣ] with the constant g_ḣ = D filled in (g_h is C(x̄) B, per step).
            gain0 = np.zeros((rows, 2))
            gain0[:, 1] = self.model.profile_error_gains(x)[1][:rows]
            base = self._r_base[rows] = (rs @ rs.T, gain0)
        r, gain0 = base
        gain = gain0.copy()
        gain[:, 0] = self.model._road_gain(x)[:rows]
        r_eff = r + gain @ sigma_eps @ gain.T
        factor, info = _dpotrf(0.5 * (r_eff + r_eff.T), lower=1, clean=1)
        if info != 0:
            raise np.linalg.LinAlgError("Matrix is not positive definite")
        return np.asarray(factor)

    def _prune(self) -> None:
        """Drop profile samples no step needs: keep the last one at or before t_prev − w/2."""
        if self._t_prev is None or len(self._pt) < 64:
            return
        keep_from = bisect.bisect_right(self._pt, self._t_prev - self._keep_s) - 1
        if keep_from > 32:
            del self._pt[:keep_from]
            del self._ph[:keep_from]
            del self._ps[:keep_from]

    def _step(self, t: float, dt: float, zb: float, zw: float | None) -> SoilStiffnessEstimate:
        cfg = self.config
        assert self._t_prev is not None
        n_sub = max(1, math.ceil(dt * cfg.substep_rate_hz - 1e-6))
        grid = self._t_prev + _grid_offsets(dt, n_sub)
        hg, max_gap = self._profile_on_grid(grid)
        spacing = self._profile_spacing()
        gap_ratio = max_gap / spacing if spacing > 0.0 else 1.0
        u_sub = (hg[1:] - hg[:-1]) / (dt / n_sub)  # np.diff(hg), one call fewer
        hdot_end, sigma_eps = self._road_at_measurement(t, u_sub, dt / n_sub)
        u: Any = StepInput(u_sub, hdot_end) if self._feedthrough else u_sub
        self._t_prev = t
        self._prune()
        self._c["steps"] += 1

        prev_state = self._state
        prior: Any
        post: Any
        nis, accepted = 0.0, False
        update_dim = 0  # measurement size of the update (0: predict-only or failed)
        failed = False
        try:
            if self.filter is self._sckf:
                prior, post, nis, accepted, update_dim = self._sckf_step(prev_state, u, dt, max_gap, zb, zw, sigma_eps)
            else:
                prior, post, nis, accepted, update_dim = self._filter_step(
                    prev_state, u, dt, max_gap, zb, zw, sigma_eps
                )
        except (ValueError, np.linalg.LinAlgError):
            # The filters raise on non-finite model output or a broken factor:
            # handled below exactly like a non-finite posterior.
            prior = post = _NonFinite(self.model.state_dim)
            nis, accepted = 0.0, False
            failed = True
        monitor_nis = nis
        if not math.isfinite(nis):
            nis = 0.0

        x = np.asarray(post.x, dtype=float)
        cov = np.asarray(post.covariance, dtype=float)
        # The filter's own correction of the stiffness (before any projection into its range)
        # is what the soil-change detector whitens.
        s_filter = float(x[-1])
        if self._monitor is not None:
            x, cov, accepted, nis = self._watch(post, x, cov, failed, update_dim, monitor_nis, accepted, nis)
        elif not (all(map(math.isfinite, x.tolist())) and np.isfinite(cov).all()):
            self._c["recoveries"] += 1
            self._state = prev_state
            self._restart_motion()
            accepted, nis = False, 0.0
            x = np.asarray(self._state.x, dtype=float)
            cov = np.asarray(self._state.covariance, dtype=float)
        else:
            k_c = self.model.project_stiffness_state(float(x[-1]))
            if k_c != x[-1]:
                # Projection of the mean into the physical range (0, k_series).
                x = x.copy()
                x[-1] = k_c
                post = dataclasses.replace(post, x=x)
            self._state = post

        change = False
        if accepted:
            # Soil-change detector (estimators.soil_change), armed from the first update.
            cov_prior = np.asarray(prior.covariance, dtype=float)
            alarm = self._detector.update(
                float(np.asarray(prior.x, dtype=float)[-1]), float(cov_prior[-1, -1]), s_filter, float(cov[-1, -1])
            )
            if alarm is not None:
                change = True
                self._c["soil_changes"] += 1
                self.last_change = alarm
                if self._jump_gain > 0.0:
                    # Move the mean to the implied new soil (GLR correction), by at most the
                    # initial std: the jump is a linearisation at the old soil, and a wild one
                    # (a few noisy updates) must not throw k̂_s further than the start guess was.
                    cap = self._detector.reopen_max_std
                    move = self._jump_gain * min(max(alarm.jump, -cap), cap)
                    x = x.copy()
                    x[-1] = self.model.project_stiffness_state(float(x[-1]) + move)
                    self._state = self.filter.initial_state(x, cov)
                if alarm.reopen_std > 0.0:
                    # Re-open the stiffness variance by the innovation-implied jump: with
                    # the small per-step random walk (A.4) the filter would need seconds
                    # to walk to the new soil; with it, a few updates.
                    # The motion states were estimated with the old soil's stiffness since
                    # the change: their variance grows by its initial value (P0) too.
                    cov = cov + np.diag(np.r_[self._p0[:-1], alarm.reopen_std**2])
                    self._state = self.filter.initial_state(x, cov)

        k_tot, k_var, k_s, k_s_var = self.model.stiffness_moments(float(x[-1]), float(cov[-1, -1]))
        cls = classify_soil(k_s, k_s_var, cfg.soil_table, cfg.class_log_std, cfg.unknown_weight)
        converged = math.sqrt(k_s_var) < cfg.convergence_rel_std * k_s

        state = tuple(x.tolist())
        if not all(map(math.isfinite, state)):
            state = tuple(v if math.isfinite(v) else 0.0 for v in state)
        est = SoilStiffnessEstimate(
            t=t,
            k_s=k_s,
            k_s_variance=k_s_var,
            k_tot=k_tot,
            k_tot_variance=k_var,
            terrain_class=cls.name,
            class_confidence=cls.confidence,
            converged=bool(converged),
            soil_change_detected=change,
            nis=nis,
            accepted=accepted,
            state=state,
            profile_gap_ratio=float(gap_ratio) if math.isfinite(gap_ratio) else 1.0,
        )
        self._last = est
        self._outbox.append(est)
        return est

    def _measurement(self, zb: float, zw: float | None) -> tuple[Any, Array]:
        """The model and measurement vector of an update: both accelerometers, or the body's alone."""
        if self._body_only is None:
            return self.model, np.array([zb])
        if zw is None:
            return self._body_only, np.array([zb])
        return self.model, np.array([zb, zw])

    def _filter_step(
        self, prev_state: Any, u: Any, dt: float, max_gap: float, zb: float, zw: float | None, sigma_eps: Array
    ) -> tuple[Any, Any, float, bool, int]:
        """Predict and (unless the profile has a gap) update with any filter: ``(prior, post, nis, accepted, dim)``.

        ``dim`` is the measurement size of the update (0 for predict-only).
        Raises what the filter raises (ValueError, LinAlgError).
        """
        cfg = self.config
        nis, accepted = 0.0, False
        update_dim = 0
        prior = self.filter.predict(prev_state, self.model, u, dt)
        post = prior
        if max_gap > cfg.profile_max_gap_s:
            self._c["predict_only"] += 1
            return prior, post, nis, accepted, update_dim
        model, z = self._measurement(zb, zw)
        if cfg.profile_noise_std > 0.0:
            rs = self._measurement_noise_sqrt(np.asarray(prior.x), z.size, sigma_eps)
            post, info = self.filter.update(prior, z, model, u, measurement_noise_sqrt=rs)
        else:
            post, info = self.filter.update(prior, z, model, u)
        nis = float(info.nis)
        accepted = bool(info.accepted)
        update_dim = z.size
        if accepted and cfg.gate_threshold is not None and not (nis <= cfg.gate_threshold):
            accepted = False
        if not accepted:
            self._c["gated"] += 1
            post = prior
        else:
            self._c["updates_accepted"] += 1
        return prior, post, nis, accepted, update_dim

    def _sckf_step(
        self,
        prev_state: SqrtGaussianState,
        u: Any,
        dt: float,
        max_gap: float,
        zb: float,
        zw: float | None,
        sigma_eps: Array,
    ) -> tuple[SqrtGaussianState, SqrtGaussianState, float, bool, int]:
        """:meth:`_filter_step` for the default SCKF, in one compiled call (:func:`.soil_stiffness_sckf.sckf_step`).

        The same filter and model as the SCKF's public ``predict``/``update``
        with the model's methods, to rounding (about 1e-13 relative): the
        numpy form of a 5-state step is mostly per-call overhead. A failed
        step (non-finite points, ``R_eff`` not positive definite) raises
        ValueError, as the public methods raise there.
        """
        cfg = self.config
        ops = self._operands
        assert ops is not None and self._sckf is not None
        update = max_gap <= cfg.profile_max_gap_s
        z = self._measurement(zb, zw)[1] if update else None
        status, x_pred, S_pred, nis, accepted, x_post, S_post = run_step(
            ops,
            self.model,
            prev_state.x,
            prev_state.S,
            u,
            dt,
            z,
            sigma_eps,
            cfg.profile_noise_std > 0.0,
            self._sckf.gate_threshold,
        )
        if status != STATUS_OK:
            raise ValueError("SCKF step failed: non-finite points or a measurement noise that is not positive definite")
        prior = SqrtGaussianState(x=x_pred, S=S_pred)
        if z is None:
            self._c["predict_only"] += 1
            return prior, prior, 0.0, False, 0
        if accepted and cfg.gate_threshold is not None and not (nis <= cfg.gate_threshold):
            accepted = False
        if not accepted:
            self._c["gated"] += 1
            return prior, prior, nis, False, z.size
        self._c["updates_accepted"] += 1
        return prior, SqrtGaussianState(x=x_post, S=S_post), nis, True, z.size

    def _watch(
        self,
        post: Any,
        x: Array,
        cov: Array,
        failed: bool,
        update_dim: int,
        monitor_nis: float,
        accepted: bool,
        nis: float,
    ) -> tuple[Array, Array, bool, float]:
        """The step's posterior under the divergence monitor; sets ``self._state``.

        The stiffness mean is projected into its range first (as without a
        monitor), so the last good estimate is always a projected one. On a
        divergence (including a failed filter step or a non-finite posterior)
        the state is re-initialised from the last good estimate and the
        update counts as not accepted.

        Returns:
            ``(x, cov, accepted, nis)`` of the state kept.
        """
        monitor = self._monitor
        assert monitor is not None
        info = None
        if not failed:
            if np.all(np.isfinite(x)):
                k_c = self.model.project_stiffness_state(float(x[-1]))
                if k_c != x[-1]:
                    x = x.copy()
                    x[-1] = k_c
                    post = dataclasses.replace(post, x=x)
            if update_dim:
                info = UpdateInfo(
                    innovation=np.zeros(update_dim),
                    innovation_cov=np.eye(update_dim),
                    nis=monitor_nis,
                    accepted=accepted,
                )
        self._state, check = monitor.supervise(
            self.filter, post, info, failure="filter step failed" if failed else None
        )
        if not check.diverged:
            return x, cov, accepted, nis
        self._c["divergences"] += 1
        self._detector.reset()
        return (
            np.asarray(self._state.x, dtype=float),
            np.asarray(self._state.covariance, dtype=float),
            False,
            0.0,
        )
