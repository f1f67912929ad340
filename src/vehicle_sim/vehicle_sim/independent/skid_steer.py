"""Independent 6-wheel skid-steered vehicle (MODELS.md B.2–B.6), speed-controlled drive, with its own effects.

Plant (planar rigid body on a plane fixed in the world)::

    v̇x = ΣF_x/m + vy r + g_bx(ψ)        v̇y = ΣF_y/m − vx r + g_by(ψ)
    ṙ  = Σ [x_i F_y,i − y_i F_x,i] / I_z     ψ̇ = r

Wheel i (axle x_i, side y_i = ±B/2) slides at v_x,i = vx − y_i r,
v_y,i = vy + x_i r. The drive is speed controlled: each side's wheel speed
ω(t) is the manoeuvre's command (the three wheels of a side share it), so the
motor torque is what that costs: T_m = [3 I_w ω̇ + R Σ_side F_x,i]/(η i_g)
+ I_m i_g ω̇.

Tire laws (:data:`TIRE_LAWS`), per wheel, with slips σ_x = (R ω − v_x,i)/V_r,
σ_y = −v_y,i/V_r, V_r = max(R|ω|, 0.05 m/s) and γ = √((C_x σ_x)² + (C_α σ_y)²):

* ``brush`` (MODELS.md B.4, the nominal): F = γ − γ²/(3μF_z) + γ³/(27μ²F_z²)
  below full sliding γ = 3μF_z, else μF_z;
* ``dugoff`` (Dugoff, Fancher & Segel 1970, a different law): λ = μF_z/(2γ),
  F = γ for λ ≥ 1, F = γ λ (2 − λ) = μF_z − (μF_z)²/(4γ) below: linear up to
  half the friction limit and saturating only asymptotically.

F_x,y = F · (C_x σ_x, C_α σ_y)/γ. Motion resistance (rolling, rut) on the
body: F_rr,i = f_rr F_z,i v_x,i/√(v_x,i² + (0.05 m/s)²), f_rr a per-bag
nuisance of the scenario (drawn; a handbook value that a real vehicle does
not state). Loads: quasi-static equal-spring axle loads (MODELS.md B.5) from
the body's specific force f = (ΣF/m, g_n), solved by a fixed-point pass
(start from the previous stage's f, two passes), split across the track by
m f_y H/(3B) per axle, floored at 0.

Ground plane: grade γ (> 0 rising ahead) and bank β (> 0 left side up) at
the start heading; gravity in the plane's axes g_p = (−g sin γ,
−g cos γ sin β, −g cos γ cos β), turned into the body frame by the heading ψ
(g_bx = g_px cos ψ + g_py sin ψ, g_by = −g_px sin ψ + g_py cos ψ); the IMU
reads f_z = g cos γ cos β. The loads carry the slope through f.

Integration: classical RK4 at :data:`STEP` with the commanded wheel speeds
exact at every stage. Sensors at 100 Hz: IMU at the centre of mass (specific
force x, y, z with σ 0.05 m/s²; angular velocity x, y, z with σ 0.002 rad/s,
roll and pitch rates 0 on the rigid body), reading (1 + s) × true + b per
axis; ``joint_states`` motor position quantised to 4096 counts/rev, velocity
the difference of the quantised positions over the period plus σ 0.02 rad/s,
effort plus σ 0.5 N·m. A late stream is a FIFO of its samples on the 1 ms
grid (the message stamped t carries the sample of t − d; the first d seconds
deliver nothing). Noise per delivered message from one stream per channel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

__all__ = ["MANOEUVRES", "TIRE_LAWS", "SkidSteerRun", "SkidSteerStreams", "SkidSteerVehicle", "simulate"]

TIRE_LAWS = ("brush", "dugoff")
MANOEUVRES = ("turn", "s_shape", "straight_then_turn")
STEP = 0.001  # s
RATE = 100.0  # Hz
ROLLING_FLOOR = 0.05  # m/s, V_r floor of the slips
RESISTANCE_SPEED = 0.05  # m/s, smooth sign of the motion resistance
RELAXATION_FLOOR = 0.2  # m/s, V = √(v_x² + floor²) of the relaxation rate V/L


@dataclass(frozen=True)
class SkidSteerVehicle:
    """MODELS.md B.2 Table 1 (the values of config/skid_steer.yaml) and the drive and sensor data."""

    mass: float = 3000.0
    yaw_inertia: float = 6390.0
    axle_x: tuple[float, float, float] = (1.836 - 0.244, -0.244, -(1.036 + 0.244))
    track: float = 2.06
    cg_height: float = 0.6
    wheel_radius: float = 0.375
    transmission_ratio: float = 27.13
    longitudinal_stiffness: float = 31300.0
    cornering_stiffness: float = 40200.0
    friction: float = 0.8
    gravity: float = 9.80665
    wheel_inertia: float = 2.0
    motor_inertia: float = 0.02
    efficiency: float = 0.9
    accel_noise: float = 0.05
    gyro_noise: float = 0.002
    encoder_counts: int = 4096
    motor_velocity_noise: float = 0.02
    effort_noise: float = 0.5


_KNOWN_EFFECTS = frozenset(
    {
        "sensor_delay",
        "wheel_speed_delay",
        "accel_bias_x",
        "accel_bias_y",
        "accel_bias_z",
        "accel_scale_x",
        "accel_scale_y",
        "accel_scale_z",
        "gyro_bias",
        "gyro_bias_x",
        "gyro_bias_y",
        "gyro_scale",
        "terrain_grade",
        "terrain_bank",
        "tire_relaxation",
        "relaxation_length_x",
        "relaxation_length_y",
        "friction_change",
        "cornering_stiffness_change",
        "wheel_radius_error",
        "turning_resistance",
        "turning_resistance_speed",
    }
)
_FACTORS = {"friction_change": 1.0, "cornering_stiffness_change": 1.0}


@dataclass(frozen=True)
class SkidSteerRun:
    """One run. ``manoeuvre`` holds ``kind`` (:data:`MANOEUVRES`) and its numbers (see :func:`commands`)."""

    duration: float
    manoeuvre: dict[str, Any]
    rolling_resistance: float
    seed: int
    tire_law: str = "brush"
    effects: dict[str, float] = field(default_factory=dict)
    vehicle: SkidSteerVehicle = field(default_factory=SkidSteerVehicle)


@dataclass
class SkidSteerStreams:
    """Recorded streams (stamps in ns from the start): IMU (N, 3) accel and gyro; joints (M, 2) left, right."""

    imu_t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    joint_t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    truth: dict[str, Any] = field(default_factory=dict)


def _quintic(x: np.ndarray | float) -> tuple[Any, Any, Any]:
    """s(x) = 10x³ − 15x⁴ + 6x⁵ on [0, 1] (clipped), its first and second derivatives."""
    x = np.clip(x, 0.0, 1.0)
    return (
        x**3 * (10.0 - 15.0 * x + 6.0 * x * x),
        30.0 * x * x * (1.0 - x) ** 2,
        60.0 * x * (1.0 - x) * (1.0 - 2.0 * x),
    )


def commands(manoeuvre: dict[str, Any], t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Commanded rim speed v and right-minus-left difference Δ (m/s) at ``t``, and their rates.

    * ``turn``: v and Δ ramp together (quintic, ``ramp`` s) to ``speed`` and ``difference``;
    * ``s_shape``: v ramps to ``speed``; Δ = ``difference`` sin(2π (t − ramp)/``period``) after the ramp;
    * ``straight_then_turn``: v ramps to ``speed``; from ``turn_at`` Δ ramps to ``difference`` over 2 s.
    """
    kind = manoeuvre["kind"]
    ramp = float(manoeuvre["ramp"])
    s, ds, _ = _quintic(t / ramp)
    v = float(manoeuvre["speed"]) * s
    dv = float(manoeuvre["speed"]) * ds / ramp
    amp = float(manoeuvre["difference"])
    if kind == "turn":
        d, dd = amp * s, amp * ds / ramp
    elif kind == "s_shape":
        period = float(manoeuvre["period"])
        phase = 2.0 * math.pi * np.maximum(t - ramp, 0.0) / period
        d = amp * np.sin(phase)
        dd = np.where(t > ramp, amp * 2.0 * math.pi / period * np.cos(phase), 0.0)
    elif kind == "straight_then_turn":
        t1 = float(manoeuvre["turn_at"])
        s2, ds2, _ = _quintic((t - t1) / 2.0)
        d, dd = amp * s2, amp * ds2 / 2.0
    else:
        raise ValueError(f"unknown manoeuvre {kind!r}; known: {', '.join(MANOEUVRES)}")
    return v, np.asarray(d, dtype=float), dv, np.asarray(dd, dtype=float)


