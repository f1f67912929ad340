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
  slip R and Estimator 2/3's Q of W and DP (rotated with γ, per wheel) matched to the innovations
  (``noise_matching``), the coloured contact-angle error and eq. 49's
  neglected wheel coupling considered in the published variances
  (``contact_angle_bias``: a prior σ_b raised to the repeat-pass measure; as an
  option the parabola's error on the path the wheels traced, with
  ``counters.beyond_curvature_validity`` where it bends ≥ 1/l_w), τ_R
  published for the window just observed plus its swing inside the window, Estimator 3's split of F_⊥12 sized by the
  slips (``split_traction_slope``), and
  ``settled`` False for the first ``settle_steps`` updates after a start.
  Each estimate carries ``consistency_nis`` for ``/diagnostics``: the slips,
  the load cells and, with two-axis cells, the side's force balance through
  the three cells, the one test a cell offset cannot hide from by moving W and
  DP (:mod:`~terrain_estimation.estimators.rover_diagnostics`).

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
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from terrain_estimation.estimators.rover_config import RoverEstimatorConfig
from terrain_estimation.estimators.rover_diagnostics import (
    ForceBalance,
    consistency_channels,
    consistency_dof,
    subset_nis,
)
from terrain_estimation.estimators.rover_noise import (
    NoiseBlock,
    RepeatPassError,
    block_part,
    considered_variances,
    coupling_variance,
    is_settled,
    match_noise_scales,
    process_block_part,
    rotated_force_noise_factor,
    smoothed_random_walk_variance,
    split_considered,
    statistical_linearisation,
)
from terrain_estimation.estimators.rover_outputs import (
    RoverBodyEstimate,
    RoverCounters,
    RoverEstimate,
    TerrainResponseCounters,
    WheelTerrainEstimate,
)
from terrain_estimation.estimators.rover_path_error import PathQuadratureError, sinkage_tilt_variance
from terrain_estimation.estimators.rover_perpendicular import perpendicular_measurement
from terrain_estimation.estimators.rover_response import (
    TerrainResponseAccumulator,
    TerrainResponseConfig,
    TerrainResponseFit,
)
from terrain_estimation.estimators.rover_windows import SensorWindows, WindowMeans
from terrain_estimation.filters.base import Array, GaussianState, UpdateInfo
from terrain_estimation.filters.faults import DivergenceCheck, DivergenceMonitor
from terrain_estimation.filters.ukf import MeasurementMoments, UnscentedKalmanFilter
from terrain_estimation.models.rover import WHEELS, carrier_angles, wheel_centres
from terrain_estimation.models.rover_estimators import (
    GeneralEstimatorModel,
    GeneralIndex,
    GeneralInput,
    WheelForceModel,
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
    wheel_force_measurement_variances,
)
from terrain_estimation.models.rover_sinkage import SinkageTracker

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

_RATE_IDX: list[int] = list(range(0, 3))
_TAU_IDX: list[int] = list(range(3, 6))


#: Memory (steps) of the averaged inertial-coupling variance of τ_R: 5 s at 5 Hz.
_COUPLING_MEMORY = 25.0
#: Estimator 1's kinematic and net-force walks (θ̇, q̇1, the four accelerations, the four net forces, ẋ^R) and
#: their σ factor while settling: the walks of before issue 21, item 2, ten times the change per step.
_SETTLE_IDX: list[int] = [_G.PITCH_RATE, _G.BOGIE_RATE, *_G.FREE_ACC, *_G.FREE_FORCE, _G.FORWARD_SPEED]
_SETTLE_BOOST = 10.0
#: Matched scales of Estimator 2/3's Q: W and DP of each wheel (rover_noise, "Noise blocks").
_WHEEL_FORCE_BLOCKS = 6


def _block_cov(L: Array, columns: list[int]) -> Array:
    """Q_g = L_g L_gᵀ of the columns ``columns`` of a factor L of Q."""
    Lg = L[:, columns]
    return np.asarray(Lg @ Lg.T, dtype=float)


def _finite_state(state: GaussianState) -> bool:
    return bool(np.isfinite(state.x).all() and np.isfinite(state.P).all())


# ---------------------------------------------------------------------------
# The estimator
# ---------------------------------------------------------------------------


