"""Configuration of the skid-steer estimator core: one frozen object, the model and filter it describes.

:class:`SkidSteerEstimatorConfig` (re-exported by
:mod:`terrain_estimation.estimators.skid_steer`) holds every setting of
:class:`~terrain_estimation.estimators.skid_steer.SkidSteerEstimator`:
vehicle, filter variant (B.8–B.10), observer model, noise, wheel-speed
lookup, stationary detection and dead-reckoning covariance.

Observer models (``model``; issue 20 item 3):

* ``"brush"`` — the paper's 3-state observer (MODELS.md B.6–B.7,
  :class:`~terrain_estimation.models.skid_steer_observer.SkidSteerObserverModel`);
* ``"brush_scales"`` — the same with tire-parameter scale states
  (:class:`~terrain_estimation.models.skid_steer_scales.SkidSteerTireScaleModel`);
* ``"kinematic"`` — IMU-driven kinematics, tire forces as pseudo-measurements
  (:class:`~terrain_estimation.models.skid_steer_kinematic.SkidSteerKinematicModel`);
* ``"kinematic_scales"`` — the kinematic model with the scale states.

Every model publishes the same three motion states; the scales go to the
estimate's ``tire_scales`` (diagnostics and the offline summary). What each
absorbs: the scale states a wrong cornering stiffness (or friction,
longitudinal stiffness) of a tire that follows the brush law's shape, once
the vehicle turns (they are not observable in straight driving and wander
there, see ``TireScaleConfig.reversion_time_s``); the kinematic process
keeps the short-term motion independent of the tire law (what the IMU
measures), so a tire law that is wrong in shape (a real vehicle on loose
ground) costs accuracy but does not drive the state away. The friction scale
is off by default: unmodelled rolling resistance reads as a lower μ in
straight acceleration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

from terrain_estimation.checks import check_fields
from terrain_estimation.estimators.skid_steer_consider import ConsiderConfig
from terrain_estimation.estimators.skid_steer_wheels import INTERPOLATIONS, Interpolation
from terrain_estimation.estimators.skid_steer_zupt import ZuptConfig
from terrain_estimation.filters.adaptive import StrongTrackingConfig
from terrain_estimation.filters.an_stukf import VARIANTS, AdaptiveStrongTrackingUKF, Variant
from terrain_estimation.filters.faults import DivergenceConfig
from terrain_estimation.filters.noise_adaptation import InnovationNoiseConfig
from terrain_estimation.filters.ukf import UnscentedKalmanFilter
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.models.skid_steer_kinematic import (
    DEFAULT_PROCESS_ACCEL_STD,
    DEFAULT_TIRE_MODEL_STD,
    DEFAULT_TIRE_MOMENT_STD,
    SkidSteerKinematicModel,
)
from terrain_estimation.models.skid_steer_observer import DEFAULT_Q0_DIAG, SkidSteerObserverModel
from terrain_estimation.models.skid_steer_observer import DEFAULT_R0_DIAG as PAPER_R0_DIAG
from terrain_estimation.models.skid_steer_scales import SkidSteerTireScaleModel, TireScaleConfig

__all__ = ["CONSISTENT_Q0_DIAG", "CONSISTENT_R0_DIAG", "MODELS", "ModelKind", "SkidSteerEstimatorConfig"]

#: Default process noise of [vx, vy, r] per 10 ms step ((m/s)², (m/s)², (rad/s)²), the base the default
#: filter's Q scale multiplies: the paper's B.10 values (DEFAULT_Q0_DIAG, 0.02 m/s and 0.005 rad/s per step)
#: × 0.1, the choice of the tuning grid for the default estimator (adaptive Q over brush_scales, the motion
#: resistance and the longitudinal stiffness considered): mean NIS and NEES nearest 3 on the nominal truth
#: plant (magic-formula tire, roll/pitch dynamics, relaxation; small-radius turn, 2 seeds; the grid and its
#: figures are in docs/results/skid_steer_fair.md, "consistent-tuning": NIS 2.93, NEES 2.95 at × 0.1 against
#: 3.01, 3.97 at × 0.03, the choice before the consider recursion's sign was fixed). B.10's Q0 gives a mean
#: NIS of 0.4 with a fixed Q.
CONSISTENT_Q0_DIAG: tuple[float, float, float] = (4e-5, 4e-5, 2.5e-6)  # B.10's (4e-4, 4e-4, 2.5e-5) × 0.1
#: Default measurement noise of [a_x, a_y, r] ((m/s²)², (m/s²)², (rad/s)²): an accelerometer σ of 0.05 m/s²
#: and a gyro σ of 0.002 rad/s, a MEMS IMU at 100 Hz (the simulator's sensors). Set them to the real IMU's
#: noise plus vibration (config/husky.yaml: 2 m/s², 0.01 rad/s on a small unsuspended robot).
CONSISTENT_R0_DIAG: tuple[float, float, float] = (0.05**2, 0.05**2, 0.002**2)

ModelKind = Literal["brush", "brush_scales", "kinematic", "kinematic_scales"]
#: The observer models the estimator can run (module docstring).
MODELS: tuple[str, ...] = ("brush", "brush_scales", "kinematic", "kinematic_scales")


@dataclass(frozen=True)
class SkidSteerEstimatorConfig:
    """Configuration of :class:`~terrain_estimation.estimators.skid_steer.SkidSteerEstimator` (one frozen object).

    Attributes:
        vehicle: vehicle parameters (Table 1 plus μ, ε; MODELS.md B.2; any
            number of axles through ``SkidSteerParams.axle_x``).
        filter: ``"ukf"`` (B.8), ``"stukf"`` (+ strong tracking, B.9),
            ``"an_stukf"`` (+ adaptive noise, B.10; the paper's filter),
            ``"adaptive"`` (whitened strong tracking and noise scales matched
            to the innovations, B.12) or ``"adaptive_sideslip"`` (that plus
            the B.10 law, guarded at low speed);
            :class:`~terrain_estimation.filters.an_stukf.AdaptiveStrongTrackingUKF`.
            Default ``"adaptive"`` with ``noise_adaptation.adapt_r`` off: R is
            the IMU's datasheet noise, Q is what the model error decides and
            what no fixed value gets right in every manoeuvre (on the truth
            plant the UKF with a fixed Q tuned on the nominal turn has a mean
            NIS of 11 at C_α +30 % and its NIS in band in 0–61 % of 2 s
            windows; matched to the innovations, the mean NIS is 2.8–3.2 in
            every scenario and in band in 48–93 % of windows,
            docs/results/skid_steer_fair.md). One-step innovations cannot
            separate Q from R (:mod:`~terrain_estimation.filters.noise_adaptation`),
            so only Q adapts.
        model: observer model (module docstring); default ``"brush_scales"``
            (the brush model with the cornering-stiffness scale as a state: the
            best of the four on the independent truth plant, docs/results/skid_steer.md).
        tire_scales: scale states of the ``*_scales`` models (ignored by the others).
            Its ``states`` may also hold ``"gravity_x", "gravity_y"``: the
            ground-slope option (off by default), gravity's body-frame
            components as states entering f
            (:mod:`~terrain_estimation.models.skid_steer_scales`); the
            Python step runs it (no compiled step).
        process_accel_std: σ_proc of the kinematic models (m/s²): accelerometer
            noise, vibration and gravity leakage integrated by the process.
        tire_model_std: σ_tire of the kinematic models (m/s²): the brush
            model's force error per unit mass, added to the accelerometer
            entries of R.
        tire_moment_std: σ_moment of the kinematic models (rad/s²): the brush
            model's yaw-moment error per unit yaw inertia, added to the
            differenced gyro's noise in the yaw-moment pseudo-measurement.
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
        noise_adaptation: the innovation-driven Q/R scales of the
            ``"adaptive*"`` filters (:mod:`terrain_estimation.filters.noise_adaptation`);
            default: Q only (``adapt_r=False``).
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
            stamp are stale (s); None (default) derives the limit from the
            measured wheel-speed period
            (:class:`~terrain_estimation.estimators.skid_steer_wheels.WheelSpeedBuffer`).
        wheel_speed_age_periods: the derived limit in measured periods (2.5).
        min_wheel_speed_age_s: floor of the derived limit (s; 0.05).
        wheel_speed_interpolation: ``"linear"`` between the bracketing samples
            (default) or ``"hold"`` (zero-order hold of the newest sample not
            after the IMU stamp).
        wheel_speed_wait_s: how long an IMU sample newer than the newest wheel
            speeds may wait for the next wheel-speed sample so that it is
            interpolated, not held (s; 0: never wait, no added latency).
        max_step_s: a longer gap between steps restarts the filter (s).
        friction: μ; None uses ``vehicle.friction``.
        initial_state: ``(vx, vy, r)`` at (re)initialisation; None = encoder
            speed, 0, measured yaw rate.
        p0_diag: initial covariance diagonal ((m/s)², (m/s)², (rad/s)²).
            Default std 0.3 m/s, 0.2 m/s, 0.02 rad/s: the encoder speed is
            off by the slip (≲ 20 % at manoeuvring speeds), vy is a small
            fraction of vx, the gyro gives r.
        divergence: divergence detection and recovery
            (:class:`~terrain_estimation.filters.faults.DivergenceConfig`); None
            (default) keeps only the recovery from a failed or non-finite step.
            ``check_low`` must be False for ``"an_stukf"``.
        max_speed: the vehicle's planar speed limit (m/s): an estimate beyond
            it is a divergence. Default 20 m/s: [SS]'s 3 t vehicle runs its
            manoeuvres at up to 30 km/h (8.3 m/s).
        max_yaw_rate: the vehicle's yaw-rate limit (rad/s), the same for ``r``.
            Default 3 rad/s.
        fault_hold_s: :attr:`SkidSteerEstimator.fault` names a limit reset for
            this long after it (s of stamps; the diagnostics period is 1 s).
        zupt: stationary detector and zero-velocity update.
        odom_correlation_time_s: correlation time τ of the twist error in the
            dead-reckoned pose covariance (s; 0: white).
        consider: tire and terrain parameters whose uncertainty the published
            covariance includes without estimating them
            (:mod:`~terrain_estimation.estimators.skid_steer_consider`).
    """

    vehicle: SkidSteerParams = field(default_factory=SkidSteerParams)
    filter: Variant = "adaptive"
    model: ModelKind = "brush_scales"
    tire_scales: TireScaleConfig = field(default_factory=TireScaleConfig)
    process_accel_std: float = DEFAULT_PROCESS_ACCEL_STD
    tire_model_std: float = DEFAULT_TIRE_MODEL_STD
    tire_moment_std: float = DEFAULT_TIRE_MOMENT_STD
    ukf_alpha: float = 1.0
    ukf_beta: float = 2.0
    ukf_kappa: float = 0.0
    gate_threshold: float | None = None
    strong_tracking: StrongTrackingConfig = field(default_factory=StrongTrackingConfig)
    k_q: float = 5.0
    k_r: float = 2.0
    noise_adaptation: InnovationNoiseConfig = field(default_factory=lambda: InnovationNoiseConfig(adapt_r=False))
    q0_diag: tuple[float, float, float] = CONSISTENT_Q0_DIAG
    q_step_dt: float = 0.01
    r0_diag: tuple[float, float, float] = CONSISTENT_R0_DIAG
    substeps: int = 1
    max_euler_gain: float | None = 0.5
    max_substeps: int = 1000
    accel_cutoff_hz: float = 2.0
    min_yaw_rate: float = 0.02
    min_sideslip_speed: float = 0.2
    max_wheel_speed_age_s: float | None = None
    wheel_speed_age_periods: float = 2.5
    min_wheel_speed_age_s: float = 0.05
    wheel_speed_interpolation: Interpolation = "linear"
    wheel_speed_wait_s: float = 0.0
    max_step_s: float = 0.1
    friction: float | None = None
    initial_state: tuple[float, float, float] | None = None
    p0_diag: tuple[float, float, float] = (0.3**2, 0.2**2, 0.02**2)
    divergence: DivergenceConfig | None = None
    max_speed: float = 20.0
    max_yaw_rate: float = 3.0
    fault_hold_s: float = 1.0
    zupt: ZuptConfig = field(default_factory=ZuptConfig)
    odom_correlation_time_s: float = 1.0
    consider: ConsiderConfig = field(default_factory=ConsiderConfig)

    def __post_init__(self) -> None:
        if self.filter not in VARIANTS:
            raise ValueError(f"filter must be one of {VARIANTS}, got {self.filter!r}")
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}, got {self.model!r}")
        if self.wheel_speed_interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"wheel_speed_interpolation must be one of {INTERPOLATIONS}, got {self.wheel_speed_interpolation!r}"
            )
        positive = (
            "accel_cutoff_hz",
            "max_step_s",
            "q_step_dt",
            "max_speed",
            "max_yaw_rate",
            "fault_hold_s",
            "wheel_speed_age_periods",
            "min_wheel_speed_age_s",
            "process_accel_std",
        )
        check_fields(self, positive)
        non_negative = (
            "min_yaw_rate",
            "min_sideslip_speed",
            "k_q",
            "k_r",
            "wheel_speed_wait_s",
            "tire_model_std",
            "tire_moment_std",
            "odom_correlation_time_s",
        )
        check_fields(self, non_negative, rule="non_negative")
        age = self.max_wheel_speed_age_s
        if age is not None and not (math.isfinite(age) and age > 0.0):
            raise ValueError(f"max_wheel_speed_age_s must be None or finite and > 0, got {age}")
        if self.friction is not None and not (math.isfinite(self.friction) and self.friction > 0.0):
            raise ValueError(f"friction must be None or finite and > 0, got {self.friction}")
        if self.initial_state is not None:
            if len(self.initial_state) != 3 or not all(math.isfinite(v) for v in self.initial_state):
                raise ValueError(f"initial_state must be None or 3 finite values, got {self.initial_state}")
        if len(self.p0_diag) != 3 or not all(math.isfinite(v) and v > 0.0 for v in self.p0_diag):
            raise ValueError(f"p0_diag must hold 3 finite variances > 0, got {self.p0_diag}")
        if self.gate_threshold is not None and not (math.isfinite(self.gate_threshold) and self.gate_threshold > 0.0):
            raise ValueError(f"gate_threshold must be None or finite and > 0, got {self.gate_threshold}")
        for name, kind in (
            ("tire_scales", TireScaleConfig),
            ("zupt", ZuptConfig),
            ("noise_adaptation", InnovationNoiseConfig),
            ("consider", ConsiderConfig),
        ):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(f"{name} must be a {kind.__name__}, got {type(getattr(self, name)).__name__}")
        if self.divergence is not None:
            if not isinstance(self.divergence, DivergenceConfig):
                raise ValueError(f"divergence must be None or a DivergenceConfig, got {type(self.divergence).__name__}")
            if self.filter in ("an_stukf", "adaptive_sideslip") and self.divergence.check_low:
                raise ValueError(
                    f"divergence.check_low must be False for filter {self.filter!r}: its sideslip law rescales R "
                    "with the tire sideslip, not with the innovations, and its NIS runs below the chi-square band "
                    "on healthy data"
                )
        # The filter and model validate their own parameters.
        self.make_model()
        self.make_filter()

    @classmethod
    def paper(cls, **changes: Any) -> SkidSteerEstimatorConfig:
        """[SS]'s filter as reconstructed (MODELS.md B.6-B.10): AN-STUKF over the 3-state brush model with
        B.10's Q0 and R0 (``filter`` may be changed to the paper's "ukf" or "stukf"); ``changes`` as for the
        constructor. The defaults of the constructor are the project's (UKF over brush_scales, consistent Q0/R0)."""
        paper: dict[str, Any] = {
            "filter": "an_stukf",
            "model": "brush",
            "q0_diag": DEFAULT_Q0_DIAG,
            "r0_diag": PAPER_R0_DIAG,
            "consider": ConsiderConfig(parameters=()),
        }
        return cls(**{**paper, **changes})

    @property
    def scale_states(self) -> tuple[str, ...]:
        """The tire-parameter scale states the model carries (empty for ``"brush"``, ``"kinematic"``)."""
        return self.tire_scales.states if self.model.endswith("_scales") else ()

    def make_model(self, *, yaw_moment: bool | None = None) -> Any:
        """The observer model these settings describe (state ``[vx, vy, r]`` + the scale states).

        Args:
            yaw_moment: for the kinematic models, whether the yaw-moment pseudo-measurement is used (None:
                the model's own choice, with scale states only).
        """
        common: dict[str, Any] = {"q0_diag": self.q0_diag, "r0_diag": self.r0_diag, "q_step_dt": self.q_step_dt}
        # The brush models' Euler sub-steps.
        brush: dict[str, Any] = {
            "substeps": self.substeps,
            "max_euler_gain": self.max_euler_gain,
            "max_substeps": self.max_substeps,
            **common,
        }
        if self.model == "brush":
            return SkidSteerObserverModel(self.vehicle, **brush)
        scales = self.tire_scales if self.model.endswith("_scales") else TireScaleConfig(states=())
        if self.model.startswith("brush"):
            return SkidSteerTireScaleModel(self.vehicle, scales, **brush)
        return SkidSteerKinematicModel(
            self.vehicle,
            scales,
            process_accel_std=self.process_accel_std,
            tire_model_std=self.tire_model_std,
            tire_moment_std=self.tire_moment_std,
            yaw_moment=yaw_moment,
            **common,
        )

    def make_filter(self) -> AdaptiveStrongTrackingUKF:
        """The filter these settings describe."""
        ukf = UnscentedKalmanFilter(
            alpha=self.ukf_alpha, beta=self.ukf_beta, kappa=self.ukf_kappa, gate_threshold=self.gate_threshold
        )
        return AdaptiveStrongTrackingUKF(
            variant=self.filter,
            ukf=ukf,
            strong_tracking=self.strong_tracking,
            k_q=self.k_q,
            k_r=self.k_r,
            noise=self.noise_adaptation,
        )
