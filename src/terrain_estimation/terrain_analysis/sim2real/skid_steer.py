"""Replay model of a skid-steered vehicle for the sim-to-real attribution (issue 6).

Open-loop replay on the bag's inputs
    A dynamic replay driven by the motor torques drifts (the wheel/ground
    traction balance is integrated open loop). Instead the body is driven by
    the *measured wheel speeds*: the planar body states vx, vy, r (and, with
    ``load_transfer_dynamics``, the sprung-mass roll and pitch; with
    ``tire_relaxation``, the per-wheel tire forces) integrate under the brush
    tire forces (MODELS.md B.4) that the slips implied by the measured wheel
    speeds and the replayed body state give. These are exactly the equations
    of the truth plant (:class:`vehicle_sim.plants.skid_steer._EquationsOfMotion`)
    without its wheel-side rotational dynamics (their output, the wheel speed,
    is measured)::

        m (v̇x − vy r) = Σ (F_x − F_rr) + m g_bx(ψ)          (ground slope, effect terrain_grade)
        m (v̇y + vx r) = Σ (F_y + F_b) + m g_by(ψ)          (F_b: effect turning_resistance)
        I_z ṙ         = Σ x_i (F_y,i + F_b,i) − y_i (F_x,i − F_rr,i)
        ψ̇ = r
        σ_x = (R ω − v_x,i)/V_r,  σ_y = −v_y,i/V_r,  V_r = max(R|ω|, ε)     (B.4)
        F_rr,i = f_rr F_z,i tanh(v_x,i / v_rr)                             (motion resistance)
        F_z = quasi-static equal-spring loads (B.5) from the specific force
              of the previous RK4 stage (the plant's one-step hold), or, with
              load-transfer dynamics, static loads ∓ suspension roll/pitch
              moments (K φ + C φ̇) plus the link and unsprung-mass parts
        Ḟ = (V/L)(F_ss − F)   (tire relaxation only)

    Predicted channels: what the IMU at the centre reads, noise free
    (specific force x, y, z in m/s², yaw rate in rad/s; with load-transfer
    dynamics rotated into the tilted body frame with the lever-arm terms of
    the plant's ``_measure``). The roll and pitch gyros (angular_velocity.x,
    .y) are compared too when the IMU measures them (covariance not −1) and
    the vehicle has a suspension: the nominal rigid body predicts 0, the
    sprung mass of ``load_transfer_dynamics`` its roll and pitch rates, the
    effect's most direct signature (without these channels it showed only
    through the tilt of the specific force, and 5 of 6 withheld bags read
    "no significant gap"). Integration: classical RK4, ``substeps`` per
    sensor period (2 ms as the plant), raised where the slip dynamics are
    stiff (λ_max Δt ≤ 2 as the plant), the wheel speed linear in time between
    samples.

Wheel speeds
    ``joint_states`` velocity is motor side (rad/s); wheel = motor / i_g.
    A drive that reports the speed as the difference of encoder positions
    over the last period gives the mean over that period, i.e. the speed half
    a period earlier: the speed at an IMU stamp t_k is the mean of the reports
    at t_k and t_k + T (``wheel_speed_timing = "period_mean"``, the
    simulator's and most drives' convention), or the report itself
    (``"instantaneous"``). Joint reports are interpolated linearly to the
    IMU stamps.

Effects (all of :data:`vehicle_sim.effects.CATALOGUE` ``["skid_steer"]``,
the same physics as :class:`vehicle_sim.plants.skid_steer.SkidSteerEffects`,
written separately)
    Sensors (post-processing of the replayed IMU, :class:`Sensing`; cached
    replays, so fitting them costs almost nothing): ``gyro_bias`` per axis
    (z; x, y where the roll/pitch gyros are compared), ``accel_bias`` and
    ``accel_scale`` per axis, ``gyro_scale`` (yaw), reading = (1 + s) × true
    + b. Stream delays: ``sensor_delay`` (IMU stream: its reading stamped t
    is the replay's at t − d) and ``wheel_speed_delay`` (encoder stream: the
    replay driven by counts of t − d predicts at t what belongs at t + d):
    both shift the prediction (linear interpolation), by d_imu − d_wheel;
    a bag shows only that difference, each effect names the stream that is
    late. With ``wheel_speed_delay`` offered, the last 0.3 s (its upper
    bound) are left out of every fit and score (:attr:`SkidSteerReplay.valid`):
    no model can predict IMU samples whose wheel speeds the bag lacks.
    Physics (a re-run of the replay): ``wheel_radius_error`` (R(1 + e) in
    the slips), ``friction_change`` (μ × factor),
    ``cornering_stiffness_change`` (C_α × factor), ``load_transfer_dynamics``
    (switch), ``tire_relaxation`` (switch), ``terrain_grade`` (a ground plane
    fixed in the world, grade γ and bank β at the start heading: gravity in
    the plane's axes g_p = −g (sin γ, cos γ sin β, ·), turned into the body
    frame by the replay's own heading ψ = ∫ r dt, g_bx = g_px cos ψ +
    g_py sin ψ, g_by = −g_px sin ψ + g_py cos ψ; loads and IMU z carry
    g_n = g cos γ cos β), ``turning_resistance`` (lateral soil resistance
    F_b,i = −c_b F_z,i tanh(v_y,i / 0.05 m/s) added to each wheel's lateral
    force: a resistive yaw moment in skid-steer turns).

    A bank and an accelerometer bias (y, z) read the same at the IMU when
    the heading does not change: g sin β on y and g (cos β − 1) on z. The
    bank also needs lateral tire forces and shifts the loads across the
    track, but at the simulator's stiffnesses that changes the yaw rate by
    less than the gyro noise; on a straight run the two are indistinguishable
    (the engine says so). Once the vehicle turns, a world-fixed slope turns
    in the body frame (g sin β cos ψ on y, g sin β sin ψ on x) and a bias
    does not: the bank is identified.

Nuisance parameters
    None by default: the initial state comes from the first wheel speeds
    (vx = R(ω_l + ω_r)/2, r = R(ω_r − ω_l)/B, vy = 0, forces and attitude 0)
    and the first ``warmup`` seconds are left out. A vehicle whose tire
    parameters are not known (the Husky) passes ``nuisance`` names of
    :data:`NUISANCE` (scale factors of C_x, C_α, μ, f_rr, I_z).

Noise budget σ per channel
    Sensor noise from the config (``sensors.accel_noise_std``,
    ``sensors.gyro_noise_std``) plus what the wheel-speed errors do through
    the replay: the replay is re-run with the joint reports perturbed as a
    drive reports them (a difference of positions quantised to the encoder
    step over the report period, (u_k − u_(k−1))/T with u ~ U(0, step), plus
    ``sensors.motor_velocity_noise_std``; or a quantised speed), at the
    reports' own times and through the same interpolation, and the RMS change
    of each channel is added in quadrature. Measured on the simulator
    (noise-free sensors, real quantisation): the quantisation costs ax
    0.016–0.019 m/s² RMS on the straight run where this estimate gives 0.011
    (the actual error is a speed-dependent pattern, not white noise, and the
    replay's gain rises with frequency), i.e. the ax budget is ≈ 2–4 % low in
    σ on the straight run and the turn; the noise tests' power floor (1.25)
    covers it.
    The replay's own error (linear wheel speed within a period instead of the
    plant's wheel dynamics) is 0.006–0.007 m/s² RMS on ax and below 1e-4 rad/s
    on the yaw rate (test_sim2real_skid_steer).

Units SI throughout (m, s, rad, N, kg).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import Candidate, Channel, FitParameter, StampOrigin, candidates_from_catalogue
from terrain_analysis.sim2real.where import Sim2RealError
from terrain_estimation.bag import bag_topics
from terrain_estimation.jit import compiled

__all__ = [
    "NUISANCE",
    "ReplayVehicle",
    "SkidSteerBagData",
    "SkidSteerReplay",
    "build_model",
    "equal_spring_loads",
    "read_skid_steer_bag",
    "replay_imu",
    "vehicle_from_config",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[str], None] | None

#: Nuisance parameters a replay can fit: name → (unit, bounds, scale, description). Off/start value 1 (scale
#: factors of the config value) except rolling_resistance (absolute, start at the config value).
NUISANCE: Mapping[str, tuple[str, tuple[float, float], float, str]] = {
    "longitudinal_stiffness_scale": ("–", (0.05, 10.0), 0.3, "C_x = config C_x × scale"),
    "cornering_stiffness_scale": ("–", (0.05, 10.0), 0.3, "C_α = config C_α × scale (nuisance, not the effect)"),
    "friction_scale": ("–", (0.2, 3.0), 0.2, "μ = config μ × scale"),
    "rolling_resistance": ("–", (0.0, 0.3), 0.02, "motion-resistance coefficient f_rr"),
    "yaw_inertia_scale": ("–", (0.3, 3.0), 0.3, "I_z = config I_z × scale"),
}

_SWITCHES = ("load_transfer_dynamics", "tire_relaxation")


# ---------------------------------------------------------------------------
# Vehicle
# ---------------------------------------------------------------------------


def equal_spring_loads(
    axle_x: FloatArray, track: float, mass: float, gravity: float, cg_height: float, ax: float, ay: float
) -> FloatArray:
    """Quasi-static wheel loads of a rigid body on equal virtual springs (MODELS.md B.5), any number of axles.

    Axle loads ``F_i = p + q x_i`` with ``n p + q Σx = m g`` and
    ``p Σx + q Σx² = −m a_x H``; lateral transfer ``m a_y H / B`` split
    equally over the axles. Wheel order: left wheels front to rear, then the
    right wheels. Not floored (the replay floors after adding the transfers).
    For three axles this is :func:`terrain_estimation.models.skid_steer.quasi_static_loads`.

    Returns:
        F_z per wheel (N), shape (2 n_axles,).
    """
    xa = np.asarray(axle_x, dtype=float)
    n = len(xa)
    s1, s2 = float(np.sum(xa)), float(np.sum(xa**2))
    d = n * s2 - s1**2
    p0 = mass * (gravity * s2 + ax * cg_height * s1) / d
    q = -mass * (n * ax * cg_height + gravity * s1) / d
    axle = p0 + q * xa
    lateral = mass * ay * cg_height / (n * track)
    return np.concatenate([0.5 * axle - lateral, 0.5 * axle + lateral])


@dataclass(frozen=True)
class ReplayVehicle:
    """What the replay needs of a skid-steered vehicle (any number of axles, one drive per side).

    Attributes:
        name: for the report.
        mass, yaw_inertia, gravity: m (kg), I_z (kg·m²), g (m/s²).
        axle_x: axle positions relative to the CM, front to rear (m).
        track: B (m), wheels at y = ±B/2.
        cg_height: H (m), for the quasi-static loads.
        wheel_radius: R (m); transmission_ratio: motor → wheel i_g.
        longitudinal_stiffness, cornering_stiffness, friction: brush C_x (N),
            C_α (N/rad), μ per wheel; rolling_speed_floor: ε (m/s).
        rolling_resistance: f_rr; rolling_resistance_speed: v_rr (m/s).
        suspension: sprung-mass data for ``load_transfer_dynamics`` or None
            (no suspension: the effect is not offered).
        longitudinal_relaxation_length, lateral_relaxation_length: L_x, L_y (m);
            relaxation_speed_floor (m/s).
        accel_noise_std, gyro_noise_std: IMU noise σ (m/s², rad/s).
        wheel_speed_noise_std: σ of the white noise on a reported *wheel-side* speed (rad/s).
        encoder_step: motor-side encoder quantum (rad) when the reported speed is
            the difference of quantised positions over the report period (0: not).
        speed_step: quantum of the reported wheel-side speed itself (rad/s; 0: not quantised).
    """

    name: str
    mass: float
    yaw_inertia: float
    gravity: float
    axle_x: tuple[float, ...]
    track: float
    cg_height: float
    wheel_radius: float
    transmission_ratio: float
    longitudinal_stiffness: float
    cornering_stiffness: float
    friction: float
    rolling_speed_floor: float
    rolling_resistance: float
    rolling_resistance_speed: float
    suspension: Suspension | None
    longitudinal_relaxation_length: float
    lateral_relaxation_length: float
    relaxation_speed_floor: float
    accel_noise_std: float
    gyro_noise_std: float
    wheel_speed_noise_std: float
    encoder_step: float = 0.0
    speed_step: float = 0.0

    @property
    def n_axles(self) -> int:
        return len(self.axle_x)

    def wheel_positions(self) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """(x, y, side) of every wheel: left side front to rear, then right (side 0 = left)."""
        xa = np.asarray(self.axle_x, dtype=float)
        n = len(xa)
        half = 0.5 * self.track
        return (
            np.concatenate([xa, xa]),
            np.concatenate([np.full(n, half), np.full(n, -half)]),
            np.concatenate([np.zeros(n, dtype=np.int64), np.ones(n, dtype=np.int64)]),
        )


@dataclass(frozen=True)
class Suspension:
    """Sprung-mass roll/pitch model of the plant (SkidSteerVehicle), for ``load_transfer_dynamics``.

    Attributes:
        sprung_mass: m_s (kg); unsprung_mass: total 2 n m_u (kg).
        roll_centre_height, pitch_centre_height: h_rc, h_pc (m).
        roll_arm, pitch_arm: H_s − h_rc, H_s − h_pc (m).
        roll_axis_inertia, pitch_axis_inertia: about the roll/pitch axes (kg·m²).
        roll_stiffness, roll_damping, pitch_stiffness, pitch_damping: K, C (N·m/rad, N·m·s/rad).
    """

    sprung_mass: float
    unsprung_mass: float
    roll_centre_height: float
    pitch_centre_height: float
    roll_arm: float
    pitch_arm: float
    roll_axis_inertia: float
    pitch_axis_inertia: float
    roll_stiffness: float
    roll_damping: float
    pitch_stiffness: float
    pitch_damping: float


def vehicle_from_config(config: str | Path | None = None) -> ReplayVehicle:
    """The 6-wheel skid steer from ``config/skid_steer.yaml`` (or ``config``): vehicle, plant and sensor sections.

    Uses the simulator's own parameter resolution and scenario builder, so the
    replay runs on exactly the plant the config describes (its ``effects.*``
    are ignored: the replay's nominal model has every catalogue effect off).
    """
    from vehicle_sim.ros.registry import get_simulator, simulator_parameters
    from vehicle_sim.ros.skid_steer import make_scenario

    entry = get_simulator("skid_steer")
    values = simulator_parameters(entry, config)
    scenario = make_scenario(values)
    v = scenario.vehicle
    p = v.nominal
    s = scenario.sensors
    from terrain_estimation.models.skid_steer import axle_positions

    step = 2.0 * math.pi / s.encoder_counts_per_revolution
    return ReplayVehicle(
        name="skid_steer",
        mass=p.mass,
        yaw_inertia=p.yaw_inertia,
        gravity=p.gravity,
        axle_x=tuple(float(x) for x in axle_positions(p)),
        track=p.track,
        cg_height=p.cg_height,
        wheel_radius=p.wheel_radius,
        transmission_ratio=p.transmission_ratio,
        longitudinal_stiffness=p.longitudinal_stiffness,
        cornering_stiffness=p.cornering_stiffness,
        friction=p.friction,
        rolling_speed_floor=p.rolling_speed_floor,
        rolling_resistance=v.rolling_resistance,
        rolling_resistance_speed=v.rolling_resistance_speed,
        suspension=Suspension(
            sprung_mass=v.sprung_mass,
            unsprung_mass=v.unsprung_mass,
            roll_centre_height=v.roll_centre_height,
            pitch_centre_height=v.pitch_centre_height,
            roll_arm=v.roll_arm,
            pitch_arm=v.pitch_arm,
            roll_axis_inertia=v.roll_axis_inertia,
            pitch_axis_inertia=v.pitch_axis_inertia,
            roll_stiffness=v.roll_stiffness,
            roll_damping=v.roll_damping,
            pitch_stiffness=v.pitch_stiffness,
            pitch_damping=v.pitch_damping,
        ),
        longitudinal_relaxation_length=v.longitudinal_relaxation_length,
        lateral_relaxation_length=v.lateral_relaxation_length,
        relaxation_speed_floor=v.relaxation_speed_floor,
        accel_noise_std=s.accel_noise_std,
        gyro_noise_std=s.gyro_noise_std,
        wheel_speed_noise_std=s.motor_velocity_noise_std / p.transmission_ratio,
        encoder_step=step,
    )


# ---------------------------------------------------------------------------
# The replay kernel (numba)
# ---------------------------------------------------------------------------

# Indices of the scalar parameter vector of the kernel.
_P_RADIUS, _P_CX, _P_CA, _P_MU, _P_FLOOR, _P_MASS, _P_IZ, _P_RR, _P_INV_RRV = range(9)
_P_GPX, _P_GN, _P_RELAX, _P_INV_LX, _P_INV_LY, _P_RELAX_FLOOR, _P_LOADDYN = range(9, 16)
_P_KR, _P_CR, _P_KP, _P_CP, _P_ROLL_DRIVE, _P_PITCH_DRIVE, _P_IR, _P_IP, _P_ROLL_ARM, _P_PITCH_ARM = range(16, 26)
_P_GPY, _P_BULL, _P_INV_VB = range(26, 29)
_N_P = 29
#: Lateral contact speed over which the soil's lateral resistance (turning_resistance) builds up (m/s): the
#: catalogue's stated form F_b = −c_b F_z tanh(v_y / 0.05 m/s).
TURNING_RESISTANCE_SPEED = 0.05


@compiled
def _derivative(s, oml, omr, hfx, hfy, p, wx, wy, side, static, lpfx, lpfy, ru, pu, out, work):
    """State derivative (into ``out``); returns (f_x, f_y, roll accel, pitch accel). Plant's equations.

    State: vx, vy, r, roll, roll rate, pitch, pitch rate, lagged F_x (n), F_y (n), heading ψ from the start.
    Gravity in the body frame: the plane's (g_px, g_py) at the start heading turned by ψ.
    """
    n = wx.shape[0]
    vx, vy, r = s[0], s[1], s[2]
    heading = s[7 + 2 * n]
    ch = math.cos(heading)
    sh = math.sin(heading)
    gbx = p[_P_GPX] * ch + p[_P_GPY] * sh
    gby = -p[_P_GPX] * sh + p[_P_GPY] * ch
    roll, roll_rate, pitch, pitch_rate = s[3], s[4], s[5], s[6]
    radius, cx, ca, mu, floor = p[_P_RADIUS], p[_P_CX], p[_P_CA], p[_P_MU], p[_P_FLOOR]
    mass = p[_P_MASS]
    relax = p[_P_RELAX] > 0.5
    loaddyn = p[_P_LOADDYN] > 0.5
    cvx = work[0]
    cvy = work[1]
    sx = work[2]
    sy = work[3]
    load = work[4]
    rpl = work[5]
    om = work[6]
    for i in range(n):
        cvx[i] = vx - wy[i] * r
        cvy[i] = vy + wx[i] * r
        om[i] = oml if side[i] == 0 else omr
        rolling = radius * om[i]
        vr = max(abs(rolling), floor)
        sx[i] = (rolling - cvx[i]) / vr
        sy[i] = -cvy[i] / vr
        base = static[i]
        if loaddyn:
            base += -ru[i] * (p[_P_KR] * roll + p[_P_CR] * roll_rate) + pu[i] * (
                p[_P_KP] * pitch + p[_P_CP] * pitch_rate
            )
        load[i] = base
        rpl[i] = p[_P_RR] * math.tanh(cvx[i] * p[_P_INV_RRV])
    fx = work[7]
    fy = work[8]
    if relax:
        sum_fx = 0.0
        sum_fy = 0.0
        for i in range(n):
            fx[i] = s[7 + i]
            fy[i] = s[7 + n + i]
            sum_fx += fx[i]
            sum_fy += fy[i]
        num = sum_fx
        den = mass
        for i in range(n):
            load[i] += lpfy[i] * (sum_fy / mass)
        for i in range(n):
            num -= rpl[i] * load[i]
            den += rpl[i] * lpfx[i]
        load_fx = num / den
        for i in range(n):
            load[i] = max(load[i] + lpfx[i] * load_fx, 0.0)
    else:
        for i in range(n):
            load[i] = max(load[i] + lpfx[i] * hfx + lpfy[i] * hfy, 0.0)
    for i in range(n):
        # Brush model (B.4), the closed form of terrain_estimation.models.skid_steer.brush_tire_forces.
        cx_sx = cx * sx[i]
        ca_sy = ca * sy[i]
        mu_fz = mu * load[i]
        gamma = math.hypot(cx_sx, ca_sy)
        limit = 3.0 * mu_fz
        if gamma > 0.0 and limit > 0.0:
            t = min(gamma, limit) / limit
            scale = mu_fz * t * (3.0 - 3.0 * t + t * t) / gamma
        else:
            scale = 0.0
        ssx = cx_sx * scale
        ssy = ca_sy * scale
        if relax:
            speed = max(max(radius * abs(om[i]), math.hypot(cvx[i], cvy[i])), p[_P_RELAX_FLOOR])
            out[7 + i] = speed * (ssx - fx[i]) * p[_P_INV_LX]
            out[7 + n + i] = speed * (ssy - fy[i]) * p[_P_INV_LY]
        else:
            fx[i] = ssx
            fy[i] = ssy
            out[7 + i] = 0.0
            out[7 + n + i] = 0.0
    sum_x = 0.0
    sum_y = 0.0
    moment = 0.0
    bull = p[_P_BULL]
    for i in range(n):
        net_x = fx[i] - rpl[i] * load[i]
        lateral = fy[i]
        if bull > 0.0:
            # turning_resistance: the soil's lateral resistance against the wheel's lateral sliding, ∝ its load.
            lateral -= bull * load[i] * math.tanh(cvy[i] * p[_P_INV_VB])
        sum_x += net_x
        sum_y += lateral
        moment += wx[i] * lateral - wy[i] * net_x
    f_x = sum_x / mass
    f_y = sum_y / mass
    out[0] = f_x + gbx + vy * r
    out[1] = f_y + gby - vx * r
    out[2] = moment / p[_P_IZ]
    out[7 + 2 * n] = r
    roll_acc = 0.0
    pitch_acc = 0.0
    if loaddyn:
        gn = p[_P_GN]
        roll_acc = (p[_P_ROLL_DRIVE] * (f_y + gn * math.sin(roll)) - p[_P_KR] * roll - p[_P_CR] * roll_rate) / p[_P_IR]
        pitch_acc = (p[_P_PITCH_DRIVE] * (gn * math.sin(pitch) - f_x) - p[_P_KP] * pitch - p[_P_CP] * pitch_rate) / p[
            _P_IP
        ]
        out[3] = roll_rate
        out[4] = roll_acc
        out[5] = pitch_rate
        out[6] = pitch_acc
    else:
        out[3] = 0.0
        out[4] = 0.0
        out[5] = 0.0
        out[6] = 0.0
    return f_x, f_y, roll_acc, pitch_acc


@compiled
def _imu(s, f_x, f_y, roll_acc, pitch_acc, p, out_row):
    """Noise-free IMU (f_x, f_y, f_z, ω_x, ω_y, ω_z) of the plant's ``_measure`` (tilted body with lever arms)."""
    roll, roll_rate, pitch, pitch_rate = s[3], s[4], s[5], s[6]
    r = s[2]
    d_r, d_p = p[_P_ROLL_ARM], p[_P_PITCH_ARM]
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    road_x = f_x + d_p * (cp * pitch_acc - sp * pitch_rate**2)
    road_y = f_y - d_r * (cr * roll_acc - sr * roll_rate**2)
    road_z = p[_P_GN] - d_r * (sr * roll_acc + cr * roll_rate**2) - d_p * (sp * pitch_acc + cp * pitch_rate**2)
    px = cp * road_x - sp * road_z
    pz = sp * road_x + cp * road_z
    out_row[0] = px
    out_row[1] = cr * road_y + sr * pz
    out_row[2] = -sr * road_y + cr * pz
    out_row[3] = roll_rate - sp * r
    out_row[4] = cr * pitch_rate + sr * cp * r
    out_row[5] = -sr * pitch_rate + cr * cp * r


@compiled
def _replay_kernel(t, omega, x0, p, wx, wy, side, static, lpfx, lpfy, ru, pu, base_dt, stiff_rate):
    """RK4 replay over the sample times ``t`` (M,) with wheel speeds ``omega`` (M, 2); IMU (M, 6) at every sample.

    Wheel speeds are linear in time between samples. Steps per interval: enough for ``base_dt``, raised to keep
    λ_max Δt ≤ 2 with λ_max = stiff_rate / V_r (the plant's stiffness bound without the wheel term).
    The load-transfer hold is the specific force of the first RK4 stage (the plant's rule).
    """
    m = t.shape[0]
    n = wx.shape[0]
    size = 8 + 2 * n
    s = np.zeros(size)
    for i in range(x0.shape[0]):
        s[i] = x0[i]
    out = np.empty((m, 6))
    k1 = np.empty(size)
    k2 = np.empty(size)
    k3 = np.empty(size)
    k4 = np.empty(size)
    tmp = np.empty(size)
    work = np.empty((9, n))
    hfx = 0.0
    hfy = 0.0
    # Initial reading.
    f_x, f_y, ra, pa = _derivative(
        s, omega[0, 0], omega[0, 1], hfx, hfy, p, wx, wy, side, static, lpfx, lpfy, ru, pu, k1, work
    )
    hfx, hfy = f_x, f_y
    _imu(s, f_x, f_y, ra, pa, p, out[0])
    radius = p[_P_RADIUS]
    floor = p[_P_FLOOR]
    relax = p[_P_RELAX] > 0.5
    for k in range(m - 1):
        dt_total = t[k + 1] - t[k]
        steps = max(1, int(math.ceil(dt_total / base_dt - 1e-9)))
        if not relax:
            om_min = min(min(abs(omega[k, 0]), abs(omega[k, 1])), min(abs(omega[k + 1, 0]), abs(omega[k + 1, 1])))
            rolling = max(radius * om_min, floor)
            stiff = int(math.ceil(stiff_rate / rolling * dt_total / 2.0))
            steps = max(steps, min(stiff, 400))
        h = dt_total / steps
        for j in range(steps):
            a0 = j / steps
            a1 = (j + 0.5) / steps
            a2 = (j + 1.0) / steps
            oml0 = omega[k, 0] + a0 * (omega[k + 1, 0] - omega[k, 0])
            omr0 = omega[k, 1] + a0 * (omega[k + 1, 1] - omega[k, 1])
            oml1 = omega[k, 0] + a1 * (omega[k + 1, 0] - omega[k, 0])
            omr1 = omega[k, 1] + a1 * (omega[k + 1, 1] - omega[k, 1])
            oml2 = omega[k, 0] + a2 * (omega[k + 1, 0] - omega[k, 0])
            omr2 = omega[k, 1] + a2 * (omega[k + 1, 1] - omega[k, 1])
            f_x, f_y, ra, pa = _derivative(
                s, oml0, omr0, hfx, hfy, p, wx, wy, side, static, lpfx, lpfy, ru, pu, k1, work
            )
            hfx, hfy = f_x, f_y
            for i in range(size):
                tmp[i] = s[i] + 0.5 * h * k1[i]
            _derivative(tmp, oml1, omr1, hfx, hfy, p, wx, wy, side, static, lpfx, lpfy, ru, pu, k2, work)
            for i in range(size):
                tmp[i] = s[i] + 0.5 * h * k2[i]
            _derivative(tmp, oml1, omr1, hfx, hfy, p, wx, wy, side, static, lpfx, lpfy, ru, pu, k3, work)
            for i in range(size):
                tmp[i] = s[i] + h * k3[i]
            _derivative(tmp, oml2, omr2, hfx, hfy, p, wx, wy, side, static, lpfx, lpfy, ru, pu, k4, work)
            for i in range(size):
                s[i] += h / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])
        f_x, f_y, ra, pa = _derivative(
            s, omega[k + 1, 0], omega[k + 1, 1], hfx, hfy, p, wx, wy, side, static, lpfx, lpfy, ru, pu, k1, work
        )
        _imu(s, f_x, f_y, ra, pa, p, out[k + 1])
        if not math.isfinite(out[k + 1, 0] + out[k + 1, 1] + out[k + 1, 5]):
            out[k + 1 :, :] = 0.0
            return out, False
    return out, True