class RoverTerrainEstimator(SensorWindows):
    """Per-wheel slip, W, DP, τ_R and contact angle of the rocker-bogie rover (module docstring).

    The sensor inputs (``add_imu``, ``add_joint_state``, ``add_velocimeter``,
    ``add_load_cell(s)``, ``flush``) and their windows are those of
    :class:`~terrain_estimation.estimators.rover_windows.SensorWindows`; this
    class runs Estimators 1 and 2|3 on each complete window (:meth:`_step`).

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
        self._sinkage = SinkageTracker(cfg.sinkage, cfg.rover.wheel_radius, cfg.rover.wheel_width)
        self._balance = ForceBalance(cfg.rover.total_mass, cfg.rover.gravity)
        # Estimator 3's F̌_⊥ floor covers eq. 88's load-proportional split; the terrain-frame split's error is
        # modelled (rover_noise.split_covariance) and the floor is not added to it.
        self._floors2 = (
            cfg.floors if cfg.perpendicular_split == "load_cell" else replace(cfg.floors, synthesised_force=0.0)
        )
        self.reset()

    # -- public API -----------------------------------------------------------------
    def reset(self) -> None:
        """Forget the filters, the windows, the outbox and the counters."""
        self._general: GaussianState | None = None
        self._wheel_force: GaussianState | None = None
        self._reset_windows()
        self._t_step: float | None = None
        self._distance = 0.0
        self._failures = 0
        self._vertical = (0.0, 0.0)
        self._sinkage.reset()
        self._balance.reset()
        self._balance_step: tuple[float, Array | None, Array] = (0.0, None, np.zeros((2, 2)))
        self._since_start = 0
        self._scales1 = np.ones(2)  # Q wheel rates, R slips
        # Q of W and of DP per wheel (rear, middle, front; rotated with γ, rover_noise.rotated_force_noise_factor)
        self._scales2 = np.ones(_WHEEL_FORCE_BLOCKS)
        self._next_scales = (self._scales1, self._scales2)
        self._tau_step_var = np.zeros(3)  # Q of τ_R over the last step
        self._coupling_var = np.zeros(3)  # averaged considered coupling variance of τ_R (rover_noise)
        self._swing_var = np.zeros(3)  # averaged within-window swing of τ_R at the stamp (rover_noise)
        self._split_var = np.zeros(3)  # Estimator 3's split error of F̌_⊥ this step (rover_noise.split_covariance)
        self._next_swing = np.zeros(3)
        self._repeat_pass = RepeatPassError(self.config.contact_angle_bias.memory_steps)
        self._path_error = PathQuadratureError(
            self.config.contact_angle_bias.memory_steps, self.config.rover.wheel_radius
        )
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

    # -- one step -------------------------------------------------------------------------
    def _step(self, t: float, m: WindowMeans) -> None:
        cfg = self.config
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
        if self.config.load_cell_axes == 2:
            balance_nis, bias, bias_cov = self._balance_step
            self._balance.commit(bias, bias_cov)
            consistency += balance_nis
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
        self._scales2 = np.ones(_WHEEL_FORCE_BLOCKS)
        self._tau_step_var = np.zeros(3)
        self._path_error.reset()  # traced by the estimates that diverged
        if failure is None:
            self._failures = 0
        self._vertical = vertical if not check1.diverged and vertical is not None else (0.0, 0.0)
        self._distance += dt * 0.5 * (float(self._general.x[_G.FORWARD_SPEED]) + float(state1.x[_G.FORWARD_SPEED]))
        self._general, self._wheel_force = state1, state2
        self._t_step = t
        self._emit(t, initialised=True, nis=(0.0, 0.0), accepted=False)

    def _initialise(self, t: float, m: WindowMeans, *, restart: bool) -> None:
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
        self._balance.reset()
        self._repeat_pass.reset()
        self._path_error.reset()
        self._failures = 0
        self._since_start = 0
        self._scales1 = np.ones(2)
        self._scales2 = np.ones(_WHEEL_FORCE_BLOCKS)
        self._tau_step_var = np.zeros(3)
        self._c["restarts" if restart else "initialisations"] += 1
        self._t_step = t
        self._emit(t, initialised=True, nis=(0.0, 0.0), accepted=False)

    def _filter_step(
        self, dt: float, m: WindowMeans
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
        if self._since_start < cfg.settle_steps:
            # Settling after a (re)start: the state is a guess whose error moves far more per step than the
            # terrain's motion the kinematic walks are sized to (rover_noise, "Settling").
            q1_sigma[_SETTLE_IDX] *= _SETTLE_BOOST
        L1 = self.general_model.process_noise_factor(q1_sigma, dt)
        self._next_tau_step_var = np.square(q1_sigma[_TAU_IDX]) * (dt / cfg.step_s)
        self._next_swing = np.square(m.wheel_torque_at_stamp - m.wheel_torque)
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

        post1, info1, moments1 = self._update(prior1, y1, self.general_model, None, np.diag(np.sqrt(r1)))
        next1 = s1
        if cfg.noise_matching.enabled and np.isfinite(info1.nis):
            mm = moments1()
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
        if cfg.load_cell_axes == 2:
            # The side's force balance through the cells (rover_diagnostics.ForceBalance): a cell fault's test.
            bal_idx = [_G.PITCH, _G.BOGIE, _G.X_ACC, _G.Z_ACC]
            cell_var = (cfg.sensor_noise.load_cell**2 + cfg.floors.load_cell**2) / m.cell_n
            r, R = self._balance.residual(
                m.axial_force, m.perpendicular_force, cell_var, x1[bal_idx], P1[np.ix_(bal_idx, bal_idx)]
            )
            self._balance_step = self._balance.step(r, R)
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
        # The τ_R increments of this step (and, quasi-static, the net forces they move) reach the measurements only
        # at the next step (rover_noise.smoothed_random_walk_variance): F̌_⊥ of this window is without them.
        perp, perp_cov = self._perpendicular(m, x1, P1 - _block_cov(L1, _TAU_IDX), gamma, gamma_cov)
        y2 = np.concatenate([gamma, m.axial_force, perp])
        if cfg.wheel_force_r_diag is not None:
            r2 = np.array(cfg.wheel_force_r_diag, dtype=float)
        else:
            r2 = wheel_force_measurement_variances(
                contact_angle_cov=gamma_cov,
                noise=cfg.sensor_noise,
                floors=self._floors2,
                load_cell_samples=m.cell_n,
                synthesised_cov=perp_cov,
            )
        L2 = rotated_force_noise_factor(
            self._q2_sigma * scale * np.sqrt(np.concatenate([np.ones(3), s2])),
            np.asarray(self._wheel_force.x, dtype=float),
        )
        prior2 = self.filter.predict(self._wheel_force, self.wheel_force_model, None, dt, process_noise_sqrt=L2)
        R2 = np.diag(np.sqrt(r2))
        post2, info2, moments2 = self._update(prior2, y2, self.wheel_force_model, eps, R2)
        if cfg.noise_matching.enabled and np.isfinite(info2.nis):
            mm2 = moments2()
            Ht2 = statistical_linearisation(mm2.P_xz, prior2.P)  # the same for every block
            blocks2 = [
                NoiseBlock(f"Q {name} {wheel}", block_part(Ht2, _block_cov(L2, [3 * g + j])))
                for g, name in ((1, "W"), (2, "DP"))
                for j, wheel in enumerate(WHEELS)
            ]
            matched = match_noise_scales(s2, blocks2, info2.innovation, info2.innovation_cov, cfg.noise_matching)
            # Two-sided: with γ's increment rotating W and DP (rotated_force_noise_factor) the cells no longer
            # pull γ when the W, DP random walks close (issue 21: before, they were held ≥ their base).
            self._next_scales = (next1, matched)
        return post1, info1, post2, info2, vertical

    def _update(
        self, prior: GaussianState, z: Array, model: Any, u: Any, noise_sqrt: Array
    ) -> tuple[GaussianState, UpdateInfo, Callable[[], MeasurementMoments]]:
        """The step filter's update, and the noise matching's moments at ``prior`` (plain UKF, ``self._moments``).

        When the step's filter is that very UKF (not wrapped: the default), the moments are those its update
        was made with (the same points and numbers, drawn once); otherwise they are drawn on demand.
        """
        flt = self.filter
        if type(flt) is UnscentedKalmanFilter and flt == self._moments:
            post, info, mm = flt.update_with_moments(prior, z, model, u, measurement_noise_sqrt=noise_sqrt)
            return post, info, lambda: mm
        post, info = flt.update(prior, z, model, u, measurement_noise_sqrt=noise_sqrt)
        return (
            post,
            info,
            lambda: self._moments.measurement_moments(prior, model, u, measurement_noise_sqrt=noise_sqrt),
        )

    def _general_measurement(self, m: WindowMeans, *, pitch_rate: float, bogie_rate: float) -> Array:
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
        self, m: WindowMeans, x1: Array, P1: Array, gamma: Array, gamma_cov: Array
    ) -> tuple[Array, Array | None]:
        """F̌_⊥ and, for Estimator 3, its covariance (:func:`~.rover_perpendicular.perpendicular_measurement`)."""
        perp, cov, split_var = perpendicular_measurement(self.config, m, x1, P1, gamma, gamma_cov)
        if split_var is not None:
            self._split_var = split_var
        return perp, cov

    def _emit(
        self, t: float, *, initialised: bool, nis: tuple[float, float], accepted: bool, consistency: float = 0.0
    ) -> None:
        assert self._general is not None and self._wheel_force is not None
        x1 = np.asarray(self._general.x, dtype=float)
        v1 = np.clip(np.diag(np.asarray(self._general.P, dtype=float)), 0.0, None)
        x2 = np.asarray(self._wheel_force.x, dtype=float)
        v2 = np.clip(np.diag(np.asarray(self._wheel_force.P, dtype=float)), 0.0, None)
        bias = self.config.contact_angle_bias
        pitch, bogie = float(x1[_G.PITCH]), float(x1[_G.BOGIE])
        model_var = 0.0
        if not initialised:
            centres = wheel_centres(self.config.rover, configuration(pitch, bogie))
            self._repeat_pass.update(self._distance, x2[0:3], v2[0:3], np.diff(centres[:, 0]))
            if bias.enabled and (bias.path_error or bias.sinkage_relative_error > 0.0):
                # The parabola's error on the path the wheels traced, and the sinkage model's tilt
                # (rover_path_error); a (re)start's estimate carries its start covariance instead, and the traced
                # profile starts again.
                weights = path_tangent_angles(self.config.rover, pitch, bogie)[1]
                if bias.path_error:
                    if is_settled(self._since_start, self.config.settle_steps):
                        # Settled estimates only: a start's transient is no slope profile.
                        self._path_error.update(self._distance, x2[0:3], v2[0:3], centres[:, 0], weights)
                        self._c["beyond_curvature_validity"] += int(self._path_error.beyond_validity)
                    model_var += self._path_error.variance
                sink = self._sinkage.sinkage if self.config.sinkage.enabled else None
                if sink is not None and bias.sinkage_relative_error > 0.0:
                    model_var += sinkage_tilt_variance(centres[:, 0], sink, weights, bias.sinkage_relative_error)
        gamma_var, load_var, pull_var = considered_variances(
            v2[0:3], x2[3:6], v2[3:6], x2[6:9], v2[6:9], bias, self._repeat_pass.variance, model_var
        )
        if self.config.load_cell_axes == 1:
            # The split error of F̌_⊥ is as slow as the terrain: the filter averages it as if white; considered.
            eps = carrier_angles(self.config.rover, configuration(pitch, bogie))
            load_var, pull_var = split_considered(load_var, pull_var, x2[0:3] - eps, self._split_var)
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
            self._swing_var = b * self._swing_var + (1.0 - b) * self._next_swing
        coupling = coupling_variance(
            self.config.rover.wheel_gear_inertia, np.sqrt(np.maximum(self._coupling_var, 0.0)), 0.0
        )
        tau_var = smoothed_random_walk_variance(v1[3:6], self._tau_step_var) + coupling + self._swing_var
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
        body = RoverBodyEstimate.from_state(x1, v1, self._vertical)
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
            consistency_dof=consistency_dof(self.config.load_cell_axes),
        )
        self._last = est
        self._outbox.append(est)
