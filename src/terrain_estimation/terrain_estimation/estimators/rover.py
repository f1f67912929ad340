"""Rocker-bogie terrain-response estimator core: 50 Hz sensors → 0.2 s windows → Estimators 1 and 2|3 ([RB] IV).

The ROS-free core the rover node and the offline runners drive
(CONTRACT.md "Rocker-bogie rover"). :class:`RoverTerrainEstimator` owns two
unscented Kalman filters over the models of
:mod:`terrain_estimation.models.rover_estimators`: Estimator 1 (22 states)
and, after it in the same step, Estimator 2 (two-axis load cells,
``load_cell_axes = 2``) or Estimator 3 (single-axis, ``load_cell_axes = 1``).
:class:`TerrainResponseAccumulator` turns the estimates into the online
DP(W, i), τ_R(W, i) models of ``terrain_msgs/TerrainResponseModel`` (C.7).

**Where the defaults leave the paper, and why** (each switchable back in
:class:`RoverEstimatorConfig`; figures measured on the project's truth plant,
``vehicle_sim.plants.rover``, terrains 1–6, Table IV noise, seed 0):

* ``vertical_velocity = "geometric"``: ż0^R from the path through the three
  wheel centres instead of ż0^R = 0 (eq. 45); the assumption's error
  δ ≈ −ż0^R/ẋ0^R (eqs. 90–91) was 0.035 rad RMS of contact angle on
  terrain 1, 1.5–2.5 N of DP.
* ``perpendicular_split = "terrain"`` (Estimator 3): the bogie's F_⊥12 split
  at a common DP/W in the terrain frames rather than a common F_⊥/F_L
  (eq. 88), which put W sin(γ − ε) into DP (5 N RMS on the middle wheel,
  terrain 1).
* ``slip_rate_source = "estimate"``: θ̇, q̇1 of eq. 66 from Estimator 1, not
  the 0.56 °/s gyro.
* ``quasi_static_forces``: the net wheel forces of Estimator 1 follow the
  equilibrium (models module), so θ̇ — the input of every contact angle —
  is not shaken by loose random walks.

* Honest variances (issue 21, :mod:`~terrain_estimation.estimators.rover_noise`):
  process noise sized to the change per step, Estimator 1's wheel-rate Q and
  slip R and Estimator 2/3's Q of W and DP (rotated with γ) matched to the innovations
  (``noise_matching``), the coloured contact-angle error and eq. 49's
  neglected wheel coupling considered in the published variances
  (``contact_angle_bias``), τ_R published for the window just observed, and
  ``settled`` False for the first ``settle_steps`` updates after a start.

* ``sinkage`` (issue 21, :mod:`~terrain_estimation.models.rover_sinkage`):
  the wheels sink into the soil by different depths under different loads,
  so the three wheel centres are not on one path and a wheel whose load
  changes moves off the surface at its sinking rate ṡ. The estimator's own
  Bekker pressure–sinkage model (nominal [RB] Table II soil, the loads of
  Estimator 2/3's prior) lifts each centre by its sinkage before the path is
  fitted and adds ṡ back to its velocity (``vertical_velocity = "geometric"``).

With the first four the RMS errors of Table V's 144 cells (6 terrains × E1+E2,
E1+E3 × 12) were at or below the paper's in 133 (92 %) on the rigid-ground
plant, with the noise sizing of issue 21 in 127 (88 %); the plant's wheel
sinkage (issue 21) took them to 114 (79 %; DP 15 of 36 cells), and the
sinkage model back to 120 (83 %, DP 19 of 36; run 0 of each terrain, the
reproduction's mean over four noise runs in ``docs/results/rover.md``):
measured on terrain 1 and 4 it does what the truth sinkage itself does when
given to the estimator (DP RMS of the rear wheel, terrain 4: 0.642 N without,
0.484 N with the true s and ṡ, 0.478 N with the model). With the paper's
choices on the same data 54–58 (38–40 %), its DP errors on this plant's
terrains being dominated by the ż0^R = 0 assumption.

Data flow (all times are the ``t`` arguments, in seconds; no wall clock):

* ``add_imu`` (specific force f_x, f_z along the body axes, m/s², gravity
  included as eqs. 72–73 read it; pitch rate about +y, rad/s), ``add_joint_state``
  (bogie angle q1, the three wheel angles q2..q4 relative to their carriers,
  rad, and the three applied wheel torques τ_W, N·m), ``add_velocimeter``
  (forward speed along the body x axis, m/s) and ``add_load_cell`` (per wheel:
  F_L along the sensing axis, and F_⊥ with two-axis cells, N). Wheel order
  :data:`~terrain_estimation.models.rover.WHEELS` (rear, middle, front).
* **Windows.** Time is cut into windows of T_e = 1/``estimator_rate_hz``
  (0.2 s) on a grid starting at the first stamp received: window k holds the
  stamps in (t0 + (k−1) T_e, t0 + k T_e]. Each stream is averaged over the
  window ("temporally averaged measurements", [RB] V); the wheel and bogie
  angles are differenced between the last sample of the window and the last
  sample of the previous one (eq. 63: the exact mean rate over the window;
  the difference is wrapped into (−π, π], so encoders that wrap are fine
  up to 15 rad/s). A window is closed when every stream has delivered a
  stamp past its end, or when any stream is ``max_latency_s`` past it (a
  stream that lags or stopped). Samples for a window already closed are
  dropped (``counters.late_samples``).
* **Steps.** A closed window with at least ``min_window_fraction`` of the
  expected samples of every stream runs one step: Estimator 1 (predict with
  the window's mean torques, update with y1) and then Estimator 2/3 (γ̌ from
  Estimator 1's posterior, eq. 79; F_⊥ measured or synthesised, eqs. 86–88).
  Other windows are skipped (``counters.incomplete_windows``) and the next
  step predicts over the longer interval. The first usable window, or one
  after a gap longer than ``max_gap_s``, initialises both filters from its
  measurements (:func:`~terrain_estimation.models.rover_estimators.initial_general_state`:
  a rover in equilibrium) and produces an estimate flagged ``initialised``.
* ``flush()`` closes every open window (end of a log); ``drain_estimates()``
  returns the estimates produced so far, oldest first.

**Pitch and bogie rates in the slip measurement.** Eq. 66 needs θ̇ and q̇1.
``slip_rate_source = "imu"`` (the paper) takes the IMU pitch rate averaged
over the window and the differenced bogie encoder; ``"estimate"``
(default) takes Estimator 1's predicted θ̇, q̇1 of the step. The IMU rate's
0.56 °/s noise, 3e-3 rad/s after averaging a window, is 1 % of a wheel's
spin at 2 cm/s and ≈ 1 mm/s of wheel-centre speed at the 0.35 m lever of
the outer wheels: measured on the simulated terrain 1 the slip RMS error
drops from 0.017 to 0.009 with the estimate (E1 θ̇ error ≈ 4e-4 rad/s).
The slip states are coupled to nothing else in Estimator 1, so using the
prediction does not feed back.

**Stamps.** Every average, and the encoder differences of eq. 63,
describes the whole window, so an estimate is stamped at the window's
centre (its end − T_e/2); it is produced when the window closes.

**Never NaN.** Non-finite values, wrong lengths, unknown wheel names and
stamps not after the previous one of the same stream raise ValueError
naming the field and value (nothing is stored). A step whose filter
arithmetic fails or leaves a non-finite state is skipped
(``counters.failed_steps``) and the filters keep their previous posterior;
after ``max_consecutive_failures`` in a row they re-initialise at the next
usable window.

**Divergence (issue 7).** With ``config.divergence`` set, each filter has a
:class:`~terrain_estimation.filters.faults.DivergenceMonitor`: a filter that
stays finite but diverges (its windowed mean NIS outside its χ² band, a
variance above ``max_variance_growth`` times its initial one, a gate
lock-out), or a step that fails or leaves a non-finite state, re-initialises
from its *last good* estimate (the newest one whose NIS window was inside its
band) with its initial covariance, and the step's estimate is flagged
``initialised`` (``counters.divergences``; :attr:`RoverTerrainEstimator.fault`
holds the reason until the filter is consistent again). Estimator 2/3 runs on
Estimator 1's posterior, so it restarts from its own last good estimate too
when Estimator 1 diverges (without a fault of its own). A failed step still
counts in ``failed_steps``, and ``max_consecutive_failures`` of them in a row
re-initialise from the measurements as without the monitor.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from terrain_estimation.estimators.rover_diagnostics import consistency_channels, subset_nis
from terrain_estimation.estimators.rover_noise import (
    ContactAngleBias,
    NoiseBlock,
    NoiseMatchingConfig,
    considered_variances,
    coupling_variance,
    is_settled,
    match_noise_scales,
    process_block_part,
    rotated_force_noise_factor,
    smoothed_random_walk_variance,
)
from terrain_estimation.filters.base import Array, GaussianState, UpdateInfo
from terrain_estimation.filters.faults import DivergenceCheck, DivergenceConfig, DivergenceMonitor
from terrain_estimation.filters.ukf import UnscentedKalmanFilter
from terrain_estimation.models.rover import WHEELS, RoverParams, carrier_angles
from terrain_estimation.models.rover_estimators import (
    GENERAL_STATES,
    GeneralEstimatorModel,
    GeneralIndex,
    GeneralInput,
    GeneralProcessNoise,
    MeasurementErrorFloors,
    SensorNoise,
    WheelForceModel,
    WheelForceProcessNoise,
    configuration,
    contact_angle_covariance,
    contact_angles_with_vertical_speed,
    general_measurement,
    general_measurement_variances,
    initial_general_state,
    initial_wheel_force_state,
    kinematic_terms,
    path_tangent_angles,
    pitch_from_gravity,
    propagate_covariance,
    synthesised_perpendicular_forces,
    wheel_force_measurement_variances,
)
from terrain_estimation.models.rover_sinkage import SinkageSoil, SinkageTracker
from terrain_estimation.models.terrain_response import (
    PolynomialModel2D,
    ValidityRegion,
    coefficient_count,
    fit_polynomial_2d,
    polynomial_exponents,
)
from terrain_estimation.models.terrain_response_error import (
    ValidatedFit,
    bounded_update,
    model_variance,
    region_mean_variance,
    validated_fit,
)

__all__ = [
    "RoverBodyEstimate",
    "RoverCounters",
    "RoverEstimate",
    "RoverEstimatorConfig",
    "RoverTerrainEstimator",
    "TerrainResponseAccumulator",
    "TerrainResponseConfig",
    "TerrainResponseCounters",
    "TerrainResponseFit",
    "WheelTerrainEstimate",
]

_G = GeneralIndex

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

_RATE_IDX: list[int] = list(range(0, 3))
_SLIP_IDX: list[int] = list(range(19, 22))
_TAU_IDX: list[int] = list(range(3, 6))


#: Memory (steps) of the averaged inertial-coupling variance of τ_R: 5 s at 5 Hz.
_COUPLING_MEMORY = 25.0


def _block_cov(L: Array, columns: list[int]) -> Array:
    """Q_g = L_g L_gᵀ of the columns ``columns`` of a factor L of Q."""
    Lg = L[:, columns]
    return np.asarray(Lg @ Lg.T, dtype=float)


_STREAMS_BASE: tuple[str, ...] = ("imu", "joint_states", "velocimeter")
_CELL_STREAMS: tuple[str, ...] = tuple(f"load_cell_{w}" for w in WHEELS)
_STREAMS: tuple[str, ...] = _STREAMS_BASE + _CELL_STREAMS


# ---------------------------------------------------------------------------
# Configuration
# ---------------------------------------------------------------------------


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
        contact_angle_bias: γ̌'s coloured error as three Gauss–Markov states
            of Estimator 2/3 (:class:`~terrain_estimation.estimators.rover_noise.ContactAngleBias`).
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


# ---------------------------------------------------------------------------
# Outputs
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class WheelTerrainEstimate:
    """Terrain response at one wheel (``terrain_msgs/WheelTerrain``); every float finite.

    Attributes:
        wheel: "rear", "middle" or "front".
        slip: i (–), Estimator 1; > 0 slip, < 0 skid.
        normal_load: W (N), Estimator 2/3.
        drawbar_pull: DP (N), Estimator 2/3.
        resistive_torque: τ_R (N·m), Estimator 1.
        contact_angle: γ, wheel–terrain contact angle w.r.t. the world
            horizontal (rad), positive where the terrain descends forward
            (same sense as the pitch), Estimator 2/3.
        *_variance: the filters' posterior variances.
    """

    wheel: str
    slip: float
    slip_variance: float
    normal_load: float
    normal_load_variance: float
    drawbar_pull: float
    drawbar_pull_variance: float
    resistive_torque: float
    resistive_torque_variance: float
    contact_angle: float
    contact_angle_variance: float


@dataclass(frozen=True)
class RoverBodyEstimate:
    """Estimator 1 body states (eq. 43) with their variances.

    Attributes:
        pitch: θ0y (rad), positive nose down.
        bogie_angle: q1 (rad).
        pitch_rate, bogie_rate: (rad/s).
        pitch_acceleration, bogie_acceleration: (rad/s²).
        x_acceleration, z_acceleration: ẍ0, z̈0 of O, world (m/s²).
        body_moment: M_0fw, moment of the wheel linear forces about O (N·m).
        bogie_moment: M_1fw, their moment about the bogie joint (N·m).
        wheel_force_x, wheel_force_z: F_xfw, F_zfw, their world sums (N).
        forward_speed: ẋ0^R along the body x axis (m/s).
        vertical_speed: ż0^R along the body z axis (m/s): 0 with
            ``vertical_velocity = "zero"``, else the geometric estimate.
        vertical_speed_variance: its variance ((m/s)²).
        wheel_rates: q̇2..q̇4, joint rates (rad/s), WHEELS order.
        variances: posterior variances of all 22 states, :data:`GENERAL_STATES` order.
    """

    pitch: float
    bogie_angle: float
    pitch_rate: float
    bogie_rate: float
    pitch_acceleration: float
    bogie_acceleration: float
    x_acceleration: float
    z_acceleration: float
    body_moment: float
    bogie_moment: float
    wheel_force_x: float
    wheel_force_z: float
    forward_speed: float
    vertical_speed: float
    vertical_speed_variance: float
    wheel_rates: tuple[float, float, float]
    variances: tuple[float, ...]

    def variance(self, state: str) -> float:
        """Variance of a state named as in :data:`GENERAL_STATES`."""
        return self.variances[GENERAL_STATES.index(state)]


@dataclass(frozen=True)
class RoverEstimate:
    """One step's estimates (``terrain_msgs/WheelTerrainArray`` plus Estimator 1's body states).

    Attributes:
        t: centre of the step's window (s): the time its averages describe.
        wheels: per-wheel estimates in WHEELS order.
        body: Estimator 1 body states.
        distance: path length travelled along the body x axis since the
            first estimate, ∫ ẋ0^R dt (m); the terrain-response accumulator
            estimates curvature from γ against it.
        estimator: 2 or 3 (which wheel-force estimator ran).
        initialised: this estimate comes from a (re)initialisation (or, with
            ``config.divergence``, a recovery from the last good estimate).
        general_nis, wheel_force_nis: NIS of the two updates (0 at initialisation).
        accepted: both updates passed the gate.
        settled: ``settle_steps`` updates have run since the last
            (re)initialisation (False for the first estimates, whose
            variances describe a start from one window's measurements).
        consistency_nis: NIS over the channels of the diagnostics' innovation
            test (velocimeter, slips, load cells;
            :mod:`~terrain_estimation.estimators.rover_diagnostics`), 0 at
            initialisation.
        consistency_dof: its degrees of freedom (10 two-axis, 7 single-axis).
    """

    t: float
    wheels: tuple[WheelTerrainEstimate, ...]
    body: RoverBodyEstimate
    distance: float
    estimator: int
    initialised: bool
    general_nis: float
    wheel_force_nis: float
    accepted: bool
    settled: bool = False
    consistency_nis: float = 0.0
    consistency_dof: int = 0

    def wheel(self, name: str) -> WheelTerrainEstimate:
        """The estimate of wheel ``name`` ("rear", "middle" or "front")."""
        return self.wheels[WHEELS.index(name)]

    def per_wheel(self, quantity: str) -> Array:
        """One quantity of every wheel (e.g. ``"normal_load"``), shape (3,), WHEELS order."""
        return np.array([getattr(w, quantity) for w in self.wheels], dtype=float)


@dataclass(frozen=True)
class RoverCounters:
    """Health counters since construction or :meth:`RoverTerrainEstimator.reset`."""

    imu_samples: int = 0
    joint_samples: int = 0
    velocimeter_samples: int = 0
    load_cell_samples: int = 0
    late_samples: int = 0
    windows: int = 0
    incomplete_windows: int = 0
    steps: int = 0
    initialisations: int = 0
    restarts: int = 0
    failed_steps: int = 0
    divergences: int = 0
    gated_general: int = 0
    gated_wheel_force: int = 0


# ---------------------------------------------------------------------------
# Input validation
# ---------------------------------------------------------------------------


def _finite(where: str, name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {name} must be a finite number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{where}: {name} must be finite, got {value!r}")
    return v


def _three(where: str, name: str, value: Any) -> Array:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {name} must be 3 finite numbers (rear, middle, front), got {value!r}") from None
    if arr.shape != (3,):
        raise ValueError(f"{where}: {name} must have 3 values (rear, middle, front), got {value!r}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{where}: {name} must be finite, got {value!r}")
    return arr


# ---------------------------------------------------------------------------
# Windows of averaged measurements
# ---------------------------------------------------------------------------


@dataclass
class _Window:
    """Sums of one window's samples (mutable, private)."""

    index: int
    imu_n: int = 0
    specific_force: Array = field(default_factory=lambda: np.zeros(2))
    pitch_rate: float = 0.0
    joint_n: int = 0
    bogie_sum: float = 0.0
    torque_sum: Array = field(default_factory=lambda: np.zeros(3))
    joint_first: tuple[float, float, Array] | None = None  # (t, bogie, wheel angles)
    joint_last: tuple[float, float, Array] | None = None
    speed_n: int = 0
    speed_sum: float = 0.0
    cell_n: Array = field(default_factory=lambda: np.zeros(3, dtype=int))
    axial_sum: Array = field(default_factory=lambda: np.zeros(3))
    perpendicular_sum: Array = field(default_factory=lambda: np.zeros(3))


def _finite_state(state: GaussianState) -> bool:
    return bool(np.isfinite(state.x).all() and np.isfinite(state.P).all())


def _angle_difference(a: Array | float, b: Array | float) -> Array:
    """a − b wrapped into (−π, π] (encoders that wrap their angle)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    return np.asarray(np.remainder(d + math.pi, 2.0 * math.pi) - math.pi, dtype=float)


# ---------------------------------------------------------------------------
# The estimator
# ---------------------------------------------------------------------------


class RoverTerrainEstimator:
    """Per-wheel slip, W, DP, τ_R and contact angle of the rocker-bogie rover (module docstring).

    Args:
        config: settings; defaults are Estimators 1 + 2 with Table IV noise.
    """

    def __init__(self, config: RoverEstimatorConfig | None = None) -> None:
        self.config = config if config is not None else RoverEstimatorConfig()
        cfg = self.config
        self.filter = cfg.make_filter()
        # Moments for the noise matching, from a plain UKF of the same parameters (the step's filter may be wrapped).
        self._moments = cfg.make_filter()
        self.general_model = GeneralEstimatorModel(
            cfg.rover, process_noise=cfg.general_process_noise, step_s=cfg.step_s, quasi_static=cfg.quasi_static_forces
        )
        self.wheel_force_model = WheelForceModel(process_noise=cfg.wheel_force_process_noise, step_s=cfg.step_s)
        q1 = (
            cfg.general_process_noise.sigma() ** 2
            if cfg.general_q_diag is None
            else np.array(cfg.general_q_diag, dtype=float)
        )
        q2 = (
            cfg.wheel_force_process_noise.sigma() ** 2
            if cfg.wheel_force_q_diag is None
            else np.array(cfg.wheel_force_q_diag, dtype=float)
        )
        self._q1_sigma = np.sqrt(q1)
        self._q2_sigma = np.sqrt(q2)
        self._p1 = np.diag(np.square(np.array(cfg.general_p0_sigma, dtype=float)))
        self._p2 = np.diag(np.square(np.array(cfg.wheel_force_p0_sigma, dtype=float)))
        self._required = _STREAMS
        self._sinkage = SinkageTracker(cfg.sinkage, cfg.rover.wheel_radius, cfg.rover.wheel_width)
        self.reset()

    # -- public API -----------------------------------------------------------------
    def reset(self) -> None:
        """Forget the filters, the windows, the outbox and the counters."""
        self._general: GaussianState | None = None
        self._wheel_force: GaussianState | None = None
        self._t_origin: float | None = None
        self._closed_upto = -1
        self._open: dict[int, _Window] = {}
        self._latest: dict[str, float] = {}
        self._last_joint: tuple[float, float, Array] | None = None
        self._t_step: float | None = None
        self._distance = 0.0
        self._failures = 0
        self._vertical = (0.0, 0.0)
        self._sinkage.reset()
        self._since_start = 0
        self._scales1 = np.ones(2)  # Q wheel rates, R slips
        self._scales2 = np.ones(2)  # Q W, Q DP (rotated with γ, rover_noise.rotated_force_noise_factor)
        self._next_scales = (self._scales1, self._scales2)
        self._tau_step_var = np.zeros(3)  # Q of τ_R over the last step
        self._coupling_var = np.zeros(3)  # averaged considered coupling variance of τ_R (rover_noise)
        self._next_tau_step_var = np.zeros(3)
        self._last: RoverEstimate | None = None
        self._outbox: list[RoverEstimate] = []
        self._c: dict[str, int] = dict.fromkeys(RoverCounters.__dataclass_fields__, 0)
        div = self.config.divergence
        # Estimator 1 and Estimator 2/3.
        self._monitors = (DivergenceMonitor(div), DivergenceMonitor(div)) if div is not None else None

    @property
    def counters(self) -> RoverCounters:
        """Snapshot of the health counters."""
        return RoverCounters(**self._c)

    @property
    def fault(self) -> str | None:
        """Why a filter was last found diverged, until it is consistent again; None when healthy.

        Names the filter (``"Estimator 1: ..."``). Always None without ``config.divergence``.
        """
        if self._monitors is None:
            return None
        numbers = (1, self.config.estimator_number)
        faults = [f"Estimator {n}: {m.fault}" for n, m in zip(numbers, self._monitors, strict=True) if m.fault]
        return "; ".join(faults) if faults else None

    @property
    def last_estimate(self) -> RoverEstimate | None:
        """The newest estimate (None before the first)."""
        return self._last

    @property
    def initialised(self) -> bool:
        """Both filters hold a state."""
        return self._general is not None and self._wheel_force is not None

    def drain_estimates(self) -> list[RoverEstimate]:
        """Estimates produced since the last call, oldest first (and clear them)."""
        out, self._outbox = self._outbox, []
        return out

    def add_imu(self, t: float, specific_force_x: float, specific_force_z: float, pitch_rate: float) -> None:
        """One IMU sample: body-frame specific force (m/s², eqs. 72–73) and pitch rate about +y (rad/s).

        Raises:
            ValueError: a non-finite argument or a stamp not after the previous IMU stamp.
        """
        where = "add_imu"
        tt = _finite(where, "t", t)
        fx = _finite(where, "specific_force_x", specific_force_x)
        fz = _finite(where, "specific_force_z", specific_force_z)
        rate = _finite(where, "pitch_rate", pitch_rate)
        window = self._window_for(where, "imu", tt)
        self._c["imu_samples"] += 1
        if window is not None:
            window.imu_n += 1
            window.specific_force += (fx, fz)
            window.pitch_rate += rate
        self._close_ready()

    def add_joint_state(
        self, t: float, bogie_angle: float, wheel_angles: Sequence[float], wheel_torques: Sequence[float]
    ) -> None:
        """One joint-state sample: bogie angle q1, wheel angles q2..q4 (rad), applied wheel torques τ_W (N·m).

        Wheel angles are relative to their carriers, positive rolling forward,
        in WHEELS order (rear, middle, front); so are the torques.

        Raises:
            ValueError: a non-finite value, not 3 wheel values, or a stamp not
                after the previous joint-state stamp.
        """
        where = "add_joint_state"
        tt = _finite(where, "t", t)
        bogie = _finite(where, "bogie_angle", bogie_angle)
        angles = _three(where, "wheel_angles", wheel_angles)
        torques = _three(where, "wheel_torques", wheel_torques)
        window = self._window_for(where, "joint_states", tt)
        self._c["joint_samples"] += 1
        if window is not None:
            window.joint_n += 1
            window.bogie_sum += bogie
            window.torque_sum += torques
            sample = (tt, bogie, angles)
            if window.joint_first is None:
                window.joint_first = sample
            window.joint_last = sample
        self._close_ready()

    def add_velocimeter(self, t: float, forward_speed: float) -> None:
        """One velocimeter sample: speed along the body x axis (m/s).

        Raises:
            ValueError: a non-finite argument or a stamp not after the previous one.
        """
        where = "add_velocimeter"
        tt = _finite(where, "t", t)
        speed = _finite(where, "forward_speed", forward_speed)
        window = self._window_for(where, "velocimeter", tt)
        self._c["velocimeter_samples"] += 1
        if window is not None:
            window.speed_n += 1
            window.speed_sum += speed
        self._close_ready()

    def add_load_cell(self, t: float, wheel: str, axial_force: float, perpendicular_force: float | None = None) -> None:
        """One load-cell sample of ``wheel``: F_L along the sensing axis and, two-axis, F_⊥ (N).

        With ``load_cell_axes = 1`` a given F_⊥ is ignored.

        Raises:
            ValueError: unknown wheel, non-finite force, F_⊥ missing with
                two-axis cells, or a stamp not after this cell's previous one.
        """
        where = "add_load_cell"
        if wheel not in WHEELS:
            raise ValueError(f"{where}: wheel must be one of {WHEELS}, got {wheel!r}")
        tt = _finite(where, "t", t)
        axial = _finite(where, "axial_force", axial_force)
        perpendicular = 0.0
        if self.config.load_cell_axes == 2:
            if perpendicular_force is None:
                raise ValueError(f"{where}: perpendicular_force is required with load_cell_axes = 2 (wheel {wheel!r})")
            perpendicular = _finite(where, "perpendicular_force", perpendicular_force)
        j = WHEELS.index(wheel)
        window = self._window_for(where, _CELL_STREAMS[j], tt)
        self._c["load_cell_samples"] += 1
        if window is not None:
            window.cell_n[j] += 1
            window.axial_sum[j] += axial
            window.perpendicular_sum[j] += perpendicular
        self._close_ready()

    def add_load_cells(
        self, t: float, axial_forces: Sequence[float], perpendicular_forces: Sequence[float] | None = None
    ) -> None:
        """All three load cells at one stamp (WHEELS order); see :meth:`add_load_cell`."""
        where = "add_load_cells"
        axial = _three(where, "axial_forces", axial_forces)
        perp = None if perpendicular_forces is None else _three(where, "perpendicular_forces", perpendicular_forces)
        for j, wheel in enumerate(WHEELS):
            self.add_load_cell(t, wheel, float(axial[j]), None if perp is None else float(perp[j]))

    def flush(self) -> None:
        """Close every open window now (end of a log); complete ones run their step."""
        while self._open:
            self._close(min(self._open))

    # -- windows ------------------------------------------------------------------------
    def _window_index(self, t: float) -> int:
        assert self._t_origin is not None
        return max(0, math.ceil((t - self._t_origin) / self.config.step_s - 1e-9))

    def _window_end(self, index: int) -> float:
        assert self._t_origin is not None
        return self._t_origin + index * self.config.step_s

    def _window_for(self, where: str, stream: str, t: float) -> _Window | None:
        """The open window of stamp ``t`` (None if already closed); checks the stream's order."""
        previous = self._latest.get(stream)
        if previous is not None and t <= previous:
            raise ValueError(f"{where}: t = {t!r} is not after the previous {stream} stamp {previous!r}")
        self._latest[stream] = t
        if self._t_origin is None:
            self._t_origin = t
        index = self._window_index(t)
        if index <= self._closed_upto:
            self._c["late_samples"] += 1
            return None
        window = self._open.get(index)
        if window is None:
            window = self._open[index] = _Window(index)
        return window

    def _close_ready(self) -> None:
        """Close every window that all streams have passed, or one stream by ``max_latency_s``.

        The watermark is the oldest newest-stamp over the streams (once each
        has reported) or the newest stamp less ``max_latency_s``, whichever is
        later; every window ending before it is closed, empty ones included,
        so a sample that arrives behind the watermark is late.
        """
        latest = [self._latest.get(s) for s in self._required]
        seen = [v for v in latest if v is not None]
        if not seen:
            return
        watermark = max(seen) - self.config.max_latency_s
        if len(seen) == len(latest):
            watermark = max(watermark, min(seen))
        assert self._t_origin is not None
        last_closed = math.ceil((watermark - 1e-9 - self._t_origin) / self.config.step_s) - 1
        while self._open and min(self._open) <= last_closed:
            self._close(min(self._open))
        self._closed_upto = max(self._closed_upto, last_closed)

    def _close(self, index: int) -> None:
        window = self._open.pop(index)
        self._closed_upto = max(self._closed_upto, index)
        self._c["windows"] += 1
        previous_joint = self._last_joint
        if window.joint_last is not None:
            self._last_joint = window.joint_last
        need = self.config.min_window_samples
        counts = [window.imu_n, window.joint_n, window.speed_n, *window.cell_n.tolist()]
        rates = self._joint_rates(window, previous_joint)
        if min(counts) < need or rates is None:
            self._c["incomplete_windows"] += 1
            return
        self._step(self._window_end(index) - 0.5 * self.config.step_s, window, rates)

    def _joint_rates(
        self, window: _Window, previous: tuple[float, float, Array] | None
    ) -> tuple[Array, float, float] | None:
        """(q̇2..4, q̇1, interval) by eq. 63 between the previous and this window's last samples."""
        if window.joint_last is None:
            return None
        t1, bogie1, wheels1 = window.joint_last
        if previous is not None and 0.0 < t1 - previous[0] <= self.config.max_gap_s:
            t0, bogie0, wheels0 = previous
        elif window.joint_first is not None and window.joint_first[0] < t1:
            t0, bogie0, wheels0 = window.joint_first
        else:
            return None
        dt = t1 - t0
        return _angle_difference(wheels1, wheels0) / dt, float(_angle_difference(bogie1, bogie0)) / dt, dt

    # -- one step -------------------------------------------------------------------------
    def _step(self, t: float, window: _Window, joint_rates: tuple[Array, float, float]) -> None:
        cfg = self.config
        wheel_rates, bogie_rate, joint_dt = joint_rates
        m = _Means(window, wheel_rates, bogie_rate, joint_dt)
        restart = self._t_step is not None and t - self._t_step > cfg.max_gap_s
        if self._general is None or self._wheel_force is None or restart:
            self._initialise(t, m, restart=restart)
            return
        assert self._t_step is not None
        dt = t - self._t_step
        failure: str | None = None
        try:
            post1, info1, post2, info2, vertical = self._filter_step(dt, m)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            failure = f"filter step failed: {exc}"
        if self._monitors is not None:
            self._supervised(t, dt, failure, *((None,) * 5 if failure else (post1, info1, post2, info2, vertical)))
            return
        if failure is not None or post2 is None or not _finite_state(post2):
            self._c["failed_steps"] += 1
            self._failures += 1
            if self._failures >= cfg.max_consecutive_failures:
                self._general = self._wheel_force = None
            return
        assert info2 is not None
        self._advance(t, dt, post1, post2, info1, info2, vertical)

    def _advance(
        self,
        t: float,
        dt: float,
        post1: GaussianState,
        post2: GaussianState,
        info1: UpdateInfo,
        info2: UpdateInfo,
        vertical: tuple[float, float],
    ) -> None:
        """Keep a step's (finite) posteriors: counters, distance, state, time, and emit the estimate."""
        assert self._general is not None
        self._failures = 0
        self._c["steps"] += 1
        self._c["gated_general"] += int(not info1.accepted)
        self._c["gated_wheel_force"] += int(not info2.accepted)
        self._distance += dt * 0.5 * (float(self._general.x[_G.FORWARD_SPEED]) + float(post1.x[_G.FORWARD_SPEED]))
        self._general, self._wheel_force = post1, post2
        self._vertical = vertical
        self._since_start += 1
        self._scales1, self._scales2 = self._next_scales
        self._tau_step_var = self._next_tau_step_var
        self._t_step = t
        nis1 = info1.nis if math.isfinite(info1.nis) else 0.0
        nis2 = info2.nis if math.isfinite(info2.nis) else 0.0
        general_channels, cell_channels = consistency_channels(self.config.load_cell_axes)
        consistency = subset_nis(info1.innovation, info1.innovation_cov, general_channels) + subset_nis(
            info2.innovation, info2.innovation_cov, cell_channels
        )
        self._emit(
            t,
            initialised=False,
            nis=(nis1, nis2),
            accepted=info1.accepted and info2.accepted,
            consistency=consistency if math.isfinite(consistency) else 0.0,
        )

    def _supervised(
        self,
        t: float,
        dt: float,
        failure: str | None,
        post1: GaussianState | None,
        info1: UpdateInfo | None,
        post2: GaussianState | None,
        info2: UpdateInfo | None,
        vertical: tuple[float, float] | None,
    ) -> None:
        """One step under the divergence monitors (module docstring): keep it or re-initialise from the last good.

        ``post2``/``info2`` are None when Estimator 2/3 did not run (a
        non-finite Estimator 1 posterior); everything is None when the step
        raised (``failure``).
        """
        assert self._monitors is not None and self._general is not None and self._wheel_force is not None
        mon1, mon2 = self._monitors
        if failure is not None:
            self._c["failed_steps"] += 1
            self._failures += 1
            if self._failures >= self.config.max_consecutive_failures:
                # The last good estimates keep failing: re-initialise from the measurements.
                mon1.fail(failure)
                self._c["divergences"] += 1
                self._general = self._wheel_force = None
                return
            state1, check1 = mon1.supervise(self.filter, self._general, failure=failure)
        else:
            state1, check1 = mon1.supervise(self.filter, post1, info1)
        if check1.diverged:
            # Estimator 2/3 ran on a diverged Estimator 1 (or not at all): its own last good estimate.
            state2, check2 = mon2.recover(self.filter), DivergenceCheck(diverged=False)
        else:
            assert post2 is not None and info2 is not None and info1 is not None
            state2, check2 = mon2.supervise(self.filter, post2, info2)
        if not (check1.diverged or check2.diverged):
            assert vertical is not None and info1 is not None and info2 is not None
            self._advance(t, dt, state1, state2, info1, info2, vertical)
            return
        self._c["divergences"] += 1
        self._since_start = 0
        self._scales1 = np.ones(2)
        self._scales2 = np.ones(2)
        self._tau_step_var = np.zeros(3)
        if failure is None:
            self._failures = 0
        self._vertical = vertical if not check1.diverged and vertical is not None else (0.0, 0.0)
        self._distance += dt * 0.5 * (float(self._general.x[_G.FORWARD_SPEED]) + float(state1.x[_G.FORWARD_SPEED]))
        self._general, self._wheel_force = state1, state2
        self._t_step = t
        self._emit(t, initialised=True, nis=(0.0, 0.0), accepted=False)

    def _initialise(self, t: float, m: _Means, *, restart: bool) -> None:
        cfg = self.config
        p = cfg.rover
        pitch = pitch_from_gravity(float(m.specific_force[0]), float(m.specific_force[1]))
        y1 = self._general_measurement(m, pitch_rate=m.pitch_rate, bogie_rate=m.bogie_rate)
        if cfg.initial_general_state is not None:
            x1 = np.array(cfg.initial_general_state, dtype=float)
        else:
            x1 = initial_general_state(
                p,
                wheel_rates=m.wheel_rates,
                wheel_torque=m.wheel_torque,
                pitch=pitch,
                bogie_angle=m.bogie_angle,
                forward_speed=m.forward_speed,
                slip=y1[8:11],
            )
        general = self.filter.initial_state(x1, self._p1)
        if cfg.initial_wheel_force_state is not None:
            x2 = np.array(cfg.initial_wheel_force_state, dtype=float)
        else:
            eps = carrier_angles(p, configuration(float(x1[_G.PITCH]), float(x1[_G.BOGIE])))
            # The rates are not known yet: the path through the three wheel centres gives γ.
            gamma = path_tangent_angles(p, float(x1[_G.PITCH]), float(x1[_G.BOGIE]))[0]
            perp, _ = self._perpendicular(m, x1, np.diag(np.diag(self._p1)), gamma, np.zeros((3, 3)))
            x2 = initial_wheel_force_state(gamma, m.axial_force, perp, eps)
        if not (np.isfinite(x1).all() and np.isfinite(x2).all()):
            self._c["failed_steps"] += 1
            return
        self._general = general
        self._wheel_force = self.filter.initial_state(x2, self._p2)
        if self._monitors is not None:
            self._monitors[0].start(self._general)
            self._monitors[1].start(self._wheel_force)
        self._vertical = (0.0, 0.0)
        self._sinkage.reset()
        self._failures = 0
        self._since_start = 0
        self._scales1 = np.ones(2)
        self._scales2 = np.ones(2)
        self._tau_step_var = np.zeros(3)
        self._c["restarts" if restart else "initialisations"] += 1
        self._t_step = t
        self._emit(t, initialised=True, nis=(0.0, 0.0), accepted=False)

    def _filter_step(
        self, dt: float, m: _Means
    ) -> tuple[GaussianState, UpdateInfo, GaussianState | None, UpdateInfo | None, tuple[float, float]]:
        """Estimator 1 then 2/3: ``(post1, info1, post2, info2, vertical speed and variance)``.

        ``post2``, ``info2`` are None when Estimator 1's posterior is not
        finite (Estimator 2/3 then does not run); ``post2`` is not checked.
        """
        cfg = self.config
        p = cfg.rover
        assert self._general is not None and self._wheel_force is not None
        x_prev = np.asarray(self._general.x, dtype=float)
        terms = kinematic_terms(p, float(x_prev[_G.PITCH]), float(x_prev[_G.BOGIE]))
        u = GeneralInput(m.wheel_torque, terms)
        scale = math.sqrt(dt / cfg.step_s)
        s1, s2 = self._scales1, self._scales2
        q1_sigma = self._q1_sigma.copy()
        q1_sigma[_RATE_IDX] *= math.sqrt(s1[0])
        L1 = self.general_model.process_noise_factor(q1_sigma, dt)
        self._next_tau_step_var = np.square(q1_sigma[_TAU_IDX]) * (dt / cfg.step_s)
        prior1 = self.filter.predict(self._general, self.general_model, u, dt, process_noise_sqrt=L1)
        # Estimator 1 update (eqs. 62–74).
        if cfg.slip_rate_source == "estimate":
            rate, brate = float(prior1.x[_G.PITCH_RATE]), float(prior1.x[_G.BOGIE_RATE])
            rate_vars = (float(prior1.P[_G.PITCH_RATE, _G.PITCH_RATE]), float(prior1.P[_G.BOGIE_RATE, _G.BOGIE_RATE]))
        else:
            rate, brate = m.pitch_rate, m.bogie_rate
            rate_vars = (
                cfg.sensor_noise.pitch_rate**2 / m.imu_n,
                2.0 * cfg.sensor_noise.bogie_angle**2 / m.joint_dt**2,
            )
        y1 = self._general_measurement(m, pitch_rate=rate, bogie_rate=brate)
        if cfg.general_r_diag is not None:
            r1 = np.array(cfg.general_r_diag, dtype=float)
        else:
            r1 = general_measurement_variances(
                p,
                cfg.sensor_noise,
                cfg.floors,
                step_s=m.joint_dt,
                samples=(m.imu_n, m.joint_n, m.speed_n),
                pitch=float(y1[3]),
                bogie_angle=m.bogie_angle,
                forward_speed=m.forward_speed,
                slip_pitch_rate=rate,
                slip_bogie_rate=brate,
                wheel_rates=m.wheel_rates,
                slip_rate_variances=rate_vars,
                absolute_spin=cfg.absolute_spin,
            )
        r1 = r1.copy()
        r1[8:11] *= s1[1]

        post1, info1 = self.filter.update(
            prior1, y1, self.general_model, None, measurement_noise_sqrt=np.diag(np.sqrt(r1))
        )
        next1 = s1
        if cfg.noise_matching.enabled and np.isfinite(info1.nis):
            mm = self._moments.measurement_moments(
                prior1, self.general_model, None, measurement_noise_sqrt=np.diag(np.sqrt(r1))
            )
            blocks = [
                NoiseBlock("Q wheel rates", process_block_part(mm.P_xz, prior1.P, _block_cov(L1, _RATE_IDX))),
                NoiseBlock("R slips", np.diag(np.where(np.arange(11) >= 8, r1, 0.0)), measurement=True),
            ]
            next1 = match_noise_scales(s1, blocks, info1.innovation, info1.innovation_cov, cfg.noise_matching)
        self._next_scales = (next1, s2)
        if not _finite_state(post1):
            return post1, info1, None, None, (0.0, 0.0)
        x1 = np.asarray(post1.x, dtype=float)
        P1 = np.asarray(post1.P, dtype=float)
        # Estimator 2/3 (eqs. 75–89) on Estimator 1's posterior.
        eps = carrier_angles(p, configuration(float(x1[_G.PITCH]), float(x1[_G.BOGIE])))
        kin_idx = [_G.PITCH, _G.BOGIE, _G.FORWARD_SPEED, _G.PITCH_RATE, _G.BOGIE_RATE]
        kin_mean, kin_cov = x1[kin_idx], P1[np.ix_(kin_idx, kin_idx)]
        if cfg.vertical_velocity == "geometric":
            sink: Array | None = None
            sink_rate: Array | None = None
            if cfg.sinkage.enabled:
                # Each wheel's sinkage under its load (Estimator 2/3's, the prior of this step) over the travel.
                load = np.asarray(self._wheel_force.x, dtype=float)[3:6]
                sink, sink_rate = self._sinkage.step(load, float(x1[_G.FORWARD_SPEED]) * dt, dt)
            vs = contact_angles_with_vertical_speed(p, kin_mean, kin_cov, sinkage=sink, sinkage_rate=sink_rate)
            gamma, gamma_cov = vs.contact_angle, vs.contact_angle_cov
            vertical = (vs.vertical_speed, vs.vertical_speed_variance)
        else:
            gamma, gamma_cov = contact_angle_covariance(p, kin_mean, kin_cov)
            vertical = (0.0, 0.0)
        perp, perp_cov = self._perpendicular(m, x1, P1, gamma, gamma_cov)
        y2 = np.concatenate([gamma, m.axial_force, perp])
        if cfg.wheel_force_r_diag is not None:
            r2 = np.array(cfg.wheel_force_r_diag, dtype=float)
        else:
            r2 = wheel_force_measurement_variances(
                contact_angle_cov=gamma_cov,
                noise=cfg.sensor_noise,
                floors=cfg.floors,
                load_cell_samples=m.cell_n,
                synthesised_cov=perp_cov,
            )
        L2 = rotated_force_noise_factor(
            self._q2_sigma * scale * np.repeat(np.sqrt(np.concatenate([[1.0], s2])), 3),
            np.asarray(self._wheel_force.x, dtype=float),
        )
        prior2 = self.filter.predict(self._wheel_force, self.wheel_force_model, None, dt, process_noise_sqrt=L2)
        R2 = np.diag(np.sqrt(r2))
        post2, info2 = self.filter.update(prior2, y2, self.wheel_force_model, eps, measurement_noise_sqrt=R2)
        if cfg.noise_matching.enabled and np.isfinite(info2.nis):
            mm2 = self._moments.measurement_moments(prior2, self.wheel_force_model, eps, measurement_noise_sqrt=R2)
            blocks2 = [
                NoiseBlock(name, process_block_part(mm2.P_xz, prior2.P, _block_cov(L2, list(range(3 * g, 3 * g + 3)))))
                for g, name in ((1, "Q W"), (2, "Q DP"))
            ]
            matched = match_noise_scales(s2, blocks2, info2.innovation, info2.innovation_cov, cfg.noise_matching)
            # Two-sided: with γ's increment rotating W and DP (rotated_force_noise_factor) the cells no longer
            # pull γ when the W, DP random walks close (issue 21: before, they were held ≥ their base).
            self._next_scales = (next1, matched)
        return post1, info1, post2, info2, vertical

    def _general_measurement(self, m: _Means, *, pitch_rate: float, bogie_rate: float) -> Array:
        return general_measurement(
            self.config.rover,
            wheel_rates=m.wheel_rates,
            specific_force=m.specific_force,
            bogie_angle=m.bogie_angle,
            forward_speed=m.forward_speed,
            slip_pitch_rate=pitch_rate,
            slip_bogie_rate=bogie_rate,
            absolute_spin=self.config.absolute_spin,
        )

    def _perpendicular(
        self, m: _Means, x1: Array, P1: Array, gamma: Array, gamma_cov: Array
    ) -> tuple[Array, Array | None]:
        """F̌_⊥ and, for Estimator 3, its covariance (eqs. 86–88 propagated); measured for Estimator 2.

        The propagation takes Estimator 1's covariance of M_1fw, F_xfw, θ, q1,
        the load-cell noise and (terrain-frame split) the covariance of γ̌;
        the cross-covariance of γ̌ with θ, q1 is left out.
        """
        cfg = self.config
        if cfg.load_cell_axes == 2:
            return m.perpendicular_force, None
        p = cfg.rover
        terrain = cfg.perpendicular_split == "terrain"
        idx = [_G.BOGIE_MOMENT, _G.FORCE_X, _G.PITCH, _G.BOGIE]
        mean = np.concatenate([x1[idx], m.axial_force, gamma])
        cov = np.zeros((10, 10))
        cov[:4, :4] = P1[np.ix_(idx, idx)]
        cov[4:7, 4:7] = np.diag(cfg.sensor_noise.load_cell**2 / m.cell_n)
        if terrain:
            cov[7:, 7:] = gamma_cov

        def perp_of(v: Array) -> Array:
            e = carrier_angles(p, configuration(v[2], v[3]))
            return synthesised_perpendicular_forces(p, v[4:7], v[0], v[1], e, v[7:10] if terrain else None)

        return perp_of(mean), propagate_covariance(perp_of, mean, cov)

    def _emit(
        self, t: float, *, initialised: bool, nis: tuple[float, float], accepted: bool, consistency: float = 0.0
    ) -> None:
        assert self._general is not None and self._wheel_force is not None
        x1 = np.asarray(self._general.x, dtype=float)
        v1 = np.clip(np.diag(np.asarray(self._general.P, dtype=float)), 0.0, None)
        x2 = np.asarray(self._wheel_force.x, dtype=float)
        v2 = np.clip(np.diag(np.asarray(self._wheel_force.P, dtype=float)), 0.0, None)
        gamma_var, load_var, pull_var = considered_variances(
            v2[0:3], x2[3:6], v2[3:6], x2[6:9], v2[6:9], self.config.contact_angle_bias
        )
        # Eq. 49 leaves out the wheels' inertial coupling to the carrier, I_wg (θ̈ + q̈1) on the bogie wheels
        # and I_wg θ̈ on the front: an error of τ_R that no innovation shows (considered, rover_noise).
        pitch_acc, bogie_acc = float(x1[_G.PITCH_ACC]), float(x1[_G.BOGIE_ACC])
        P1 = np.asarray(self._general.P, dtype=float)
        pa, ba = _G.PITCH_ACC, _G.BOGIE_ACC
        carrier_acc_var = float(P1[pa, pa] + P1[ba, ba] + 2.0 * P1[pa, ba])
        # The coupling's size is a property of the terrain over seconds and its one-step estimate â² − P is
        # mostly noise: â² − P is averaged over _COUPLING_MEMORY steps and floored after averaging (unbiased).
        if not initialised:
            b = 1.0 - 1.0 / _COUPLING_MEMORY
            acc = np.array([pitch_acc + bogie_acc] * 2 + [pitch_acc])
            var = np.array([carrier_acc_var] * 2 + [float(P1[pa, pa])])
            self._coupling_var = b * self._coupling_var + (1.0 - b) * (acc * acc - var)
        coupling = coupling_variance(
            self.config.rover.wheel_gear_inertia, np.sqrt(np.maximum(self._coupling_var, 0.0)), 0.0
        )
        tau_var = smoothed_random_walk_variance(v1[3:6], self._tau_step_var) + coupling
        wheels = tuple(
            WheelTerrainEstimate(
                wheel=name,
                slip=float(x1[19 + j]),
                slip_variance=float(v1[19 + j]),
                normal_load=float(x2[3 + j]),
                normal_load_variance=float(load_var[j]),
                drawbar_pull=float(x2[6 + j]),
                drawbar_pull_variance=float(pull_var[j]),
                resistive_torque=float(x1[3 + j]),
                resistive_torque_variance=float(tau_var[j]),
                contact_angle=float(x2[j]),
                contact_angle_variance=float(gamma_var[j]),
            )
            for j, name in enumerate(WHEELS)
        )
        body = RoverBodyEstimate(
            pitch=float(x1[_G.PITCH]),
            bogie_angle=float(x1[_G.BOGIE]),
            pitch_rate=float(x1[_G.PITCH_RATE]),
            bogie_rate=float(x1[_G.BOGIE_RATE]),
            pitch_acceleration=float(x1[_G.PITCH_ACC]),
            bogie_acceleration=float(x1[_G.BOGIE_ACC]),
            x_acceleration=float(x1[_G.X_ACC]),
            z_acceleration=float(x1[_G.Z_ACC]),
            body_moment=float(x1[_G.BODY_MOMENT]),
            bogie_moment=float(x1[_G.BOGIE_MOMENT]),
            wheel_force_x=float(x1[_G.FORCE_X]),
            wheel_force_z=float(x1[_G.FORCE_Z]),
            forward_speed=float(x1[_G.FORWARD_SPEED]),
            vertical_speed=float(self._vertical[0]),
            vertical_speed_variance=float(self._vertical[1]),
            wheel_rates=(float(x1[0]), float(x1[1]), float(x1[2])),
            variances=tuple(float(v) for v in v1),
        )
        est = RoverEstimate(
            t=t,
            wheels=wheels,
            body=body,
            distance=self._distance,
            estimator=self.config.estimator_number,
            initialised=initialised,
            general_nis=float(nis[0]),
            wheel_force_nis=float(nis[1]),
            accepted=accepted,
            settled=not initialised and is_settled(self._since_start, self.config.settle_steps),
            consistency_nis=float(consistency),
            consistency_dof=sum(len(c) for c in consistency_channels(self.config.load_cell_axes)),
        )
        self._last = est
        self._outbox.append(est)


class _Means:
    """One window's averaged measurements (private)."""

    def __init__(self, w: _Window, wheel_rates: Array, bogie_rate: float, joint_dt: float) -> None:
        self.imu_n = w.imu_n
        self.joint_n = w.joint_n
        self.speed_n = w.speed_n
        self.cell_n = w.cell_n.astype(float)
        self.specific_force = w.specific_force / w.imu_n
        self.pitch_rate = w.pitch_rate / w.imu_n
        self.bogie_angle = w.bogie_sum / w.joint_n
        self.wheel_torque = w.torque_sum / w.joint_n
        self.forward_speed = w.speed_sum / w.speed_n
        self.axial_force = w.axial_sum / self.cell_n
        self.perpendicular_force = w.perpendicular_sum / self.cell_n
        self.wheel_rates = wheel_rates
        self.bogie_rate = bogie_rate
        self.joint_dt = joint_dt


# ---------------------------------------------------------------------------
# Online terrain-response model ([RB] IV-E, IV-F, V-C; MODELS.md C.7)
# ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class TerrainResponseConfig:
    """Configuration of :class:`TerrainResponseAccumulator`.

    Attributes:
        sample_period_s: estimates are averaged to one sample per wheel per
            period (2 s, [RB] V-C).
        order: polynomial order of the fits (2 over the operating range, [RB] IV-E).
        max_samples: bounded window of averaged samples kept for the fit
            (all wheels together; oldest dropped first). 900 = 10 min of
            driving with three wheels.
        min_samples: fewer kept samples → no fit; None = 2 × the number of
            coefficients.
        wheelbase: l_w (m); buckets with curvature κ ≥ 1/l_w are rejected
            ([RB] V-B: 1.43 m⁻¹ for Kapvik).
        curvature_gate: apply that gate (when a curvature is known).
        min_curvature_distance: a bucket's curvature is estimated from its
            contact angles only over at least this much travel (m).
        min_bucket_estimates: a bucket needs this many estimates (5 Hz × 2 s = 10).
        min_forward_speed: buckets slower than this are rejected (m/s): the
            slip of a rover at rest is undefined.
        wheels: wheels whose samples feed the fit (e.g. ("front",) to use the
            front wheel as a "sensing wheel" with single-axis cells, [RB] IV-E).
        weighted: weight each sample by 1/variance of its averaged estimate
            (per quantity); False: equal weights as in the paper.
        history_length: fits kept in :attr:`TerrainResponseAccumulator.history`.
        validation_blocks: the kept samples are cut into at most this many
            contiguous blocks of sample periods; each is left out in turn for
            the held-out prediction error and the jackknife covariance of the
            coefficients (:mod:`~terrain_estimation.models.terrain_response_error`).
        max_jump: a new fit moves the published model by at most this
            Mahalanobis distance in the previous model's stated covariance
            (1: one stated σ, for every coefficient and every (i, W));
            ``math.inf``: publish every fit as it is.
    """

    sample_period_s: float = 2.0
    order: int = 2
    max_samples: int = 900
    min_samples: int | None = None
    wheelbase: float = 0.70
    curvature_gate: bool = True
    min_curvature_distance: float = 0.01
    min_bucket_estimates: int = 5
    min_forward_speed: float = 0.005
    wheels: tuple[str, ...] = WHEELS
    weighted: bool = False
    history_length: int = 50
    validation_blocks: int = 10
    max_jump: float = 1.0

    def __post_init__(self) -> None:
        if not (isinstance(self.validation_blocks, int) and self.validation_blocks >= 2):
            raise ValueError(f"validation_blocks must be an int ≥ 2, got {self.validation_blocks!r}")
        if not (isinstance(self.max_jump, int | float) and self.max_jump > 0.0 and not math.isnan(self.max_jump)):
            raise ValueError(f"max_jump must be > 0 (inf: unbounded), got {self.max_jump!r}")
        for name in ("sample_period_s", "wheelbase", "min_curvature_distance"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if not (math.isfinite(self.min_forward_speed) and self.min_forward_speed >= 0.0):
            raise ValueError(f"min_forward_speed must be finite and ≥ 0, got {self.min_forward_speed!r}")
        if not (isinstance(self.order, int) and 0 <= self.order <= 6):
            raise ValueError(f"order must be an int in 0..6, got {self.order!r}")
        for name in ("max_samples", "min_bucket_estimates", "history_length"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"{name} must be an int ≥ 1, got {value!r}")
        if self.min_samples is not None and not (
            isinstance(self.min_samples, int) and coefficient_count(self.order) <= self.min_samples <= self.max_samples
        ):
            raise ValueError(
                f"min_samples must be None or an int in [{coefficient_count(self.order)}, max_samples], "
                f"got {self.min_samples!r}"
            )
        if not self.wheels or any(w not in WHEELS for w in self.wheels) or len(set(self.wheels)) != len(self.wheels):
            raise ValueError(f"wheels must be distinct names from {WHEELS}, got {self.wheels!r}")

    @property
    def max_curvature(self) -> float:
        """1/l_w (m⁻¹)."""
        return 1.0 / self.wheelbase

    @property
    def required_samples(self) -> int:
        """Kept samples needed for a fit."""
        return self.min_samples if self.min_samples is not None else 2 * coefficient_count(self.order)


@dataclass(frozen=True)
class TerrainResponseFit:
    """Fitted DP(W, i) and τ_R(W, i) (the fields of ``terrain_msgs/TerrainResponseModel``).

    The error figures are those of
    :mod:`~terrain_estimation.models.terrain_response_error`: the stated
    error of the model's value at (i, W) is
    σ(i, W) = √(holdout_rms² + estimate_rms² + xᵀ Σ x), x = the terms i^k W^l.

    Attributes:
        t: time of the newest sample in the fit (s).
        order: polynomial order.
        drawbar_pull: DP model (N), validity = the samples' (i, W) range.
        resistive_torque: τ_R model (N·m).
        samples: number of averaged samples fitted.
        dp_rms, tau_rms: residual RMS of the published models on the fitted samples (N, N·m).
        dp_covariance, tau_covariance: (n, n) covariance Σ of the published coefficients.
        dp_holdout_rms, tau_holdout_rms: RMS error on held-out samples (fits without their block).
        dp_estimate_rms, tau_estimate_rms: √(mean stated variance of the fitted estimates): their shared
            error, which no hold-out sees (0 when the estimates came without variances).
        dp_prediction_rms, tau_prediction_rms: √(mean σ(i, W)²) over the validity rectangle.
        validation_samples: samples predicted by a fit that did not see them.
        dp_jump, tau_jump: Mahalanobis distance of the new least-squares fit
            from the previously published model, in that model's covariance
            (0 for the first model).
        limited: the step was shortened to ``max_jump`` (for DP or τ_R).
    """

    t: float
    order: int
    drawbar_pull: PolynomialModel2D
    resistive_torque: PolynomialModel2D
    samples: int
    dp_rms: float
    tau_rms: float
    dp_covariance: Array = field(default_factory=lambda: np.zeros((0, 0)))
    tau_covariance: Array = field(default_factory=lambda: np.zeros((0, 0)))
    dp_holdout_rms: float = 0.0
    tau_holdout_rms: float = 0.0
    dp_estimate_rms: float = 0.0
    tau_estimate_rms: float = 0.0
    dp_prediction_rms: float = 0.0
    tau_prediction_rms: float = 0.0
    validation_samples: int = 0
    dp_jump: float = 0.0
    tau_jump: float = 0.0
    limited: bool = False

    def dp_std(self, slip: Sequence[float] | Array | float, load: Sequence[float] | Array | float) -> Array:
        """Stated error σ(i, W) of the DP model (N)."""
        base = self.dp_holdout_rms**2 + self.dp_estimate_rms**2
        return np.sqrt(base + model_variance(self.order, self.dp_covariance, slip, load))

    def tau_std(self, slip: Sequence[float] | Array | float, load: Sequence[float] | Array | float) -> Array:
        """Stated error σ(i, W) of the τ_R model (N·m)."""
        base = self.tau_holdout_rms**2 + self.tau_estimate_rms**2
        return np.sqrt(base + model_variance(self.order, self.tau_covariance, slip, load))

    @property
    def validity(self) -> ValidityRegion:
        """(i, W) rectangle of the samples."""
        region = self.drawbar_pull.validity
        assert region is not None
        return region

    @property
    def dp_coefficients(self) -> tuple[float, ...]:
        """DP coefficients, term order :func:`~terrain_estimation.models.terrain_response.polynomial_exponents`."""
        return self.drawbar_pull.coefficients

    @property
    def tau_coefficients(self) -> tuple[float, ...]:
        """τ_R coefficients, same term order."""
        return self.resistive_torque.coefficients

    @property
    def exponents(self) -> tuple[tuple[int, int], ...]:
        """(k, l) of each coefficient's term i^k W^l."""
        return polynomial_exponents(self.order)

    @property
    def slip_min(self) -> float:
        return self.validity.slip_min

    @property
    def slip_max(self) -> float:
        return self.validity.slip_max

    @property
    def load_min(self) -> float:
        return self.validity.load_min

    @property
    def load_max(self) -> float:
        return self.validity.load_max


@dataclass(frozen=True)
class TerrainResponseCounters:
    """What the accumulator did with its buckets."""

    estimates: int = 0
    buckets: int = 0
    buckets_used: int = 0
    rejected_curvature: int = 0
    rejected_speed: int = 0
    rejected_sparse: int = 0
    samples_dropped: int = 0
    fits: int = 0


@dataclass
class _Bucket:
    index: int
    t: list[float] = field(default_factory=list)
    slip: list[Array] = field(default_factory=list)
    load: list[Array] = field(default_factory=list)
    pull: list[Array] = field(default_factory=list)
    torque: list[Array] = field(default_factory=list)
    variances: list[Array] = field(default_factory=list)  # (4, 3): slip, W, DP, τ_R
    gamma: list[Array] = field(default_factory=list)
    distance: list[float] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)
    curvature: list[float] = field(default_factory=list)


class TerrainResponseAccumulator:
    """Online terrain-response model ([RB] IV-E/F, V-C): average, gate, keep a window, fit.

    Feed it the estimator's output (:meth:`add_estimate`, or the lower-level
    :meth:`add`); estimates are grouped in buckets of ``sample_period_s``
    (2 s) on a grid from the first stamp and each closed bucket gives one
    averaged (i, W, DP, τ_R) sample per wheel of ``config.wheels``.
    :meth:`fit` fits the 2nd-order DP(W, i), τ_R(W, i) to the kept samples.

    **Curvature gate** ([RB] V-B: terrain with κ ≥ 1/l_w breaks the ż0^R ≈ 0
    assumption). A bucket is rejected when its curvature is ≥ 1/l_w. The
    curvature is, in this order: the largest ``curvature`` passed with the
    bucket's estimates (e.g. from forward-looking range data, as the paper
    proposes); otherwise estimated from the estimates themselves: the
    contact angle γ_j is the direction of wheel j's path, so its rate of
    change along the travelled distance s = ∫ẋ0^R dt is the path curvature,
    κ_j = |dγ_j/ds|, fitted by least squares over the bucket (≈ 4 cm of travel
    at 2 cm/s, where γ noise of 2e-3 rad gives ≈ 0.1 m⁻¹ of curvature noise
    against the 1.43 m⁻¹ gate); κ = max over the wheels. With too little
    travel (< ``min_curvature_distance``) the curvature is unknown and the
    bucket is not gated on it (it is still gated on ``min_forward_speed``).

    **The model's error** (issue 21; :mod:`~terrain_estimation.models.terrain_response_error`).
    The fit residual (``dp_rms``) understates the model's error 3–4× on the
    Kapvik runs (correlated samples, lack of fit, empty corners of the
    rectangle, biases the samples share). Each fit therefore carries the
    coefficients' covariance (delete-a-block jackknife over
    ``validation_blocks`` contiguous blocks of sample periods), the RMS error
    on held-out samples, and the estimates' own stated error; and a new fit
    moves the published model by at most ``max_jump`` of the previous
    model's stated σ (the step not taken is added to the covariance).

    Args:
        config: settings.
    """

    def __init__(self, config: TerrainResponseConfig | None = None) -> None:
        self.config = config if config is not None else TerrainResponseConfig()
        self._wheel_idx = [WHEELS.index(w) for w in self.config.wheels]
        self.reset()

    def reset(self) -> None:
        """Forget the buckets, samples, history and counters."""
        self._t_origin: float | None = None
        self._t_last: float | None = None
        self._bucket: _Bucket | None = None
        self._samples: deque[tuple[float, float, float, float, float, Array]] = deque(maxlen=self.config.max_samples)
        self._history: deque[TerrainResponseFit] = deque(maxlen=self.config.history_length)
        self._c: dict[str, int] = dict.fromkeys(TerrainResponseCounters.__dataclass_fields__, 0)
        self._last_curvature: float | None = None

    @property
    def counters(self) -> TerrainResponseCounters:
        return TerrainResponseCounters(**self._c)

    @property
    def sample_count(self) -> int:
        """Averaged samples kept for the fit."""
        return len(self._samples)

    @property
    def history(self) -> tuple[TerrainResponseFit, ...]:
        """Past fits, oldest first (a history of coefficients, [RB] IV-F)."""
        return tuple(self._history)

    @property
    def last_curvature(self) -> float | None:
        """Curvature of the last closed bucket (m⁻¹), None if unknown."""
        return self._last_curvature

    def samples(self) -> dict[str, Array]:
        """Kept samples as arrays: ``t``, ``slip``, ``normal_load``, ``drawbar_pull``, ``resistive_torque``.

        Also ``<quantity>_variance``: the mean of the averaged estimates' variances (ones when none were given).
        """
        rows = list(self._samples)
        names = ("t", "slip", "normal_load", "drawbar_pull", "resistive_torque")
        out = {name: np.array([r[k] for r in rows], dtype=float) for k, name in enumerate(names)}
        var = np.array([r[5] for r in rows], dtype=float).reshape(-1, 4)
        for k, name in enumerate(names[1:]):
            out[f"{name}_variance"] = var[:, k]
        return out

    def add_estimate(self, estimate: RoverEstimate, curvature: float | None = None) -> None:
        """Add one estimator output; ``curvature`` (m⁻¹) overrides the γ-based estimate for its bucket."""
        self.add(
            estimate.t,
            slip=estimate.per_wheel("slip"),
            normal_load=estimate.per_wheel("normal_load"),
            drawbar_pull=estimate.per_wheel("drawbar_pull"),
            resistive_torque=estimate.per_wheel("resistive_torque"),
            variances=np.array(
                [
                    estimate.per_wheel("slip_variance"),
                    estimate.per_wheel("normal_load_variance"),
                    estimate.per_wheel("drawbar_pull_variance"),
                    estimate.per_wheel("resistive_torque_variance"),
                ]
            ),
            contact_angle=estimate.per_wheel("contact_angle"),
            distance=estimate.distance,
            forward_speed=estimate.body.forward_speed,
            curvature=curvature,
        )

    def add(
        self,
        t: float,
        *,
        slip: Sequence[float] | Array,
        normal_load: Sequence[float] | Array,
        drawbar_pull: Sequence[float] | Array,
        resistive_torque: Sequence[float] | Array,
        variances: Array | None = None,
        contact_angle: Sequence[float] | Array | None = None,
        distance: float | None = None,
        forward_speed: float | None = None,
        curvature: float | None = None,
    ) -> None:
        """Add one set of per-wheel estimates (WHEELS order) at time ``t``.

        Args:
            t: stamp (s), increasing.
            slip, normal_load, drawbar_pull, resistive_torque: (3,) each.
            variances: (4, 3) variances of slip, W, DP, τ_R (for ``weighted``).
            contact_angle: γ (3,) (rad) and ``distance`` travelled (m): for
                the curvature estimate.
            forward_speed: (m/s), for the speed gate (None: not gated).
            curvature: known curvature (m⁻¹) at this estimate.

        Raises:
            ValueError: non-finite or mis-sized values, or a stamp not after the previous one.
        """
        where = "TerrainResponseAccumulator.add"
        tt = _finite(where, "t", t)
        if self._t_last is not None and tt <= self._t_last:
            raise ValueError(f"{where}: t = {t!r} is not after the previous stamp {self._t_last!r}")
        values = [_three(where, n, v) for n, v in (("slip", slip), ("normal_load", normal_load))]
        values += [
            _three(where, n, v) for n, v in (("drawbar_pull", drawbar_pull), ("resistive_torque", resistive_torque))
        ]
        var = None
        if variances is not None:
            var = np.asarray(variances, dtype=float)
            if var.shape != (4, 3) or not np.isfinite(var).all():
                raise ValueError(f"{where}: variances must be finite with shape (4, 3), got {variances!r}")
        gamma = None if contact_angle is None else _three(where, "contact_angle", contact_angle)
        dist = None if distance is None else _finite(where, "distance", distance)
        speed = None if forward_speed is None else _finite(where, "forward_speed", forward_speed)
        kappa = None if curvature is None else abs(_finite(where, "curvature", curvature))
        self._t_last = tt
        self._c["estimates"] += 1
        if self._t_origin is None:
            self._t_origin = tt
        index = math.floor((tt - self._t_origin) / self.config.sample_period_s + 1e-9)
        if self._bucket is not None and index != self._bucket.index:
            self._close_bucket()
        if self._bucket is None:
            self._bucket = _Bucket(index)
        b = self._bucket
        b.t.append(tt)
        b.slip.append(values[0])
        b.load.append(values[1])
        b.pull.append(values[2])
        b.torque.append(values[3])
        if var is not None:
            b.variances.append(var)
        if gamma is not None and dist is not None:
            b.gamma.append(gamma)
            b.distance.append(dist)
        if speed is not None:
            b.speed.append(speed)
        if kappa is not None:
            b.curvature.append(kappa)

    def flush(self) -> None:
        """Close the open bucket now (e.g. before fitting when the rover stops)."""
        if self._bucket is not None:
            self._close_bucket()

    def start_segment(self) -> None:
        """Close the open bucket and restart the time base, keeping the samples.

        For a new log (e.g. another traverse replayed offline) whose stamps
        start again from an earlier time.
        """
        self.flush()
        self._t_origin = None
        self._t_last = None

    def bucket_curvature(self, gamma: Array, distance: Array) -> float | None:
        """max_j |dγ_j/ds| by least squares over a bucket (m⁻¹); None with too little travel."""
        s = np.asarray(distance, dtype=float)
        if s.size < 3 or float(s.max() - s.min()) < self.config.min_curvature_distance:
            return None
        ds = s - s.mean()
        g = np.asarray(gamma, dtype=float)
        slopes = (ds @ (g - g.mean(axis=0))) / float(ds @ ds)
        return float(np.max(np.abs(slopes)))

    def _close_bucket(self) -> None:
        b = self._bucket
        self._bucket = None
        assert b is not None
        cfg = self.config
        self._c["buckets"] += 1
        if len(b.t) < cfg.min_bucket_estimates:
            self._c["rejected_sparse"] += 1
            return
        if b.curvature:
            kappa: float | None = max(b.curvature)
        elif len(b.gamma) == len(b.t):
            kappa = self.bucket_curvature(np.array(b.gamma), np.array(b.distance))
        else:
            kappa = None
        self._last_curvature = kappa
        if b.speed and float(np.mean(b.speed)) < cfg.min_forward_speed:
            self._c["rejected_speed"] += 1
            return
        if cfg.curvature_gate and kappa is not None and kappa >= cfg.max_curvature:
            self._c["rejected_curvature"] += 1
            return
        self._c["buckets_used"] += 1
        t_mean = float(np.mean(b.t))
        n = len(b.t)
        mean = [np.mean(np.array(q), axis=0) for q in (b.slip, b.load, b.pull, b.torque)]
        # Variance of a mean of n correlated filter outputs: at most the mean variance
        # (fully correlated); used only as a relative weight.
        # NaN: no variances came with the estimates (weights then equal, no estimate error stated).
        var = np.mean(np.array(b.variances), axis=0) if len(b.variances) == n else np.full((4, 3), np.nan)
        for j in self._wheel_idx:
            if len(self._samples) == self._samples.maxlen:
                self._c["samples_dropped"] += 1
            self._samples.append(
                (t_mean, float(mean[0][j]), float(mean[1][j]), float(mean[2][j]), float(mean[3][j]), var[:, j].copy())
            )

    def fit(self) -> TerrainResponseFit | None:
        """2nd-order (``config.order``) fits of DP(W, i) and τ_R(W, i) to the kept samples, with their error.

        Each fit comes with its coefficient covariance (block jackknife) and
        held-out error (:func:`~terrain_estimation.models.terrain_response_error.validated_fit`,
        blocks of whole sample periods), and moves the previously published
        model by at most ``config.max_jump`` of its stated σ
        (:func:`~terrain_estimation.models.terrain_response_error.bounded_update`).

        Returns None with fewer than ``config.required_samples`` samples or a
        rank-deficient design (e.g. all samples at one slip); a fit is also
        appended to :attr:`history`.
        """
        cfg = self.config
        if len(self._samples) < cfg.required_samples:
            return None
        rows = list(self._samples)
        stamps = np.array([r[0] for r in rows])
        slip = np.array([r[1] for r in rows])
        load = np.array([r[2] for r in rows])
        pull = np.array([r[3] for r in rows])
        torque = np.array([r[4] for r in rows])
        var = np.array([r[5] for r in rows])
        weights = np.nan_to_num(var, nan=1.0)
        w_dp = 1.0 / np.maximum(weights[:, 2], 1e-12) if cfg.weighted else None
        w_tau = 1.0 / np.maximum(weights[:, 3], 1e-12) if cfg.weighted else None
        blocks = cfg.validation_blocks
        try:
            # Errors in the variables: a sample sits at the estimated (i, W), so the errors of slip and load
            # reach the model through its slopes (τ_R and DP are steep in slip); the stated error uses
            # var_y + (∂y/∂i)² var_i + (∂y/∂W)² var_W, the slopes those of the plain least-squares fit (the
            # validated fit's coefficients are the same, issue 21).
            dp_slopes = fit_polynomial_2d(slip, load, pull, cfg.order, w_dp).model
            tau_slopes = fit_polynomial_2d(slip, load, torque, cfg.order, w_tau).model
            dp = validated_fit(
                slip,
                load,
                pull,
                cfg.order,
                groups=stamps,
                weights=w_dp,
                max_blocks=blocks,
                sample_variances=_in_variables(dp_slopes, slip, load, var[:, 2], var[:, 0], var[:, 1]),
            )
            tau = validated_fit(
                slip,
                load,
                torque,
                cfg.order,
                groups=stamps,
                weights=w_tau,
                max_blocks=blocks,
                sample_variances=_in_variables(tau_slopes, slip, load, var[:, 3], var[:, 0], var[:, 1]),
            )
        except ValueError:
            return None
        previous = self._history[-1] if self._history else None
        published = []
        for new, old_model, old_cov, weight, values in (
            (
                dp,
                None if previous is None else previous.drawbar_pull,
                None if previous is None else previous.dp_covariance,
                w_dp,
                pull,
            ),
            (
                tau,
                None if previous is None else previous.resistive_torque,
                None if previous is None else previous.tau_covariance,
                w_tau,
                torque,
            ),
        ):
            known = old_model is not None and old_cov is not None and old_cov.size > 0
            step = bounded_update(
                old_model.coefficients if known and old_model is not None else None,
                old_cov if known else None,
                new.model.coefficients,
                new.covariance,
                cfg.max_jump,
            )
            model = PolynomialModel2D(
                order=cfg.order, coefficients=tuple(step.coefficients), validity=new.model.validity
            )
            published.append((new, step, model, model.residual_rms(slip, load, values, weight)))
        (dp_fit, dp_step, dp_model, dp_rms), (tau_fit, tau_step, tau_model, tau_rms) = published
        result = TerrainResponseFit(
            t=float(stamps.max()),
            order=cfg.order,
            drawbar_pull=dp_model,
            resistive_torque=tau_model,
            samples=len(rows),
            dp_rms=dp_rms,
            tau_rms=tau_rms,
            dp_covariance=dp_step.covariance,
            tau_covariance=tau_step.covariance,
            dp_holdout_rms=dp_fit.holdout_rms,
            tau_holdout_rms=tau_fit.holdout_rms,
            dp_estimate_rms=dp_fit.estimate_rms,
            tau_estimate_rms=tau_fit.estimate_rms,
            dp_prediction_rms=_prediction_rms(dp_fit, dp_step.covariance),
            tau_prediction_rms=_prediction_rms(tau_fit, tau_step.covariance),
            validation_samples=min(dp_fit.validation_samples, tau_fit.validation_samples),
            dp_jump=dp_step.distance,
            tau_jump=tau_step.distance,
            limited=dp_step.limited or tau_step.limited,
        )
        self._c["fits"] += 1
        self._history.append(result)
        return result


def _in_variables(
    model: PolynomialModel2D, slip: Array, load: Array, var_y: Array, var_slip: Array, var_load: Array
) -> Array:
    """var_y + (∂y/∂i)² var_i + (∂y/∂W)² var_W at each sample (central differences of ``model``); NaN stays NaN."""
    di, dw = 1e-4, 1e-2
    d_slip = (model.evaluate(slip + di, load) - model.evaluate(slip - di, load)) / (2.0 * di)
    d_load = (model.evaluate(slip, load + dw) - model.evaluate(slip, load - dw)) / (2.0 * dw)
    out: Array = var_y + d_slip * d_slip * var_slip + d_load * d_load * var_load
    return out


def _prediction_rms(fit: ValidatedFit, covariance: Array) -> float:
    """√(holdout² + estimate² + mean xᵀΣx) over the fit's validity rectangle, with the published covariance."""
    region = fit.model.validity
    assert region is not None
    base = fit.holdout_rms**2 + fit.estimate_rms**2
    return math.sqrt(base + region_mean_variance(fit.model.order, covariance, region))