@dataclass(frozen=True)
class Physics:
    """Physical values one replay runs with (nominal config changed by effects and nuisance)."""

    wheel_radius_error: float = 0.0
    friction_factor: float = 1.0
    cornering_factor: float = 1.0
    longitudinal_factor: float = 1.0
    yaw_inertia_factor: float = 1.0
    rolling_resistance: float | None = None
    terrain_grade: float = 0.0
    terrain_bank: float = 0.0
    turning_resistance: float = 0.0
    load_transfer_dynamics: bool = False
    tire_relaxation: bool = False


@dataclass(frozen=True)
class Sensing:
    """What the sensors do to the replayed IMU (post-processing: no replay is re-run).

    Attributes:
        shift: IMU stream delay minus wheel-encoder stream delay (s). The IMU
            reading stamped t is the replay's at t − d_imu; a replay driven by
            encoder counts of t − d_wheel predicts at t what happened at
            t − d_wheel, i.e. its prediction belongs at t + d_wheel. Both are a
            shift of the prediction by ``shift`` (linear interpolation; the
            first/last prediction held beyond the ends).
        scale: scale-factor errors of (f_x, f_y, f_z, ω_x, ω_y, ω_z): reading = (1 + s) × true.
        bias: biases of the same six (added after the scale).
    """

    shift: float = 0.0
    scale: FloatArray = field(default_factory=lambda: np.zeros(6))
    bias: FloatArray = field(default_factory=lambda: np.zeros(6))

    def apply(self, t: FloatArray, imu: FloatArray) -> FloatArray:
        """The sensed IMU (M, 6) from the replay's true one at the sample times ``t``."""
        if self.shift != 0.0:
            out = np.column_stack([np.interp(t - self.shift, t, imu[:, j]) for j in range(imu.shape[1])])
        else:
            out = imu.copy()
        if np.any(self.scale):
            out *= 1.0 + self.scale
        out += self.bias
        return out