@njit(cache=True)
def _wheel_forces(p, xa, st, wl, wr, fx0, fy0, out_lon, out_lat, out_fx, out_fxss, out_fyss, out_vx):
    """Per wheel (left axles, then right): body forces lon/lat, tire F_x, steady-state F_x, F_y; returns (f_x, f_y).

    Two fixed-point passes of the quasi-static loads on the specific force, from (fx0, fy0).
    """
    m, g_normal, h_cg, track = p[0], p[2], p[5], p[6]
    sum_x, sum_x2, det, radius, cx, ca = p[7], p[8], p[9], p[10], p[11], p[12]
    mu, f_rr, c_b, v_b = p[13], p[14], p[15], p[16]
    relax, dugoff = p[19] > 0.5, p[20] > 0.5
    vx, vy, r = st[0], st[1], st[2]
    fx, fy = fx0, fy0
    for _ in range(2):
        n = m * g_normal
        pp = (n * sum_x2 + m * fx * h_cg * sum_x) / det
        qq = -(3.0 * m * fx * h_cg + n * sum_x) / det
        side = m * fy * h_cg / (3.0 * track)
        tot_lon = 0.0
        tot_lat = 0.0
        for k in range(6):
            a = k % 3
            left = k < 3
            yk = 0.5 * track if left else -0.5 * track
            fz = 0.5 * (pp + qq * xa[a]) + (-side if left else side)
            if fz < 0.0:
                fz = 0.0
            vxi = vx - yk * r
            vyi = vy + xa[a] * r
            rim = radius * (wl if left else wr)
            vr = abs(rim)
            if vr < ROLLING_FLOOR:
                vr = ROLLING_FLOOR
            ux = cx * (rim - vxi) / vr
            uy = ca * (-vyi / vr)
            gam = math.sqrt(ux * ux + uy * uy)
            cap = mu * fz
            if gam <= 0.0:
                force = 0.0
            elif dugoff:
                force = gam if cap >= 2.0 * gam else cap - cap * cap / (4.0 * gam)
            elif gam < 3.0 * cap:
                force = gam - gam * gam / (3.0 * cap) + gam * gam * gam / (27.0 * cap * cap)
            else:
                force = cap
            ratio = force / gam if gam > 0.0 else 0.0
            fxss, fyss = ratio * ux, ratio * uy
            if relax:
                ftx, fty = st[6 + k], st[12 + k]
            else:
                ftx, fty = fxss, fyss
            rr = f_rr * fz * vxi / math.sqrt(vxi * vxi + RESISTANCE_SPEED * RESISTANCE_SPEED)
            fb = -c_b * fz * (2.0 / math.pi) * math.atan(vyi / v_b) if c_b != 0.0 else 0.0
            out_lon[k] = ftx - rr
            out_lat[k] = fty + fb
            out_fx[k], out_fxss[k], out_fyss[k], out_vx[k] = ftx, fxss, fyss, vxi
            tot_lon += ftx - rr
            tot_lat += fty + fb
        fx, fy = tot_lon / m, tot_lat / m
    return fx, fy


