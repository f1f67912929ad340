"""Configuration of the rover's terrain-response estimator (:class:`RoverEstimatorConfig`).

One frozen object of every setting of
:class:`~terrain_estimation.estimators.rover.RoverTerrainEstimator`: the
rover, the load cells (Estimator 2 or 3), rates, noise, the deviations from
the paper the module docstring of :mod:`terrain_estimation.estimators.rover`
explains, windowing and failure handling; re-exported there.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

from terrain_estimation.checks import check_non_negative
from terrain_estimation.estimators.rover_noise import ContactAngleBias, NoiseMatchingConfig
from terrain_estimation.filters.faults import DivergenceConfig
from terrain_estimation.filters.ukf import UnscentedKalmanFilter
from terrain_estimation.models.rover import RoverParams
from terrain_estimation.models.rover_estimator_noise import (
    GeneralProcessNoise,
    MeasurementErrorFloors,
    SensorNoise,
    WheelForceProcessNoise,
)
from terrain_estimation.models.rover_sinkage import SinkageSoil

__all__ = ["RoverEstimatorConfig"]

#: Default initial standard deviations of Estimator 1 (x1 order): the
#: measurements pin rates, angles and speed; the equilibrium guess of the
#: net forces and torques is off by what the rover was doing.
_GENERAL_P0_SIGMA: tuple[float, ...] = (
    (1e-3,) * 3  # wheel rates (rad/s)
    + (0.1,) * 3  # τ_R (N·m)
    + (2e-4, 1e-4, 1e-3, 1e-3)  # θ, q1 (rad), θ̇, q̇1 (rad/s)
    + (1e-2, 1e-2, 1e-2, 1e-2)  # θ̈, q̈1 (rad/s²), ẍ0, z̈0 (m/s²)
    + (0.5, 0.3, 1.0, 1.0)  # M_0fw, M_1fw (N·m), F_xfw, F_zfw (N)
    + (1e-3,)  # ẋ^R (m/s)
    + (0.05,) * 3  # slips
)
#: Default initial standard deviations of Estimators 2/3 (x2 order): γ (rad), W (N), DP (N).
_WHEEL_FORCE_P0_SIGMA: tuple[float, ...] = (0.02,) * 3 + (1.0,) * 3 + (1.0,) * 3


def _check_optional_values(name: str, value: Sequence[float] | None, size: int, *, positive: bool) -> None:
    if value is None:
        return
    values = tuple(float(v) for v in value)
    ok = len(values) == size and all(math.isfinite(v) and (v > 0.0 if positive else True) for v in values)
    if not ok:
        need = "finite values > 0" if positive else "finite values"
        raise ValueError(f"{name} must be None or {size} {need}, got {value!r}")


@dataclass(frozen=True, kw_only=True)
class RoverEstimatorConfig:
    """Configuration of :class:`RoverTerrainEstimator` (one frozen object).

    Attributes:
        rover: vehicle parameters (Tables I and III plus the geometry, MODELS.md C.3).
        load_cell_axes: 2 → Estimator 2 (two-axis cells, F_⊥ measured);
            1 → Estimator 3 (single-axis, F_⊥ synthesised by eqs. 86–88).
        sensor_rate_hz: nominal rate of every sensor stream (50 Hz, CONTRACT.md).
        estimator_rate_hz: 1/T_e (5 Hz, [RB] V).
        sensor_noise: Table IV σ of one sample (sets R, module
            :mod:`~terrain_estimation.models.rover_estimators`).
        floors: model-error σ added to R.
        general_process_noise, wheel_force_process_noise: Q per T_e.
        general_q_diag, wheel_force_q_diag: override Q (22 / 9 variances per T_e).
        general_r_diag, wheel_force_r_diag: override R (11 / 9 variances), held
            fixed instead of the per-step propagated values.
        initial_general_state, initial_wheel_force_state: override the
            measurement-based initial means (22 / 9 values, x1 / x2 order).
        general_p0_sigma, wheel_force_p0_sigma: initial σ (22 / 9 values).
        slip_rate_source: θ̇, q̇1 of eq. 66: ``"imu"`` or ``"estimate"`` (module docstring).
        perpendicular_split: how Estimator 3 splits F_⊥12 between the bogie
            wheels: ``"load_cell"`` = eq. 88 (same F_⊥/F_L), ``"terrain"`` =
            same DP/W in the frames of the measured contact angles γ̌ (see
            :func:`~terrain_estimation.models.rover_estimators.synthesised_perpendicular_forces`).
        vertical_velocity: ż0^R in the contact angles (eq. 79): ``"zero"``
            as the paper assumes (eq. 45), or ``"geometric"`` from the path
            through the three wheel centres
            (:func:`~terrain_estimation.models.rover_estimators.contact_angles_with_vertical_speed`).
        quasi_static_forces: Estimator 1's net wheel forces follow the
            equilibrium (True) or are pure random walks, eq. 59 (False); see
            :class:`~terrain_estimation.models.rover_estimators.GeneralEstimatorModel`.
        absolute_spin: slip from the wheel's absolute spin (True) or its
            joint rate as eq. 68 prints (False); see
            :func:`~terrain_estimation.models.rover_estimators.slip_measurement`.
        min_window_fraction: a window needs at least this fraction of the
            expected samples (rate × T_e) of every stream, and at least one.
        max_latency_s: how long a window waits for a lagging stream (s).
        max_gap_s: a longer time without a step re-initialises the filters (s).
        max_consecutive_failures: failed steps in a row before re-initialising.
        ukf_alpha, ukf_beta, ukf_kappa: sigma-point parameters (α = 1, κ = 0:
            positive weights for any n).
        gate_threshold: NIS gate of both filters; None disables.
        divergence: divergence detection and recovery of both filters
            (:class:`~terrain_estimation.filters.faults.DivergenceConfig`, one
            monitor per filter, module docstring); None (default) keeps only
            the handling of failed steps.
        noise_matching: innovation matching of the noise blocks (Estimator 1:
            Q of the slips, Q of τ_R, R of the slip channels; Estimator 2/3:
            Q of γ, W, DP), :mod:`~terrain_estimation.estimators.rover_noise`.
        contact_angle_bias: γ̌'s coloured error, considered in the published
            variances of γ, W and DP: a prior σ_b raised to the error the
            wheels' repeat passes show; optionally the parabola's error on the
            path the wheels traced and the sinkage model's tilt
            (:class:`~terrain_estimation.estimators.rover_noise.ContactAngleBias`).
        split_traction_slope: Estimator 3 (terrain-frame split): k, the slope
            of DP/W against slip, which with the bogie wheels' slip difference
            sizes the error of giving both one DP/W
            (:func:`~terrain_estimation.estimators.rover_noise.split_covariance`);
            0.55 for the nominal [RB] Table II soil under a Kapvik wheel at
            slips 0.15–0.25 (the slope of the Wong–Reece surrogate there,
            DP/W 0.003 → 0.058 from i = 0.15 to 0.25 at 41–60 N); 0 disables.
        settle_steps: updates after a (re)initialisation before an estimate
            is flagged ``settled``.
        sinkage: the estimator's own model of each wheel's sinkage (Bekker's
            pressure–sinkage with nominal soil, loads from Estimator 2/3),
            which lifts the wheel centres back onto the path and removes the
            sinking rate from the kinematic contact angles
            (:mod:`~terrain_estimation.models.rover_sinkage`; ``vertical_velocity
            = "geometric"`` only).
    """

    rover: RoverParams = field(default_factory=RoverParams)
    load_cell_axes: int = 2
    sensor_rate_hz: float = 50.0
    estimator_rate_hz: float = 5.0
    sensor_noise: SensorNoise = field(default_factory=SensorNoise)
    floors: MeasurementErrorFloors = field(default_factory=MeasurementErrorFloors)
    general_process_noise: GeneralProcessNoise = field(default_factory=GeneralProcessNoise)
    wheel_force_process_noise: WheelForceProcessNoise = field(default_factory=WheelForceProcessNoise)
    general_q_diag: tuple[float, ...] | None = None
    wheel_force_q_diag: tuple[float, ...] | None = None
    general_r_diag: tuple[float, ...] | None = None
    wheel_force_r_diag: tuple[float, ...] | None = None
    initial_general_state: tuple[float, ...] | None = None
    initial_wheel_force_state: tuple[float, ...] | None = None
    general_p0_sigma: tuple[float, ...] = _GENERAL_P0_SIGMA
    wheel_force_p0_sigma: tuple[float, ...] = _WHEEL_FORCE_P0_SIGMA
    slip_rate_source: Literal["imu", "estimate"] = "estimate"
    absolute_spin: bool = True
    quasi_static_forces: bool = True
    perpendicular_split: Literal["terrain", "load_cell"] = "terrain"
    vertical_velocity: Literal["geometric", "zero"] = "geometric"
    min_window_fraction: float = 0.5
    max_latency_s: float = 0.1
    max_gap_s: float = 1.0
    max_consecutive_failures: int = 3
    ukf_alpha: float = 1.0
    ukf_beta: float = 2.0
    ukf_kappa: float = 0.0
    gate_threshold: float | None = None
    divergence: DivergenceConfig | None = None
    noise_matching: NoiseMatchingConfig = field(default_factory=NoiseMatchingConfig)
    contact_angle_bias: ContactAngleBias = field(default_factory=ContactAngleBias)
    split_traction_slope: float = 0.55
    settle_steps: int = 10
    sinkage: SinkageSoil = field(default_factory=SinkageSoil)

    def __post_init__(self) -> None:
        if self.divergence is not None and not isinstance(self.divergence, DivergenceConfig):
            raise ValueError(f"divergence must be None or a DivergenceConfig, got {type(self.divergence).__name__}")
        if self.load_cell_axes not in (1, 2) or isinstance(self.load_cell_axes, bool):
            raise ValueError(f"load_cell_axes must be 1 or 2, got {self.load_cell_axes!r}")
        for name in ("sensor_rate_hz", "estimator_rate_hz", "max_latency_s", "max_gap_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if self.estimator_rate_hz > self.sensor_rate_hz:
            raise ValueError(
                f"estimator_rate_hz ({self.estimator_rate_hz}) must not exceed sensor_rate_hz ({self.sensor_rate_hz})"
            )
        if self.max_gap_s <= self.step_s:
            raise ValueError(f"max_gap_s ({self.max_gap_s}) must exceed the step 1/estimator_rate_hz ({self.step_s})")
        if not (math.isfinite(self.min_window_fraction) and 0.0 <= self.min_window_fraction <= 1.0):
            raise ValueError(f"min_window_fraction must be in [0, 1], got {self.min_window_fraction!r}")
        if not (isinstance(self.max_consecutive_failures, int) and self.max_consecutive_failures >= 1):
            raise ValueError(f"max_consecutive_failures must be an int ≥ 1, got {self.max_consecutive_failures!r}")
        if self.vertical_velocity not in ("geometric", "zero"):
            raise ValueError(f"vertical_velocity must be 'geometric' or 'zero', got {self.vertical_velocity!r}")
        if self.perpendicular_split not in ("terrain", "load_cell"):
            raise ValueError(f"perpendicular_split must be 'terrain' or 'load_cell', got {self.perpendicular_split!r}")
        if self.slip_rate_source not in ("imu", "estimate"):
            raise ValueError(f"slip_rate_source must be 'imu' or 'estimate', got {self.slip_rate_source!r}")
        if not (
            isinstance(self.settle_steps, int) and not isinstance(self.settle_steps, bool) and self.settle_steps >= 0
        ):
            raise ValueError(f"settle_steps must be an int ≥ 0, got {self.settle_steps!r}")
        check_non_negative("RoverEstimatorConfig", "split_traction_slope", self.split_traction_slope)
        _check_optional_values("general_q_diag", self.general_q_diag, 22, positive=False)
        if self.general_q_diag is not None and min(self.general_q_diag) < 0.0:
            raise ValueError(f"general_q_diag must hold variances ≥ 0, got {self.general_q_diag!r}")
        _check_optional_values("wheel_force_q_diag", self.wheel_force_q_diag, 9, positive=False)
        if self.wheel_force_q_diag is not None and min(self.wheel_force_q_diag) < 0.0:
            raise ValueError(f"wheel_force_q_diag must hold variances ≥ 0, got {self.wheel_force_q_diag!r}")
        _check_optional_values("general_r_diag", self.general_r_diag, 11, positive=True)
        _check_optional_values("wheel_force_r_diag", self.wheel_force_r_diag, 9, positive=True)
        _check_optional_values("initial_general_state", self.initial_general_state, 22, positive=False)
        _check_optional_values("initial_wheel_force_state", self.initial_wheel_force_state, 9, positive=False)
        _check_optional_values("general_p0_sigma", self.general_p0_sigma, 22, positive=True)
        _check_optional_values("wheel_force_p0_sigma", self.wheel_force_p0_sigma, 9, positive=True)
        self.make_filter()  # validates α, β, κ and the gate

    @property
    def step_s(self) -> float:
        """T_e = 1/``estimator_rate_hz`` (s)."""
        return 1.0 / self.estimator_rate_hz

    @property
    def estimator_number(self) -> int:
        """2 (two-axis load cells) or 3 (single-axis)."""
        return 2 if self.load_cell_axes == 2 else 3

    @property
    def min_window_samples(self) -> int:
        """Samples per stream a window needs to run a step."""
        return max(1, math.ceil(self.min_window_fraction * self.sensor_rate_hz * self.step_s - 1e-9))

    def make_filter(self) -> UnscentedKalmanFilter:
        """The UKF both estimators use."""
        return UnscentedKalmanFilter(
            alpha=self.ukf_alpha, beta=self.ukf_beta, kappa=self.ukf_kappa, gate_threshold=self.gate_threshold
        )