def replay_imu(
    vehicle: ReplayVehicle,
    t: FloatArray,
    omega: FloatArray,
    physics: Physics = Physics(),
    *,
    integration_step: float = 2.0e-3,
    initial_state: FloatArray | None = None,
) -> FloatArray:
    """Noise-free IMU readings (M, 6): f_x, f_y, f_z (m/s²), ω_x, ω_y, ω_z (rad/s) replayed on the wheel speeds.

    Args:
        vehicle: the vehicle.
        t: sample times (s), increasing, (M,).
        omega: wheel-side speeds (left, right) at ``t`` (rad/s), (M, 2).
        physics: effects and nuisance values.
        integration_step: largest RK4 step (s).
        initial_state: (vx, vy, r) at t[0]; default from the first wheel speeds.
    """
    radius = vehicle.wheel_radius * (1.0 + physics.wheel_radius_error)
    xw, yw, side = vehicle.wheel_positions()
    xa = np.asarray(vehicle.axle_x, dtype=float)
    m, g, h = vehicle.mass, vehicle.gravity, vehicle.cg_height
    # The ground plane (grade, bank at the start heading; SkidSteerGround's rotation order: grade about y, then
    # bank about the new x): gravity in its axes, the normal part constant whatever the heading.
    cg, sg = math.cos(physics.terrain_grade), math.sin(physics.terrain_grade)
    cb, sb = math.cos(physics.terrain_bank), math.sin(physics.terrain_bank)
    cos_grade = cg * cb  # g_n / g
    static = equal_spring_loads(xa, vehicle.track, m, g, h, 0.0, 0.0)
    susp = vehicle.suspension
    load_dyn = physics.load_transfer_dynamics and susp is not None
    n_wheels = len(xw)
    roll_unit = yw / float(np.sum(yw**2))
    x_dev = xw - xw.mean()
    pitch_unit = x_dev / float(np.sum(x_dev**2))
    if load_dyn:
        assert susp is not None
        unsprung = susp.unsprung_mass
        lpfx = -(susp.sprung_mass * susp.pitch_centre_height + unsprung * vehicle.wheel_radius) * pitch_unit
        lpfy = -(susp.sprung_mass * susp.roll_centre_height + unsprung * vehicle.wheel_radius) * roll_unit
    else:
        lpfx = equal_spring_loads(xa, vehicle.track, m, g, h, 1.0, 0.0) - static
        lpfy = equal_spring_loads(xa, vehicle.track, m, g, h, 0.0, 1.0) - static
    cx = vehicle.longitudinal_stiffness * physics.longitudinal_factor
    ca = vehicle.cornering_stiffness * physics.cornering_factor
    mu = vehicle.friction * physics.friction_factor
    iz = vehicle.yaw_inertia * physics.yaw_inertia_factor
    rr = vehicle.rolling_resistance if physics.rolling_resistance is None else physics.rolling_resistance
    p = np.zeros(_N_P)
    p[_P_RADIUS], p[_P_CX], p[_P_CA], p[_P_MU], p[_P_FLOOR] = radius, cx, ca, mu, vehicle.rolling_speed_floor
    p[_P_MASS], p[_P_IZ], p[_P_RR], p[_P_INV_RRV] = m, iz, rr, 1.0 / vehicle.rolling_resistance_speed
    p[_P_GPX], p[_P_GPY], p[_P_GN] = -g * sg, -g * cg * sb, g * cos_grade
    p[_P_BULL], p[_P_INV_VB] = physics.turning_resistance, 1.0 / TURNING_RESISTANCE_SPEED
    p[_P_RELAX] = 1.0 if physics.tire_relaxation else 0.0
    p[_P_INV_LX] = 1.0 / vehicle.longitudinal_relaxation_length
    p[_P_INV_LY] = 1.0 / vehicle.lateral_relaxation_length
    p[_P_RELAX_FLOOR] = vehicle.relaxation_speed_floor
    p[_P_LOADDYN] = 1.0 if load_dyn else 0.0
    if load_dyn:
        assert susp is not None
        p[_P_KR], p[_P_CR], p[_P_KP], p[_P_CP] = (
            susp.roll_stiffness,
            susp.roll_damping,
            susp.pitch_stiffness,
            susp.pitch_damping,
        )
        p[_P_ROLL_DRIVE] = susp.sprung_mass * susp.roll_arm
        p[_P_PITCH_DRIVE] = susp.sprung_mass * susp.pitch_arm
        p[_P_IR], p[_P_IP] = susp.roll_axis_inertia, susp.pitch_axis_inertia
        p[_P_ROLL_ARM], p[_P_PITCH_ARM] = susp.roll_arm, susp.pitch_arm
    stiff_rate = n_wheels * (cx + ca) / m + (cx * float(np.sum(yw**2)) + ca * float(np.sum(xw**2))) / iz
    om = np.ascontiguousarray(omega, dtype=float)
    if initial_state is None:
        x0 = np.array(
            (radius * 0.5 * (om[0, 0] + om[0, 1]), 0.0, radius * (om[0, 1] - om[0, 0]) / vehicle.track), dtype=float
        )
    else:
        x0 = np.asarray(initial_state, dtype=float)
    out, ok = _replay_kernel(
        np.ascontiguousarray(t, dtype=float),
        om,
        x0,
        p,
        xw,
        yw,
        side,
        static * cos_grade,
        lpfx,
        lpfy,
        roll_unit,
        pitch_unit,
        float(integration_step),
        float(stiff_rate),
    )
    if not ok:
        out[~np.isfinite(out)] = 0.0
    return np.asarray(out)


