"""Observer model of a skid-steered vehicle (N axles per side): state [vx, vy, r] ([SS], MODELS.md B.6–B.7).

:class:`SkidSteerObserverModel` implements
:class:`~terrain_estimation.filters.base.StateSpaceModel` for the (AN-ST)UKF of
:mod:`terrain_estimation.filters.an_stukf`:

* state ``x = [vx, vy, r]`` (m/s, m/s, rad/s), body frame REP 103 at the CM;
* input :class:`SkidSteerInput`: the two side wheel speeds ``ω_l, ω_r``
  (wheel side, rad/s = motor ÷ i_g, paper eq. 39), the low-pass-filtered
  measured ``a_x, a_y`` that set the quasi-static wheel loads (B.5: measured,
  not predicted, which avoids an algebraic loop) and the friction ``μ``;
* measurement ``z = [a_x, a_y, r]`` from the IMU at the CM, predicted as
  ``h(x, u) = [ΣF_x/m, ΣF_y/m, r]`` at the state (B.7: on flat ground the
  IMU's ``a_x = v̇x − vy r``, ``a_y = v̇y + vx r``, which the Newton–Euler
  equations B.6 equate to the summed tire forces over m).

All the physics (contact kinematics, brush tire, loads, body forces) comes
from the shared module :mod:`terrain_estimation.models.skid_steer`; this
module only adds the time discretisation, the noise and the derived outputs.
Every per-wheel quantity runs over the vehicle's 2N wheels
(``SkidSteerParams.axle_x``; the paper's six by default).

**Discretisation (B.6) and sub-steps.** ``f`` is forward Euler of B.6
repeated over ``N`` equal sub-steps of the step ``dt``. With ``N = 1`` it is
the paper's scheme, but the brush tire makes the dynamics stiff at low
rolling speed: linearised, the tire forces relax the velocities at rates up
to ``κ_v / V_r`` with ``V_r = max(R|ω|, ε)`` and ``κ_v ≈ 84.5 m/s²`` for
Table 1 (the largest eigenvalue of ``M^{-1/2} Σ_w E_wᵀ C E_w M^{-1/2}``,
``M = diag(m, m, I_z)``, at unit rolling speed). That is 61 s⁻¹ at 5 km/h
(Euler gain ``dt·rate`` = 0.6 at 10 ms), 10 s⁻¹ at 30 km/h, but 1700 s⁻¹ at
the floor ε = 0.05 m/s, where a 10 ms Euler step (gain 17) diverges. So
``N`` is chosen per step from the input alone (the rate bound depends only
on ``V_r``; saturation can only lower the slope of the brush force, whose
derivative ``(1 − γ/(3μF_z))²`` and secant ``F/γ`` both lie in [0, 1]) so
that the Euler gain per sub-step stays below ``max_euler_gain`` (default
0.5: monotone decay with a relaxation error below 20 % per sub-step; any
gain < 2 is stable). Typical cost: ``N = 1`` above ≈ 3 m/s, 2 at 5 km/h, 34
at standstill. The equilibria (steady states) of the Euler map are those of
the continuous model whatever ``N``, so the sub-steps change transients only.
A step that would need more than ``max_substeps`` sub-steps raises
ValueError (the estimator treats it like a non-finite state and restarts).
``max_euler_gain=None`` gives a fixed ``N = substeps`` (``1``: the literal
paper scheme).

**Noise defaults (B.10) and why.** ``Q0 = diag(0.02², 0.02², 0.005²)`` per
10 ms step and ``R0 = diag(0.1², 0.1², 0.005²)`` as in MODELS.md B.10,
checked against sensors and model errors:

* ``R0`` gyro, σ = 0.005 rad/s (0.29 °/s): a MEMS gyro's white noise at
  100 Hz is 0.001–0.002 rad/s (0.005–0.01 °/s/√Hz × √50 Hz); the rest covers
  vibration-induced rate noise. ``h_3 = r`` has no model in between, so
  this is the one entry that is pure sensor noise; it makes the gyro the
  dominant source of ``r`` (the process noise lets r move 0.005 rad/s per
  step).
* ``R0`` accelerations, σ = 0.1 m/s²: a MEMS accelerometer's white noise at
  100 Hz is only 0.005–0.02 m/s² (60–200 µg/√Hz), so 0.1 m/s² mostly stands
  for what the IMU sees that ``h = ΣF/m`` does not model: body vibration on
  unpaved ground, gravity leaking through unmodelled roll and pitch
  (``g·sin 1° = 0.17 m/s²``) and the brush model's force error. It is the
  lower end of that range: a real skid steer on rough ground shows far more
  (the BorealTC Husky logs in ``real_data/`` carry 0.7–2.6 m/s² rms above
  2 Hz on a small unsuspended robot). **Set it to the actual accelerometer
  noise + vibration of the data.** Measured with these defaults on the
  model's own data (2 m/s, 0.13 rad/s turn): ``P_zz`` of the accelerations is
  0.12–0.21 (m/s²)², mostly ``H Q0 Hᵀ`` (R0 is 0.01), so the update leans on
  the accelerometers through the tire model and accelerometer noise above
  R0 passes into vx, vy: at σ_a = 0.3 m/s² the rms errors are 0.017 / 0.012
  m/s against reported standard deviations of 0.006 / 0.004 (at σ_a = 0.1:
  0.0055 / 0.004). The NIS stays below 3 and strong tracking fires on ≈ 2 %
  of the steps, so a too-small R0 shows as over-confident variances, not as
  a fading factor stuck above 1.
* ``Q0``: 0.02 m/s per 10 ms step is 2 m/s² of unmodelled specific force
  (rolling resistance 0.2–0.5 m/s² for c_rr = 0.02–0.05, a 1° slope
  0.17 m/s², tire-model error of a few 100 N per wheel), 0.005 rad/s per
  step is 0.5 rad/s² of yaw acceleration, ≈ 3 kN·m on I_z = 6390 kg·m²
  (against lateral tire moments of ≈ 10 kN·m in a tight turn). The brush
  model relaxes velocities within 0.02–0.1 s at driving speeds, so the
  propagated spread stays small and Q0 dominates the prior (measured at
  2 m/s: ``P̄0`` ≈ 2.5e-5 against Q0 = 4e-4 (m/s)² for vx). Q is per
  ``q_step_dt`` (10 ms) and scales linearly with the actual step (a random
  walk).

**Derived outputs (B.3).** :func:`side_slips` (κ per side, bounded,
positive in traction), :func:`tire_sideslips` (2N α in wheel order: FL, ML,
RL, FR, MR, RR for the paper's vehicle), :func:`encoder_kinematics` (slip-free ``vx``, ``r`` from the
wheel speeds alone) and :func:`derived_outputs` (all of them plus body
sideslip and the ICR with its validity flag).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from terrain_estimation.checks import check_fields
from terrain_estimation.filters.base import Array
from terrain_estimation.models.skid_steer import (
    SkidSteerParams,
    axle_positions,
    body_forces,
    brush_tire_forces,
    contact_velocities,
    side_slip_ratios,
    theoretical_slips,
    tire_sideslip_angles,
    wheel_positions,
)

__all__ = [
    "DEFAULT_Q0_DIAG",
    "DEFAULT_R0_DIAG",
    "SkidSteerInput",
    "SkidSteerObserverModel",
    "SkidSteerOutputs",
    "relaxation_rate_per_speed",
    "side_slips",
    "tire_sideslips",
    "encoder_kinematics",
    "derived_outputs",
]

#: Base process noise per 10 ms step, ((m/s)², (m/s)², (rad/s)²) (MODELS.md B.10).
DEFAULT_Q0_DIAG: tuple[float, float, float] = (0.02**2, 0.02**2, 0.005**2)
#: Base measurement noise, ((m/s²)², (m/s²)², (rad/s)²) (MODELS.md B.10).
DEFAULT_R0_DIAG: tuple[float, float, float] = (0.1**2, 0.1**2, 0.005**2)


@dataclass(frozen=True)
class SkidSteerInput:
    """Input of one observer step (MODELS.md B.7), held constant over the step.

    Attributes:
        omega_left: left-side wheel speed ω_l (rad/s, wheel side: motor ÷ i_g).
        omega_right: right-side wheel speed ω_r (rad/s).
        ax: low-pass-filtered measured longitudinal acceleration for the load
            model (m/s², specific force on flat ground).
        ay: same, lateral (m/s²).
        friction: tire–ground friction coefficient μ; None uses the vehicle's
            ``SkidSteerParams.friction``.
    """

    omega_left: float
    omega_right: float
    ax: float = 0.0
    ay: float = 0.0
    friction: float | None = None

    def __post_init__(self) -> None:
        isfinite = math.isfinite
        if not (isfinite(self.omega_left) and isfinite(self.omega_right) and isfinite(self.ax) and isfinite(self.ay)):
            check_fields(self, ("omega_left", "omega_right", "ax", "ay"), rule="finite")
        mu = self.friction
        if mu is not None and not (math.isfinite(mu) and mu > 0.0):
            raise ValueError(f"SkidSteerInput.friction must be None or finite and > 0, got {mu}")


def relaxation_rate_per_speed(p: SkidSteerParams) -> float:
    """``κ_v``: bound of the velocity relaxation rate times the rolling speed (m/s²).

    Linearised brush tire (unsaturated), wheel w at ``(x_w, y_w)``: the
    generalised forces on ``[vx, vy, r]`` are ``−(1/V_r) D v`` with
    ``D = Σ_w C_x e_x e_xᵀ + C_α e_y e_yᵀ``, ``e_x = (1, 0, −y_w)``,
    ``e_y = (0, 1, x_w)``. The rates are the eigenvalues of ``M⁻¹ D / V_r``,
    ``M = diag(m, m, I_z)``; for unequal side speeds ``D/V ⪯ D/min V``. The
    Coriolis terms (``±vy r, ∓vx r``) are ignored: they rotate, not relax.
    """
    xw, yw = wheel_positions(p)
    d = np.zeros((3, 3))
    for x_i, y_i in zip(xw, yw, strict=True):
        ex = np.array([1.0, 0.0, -y_i])
        ey = np.array([0.0, 1.0, x_i])
        d += p.longitudinal_stiffness * np.outer(ex, ex) + p.cornering_stiffness * np.outer(ey, ey)
    s = 1.0 / np.sqrt(np.array([p.mass, p.mass, p.yaw_inertia]))
    return float(np.linalg.eigvalsh(s[:, None] * d * s[None, :])[-1])


@dataclass(slots=True)
class _StepTerms:
    """Per-input constants of a step: wheel speeds per wheel (2N), loads, μ, rolling floor, and the
    per-wheel factors of the brush model that depend on the input alone (``R ω``, ``V_r``,
    ``μ F_z``, the saturation limit ``3 μ F_z`` and its divisor). Not modified once built
    (slots, not frozen: built once per step, read by every force evaluation)."""

    omega_wheel: Array
    normal_load: Array
    friction: float
    min_rolling_speed: float
    rolling: Array
    rolling_floored: Array
    mu_fz: Array
    limit: Array
    limit_divisor: Array


class SkidSteerObserverModel:
    """3-state skid-steer observer model (MODELS.md B.6–B.7) for the sigma-point filters.

    ``f`` and ``h`` are vectorised over points (``(m, 3)`` → ``(m, 3)``), as
    the filter protocol requires, and take a :class:`SkidSteerInput`.

    Args:
        params: vehicle (Table 1 plus μ, ε).
        q0_diag: base process-noise variances ``Q0`` per ``q_step_dt``
            ((m/s)², (m/s)², (rad/s)²); see the module docstring for the
            defaults.
        r0_diag: base measurement-noise variances ``R0`` of
            ``[a_x, a_y, r]`` ((m/s²)², (m/s²)², (rad/s)²), all > 0.
        q_step_dt: step length ``Q0`` refers to (s); Q scales with ``dt/q_step_dt``.
        substeps: the minimum number of Euler sub-steps per step (≥ 1).
        max_euler_gain: upper bound of ``δ · κ_v / V_r`` per sub-step; the
            number of sub-steps grows to respect it. None: exactly
            ``substeps`` sub-steps (1 = the literal B.6 scheme, unstable at
            low speed).
        max_substeps: ``f`` raises ValueError if a step needs more.

    Raises:
        ValueError: on invalid arguments.
    """

    def __init__(
        self,
        params: SkidSteerParams | None = None,
        *,
        q0_diag: tuple[float, float, float] = DEFAULT_Q0_DIAG,
        r0_diag: tuple[float, float, float] = DEFAULT_R0_DIAG,
        q_step_dt: float = 0.01,
        substeps: int = 1,
        max_euler_gain: float | None = 0.5,
        max_substeps: int = 1000,
    ) -> None:
        self.params = params if params is not None else SkidSteerParams()
        q = tuple(float(v) for v in q0_diag)
        r = tuple(float(v) for v in r0_diag)
        if len(q) != 3 or not all(math.isfinite(v) and v >= 0.0 for v in q):
            raise ValueError(f"q0_diag must hold 3 finite variances >= 0, got {q0_diag}")
        if len(r) != 3 or not all(math.isfinite(v) and v > 0.0 for v in r):
            raise ValueError(f"r0_diag must hold 3 finite variances > 0, got {r0_diag}")
        if not (math.isfinite(q_step_dt) and q_step_dt > 0.0):
            raise ValueError(f"q_step_dt must be finite and > 0, got {q_step_dt}")
        if not (isinstance(substeps, int) and substeps >= 1):
            raise ValueError(f"substeps must be an int >= 1, got {substeps}")
        if max_euler_gain is not None and not (math.isfinite(max_euler_gain) and 0.0 < max_euler_gain < 2.0):
            raise ValueError(f"max_euler_gain must be None or in (0, 2), got {max_euler_gain}")
        if not (isinstance(max_substeps, int) and max_substeps >= substeps):
            raise ValueError(f"max_substeps must be an int >= substeps, got {max_substeps}")
        self.q0_diag: tuple[float, ...] = q
        self.r0_diag: tuple[float, ...] = r
        self.q_step_dt = float(q_step_dt)
        self.substeps = substeps
        self.max_euler_gain = max_euler_gain
        self.max_substeps = max_substeps
        self.relaxation_rate_per_speed = relaxation_rate_per_speed(self.params)
        self._wheel_x, self._wheel_y = wheel_positions(self.params)  # the params are frozen
        # Stacked constants of _force_sums and f (x row first, y row second).
        self._contact_arm = np.array([self._wheel_y, -self._wheel_x])[:, None, :]
        self._moment_arm = np.array([-self._wheel_y, self._wheel_x])[:, None, :]
        self._stiffness = np.array([self.params.longitudinal_stiffness, -self.params.cornering_stiffness])[
            :, None, None
        ]
        self._coriolis_sign = np.array([1.0, -1.0])[:, None]
        self._rate_divisor = np.array([self.params.mass, self.params.mass, 1.0])[:, None]
        xa = axle_positions(self.params)
        n_axles = float(xa.size)
        s1, s2 = float(np.sum(xa)), float(np.sum(xa**2))
        self._axles = (tuple(xa.tolist()), s1, s2, n_axles * s2 - s1**2, n_axles)
        self._q0_sqrt = np.sqrt(np.array(q))
        self._r0_sqrt = np.diag(np.sqrt(np.array(r)))
        # One-entry cache of the per-input terms: f and h see the same frozen
        # input object several times per filter step (propagate, moments, update).
        self._cached_input: SkidSteerInput | None = None
        self._cached_terms: _StepTerms | None = None

    # -- StateSpaceModel ----------------------------------------------------
    @property
    def state_dim(self) -> int:
        return 3

    @property
    def measurement_dim(self) -> int:
        return 3

    def f(self, x: Array, u: Any, dt: float) -> Array:
        """Forward Euler of B.6 over ``N`` sub-steps (module docstring): ``(3,)``/``(m, 3)`` → same shape.

        ::

            vx ← vx + δ (ΣF_x/m + vy r)
            vy ← vy + δ (ΣF_y/m − vx r)
            r  ← r  + δ M_z/I_z,          δ = dt/N

        Raises:
            ValueError: ``dt`` not finite and > 0, a non-input ``u``, or more
                than ``max_substeps`` sub-steps needed.
        """
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be finite and > 0, got {dt}")
        terms = self._terms(u)
        n_sub = self._substeps(terms, dt)
        delta = dt / n_sub
        p = self.params
        xs = np.asarray(x, dtype=float)  # only read: every sub-step makes a new array
        # Per sub-step, on the components (rows of c, _force_sums's form), the same operations per
        # element as vx += δ (ΣF_x/m + vy r), vy += δ (ΣF_y/m − vx r), r += (δ M_z)/I_z, with the
        # rows stacked: [ΣF_x/m, ΣF_y/m, M_z/1] + [vy r, −(vx r), 0] (a − b is a + (−b) exactly),
        # times δ, the last row then divided by I_z.
        c = _component_rows(xs)
        out = xs  # n_sub >= 1: replaced by a new array at the first sub-step
        for _ in range(n_sub):
            rate = self._force_sums(c, terms) / self._rate_divisor
            coriolis = c[1::-1] * self._coriolis_sign  # [vy, −vx]
            coriolis *= c[2]
            rate[:2] += coriolis
            rate *= delta
            rate[2] /= p.yaw_inertia
            out = np.empty(c.shape[::-1])
            c = np.add(c, rate, out=out.T)
        return out.reshape(xs.shape)

    def h(self, x: Array, u: Any) -> Array:
        """``[ΣF_x/m, ΣF_y/m, r]`` at the state (B.7): ``(3,)``/``(m, 3)`` → same shape."""
        terms = self._terms(u)
        xs = np.asarray(x, dtype=float)
        c = _component_rows(xs)
        out = np.empty(c.shape[::-1])
        z = out.T
        np.divide(self._force_sums(c, terms)[:2], self.params.mass, out=z[:2])
        z[2] = c[2]
        return out.reshape(xs.shape)

    def process_noise_sqrt(self, x: Array, u: Any, dt: float) -> Array:
        """``√Q_k = diag(√(q0 · dt/q_step_dt))`` (B.10 base noise, random-walk scaling)."""
        factor = np.zeros(9)  # np.diag's result, without its Python-level dispatch (once per step)
        factor[::4] = self._q0_sqrt * math.sqrt(dt / self.q_step_dt)
        return factor.reshape(3, 3)

    def measurement_noise_sqrt(self) -> Array:
        """``√R0 = diag(√r0)`` (B.10 base noise)."""
        return self._r0_sqrt.copy()

    # -- for the adaptive filter (B.10) ---------------------------------------
    def tire_sideslip(self, x: Array, u: Any = None) -> Array:
        """The 2N tire sideslip angles α at the state (paper eq. 6), rad; ``(3,)`` → ``(2N,)``."""
        return tire_sideslips(x, self.params)

    # -- helpers ----------------------------------------------------------------
    def substep_count(self, u: SkidSteerInput, dt: float) -> int:
        """Number of Euler sub-steps ``f`` uses for this input and step (see module docstring)."""
        return self._substeps(self._terms(u), dt)

    def forces(self, x: Array, u: SkidSteerInput) -> tuple[Array, Array, Array]:
        """``(ΣF_x, ΣF_y, M_z)`` at the state(s) ``x`` ``(..., 3)`` (N, N, N·m)."""
        xs = np.asarray(x, dtype=float)
        sums = self._force_sums(_component_rows(xs), self._terms(u))
        shape = xs.shape[:-1]
        return sums[0].reshape(shape)[()], sums[1].reshape(shape)[()], sums[2].reshape(shape)[()]

    def _substeps(self, terms: _StepTerms, dt: float, stiffness_scale: float = 1.0) -> int:
        """Euler sub-steps of a step of ``dt``; ``stiffness_scale``: the largest multiplier of the slip
        stiffnesses (a scale model's points), which speeds up the relaxation alike."""
        if self.max_euler_gain is None:
            return self.substeps
        rate = self.relaxation_rate_per_speed * stiffness_scale / terms.min_rolling_speed
        n = max(self.substeps, math.ceil(dt * rate / self.max_euler_gain - 1e-9))
        if n > self.max_substeps:
            raise ValueError(
                f"step of {dt} s needs {n} Euler sub-steps at rolling speed {terms.min_rolling_speed} m/s "
                f"(max_substeps = {self.max_substeps})"
            )
        return n

    def _terms(self, u: Any) -> _StepTerms:
        if u is self._cached_input and self._cached_terms is not None:
            return self._cached_terms
        if not isinstance(u, SkidSteerInput):
            raise ValueError(f"u must be a SkidSteerInput, got {type(u).__name__}")
        p = self.params
        # The float64 arithmetic of the array form (np.repeat of the side speeds, R ω, V_r, μ F_z,
        # 3 μ F_z, np.where(limit > 0, limit, 1)), element by element in scalars where numpy's
        # per-call cost exceeds the arithmetic: + − ×, abs, min, max and the comparisons give the
        # same floats in both (the inputs are finite, SkidSteerInput checks; a test compares).
        wl, wr = float(u.omega_left), float(u.omega_right)
        radius, floor = p.wheel_radius, p.rolling_speed_floor
        rolling = max(min(abs(wl), abs(wr)) * radius, floor)
        normal_load = self._loads(u.ax, u.ay)  # floored at 0 already
        friction = p.friction if u.friction is None else u.friction
        mu = float(friction)
        rl, rr = radius * wl, radius * wr
        fl, fr = max(abs(rl), floor), max(abs(rr), floor)
        mu_fz = [mu * load for load in normal_load.tolist()]
        limit = [3.0 * v for v in mu_fz]
        n = len(mu_fz) // 2  # axles per side
        # One array, a row per per-wheel term (one conversion instead of six).
        rows = np.array(
            [
                [wl] * n + [wr] * n,
                [rl] * n + [rr] * n,
                [fl] * n + [fr] * n,
                mu_fz,
                limit,
                [v if v > 0.0 else 1.0 for v in limit],
            ]
        )
        terms = _StepTerms(
            omega_wheel=rows[0],
            normal_load=normal_load,
            friction=friction,
            min_rolling_speed=rolling,
            rolling=rows[1],
            rolling_floored=rows[2],
            mu_fz=rows[3],
            limit=rows[4],
            limit_divisor=rows[5],
        )
        self._cached_input, self._cached_terms = u, terms
        return terms

    def _force_sums(self, c: Array, terms: _StepTerms) -> Array:
        """Summed brush forces and yaw moment (B.3–B.6) ``[ΣF_x, ΣF_y, M_z]`` ``(3, m)`` at the
        states whose components are the rows of ``c`` ``(3, m)`` (``vx, vy, r``).

        The composition :func:`contact_velocities` → :func:`theoretical_slips` →
        :func:`brush_tire_forces` → :func:`body_forces` of the shared module
        (:meth:`reference_forces`), operation for operation on every element, so
        the floats are the same (a test checks), with what depends on the step's
        input alone taken from ``terms``. Why spelled out: it runs for every sigma
        point two or three times per filter step, and the shared functions'
        argument handling (``asarray``, the wheel positions rebuilt per call) cost
        more than the arithmetic on a ``(7, 6)`` array. The x and y quantities are
        stacked (first axis) so each operation runs once for both, with signs
        folded into constants where IEEE arithmetic makes that exact (``a + b r``
        as ``a − b' r`` with ``b' = −b``; ``C_α (−v_y/V_r)`` as
        ``(−C_α)(v_y/V_r)``), and the three per-wheel terms are summed over the
        wheels in one call (each row of six is reduced on its own: the same sums).
        """
        # [v_x, v_y] = [vx, vy] − r [y_w, −x_w]  (contact_velocities), shape (2, m, 6)
        v = c[:2, :, None] - c[2, :, None] * self._contact_arm
        # [C_x σ_x, C_α σ_y] = [C_x, −C_α] [(R ω − v_x)/V_r, v_y/V_r]  (theoretical_slips, brush_tire_forces)
        np.subtract(terms.rolling, v[0], out=v[0])
        v /= terms.rolling_floored
        v *= self._stiffness
        gamma = np.hypot(v[0], v[1])
        t = np.minimum(gamma, terms.limit)
        t /= terms.limit_divisor
        force = terms.mu_fz * t * (3.0 - 3.0 * t + t * t)
        scale = np.divide(force, gamma, out=np.zeros(gamma.shape), where=gamma > 0.0)
        per_wheel = np.empty((3, *gamma.shape))
        fxy = np.multiply(v, scale, out=per_wheel[:2])  # [F_x, F_y]
        moment = fxy * self._moment_arm  # [−y_w F_x, x_w F_y]
        np.add(moment[1], moment[0], out=per_wheel[2])  # x_w F_y − y_w F_x (body_forces)
        return np.add.reduce(per_wheel, axis=-1)  # per_wheel.sum(axis=-1), without its Python wrapper

    def _loads(self, ax: float, ay: float) -> Array:
        """:func:`quasi_static_loads` for one ``(a_x, a_y)``, operation for operation (the same
        floats, a test checks) with the axle sums computed once: it runs once per filter step."""
        p = self.params
        xa, s1, s2, d, n = self._axles
        m, g, h = p.mass, p.gravity, p.cg_height
        ax, ay = float(ax), float(ay)  # float64 scalars: the same arithmetic, cheaper
        p0 = m * (g * s2 + ax * h * s1) / d
        q = -m * (n * ax * h + g * s1) / d
        lateral = m * ay * h / (n * p.track)
        half = [0.5 * (p0 + q * x) for x in xa]  # 0.5 · axle, axle = p0 + q x_a (scalars: same floats)
        return np.maximum(np.array([a - lateral for a in half] + [a + lateral for a in half]), 0.0)

    def reference_forces(self, x: Array, u: SkidSteerInput) -> tuple[Array, Array, Array]:
        """:meth:`forces` through the shared module's functions, one after the other (the reference
        that ``f`` and ``h``'s fused arithmetic must equal)."""
        p = self.params
        xs = np.asarray(x, dtype=float)
        terms = self._terms(u)
        v_x, v_y = contact_velocities(xs[..., 0], xs[..., 1], xs[..., 2], p)
        sx, sy = theoretical_slips(terms.omega_wheel, v_x, v_y, p)
        fx, fy = brush_tire_forces(
            sx,
            sy,
            terms.normal_load,
            longitudinal_stiffness=p.longitudinal_stiffness,
            cornering_stiffness=p.cornering_stiffness,
            friction=terms.friction,
        )
        return body_forces(fx, fy, p)


def _component_rows(xs: Array) -> Array:
    """The states ``xs`` ``(..., 3)`` as rows of components ``(3, m)`` (``vx``, ``vy``, ``r``): a view
    where the layout allows."""
    if xs.shape[-1:] != (3,):
        raise ValueError(f"x must have shape (3,) or (..., 3), got {xs.shape}")
    return xs.reshape(-1, 3).T


@dataclass(frozen=True)
class SkidSteerOutputs:
    """Quantities derived from one state and the wheel speeds (MODELS.md B.3).

    Attributes:
        slip_left, slip_right: longitudinal slip per side κ (bounded, > 0 in traction).
        tire_sideslip: the 2N tire sideslip angles α (rad) in wheel order (FL, ML,
            RL, FR, MR, RR for the paper's vehicle).
        body_sideslip: β = atan2(vy, vx) (rad, eq. 40).
        icr_x, icr_y: ICR in body axes (m, eq. 41); 0 when not valid.
        icr_valid: |r| above the threshold (the ICR is meaningless as r → 0).
        vx_encoder: slip-free ``R(ω_l + ω_r)/2`` (m/s).
        yaw_rate_encoder: slip-free ``R(ω_r − ω_l)/B`` (rad/s), the "encoder
            yaw rate" that overestimates r in turns.
    """

    slip_left: float
    slip_right: float
    tire_sideslip: tuple[float, ...]
    body_sideslip: float
    icr_x: float
    icr_y: float
    icr_valid: bool
    vx_encoder: float
    yaw_rate_encoder: float


def side_slips(x: Any, omega_left: Any, omega_right: Any, p: SkidSteerParams) -> Array:
    """Per-side slip ``κ_l, κ_r`` at state(s) ``x`` ``(..., 3)`` (B.3), shape ``(..., 2)``.

    The side contact lines move at ``vx ∓ r B/2`` (eq. 3); the bounded slip of
    :func:`~terrain_estimation.models.skid_steer.side_slip_ratios` follows.
    """
    xs = np.asarray(x, dtype=float)
    half = 0.5 * p.track * xs[..., 2]
    v_side = np.stack([xs[..., 0] - half, xs[..., 0] + half], axis=-1)
    omega = np.stack(np.broadcast_arrays(np.asarray(omega_left, float), np.asarray(omega_right, float)), axis=-1)
    return side_slip_ratios(omega, v_side, p)


def tire_sideslips(x: Any, p: SkidSteerParams) -> Array:
    """The 2N tire sideslip angles α (eqs. 5–6) at state(s) ``x`` ``(..., 3)``, shape ``(..., 2N)``."""
    xs = np.asarray(x, dtype=float)
    v_x, v_y = contact_velocities(xs[..., 0], xs[..., 1], xs[..., 2], p)
    return tire_sideslip_angles(v_x, v_y)


def encoder_kinematics(omega_left: float, omega_right: float, p: SkidSteerParams) -> tuple[float, float]:
    """Slip-free kinematic estimates from the wheel speeds alone (eq. 1 with κ = 0).

    Returns:
        ``(vx, r) = (R(ω_l + ω_r)/2, R(ω_r − ω_l)/B)`` (m/s, rad/s).
    """
    rad = p.wheel_radius
    return 0.5 * rad * (omega_left + omega_right), rad * (omega_right - omega_left) / p.track


def derived_outputs(
    x: Any, omega_left: float, omega_right: float, p: SkidSteerParams, min_yaw_rate: float = 0.02
) -> SkidSteerOutputs:
    """Slips, sideslip angles, body sideslip, ICR and encoder estimates at one state ``(3,)`` (B.3).

    Every returned float is finite for a finite state (the ICR is 0 and
    ``icr_valid`` False where ``|r| ≤ min_yaw_rate``). The same formulas as the
    vectorised :func:`side_slips`, :func:`tire_sideslips`,
    :func:`~terrain_estimation.models.skid_steer.body_sideslip` and
    :func:`~terrain_estimation.models.skid_steer.instantaneous_centre_of_rotation`
    (a test compares them), in scalar arithmetic: the estimator calls this once
    per step for one state, where numpy's per-call cost is most of the time.
    """
    xs = np.asarray(x, dtype=float)
    if xs.shape != (3,):
        raise ValueError(f"x must have shape (3,), got {xs.shape}")
    vx, vy, r = xs.tolist()
    xw, yw = _wheel_xy(p)
    return SkidSteerOutputs(*_derived_values(vx, vy, r, omega_left, omega_right, p, min_yaw_rate, xw, yw))


def _derived_values(
    vx: float,
    vy: float,
    r: float,
    omega_left: float,
    omega_right: float,
    p: SkidSteerParams,
    min_yaw_rate: float,
    xw: tuple[float, ...],
    yw: tuple[float, ...],
) -> tuple[float, float, tuple[float, ...], float, float, float, bool, float, float]:
    """The fields of :func:`derived_outputs` in :class:`SkidSteerOutputs` order, from the state's
    floats and the wheel positions (``_wheel_xy(p)``; the estimator keeps them)."""
    half = 0.5 * p.track * r
    valid = abs(r) > min_yaw_rate
    vx_enc, r_enc = encoder_kinematics(omega_left, omega_right, p)
    return (
        _side_slip(p.wheel_radius * omega_left, vx - half, p.rolling_speed_floor),
        _side_slip(p.wheel_radius * omega_right, vx + half, p.rolling_speed_floor),
        tuple(math.atan2(vy + xi * r, abs(vx - yi * r)) for xi, yi in zip(xw, yw, strict=True)),
        math.atan2(vy, vx),
        -vy / r if valid else 0.0,
        vx / r if valid else 0.0,
        valid,
        float(vx_enc),
        float(r_enc),
    )


def _side_slip(rolling: float, v: float, floor: float) -> float:
    """:func:`~terrain_estimation.models.skid_steer.side_slip_ratios` for one side, in scalars."""
    den = rolling if abs(rolling) >= abs(v) else v
    return 0.0 if abs(den) < floor else (rolling - v) / den


@functools.lru_cache(maxsize=16)
def _wheel_xy(p: SkidSteerParams) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """:func:`~terrain_estimation.models.skid_steer.wheel_positions` as tuples of floats (cached:
    the parameters are frozen and hashable)."""
    xw, yw = wheel_positions(p)
    return tuple(xw.tolist()), tuple(yw.tolist())
