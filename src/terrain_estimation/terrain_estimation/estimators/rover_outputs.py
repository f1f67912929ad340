"""What the rover's terrain-response estimator publishes: per-wheel and body estimates, health counters.

:class:`RoverEstimate` (one step: :class:`WheelTerrainEstimate` per wheel and
Estimator 1's :class:`RoverBodyEstimate`) and the health counters of the
estimator (:class:`RoverCounters`) and of the terrain-response accumulator
(:class:`TerrainResponseCounters`); re-exported by
:mod:`terrain_estimation.estimators.rover`.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from terrain_estimation.filters.base import Array
from terrain_estimation.models.rover import WHEELS
from terrain_estimation.models.rover_estimator_states import GENERAL_STATES

__all__ = [
    "RoverBodyEstimate",
    "RoverCounters",
    "RoverEstimate",
    "TerrainResponseCounters",
    "WheelTerrainEstimate",
]


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

    @classmethod
    def from_state(cls, x1: Array, variances: Array, vertical: tuple[float, float]) -> RoverBodyEstimate:
        """The body states of Estimator 1's state ``x1`` (the fields named as in :data:`GENERAL_STATES`).

        ``variances``: the 22 posterior variances; ``vertical``: ż0^R and its variance.
        """
        named: dict[str, Any] = {
            f.name: float(x1[GENERAL_STATES.index(f.name)]) for f in fields(cls) if f.name in GENERAL_STATES
        }
        return cls(
            **named,
            vertical_speed=float(vertical[0]),
            vertical_speed_variance=float(vertical[1]),
            wheel_rates=(float(x1[0]), float(x1[1]), float(x1[2])),
            variances=tuple(float(v) for v in variances),
        )


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
            test (slips, load cells, the side's force balance;
            :mod:`~terrain_estimation.estimators.rover_diagnostics`), 0 at
            initialisation.
        consistency_dof: its degrees of freedom (11 two-axis: 9 channels and the force balance; 6 single-axis).
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
    beyond_curvature_validity: int = 0  # settled-or-not estimates over a span bent ≥ 1/l_w ([RB] V-B)


@dataclass(frozen=True)
class TerrainResponseCounters:
    """What :class:`~terrain_estimation.estimators.rover_response.TerrainResponseAccumulator` did with its buckets."""

    estimates: int = 0
    buckets: int = 0
    buckets_used: int = 0
    rejected_curvature: int = 0
    rejected_speed: int = 0
    rejected_sparse: int = 0
    samples_dropped: int = 0
    fits: int = 0