# ---------------------------------------------------------------------------
# Bag reading
# ---------------------------------------------------------------------------


@dataclass
class SkidSteerBagData:
    """The bag's signals on the IMU time base (s from the first IMU stamp).

    Attributes:
        t: IMU sample times (M,).
        accel: specific force (M, 3) (m/s²).
        yaw_rate: gyro z (M,) (rad/s).
        body_rates: gyro x, y (M, 2) (rad/s: roll and pitch rate), or None when
            the IMU does not measure them (angular_velocity_covariance[0] or [4]
            is −1, REP 145).
        omega: wheel-side speeds (left, right) at ``t`` (M, 2) (rad/s).
        joint_t: joint-state times (K,), and ``motor_velocity`` (K, 2) as reported.
        start_stamp: the first IMU stamp (s, bag clock).
        source: description for the report.
    """

    t: FloatArray
    accel: FloatArray
    yaw_rate: FloatArray
    omega: FloatArray
    joint_t: FloatArray
    motor_velocity: FloatArray
    start_stamp: float
    source: str
    body_rates: FloatArray | None = None
    transmission_ratio: float = 1.0
    timing: str = "period_mean"
    notes: list[str] = field(default_factory=list)


def wheel_speeds_at(
    imu_t: FloatArray,
    joint_t: FloatArray,
    motor_velocity: FloatArray,
    transmission_ratio: float,
    timing: str,
) -> FloatArray:
    """Wheel-side speeds (M, 2) at the IMU times from the joint reports (module docstring, "Wheel speeds")."""
    wheel = np.asarray(motor_velocity, dtype=float) / transmission_ratio
    jt = np.asarray(joint_t, dtype=float)
    if timing == "period_mean":
        # A report at t_j is the mean over (t_{j-1}, t_j]: it belongs to the middle of that interval.
        period = np.diff(jt)
        mid = jt.copy()
        mid[1:] -= 0.5 * period
        mid[0] -= 0.5 * (period[0] if len(period) else 0.0)
        jt = mid
    elif timing != "instantaneous":
        raise ValueError(f"wheel_speed_timing must be 'period_mean' or 'instantaneous', got {timing!r}")
    return np.column_stack([np.interp(imu_t, jt, wheel[:, i]) for i in range(2)])


