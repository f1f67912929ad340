"""Skid-steer observer with tire-parameter scale states: model error the filter can absorb (issue 20 item 3).

The 3-state observer (:mod:`~terrain_estimation.models.skid_steer_observer`)
sees the lateral velocity only through its tire model: ``h = ΣF(x)/m`` with
the nominal friction μ, cornering stiffness C_α and longitudinal stiffness C_x
(MODELS.md B.12). A wrong C_α or μ biases ``v_y`` and no Q/R removes it. Here
the state is augmented with the logarithms of multiplicative scales of a
chosen subset of those parameters::

    x = [vx, vy, r, ln s_1, …, ln s_k],     s_j ∈ {s_μ, s_Cα, s_Cx}
    μ_eff = s_μ μ,   C_α,eff = s_Cα C_α,   C_x,eff = s_Cx C_x

Each ``ln s`` is a random walk (slowly varying terrain and tire; ``walk_std``
per √s), optionally mean-reverting to 0 (s = 1) with the time constant
``reversion_time_s`` (a first-order Gauss–Markov process: where nothing is
learned, e.g. in straight driving for ``s_Cα``, the scale returns to the
nominal instead of wandering), bounded to ``[ln s_min, ln s_max]`` (a scale is clipped wherever it is
used and after each step, so a sigma point beyond the bound acts as the
bound). Logarithms keep the scales positive and make the random walk relative
(a 10 % change is as likely at any level).

What makes the scales observable: in a turn the measured lateral specific
force fixes ``ΣF_y`` and the gyro's yaw rate (through the yaw-moment
balance ``I_z ṙ = M_z``) fixes the moment; the two depend differently on
``v_y`` and on the stiffness (the lateral forces of the front and rear axles
enter the moment with opposite arms), so ``v_y`` and ``s_Cα`` are both
determined. In straight driving ``s_Cα`` is not observable and its variance
grows with the random walk until the next turn; ``s_μ`` only matters where
the tires saturate (a tight skid-steer turn), ``s_Cx`` through the
longitudinal slip against the measured ``a_x``.

**Ground slope (option, states ``gravity_x``, ``gravity_y``).** The
accelerometers measure the specific force, the tire forces over m, so ``h``
is right on a slope; the process ``v̇ = ΣF/m − r×v`` lacks gravity's
components in the body frame, ``g_x = −g sin(grade)`` and ``g_y = −g
cos(grade) sin(bank)`` (grade > 0 rising ahead, bank > 0 left side up; a
5° bank is ``g_y = −0.855 m/s²``). With both names in the states they are
added (m/s²) and enter f: ``v̇_x += g_x``, ``v̇_y += g_y``. On a plane fixed
in the world the body-frame components turn with the vehicle, ``ġ = −r ẑ×g``
(``ġ_x = r g_y``, ``ġ_y = −r g_x``, exact rotation by ``−r Δt`` per
sub-step), plus a first-order Gauss–Markov drive (``slope_std``,
``slope_time_s``) for a plane that changes. Why states, not gravity from a
roll/pitch estimate: the filter has no attitude (no a_z, no roll and pitch
rates), and the accelerometers cannot give the tilt, as they read tire
forces; the slope is what the model error is, and the innovations estimate
it. Observability: in a steady run ``v̇_y = 0`` gives ``g_y = v_x r − a_y``
(``a_y = ΣF_y/m`` is measured), so the bank is found from the accelerometer
even driving straight; what the bank does leave open there is the ``v_y``
that produces the holding force ``ΣF_y = −m g_y``, which the tire model
fixes only with the right stiffness: with a cornering-stiffness scale state
a bank and a ``v_y`` bias look alike until the vehicle turns (a turn on a
plane also rotates ``g`` in the body frame). Measured on the straight
acceleration run: the published standard deviation of ``g_y`` stays at
0.05–0.07 m/s² (3–4× a turn's) with e²/σ² 0.25, and the ``v_y`` variance
does not collapse (e²/σ² 0.55). Along x a grade and the motion resistance
are both a deceleration: on a straight run they cannot be told apart (the
resistance changes sign with the travel direction, the grade with the
heading): ``g_x`` reads the resistance (−0.15 m/s² on level ground). Keep
the resistance considered (the default ``consider``), which widens ``g_x``'s
published standard deviation to 0.2 m/s² by what it trades with (e²/σ² 0.4
there), rather than a resistance state beside the slope. Measured on the
independent truth plant, the slope states also take up lateral model error
on level ground (a sharp turn reads ``g_y ≈ −0.13 m/s²``), which is why the
option is off by default (3 seeds, against the default without it: on the
5° bank mean |e_β| 1.89 against 2.13 mrad, RMS e_vy 0.0033 against 0.0037
m/s; on the level nominal turn 2.00 against 1.57 mrad, 0.0029 against 0.0023
m/s). A tighter prior does not keep the states out of it: with ``slope_std``
0.5 m/s² (3°) and ``slope_time_s`` 600 or 3600 s the nominal turn's |e_β| is
1.92–1.93 mrad against 1.95 with the defaults and 1.53 without the states
(seed 1000): the lateral model error they take up (≈ 0.13 m/s² in the sharp
turn, under 1° of bank) is inside any prior that still admits a real bank.

The forces are the shared brush model (:mod:`~terrain_estimation.models.skid_steer`,
MODELS.md B.4) evaluated with the per-point effective parameters:
:func:`scaled_force_sums`. The process is the B.6 forward Euler of the
observer with its sub-step rule (the relaxation-rate bound grows with the
largest stiffness scale of the points).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from terrain_estimation.checks import check_fields
from terrain_estimation.filters.base import Array
from terrain_estimation.models.skid_steer import SkidSteerParams
from terrain_estimation.models.skid_steer_observer import (
    DEFAULT_Q0_DIAG,
    DEFAULT_R0_DIAG,
    SkidSteerObserverModel,
    _StepTerms,
    tire_sideslips,
)

__all__ = [
    "GRAVITY_NAMES",
    "RESISTANCE_NAME",
    "SCALE_NAMES",
    "STATE_NAMES",
    "TireScaleConfig",
    "SkidSteerTireScaleModel",
    "scaled_force_sums",
    "state_names",
]

#: The tire parameters that may carry a scale state, in state order.
SCALE_NAMES: tuple[str, ...] = ("friction", "cornering_stiffness", "longitudinal_stiffness")
#: The motion-resistance coefficient state (additive, after the scales; module docstring).
RESISTANCE_NAME = "motion_resistance"
#: The ground-slope states (gravity's body-frame x, y components, m/s²; module docstring), after the resistance.
GRAVITY_NAMES: tuple[str, str] = ("gravity_x", "gravity_y")
#: Every name :attr:`TireScaleConfig.states` accepts, in state order.
STATE_NAMES: tuple[str, ...] = (*SCALE_NAMES, RESISTANCE_NAME, *GRAVITY_NAMES)


def state_names(what: str, value: Any) -> tuple[str, ...]:
    """``value``, distinct names of :data:`STATE_NAMES`, in state order; ValueError naming ``what`` otherwise."""
    names = tuple(str(s) for s in value)
    unknown = [s for s in names if s not in STATE_NAMES]
    if unknown or len(set(names)) != len(names):
        raise ValueError(f"{what} must be distinct names of {STATE_NAMES}, got {value!r}")
    return tuple(s for s in STATE_NAMES if s in names)


@dataclass(frozen=True)
class TireScaleConfig:
    """Which tire parameters carry a scale state, and how the scales move.

    Attributes:
        states: names from :data:`STATE_NAMES` (any subset, in any order;
            stored in :data:`STATE_NAMES` order). Empty: no scale state.
            ``"motion_resistance"`` adds the resistance coefficient state,
            ``"gravity_x"`` with ``"gravity_y"`` (both or neither) the ground
            slope (module docstring), the others a log-scale each.
        walk_std: random-walk standard deviation of each ``ln s`` (1/√s):
            0.02 lets a scale drift by ≈ 6 % in 10 s.
        initial_std: standard deviation of ``ln s`` at (re)initialisation
            (0.3: the nominal value is right within ≈ ±35 %).
        min_scale, max_scale: bounds of every scale (dimensionless, 0 < min < 1 < max).
        reversion_time_s: time constant of the reversion of each ``ln s`` to 0
            (s); 0: none (a pure random walk).
        resistance_nominal: prior mean c_0 of the motion-resistance
            coefficient (force per unit normal load; 0.01–0.03 for tires on
            firm ground, 0.05–0.15 on grass, sand, mud).
        resistance_std: prior and stationary standard deviation of the
            coefficient around ``resistance_nominal``.
        resistance_time_s: correlation time of the coefficient (s): it is a
            first-order Gauss–Markov process reverting to c_0, so where it is
            not observable (a steady run) its variance stays at the prior's.
        resistance_max: upper bound of the coefficient (its lower bound is 0).
        resistance_speed: smoothing speed v_0 of the resistance's direction,
            ``tanh(v_wheel/v_0)`` (m/s).
        slope_std: prior and stationary standard deviation of each gravity
            component (m/s²; 1.0 ≈ a 6° slope).
        slope_time_s: correlation time of the gravity components (s): how
            long a slope holds; where the slope is not observable its variance
            returns to ``slope_std²``.
        slope_max: bound of each gravity component (m/s²; 5 ≈ 30°).
    """

    states: tuple[str, ...] = ("cornering_stiffness",)
    walk_std: float = 0.02
    initial_std: float = 0.3
    min_scale: float = 0.25
    max_scale: float = 4.0
    reversion_time_s: float = 0.0
    resistance_nominal: float = 0.02
    resistance_std: float = 0.02
    resistance_time_s: float = 30.0
    resistance_max: float = 0.5
    resistance_speed: float = 0.1
    slope_std: float = 1.0
    slope_time_s: float = 60.0
    slope_max: float = 5.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "states", state_names("TireScaleConfig.states", self.states))
        non_negative = ("walk_std", "initial_std", "reversion_time_s", "resistance_nominal", "resistance_std")
        check_fields(self, non_negative, rule="non_negative")
        lo, hi = self.min_scale, self.max_scale
        if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo < 1.0 < hi):
            raise ValueError(
                f"TireScaleConfig.min_scale and max_scale must satisfy 0 < min < 1 < max, got {lo} and {hi}"
            )

        check_fields(self, ("resistance_time_s", "resistance_speed", "slope_std", "slope_time_s", "slope_max"))
        if sum(name in self.states for name in GRAVITY_NAMES) == 1:
            raise ValueError(f"TireScaleConfig.states must hold both or neither of {GRAVITY_NAMES}, got {self.states}")
        if not (math.isfinite(self.resistance_max) and self.resistance_max > self.resistance_nominal):
            raise ValueError(
                f"TireScaleConfig.resistance_max must be finite and > resistance_nominal "
                f"({self.resistance_nominal}), got {self.resistance_max}"
            )

    @property
    def count(self) -> int:
        """Number of added states (log-scales and the resistance coefficient)."""
        return len(self.states)

    @property
    def scale_count(self) -> int:
        """Number of log-scale states k (the tire parameters of :data:`SCALE_NAMES`)."""
        return self.count - int(self.resistance) - 2 * int(self.slope)

    @property
    def resistance(self) -> bool:
        """Whether the motion-resistance coefficient is a state."""
        return RESISTANCE_NAME in self.states

    @property
    def slope(self) -> bool:
        """Whether the ground slope (gravity's body-frame x, y components) is a state pair."""
        return GRAVITY_NAMES[0] in self.states


def scaled_force_sums(base: SkidSteerObserverModel, c: Array, terms: _StepTerms, multipliers: Array | None) -> Array:
    """``[ΣF_x, ΣF_y, M_z]`` ``(3, m)`` of the brush model (B.3–B.6) with per-point parameter scales.

    Args:
        base: the nominal observer model (geometry, stiffnesses, loads).
        c: states as component rows ``(3, m)`` (``vx, vy, r``; m/s, m/s, rad/s).
        terms: the step's per-input terms (``base._terms(u)``).
        multipliers: ``(3, m)`` scales of ``μ, C_α, C_x`` per point (rows in
            :data:`SCALE_NAMES` order), or None for the nominal model (then
            exactly the observer's own force sums).

    Returns:
        Forces (N) and yaw moment (N·m) per point.
    """
    if multipliers is None:
        return base._force_sums(c, terms)
    v = c[:2, :, None] - c[2, :, None] * base._contact_arm  # contact velocities (2, m, 2N)
    np.subtract(terms.rolling, v[0], out=v[0])
    v /= terms.rolling_floored  # [σ_x, −σ_y]
    stiffness = base._stiffness * multipliers[[2, 1], :, None]  # [C_x s_Cx, −C_α s_Cα] (2, m, 1)
    v *= stiffness
    gamma = np.hypot(v[0], v[1])
    mu_fz = terms.mu_fz * multipliers[0][:, None]  # (m, 2N)
    limit = 3.0 * mu_fz
    t = np.minimum(gamma, limit)
    t /= np.where(limit > 0.0, limit, 1.0)
    force = mu_fz * t * (3.0 - 3.0 * t + t * t)
    scale = np.divide(force, gamma, out=np.zeros(gamma.shape), where=gamma > 0.0)
    per_wheel = np.empty((3, *gamma.shape))
    fxy = np.multiply(v, scale, out=per_wheel[:2])
    moment = fxy * base._moment_arm
    np.add(moment[1], moment[0], out=per_wheel[2])
    return np.add.reduce(per_wheel, axis=-1)


def resistance_force_sums(
    base: SkidSteerObserverModel, c: Array, terms: _StepTerms, coefficient: Array, speed: float
) -> Array:
    """``[ΣF_x, 0, M_z]`` ``(3, m)`` of the motion resistance (rolling, bulldozing) at each point.

    Each wheel is resisted along the body x axis by ``c F_z tanh(v_x,w/v_0)``,
    ``v_x,w = v_x − r y_w`` its contact point's forward speed: in a turn the
    faster side is resisted more, which gives the yaw moment that opposes the
    turn.

    Args:
        base: the nominal observer model (geometry, loads).
        c: states as component rows ``(3, m)``.
        terms: the step's per-input terms (loads).
        coefficient: the resistance coefficient of each point ``(m,)`` (≥ 0).
        speed: smoothing speed v_0 (m/s).
    """
    wheel_vx = c[0, :, None] - c[2, :, None] * base._contact_arm[0]  # (m, 2N)
    fx = -(coefficient[:, None] * terms.normal_load) * np.tanh(wheel_vx / speed)
    out = np.zeros((3, c.shape[1]))
    out[0] = fx.sum(axis=-1)
    out[2] = (fx * base._moment_arm[0]).sum(axis=-1)  # −y_w F_x
    return out


class _ScaledModelBase:
    """What the scale-augmented models share: the state layout, the scales, ``h`` and the noise."""

    def __init__(
        self,
        params: SkidSteerParams | None,
        scales: TireScaleConfig,
        *,
        q0_diag: Sequence[float],
        r0_diag: Sequence[float],
        q_step_dt: float,
        substeps: int,
        max_euler_gain: float | None,
        max_substeps: int,
    ) -> None:
        if not isinstance(scales, TireScaleConfig):
            raise ValueError(f"scales must be a TireScaleConfig, got {type(scales).__name__}")
        self.base = SkidSteerObserverModel(
            params,
            q0_diag=tuple(q0_diag),  # type: ignore[arg-type]
            r0_diag=tuple(r0_diag),  # type: ignore[arg-type]
            q_step_dt=q_step_dt,
            substeps=substeps,
            max_euler_gain=max_euler_gain,
            max_substeps=max_substeps,
        )
        self.params = self.base.params
        self.scales = scales
        self._k = scales.scale_count
        self._rows = np.array([SCALE_NAMES.index(s) for s in scales.states[: self._k]], dtype=int)
        self._log_bounds = (math.log(scales.min_scale), math.log(scales.max_scale))
        #: Rows of the resistance coefficient and of the gravity pair in the state (after the log-scales).
        self._res = 3 + self._k
        self._grav = self._res + int(scales.resistance)
        self.q0_diag = self.base.q0_diag
        self.r0_diag = self.base.r0_diag
        self.q_step_dt = self.base.q_step_dt

    @property
    def state_dim(self) -> int:
        return 3 + self.scales.count

    @property
    def measurement_dim(self) -> int:
        return 3

    # -- state layout ---------------------------------------------------------------
    def _rows_of(self, x: Array) -> Array:
        xs = np.asarray(x, dtype=float)
        n = self.state_dim
        if xs.shape[-1:] != (n,):
            raise ValueError(f"x must have shape ({n},) or (..., {n}), got {xs.shape}")
        return xs.reshape(-1, n).T

    def _multipliers(self, rows: Array) -> Array | None:
        """``(3, m)`` scales of μ, C_α, C_x of the points (None without scale states)."""
        if not self._k:
            return None
        lo, hi = self._log_bounds
        mult = np.ones((3, rows.shape[1]))
        mult[self._rows] = np.exp(np.clip(rows[3 : 3 + self._k], lo, hi))
        return mult

    def _force_sums(self, rows: Array, terms: _StepTerms) -> Array:
        """``[ΣF_x, ΣF_y, M_z]`` ``(3, m)``: the tires with the points' scales, plus the motion resistance."""
        sums = scaled_force_sums(self.base, rows[:3], terms, self._multipliers(rows))
        if self.scales.resistance:
            coefficient = np.clip(rows[self._res], 0.0, self.scales.resistance_max)
            sums += resistance_force_sums(self.base, rows[:3], terms, coefficient, self.scales.resistance_speed)
        return sums

    def scale_values(self, x: Array) -> tuple[float, ...]:
        """The added states of one state ``(n,)`` in :attr:`scales` ``.states`` order: the scales
        ``s = exp(ln s)`` (bounded), then the resistance coefficient (bounded)."""
        lo, hi = self._log_bounds
        extra = np.asarray(x, dtype=float)[3:]
        values = [math.exp(min(max(float(v), lo), hi)) for v in extra[: self._k]]
        if self.scales.resistance:
            values.append(min(max(float(extra[self._res - 3]), 0.0), self.scales.resistance_max))
        if self.scales.slope:
            bound = self.scales.slope_max
            values.extend(min(max(float(v), -bound), bound) for v in extra[self._grav - 3 :])
        return tuple(values)

    def initial_scale_state(self) -> Array:
        """The added states at (re)initialisation ``(k,)``: ``ln s = 0``, the coefficient at its prior mean,
        level ground."""
        out = np.zeros(self.scales.count)
        if self.scales.resistance:
            out[self._res - 3] = self.scales.resistance_nominal
        return out

    def initial_scale_covariance(self) -> Array:
        """``diag(initial_std², …, resistance_std², slope_std², slope_std²)`` of the added states ``(k, k)``."""
        sc = self.scales
        slope = [sc.slope_std**2] * (2 * int(sc.slope))
        return np.diag([sc.initial_std**2] * self._k + [sc.resistance_std**2] * int(sc.resistance) + slope)

    # -- StateSpaceModel ------------------------------------------------------------
    def h(self, x: Array, u: Any) -> Array:
        """``[ΣF_x/m, ΣF_y/m, r]`` at the state(s) with their scales: ``(n,)``/``(m, n)`` → ``(3,)``/``(m, 3)``."""
        xs = np.asarray(x, dtype=float)
        rows = self._rows_of(xs)
        terms = self.base._terms(self._wheel_input(u))
        sums = self._force_sums(rows, terms)
        out = np.empty((rows.shape[1], 3))
        out[:, 0] = sums[0] / self.params.mass
        out[:, 1] = sums[1] / self.params.mass
        out[:, 2] = rows[2]
        return out.reshape(*xs.shape[:-1], 3)

    def measurement_noise_sqrt(self) -> Array:
        """``√R = diag(√r0)``."""
        return self.base.measurement_noise_sqrt()

    def _scale_noise(self, dt: float) -> Array:
        """Per-step noise std of the added states: the scales' walk, the coefficient's Gauss–Markov drive."""
        sc = self.scales
        noise = [sc.walk_std * math.sqrt(dt)] * self._k
        if sc.resistance:
            noise.append(sc.resistance_std * math.sqrt(-math.expm1(-2.0 * dt / sc.resistance_time_s)))
        if sc.slope:
            noise.extend([sc.slope_std * math.sqrt(-math.expm1(-2.0 * dt / sc.slope_time_s))] * 2)
        return np.array(noise)

    def tire_sideslip(self, x: Array, u: Any = None) -> Array:
        """The 2N tire sideslip angles α at the motion part of the state (rad), for B.10."""
        return tire_sideslips(np.asarray(x, dtype=float)[..., :3], self.params)

    def forces(self, x: Array, u: Any) -> tuple[Array, Array, Array]:
        """``(ΣF_x, ΣF_y, M_z)`` at the state(s) ``(..., n)`` with their scales (N, N, N·m)."""
        xs = np.asarray(x, dtype=float)
        rows = self._rows_of(xs)
        sums = self._force_sums(rows, self.base._terms(self._wheel_input(u)))
        shape = xs.shape[:-1]
        return sums[0].reshape(shape)[()], sums[1].reshape(shape)[()], sums[2].reshape(shape)[()]

    def _wheel_input(self, u: Any) -> Any:
        return u

    def _clip_scales(self, out: Array, dt: float) -> None:
        """Revert the added states (rows ``out[3:]``) towards their prior over ``dt`` and bound them, in place:
        the log-scales to 0 (if ``reversion_time_s`` is set), the coefficient to ``resistance_nominal``."""
        k = self._k
        if k:
            tau = self.scales.reversion_time_s
            if tau > 0.0:
                out[3 : 3 + k] *= math.exp(-dt / tau)
            lo, hi = self._log_bounds
            np.clip(out[3 : 3 + k], lo, hi, out=out[3 : 3 + k])
        sc = self.scales
        if sc.resistance:
            i = self._res
            decay = math.exp(-dt / sc.resistance_time_s)
            out[i] = sc.resistance_nominal + (out[i] - sc.resistance_nominal) * decay
            np.clip(out[i], 0.0, sc.resistance_max, out=out[i])
        if sc.slope:
            g = out[self._grav : self._grav + 2]
            g *= math.exp(-dt / sc.slope_time_s)
            np.clip(g, -sc.slope_max, sc.slope_max, out=g)

    def _gravity(self, rows: Array) -> Array | None:
        """The points' gravity components ``(2, m)`` (bounded; a view's copy), None without the slope states."""
        if not self.scales.slope:
            return None
        bound = self.scales.slope_max
        return np.clip(rows[self._grav : self._grav + 2], -bound, bound)

    @staticmethod
    def _turn_gravity(gravity: Array, r: Array, dt: float) -> None:
        """Rotate the body-frame gravity components ``(2, m)`` by ``−r dt`` in place (a world-fixed plane)."""
        angle = r * dt
        cos, sin = np.cos(angle), np.sin(angle)
        gx = gravity[0].copy()
        gravity[0] = cos * gx + sin * gravity[1]
        gravity[1] = cos * gravity[1] - sin * gx


class SkidSteerTireScaleModel(_ScaledModelBase):
    """Brush-model process (B.6) with tire-parameter scale states (module docstring).

    State ``[vx, vy, r, ln s…]`` (m/s, m/s, rad/s, −); input
    :class:`~terrain_estimation.models.skid_steer_observer.SkidSteerInput`;
    measurement ``[a_x, a_y, r]`` as the observer's.

    Args:
        params: vehicle (nominal μ, C_α, C_x that the scales multiply).
        scales: which scales and their random walk.
        q0_diag, r0_diag, q_step_dt, substeps, max_euler_gain, max_substeps:
            as :class:`~terrain_estimation.models.skid_steer_observer.SkidSteerObserverModel`
            (``q0_diag`` for the three motion states).

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
        substeps: int = 1,
        max_euler_gain: float | None = 0.5,
        max_substeps: int = 1000,
    ) -> None:
        super().__init__(
            params,
            scales if scales is not None else TireScaleConfig(),
            q0_diag=q0_diag,
            r0_diag=r0_diag,
            q_step_dt=q_step_dt,
            substeps=substeps,
            max_euler_gain=max_euler_gain,
            max_substeps=max_substeps,
        )

    def f(self, x: Array, u: Any, dt: float) -> Array:
        """Forward Euler of B.6 over sub-steps with each point's scales; the scales are held (and bounded).

        Raises:
            ValueError: ``dt`` not finite and > 0, a non-input ``u``, or more
                than ``max_substeps`` sub-steps needed.
        """
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be finite and > 0, got {dt}")
        xs = np.asarray(x, dtype=float)
        rows = self._rows_of(xs).copy()
        terms = self.base._terms(u)
        mult = self._multipliers(rows)
        stiffest = 1.0 if mult is None else float(np.max(mult[1:]))
        n_sub = self.base._substeps(terms, dt, stiffest)
        delta = dt / n_sub
        p = self.params
        c = rows[:3]
        sc = self.scales
        coefficient = np.clip(rows[self._res], 0.0, sc.resistance_max) if sc.resistance else None
        gravity = self._gravity(rows)
        for _ in range(n_sub):
            rate = scaled_force_sums(self.base, c, terms, mult)
            if coefficient is not None:
                rate += resistance_force_sums(self.base, c, terms, coefficient, sc.resistance_speed)
            rate /= self.base._rate_divisor
            rate[0] += c[1] * c[2]
            rate[1] -= c[0] * c[2]
            rate[2] /= p.yaw_inertia
            if gravity is not None:
                rate[:2] += gravity
                self._turn_gravity(gravity, c[2], delta)
            c += delta * rate
        if gravity is not None:
            rows[self._grav : self._grav + 2] = gravity
        self._clip_scales(rows, dt)
        return np.ascontiguousarray(rows.T).reshape(xs.shape)

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        """``diag(√(q0 dt/q_step_dt), walk_std √dt …)``: B.10 base noise and the scales' random walk."""
        motion = np.sqrt(np.asarray(self.q0_diag, dtype=float) * (dt / self.q_step_dt))
        return np.diag(np.concatenate([motion, self._scale_noise(dt)]))