@njit(cache=True)
def _deriv(p, xa, st, wl, wr, fx0, fy0, out, lon, lat, fxt, fxss, fyss, vxs):
    fx, fy = _wheel_forces(p, xa, st, wl, wr, fx0, fy0, lon, lat, fxt, fxss, fyss, vxs)
    iz, gpx, gpy, track, lx, ly, relax = p[1], p[3], p[4], p[6], p[17], p[18], p[19] > 0.5
    vx, vy, r, psi = st[0], st[1], st[2], st[3]
    c, s = math.cos(psi), math.sin(psi)
    out[0] = fx + vy * r + gpx * c + gpy * s
    out[1] = fy - vx * r - gpx * s + gpy * c
    mz = 0.0
    for k in range(6):
        yk = 0.5 * track if k < 3 else -0.5 * track
        mz += xa[k % 3] * lat[k] - yk * lon[k]
    out[2] = mz / iz
    out[3] = r
    out[4], out[5] = wl, wr
    if relax:
        for k in range(6):
            speed = math.sqrt(vxs[k] * vxs[k] + RELAXATION_FLOOR * RELAXATION_FLOOR)
            out[6 + k] = speed / lx * (fxss[k] - st[6 + k])
            out[12 + k] = speed / ly * (fyss[k] - st[12 + k])
    return fx, fy