def read_skid_steer_bag(
    bag: str | Path,
    *,
    namespace: str = "/skid_steer",
    joints: tuple[str, str] = ("left_motor", "right_motor"),
    transmission_ratio: float = 27.13,
    wheel_speed_timing: str = "period_mean",
) -> SkidSteerBagData:
    """Read ``imu`` and ``joint_states`` of a skid-steer contract bag (CONTRACT.md).

    Raises:
        Sim2RealError: a topic is missing or too short, a joint is absent, a
            value is not finite (the message names topic, field and value).
    """
    from terrain_estimation.bag import read_bag
    from terrain_estimation.tools.estimate import topic_name

    imu_topic = topic_name(namespace, "imu")
    joint_topic = topic_name(namespace, "joint_states")
    present = bag_topics(bag)
    for topic in (imu_topic, joint_topic):
        if topic not in present:
            raise Sim2RealError(
                f"bag {str(bag)!r} has no messages on {topic}, which the skid-steer diagnosis needs "
                f"(namespace {namespace!r}; the bag has {sorted(present)}; pass --namespace if it was recorded "
                f"under another one)"
            )
    imu_rows: list[tuple[float, float, float, float, float]] = []
    rate_rows: list[tuple[float, float]] = []
    rates_measured = True
    joint_rows: list[tuple[float, float, float]] = []
    clock = StampOrigin()  # seconds from the first stamp (epoch stamps lose precision as floats)
    for item in read_bag(bag, [imu_topic, joint_topic]):
        msg = item.msg
        stamp = clock(msg)
        if item.topic == imu_topic:
            a, w = msg.linear_acceleration, msg.angular_velocity
            row = (stamp, float(a.x), float(a.y), float(a.z), float(w.z))
            for name, value in zip(
                (
                    "header.stamp",
                    "linear_acceleration.x",
                    "linear_acceleration.y",
                    "linear_acceleration.z",
                    "angular_velocity.z",
                ),
                row,
                strict=True,
            ):
                if not math.isfinite(value):
                    raise Sim2RealError(f"bag {str(bag)!r}: {imu_topic} field {name} is {value} at stamp {stamp:.6f}")
            imu_rows.append(row)
            cov = msg.angular_velocity_covariance
            rates = (float(w.x), float(w.y))
            if cov[0] < 0.0 or cov[4] < 0.0 or not all(math.isfinite(v) for v in rates):
                rates_measured = False  # REP 145: −1 means "not measured"; one such message disables both
            rate_rows.append(rates)
        else:
            names = list(msg.name)
            velocity = list(msg.velocity)
            values = []
            for joint in joints:
                if joint not in names:
                    raise Sim2RealError(
                        f"bag {str(bag)!r}: {joint_topic} has no joint {joint!r} (names {names}) at stamp {stamp:.6f}"
                    )
                index = names.index(joint)
                if index >= len(velocity):
                    raise Sim2RealError(
                        f"bag {str(bag)!r}: {joint_topic} field velocity has {len(velocity)} values, no entry for "
                        f"joint {joint!r} at stamp {stamp:.6f}"
                    )
                value = float(velocity[index])
                if not math.isfinite(value):
                    raise Sim2RealError(
                        f"bag {str(bag)!r}: {joint_topic} field velocity[{joint}] is {value} at stamp {stamp:.6f}"
                    )
                values.append(value)
            joint_rows.append((stamp, values[0], values[1]))
    for topic, rows in ((imu_topic, imu_rows), (joint_topic, joint_rows)):
        if len(rows) < 10:
            raise Sim2RealError(
                f"bag {str(bag)!r} has {len(rows)} messages on {topic}; the skid-steer diagnosis needs at least 10 "
                f"(namespace {namespace!r}; pass --namespace if the bag was recorded under another one)"
            )
    imu = np.array(imu_rows, dtype=float)
    order = np.argsort(imu[:, 0], kind="stable")
    imu = imu[order]
    body_rates = np.array(rate_rows, dtype=float)[order] if rates_measured else None
    jnt = np.array(joint_rows, dtype=float)
    jnt = jnt[np.argsort(jnt[:, 0], kind="stable")]
    return bag_data_from_arrays(
        imu[:, 0],
        imu[:, 1:4],
        imu[:, 4],
        jnt[:, 0],
        jnt[:, 1:3],
        transmission_ratio=transmission_ratio,
        wheel_speed_timing=wheel_speed_timing,
        source=str(bag),
        stamp_origin=clock.origin,
        body_rates=body_rates,
    )


