"""Independent 2-DOF quarter car on deformable soil (MODELS.md A.1, A.2, A.8), with its own effects.

Plant (deviations from static equilibrium, gravity cancels)::

    m_s  ÿ1 = −k (y1 − y2) − c (ẏ1 − ẏ2) − F_f
    m_ns ÿ2 =  k (y1 − y2) + c (ẏ1 − ẏ2) + F_f + F_d + c_t (ḣ_e − ẏ2)

F_d is the dynamic force of the tire (linear, k_t) in series with the soil,
given the chain's extra compression u = h_e − y2 beyond the static one
(h_e: the road the tire feels). Integrated by classical RK4 at
:data:`STEP` with the road, its slope and the enveloped road exact at every
stage (:mod:`.road`: an inverse FFT on the stage grid), from rest at the road
height (y1 = y2 = h_e(0)).

Soil laws (:data:`SOIL_LAWS`), each with the stiffness k_s at the static load
W = (m_s + m_ns) g (the linear-equivalent k_s, from MODELS.md Table 1):

* ``linear``: F = W + k_s δ (the nominal);
* ``hyperbolic`` (Kondner's hyperbola, softening): F(z) = z / (a + b z) in
  the sinkage z from the surface, saturating at the ultimate load 1/b; the
  shape parameter r = W b ∈ (0, 1) is the static load as a fraction of the
  ultimate one (a = z0 (1 − r)/W, z0 = W (1 − r)/k_s);
* ``hard_layer`` (stiffening): a deformable layer of depth D over a rigid
  one, F(z) = k0 z / (1 − z/D); shape q = z0/D ∈ (0, 1), the fraction of
  the layer compressed at rest (k0 = k_s (1 − q)², z0 = W/(k_s (1 − q)));
* ``zener`` (viscoelastic standard linear solid, a structure the catalogue
  does not have): the soil is a spring k_s in parallel with a Maxwell branch
  (spring ρ k_s in series with a damper of relaxation time τ), in series with
  the tire. Static stiffness k_s, high-frequency stiffness (1 + ρ) k_s. One
  more state, the Maxwell force F_m:
  (1 + k2/(k_t + k_s)) Ḟ_m = k2 k_t u̇/(k_t + k_s) − F_m/τ.

The series chain is solved in closed form (a quadratic for the two
nonlinear elastic laws). ``wheel_liftoff``: the total contact force W + F_d
is not allowed below 0 (unilateral contact); otherwise the contact is
bilateral (the nominal).

Sensors: body and wheel accelerometers (specific force z = ÿ + g, REP 145)
at :data:`RATE`, white noise of variance 0.5 (m/s²)², reading
(1 + s)(ÿ + g) + b; ``joint_states`` wheel angle s/R and rate v/R (noise
free); ``terrain/profile`` at 1 kHz: distance s and the road under the
tire plus white noise of 0.1 mm (the profile measures the road itself, not
the enveloped road). A late stream (``sensor_delay_*``) is a FIFO of the
stream's samples: the message stamped t carries the sample taken at t − d
(d rounded to the stream's sample grid: 0.5 ms for the accelerometers, whose
truth is kept at every RK4 step, 1 ms for the profile); the first d seconds of
that stream deliver nothing. Noise is drawn per delivered message from one
stream per channel (a fixed number of draws), so a run and its twin with
the effect off share the noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vehicle_sim.independent.road import Road, iso8608_road

__all__ = ["QuarterCarRun", "QuarterCarVehicle", "RATE", "SOILS", "SOIL_LAWS", "STEP", "Streams", "simulate"]

#: MODELS.md A.2 Table 1: equivalent soil stiffness k_s (N/m).
SOILS: dict[str, float] = {
    "upland_sandy_loam": 218.1e3,
    "lete_sand": 2283.0e3,
    "rubicon_sandy_loam": 272.1e3,
    "north_gower_clayey_loam": 221.9e3,
    "graneville_loam": 651.1e3,
}
SOIL_LAWS = ("linear", "hyperbolic", "hard_layer", "zener")
RATE = 100.0  # Hz, accelerometers and joint states
PROFILE_RATE = 1000.0  # Hz
STEP = 0.0005  # s, RK4 step (the road grid is at half steps)
GRAVITY = 9.80665
ACCEL_VARIANCE = 0.5  # (m/s²)², MODELS.md A.3 R
PROFILE_NOISE = 1e-4  # m
FRICTION_SPEED = 0.01  # m/s, regularisation of the Coulomb suspension friction: F_c (2/π) atan(Δv / v_f)


@dataclass(frozen=True)
class QuarterCarVehicle:
    """MODELS.md A.1 Table 2 (the values of config/quarter_car.yaml)."""

    sprung_mass: float = 455.0
    unsprung_mass: float = 45.5
    suspension_stiffness: float = 25e3
    suspension_damping: float = 2e3
    tire_stiffness: float = 175e3
    wheel_radius: float = 0.3885


@dataclass(frozen=True)
class QuarterCarRun:
    """One run: scenario, soil law, effects (all off by default) and noise seed.

    ``effects`` keys (the catalogue's parameter names where the physics
    corresponds): ``sensor_delay_body``, ``sensor_delay_wheel``,
    ``sensor_delay_profile`` (s); ``accel_bias_body``, ``accel_bias_wheel``
    (m/s²); ``accel_scale_body``, ``accel_scale_wheel`` (–);
    ``sprung_mass_change`` (–); ``tire_damping`` (N·s/m);
    ``suspension_friction`` (N); ``tire_contact_length`` (m, two-point
    follower: the tire feels (h(s − L/2) + h(s + L/2))/2); ``wheel_liftoff``
    (0/1).
    """

    duration: float
    speed: float
    road_class: str
    road_seed: int
    soil: str
    seed: int
    soil_law: str = "linear"
    soil_shape: dict[str, float] = field(default_factory=dict)
    effects: dict[str, float] = field(default_factory=dict)
    vehicle: QuarterCarVehicle = field(default_factory=QuarterCarVehicle)


@dataclass
class Streams:
    """The recorded sensor streams (stamps in ns from the start of the run)."""

    body_t: np.ndarray
    body: np.ndarray
    wheel_t: np.ndarray
    wheel: np.ndarray
    joint_t: np.ndarray
    joint_position: np.ndarray
    joint_velocity: np.ndarray
    profile_t: np.ndarray
    profile_x: np.ndarray
    profile_z: np.ndarray
    truth: dict[str, Any] = field(default_factory=dict)


_KNOWN_EFFECTS = frozenset(
    {
        "sensor_delay_body",
        "sensor_delay_wheel",
        "sensor_delay_profile",
        "accel_bias_body",
        "accel_bias_wheel",
        "accel_scale_body",
        "accel_scale_wheel",
        "sprung_mass_change",
        "tire_damping",
        "suspension_friction",
        "tire_contact_length",
        "wheel_liftoff",
    }
)


class _Chain:
    """Tire (k_t) in series with the soil: the dynamic force F_d(u) of the chain's extra compression u."""

    def __init__(self, law: str, shape: dict[str, float], k_s: float, k_t: float, load: float) -> None:
        self.law, self.k_t, self.load = law, k_t, load
        self.k_tot = k_s * k_t / (k_s + k_t)
        if law == "hyperbolic":
            r = float(shape["load_ratio"])
            if not 0.0 < r < 1.0:
                raise ValueError(f"hyperbolic soil: load_ratio must be in (0, 1), got {r}")
            z0 = load * (1.0 - r) / k_s
            self.a, self.b = z0 * (1.0 - r) / load, r / load
            self.c0 = load / k_t + z0  # chain compression from unloaded at rest
            self.k_zero = 1.0 / (1.0 / k_t + self.a)  # series stiffness at zero load
        elif law == "hard_layer":
            q = float(shape["depth_ratio"])
            if not 0.0 < q < 1.0:
                raise ValueError(f"hard_layer soil: depth_ratio must be in (0, 1), got {q}")
            z0 = load / (k_s * (1.0 - q))
            self.k0, self.depth = k_s * (1.0 - q) ** 2, z0 / q
            self.c0 = load / k_t + z0
            self.k_zero = 1.0 / (1.0 / k_t + 1.0 / self.k0)
        elif law not in ("linear", "zener"):
            raise ValueError(f"unknown soil law {law!r}; known: {', '.join(SOIL_LAWS)}")

    def force(self, u: float) -> float:
        """Dynamic chain force F_d (N) for an extra compression u (m); elastic laws only."""
        if self.law == "linear" or self.law == "zener":
            return self.k_tot * u
        c = self.c0 + u
        if c <= 0.0:
            return self.k_zero * c - self.load  # beyond unloaded: bilateral tangent continuation
        kt = self.k_t
        if self.law == "hyperbolic":
            # F/k_t + a F/(1 − b F) = c  →  b F² − (1 + k_t a + c k_t b) F + c k_t = 0, the root below 1/b.
            p = 1.0 + kt * self.a + c * kt * self.b
            disc = p * p - 4.0 * self.b * c * kt
            f = 2.0 * c * kt / (p + math.sqrt(max(disc, 0.0)))
        else:
            # F/k_t + F D/(k0 D + F) = c  →  F² + (k0 D + k_t D − c k_t) F − c k_t k0 D = 0, the positive root.
            p = self.k0 * self.depth + kt * self.depth - c * kt
            q = c * kt * self.k0 * self.depth
            f = 2.0 * q / (p + math.sqrt(p * p + 4.0 * q)) if p > 0 else (-p + math.sqrt(p * p + 4.0 * q)) / 2.0
        return f - self.load