@njit(cache=True)
def _integrate(p, xa, w_left, w_right, n_steps, h):
    """Classical RK4; returns per step: specific force (x, y, z), yaw rate, heading, wheel angles, side traction."""
    n_state = 18 if p[19] > 0.5 else 6
    st = np.zeros(n_state)
    k1 = np.zeros(n_state)
    k2 = np.zeros(n_state)
    k3 = np.zeros(n_state)
    k4 = np.zeros(n_state)
    tmp = np.zeros(n_state)
    lon = np.zeros(6)
    lat = np.zeros(6)
    fxt = np.zeros(6)
    fxss = np.zeros(6)
    fyss = np.zeros(6)
    vxs = np.zeros(6)
    n1 = n_steps + 1
    spec = np.zeros((n1, 3))
    yaw_rate = np.zeros(n1)
    heading = np.zeros(n1)
    angle = np.zeros((n1, 2))
    traction = np.zeros((n1, 2))
    fx, fy = _deriv(p, xa, st, w_left[0], w_right[0], 0.0, 0.0, k1, lon, lat, fxt, fxss, fyss, vxs)
    for i in range(n1):
        if i > 0:
            j = 2 * (i - 1)
            f1x, f1y = _deriv(p, xa, st, w_left[j], w_right[j], fx, fy, k1, lon, lat, fxt, fxss, fyss, vxs)
            for n in range(n_state):
                tmp[n] = st[n] + 0.5 * h * k1[n]
            f2x, f2y = _deriv(p, xa, tmp, w_left[j + 1], w_right[j + 1], f1x, f1y, k2, lon, lat, fxt, fxss, fyss, vxs)
            for n in range(n_state):
                tmp[n] = st[n] + 0.5 * h * k2[n]
            f3x, f3y = _deriv(p, xa, tmp, w_left[j + 1], w_right[j + 1], f2x, f2y, k3, lon, lat, fxt, fxss, fyss, vxs)
            for n in range(n_state):
                tmp[n] = st[n] + h * k3[n]
            _deriv(p, xa, tmp, w_left[j + 2], w_right[j + 2], f3x, f3y, k4, lon, lat, fxt, fxss, fyss, vxs)
            for n in range(n_state):
                st[n] += h / 6.0 * (k1[n] + 2.0 * k2[n] + 2.0 * k3[n] + k4[n])
            fx, fy = _deriv(p, xa, st, w_left[j + 2], w_right[j + 2], f3x, f3y, k4, lon, lat, fxt, fxss, fyss, vxs)
        spec[i, 0], spec[i, 1], spec[i, 2] = fx, fy, p[2]
        yaw_rate[i] = st[2]
        heading[i] = st[3]
        angle[i, 0], angle[i, 1] = st[4], st[5]
        traction[i, 0] = fxt[0] + fxt[1] + fxt[2]
        traction[i, 1] = fxt[3] + fxt[4] + fxt[5]
    return spec, yaw_rate, heading, angle, traction


