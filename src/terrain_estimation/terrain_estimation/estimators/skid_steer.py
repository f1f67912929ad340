"""Skid-steer motion-state estimator core: wheel speeds + IMU → AN-STUKF → SkidSteerState ([SS], MODELS.md Part B).

The ROS-free core that the skid-steer estimator node and the offline bag
runner drive (CONTRACT.md "Skid-steer vehicle"). It owns one
:class:`~terrain_estimation.filters.an_stukf.AdaptiveStrongTrackingUKF`
(variant ``"ukf"``, ``"stukf"`` or ``"an_stukf"``) over the 3-state
:class:`~terrain_estimation.models.skid_steer_observer.SkidSteerObserverModel`
and turns its state ``[vx, vy, r]`` into every field of
``terrain_msgs/SkidSteerState`` plus a dead-reckoned pose for ``odom``.

Data flow (all times are the ``t`` arguments, in seconds; no wall clock):

* :meth:`SkidSteerEstimator.add_joint_state` buffers the two motor speeds
  (motor side, rad/s); the wheel side is motor ÷ ``transmission_ratio``
  (paper eq. 39; 27.13 for Table 1).
* :meth:`SkidSteerEstimator.add_imu` takes one IMU sample (specific force
  ``a_x, a_y`` in m/s², REP 145, gravity is along z and not used on flat
  ground; yaw rate in rad/s) and runs one filter step from the previous
  step's stamp to ``t`` with ``z = [a_x, a_y, r]``.

**Wheel speeds (zero-order hold).** A step uses the newest buffered wheel
speeds stamped at or before ``t`` (or, if all are newer, the oldest one):
they are held over the step. Wheel speeds older (or newer) than
``max_wheel_speed_age_s`` relative to the IMU sample are stale: the IMU
sample is not used for a step (``counters.stale_wheel_speeds``, or
``no_wheel_speeds`` before the first joint state) and the next step spans
the gap.

**Load model input.** The quasi-static wheel loads (B.5) take the measured
``a_x, a_y`` through a first-order low-pass (``accel_cutoff_hz``, default
2 Hz: passes the manoeuvre, removes vibration, and roughly mimics the lag of
the real body's pitch/roll load transfer). A step uses the low-pass output
*before* the step's own sample, so the input does not contain the
measurement noise of the update it feeds.

**Initialisation and restarts.** The first IMU sample with usable wheel
speeds initialises the filter at ``initial_state`` or, by default, at the
encoder-only speed ``R(ω_l + ω_r)/2``, ``vy = 0`` and the measured yaw rate,
with covariance ``diag(p0_diag)``; it produces an estimate (no update). A
gap longer than ``max_step_s`` since the last step restarts the same way
(``counters.restarts``): explicit Euler over a long gap at low rolling speed
would need hundreds of sub-steps, and the state has moved on anyway.

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
its band; the previous posterior may already be off) with the initial
covariance and a fresh strong-tracking memory (``counters.divergences``
instead of ``recoveries``; :attr:`SkidSteerEstimator.fault` holds the reason
until a new window is consistent). The low side of the band
(``DivergenceConfig.check_low``) is refused for the AN-STUKF, whose
adaptive noise rescales R with the tire sideslip, and fires on healthy data
for every variant with the default ``r0_diag`` (4 × the accelerometer noise
variance): the mean NIS is 0.13–0.26 against 3 on the shipped bags
(docs/results/skid_steer.md: UKF 0.196, AN-STUKF 0.157), and the node keeps
it off. With it off the monitor never fired on those bags (three
variants; ``window`` 20, ``probability`` 0.999, ``persistence`` 10).

**Physical limits (issue 19).** No estimate leaves the vehicle's envelope
``max_speed`` (planar speed ``√(vx² + vy²)``, m/s) and ``max_yaw_rate``
(``|r|``, rad/s). A step whose posterior mean lies beyond it is a divergence
(``counters.limit_resets`` and ``counters.divergences``): the filter restarts
from the wheel odometry and the gyro, not from the bad state (``vx`` = the
encoder speed, ``vy = 0``, ``r`` = the measured yaw rate, each clipped to the
envelope; covariance ``diag(p0_diag)``), that restart is the estimate of the
step (``initialised``), and :attr:`SkidSteerEstimator.fault` names the limit
for ``fault_hold_s`` of stamps after the last one. The runaway this stops
(BorealTC Husky, deep snow and bumps; found by comparing the variants): when the
brush forces of the state saturate (slip velocities beyond ``≈ 3 μ F_z V_r / C``,
0.1 m/s at 0.5 m/s wheel speed on the Husky), ``h`` no longer depends on the
speed's magnitude; accelerations the tires cannot produce (bumps of 2–6 g,
sides spinning against a body that does not turn) then keep the innovation
large, the strong-tracking fading factor sits at ``λ_max`` step after step and
multiplies the covariance by it each time (10ᵏ), and the update moves the
mean by about its standard deviation: ``|v|`` grows by ≈ √10 per step to
1e155 m/s (the plain UKF, whose covariance grows only by Q, stays bounded).
The mean moves by about √P per step, so the check on the mean also bounds the
covariance (each reset restores ``p0_diag``). The cause is in the tuning for
such data: ``config/husky.yaml`` sets the measured IMU noise and
``lambda_max`` 2 and runs the 21 BorealTC runs without a reset. The
NIS-band monitor (``divergence``) is no guard there: the bumps' heavy tails put
the windowed mean NIS above its band on every run (23–376 "divergences" per
run), which is why it stays off by default.

**Outputs.** :meth:`~SkidSteerEstimator.add_imu` returns the estimate its
step produced (None if none); every estimate also goes to an outbox read
by :meth:`~SkidSteerEstimator.drain_estimates`. The body sideslip variance
is the first-order propagation of the ``(vx, vy)`` covariance through
``β = atan2(vy, vx)``. The pose (``x, y, yaw`` in the odom frame, origin at
the first sample) integrates the estimated twist with the trapezoidal rule
and the mid-step heading.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from terrain_estimation.filters.adaptive import StrongTrackingConfig
from terrain_estimation.filters.an_stukf import VARIANTS, AdaptiveStrongTrackingUKF, Variant
from terrain_estimation.filters.base import Array, GaussianState, UpdateInfo
from terrain_estimation.filters.faults import DivergenceConfig, DivergenceMonitor
from terrain_estimation.filters.ukf import UnscentedKalmanFilter
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.models.skid_steer_observer import (
    DEFAULT_Q0_DIAG,
    DEFAULT_R0_DIAG,
    SkidSteerInput,
    SkidSteerObserverModel,
    _derived_values,
    _wheel_xy,
    encoder_kinematics,
)

__all__ = [
    "SkidSteerEstimatorConfig",
    "SkidSteerEstimate",
    "SkidSteerCounters",
    "SkidSteerEstimator",
]

#: Joint-state samples kept for the zero-order hold lookup.
_JOINT_BUFFER = 64


@dataclass(frozen=True)
class SkidSteerEstimatorConfig:
    """Configuration of :class:`SkidSteerEstimator` (one frozen object).

    Attributes:
        vehicle: vehicle parameters (Table 1 plus μ, ε; MODELS.md B.2).
        filter: ``"ukf"`` (B.8), ``"stukf"`` (+ strong tracking, B.9) or
            ``"an_stukf"`` (+ adaptive noise, B.10; the paper's filter).
        ukf_alpha: sigma-point spread α. Default 1: the paper asks for "α
            small", but with n = 3 and κ = 0 a small α makes ``W_m0 = 1 −
            3/(α²·3)`` large and negative (−9999 at α = 0.01), which loses
            positive-definiteness of the predicted covariance; α = 1 gives
            ``W_m0 = 0``, ``W_c0 = 2`` and well-conditioned weights (B.8).
        ukf_beta: β (2: optimal for a Gaussian prior).
        ukf_kappa: κ (0 = 3 − n for n = 3).
        gate_threshold: NIS gate (χ²₃ quantile, e.g. 16.3 for 0.999); None
            disables. A gated update keeps the prediction.
        strong_tracking: ρ, β_w, γ_th, λ_max of the fading factor (B.9;
            defaults ρ = 0.95, β_w = 1, γ_th = 3, λ_max = 10).
        k_q: ``K_q`` (rad⁻¹) of ``Q_k = Q0(1 + K_q ᾱ)`` (B.10, default 5).
        k_r: ``K_r`` (rad⁻¹) of ``R_k = R0/(1 + K_r ᾱ)`` (B.10, default 2).
        q0_diag: base process noise per ``q_step_dt`` ((m/s)², (m/s)²,
            (rad/s)²); reasons in :mod:`~terrain_estimation.models.skid_steer_observer`.
        q_step_dt: step length ``q0_diag`` refers to (s).
        r0_diag: base measurement noise of ``[a_x, a_y, r]`` ((m/s²)²,
            (m/s²)², (rad/s)²). Set the acceleration entries to the real
            accelerometer noise + vibration (see the observer module).
        substeps: minimum Euler sub-steps per filter step.
        max_euler_gain: Euler gain bound per sub-step that sets the number of
            sub-steps (None: exactly ``substeps``, the literal B.6 scheme).
        max_substeps: a step needing more sub-steps fails (→ recovery).
        accel_cutoff_hz: cut-off of the first-order low-pass of the measured
            ``a_x, a_y`` that feed the load model (Hz).
        min_yaw_rate: ICR published only for ``|r|`` above it (rad/s, B.3).
        min_sideslip_speed: below this speed (m/s) the body and tire sideslip
            angles are undefined and reported as 0 with variance π².
        max_wheel_speed_age_s: wheel speeds further than this from the IMU
            stamp are stale (s).
        max_step_s: a longer gap between steps restarts the filter (s).
        friction: μ; None uses ``vehicle.friction``.
        initial_state: ``(vx, vy, r)`` at (re)initialisation; None = encoder
            speed, 0, measured yaw rate.
        p0_diag: initial covariance diagonal ((m/s)², (m/s)², (rad/s)²).
            Default std 0.3 m/s, 0.2 m/s, 0.02 rad/s: the encoder speed is
            off by the slip (≲ 20 % at manoeuvring speeds), vy is a small
            fraction of vx, the gyro gives r.
        divergence: divergence detection and recovery
            (:class:`~terrain_estimation.filters.faults.DivergenceConfig`,
            module docstring); None (default) keeps only the recovery from a
            failed or non-finite step. ``check_low`` must be False for
            ``"an_stukf"``.
        max_speed: the vehicle's planar speed limit (m/s): an estimate beyond
            it is a divergence (module docstring). Default 20 m/s: [SS]'s 3 t vehicle runs its
            manoeuvres at up to 30 km/h (8.3 m/s).
        max_yaw_rate: the vehicle's yaw-rate limit (rad/s), the same for ``r``.
            Default 3 rad/s.
        fault_hold_s: :attr:`SkidSteerEstimator.fault` names a limit reset for
            this long after it (s of stamps; the diagnostics period is 1 s).
    """

    vehicle: SkidSteerParams = field(default_factory=SkidSteerParams)
    filter: Variant = "an_stukf"
    ukf_alpha: float = 1.0
    ukf_beta: float = 2.0
    ukf_kappa: float = 0.0
    gate_threshold: float | None = None
    strong_tracking: StrongTrackingConfig = field(default_factory=StrongTrackingConfig)
    k_q: float = 5.0
    k_r: float = 2.0
    q0_diag: tuple[float, float, float] = DEFAULT_Q0_DIAG
    q_step_dt: float = 0.01
    r0_diag: tuple[float, float, float] = DEFAULT_R0_DIAG
    substeps: int = 1
    max_euler_gain: float | None = 0.5
    max_substeps: int = 1000
    accel_cutoff_hz: float = 2.0
    min_yaw_rate: float = 0.02
    min_sideslip_speed: float = 0.2
    max_wheel_speed_age_s: float = 0.05
    max_step_s: float = 0.1
    friction: float | None = None
    initial_state: tuple[float, float, float] | None = None
    p0_diag: tuple[float, float, float] = (0.3**2, 0.2**2, 0.02**2)
    divergence: DivergenceConfig | None = None
    max_speed: float = 20.0
    max_yaw_rate: float = 3.0
    fault_hold_s: float = 1.0

    def __post_init__(self) -> None:
        if self.filter not in VARIANTS:
            raise ValueError(f"filter must be one of {VARIANTS}, got {self.filter!r}")
        positive = (
            "accel_cutoff_hz",
            "max_wheel_speed_age_s",
            "max_step_s",
            "q_step_dt",
            "max_speed",
            "max_yaw_rate",
            "fault_hold_s",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        for name in ("min_yaw_rate", "min_sideslip_speed", "k_q", "k_r"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")
        if self.friction is not None and not (math.isfinite(self.friction) and self.friction > 0.0):
            raise ValueError(f"friction must be None or finite and > 0, got {self.friction}")
        if self.initial_state is not None:
            if len(self.initial_state) != 3 or not all(math.isfinite(v) for v in self.initial_state):
                raise ValueError(f"initial_state must be None or 3 finite values, got {self.initial_state}")
        if len(self.p0_diag) != 3 or not all(math.isfinite(v) and v > 0.0 for v in self.p0_diag):
            raise ValueError(f"p0_diag must hold 3 finite variances > 0, got {self.p0_diag}")
        if self.gate_threshold is not None and not (math.isfinite(self.gate_threshold) and self.gate_threshold > 0.0):
            raise ValueError(f"gate_threshold must be None or finite and > 0, got {self.gate_threshold}")
        if self.divergence is not None:
            if not isinstance(self.divergence, DivergenceConfig):
                raise ValueError(f"divergence must be None or a DivergenceConfig, got {type(self.divergence).__name__}")
            if self.filter == "an_stukf" and self.divergence.check_low:
                raise ValueError(
                    "divergence.check_low must be False for filter 'an_stukf': its adaptive noise rescales R, "
                    "and its NIS runs far below the chi-square band on healthy data (mean about 0.2 against 3)"
                )
        # The filter and model validate their own parameters.
        self.make_model()
        self.make_filter()

    def make_model(self) -> SkidSteerObserverModel:
        """The observer model these settings describe."""
        return SkidSteerObserverModel(
            self.vehicle,
            q0_diag=self.q0_diag,
            r0_diag=self.r0_diag,
            q_step_dt=self.q_step_dt,
            substeps=self.substeps,
            max_euler_gain=self.max_euler_gain,
            max_substeps=self.max_substeps,
        )

    def make_filter(self) -> AdaptiveStrongTrackingUKF:
        """The filter these settings describe."""
        ukf = UnscentedKalmanFilter(
            alpha=self.ukf_alpha, beta=self.ukf_beta, kappa=self.ukf_kappa, gate_threshold=self.gate_threshold
        )
        return AdaptiveStrongTrackingUKF(
            variant=self.filter, ukf=ukf, strong_tracking=self.strong_tracking, k_q=self.k_q, k_r=self.k_r
        )


@dataclass(frozen=True)
class SkidSteerEstimate:
    """One filter step's result: every ``SkidSteerState`` field, the odometry pose and diagnostics.

    Every float is finite.

    Attributes:
        t: time of the step (s), the IMU sample's stamp.
        vx, vy: body-frame velocity of the CM (m/s).
        yaw_rate: r (rad/s).
        vx_variance, vy_variance, yaw_rate_variance: filter variances.
        body_sideslip: β = atan2(vy, vx) (rad).
        body_sideslip_variance: first-order variance of β (rad², ≤ π²).
        slip_left, slip_right: per-side longitudinal slip κ (> 0 in traction).
        tire_sideslip: α of FL, ML, RL, FR, MR, RR (rad).
        icr_x, icr_y: instantaneous centre of rotation in body axes (m); 0
            when not valid.
        icr_valid: ``|r| > min_yaw_rate``.
        fading_factor: strong-tracking λ (1 for the plain UKF or a consistent step).
        noise_scale: ``1 + K_q ᾱ`` (1 unless an_stukf).
        mean_abs_tire_sideslip: ᾱ that set the noise scale (rad; 0 unless an_stukf).
        x, y, yaw: dead-reckoned pose in the odom frame (m, m, rad in (−π, π]).
        twist_covariance: covariance of ``[vx, vy, r]``, 9 values row-major.
        nis: normalised innovation squared of the update (0 without update).
        accepted: a measurement update was applied at this step.
        initialised: this estimate comes from a (re)initialisation, not a filter step.
        wheel_speed_left, wheel_speed_right: wheel-side speeds used (rad/s).
        vx_encoder, yaw_rate_encoder: slip-free encoder-only estimates (m/s, rad/s).
    """

    t: float
    vx: float
    vx_variance: float
    vy: float
    vy_variance: float
    yaw_rate: float
    yaw_rate_variance: float
    body_sideslip: float
    body_sideslip_variance: float
    slip_left: float
    slip_right: float
    tire_sideslip: tuple[float, ...]
    icr_x: float
    icr_y: float
    icr_valid: bool
    fading_factor: float
    noise_scale: float
    mean_abs_tire_sideslip: float
    x: float
    y: float
    yaw: float
    twist_covariance: tuple[float, ...]
    nis: float
    accepted: bool
    initialised: bool
    wheel_speed_left: float
    wheel_speed_right: float
    vx_encoder: float
    yaw_rate_encoder: float


@dataclass(frozen=True)
class SkidSteerCounters:
    """Health counters since construction or :meth:`SkidSteerEstimator.reset`."""

    imu_samples: int = 0
    joint_states: int = 0
    steps: int = 0
    updates_accepted: int = 0
    gated: int = 0
    strong_tracking_active: int = 0
    initialisations: int = 0
    restarts: int = 0
    recoveries: int = 0
    divergences: int = 0
    limit_resets: int = 0
    stale_wheel_speeds: int = 0
    no_wheel_speeds: int = 0
    imu_out_of_order: int = 0
    joint_out_of_order: int = 0


def _finite(where: str, name: str, value: Any) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{where}: {name} must be finite, got {value!r}")
    return v


def _wrap(angle: float) -> float:
    """Angle in (−π, π]."""
    a = math.remainder(angle, 2.0 * math.pi)
    return math.pi if a == -math.pi else a


class SkidSteerEstimator:
    """Motion states of the six-wheel skid steer from wheel speeds and the IMU (module docstring).

    Args:
        config: settings; defaults are the AN-STUKF with the B.10 noise.
    """

    def __init__(self, config: SkidSteerEstimatorConfig | None = None) -> None:
        self.config = config if config is not None else SkidSteerEstimatorConfig()
        self.model = self.config.make_model()
        self.filter = self.config.make_filter()
        self._p0 = np.diag(np.array(self.config.p0_diag, dtype=float))
        self._friction = self.config.friction
        # Per-step constants of _estimate.
        self._wheel_xy = _wheel_xy(self.config.vehicle)
        self._speed_floor_sq = self.config.vehicle.rolling_speed_floor**2
        self._min_sideslip_speed_sq = self.config.min_sideslip_speed**2
        self.reset()

    # -- public API ---------------------------------------------------------------
    def reset(self) -> None:
        """Forget the state, the buffers, the pose, the outbox and the counters."""
        self._state: GaussianState | None = None
        self._memory: Array | None = None
        self._t_prev: float | None = None
        self._t_last_imu: float | None = None
        self._a_lp: tuple[float, float] | None = None
        self._joints: deque[tuple[float, float, float]] = deque(maxlen=_JOINT_BUFFER)
        self._pose = (0.0, 0.0, 0.0)
        self._last: SkidSteerEstimate | None = None
        self._outbox: list[SkidSteerEstimate] = []
        self._c: dict[str, int] = dict.fromkeys(SkidSteerCounters.__dataclass_fields__, 0)
        div = self.config.divergence
        self._monitor = DivergenceMonitor(div) if div is not None else None
        self._limit_fault: str | None = None
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

        Raises:
            ValueError: a non-finite argument (named in the message).
        """
        where = "add_joint_state"
        tt = _finite(where, "t", t)
        wl = _finite(where, "motor_velocity_left", motor_velocity_left)
        wr = _finite(where, "motor_velocity_right", motor_velocity_right)
        self._c["joint_states"] += 1
        if self._joints and tt <= self._joints[-1][0]:
            self._c["joint_out_of_order"] += 1
            return
        ratio = self.config.vehicle.transmission_ratio
        self._joints.append((tt, wl / ratio, wr / ratio))

    def add_imu(self, t: float, ax: float, ay: float, yaw_rate: float) -> SkidSteerEstimate | None:
        """One IMU sample (specific force a_x, a_y in m/s²; yaw rate in rad/s): one filter step.

        Returns:
            The estimate of this step, or None when no step ran (out-of-order
            stamp, stale or missing wheel speeds).

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
        if self._limit_fault is not None and tt >= self._limit_fault_until:
            self._limit_fault = None
        wheels = self._wheel_speeds_at(tt)
        if wheels is None:
            return None
        wl, wr = wheels
        if self._state is None or self._t_prev is None:
            est = self._initialise(tt, wl, wr, z, restart=False)
        elif tt - self._t_prev > self.config.max_step_s:
            est = self._initialise(tt, wl, wr, z, restart=True)
        else:
            est = self._step(tt, wl, wr, z, a_prev)
        self._last = est
        self._outbox.append(est)
        return est

    # -- internals ------------------------------------------------------------------
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
        """Zero-order hold: newest wheel speeds stamped ≤ t (else the oldest), None if stale/missing."""
        if not self._joints:
            self._c["no_wheel_speeds"] += 1
            return None
        chosen = self._joints[0]
        for sample in reversed(self._joints):
            if sample[0] <= t:
                chosen = sample
                break
        if abs(t - chosen[0]) > self.config.max_wheel_speed_age_s:
            self._c["stale_wheel_speeds"] += 1
            return None
        return chosen[1], chosen[2]

    def _input(self, wl: float, wr: float, a: tuple[float, float]) -> SkidSteerInput:
        return SkidSteerInput(wl, wr, a[0], a[1], self._friction)

    def _initialise(self, t: float, wl: float, wr: float, z: Array, *, restart: bool) -> SkidSteerEstimate:
        cfg = self.config
        if cfg.initial_state is not None:
            x0 = np.array(cfg.initial_state, dtype=float)
        else:
            x0 = self._odometry_state(wl, wr, float(z[2]))
        self._state = self.filter.initial_state(x0, self._p0)
        self._memory = None
        if self._monitor is not None:
            self._monitor.start(self._state)
        self._c["restarts" if restart else "initialisations"] += 1
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        return self._estimate(t, wl, wr, dt, fading=1.0, scale=1.0, a_bar=0.0, nis=0.0, accepted=False, init=True)

    def _step(self, t: float, wl: float, wr: float, z: Array, a_prev: tuple[float, float]) -> SkidSteerEstimate:
        assert self._state is not None and self._t_prev is not None
        dt = t - self._t_prev
        self._t_prev = t
        self._c["steps"] += 1
        prev = self._state
        u = self._input(wl, wr, a_prev)
        failure: str | None = None
        try:
            filt = self.filter
            if type(filt) is AdaptiveStrongTrackingUKF:
                # step's own checks hold here: prev.x is the filter's (3,) float mean, z the finite
                # float array add_imu built (the model's output is still checked).
                post, res = filt._step(prev, prev.x, z, self.model, u, dt, self._memory)
            else:
                post, res = filt.step(prev, z, self.model, u, dt, self._memory)
            # np.isfinite(x).all() and np.isfinite(P).all(), on the floats (3 + 9: cheaper than two ufuncs).
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
        vx, vy, r = np.asarray(x, dtype=float).tolist()
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
        self._state = self.filter.initial_state(self._odometry_state(wl, wr, yaw_rate), self._p0)
        self._memory = None
        if self._monitor is not None:
            self._monitor.start(self._state)
        self._limit_fault = f"estimate beyond the vehicle's limits: {reason}; restarted from wheel odometry and gyro"
        self._limit_fault_until = t + self.config.fault_hold_s
        return self._estimate(t, wl, wr, dt, fading=1.0, scale=1.0, a_bar=0.0, nis=0.0, accepted=False, init=True)

    def _advance_pose(self, dt: float, vx_new: float, vy_new: float, r_new: float) -> None:
        """Trapezoidal twist, mid-step heading (exact for constant twist to O(dt³))."""
        px, py, yaw = self._pose
        if dt > 0.0 and self._last is not None:
            vx = 0.5 * (self._last.vx + vx_new)
            vy = 0.5 * (self._last.vy + vy_new)
            r = 0.5 * (self._last.yaw_rate + r_new)
            mid = yaw + 0.5 * dt * r
            c, s = math.cos(mid), math.sin(mid)
            px += dt * (c * vx - s * vy)
            py += dt * (s * vx + c * vy)
            yaw = _wrap(yaw + dt * r)
        self._pose = (px, py, yaw)

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
        vx, vy, r = x.tolist()  # the floats of x[0], x[1], x[2]
        self._advance_pose(dt, vx, vy, r)
        slip_left, slip_right, alpha, beta, icr_x, icr_y, icr_valid, vx_enc, r_enc = _derived_values(
            vx, vy, r, wl, wr, cfg.vehicle, cfg.min_yaw_rate, *self._wheel_xy
        )
        v2, beta_var = _body_sideslip_variance(vx, vy, P, self._speed_floor_sq)
        if v2 < self._min_sideslip_speed_sq:
            # Near standstill the direction of travel, hence every sideslip
            # angle, is undefined: atan2 of two noise-sized velocities would
            # publish angles up to ±π. Report 0 with the whole-range variance.
            beta, beta_var, alpha = 0.0, math.pi**2, (0.0,) * len(alpha)
        px, py, yaw = self._pose
        cov = P.ravel().tolist()
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
            tire_sideslip=alpha,
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
        )


def _body_sideslip_variance(vx: float, vy: float, P: Array, speed_floor_sq: float) -> tuple[float, float]:
    """``(v², var β)``: the squared speed, floored at ``speed_floor_sq``, and the first-order variance
    of ``β = atan2(vy, vx)``, capped at π².

    ``∂β/∂(vx, vy) = (−vy, vx)/(vx² + vy²)``; the floor (the rolling-speed floor squared) keeps the
    variance finite at rest, the cap is β's whole range (2π). On the state's floats: Python's
    ``float ** 2`` and numpy's float64 ``** 2`` are the same libm ``pow`` (not ``x * x``, which
    rounds differently now and then), and ``−vy/v²`` is ``(−vy)/v²`` exactly, so these are the
    floats of the array form (a test compares), overflow included.
    """
    try:
        v2 = max(vx**2 + vy**2, speed_floor_sq)
    except OverflowError:  # Python's float ** raises where numpy's gives inf (and warns): numpy's then
        v2 = max(float(np.float64(vx) ** 2 + np.float64(vy) ** 2), speed_floor_sq)
    jac = np.array([-vy / v2, vx / v2])
    return v2, min(float(jac @ P[:2, :2] @ jac), math.pi**2)