def _grid_points(duration: float) -> int:
    return int(round(duration / STEP)) * 2 + 1


def simulate(run: QuarterCarRun, noise: bool = True) -> Streams:
    """Simulate ``run`` and return its sensor streams (nothing written; ``noise`` False: noise-free readings)."""
    unknown = sorted(set(run.effects) - _KNOWN_EFFECTS)
    if unknown:
        raise ValueError(f"unknown quarter-car effect parameter(s) {unknown}; known: {sorted(_KNOWN_EFFECTS)}")
    if run.soil not in SOILS:
        raise ValueError(f"unknown soil {run.soil!r}; known: {', '.join(SOILS)}")
    if not (run.duration > 0.5 and run.speed > 0.0):
        raise ValueError(f"duration must be > 0.5 s and speed > 0, got {run.duration}, {run.speed}")
    e = {name: float(run.effects.get(name, 0.0)) for name in _KNOWN_EFFECTS}
    v = run.vehicle
    m_s = v.sprung_mass * (1.0 + e["sprung_mass_change"])
    m_u = v.unsprung_mass
    k, c, k_t = v.suspension_stiffness, v.suspension_damping, v.tire_stiffness
    k_s = SOILS[run.soil]
    load = (m_s + m_u) * GRAVITY
    chain = _Chain(run.soil_law, run.soil_shape, k_s, k_t, load)
    zener = run.soil_law == "zener"
    if zener:
        rho, tau = float(run.soil_shape["stiffness_ratio"]), float(run.soil_shape["relaxation_time"])
        k2 = rho * k_s
        zg = k2 / (k_t + k_s)
        zener_gain = zg * k_t / (1.0 + zg)  # Ḟ_m = zener_gain u̇ − F_m / (τ (1 + zg))
        zener_rate = 1.0 / (tau * (1.0 + zg))
    c_t, f_c = e["tire_damping"], e["suspension_friction"]
    liftoff = e["wheel_liftoff"] > 0.5

    # Road on the stage grid (half RK4 steps), long enough for every stage.
    n_steps = int(round(run.duration / STEP))
    points = 2 * n_steps + 1
    ds = run.speed * STEP / 2.0
    road_rng = np.random.default_rng(run.road_seed)
    size = int(math.ceil((points + 64) / 4096.0) * 4096)
    road = iso8608_road(run.road_class, road_rng, size, ds)
    contact = e["tire_contact_length"]
    tire_road: Road = road
    if contact > 0.0:
        freq = np.arange(road.spectrum.size) / road.length
        tire_road = road.filtered(np.cos(math.pi * freq * contact))  # two-point follower (tandem) of base L
    he = tire_road.h
    hedot = tire_road.dh * run.speed

    def deriv(y1: float, v1: float, y2: float, v2: float, fm: float, j: int) -> tuple[float, ...]:
        u = he[j] - y2
        du = hedot[j] - v2
        if zener:
            # Soil deflection δ with k_t (u − δ) = k_s δ + F_m.
            fd = k_t * (u - (k_t * u - fm) / (k_t + k_s))
            dfm = zener_gain * du - zener_rate * fm
        else:
            fd = chain.force(u)
            dfm = 0.0
        fd += c_t * du
        if liftoff and fd < -load:
            fd = -load
        rel = v1 - v2
        fs = k * (y1 - y2) + c * rel
        if f_c:
            fs += f_c * (2.0 / math.pi) * math.atan(rel / FRICTION_SPEED)
        return v1, -fs / m_s, v2, (fs + fd) / m_u, dfm

    y = [he[0], 0.0, he[0], 0.0, 0.0]
    acc_body = np.empty(n_steps + 1)
    acc_wheel = np.empty(n_steps + 1)
    d0 = deriv(*y, 0)  # type: ignore[call-arg]
    acc_body[0], acc_wheel[0] = d0[1], d0[3]
    h = STEP
    for i in range(n_steps):
        j = 2 * i
        k1 = deriv(*y, j)  # type: ignore[call-arg]
        y2_ = [y[n] + 0.5 * h * k1[n] for n in range(5)]
        k2_ = deriv(*y2_, j + 1)  # type: ignore[call-arg]
        y3_ = [y[n] + 0.5 * h * k2_[n] for n in range(5)]
        k3 = deriv(*y3_, j + 1)  # type: ignore[call-arg]
        y4_ = [y[n] + h * k3[n] for n in range(5)]
        k4 = deriv(*y4_, j + 2)  # type: ignore[call-arg]
        y = [y[n] + h / 6.0 * (k1[n] + 2.0 * k2_[n] + 2.0 * k3[n] + k4[n]) for n in range(5)]
        d = deriv(*y, j + 2)  # type: ignore[call-arg]
        acc_body[i + 1], acc_wheel[i + 1] = d[1], d[3]
        if not all(math.isfinite(x) for x in y):
            raise FloatingPointError(f"quarter car diverged at t = {(i + 1) * h:.4f} s")

    seqs = np.random.SeedSequence(run.seed).spawn(3)
    per_sample = int(round(1.0 / (RATE * STEP)))
    n_samples = n_steps // per_sample + 1
    t_ns = np.arange(n_samples, dtype=np.int64) * int(round(1e9 / RATE))

    def accelerometer(truth: np.ndarray, delay: float, bias: float, scale: float, seq: Any) -> tuple[Any, Any]:
        lag = int(round(delay / STEP))
        rng = np.random.default_rng(seq)
        white = rng.normal(0.0, math.sqrt(ACCEL_VARIANCE), n_samples) * float(noise)
        idx = np.arange(n_samples) * per_sample - lag
        ok = idx >= 0
        reading = (1.0 + scale) * (truth[idx[ok]] + GRAVITY) + bias + white[ok]
        return t_ns[ok], reading

    body_t, body = accelerometer(acc_body, e["sensor_delay_body"], e["accel_bias_body"], e["accel_scale_body"], seqs[0])
    wheel_t, wheel = accelerometer(
        acc_wheel, e["sensor_delay_wheel"], e["accel_bias_wheel"], e["accel_scale_wheel"], seqs[1]
    )
    per_profile = int(round(1.0 / (PROFILE_RATE * STEP / 2.0)))
    n_profile = (points - 1) // per_profile + 1
    p_ns = np.arange(n_profile, dtype=np.int64) * int(round(1e9 / PROFILE_RATE))
    lag_p = int(round(e["sensor_delay_profile"] * PROFILE_RATE))
    white_p = np.random.default_rng(seqs[2]).normal(0.0, PROFILE_NOISE, n_profile) * float(noise)
    src = np.arange(n_profile) - lag_p
    okp = src >= 0
    grid = src[okp] * per_profile
    distance = grid * ds
    return Streams(
        body_t=body_t,
        body=body,
        wheel_t=wheel_t,
        wheel=wheel,
        joint_t=t_ns,
        joint_position=(t_ns * 1e-9) * run.speed / v.wheel_radius,
        joint_velocity=np.full(n_samples, run.speed / v.wheel_radius),
        profile_t=p_ns[okp],
        profile_x=distance,
        profile_z=road.h[grid] + white_p[okp],
        truth={"k_s": k_s, "k_tot": chain.k_tot, "static_load": load},
    )
