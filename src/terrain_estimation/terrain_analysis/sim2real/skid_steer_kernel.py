"""The skid-steer replay's dynamics: the numba RK4 kernel driven by the measured wheel speeds.

:func:`replay_imu` integrates the planar body (and, with ``load_transfer_dynamics``, the sprung mass; with
``tire_relaxation``, the lagged tire forces) under the brush tire forces the measured wheel speeds give, and
returns the noise-free IMU; :class:`Physics` holds the physical values of one replay, :class:`Sensing` what the
sensors do to its output (the equations are in the docstring of :mod:`terrain_analysis.sim2real.skid_steer`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.skid_steer_vehicle import ReplayVehicle, equal_spring_loads, no_slip_motion
from terrain_estimation.jit import compiled

__all__ = ["RELAXATION_LENGTH_MIN", "TURNING_RESISTANCE_SPEED", "Physics", "Sensing", "replay_imu"]

FloatArray = NDArray[np.float64]

# Indices of the scalar parameter vector of the kernel.
_P_RADIUS, _P_CX, _P_CA, _P_MU, _P_FLOOR, _P_MASS, _P_IZ, _P_RR, _P_INV_RRV = range(9)
_P_GPX, _P_GN, _P_RELAX, _P_INV_LX, _P_INV_LY, _P_RELAX_FLOOR, _P_LOADDYN = range(9, 16)
_P_KR, _P_CR, _P_KP, _P_CP, _P_ROLL_DRIVE, _P_PITCH_DRIVE, _P_IR, _P_IP, _P_ROLL_ARM, _P_PITCH_ARM = range(16, 26)
_P_GPY, _P_BULL, _P_INV_VB, _P_RELAX_ROLLING = range(26, 30)
_N_P = 30
#: Rows of the derivative's work array (per wheel): contact speeds, slips, loads, rolling resistance, wheel speed,
#: tire forces, lateral sliding resistance. Indexed in two dimensions, not through row views: numba makes each view
#: a reference-counted array on every call (≈ 10 % of the replay's time).
_W_CVX, _W_CVY, _W_SX, _W_SY, _W_LOAD, _W_RPL, _W_OM, _W_FX, _W_FY, _W_SLIDING = range(10)
#: Lateral contact speed over which the soil's lateral resistance (turning_resistance) builds up (m/s), nominal:
#: the catalogue's stated form F_b = −c_b F_z tanh(v_y / 0.05 m/s); the replay fits it
#: (:data:`~terrain_analysis.sim2real.skid_steer_replay.TURNING_RESISTANCE_SPEED_PARAMETER`).
TURNING_RESISTANCE_SPEED = 0.05
#: Shortest relaxation length the replay integrates (m): 5 mm lags the force by 5 ms at 1 m/s, below one IMU
#: sample, so a fitted length of 0 (no lag on that axis) runs as this one.
RELAXATION_LENGTH_MIN = 0.005
#: Below this relaxation length (m) the lagged forces follow the slips so closely that the slip equations'
#: own stiffness returns: the replay sub-steps for it as without a lag.
RELAXATION_LENGTH_STIFF = 0.05


@compiled(error_model="numpy")
def _earlier_equal(values, row, i):
    """Index of the first of ``values[:i]`` equal to ``values[i]`` (i: none). A function of equal arguments is
    equal: the kernel takes a wheel's tanh from an earlier wheel with the same argument (the wheels of one side
    share their longitudinal contact speed, those of one axle their lateral one), bit for bit the same value."""
    x = values[row, i]
    for j in range(i):
        if values[row, j] == x:
            return j
    return i


@compiled(error_model="numpy")
def _derivative(s, oml, omr, hfx, hfy, p, wx, wy, side, static, lpfx, lpfy, ru, pu, out, work):
    """State derivative (into ``out``); returns (f_x, f_y, roll accel, pitch accel). Plant's equations.

    State: vx, vy, r, roll, roll rate, pitch, pitch rate, lagged F_x (n), F_y (n), heading ψ from the start.
    Gravity in the body frame: the plane's (g_px, g_py) at the start heading turned by ψ (on level ground both
    are zero whatever ψ: no trigonometry). ``error_model="numpy"``: no division here can be by zero (speeds are
    floored, masses and inertias positive), so numba's per-division zero checks only cost time.
    """
    n = wx.shape[0]
    vx, vy, r = s[0], s[1], s[2]
    if p[_P_GPX] != 0.0 or p[_P_GPY] != 0.0:
        heading = s[7 + 2 * n]
        ch = math.cos(heading)
        sh = math.sin(heading)
        gbx = p[_P_GPX] * ch + p[_P_GPY] * sh
        gby = -p[_P_GPX] * sh + p[_P_GPY] * ch
    else:
        gbx = 0.0
        gby = 0.0
    roll, roll_rate, pitch, pitch_rate = s[3], s[4], s[5], s[6]
    radius, cx, ca, mu, floor = p[_P_RADIUS], p[_P_CX], p[_P_CA], p[_P_MU], p[_P_FLOOR]
    mass = p[_P_MASS]
    relax = p[_P_RELAX] > 0.5
    loaddyn = p[_P_LOADDYN] > 0.5
    for i in range(n):
        work[_W_CVX, i] = vx - wy[i] * r
        work[_W_CVY, i] = vy + wx[i] * r
        work[_W_OM, i] = oml if side[i] == 0 else omr
        rolling = radius * work[_W_OM, i]
        vr = max(abs(rolling), floor)
        work[_W_SX, i] = (rolling - work[_W_CVX, i]) / vr
        work[_W_SY, i] = -work[_W_CVY, i] / vr
        base = static[i]
        if loaddyn:
            base += -ru[i] * (p[_P_KR] * roll + p[_P_CR] * roll_rate) + pu[i] * (
                p[_P_KP] * pitch + p[_P_CP] * pitch_rate
            )
        work[_W_LOAD, i] = base
        same = _earlier_equal(work, _W_CVX, i)
        work[_W_RPL, i] = work[_W_RPL, same] if same < i else p[_P_RR] * math.tanh(work[_W_CVX, i] * p[_P_INV_RRV])
    if relax:
        sum_fx = 0.0
        sum_fy = 0.0
        for i in range(n):
            work[_W_FX, i] = s[7 + i]
            work[_W_FY, i] = s[7 + n + i]
            sum_fx += work[_W_FX, i]
            sum_fy += work[_W_FY, i]
        num = sum_fx
        den = mass
        for i in range(n):
            work[_W_LOAD, i] += lpfy[i] * (sum_fy / mass)
        for i in range(n):
            num -= work[_W_RPL, i] * work[_W_LOAD, i]
            den += work[_W_RPL, i] * lpfx[i]
        load_fx = num / den
        for i in range(n):
            work[_W_LOAD, i] = max(work[_W_LOAD, i] + lpfx[i] * load_fx, 0.0)
    else:
        for i in range(n):
            work[_W_LOAD, i] = max(work[_W_LOAD, i] + lpfx[i] * hfx + lpfy[i] * hfy, 0.0)
    for i in range(n):
        # Brush model (B.4), the closed form of terrain_estimation.models.skid_steer.brush_tire_forces.
        cx_sx = cx * work[_W_SX, i]
        ca_sy = ca * work[_W_SY, i]
        mu_fz = mu * work[_W_LOAD, i]
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
            contact = math.hypot(work[_W_CVX, i], work[_W_CVY, i])
            speed = max(max(p[_P_RELAX_ROLLING] * radius * abs(work[_W_OM, i]), contact), p[_P_RELAX_FLOOR])
            out[7 + i] = speed * (ssx - work[_W_FX, i]) * p[_P_INV_LX]
            out[7 + n + i] = speed * (ssy - work[_W_FY, i]) * p[_P_INV_LY]
        else:
            work[_W_FX, i] = ssx
            work[_W_FY, i] = ssy
            out[7 + i] = 0.0
            out[7 + n + i] = 0.0
    sum_x = 0.0
    sum_y = 0.0
    moment = 0.0
    bull = p[_P_BULL]
    for i in range(n):
        net_x = work[_W_FX, i] - work[_W_RPL, i] * work[_W_LOAD, i]
        lateral = work[_W_FY, i]
        if bull > 0.0:
            # turning_resistance: the soil's lateral resistance against the wheel's lateral sliding, ∝ its load.
            same = _earlier_equal(work, _W_CVY, i)
            work[_W_SLIDING, i] = work[_W_SLIDING, same] if same < i else math.tanh(work[_W_CVY, i] * p[_P_INV_VB])
            lateral -= bull * work[_W_LOAD, i] * work[_W_SLIDING, i]
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


@compiled(error_model="numpy")
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


@compiled(error_model="numpy", nogil=True)
def _replay_kernel(t, omega, x0, p, wx, wy, side, static, lpfx, lpfy, ru, pu, base_dt, stiff_rate):
    """RK4 replay over the sample times ``t`` (M,) with wheel speeds ``omega`` (M, 2); IMU (M, 6) at every sample.

    Wheel speeds are linear in time between samples. Steps per interval: enough for ``base_dt``, raised to keep
    λ_max Δt ≤ 2 with λ_max = stiff_rate / V_r (the plant's stiffness bound without the wheel term).
    The load-transfer hold is the specific force of the first RK4 stage (the plant's rule). Releases the GIL
    (``nogil``): replays of different physics (a Jacobian's columns) can run on several cores from threads.
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
    work = np.empty((10, n))
    hfx = 0.0
    hfy = 0.0
    # Initial reading.
    f_x, f_y, ra, pa = _derivative(
        s, omega[0, 0], omega[0, 1], hfx, hfy, p, wx, wy, side, static, lpfx, lpfy, ru, pu, k1, work
    )
    hfx, hfy = f_x, f_y
    _imu(s, f_x, f_y, ra, pa, p, out[0])
    # After the first interval, a reading's derivative is the next interval's first stage (same state, wheel
    # speeds and load hold; the first sample's reading used no hold): k1 holds it, read_fx/fy its specific force.
    reuse = False
    read_fx, read_fy = f_x, f_y
    radius = p[_P_RADIUS]
    floor = p[_P_FLOOR]
    relax = p[_P_RELAX] > 0.5
    for k in range(m - 1):
        dt_total = t[k + 1] - t[k]
        steps = max(1, int(math.ceil(dt_total / base_dt - 1e-9)))
        if not relax or max(p[_P_INV_LX], p[_P_INV_LY]) > 1.0 / RELAXATION_LENGTH_STIFF:
            # Without a lag (or with one so short that the forces follow the slips at once) the slip
            # equations are stiff at low rolling speed.
            om_min = min(min(abs(omega[k, 0]), abs(omega[k, 1])), min(abs(omega[k + 1, 0]), abs(omega[k + 1, 1])))
            rolling = max(radius * om_min, floor)
            stiff = int(math.ceil(stiff_rate / rolling * dt_total / 2.0))
            steps = max(steps, min(stiff, 400))
        if relax:
            # The force lag's rate V/L: a short relaxation length is a stiff mode, RK4 needs h V/L <= 2
            # (V: twice the fastest rolling speed, a margin for sliding contact).
            om_max = max(max(abs(omega[k, 0]), abs(omega[k, 1])), max(abs(omega[k + 1, 0]), abs(omega[k + 1, 1])))
            speed = 2.0 * max(radius * om_max, p[_P_RELAX_FLOOR])
            stiff = int(math.ceil(speed * max(p[_P_INV_LX], p[_P_INV_LY]) * dt_total / 2.0))
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
            if j == 0 and reuse:
                f_x, f_y = read_fx, read_fy
            else:
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
        reuse = True
        read_fx, read_fy = f_x, f_y
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
    turning_resistance_speed: float = TURNING_RESISTANCE_SPEED
    load_transfer_dynamics: bool = False
    tire_relaxation: bool = False
    relaxation_length_x: float | None = None
    relaxation_length_y: float | None = None
    relaxation_rolling_weight: float = 1.0


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
    p[_P_BULL], p[_P_INV_VB] = physics.turning_resistance, 1.0 / physics.turning_resistance_speed
    p[_P_RELAX] = 1.0 if physics.tire_relaxation else 0.0
    lx, ly = physics.relaxation_length_x, physics.relaxation_length_y
    p[_P_INV_LX] = 1.0 / (vehicle.longitudinal_relaxation_length if lx is None else max(lx, RELAXATION_LENGTH_MIN))
    p[_P_INV_LY] = 1.0 / (vehicle.lateral_relaxation_length if ly is None else max(ly, RELAXATION_LENGTH_MIN))
    p[_P_RELAX_FLOOR] = vehicle.relaxation_speed_floor
    p[_P_RELAX_ROLLING] = physics.relaxation_rolling_weight
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
        speed, yaw_rate = no_slip_motion(om[0], radius, vehicle.track)
        x0 = np.array((speed, 0.0, yaw_rate), dtype=float)
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
