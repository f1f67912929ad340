"""Soil-stiffness estimator core: queue, profile buffer, filter, soil reporting.

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

The road of a step (the sub-step input, ḣ at the measurement time, the
covariance of the profile errors, and how profile noise enters the
measurement noise) is :mod:`.soil_road`'s; the filter step (the compiled SCKF
and EKF, or any filter's public methods) is :mod:`.soil_filter_step`'s; the
configuration and outputs are :mod:`.soil_stiffness_config`'s (importable from
here).

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

import dataclasses
import math
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from types import MappingProxyType
from typing import Any

import numpy as np

from terrain_estimation.estimators.soil_change import ChangeAlarm, SoilChangeDetector
from terrain_estimation.estimators.soil_filter_step import FilterSteps
from terrain_estimation.estimators.soil_road import _EPS_T, _HDOT_MAX_WINDOW_S, ProfileRoad, _grid_offsets
from terrain_estimation.estimators.soil_road_fit import warm_up_fits
from terrain_estimation.estimators.soil_stiffness_config import (
    _P0_LRV,
    _P0_QUARTER_CAR,
    FILTER_CLASSES,
    P0_LOG_KS,
    EstimatorCounters,
    SoilStiffnessEstimate,
    SoilStiffnessEstimatorConfig,
    make_filter,
    soil_estimate,
)
from terrain_estimation.estimators.soil_stiffness_ekf import warm_up_ekf
from terrain_estimation.estimators.soil_stiffness_kernels import model_operands
from terrain_estimation.estimators.soil_stiffness_sckf import warm_up
from terrain_estimation.filters.base import Array, UpdateInfo
from terrain_estimation.filters.faults import DivergenceMonitor
from terrain_estimation.models.quarter_car import LRVModel, QuarterCarModel, StepInput

__all__ = [
    "SoilStiffnessEstimatorConfig",
    "SoilStiffnessEstimate",
    "EstimatorCounters",
    "SoilStiffnessEstimator",
    "make_filter",
    "FILTER_CLASSES",
    "P0_LOG_KS",
    "set_compiled_steps",
]


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


class _NonFinite:
    """Stand-in posterior after a filter exception (triggers the recovery path)."""

    def __init__(self, n: int) -> None:
        self.x = np.full(n, np.nan)
        self.covariance = np.full((n, n), np.nan)


#: The filters that estimators built without ``compiled=`` run as a compiled step (:func:`set_compiled_steps`).
_compiled_filters: frozenset[str] = frozenset({"sckf", "ekf"})


def set_compiled_steps(filters: Iterable[str]) -> frozenset[str]:
    """Which filters (``"sckf"``, ``"ekf"``) estimators built from now on in this process run compiled; returns the
    previous set.

    For benchmarks and comparisons that build estimators through code they do
    not control (a reproduction's run function in a worker process): a filter
    left out runs through its public numpy ``predict``/``update``, the
    reference path. An estimator's own ``compiled=`` argument takes precedence.
    """
    global _compiled_filters
    previous = _compiled_filters
    chosen = frozenset(filters)
    unknown = chosen - {"sckf", "ekf"}
    if unknown:
        raise ValueError(f"no compiled step for {sorted(unknown)}; expected 'sckf' and/or 'ekf'")
    _compiled_filters = chosen
    return previous


class SoilStiffnessEstimator(ProfileRoad, FilterSteps):
    """Soil stiffness from ride vibration: the ROS-free core (see module docstring).

    Args:
        config: the configuration; defaults to the 2-DOF quarter car with SCKF.
        filter_impl: a filter object to use instead of ``make_filter(config.filter)``
            (tests, or a filter configured beyond its defaults); it runs through
            its public ``predict``/``update``.
        compiled: run the default SCKF and EKF as one compiled call per step
            (:mod:`.soil_stiffness_sckf`, :mod:`.soil_stiffness_ekf`; the same
            results to rounding); False: the filters' public numpy
            ``predict``/``update`` (the reference path, for benchmarks and
            identity tests). None: the process default,
            :func:`set_compiled_steps` (both compiled unless changed).

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
        compiled: bool | None = None,
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
        # The default SCKF and EKF run as one compiled step (_compiled_step,
        # with the model's constants in _operands; not for the
        # "expm" discretisation); any other filter, a filter_impl, or a filter
        # swapped in later through the public predict/update (_filter_step).
        self._operands = model_operands(self.model)
        use_compiled = cfg.filter in _compiled_filters if compiled is None else bool(compiled)
        fast = filter_impl is None and self._operands is not None and use_compiled
        self._sckf: Any = self.filter if fast and cfg.filter == "sckf" else None
        self._ekf: Any = self.filter if fast and cfg.filter == "ekf" else None
        if self._sckf is not None:
            warm_up()
        if self._ekf is not None:
            warm_up_ekf()
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
        if self._hdot_fit:
            warm_up_fits()
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

    def add_profile_samples(
        self, t: Sequence[float], distance: Sequence[float], elevation: Sequence[float], start: int, stop: int
    ) -> int:
        """:meth:`add_profile_sample` of the samples ``start`` … ``stop − 1`` (stamps in s), the same buffers and
        arithmetic, up to the first one it would reject or that may complete a queued step: that one's index (not
        taken; hand it to :meth:`add_profile_sample`), else ``stop``. For a caller holding the samples as lists
        (an offline ride, a bag's run of profile messages), without a method call per sample."""
        pt, ph, ps = self._pt, self._ph, self._ps
        wait = self._profile_wait if self._pending else math.inf
        after = pt[-1] + _EPS_T if pt else -math.inf  # a stamp must be above this
        isfinite = math.isfinite
        i = start
        while i < stop:
            ti, si, hi = float(t[i]), float(distance[i]), float(elevation[i])
            if not (after < ti < wait and isfinite(ti) and isfinite(si) and isfinite(hi)):
                break
            pt.append(ti)
            ph.append(hi)
            ps.append(si)
            after = ti + _EPS_T
            i += 1
        if i > start:
            self._last_distance = float(distance[i - 1])
        return i

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
            if self.filter is self._sckf or self.filter is self._ekf:
                step = self._compiled_step
            else:
                step = self._filter_step
            prior, post, nis, accepted, update_dim = step(prev_state, u, dt, max_gap, zb, zw, sigma_eps)
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

        moments = self.model.stiffness_moments(float(x[-1]), float(cov[-1, -1]))
        state = tuple(x.tolist())
        if not all(map(math.isfinite, state)):
            state = tuple(v if math.isfinite(v) else 0.0 for v in state)
        est = soil_estimate(
            t,
            moments,
            cfg,
            soil_change_detected=change,
            nis=nis,
            accepted=accepted,
            state=state,
            profile_gap_ratio=float(gap_ratio) if math.isfinite(gap_ratio) else 1.0,
        )
        self._last = est
        self._outbox.append(est)
        return est

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