def simulate(run: SkidSteerRun, noise: bool = True) -> SkidSteerStreams:
    """Simulate ``run`` and return its sensor streams (nothing written; ``noise`` False: noise-free readings)."""
    unknown = sorted(set(run.effects) - _KNOWN_EFFECTS)
    if unknown:
        raise ValueError(f"unknown skid-steer effect parameter(s) {unknown}; known: {sorted(_KNOWN_EFFECTS)}")
    if run.tire_law not in TIRE_LAWS:
        raise ValueError(f"unknown tire law {run.tire_law!r}; known: {', '.join(TIRE_LAWS)}")
    if not run.duration > 2.0:
        raise ValueError(f"duration must be > 2 s, got {run.duration}")
    e = {name: float(run.effects.get(name, _FACTORS.get(name, 0.0))) for name in _KNOWN_EFFECTS}
    veh = run.vehicle
    m, iz, g = veh.mass, veh.yaw_inertia, veh.gravity
    xa = np.asarray(veh.axle_x, dtype=float)
    sum_x, sum_x2 = float(xa.sum()), float((xa * xa).sum())
    det = 3.0 * sum_x2 - sum_x * sum_x
    radius = veh.wheel_radius * (1.0 + e["wheel_radius_error"])
    cx = veh.longitudinal_stiffness
    ca = veh.cornering_stiffness * e["cornering_stiffness_change"]
    mu = veh.friction * e["friction_change"]
    f_rr = float(run.rolling_resistance)
    c_b, v_b = e["turning_resistance"], max(e["turning_resistance_speed"], 1e-3)
    grade, bank = e["terrain_grade"], e["terrain_bank"]
    gpx, gpy = -g * math.sin(grade), -g * math.cos(grade) * math.sin(bank)
    g_normal = g * math.cos(grade) * math.cos(bank)
    relax = e["tire_relaxation"] > 0.5
    lx, ly = e["relaxation_length_x"], e["relaxation_length_y"]
    if relax and not (lx > 0.0 and ly > 0.0):
        raise ValueError(f"tire_relaxation needs relaxation_length_x, _y > 0, got {lx}, {ly}")
    dugoff = run.tire_law == "dugoff"
    h_cg, half_track = veh.cg_height, veh.track

    n_steps = int(round(run.duration / STEP))
    t_stage = np.arange(2 * n_steps + 1) * (STEP / 2.0)
    v_cmd, d_cmd, dv_cmd, dd_cmd = commands(run.manoeuvre, t_stage)
    w_left = (v_cmd - d_cmd / 2.0) / veh.wheel_radius  # the drive commands wheel speed from the nominal radius
    w_right = (v_cmd + d_cmd / 2.0) / veh.wheel_radius
    wd_left = (dv_cmd - dd_cmd / 2.0) / veh.wheel_radius
    wd_right = (dv_cmd + dd_cmd / 2.0) / veh.wheel_radius

    params = np.array(
        [
            m,
            iz,
            g_normal,
            gpx,
            gpy,
            h_cg,
            half_track,
            sum_x,
            sum_x2,
            det,
            radius,
            cx,
            ca,
            mu,
            f_rr,
            c_b,
            v_b,
            lx if relax else 1.0,
            ly if relax else 1.0,
            1.0 if relax else 0.0,
            1.0 if dugoff else 0.0,
        ]
    )
    spec, yaw_rate, heading, wheel_angle, traction = _integrate(params, xa.copy(), w_left, w_right, n_steps, STEP)
    if not (np.all(np.isfinite(spec)) and np.all(np.isfinite(yaw_rate))):
        raise FloatingPointError("skid steer diverged (non-finite state)")
    n1 = n_steps + 1

    # Sensors at 100 Hz from the 1 ms grid; FIFO delays in whole grid samples.
    per = int(round(1.0 / (RATE * STEP)))
    n_samples = n_steps // per + 1
    t_ns = np.arange(n_samples, dtype=np.int64) * int(round(1e9 / RATE))
    seqs = np.random.SeedSequence(run.seed).spawn(4)
    lag = int(round(e["sensor_delay"] / STEP))
    src = np.arange(n_samples) * per - lag
    ok = src >= 0
    s_imu = src[ok]
    scale = np.array([e["accel_scale_x"], e["accel_scale_y"], e["accel_scale_z"]])
    bias = np.array([e["accel_bias_x"], e["accel_bias_y"], e["accel_bias_z"]])
    noise_a = np.random.default_rng(seqs[0]).normal(0.0, veh.accel_noise, (n_samples, 3))[ok] * float(noise)
    noise_g = np.random.default_rng(seqs[1]).normal(0.0, veh.gyro_noise, (n_samples, 3))[ok] * float(noise)
    accel = (1.0 + scale) * spec[s_imu] + bias + noise_a
    gyro = np.zeros((s_imu.size, 3))
    gyro[:, 2] = (1.0 + e["gyro_scale"]) * yaw_rate[s_imu] + e["gyro_bias"]
    gyro[:, 0] += e["gyro_bias_x"]
    gyro[:, 1] += e["gyro_bias_y"]
    gyro += noise_g

    lag_w = int(round(e["wheel_speed_delay"] / STEP))
    src_w = np.arange(n_samples) * per - lag_w
    okw = src_w >= 0
    s_w = src_w[okw]
    ig = veh.transmission_ratio
    step_angle = 2.0 * math.pi / veh.encoder_counts
    counts = np.floor(wheel_angle * ig / step_angle)
    position = counts * step_angle
    prev_idx = np.maximum(np.arange(n1) - per, 0)
    previous = position[prev_idx]
    period = per * STEP
    velocity = (position - previous) / period
    wd = np.stack([wd_left[::2], wd_right[::2]], axis=1)[:n1]
    wheel_torque = 3.0 * veh.wheel_inertia * wd + radius * traction
    effort = wheel_torque / (veh.efficiency * ig) + veh.motor_inertia * ig * wd
    noise_v = np.random.default_rng(seqs[2]).normal(0.0, veh.motor_velocity_noise, (n_samples, 2))[okw] * float(noise)
    noise_e = np.random.default_rng(seqs[3]).normal(0.0, veh.effort_noise, (n_samples, 2))[okw] * float(noise)
    return SkidSteerStreams(
        imu_t=t_ns[ok],
        accel=accel,
        gyro=gyro,
        joint_t=t_ns[okw],
        position=position[s_w],
        velocity=velocity[s_w] + noise_v,
        effort=effort[s_w] + noise_e,
        truth={
            "final_heading": float(heading[-1]),
            "mean_yaw_rate": float(np.mean(yaw_rate)),
            "max_speed": float(np.max(np.abs(v_cmd))),
        },
    )
