"""IMU-driven kinematic skid-steer model with the tire forces as pseudo-measurements (issue 20 item 3).

The brush observer (MODELS.md B.6–B.7) puts its tire model in the process
*and* in the measurement, so the velocity it estimates is whatever the tire
model says: a tire-law, μ or C_α error becomes a bias of ``v_y`` that its
covariance does not show (MODELS.md B.12). Here the process is the rigid-body
kinematics driven by the measured specific force and the gyro, which hold on
any terrain; the tire model only enters as a pseudo-measurement whose
variance states how far it is trusted::

    process (the IMU sample before the step, a_x, a_y in m/s²; body rotating at r):
        [vx, vy] ← Rot(−r Δt) [vx, vy] + Δt [a_x, a_y]     (v̇x = a_x + r v_y, v̇y = a_y − r v_x)
        r        ← r (random walk, q0_diag[2] per q_step_dt: the gyro drives it through the update)
        ln s     ← ln s (random walk, when scale states are on)
    pseudo-measurements (the IMU sample at the step's end):
        [a_x, a_y, r_gyro] = [ΣF_x(x)/m, ΣF_y(x)/m, r] + v,
        R = diag(σ_a² + σ_tire², σ_a² + σ_tire², σ_gyro²)
    with scale states (``yaw_moment``), a fourth:
        0 = M_z(x)/I_z − ṙ_gyro + v₄,   R₄ = 2 σ_gyro²/Δt² + σ_moment²

with ``σ_a²`` the accelerometer entries of ``r0_diag``, ``σ_tire`` (m/s²)
the tire model's force error per unit mass, ``ṙ_gyro = (r_k − r_{k−1})/Δt``
the differenced gyro (its noise ``√2 σ_gyro/Δt`` at the nominal step
``q_step_dt``) and ``σ_moment`` (rad/s²) the tire model's yaw-moment error
per unit inertia. The yaw-moment pseudo-measurement carries what the brush
observer learns from its ``r`` dynamics: the lateral forces of the front and
rear axles enter ``M_z`` with opposite arms, so together with ``ΣF_y`` it
separates ``v_y`` from a cornering-stiffness scale (without it a scale state
is not observable in this model). Without scale states it is left out by
default: it adds little to the motion states (on the simulator) and, where
the brush law describes the vehicle badly (a Husky on sand), it pulls them
towards the model's yaw balance. The process noise on
``vx, vy`` is the accelerometer's error integrated over the step,
``(σ_proc Δt)²`` with ``σ_proc`` (m/s²) the noise, vibration and gravity
leakage through unmodelled roll/pitch the integration takes in.

The step uses the previous IMU sample in the process and the current one in
the pseudo-measurement, so the two noises are independent. The exact
rotation (not Euler) keeps ``|v|`` unchanged by ``r`` for any step length.
No Euler sub-steps are needed: the process is not stiff (the tire model's
stiffness only weighs the update), which also makes this model's step cost
independent of the rolling speed.

Optional tire-parameter scale states (:class:`~terrain_estimation.models.skid_steer_scales.TireScaleConfig`)
enter the pseudo-measurement as in the brush-scale model.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from terrain_estimation.checks import check_fields, check_non_negative, check_positive
from terrain_estimation.filters.base import Array
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.models.skid_steer_observer import DEFAULT_Q0_DIAG, DEFAULT_R0_DIAG, SkidSteerInput
from terrain_estimation.models.skid_steer_scales import TireScaleConfig, _ScaledModelBase

__all__ = [
    "KinematicInput",
    "SkidSteerKinematicModel",
    "DEFAULT_PROCESS_ACCEL_STD",
    "DEFAULT_TIRE_MODEL_STD",
    "DEFAULT_TIRE_MOMENT_STD",
]

#: σ_proc (m/s²): accelerometer noise, vibration and gravity leakage the integration takes in.
DEFAULT_PROCESS_ACCEL_STD = 0.3
#: σ_tire (m/s²): error of the brush model's force per unit mass (≈ 5 % of μ g at μ = 0.8).
DEFAULT_TIRE_MODEL_STD = 0.4
#: σ_moment (rad/s²): error of the brush model's yaw moment per unit yaw inertia.
DEFAULT_TIRE_MOMENT_STD = 0.3


@dataclass(frozen=True)
class KinematicInput:
    """Input of one kinematic step.

    Attributes:
        wheels: wheel speeds, load accelerations and μ for the tire pseudo-measurement.
        ax, ay: specific force that drives the step (m/s², the IMU sample before it).
        yaw_acceleration: ``ṙ_gyro``, the differenced gyro over the step (rad/s²).
    """

    wheels: SkidSteerInput
    ax: float
    ay: float
    yaw_acceleration: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.wheels, SkidSteerInput):
            raise ValueError(f"KinematicInput.wheels must be a SkidSteerInput, got {type(self.wheels).__name__}")
        check_fields(self, ("ax", "ay", "yaw_acceleration"), rule="finite")


class SkidSteerKinematicModel(_ScaledModelBase):
    """IMU-driven kinematics, tire forces as pseudo-measurements (module docstring).

    State ``[vx, vy, r, ln s…]``; input :class:`KinematicInput`; measurement
    ``[a_x, a_y, r]``, with ``yaw_moment`` ``[a_x, a_y, r, 0]`` (the last: the
    yaw-moment pseudo-measurement).

    Args:
        params: vehicle.
        scales: tire-parameter scale states (default none).
        q0_diag: base process noise per ``q_step_dt``; only its yaw-rate entry
            is used (the r random walk, (rad/s)²).
        r0_diag: sensor noise of ``[a_x, a_y, r]`` ((m/s²)², (m/s²)², (rad/s)²).
        q_step_dt: step length ``q0_diag`` refers to (s).
        process_accel_std: σ_proc (m/s², > 0).
        tire_model_std: σ_tire (m/s², ≥ 0).
        tire_moment_std: σ_moment (rad/s², ≥ 0).
        yaw_moment: use the yaw-moment pseudo-measurement; None (default): with
            scale states only.

    Raises:
        ValueError: on invalid arguments.
    """

    def __init__(
        self,
        params: SkidSteerParams | None = None,
        scales: TireScaleConfig | None = None,
        *,
        q0_diag: Sequence[float] = DEFAULT_Q0_DIAG,
        r0_diag: Sequence[float] = DEFAULT_R0_DIAG,
        q_step_dt: float = 0.01,
        process_accel_std: float = DEFAULT_PROCESS_ACCEL_STD,
        tire_model_std: float = DEFAULT_TIRE_MODEL_STD,
        tire_moment_std: float = DEFAULT_TIRE_MOMENT_STD,
        yaw_moment: bool | None = None,
    ) -> None:
        super().__init__(
            params,
            scales if scales is not None else TireScaleConfig(states=()),
            q0_diag=q0_diag,
            r0_diag=r0_diag,
            q_step_dt=q_step_dt,
            substeps=1,
            max_euler_gain=None,
            max_substeps=1,
        )
        owner = type(self).__name__
        check_positive(owner, "process_accel_std", process_accel_std)
        check_non_negative(owner, "tire_model_std", tire_model_std)
        check_non_negative(owner, "tire_moment_std", tire_moment_std)
        self.process_accel_std = float(process_accel_std)
        self.tire_model_std = float(tire_model_std)
        self.tire_moment_std = float(tire_moment_std)
        self.yaw_moment = bool(self.scales.count) if yaw_moment is None else bool(yaw_moment)
        r = np.array([*self.r0_diag, 0.0], dtype=float)
        r[:2] += self.tire_model_std**2
        r[3] = 2.0 * self.r0_diag[2] / self.q_step_dt**2 + self.tire_moment_std**2
        p = self.measurement_dim
        self._r_sqrt = np.diag(np.sqrt(r[:p]))

    @property
    def measurement_dim(self) -> int:
        return 4 if self.yaw_moment else 3

    def h(self, x: Array, u: Any) -> Array:
        """``[ΣF_x/m, ΣF_y/m, r(, M_z/I_z − ṙ_gyro)]``: ``(n,)``/``(m, n)`` → ``(p,)``/``(m, p)``."""
        if not isinstance(u, KinematicInput):
            raise ValueError(f"u must be a KinematicInput, got {type(u).__name__}")
        xs = np.asarray(x, dtype=float)
        rows = self._rows_of(xs)
        terms = self.base._terms(u.wheels)
        sums = self._force_sums(rows, terms)
        p = self.params
        dim = self.measurement_dim
        out = np.empty((rows.shape[1], dim))
        out[:, 0] = sums[0] / p.mass
        out[:, 1] = sums[1] / p.mass
        out[:, 2] = rows[2]
        if self.yaw_moment:
            out[:, 3] = sums[2] / p.yaw_inertia - u.yaw_acceleration
        return out.reshape(*xs.shape[:-1], dim)

    def f(self, x: Array, u: Any, dt: float) -> Array:
        """Rotate ``[vx, vy]`` by ``−r Δt`` and add ``Δt [a_x, a_y]``; ``r`` and the scales held (bounded).

        Raises:
            ValueError: ``dt`` not finite and > 0, or ``u`` not a :class:`KinematicInput`.
        """
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be finite and > 0, got {dt}")
        if not isinstance(u, KinematicInput):
            raise ValueError(f"u must be a KinematicInput, got {type(u).__name__}")
        xs = np.asarray(x, dtype=float)
        rows = self._rows_of(xs).copy()
        angle = rows[2] * dt
        cos, sin = np.cos(angle), np.sin(angle)
        vx, vy = rows[0].copy(), rows[1].copy()
        rows[0] = cos * vx + sin * vy + dt * u.ax
        rows[1] = cos * vy - sin * vx + dt * u.ay
        gravity = self._gravity(rows)
        if gravity is not None:  # the ground slope (scales module): v̇ += g, g turned by −r Δt
            rows[:2] += dt * gravity
            self._turn_gravity(gravity, rows[2], dt)
            rows[self._grav : self._grav + 2] = gravity
        self._clip_scales(rows, dt)
        return np.ascontiguousarray(rows.T).reshape(xs.shape)

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        """``diag(σ_proc Δt, σ_proc Δt, √(q0_r Δt/q_step_dt), walk_std √Δt …)``."""
        accel = self.process_accel_std * dt
        yaw = math.sqrt(self.q0_diag[2] * dt / self.q_step_dt)
        return np.diag(np.concatenate([[accel, accel, yaw], self._scale_noise(dt)]))

    def measurement_noise_sqrt(self) -> Array:
        """``√R`` with the tire model's error added to the accelerometer entries."""
        return self._r_sqrt.copy()

    def _wheel_input(self, u: Any) -> Any:
        if isinstance(u, KinematicInput):
            return u.wheels
        raise ValueError(f"u must be a KinematicInput, got {type(u).__name__}")