def bag_data_from_arrays(
    imu_stamp: FloatArray,
    accel: FloatArray,
    yaw_rate: FloatArray,
    joint_stamp: FloatArray,
    motor_velocity: FloatArray,
    *,
    transmission_ratio: float,
    wheel_speed_timing: str = "period_mean",
    source: str = "arrays",
    stamp_origin: float = 0.0,
    body_rates: FloatArray | None = None,
) -> SkidSteerBagData:
    """:class:`SkidSteerBagData` from arrays (stamps in s on any common clock, best relative to
    ``stamp_origin`` on the bag clock); keeps the IMU samples inside the span of the joint reports
    (no extrapolation of the inputs)."""
    imu_stamp = np.asarray(imu_stamp, dtype=float)
    joint_stamp = np.asarray(joint_stamp, dtype=float)
    if np.any(np.diff(imu_stamp) <= 0.0):
        raise Sim2RealError(f"{source}: IMU stamps are not strictly increasing (duplicate stamps)")
    if np.any(np.diff(joint_stamp) <= 0.0):
        raise Sim2RealError(f"{source}: joint_states stamps are not strictly increasing (duplicate stamps)")
    lo, hi = joint_stamp[0], joint_stamp[-1]
    keep = (imu_stamp >= lo - 1e-9) & (imu_stamp <= hi + 1e-9)
    if int(np.sum(keep)) < 10:
        raise Sim2RealError(
            f"{source}: only {int(np.sum(keep))} IMU samples lie within the joint_states span "
            f"[{lo:.3f}, {hi:.3f}] s; the stamps of imu and joint_states do not overlap"
        )
    t_abs = imu_stamp[keep]
    start = float(t_abs[0])
    omega = wheel_speeds_at(t_abs - start, joint_stamp - start, motor_velocity, transmission_ratio, wheel_speed_timing)
    return SkidSteerBagData(
        t=t_abs - start,
        accel=np.asarray(accel, dtype=float)[keep],
        yaw_rate=np.asarray(yaw_rate, dtype=float)[keep],
        omega=omega,
        joint_t=joint_stamp - start,
        motor_velocity=np.asarray(motor_velocity, dtype=float),
        start_stamp=start + stamp_origin,
        source=source,
        body_rates=None if body_rates is None else np.asarray(body_rates, dtype=float)[keep],
        transmission_ratio=transmission_ratio,
        timing=wheel_speed_timing,
    )


# ---------------------------------------------------------------------------
# The replay model (ReplayModel protocol)
# ---------------------------------------------------------------------------

_CHANNELS = (
    ("yaw_rate", "imu angular_velocity.z", "rad/s"),
    ("ax", "imu linear_acceleration.x", "m/s²"),
    ("ay", "imu linear_acceleration.y", "m/s²"),
    ("az", "imu linear_acceleration.z", "m/s²"),
    ("roll_rate", "imu angular_velocity.x", "rad/s"),
    ("pitch_rate", "imu angular_velocity.y", "rad/s"),
)
_IMU_COLUMN = {"ax": 0, "ay": 1, "az": 2, "roll_rate": 3, "pitch_rate": 4, "yaw_rate": 5}
#: Gyro x, y: the sprung mass's roll and pitch rates, which only load_transfer_dynamics moves.
_BODY_RATE_CHANNELS = ("roll_rate", "pitch_rate")


