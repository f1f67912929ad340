"""Equations of motion of the skid-steer truth plant and their RK4 integrator.

The plant and what it has beyond the observer: :mod:`vehicle_sim.plants.skid_steer`.

State (26 values, SI units)
    pose ``x, y, yaw`` in the odom frame (the ground plane's axes on a slope);
    body-frame ``vx, vy, r``; wheel-side speeds ``ω_l, ω_r`` and wheel angles
    (rad); sprung-mass ``roll, roll rate, pitch, pitch rate``; lagged tire
    forces ``F_x`` (6) and ``F_y`` (6) (used only with tire relaxation; on a
    slope ``F_y`` starts holding the vehicle against it). Wheel order FL, ML,
    RL, FR, MR, RR.

Integration
    Classical fixed-step RK4; motor torques are held over the 10 ms sensor
    period (the drive controller runs at the sensor rate). The default step is
    2 ms (five per period), not 1 ms: the fastest mode of the truth plant is
    the wheel–tire torsional mode through the relaxation spring C_x/L_x,
    ≈ 7 Hz rolling and ≈ 18 Hz at standstill (ω Δt ≤ 0.23 at 2 ms), and
    halving the cost keeps the 45 s turn at ≈ 3 s of wall time. Measured
    against 0.25 ms steps on the three manoeuvres of B.11: with the truth
    effects |Δvx| ≤ 2e-6 m/s, |Δr| ≤ 2e-9 rad/s, |Δα| ≤ 2e-9 rad,
    |ΔF_z| ≤ 0.01 N; with the nominal physics (one-step load-transfer hold,
    below) |Δvx| ≤ 1e-6 m/s, |Δr| ≤ 3e-7 rad/s, |ΔF_z| ≤ 25 N (of ≈ 4900 N)
    right after a step in acceleration, zero in steady states. Starting from
    rest with large torques (slips saturating within milliseconds) the errors
    reach 3e-5 m/s in speed and 0.05 % in wheel speed for a moment; a 1 ms
    step (``SkidSteerScenario.integration_step``) cuts them twentyfold. With
    the magic-formula truth (12 s of each manoeuvre against 0.25 ms steps):
    |Δvx| ≤ 1.7e-5 m/s (from rest), |Δr| ≤ 2e-9 rad/s, |Δα| ≤ 3e-9 rad,
    |ΔF_z| ≤ 0.04 N; the torque step from rest 3e-5 m/s and 0.02 % in wheel
    speed.
    Without tire relaxation the slip equations become stiff at low rolling
    speed (the slip denominator V_r shrinks to ε = 0.05 m/s), so the number
    of steps of a period is raised until ``λ_max Δt ≤ 2`` for a bound
    λ_max ∝ 1/V_r of the fastest tire mode (RK4 is stable up to 2.78 on the
    negative real axis): ≈ 0.06 ms steps when starting from rest.

Algebraic loop
    Loads depend on the body acceleration, which depends on the tire forces,
    which depend on the loads. With tire relaxation the forces are states and
    the only loop left (loads → motion resistance → f_x) is linear: it is
    solved exactly at every stage. Without relaxation the load transfer uses
    the specific force of the first RK4 stage of the current step (that stage
    reuses the value of the previous step): a delay of at most one step, far
    below the 0.5 s roll/pitch periods and without effect in a steady state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.models.skid_steer import (
    body_forces,
    contact_velocities,
    theoretical_slips,
    wheel_positions,
)
from vehicle_sim.plants.skid_steer_ground import GroundContact, SkidSteerGround, Surface, equal_spring_loads
from vehicle_sim.plants.skid_steer_manoeuvres import SkidSteerScenario
from vehicle_sim.plants.skid_steer_vehicle import TURNING_RESISTANCE_SPEED
from vehicle_sim.plants.tire_laws import MagicFormulaWheels, brush_forces

__all__ = ["effective_ground"]

Array = NDArray[np.float64]

# ---------------------------------------------------------------------------
# Equations of motion
# ---------------------------------------------------------------------------

_X, _Y, _YAW, _VX, _VY, _R = 0, 1, 2, 3, 4, 5
_OMEGA_L, _OMEGA_R, _ANGLE_L, _ANGLE_R = 6, 7, 8, 9
_ROLL, _ROLL_RATE, _PITCH, _PITCH_RATE = 10, 11, 12, 13
_FX = slice(14, 20)
_FY = slice(20, 26)
_N_STATES = 26

#: Largest λ_max Δt of the stiffness-limited step (RK4 is stable to 2.78).
_STIFF_STEP_LIMIT = 2.0
#: Most RK4 steps in one sensor period.
_MAX_SUBSTEPS = 400


@dataclass(frozen=True, slots=True)
class _Evaluation:
    """Intermediate quantities of one evaluation of the equations of motion."""

    derivative: Array
    normal_load: Array
    tire_force_x: Array
    tire_force_y: Array
    steady_tire_force_x: Array
    steady_tire_force_y: Array
    motion_resistance: Array
    friction: Array
    contact_vx: Array
    contact_vy: Array
    specific_force_x: float
    specific_force_y: float
    normal_gravity: float


def effective_ground(scenario: SkidSteerScenario) -> SkidSteerGround:
    """The scenario's ground with the effect ``terrain_slope`` (grade, bank at the start heading) applied.

    Raises:
        ValueError: the effect asks for a slope on a ground that is already inclined.
    """
    grade, bank = scenario.effects.terrain_slope
    if grade == 0.0 and bank == 0.0:
        return scenario.ground
    if not scenario.ground.level:
        raise ValueError(
            f"SkidSteerEffects.terrain_slope {scenario.effects.terrain_slope} on a ground already inclined "
            f"(grade {scenario.ground.grade}, cross_slope {scenario.ground.cross_slope}): give one of the two"
        )
    return replace(scenario.ground, grade=grade, cross_slope=bank)


class _EquationsOfMotion:
    """Planar 3-DOF body, wheel sides, sprung roll/pitch, tire lag (MODELS.md B.4–B.6 plus effects).

    ::

        m (v̇x − vy r) = Σ (F_x − F_rr) + m g_bx                (B.6, gravity, motion resistance)
        m (v̇y + vx r) = Σ F_y + m g_by
        I_z ṙ         = Σ x_i F_y − y_j (F_x − F_rr)
        I_side ω̇_j    = η i_g T_m,j − R Σ_i F_x,ij            (B.6 wheel-side dynamics)
        I_φ φ̈ = m_s f_y (H_s − h_rc) + m_s g_n (H_s − h_rc) sin φ − K_φ φ − C_φ φ̇
        I_θ θ̈ = −m_s f_x (H_s − h_pc) + m_s g_n (H_s − h_pc) sin θ − K_θ θ − C_θ θ̇
        Ḟ = (V/L)(F_ss − F),   V = max(R|ω|, |v_contact|, V_floor)       (relaxation)

    f = Σ ground forces / m is the specific force of the road frame; g_bx,
    g_by, g_n are gravity along body x, y and normal to the ground
    (:class:`~vehicle_sim.plants.skid_steer_ground.GroundContact`: ``−g sin γ,
    0, g cos γ`` for the effect ``terrain_grade`` γ on a level plane). F, F_ss
    come from the vehicle's tire law with μ, stiffness scale and f_rr of the
    surface under each wheel. Loads:
    quasi-static (B.5) as ``F_z = F_z0 g_n/g + ∂F_z/∂a_x f_x + ∂F_z/∂a_y f_y``
    (the exact affine decomposition of the equal-spring loads), or, with
    load-transfer dynamics, the static loads plus the roll and pitch moments
    through the suspension springs/dampers (``∓(K φ + C φ̇)``), the links at the
    roll/pitch centres (``m_s f h_c``, instantaneous) and the unsprung masses
    (``m_u f R``), distributed like rigid-body equal-spring deflections: equal
    per axle laterally, linear in x_i longitudinally. In a steady state both
    give the same loads apart from the CM shift of the tilted body.
    """

    def __init__(self, scenario: SkidSteerScenario) -> None:
        vehicle, effects = scenario.vehicle, scenario.effects
        nominal = vehicle.nominal
        self.params = effects.true_params(nominal)
        p = self.params
        self.load_dynamics = effects.load_transfer_dynamics
        self.relaxation = effects.tire_relaxation
        self.magic_formula = vehicle.tire_law == "magic_formula"
        self.mass = p.mass
        self.yaw_inertia = p.yaw_inertia
        self.radius = p.wheel_radius
        self.gravity = p.gravity
        self.grade_accel = p.gravity * math.sin(effects.terrain_grade)
        self.normal_gravity = p.gravity * math.cos(effects.terrain_grade)
        self.drive_gain = vehicle.transmission_efficiency * p.transmission_ratio
        self.side_inertia = vehicle.side_inertia
        self.cx, self.ca, self.mu = p.longitudinal_stiffness, p.cornering_stiffness, p.friction
        self.rr, self.rr_speed = vehicle.rolling_resistance, vehicle.rolling_resistance_speed
        self.lx, self.ly = vehicle.longitudinal_relaxation_length, vehicle.lateral_relaxation_length
        self.relax_floor = vehicle.relaxation_speed_floor
        self.inverse_lx = 1.0 / vehicle.longitudinal_relaxation_length
        self.inverse_ly = 1.0 / vehicle.lateral_relaxation_length
        self.inverse_rr_speed = 1.0 / vehicle.rolling_resistance_speed

        # The kinematics (eqs. 3, 5) and the force sums (B.6) are linear: their matrices are taken from the shared
        # functions once (unit inputs), so the RK4 stage applies exactly contact_velocities and body_forces
        # at the cost of one matrix product each.
        identity = np.eye(3)
        unit_vx, unit_vy = contact_velocities(identity[0], identity[1], identity[2], p)
        self.contact_map = np.vstack((unit_vx.T, unit_vy.T))  # (12, 3): (vx, vy, r) → (v_x contact, v_y contact)
        unit = np.eye(12)
        self.force_map = np.vstack(body_forces(unit[:, :6], unit[:, 6:], p))  # (3, 12): (F_x, F_y) → (ΣF_x, ΣF_y, M_z)
        self.side_map = np.kron(np.eye(2), np.ones(3))  # (2, 6): per-wheel → per-side sums

        # Loads: exact affine decomposition of B.5 (the equal-spring loads are affine in g, a_x, a_y before the floor).
        cos_grade = math.cos(effects.terrain_grade)
        xw, yw = wheel_positions(nominal)

        def quasi_static_loads(f_x: float, f_y: float) -> Array:
            return equal_spring_loads(xw[:3], nominal.track, nominal.mass, nominal.gravity, nominal.cg_height, f_x, f_y)

        static = quasi_static_loads(0.0, 0.0)
        self.static_load = static * cos_grade
        self.static_load_per_gravity = static / nominal.gravity
        # Unit moment distributions: Σ u = 0, Σ y u_roll = 1, Σ x u_pitch = 1 (equal springs, rigid body).
        self.roll_unit = yw / float(np.sum(yw**2))
        x_dev = xw - xw.mean()
        self.pitch_unit = x_dev / float(np.sum(x_dev**2))
        self.roll_stiffness, self.roll_damping = vehicle.roll_stiffness, vehicle.roll_damping
        self.pitch_stiffness, self.pitch_damping = vehicle.pitch_stiffness, vehicle.pitch_damping
        m_s, m_u, radius = vehicle.sprung_mass, vehicle.unsprung_mass, nominal.wheel_radius
        # Load sensitivity to the specific force (N per m/s²): instantaneous parts of the load transfer.
        if self.load_dynamics:
            # Links at the roll/pitch centres and the unsprung masses at the wheel centres.
            self.load_per_fx = -(m_s * vehicle.pitch_centre_height + m_u * radius) * self.pitch_unit
            self.load_per_fy = -(m_s * vehicle.roll_centre_height + m_u * radius) * self.roll_unit
        else:
            self.load_per_fx = quasi_static_loads(1.0, 0.0) - static
            self.load_per_fy = quasi_static_loads(0.0, 1.0) - static
        self.roll_drive = m_s * vehicle.roll_arm
        self.pitch_drive = m_s * vehicle.pitch_arm
        self.roll_axis_inertia = vehicle.roll_axis_inertia
        self.pitch_axis_inertia = vehicle.pitch_axis_inertia

        # Ground: surfaces under the wheels (the vehicle's own unless patched) and gravity on the slope.
        base = Surface(name="vehicle", friction=self.mu, rolling_resistance=self.rr)
        self.ground = GroundContact(
            effective_ground(scenario), base, effects.friction_change, xw, yw, p.gravity, effects.terrain_grade
        )
        self.turning_resistance = effects.turning_resistance
        self.inverse_turning_speed = 1.0 / TURNING_RESISTANCE_SPEED
        self.gravity_x = -self.grade_accel
        # The tire law: the plant's magic formula (stiffnesses C_x, C_α at m g / 6) or the brush (B.4).
        self.tire = (
            MagicFormulaWheels(vehicle.magic_formula, vehicle.nominal_wheel_load, self.cx, self.ca, 6)
            if self.magic_formula
            else None
        )

        # Bound on the fastest tire mode without relaxation, times the slip denominator (1/s · m/s): the
        # brush's V_r, or the magic formula's V (its stiffnesses bounded for loads up to twice F_z0).
        half_track2 = (0.5 * p.track) ** 2
        x2 = float(np.sum(xw**2))
        cx, ca = self.cx, self.ca
        if self.tire is not None:
            cx, ca = vehicle.magic_formula.max_stiffnesses(
                vehicle.nominal_wheel_load, self.cx, self.ca, 2.0 * vehicle.nominal_wheel_load
            )
        cx, ca = cx * self.ground.max_stiffness_scale, ca * self.ground.max_stiffness_scale
        self.stiffness_times_speed = (
            3.0 * p.wheel_radius**2 * cx / self.side_inertia
            + 6.0 * (cx + ca) / p.mass
            + (6.0 * cx * half_track2 + ca * x2) / p.yaw_inertia
        )

    def derivative(
        self, state: Array, wheel_torque: tuple[float, float], hold: tuple[float, float]
    ) -> tuple[Array, float, float, tuple[Any, ...]]:
        """Derivative of the state (the RK4 stage function).

        Args:
            state: the 26 states.
            wheel_torque: η i_g T_m per side (N·m at the wheel), held over the step.
            hold: specific force (f_x, f_y) used by the load transfer without tire
                relaxation (m/s²); with relaxation the loop is solved exactly.

        Returns:
            ``(derivative, f_x, f_y, forces)`` with f the specific force of the
            road frame (m/s²) and ``forces`` = (F_z, F_x, F_y, F_x,ss, F_y,ss,
            F_rr, v_x contact, v_y contact), each (6,), then μ (scalar or (6,))
            and g_n (m/s²).
        """
        x, y, yaw, vx, vy, r, omega_l, omega_r, _, _, roll, roll_rate, pitch, pitch_rate = state[:14].tolist()
        cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
        ground = self.ground
        mu: Any = self.mu
        scale: Any = 1.0
        rr: Any = self.rr
        if not ground.uniform:
            mu, scale, rr = ground.surfaces(x, y, cos_yaw, sin_yaw)
        if ground.level:
            gravity_x, gravity_y, normal_gravity = self.gravity_x, 0.0, self.normal_gravity
            static_load = self.static_load
        else:
            gravity_x, gravity_y, normal_gravity = ground.gravity(cos_yaw, sin_yaw)
            static_load = self.static_load_per_gravity * normal_gravity
        contact = self.contact_map @ np.array((vx, vy, r))
        cvx, cvy = contact[:6], contact[6:]
        omega = np.array((omega_l, omega_l, omega_l, omega_r, omega_r, omega_r))
        if self.load_dynamics:
            # Suspension springs and dampers; the links and unsprung masses add the f-dependent part below.
            load = (
                static_load
                - self.roll_unit * (self.roll_stiffness * roll + self.roll_damping * roll_rate)
                + self.pitch_unit * (self.pitch_stiffness * pitch + self.pitch_damping * pitch_rate)
            )
        else:
            load = static_load
        resistance_per_load = rr * np.tanh(cvx * self.inverse_rr_speed)
        derivative = np.zeros(_N_STATES)
        if self.relaxation:
            # The tire forces are states: solve the loop loads → motion resistance → f_x exactly (linear).
            fx, fy = state[_FX], state[_FY]
            load = load + self.load_per_fy * (float(np.sum(fy)) / self.mass)
            load_f_x = (float(np.sum(fx)) - float(resistance_per_load @ load)) / (
                self.mass + float(resistance_per_load @ self.load_per_fx)
            )
            load = np.maximum(load + self.load_per_fx * load_f_x, 0.0)
            steady_fx, steady_fy = self._tire_forces(omega, cvx, cvy, load, mu, scale)
            speed = np.maximum(np.maximum(self.radius * np.abs(omega), np.hypot(cvx, cvy)), self.relax_floor)
            derivative[_FX] = speed * (steady_fx - fx) * self.inverse_lx
            derivative[_FY] = speed * (steady_fy - fy) * self.inverse_ly
        else:
            hold_fx, hold_fy = hold
            load = np.maximum(load + self.load_per_fx * hold_fx + self.load_per_fy * hold_fy, 0.0)
            steady_fx, steady_fy = self._tire_forces(omega, cvx, cvy, load, mu, scale)
            fx, fy = steady_fx, steady_fy
        resistance = resistance_per_load * load
        lateral = fy
        if self.turning_resistance > 0.0:
            # Lateral soil resistance (effect turning_resistance): against each wheel's lateral sliding, ∝ its load.
            lateral = fy - self.turning_resistance * load * np.tanh(cvy * self.inverse_turning_speed)
        sum_fx, sum_fy, yaw_moment = (self.force_map @ np.concatenate((fx - resistance, lateral))).tolist()
        f_x = sum_fx / self.mass
        f_y = sum_fy / self.mass
        thrust_l, thrust_r = (self.side_map @ fx).tolist()
        if ground.level:
            accel_x, accel_y = f_x - self.grade_accel + vy * r, f_y - vx * r
        else:
            accel_x, accel_y = f_x + gravity_x + vy * r, f_y + gravity_y - vx * r
        derivative[:10] = (
            vx * cos_yaw - vy * sin_yaw,
            vx * sin_yaw + vy * cos_yaw,
            r,
            accel_x,
            accel_y,
            yaw_moment / self.yaw_inertia,
            (wheel_torque[0] - self.radius * thrust_l) / self.side_inertia,
            (wheel_torque[1] - self.radius * thrust_r) / self.side_inertia,
            omega_l,
            omega_r,
        )
        if self.load_dynamics:
            gn = normal_gravity
            derivative[_ROLL : _PITCH_RATE + 1] = (
                roll_rate,
                (
                    self.roll_drive * (f_y + gn * math.sin(roll))
                    - self.roll_stiffness * roll
                    - self.roll_damping * roll_rate
                )
                / self.roll_axis_inertia,
                pitch_rate,
                (
                    self.pitch_drive * (gn * math.sin(pitch) - f_x)
                    - self.pitch_stiffness * pitch
                    - self.pitch_damping * pitch_rate
                )
                / self.pitch_axis_inertia,
            )
        return derivative, f_x, f_y, (load, fx, fy, steady_fx, steady_fy, resistance, cvx, cvy, mu, normal_gravity)

    def _tire_forces(
        self, omega: Array, cvx: Array, cvy: Array, load: Array, mu: Any, scale: Any
    ) -> tuple[Array, Array]:
        """Steady forces (F_x, F_y) of the vehicle's tire law per wheel (N); μ, scale scalars or per wheel."""
        if self.tire is not None:
            return self.tire.forces(self.radius * omega, cvx, cvy, load, mu, scale)
        sigma_x, sigma_y = theoretical_slips(omega, cvx, cvy, self.params)
        return brush_forces(
            sigma_x,
            sigma_y,
            load,
            longitudinal_stiffness=self.cx * scale,
            cornering_stiffness=self.ca * scale,
            friction=mu,
        )

    def evaluate(self, state: Array, wheel_torque: tuple[float, float], hold: tuple[float, float]) -> _Evaluation:
        """:meth:`derivative` with its intermediate forces named (for the sensors and the truth)."""
        derivative, f_x, f_y, forces = self.derivative(state, wheel_torque, hold)
        load, fx, fy, steady_fx, steady_fy, resistance, cvx, cvy, mu, normal_gravity = forces
        return _Evaluation(
            derivative=derivative,
            normal_load=load,
            tire_force_x=np.array(fx, dtype=float),
            tire_force_y=np.array(fy, dtype=float),
            steady_tire_force_x=steady_fx,
            steady_tire_force_y=steady_fy,
            motion_resistance=resistance,
            friction=np.broadcast_to(np.asarray(mu, dtype=float), (6,)).copy(),
            contact_vx=cvx.copy(),
            contact_vy=cvy.copy(),
            specific_force_x=f_x,
            specific_force_y=f_y,
            normal_gravity=float(normal_gravity),
        )

    def stiff_substeps(self, state: Array, period: float) -> int:
        """RK4 steps per period that keep λ_max Δt ≤ 2 for the instantaneous (unrelaxed) tire model.

        λ_max ≈ (3R²C_x/I_side + 6(C_x + C_α)/m + (6C_x B²/4 + C_α Σx_i²)/I_z) / V_r
        bounds the slip-stiffness eigenvalues (Gershgorin); V_r is the smallest
        side rolling speed, halved for the speed change within the period. For
        the magic formula V_r is its slip denominator max(|v_x|, V_low) at the
        slowest contact and C_x, C_α its largest stiffnesses (loads up to 2 F_z0,
        the stiffest surface).
        """
        if self.relaxation:
            return 1
        if self.tire is not None:
            # The magic formula's slip denominator: the contact speed, floored at V_low.
            contact_vx = self.contact_map[:6] @ state[_VX : _R + 1]
            floor = self.tire.tire.low_speed
            rolling = max(0.5 * float(np.min(np.abs(contact_vx))), floor)
        else:
            omega_min = min(abs(float(state[_OMEGA_L])), abs(float(state[_OMEGA_R])))
            rolling = max(0.5 * self.radius * omega_min, self.params.rolling_speed_floor)
        rate = self.stiffness_times_speed / rolling
        return min(_MAX_SUBSTEPS, math.ceil(rate * period / _STIFF_STEP_LIMIT))


def _rk4(
    equations: _EquationsOfMotion,
    state: Array,
    wheel_torque: tuple[float, float],
    hold: tuple[float, float],
    dt: float,
    steps: int,
) -> tuple[Array, tuple[float, float]]:
    """``steps`` classical RK4 steps of ``dt``; returns the state and the updated load-transfer hold."""
    half = 0.5 * dt
    sixth = dt / 6.0
    for _ in range(steps):
        k1, f_x, f_y, _ = equations.derivative(state, wheel_torque, hold)
        hold = (f_x, f_y)
        k2 = equations.derivative(state + half * k1, wheel_torque, hold)[0]
        k3 = equations.derivative(state + half * k2, wheel_torque, hold)[0]
        k4 = equations.derivative(state + dt * k3, wheel_torque, hold)[0]
        state = state + sixth * (k1 + 2.0 * (k2 + k3) + k4)
    return state, hold
