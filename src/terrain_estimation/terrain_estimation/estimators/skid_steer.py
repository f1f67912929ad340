"""Skid-steer motion-state estimator core: wheel speeds + IMU → AN-STUKF → SkidSteerState ([SS], MODELS.md Part B).

The ROS-free core that the skid-steer estimator node and the offline bag
runner drive (CONTRACT.md "Skid-steer vehicle"). It owns one
:class:`~terrain_estimation.filters.an_stukf.AdaptiveStrongTrackingUKF`
(variant ``"ukf"``, ``"stukf"`` or ``"an_stukf"``) over an observer model
(``config.model``: the paper's 3-state brush model by default, or one that
absorbs tire-model error: scale states, IMU-driven kinematics; see
:mod:`~terrain_estimation.estimators.skid_steer_config`) for a vehicle with
any number of axles, and turns its motion state ``[vx, vy, r]`` into every
field of ``terrain_msgs/SkidSteerState`` plus a dead-reckoned pose with its
covariance for ``odom``.

Data flow (all times are the ``t`` arguments, in seconds; no wall clock):

* :meth:`SkidSteerEstimator.add_joint_state` buffers the two motor speeds
  (motor side, rad/s); the wheel side is motor ÷ ``transmission_ratio``
  (paper eq. 39; 27.13 for Table 1).
* :meth:`SkidSteerEstimator.add_imu` takes one IMU sample (specific force
  ``a_x, a_y`` in m/s², REP 145, gravity is along z and not used on flat
  ground; yaw rate in rad/s) and runs one filter step from the previous
  step's stamp to ``t`` with ``z = [a_x, a_y, r]``.

**Wheel speeds at any rate.** A step uses the wheel speeds at its IMU stamp
(:mod:`~terrain_estimation.estimators.skid_steer_wheels`): linearly
interpolated between the two samples that bracket it, the newest held
beyond it, within an age limit that follows the measured wheel-speed period
(2.5 periods, at least 0.05 s; or ``max_wheel_speed_age_s``). Further away
they are stale: the IMU sample is not used for a step
(``counters.stale_wheel_speeds``, or ``no_wheel_speeds`` before the first
joint state) and the next step spans the gap. ``counters``
``wheel_speeds_interpolated`` and ``wheel_speeds_held`` say which lookup each
step had, :attr:`SkidSteerEstimator.wheel_speed_period_s` the measured
period. With ``wheel_speed_wait_s`` > 0 an IMU sample newer than the newest
wheel speeds waits (up to that long) for the next one, to be interpolated.

**Load model input.** The quasi-static wheel loads (B.5) take the measured
``a_x, a_y`` through a first-order low-pass (``accel_cutoff_hz``, default
2 Hz: passes the manoeuvre, removes vibration, and roughly mimics the lag of
the real body's pitch/roll load transfer). A step uses the low-pass output
*before* the step's own sample, so the input does not contain the
measurement noise of the update it feeds. The kinematic models' process
takes the raw IMU sample before the step's own.

**Standing still.** Wheels stopped and the IMU quiet over a short window
(:mod:`~terrain_estimation.estimators.skid_steer_zupt`) add a zero-velocity
update after the step (``counters.zero_velocity_updates``; the estimate's
``stationary``).

**Initialisation and restarts.** The first IMU sample with usable wheel
speeds initialises the filter at ``initial_state`` or, by default, at the
encoder-only speed ``R(ω_l + ω_r)/2``, ``vy = 0`` and the measured yaw rate,
with covariance ``diag(p0_diag)`` (scale states at 1 with
``tire_scales.initial_std``; a restart keeps their last estimate); it
produces an estimate (no update). A gap longer than ``max_step_s`` since the
last step restarts the same way (``counters.restarts``): explicit Euler over
a long gap at low rolling speed would need hundreds of sub-steps, and the
state has moved on anyway.

**Never NaN.** Non-finite arguments raise ValueError naming the field and
its value (the caller's bug or a broken driver; nothing is stored). If a
filter step fails (non-finite model output, a step needing more than
``max_substeps`` sub-steps, a broken factorisation) or leaves a non-finite
state, the filter re-initialises from the last good estimate's mean with
the initial covariance and a fresh strong-tracking memory
(``counters.recoveries``). Every float of an estimate is finite: the ICR is
0 with ``icr_valid = False`` for ``|r| ≤ min_yaw_rate``, the variance of the
body sideslip is capped at π².

**Divergence (issue 7).** With ``config.divergence`` set, a
:class:`~terrain_estimation.filters.faults.DivergenceMonitor` also watches
for a filter that stays finite but diverges: a variance above
``max_variance_growth`` times its initial one (covariance blow-up), the
windowed mean NIS above its χ² band, a gate lock-out. On any fault,
including a failed step or a non-finite state, the filter re-initialises
from the *last good* estimate (the newest one whose NIS window was inside
its band) with the initial covariance and a fresh strong-tracking memory
(``counters.divergences`` instead of ``recoveries``;
:attr:`SkidSteerEstimator.fault` holds the reason until a new window is
consistent). The low side of the band (``DivergenceConfig.check_low``) is
refused for the AN-STUKF, whose adaptive noise rescales R with the tire
sideslip, and fires on healthy data for every variant with the default
``r0_diag``: the mean NIS is 0.13–0.26 against 3 on the shipped bags, and
the node keeps it off.

**Physical limits (issue 19).** No estimate leaves the vehicle's envelope
``max_speed`` (planar speed ``√(vx² + vy²)``, m/s) and ``max_yaw_rate``
(``|r|``, rad/s). A step whose posterior mean lies beyond it is a divergence
(``counters.limit_resets`` and ``counters.divergences``): the filter restarts
from the wheel odometry and the gyro, not from the bad state (``vx`` = the
encoder speed, ``vy = 0``, ``r`` = the measured yaw rate, each clipped to the
envelope; covariance ``diag(p0_diag)``), that restart is the estimate of the
step (``initialised``), and :attr:`SkidSteerEstimator.fault` names the limit
for ``fault_hold_s`` of stamps after the last one. The runaway this stops
(BorealTC Husky, deep snow and bumps): when the brush forces of the state
saturate, ``h`` no longer depends on the speed's magnitude; accelerations the
tires cannot produce (bumps of 2–6 g, sides spinning against a body that does
not turn) keep the innovation large, the strong-tracking fading factor sits
at ``λ_max`` step after step and multiplies the covariance by it each time,
and ``|v|`` grew to 1e155 m/s. ``config/husky.yaml`` sets the measured IMU
noise and ``lambda_max`` 2 for such data.

**Outputs.** :meth:`~SkidSteerEstimator.add_imu` returns the estimate its
step produced (None if none; :class:`SkidSteerEstimate` and the counters are
in :mod:`~terrain_estimation.estimators.skid_steer_estimate`); every estimate also goes to an outbox read
by :meth:`~SkidSteerEstimator.drain_estimates`. The body sideslip variance
is the first-order propagation of the ``(vx, vy)`` covariance through
``β = atan2(vy, vx)``. The pose (``x, y, yaw`` in the odom frame, origin at
the first sample) integrates the estimated twist with the trapezoidal rule
and the mid-step heading, its covariance through the same map's Jacobians
(:mod:`~terrain_estimation.estimators.skid_steer_odometry`). The tire
sideslip of all 2N wheels is ``wheel_tire_sideslip``; ``tire_sideslip`` is
the contract's six (front, middle, rear per side; for N ≠ 3 the middle is
interpolated, :func:`~terrain_estimation.models.skid_steer.contract_tire_sideslip`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import numpy as np

from terrain_estimation.estimators.skid_steer_compiled import STATUS_OK, CompiledSkidSteerStep, warm_up
from terrain_estimation.estimators.skid_steer_config import MODELS, SkidSteerEstimatorConfig
from terrain_estimation.estimators.skid_steer_consider import ConsiderCovariance
from terrain_estimation.estimators.skid_steer_estimate import (
    SkidSteerCounters,
    SkidSteerEstimate,
    body_sideslip_variance,
    contract_mapping,
    map_contract,
)
from terrain_estimation.estimators.skid_steer_odometry import DeadReckoning
from terrain_estimation.estimators.skid_steer_wheels import WheelSpeedBuffer
from terrain_estimation.estimators.skid_steer_zupt import StationaryDetector, zero_velocity_update
from terrain_estimation.filters.an_stukf import AdaptiveStrongTrackingUKF, AnStukfResult
from terrain_estimation.filters.base import Array, GaussianState, UpdateInfo
from terrain_estimation.filters.faults import DivergenceMonitor
from terrain_estimation.models.skid_steer_kinematic import KinematicInput
from terrain_estimation.models.skid_steer_observer import (
    SkidSteerInput,
    _derived_values,
    _wheel_xy,
    encoder_kinematics,
)

__all__ = [
    "MODELS",
    "SkidSteerEstimatorConfig",
    "SkidSteerEstimate",
    "SkidSteerCounters",
    "SkidSteerEstimator",
]

#: Joint-state samples kept for the wheel-speed lookup.
_JOINT_BUFFER = 64


def _finite(where: str, name: str, value: Any) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{where}: {name} must be finite, got {value!r}")
    return v


class SkidSteerEstimator:
    """Motion states of a skid-steered vehicle from wheel speeds and the IMU (module docstring).

    Args:
        config: settings; defaults are the AN-STUKF with the B.10 noise on the paper's vehicle.
    """

    def __init__(self, config: SkidSteerEstimatorConfig | None = None) -> None:
        self.config = config if config is not None else SkidSteerEstimatorConfig()
        cfg = self.config
        self.model = cfg.make_model()
        self.filter = cfg.make_filter()
        self._n_scales = len(cfg.scale_states)
        p0 = np.zeros((3 + self._n_scales, 3 + self._n_scales))
        p0[:3, :3] = np.diag(np.array(cfg.p0_diag, dtype=float))
        if self._n_scales:
            p0[3:, 3:] = self.model.initial_scale_covariance()
        self._p0 = p0
        self._consider = ConsiderCovariance.for_estimator(cfg.consider, cfg, self.model)
        self._friction = cfg.friction
        self._kinematic = cfg.model.startswith("kinematic")
        # Per-step constants of _estimate.
        self._wheel_xy = _wheel_xy(cfg.vehicle)
        self._speed_floor_sq = cfg.vehicle.rolling_speed_floor**2
        self._min_sideslip_speed_sq = cfg.min_sideslip_speed**2
        self._contract_map = contract_mapping(cfg)
        # The compiled filter + consider step (estimators.skid_steer_compiled) where it applies: the
        # "adaptive" filter over a brush model. It runs while ``filter`` and ``model`` are the ones it was
        # built for and ``use_compiled`` is True; the Python step remains the reference and runs otherwise
        # (and for any step the compiled one hands back).
        self._compiled = (
            None if self._kinematic else CompiledSkidSteerStep.for_estimator(self.filter, self.model, self._consider)
        )
        self._compiled_filter = self.filter
        #: Run the compiled step where it applies (False: the Python step only, the reference path).
        self.use_compiled = self._compiled is not None
        if self._compiled is not None:
            warm_up(self._compiled)
        self.reset()

    # -- public API ---------------------------------------------------------------
    def reset(self) -> None:
        """Forget the state, the buffers, the pose, the outbox and the counters."""
        cfg = self.config
        self._state: GaussianState | None = None
        self._memory: Array | None = None
        self._t_prev: float | None = None
        self._t_last_imu: float | None = None
        self._a_lp: tuple[float, float] | None = None
        self._a_raw_prev: tuple[float, float] | None = None
        self._gyro_prev = 0.0
        self._wheels = WheelSpeedBuffer(
            cfg.wheel_speed_interpolation,
            max_age_s=cfg.max_wheel_speed_age_s,
            age_periods=cfg.wheel_speed_age_periods,
            min_age_s=cfg.min_wheel_speed_age_s,
            capacity=_JOINT_BUFFER,
        )
        self._pending: deque[tuple[float, Array, tuple[float, float]]] = deque()
        self._odometry = DeadReckoning(cfg.odom_correlation_time_s)
        self._detector = StationaryDetector(cfg.zupt, cfg.vehicle.wheel_radius)
        self._stationary = False
        self._last: SkidSteerEstimate | None = None
        self._outbox: list[SkidSteerEstimate] = []
        self._c: dict[str, int] = dict.fromkeys(SkidSteerCounters.__dataclass_fields__, 0)
        div = cfg.divergence
        self._monitor = DivergenceMonitor(div) if div is not None else None
        self._limit_fault: str | None = None
        self._compiled_psi: tuple[Array, Array] | None = None
        self._limit_fault_until = -math.inf

    @property
    def counters(self) -> SkidSteerCounters:
        """Snapshot of the health counters."""
        return SkidSteerCounters(**self._c)

    def counter_values(self) -> Mapping[str, int]:
        """The health counters by :class:`SkidSteerCounters` field name, in field order: a read-only
        view of the live counts (until :meth:`reset`), cheaper than the :attr:`counters` snapshot."""
        return MappingProxyType(self._c)

    @property
    def compiled_available(self) -> bool:
        """This configuration has a compiled filter step (:mod:`.skid_steer_compiled`; ``use_compiled``)."""
        return self._compiled is not None

    @property
    def wheel_speed_period_s(self) -> float | None:
        """Measured wheel-speed period (s, running median); None before two joint states."""
        return self._wheels.period_s

    @property
    def wheel_speed_max_age_s(self) -> float:
        """The wheel-speed age limit in force (s)."""
        return self._wheels.max_age_s

    @property
    def tire_scales(self) -> dict[str, float]:
        """The current tire-parameter scale estimates by name (empty without scale states or state)."""
        if not self._n_scales or self._state is None:
            return {}
        values = self.model.scale_values(self._state.x)
        return dict(zip(self.config.scale_states, values, strict=True))

    @property
    def fault(self) -> str | None:
        """Why the filter was last found diverged, until it is consistent again; None when healthy.

        A limit reset for ``fault_hold_s`` after it; a fault of the divergence monitor
        (``config.divergence``) until a new NIS window is inside its band.
        """
        if self._limit_fault is not None:
            return self._limit_fault
        return None if self._monitor is None else self._monitor.fault

    @property
    def last_estimate(self) -> SkidSteerEstimate | None:
        """The newest estimate (None before the first)."""
        return self._last

    @property
    def initialised(self) -> bool:
        """The filter holds a state."""
        return self._state is not None

    def drain_estimates(self) -> list[SkidSteerEstimate]:
        """Estimates produced since the last call, oldest first (and clear them)."""
        out, self._outbox = self._outbox, []
        return out

    def set_friction(self, friction: float | None) -> None:
        """Friction μ for the following steps (e.g. from a μ identifier); None = the vehicle's."""
        if friction is not None:
            mu = _finite("set_friction", "friction", friction)
            if mu <= 0.0:
                raise ValueError(f"set_friction: friction must be > 0, got {friction!r}")
        self._friction = friction

    def add_joint_state(self, t: float, motor_velocity_left: float, motor_velocity_right: float) -> None:
        """Buffer one sample of the motor speeds (motor side, rad/s, > 0 drives forward).

        With ``wheel_speed_wait_s`` > 0, IMU samples waiting for it are processed now (their
        estimates go to the outbox).

        Raises:
            ValueError: a non-finite argument (named in the message).
        """
        where = "add_joint_state"
        tt = _finite(where, "t", t)
        wl = _finite(where, "motor_velocity_left", motor_velocity_left)
        wr = _finite(where, "motor_velocity_right", motor_velocity_right)
        self._c["joint_states"] += 1
        ratio = self.config.vehicle.transmission_ratio
        if not self._wheels.add(tt, wl / ratio, wr / ratio):
            self._c["joint_out_of_order"] += 1
            return
        if self._pending and self._t_last_imu is not None:
            self._release(self._t_last_imu)

    def add_imu(self, t: float, ax: float, ay: float, yaw_rate: float) -> SkidSteerEstimate | None:
        """One IMU sample (specific force a_x, a_y in m/s²; yaw rate in rad/s): one filter step.

        Returns:
            The estimate of this step (with ``wheel_speed_wait_s`` > 0: of the newest step this call
            ran), or None when no step ran (out-of-order stamp, stale or missing wheel speeds, waiting).

        Raises:
            ValueError: a non-finite argument (named in the message).
        """
        values = (t, ax, ay, yaw_rate)
        try:
            floats = [float(v) for v in values]
        except (TypeError, ValueError):
            floats = []
        if len(floats) != 4 or not all(map(math.isfinite, floats)):
            # The first offending argument, named (what the loop below raises).
            for name, value in zip(("t", "ax", "ay", "yaw_rate"), values, strict=True):
                _finite("add_imu", name, value)
        tt = floats[0]
        z = np.array(floats[1:])
        self._c["imu_samples"] += 1
        if self._t_last_imu is not None and tt <= self._t_last_imu:
            self._c["imu_out_of_order"] += 1
            return None
        a_prev = self._lowpass(tt, z[0], z[1])
        if self.config.wheel_speed_wait_s > 0.0:
            self._pending.append((tt, z, a_prev))
            return self._release(tt)
        return self._process(tt, z, a_prev)

    # -- internals ------------------------------------------------------------------
    def _release(self, now: float) -> SkidSteerEstimate | None:
        """Process the waiting IMU samples whose wheel speeds are bracketed or whose wait ran out."""
        est = None
        wait = self.config.wheel_speed_wait_s
        pending = self._pending
        while pending:
            t = pending[0][0]
            newest = self._wheels.newest_time
            if (newest is None or newest < t) and now - t < wait:
                break
            est = self._process(*pending.popleft())
        return est

    def _process(self, tt: float, z: Array, a_prev: tuple[float, float]) -> SkidSteerEstimate | None:
        """One IMU sample, in stamp order: wheel speeds, stationarity, then initialise, restart or step."""
        a_raw = self._a_raw_prev if self._a_raw_prev is not None else (float(z[0]), float(z[1]))
        self._a_raw_prev = (float(z[0]), float(z[1]))
        if self._limit_fault is not None and tt >= self._limit_fault_until:
            self._limit_fault = None
        wheels = self._wheel_speeds_at(tt)
        if wheels is None:
            return None
        wl, wr = wheels
        self._stationary = self._detector.observe(tt, float(z[0]), float(z[1]), float(z[2]), wl, wr)
        if self._state is None or self._t_prev is None:
            est = self._initialise(tt, wl, wr, z, restart=False)
        elif tt - self._t_prev > self.config.max_step_s:
            est = self._initialise(tt, wl, wr, z, restart=True)
        else:
            est = self._step(tt, wl, wr, z, a_prev, a_raw)
        self._gyro_prev = float(z[2])
        self._last = est
        self._outbox.append(est)
        return est

    def _lowpass(self, t: float, ax: float, ay: float) -> tuple[float, float]:
        """Advance the a_x, a_y low-pass with a sample; return its output *before* the sample."""
        if self._a_lp is None or self._t_last_imu is None:
            self._a_lp = (ax, ay)
            self._t_last_imu = t
            return self._a_lp
        prev = self._a_lp
        g = 1.0 - math.exp(-2.0 * math.pi * self.config.accel_cutoff_hz * (t - self._t_last_imu))
        self._a_lp = (prev[0] + g * (ax - prev[0]), prev[1] + g * (ay - prev[1]))
        self._t_last_imu = t
        return prev

    def _wheel_speeds_at(self, t: float) -> tuple[float, float] | None:
        """The wheel speeds at ``t`` (interpolated or held), None if stale or missing (counted)."""
        if not len(self._wheels):
            self._c["no_wheel_speeds"] += 1
            return None
        found = self._wheels.at(t)
        if found is None:
            self._c["stale_wheel_speeds"] += 1
            return None
        self._c["wheel_speeds_interpolated" if found[2] == "interpolated" else "wheel_speeds_held"] += 1
        return found[0], found[1]

    def _input(self, wl: float, wr: float, a: tuple[float, float]) -> SkidSteerInput:
        return SkidSteerInput(wl, wr, a[0], a[1], self._friction)

    def _model_input(
        self, wl: float, wr: float, a: tuple[float, float], a_raw: tuple[float, float], yaw_acceleration: float
    ) -> Any:
        u = self._input(wl, wr, a)
        return KinematicInput(u, a_raw[0], a_raw[1], yaw_acceleration) if self._kinematic else u

    def _full_state(self, motion: Array, scales: Array | None = None) -> Array:
        """``[vx, vy, r]`` with the added states appended (given, else the current estimate's, else their prior)."""
        if not self._n_scales:
            return motion
        if scales is None:
            scales = self.model.initial_scale_state()
            if self._state is not None:
                current = np.asarray(self._state.x, dtype=float)[3:]
                if np.isfinite(current).all():
                    scales = current
        return np.concatenate([motion, scales])

    def _initialise(self, t: float, wl: float, wr: float, z: Array, *, restart: bool) -> SkidSteerEstimate:
        cfg = self.config
        if cfg.initial_state is not None:
            x0 = np.array(cfg.initial_state, dtype=float)
        else:
            x0 = self._odometry_state(wl, wr, float(z[2]))
        self._state = self.filter.initial_state(self._full_state(x0), self._p0)
        self._memory = None
        if self._consider is not None:
            self._consider.reset()
        if self._monitor is not None:
            self._monitor.start(self._state)
        self._c["restarts" if restart else "initialisations"] += 1
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        return self._estimate(t, wl, wr, dt, fading=1.0, scale=1.0, a_bar=0.0, nis=0.0, accepted=False, init=True)

    def _step(
        self, t: float, wl: float, wr: float, z: Array, a_prev: tuple[float, float], a_raw: tuple[float, float]
    ) -> SkidSteerEstimate:
        assert self._state is not None and self._t_prev is not None
        dt = t - self._t_prev
        self._t_prev = t
        self._c["steps"] += 1
        prev = self._state
        fast = self._compiled
        compiled = None
        u: Any = None
        if self._kinematic:
            u = self._model_input(wl, wr, a_prev, a_raw, (float(z[2]) - self._gyro_prev) / dt)
            if self.model.measurement_dim == 4:  # the yaw-moment pseudo-measurement: z = [a_x, a_y, r, 0]
                z = np.append(z, 0.0)
        elif (
            fast is not None
            and self.use_compiled
            and self.filter is self._compiled_filter
            and self.model is fast.model
            and math.isfinite(a_prev[0])
            and math.isfinite(a_prev[1])  # what SkidSteerInput checks (wl, wr are finite): it is built if needed
        ):
            compiled = self._compiled_step(fast, prev, z, wl, wr, a_prev, dt)
        if u is None and (compiled is None or self._consider is not None and self._compiled_psi is None):
            u = self._model_input(wl, wr, a_prev, a_raw, 0.0)
        failure: str | None = None
        try:
            filt = self.filter
            if compiled is not None:
                post, res = compiled
            elif type(filt) is AdaptiveStrongTrackingUKF:
                # step's own checks hold here: prev.x is the filter's (n,) float mean, z the finite
                # float array add_imu built (the model's output is still checked).
                post, res = filt._step(prev, prev.x, z, self.model, u, dt, self._memory)
            else:
                post, res = filt.step(prev, z, self.model, u, dt, self._memory)
            # np.isfinite(x).all() and np.isfinite(P).all(), on the floats (cheaper than two ufuncs).
            ok = all(map(math.isfinite, np.asarray(post.x, dtype=float).ravel().tolist())) and all(
                map(math.isfinite, np.asarray(post.P, dtype=float).ravel().tolist())
            )
        except (ValueError, np.linalg.LinAlgError) as exc:
            # Non-finite model output, too many Euler sub-steps, a broken factor.
            ok = False
            failure = f"filter step failed: {exc}"
        if ok:
            beyond = self._beyond_limits(post.x)
            if beyond:
                return self._limit_reset(t, wl, wr, float(z[2]), dt, beyond)
        if self._monitor is not None:
            info = None
            if failure is None:
                info = UpdateInfo(
                    innovation=res.innovation, innovation_cov=res.innovation_cov, nis=res.nis, accepted=res.accepted
                )
            # A non-finite posterior is a divergence of observe(); a failed step one of fail().
            state, check = self._monitor.supervise(self.filter, prev if failure else post, info, failure=failure)
            if check.diverged:
                # Re-initialised from the last good estimate (initial covariance, fresh memory).
                self._c["divergences"] += 1
                self._state = state
                self._memory = None
                return self._estimate(
                    t, wl, wr, dt, fading=1.0, scale=1.0, a_bar=0.0, nis=0.0, accepted=False, init=True
                )
        elif not ok:
            # Re-initialise from the last good mean (the previous posterior is finite by induction).
            self._c["recoveries"] += 1
            self._state = self.filter.initial_state(np.asarray(prev.x, dtype=float), self._p0)
            self._memory = None
            return self._estimate(t, wl, wr, dt, fading=1.0, scale=1.0, a_bar=0.0, nis=0.0, accepted=False, init=True)
        self._state = post
        self._memory = res.memory
        if self._consider is not None:
            if compiled is not None and self._compiled_psi is not None:
                self._consider.set_sensitivity(*self._compiled_psi)  # computed with the filter step
            else:
                try:
                    self._consider.step(prev.x, post.x, res, post.P, u, dt)
                except ValueError:
                    self._consider.reset()
        if self._stationary and self.config.zupt.enabled:
            self._state = zero_velocity_update(post, self._detector.mean_yaw_rate(), self.config.zupt)
            self._c["zero_velocity_updates"] += 1
            if self._consider is not None:
                self._consider.reset()
        if res.accepted:
            self._c["updates_accepted"] += 1
        else:
            self._c["gated"] += 1
        if res.fading_factor > 1.0:
            self._c["strong_tracking_active"] += 1
        nis = res.nis if math.isfinite(res.nis) else 0.0
        return self._estimate(
            t,
            wl,
            wr,
            dt,
            fading=res.fading_factor,
            scale=res.noise_scale,
            a_bar=res.mean_abs_sideslip,
            nis=nis,
            accepted=res.accepted,
            init=False,
        )

    def _compiled_step(
        self,
        fast: CompiledSkidSteerStep,
        prev: GaussianState,
        z: Array,
        wl: float,
        wr: float,
        a_prev: tuple[float, float],
        dt: float,
    ) -> tuple[GaussianState, AnStukfResult] | None:
        """The filter step (and the consider step, kept in ``_compiled_psi``) in one compiled call; None when
        the compiled step hands this step back to the Python one."""
        consider = self._consider
        mu = self.config.vehicle.friction if self._friction is None else float(self._friction)
        out = fast.run(
            _writable(prev.x),
            _writable(prev.P),
            self._memory,
            z,
            wl,
            wr,
            a_prev[0],
            a_prev[1],
            mu,
            dt,
            None if consider is None else _writable(consider.psi),
        )
        status, c_status, accepted, lam, noise_scale, nis, buf = out
        if status != STATUS_OK:
            return None
        x, P, nu, P_zz, P_prior, P_xz, memory, r_scale, psi, cov = fast.unpack(buf)
        self._compiled_psi = (psi, cov) if c_status == STATUS_OK and consider is not None else None
        res = AnStukfResult(
            fading_factor=lam,
            noise_scale=noise_scale,
            mean_abs_sideslip=0.0,
            nis=nis,
            innovation=nu,
            innovation_cov=P_zz,
            accepted=accepted,
            memory=memory,
            measurement_noise_scale=r_scale,
            prior_cov=P_prior,
            cross_cov=P_xz,
        )
        return GaussianState(x=x, P=P), res

    def _odometry_state(self, wl: float, wr: float, yaw_rate: float) -> Array:
        """``[encoder speed, 0, measured yaw rate]``, clipped to the envelope (a (re)start's mean)."""
        cfg = self.config
        vx_enc, _ = encoder_kinematics(wl, wr, cfg.vehicle)
        return np.array(
            [
                min(max(vx_enc, -cfg.max_speed), cfg.max_speed),
                0.0,
                min(max(yaw_rate, -cfg.max_yaw_rate), cfg.max_yaw_rate),
            ]
        )

    def _beyond_limits(self, x: Array) -> str:
        """Why the finite mean ``x`` is outside the vehicle's envelope, or ``""``."""
        cfg = self.config
        vx, vy, r = np.asarray(x, dtype=float)[:3].tolist()
        speed = math.hypot(vx, vy)
        if speed > cfg.max_speed:
            return f"speed {speed:.3g} m/s beyond vehicle.max_speed {cfg.max_speed:g} m/s"
        if abs(r) > cfg.max_yaw_rate:
            return f"yaw rate {r:.3g} rad/s beyond vehicle.max_yaw_rate {cfg.max_yaw_rate:g} rad/s"
        return ""

    def _limit_reset(
        self, t: float, wl: float, wr: float, yaw_rate: float, dt: float, reason: str
    ) -> SkidSteerEstimate:
        """Restart from the wheel odometry and the gyro after an estimate beyond the envelope."""
        self._c["limit_resets"] += 1
        self._c["divergences"] += 1
        x0 = self._full_state(self._odometry_state(wl, wr, yaw_rate))
        self._state = self.filter.initial_state(x0, self._p0)
        self._memory = None
        if self._monitor is not None:
            self._monitor.start(self._state)
        self._limit_fault = f"estimate beyond the vehicle's limits: {reason}; restarted from wheel odometry and gyro"
        self._limit_fault_until = t + self.config.fault_hold_s
        return self._estimate(t, wl, wr, dt, fading=1.0, scale=1.0, a_bar=0.0, nis=0.0, accepted=False, init=True)

    def _estimate(
        self,
        t: float,
        wl: float,
        wr: float,
        dt: float,
        *,
        fading: float,
        scale: float,
        a_bar: float,
        nis: float,
        accepted: bool,
        init: bool,
    ) -> SkidSteerEstimate:
        assert self._state is not None
        cfg = self.config
        x = np.asarray(self._state.x, dtype=float)
        P = np.asarray(self._state.P, dtype=float)
        if self._consider is not None:
            if init:  # a (re)start: the new estimate does not yet depend on the parameters
                self._consider.reset()
            P = P + self._consider.covariance()
        if self._n_scales:
            P3 = np.ascontiguousarray(P[:3, :3])
            vx, vy, r = x[:3].tolist()
            scales = self.model.scale_values(x)
        else:
            P3 = P
            vx, vy, r = x.tolist()  # the floats of x[0], x[1], x[2]
            scales = ()
        cov = P3.ravel().tolist()
        if dt > 0.0 and self._last is not None:
            last = self._last
            self._odometry.advance(dt, (last.vx, last.vy, last.yaw_rate), (vx, vy, r), last.twist_covariance, cov)
        slip_left, slip_right, alpha, beta, icr_x, icr_y, icr_valid, vx_enc, r_enc = _derived_values(
            vx, vy, r, wl, wr, cfg.vehicle, cfg.min_yaw_rate, *self._wheel_xy
        )
        v2, beta_var = body_sideslip_variance(vx, vy, P3, self._speed_floor_sq)
        if v2 < self._min_sideslip_speed_sq:
            # Near standstill the direction of travel, hence every sideslip
            # angle, is undefined: atan2 of two noise-sized velocities would
            # publish angles up to ±π. Report 0 with the whole-range variance.
            beta, beta_var, alpha = 0.0, math.pi**2, (0.0,) * len(alpha)
        px, py, yaw = self._odometry.pose
        return SkidSteerEstimate(
            t=t,
            vx=vx,
            vx_variance=cov[0],
            vy=vy,
            vy_variance=cov[4],
            yaw_rate=r,
            yaw_rate_variance=cov[8],
            body_sideslip=beta,
            body_sideslip_variance=max(beta_var, 0.0),
            slip_left=slip_left,
            slip_right=slip_right,
            tire_sideslip=alpha if self._contract_map is None else map_contract(alpha, self._contract_map),
            icr_x=icr_x,
            icr_y=icr_y,
            icr_valid=icr_valid,
            fading_factor=float(fading),
            noise_scale=float(scale),
            mean_abs_tire_sideslip=float(a_bar),
            x=px,
            y=py,
            yaw=yaw,
            twist_covariance=tuple(cov),
            nis=float(nis),
            accepted=bool(accepted),
            initialised=init,
            wheel_speed_left=wl,
            wheel_speed_right=wr,
            vx_encoder=vx_enc,
            yaw_rate_encoder=r_enc,
            pose_covariance=self._odometry.covariance_values,
            wheel_tire_sideslip=alpha,
            tire_scales=scales,
            stationary=self._stationary,
        )


def _writable(a: Any) -> Array:
    """``a`` as a writable C-contiguous float64 array (itself when it is one): the compiled step's argument type."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(a, dtype=np.float64, order="C")