#: Sensor parameters that act on one channel only: parameter → channel.
_SENSOR_CHANNEL = {
    **{f"accel_bias_{axis}": f"a{axis}" for axis in "xyz"},
    **{f"accel_scale_{axis}": f"a{axis}" for axis in "xyz"},
    "gyro_bias": "yaw_rate",
    "gyro_bias_x": "roll_rate",
    "gyro_bias_y": "pitch_rate",
    "gyro_scale": "yaw_rate",
}


def _restrict_to_channels(
    candidates: Mapping[str, Candidate], channels: Sequence[str], notes: list[str]
) -> dict[str, Candidate]:
    """The candidates without the sensor parameters of channels the model does not compare.

    A bias or scale of an axis the bag does not measure (or the replay does not
    predict) has no effect on any residual: fitting it would only add an
    unidentifiable parameter (and its penalty). An effect left without
    parameters (it had some) is dropped; both are noted for the report.
    """
    out: dict[str, Candidate] = {}
    for name, candidate in candidates.items():
        keep = tuple(p for p in candidate.parameters if _SENSOR_CHANNEL.get(p.name, channels[0]) in channels)
        dropped = [p.name for p in candidate.parameters if p not in keep]
        if dropped and not keep:
            notes.append(f"{name} not offered: its channels are not compared ({', '.join(dropped)})")
            continue
        if dropped:
            notes.append(f"{name}: {', '.join(dropped)} not fitted (channel not compared)")
            candidate = replace(candidate, parameters=keep)
        out[name] = candidate
    return out


class SkidSteerReplay:
    """:class:`~terrain_analysis.sim2real.model.ReplayModel` of one skid-steer bag (module docstring)."""

    vehicle: str
    channels: Sequence[Channel]
    times: Mapping[str, FloatArray]
    measured: Mapping[str, FloatArray]
    nuisance: Sequence[FitParameter]
    candidates: Mapping[str, Candidate]
    regimes: Mapping[str, tuple[FloatArray, FloatArray]]
    warmup: float
    notes: list[str]
    #: Per channel, the samples inside the model's domain (set when some are not: model.py "valid").
    valid: Mapping[str, NDArray[np.bool_]]

    def __init__(
        self,
        data: SkidSteerBagData,
        vehicle: ReplayVehicle,
        *,
        vehicle_key: str = "skid_steer",
        nuisance: Sequence[str] = (),
        candidates: Mapping[str, Candidate] | None = None,
        channels: Sequence[str] | None = None,
        warmup: float = 1.0,
        integration_step: float = 2.0e-3,
        noise_repeats: int = 2,
        noise_seed: int = 0,
    ) -> None:
        self.vehicle = vehicle_key
        self.replay_vehicle = vehicle
        self.data = data
        self.warmup = float(warmup)
        self.integration_step = float(integration_step)
        self.notes: list[str] = list(data.notes)
        self._cache: dict[tuple[Any, ...], FloatArray] = {}
        if channels is None:
            # The roll and pitch gyros carry the sprung mass's motion: compared when the IMU measures
            # them and the vehicle has a suspension (a rigid chassis predicts 0 and a real one shakes).
            channels = ("yaw_rate", "ax", "ay", "az")
            if data.body_rates is not None and vehicle.suspension is not None:
                channels += _BODY_RATE_CHANNELS
        self._channel_names = tuple(channels)
        for name in self._channel_names:
            if name not in _IMU_COLUMN:
                raise ValueError(f"unknown channel {name!r}; known: {sorted(_IMU_COLUMN)}")
            if name in _BODY_RATE_CHANNELS and data.body_rates is None:
                raise ValueError(f"channel {name!r}: the bag's IMU does not measure angular_velocity.x/y")
        measured = {
            "ax": data.accel[:, 0],
            "ay": data.accel[:, 1],
            "az": data.accel[:, 2],
            "yaw_rate": data.yaw_rate,
        }
        if data.body_rates is not None:
            measured["roll_rate"], measured["pitch_rate"] = data.body_rates[:, 0], data.body_rates[:, 1]
        self.times = {name: data.t for name in self._channel_names}
        self.measured = {name: np.asarray(measured[name], dtype=float) for name in self._channel_names}
        unknown = sorted(set(nuisance) - set(NUISANCE))
        if unknown:
            raise ValueError(f"unknown nuisance parameter(s) {unknown}; known: {sorted(NUISANCE)}")
        self.nuisance = tuple(
            FitParameter(
                name,
                NUISANCE[name][0],
                vehicle.rolling_resistance if name == "rolling_resistance" else 1.0,
                NUISANCE[name][1],
                NUISANCE[name][2],
            )
            for name in nuisance
        )
        if candidates is None:
            exclude = () if vehicle.suspension is not None else ("load_transfer_dynamics",)
            candidates = candidates_from_catalogue("skid_steer", exclude=exclude)
            if exclude:
                self.notes.append(
                    "load_transfer_dynamics not offered: the vehicle config has no suspension (rigid chassis)"
                )
        self.candidates = _restrict_to_channels(candidates, self._channel_names, self.notes)
        if "wheel_speed_delay" in self.candidates:
            # The IMU's last d seconds follow wheel speeds the bag no longer holds: with the encoder-stream delay
            # at its upper bound they cannot be predicted by any model; they are left out of every fit and score.
            longest = max(p.bounds[1] for p in self.candidates["wheel_speed_delay"].parameters)
            inside = data.t <= data.t[-1] - longest
            self.valid = {name: inside for name in self._channel_names}
            self.notes.append(
                f"last {longest:g} s left out: a wheel-encoder stream delayed by up to {longest:g} s "
                "(wheel_speed_delay) leaves the IMU's last samples without wheel speeds"
            )
        speed = vehicle.wheel_radius * 0.5 * np.abs(data.omega[:, 0] + data.omega[:, 1])
        encoder_rate = vehicle.wheel_radius * (data.omega[:, 1] - data.omega[:, 0]) / vehicle.track
        self.regimes = {
            "speed (m/s)": (data.t, speed),
            "|encoder yaw rate| (rad/s)": (data.t, np.abs(encoder_rate)),
        }
        sigma_input = self._input_noise(noise_repeats, noise_seed)
        sensor = {"ax": vehicle.accel_noise_std, "ay": vehicle.accel_noise_std, "az": vehicle.accel_noise_std}
        sensor["yaw_rate"] = sensor["roll_rate"] = sensor["pitch_rate"] = vehicle.gyro_noise_std
        self.input_noise = sigma_input
        self.channels = tuple(
            Channel(
                name,
                topic,
                unit,
                float(max(math.hypot(sensor[name], sigma_input[name]), 1e-9)),
            )
            for name, topic, unit in _CHANNELS
            if name in self._channel_names
        )

    # --- physics ----------------------------------------------------------

    def _physics(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> tuple[Physics, Sensing]:
        """(dynamic physics, sensor post-processing) of an effects/nuisance mapping."""
        unknown = sorted(set(effects) - set(self.candidates))
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown} for this replay; known: {sorted(self.candidates)}")

        def value(effect: str, name: str, off: float) -> float:
            return float(effects.get(effect, {}).get(name, off))

        physics = Physics(
            wheel_radius_error=value("wheel_radius_error", "wheel_radius_error", 0.0),
            friction_factor=value("friction_change", "friction_change", 1.0)
            * float(nuisance.get("friction_scale", 1.0)),
            cornering_factor=value("cornering_stiffness_change", "cornering_stiffness_change", 1.0)
            * float(nuisance.get("cornering_stiffness_scale", 1.0)),
            longitudinal_factor=float(nuisance.get("longitudinal_stiffness_scale", 1.0)),
            yaw_inertia_factor=float(nuisance.get("yaw_inertia_scale", 1.0)),
            rolling_resistance=float(nuisance["rolling_resistance"]) if "rolling_resistance" in nuisance else None,
            terrain_grade=value("terrain_grade", "terrain_grade", 0.0),
            terrain_bank=value("terrain_grade", "terrain_bank", 0.0),
            turning_resistance=value("turning_resistance", "turning_resistance", 0.0),
            load_transfer_dynamics="load_transfer_dynamics" in effects,
            tire_relaxation="tire_relaxation" in effects,
        )
        sensing = Sensing(
            shift=value("sensor_delay", "sensor_delay", 0.0) - value("wheel_speed_delay", "wheel_speed_delay", 0.0),
            scale=np.array(
                [value("accel_scale", f"accel_scale_{axis}", 0.0) for axis in "xyz"]
                + [0.0, 0.0, value("gyro_scale", "gyro_scale", 0.0)]
            ),
            bias=np.array(
                [value("accel_bias", f"accel_bias_{axis}", 0.0) for axis in "xyz"]
                + [value("gyro_bias", "gyro_bias_x", 0.0), value("gyro_bias", "gyro_bias_y", 0.0)]
                + [value("gyro_bias", "gyro_bias", 0.0)]
            ),
        )
        return physics, sensing

    def _dynamic(self, physics: Physics, omega: FloatArray | None = None) -> FloatArray:
        if omega is not None:
            return replay_imu(self.replay_vehicle, self.data.t, omega, physics, integration_step=self.integration_step)
        key = tuple(sorted(vars(physics).items()))
        hit = self._cache.get(key)
        if hit is None:
            hit = replay_imu(
                self.replay_vehicle, self.data.t, self.data.omega, physics, integration_step=self.integration_step
            )
            if len(self._cache) > 256:
                self._cache.clear()
            self._cache[key] = hit
        return hit

    def imu(self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]) -> FloatArray:
        """Predicted IMU (M, 6) with the stream delays, scale factors and biases applied (:class:`Sensing`)."""
        physics, sensing = self._physics(effects, nuisance)
        return sensing.apply(self.data.t, self._dynamic(physics))

    def predict(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, FloatArray]:
        imu = self.imu(effects, nuisance)
        return {name: imu[:, _IMU_COLUMN[name]] for name in self._channel_names}

    def _input_noise(self, repeats: int, seed: int) -> dict[str, float]:
        """RMS change of each channel when the wheel speeds get white noise of their reported σ (after warm-up)."""
        vehicle = self.replay_vehicle
        sigma = vehicle.wheel_speed_noise_std
        zero = {name: 0.0 for name in _IMU_COLUMN}
        if repeats <= 0 or (sigma <= 0.0 and vehicle.encoder_step <= 0.0 and vehicle.speed_step <= 0.0):
            return zero
        base = self._dynamic(Physics())
        rng = np.random.default_rng(seed)
        use = self.data.t >= self.data.t[0] + self.warmup
        if not np.any(use):
            return zero
        # The noise is drawn on the joint reports (at their own times and rate) and goes through the same
        # interpolation as the data; an encoder at rest reports exactly 0, so only non-zero reports get noise.
        data = self.data
        ratio = data.transmission_ratio
        moving = np.abs(data.motor_velocity) > 0.0
        acc = {name: 0.0 for name in _IMU_COLUMN}
        for _ in range(repeats):
            shape = data.motor_velocity.shape
            noise = sigma * ratio * rng.standard_normal(shape)
            if vehicle.encoder_step > 0.0:
                # Difference of quantised positions over the report period: (u_k − u_(k−1))/T, u ~ U(0, step).
                # (Integrating the reported speeds would only give back the quantised positions.)
                u = rng.uniform(0.0, vehicle.encoder_step, (shape[0] + 1, shape[1]))
                period = np.diff(data.joint_t, prepend=2.0 * data.joint_t[0] - data.joint_t[1])[:, None]
                noise += (u[1:] - u[:-1]) / period
            if vehicle.speed_step > 0.0:
                noise += rng.uniform(-0.5, 0.5, shape) * vehicle.speed_step * ratio
            noisy_motor = data.motor_velocity + noise * moving
            noisy = wheel_speeds_at(data.t, data.joint_t, noisy_motor, ratio, data.timing)
            diff = self._dynamic(Physics(), noisy) - base
            for name, col in _IMU_COLUMN.items():
                acc[name] += float(np.mean(diff[use, col] ** 2)) / repeats
        return {name: math.sqrt(v) for name, v in acc.items()}


def _config_kind(config: str | Path) -> str:
    from terrain_estimation.params import load_parameter_file

    return str(load_parameter_file(config).get("vehicle.kind", "skid_steer"))


def build_model(
    bag: str | Path,
    *,
    config: str | Path | None = None,
    namespace: str | None = None,
    progress: Progress = None,
    vehicle: ReplayVehicle | None = None,
    nuisance: Sequence[str] = (),
    warmup: float = 1.0,
    wheel_speed_timing: str = "period_mean",
    joints: tuple[str, str] | None = None,
) -> SkidSteerReplay:
    """The replay model of a skid-steer bag for :func:`terrain_analysis.sim2real.attribution.attribute`.

    Args:
        bag: the bag (CONTRACT.md skid-steer topics ``imu``, ``joint_states``).
        config: the vehicle's config (default ``config/skid_steer.yaml``); a config with
            ``vehicle.kind: husky`` (``config/husky.yaml``) gives the 4-wheel Husky model of
            :func:`terrain_analysis.sim2real.husky.build_husky_model` (default namespace ``/husky``).
        namespace: the bag's namespace (default ``/skid_steer``).
        progress: called with progress lines.
        vehicle: a ready :class:`ReplayVehicle` instead of the config (e.g. the Husky).
        nuisance: names of :data:`NUISANCE` to fit in every model.
        warmup: seconds left out at the start.
        wheel_speed_timing: ``period_mean`` or ``instantaneous`` (module docstring).
        joints: (left, right) joint names (default: the config's ``joints.*``).
    """
    if vehicle is None and config is not None and _config_kind(config) == "husky":
        from terrain_analysis.sim2real.husky import build_husky_model

        if progress is not None:
            progress(f"reading {bag} (Husky config {config})")
        return build_husky_model(bag, config, namespace=namespace or "/husky", warmup=warmup)
    if vehicle is None:
        vehicle = vehicle_from_config(config)
        if joints is None:
            from vehicle_sim.ros.registry import get_simulator, simulator_parameters

            values = simulator_parameters(get_simulator("skid_steer"), config)
            joints = (str(values["joints.left_motor"]), str(values["joints.right_motor"]))
    if progress is not None:
        progress(f"reading {bag}")
    data = read_skid_steer_bag(
        bag,
        namespace=namespace or "/skid_steer",
        joints=joints or ("left_motor", "right_motor"),
        transmission_ratio=vehicle.transmission_ratio,
        wheel_speed_timing=wheel_speed_timing,
    )
    if data.t[-1] < warmup + 2.0:
        raise Sim2RealError(
            f"bag {str(bag)!r}: {data.t[-1]:.2f} s of overlapping imu and joint_states data; the diagnosis needs "
            f"at least the {warmup:g} s warm-up plus 2 s"
        )
    model = SkidSteerReplay(data, vehicle, nuisance=nuisance, warmup=warmup)
    if progress is not None:
        progress(
            f"replay model: {len(data.t)} IMU samples over {data.t[-1]:.1f} s; noise budget "
            + ", ".join(f"{c.name} {c.noise_std:.3g} {c.unit}" for c in model.channels)
        )
    return model


def with_vehicle(vehicle: ReplayVehicle, **changes: Any) -> ReplayVehicle:
    """A copy of ``vehicle`` with fields changed (dataclasses.replace, for tests and the Husky)."""
    return replace(vehicle, **changes)
