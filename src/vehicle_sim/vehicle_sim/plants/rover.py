"""Truth plant of one side of the Kapvik rocker-bogie rover on deformable soil ([RB] III, MODELS.md C.1–C.4).

The estimators of [RB] (MODELS.md C.5–C.6) see the rover through its sensors
only and drop the Coriolis terms, the inertial coupling of the wheels and the
z-velocity of the body; this plant keeps all of them (DESIGN.md: the truth
has more physics than the filter). The rigid-body model is shared with the
estimators (:mod:`terrain_estimation.models.rover`), the soil is the
Wong–Reece rigid wheel (:mod:`vehicle_sim.terrain.wong_reece`) or its 4th-order
polynomial surrogate (:mod:`vehicle_sim.terrain.terramechanics_surrogate`, the
paper's choice for its simulation), selected by
:attr:`RoverScenario.terramechanics`.

Dynamics (eq. 32)
    Constrained Lagrangian dynamics of the 7 planar coordinates g (see
    :data:`~terrain_estimation.models.rover.COORDINATES`) with the three
    wheel-centre path constraints Ψ_j = z_j − z_wc(x_j) (eq. 26) and Baumgarte
    stabilisation Ψ̈ + 2α Ψ̇ + β² Ψ = 0 (eq. 31, α = β = 500: a critically damped
    constraint mode at 500 s⁻¹). At every evaluation the bordered system::

        [ H    Ψ_gᵀ ] [ g̈  ]   [ Q − c − ∂V/∂g ]
        [ Ψ_g  0    ] [ −λ ] = [ ζ             ],
        ζ = −(J̇_z ġ − z'_wc J̇_x ġ − z''_wc ẋ_j²) − 2α Ψ̇ − β² Ψ

    is solved for g̈ and λ. c = Ḣ ġ − ∂T/∂g is kept in full (the paper
    dropped ∂T/∂g in its simulation, and both in its estimator). λ_j is the
    vertical component of wheel j's constraint reaction (eq. 30); the
    reaction Ψ_gᵀ λ is a world force λ_j (−z'_wc, 1) at the wheel centre,
    normal to the path, so the **normal load** is W_j = λ_j √(1 + z'_wc²).
    Q (eqs. 33–40) holds DP_j along the terrain tangent (cos γ_j, −sin γ_j)
    at the wheel centre, the soil's moment −τ_R,j on the wheel (which also
    loads θ and q1, eq. 34), and the internal drive torque τ_W,j − b_d q̇_j
    between wheel and carrier (eq. 40).

Contact angle γ
    γ_j = −atan(dz_wc/dx) at the wheel centre: the angle of the terrain
    tangent below the horizontal, positive downhill, the sense of eq. 39's
    tangent (cos γ, −sin γ), of eq. 79 (γ = atan(−v_z/v_x) of the centre
    velocity, which is along the path) and of the pitch. The terrain is the
    path offset by r_w along its normal (eq. 25), so the terrain normal under
    the wheel is the path normal at its centre.

Sinkage (``RoverScenario.wheel_sinkage``, on by default; issue 21)
    Each wheel sinks into the soil: its centre runs the depth s_j below the
    path (Ψ_j = z_j − z_wc(x_j) + s_j(t)), so wheels under different loads and
    slips ride at different depths and the body pitches by their difference
    over the wheelbase, which the estimators' geometry (all three centres on
    one path) does not know. The steady depth is the plant's own Wong–Reece
    solution (:func:`~vehicle_sim.terrain.wong_reece.contact_angle`, with the
    full model even when the forces come from the surrogate)::

        z*_j = r (1 − cos θ0(W_j, |i_j|))      (static at i = 0, dynamic: deeper with slip)

    ≈ 14–17 mm for Table II's soil at 40–60 N (≈ 0.2 mm/N; + 0.5 mm from
    i = 0 to 0.4). The depth follows z* (held over the step with W) as a
    critically damped second-order lag s̈ = ω² (z* − s) − 2ω ṡ, solved in
    closed form within the step, so s and ṡ are continuous and the constraint
    sees no velocity jump. Its rate is asymmetric, as a plastic soil is:
    a rising load presses the soil under the rim at once (ω = 1 /
    ``sinkage_loading_time``, 0.1 s: quasi-static pressure–sinkage, smoothed
    over five control steps; a first-order lag with the load held over the
    step fed the constraint's Baumgarte force back into W and diverged); a
    falling load leaves a compacted rut that does not spring back, and the
    rim climbs onto fresh soil over about one contact length r sin θ0 of
    travel (ω = |v_t| / (r sin θ0), ≈ 0.5 s⁻¹ at 2 cm/s). ṡ enters Ψ̇, s̈ the
    constraint acceleration ζ. The soil forces keep acting in the frame of
    the undisturbed surface (γ from the path slope), so a sinking centre
    moves at atan(ṡ/v) off the γ it reports. Off: bit-identical to the
    plant without sinkage.

What is held over a 50 Hz step, and why
    As in the paper, the wheel torques τ_W (PID at 50 Hz) and the normal loads
    W are held over a control step while the slip evolves continuously: DP
    and τ_R are very sensitive to slip (the paper's reason for ode45). With
    Table II's soil dDP/di ≈ 30 N per wheel at W ≈ 50 N and ∂i/∂v = −1/(r_w ω)
    ≈ −43 s/m at 2 cm/s, so the forward speed relaxes to its slip equilibrium
    with a time constant of ≈ 4 ms: holding DP itself over 20 ms would be
    unstable. The terramechanics is therefore evaluated **once per step**, in
    one vectorised call, at the held load W_j and three slips i_j − δ, i_j,
    i_j + δ (δ = :attr:`RoverScenario.slip_stencil`); DP(i) and τ_R(i) in the
    step are the quadratics through those points, evaluated at the current
    slip of every integration stage (the slip moves by ≲ 1e-3 in a step, so
    the quadratic is exact to far below the surrogate's own error).

    W_j is λ_j at the start of the step (evaluated with the new wheel
    torques and the previous step's DP/τ_R model — the algebraic loop W → DP →
    λ is broken by this one-step hold, as in the paper's "previously evaluated
    generalized constraint forces"). A wheel with W_j ≤ 0 has lifted off: it
    gets no soil force (DP = τ_R = 0) and reports W_j = 0; the path constraint
    itself stays bilateral (the paper's model), so the wheel centre cannot
    leave the path. Loads above what the wheel can carry are saturated:
    the full model at θ0 = π/2 (``overload="saturate"``), the surrogate at
    the 200 N edge of its fitting grid.

    The load cells read the contact force that acts at the sample: DP of
    this step's model and the normal load of λ evaluated with it. The held
    W_j is the soil model's input; the two agree to ≈ 4e-4 N (median) except
    at the sample where a wheel enters another soil, where DP jumps and λ
    with it (0.5–3 N). Until session 7 the cells reported the held W_j: a
    40–50 σ spike in the replay of a soil change that no real cell makes.

Slip (eqs. 1–2)
    From the wheel's absolute spin θ̇ + q̇1 + q̇_j (θ̇ + q̇4 for the front wheel)
    and the centre's speed along the path tangent, clipped to [−1, 1]
    (:func:`~terrain_estimation.models.rover.slip_from_motion`); a stalled
    rover sliding back under turning wheels is at full slip i = 1, so the
    soil pushes it forward. The estimator uses the relative rate q̇_j (eq. 68);
    the difference is the carrier rate.

Wheel-speed control (Table III)
    A discrete PID per wheel at 50 Hz on the rim-speed error
    e = v_d − r_w q̇_j (m/s), the quantity the paper names, with the gains
    applied per sample as Table III's unit column ("–") suggests::

        τ_W,k = K_p e_k + K_i Σ_{m≤k} e_m + K_d (e_k − e_{k−1})      (N·m)

    (continuous-time equivalents K_i/T = 25 N·m/m, K_d·T = 0.25 N·m·s²/m).
    Other readings of Table III: with continuous-time gains on e in m/s the
    integral is too weak to reach v_d within a run (the ≈ 1.7 N·m of steady
    wheel torque needs ≈ 3 m of accumulated rim-speed error); with e in rad/s
    and the derivative per second the loop is unstable at 50 Hz (K_d/I_wg =
    11.6 > 1 with one sample of delay); e in rad/s with per-sample gains is
    stable and 1/r_w ≈ 13 times stiffer (scale the gains to get it). Output
    saturated at ±:attr:`RoverController.max_torque`
    with conditional integration (no wind-up). The controller reads the true
    relative wheel rates (the 1400:1 motor encoders resolve them far better
    than the estimator needs).

Start
    The rover starts rolling in a steady state at O's x = :attr:`RoverScenario.start_x`:
    all three wheel centres on the path (Newton on z0, θ, q1), the velocity
    along the constraint manifold, wheel rates at v_d / r_w, body speed
    v_d (1 − i0) with the common slip i0 that balances the forces along the
    path, PID integrators preloaded with τ_R + b_d q̇. (The steady-state soil
    model has DP(i = 0) < 0: a rover at rest would be pushed backward, so
    starting from rest is not modelled.)

Integration
    Classical RK4 over each 20 ms control step, divided into the smallest
    number of equal steps ≤ :attr:`RoverScenario.integration_step` and more
    when the slip modes demand it (estimate λ ≈ Σ|dDP/di| |∂i/∂v| / m +
    |dτ_R/di| |∂i/∂ω| / I_wg, step ≤ 1.5/λ; λ ≈ 350 s⁻¹ while rolling at
    2 cm/s, far more near standstill). The default 2 ms puts the Baumgarte
    mode at λΔt = 1 (RK4 is stable to 2.78). Measured against 0.5 ms steps
    over 30 s on terrains 1 and 6 (surrogate soil): 2 ms → |ΔW| ≤ 1e-4 N,
    |Δi| ≤ 1e-6, |ΔDP| ≤ 3e-5 N, |Δf| ≤ 1e-5 m/s², |Ψ| ≤ 5e-11 m; 4 ms
    (about 1.5× faster) → |ΔW| ≤ 4e-3 N, |Δi| ≤ 6e-5, |Δf| ≤ 4e-4 m/s² (a
    third of the accelerometer's σ), |Ψ| ≤ 3e-9 m.

Sensors (Table IV, MODELS.md C.4) at 50 Hz, unbiased Gaussian noise unless an
    effect adds bias: bogie angle q1, pitch rate θ̇ (about +y), velocimeter
    ẋ0^R = ẋ0 cos θ − ż0 sin θ, body specific force (eqs. 72–73, REP 145: +g
    on z at rest), wheel angles q2…q4, load cells F_L and F_⊥ (eqs. 81–82 with
    the true W, DP, γ, ε), effort = applied wheel torque τ_W (no noise). A
    sample at t_k reports the state at t_k and the torque applied from t_k on.

Effects (:class:`RoverEffects`, all off by default): load-cell bias and
    cross-talk, IMU biases, sensor delay, a soil change at a given distance,
    slip-sinkage, grousers and a short-wavelength undulation of the wheel
    path. The vertical body velocity the estimator ignores is always present
    (terrain-induced); the undulation makes it larger. With every effect off
    the plant is bit-identical to the nominal one (each effect is a separate
    branch that is skipped when off). The catalogue with fit ranges is
    :mod:`vehicle_sim.effects`.

    Slip-sinkage (``slip_sinkage_coefficient`` c ≥ 0, –): the pressure–sinkage
        moduli (k1, k2 of eqs. 4–5, i.e. Bekker's k_c, k_φ) fall with slip,
        k_eff = k / (1 + c |i|), so a slipping wheel sinks deeper than the
        static pressure–sinkage law says (Lyasko 2010's slip-sinkage; Ding et
        al. 2011 obtain the same trend by raising n with slip). Implemented
        at the force level, so it works with the full model and the surrogate
        alike: with zero cohesion every stress of eqs. 4–6 scales with k at a
        given θ0, hence W, DP and τ_R do too, and a wheel on modulus s·k at
        load W has the θ0 of a wheel on modulus k at load W/s with forces
        s × those. With s = 1/(1 + c |i|) the soil model is evaluated at
        W (1 + c |i|) and its DP, τ_R are divided by 1 + c |i| (θ0 is the
        model's own). Cohesion breaks the identity by ≈ c_soil/(σ tan φ)
        (≈ 1 % with Table II's soil at 50 N). The surrogate's 200 N cap
        applies to the scaled load.
    Grousers (``grouser_height`` h_g ≥ 0, m): the soil between the grousers
        moves with the wheel, so the shearing surface is the cylinder through
        the grouser tips (Wong, *Theory of Ground Vehicles*, lugged wheels;
        Ishigami et al. 2007 use the same effective radius). The soil model is
        evaluated for a rigid wheel of radius r_w + h_g (same width) at the
        tip slip i_g = 1 − (1 − i) r_w/(r_w + h_g) (the tip speed is
        (r_w + h_g) ω); its DP and τ_R (about the axle) act on the plant. The
        kinematics (path offset r_w, slip i) are unchanged: the rim rests on
        the terrain and the grousers dig into it. The surrogate is fitted for
        the larger wheel (≈ 0.5 s, cached).
    Path undulation (``path_undulation_amplitude`` A ≥ 0, m,
        ``path_undulation_wavelength`` λ > 0, m): A (1 − cos(2π x/λ)) is added
        to the terrain's wheel-centre path (:attr:`RoverScenario.path`):
        short-wavelength ground roughness that moves the body vertically
        (ż0^R ≠ 0, what the estimators assume away, eq. 45) and adds terrain
        curvature A (2π/λ)², which must stay below 1/r_w (smooth terrain
        under the rim).

Units: SI throughout (m, s, kg, rad, N, N·m).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.lapack import dgesv

from terrain_estimation.models.rover import (
    WHEELS,
    RoverParams,
    body_specific_force,
    carrier_angles,
    dynamics_terms,
    load_cell_forces,
    slip_from_motion_scalar,
    wheel_centres,
)
from vehicle_sim.terrain.terramechanics_surrogate import SURROGATE_LOAD_RANGE, terramechanics_surrogate
from vehicle_sim.terrain.wong_reece import (
    DEFAULT_SIMPSON_POINTS,
    TABLE_II_SOIL,
    RigidWheel,
    WongReeceSoil,
    contact_angle,
    wheel_forces,
)

__all__ = [
    "CONTROL_RATE",
    "TERRAINS",
    "TERRAIN_NUMBERS",
    "RoverController",
    "RoverEffects",
    "RoverRun",
    "RoverSample",
    "RoverScenario",
    "RoverSensorNoise",
    "RoverSensors",
    "RoverSimulator",
    "RoverTruth",
    "TerramechanicsName",
    "WHEELS",
    "WheelPath",
    "flat_path",
    "rolling_path",
    "simulate_rover",
    "slope_path",
    "solve_configuration",
    "step_path",
    "undulated_path",
]

Array = NDArray[np.float64]
TerramechanicsName = Literal["wong_reece", "surrogate"]

CONTROL_RATE = 50.0
"""PID, recording and sensor rate (Hz), [RB] III-C."""

_N_WHEELS = 3
_STATE_SIZE = 14  # [g (7), ġ (7)]
#: Largest λ Δt of the slip modes per RK4 step (RK4 is stable to 2.78 on the negative real axis).
_SLIP_MODE_STEP_LIMIT = 1.5


def _check_finite(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value)):
        raise ValueError(f"{owner}.{name} must be finite, got {value!r}")


def _check_positive(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
        raise ValueError(f"{owner}.{name} must be finite and > 0, got {value!r}")


def _check_non_negative(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
        raise ValueError(f"{owner}.{name} must be finite and ≥ 0, got {value!r}")


def _finite_tuple(owner: str, name: str, value: Sequence[float], size: int) -> tuple[float, ...]:
    result = tuple(float(v) for v in value)
    if len(result) != size or not all(math.isfinite(v) for v in result):
        raise ValueError(f"{owner}.{name} must be {size} finite values, got {value!r}")
    return result


# ---------------------------------------------------------------------------
# Wheel-centre paths (Fig. 10)
# ---------------------------------------------------------------------------

Profile = Callable[[Array], tuple[Array, Array, Array]]
PointProfile = Callable[[float], tuple[float, float, float]]


@dataclass(frozen=True, kw_only=True)
class WheelPath:
    """A wheel-centre path z_wc(x) (eqs. 25–26) with its slope and second derivative.

    The terrain is the path offset by r_w along its normal (eq. 25). Every
    path here is C² (C¹ is what the constraint needs; C² gives a continuous
    curvature and constraint acceleration).

    Attributes:
        name: key in :data:`TERRAINS`.
        description: what it is and which figure it reproduces.
        duration: simulated time the run is meant to take (s) at v_d = 2 cm/s.
        profile: x (m) → (z, dz/dx, d²z/dx²), vectorised.
        point: the same for one float x, in plain floats (the plant's inner
            loop evaluates three points four times per integration step).
    """

    name: str
    description: str
    duration: float
    profile: Profile
    point: PointProfile

    def evaluate(self, x: ArrayLike) -> tuple[Array, Array, Array]:
        """(z_wc (m), dz_wc/dx (–), d²z_wc/dx² (1/m)) at x (m)."""
        return self.profile(np.asarray(x, dtype=float))

    def height(self, x: ArrayLike) -> Array:
        """z_wc(x) (m)."""
        return self.evaluate(x)[0]

    def slope(self, x: ArrayLike) -> Array:
        """dz_wc/dx (–)."""
        return self.evaluate(x)[1]

    def contact_angle(self, x: ArrayLike) -> Array:
        """γ = −atan(dz_wc/dx) (rad), positive downhill (module docstring)."""
        return -np.arctan(self.evaluate(x)[1])

    def curvature(self, x: ArrayLike) -> Array:
        """Signed curvature of the wheel-centre path κ = z''/(1 + z'²)^(3/2) (1/m); > 0 in a hollow."""
        _, dz, d2z = self.evaluate(x)
        result: Array = d2z / (1.0 + dz**2) ** 1.5
        return result

    def terrain_curvature(self, x: ArrayLike, wheel_radius: float) -> Array:
        """Curvature of the terrain under a wheel centred at x: κ_t = κ/(1 + r_w κ) (1/m).

        The terrain is the path offset by r_w towards the soil: on a crest of
        path radius R it has radius R − r_w, in a hollow R + r_w. [RB] gates
        the estimates on κ < 1/l_w (MODELS.md C.7).
        """
        kappa = self.curvature(x)
        result: Array = kappa / (1.0 + wheel_radius * kappa)
        return result

    def terrain_points(self, x: ArrayLike, wheel_radius: float) -> tuple[Array, Array]:
        """(x_t, z_t) of the terrain under path point x, eq. 25 (m)."""
        x_ = np.asarray(x, dtype=float)
        z, dz, _ = self.evaluate(x_)
        norm = np.sqrt(1.0 + dz**2)
        return x_ + wheel_radius * dz / norm, z - wheel_radius / norm


def _smoothstep_ramps(
    x: Array, starts: Sequence[float], changes: Sequence[float], length: float
) -> tuple[Array, Array, Array]:
    """Σ_k Δs_k L I(u_k), Σ Δs_k S(u_k), Σ Δs_k S'(u_k)/L with u = (x − a_k)/L, S = 3u² − 2u³, I = ∫S."""
    z = np.zeros_like(x)
    dz = np.zeros_like(x)
    d2z = np.zeros_like(x)
    for start, change in zip(starts, changes, strict=True):
        u = np.clip((x - start) / length, 0.0, 1.0)
        beyond = np.maximum((x - start) / length - 1.0, 0.0)
        z += change * length * (u**3 - 0.5 * u**4 + beyond)
        dz += change * (3.0 * u**2 - 2.0 * u**3)
        d2z += change * 6.0 * u * (1.0 - u) / length
    return z, dz, d2z


def flat_path(duration: float = 60.0) -> WheelPath:
    """Level ground at z_wc = 0 (not one of Fig. 10's terrains; the reference case of the tests)."""

    def profile(x: Array) -> tuple[Array, Array, Array]:
        zeros = np.zeros_like(x)
        return zeros, zeros.copy(), zeros.copy()

    def point(x: float) -> tuple[float, float, float]:
        return 0.0, 0.0, 0.0

    return WheelPath(name="flat", description="level ground", duration=duration, profile=profile, point=point)


#: Terrain 1 [recon]: two cosine undulations, (amplitude (m), wavelength (m)).
ROLLING_COMPONENTS: tuple[tuple[float, float], ...] = ((0.05, 2.4), (0.012, 0.9))


def rolling_path(duration: float = 200.0) -> WheelPath:
    """Fig. 10 terrain 1, gently rolling [recon]: z = Σ A (1 − cos(2π x/λ)) of :data:`ROLLING_COMPONENTS`.

    200 s as in the paper (≈ 3.4 m at 2 cm/s and ≈ 15 % slip). Level at
    x = 0; |κ| ≤ 0.92 m⁻¹ < 1/l_w = 1.43 m⁻¹, slope ≤ 12°.
    """
    components = ROLLING_COMPONENTS

    def profile(x: Array) -> tuple[Array, Array, Array]:
        z = np.zeros_like(x)
        dz = np.zeros_like(x)
        d2z = np.zeros_like(x)
        for amplitude, wavelength in components:
            k = 2.0 * math.pi / wavelength
            z += amplitude * (1.0 - np.cos(k * x))
            dz += amplitude * k * np.sin(k * x)
            d2z += amplitude * k * k * np.cos(k * x)
        return z, dz, d2z

    def point(x: float) -> tuple[float, float, float]:
        z = dz = d2z = 0.0
        for amplitude, wavelength in components:
            k = 2.0 * math.pi / wavelength
            c, s = math.cos(k * x), math.sin(k * x)
            z += amplitude * (1.0 - c)
            dz += amplitude * k * s
            d2z += amplitude * k * k * c
        return z, dz, d2z

    return WheelPath(
        name="rolling",
        description="Fig. 10 terrain 1: gently rolling",
        duration=duration,
        profile=profile,
        point=point,
    )


#: Terrains 2–3 [recon]: where the slope starts changing (m), transition length (m).
SLOPE_TRANSITIONS: tuple[float, ...] = (0.5, 1.8)
SLOPE_TRANSITION_LENGTH = 0.3


def slope_path(direction: Literal[1, -1] = 1, duration: float = 200.0) -> WheelPath:
    """Fig. 10 terrains 2 (uphill, ``direction=1``) and 3 (downhill, ``-1``) [recon].

    Level up to x = 0.5 m, 4° from 0.8 m to 1.8 m, 8° from 2.1 m on; the slope
    (dz/dx = tan of the angle) changes over 0.3 m by a cubic smoothstep, so
    |κ| ≤ 1.5 Δ(tan)/0.3 m ≈ 0.36 m⁻¹. 200 s take the whole rover onto the
    8° stretch uphill (slip ≈ 0.4 there) and downhill.
    """
    sign = float(direction)
    if sign not in (1.0, -1.0):
        raise ValueError(f"direction must be 1 (uphill) or -1 (downhill), got {direction}")
    slopes = [0.0, math.tan(math.radians(4.0)), math.tan(math.radians(8.0))]
    changes = [sign * (b - a) for a, b in zip(slopes[:-1], slopes[1:], strict=True)]

    def profile(x: Array) -> tuple[Array, Array, Array]:
        return _smoothstep_ramps(x, SLOPE_TRANSITIONS, changes, SLOPE_TRANSITION_LENGTH)

    def point(x: float) -> tuple[float, float, float]:
        length = SLOPE_TRANSITION_LENGTH
        z = dz = d2z = 0.0
        for start, change in zip(SLOPE_TRANSITIONS, changes, strict=True):
            u = (x - start) / length
            if u <= 0.0:
                continue
            if u >= 1.0:
                z += change * length * (u - 0.5)
                dz += change
                continue
            z += change * length * (u**3 - 0.5 * u**4)
            dz += change * (3.0 * u * u - 2.0 * u**3)
            d2z += change * 6.0 * u * (1.0 - u) / length
        return z, dz, d2z

    name, word = ("uphill", "uphill 0°, 4°, 8°") if sign > 0 else ("downhill", "downhill 0°, −4°, −8°")
    number = 2 if sign > 0 else 3
    return WheelPath(
        name=name,
        description=f"Fig. 10 terrain {number}: {word}",
        duration=duration,
        profile=profile,
        point=point,
    )


#: Terrains 4–6: step height (m) = half the wheel diameter, step position (m).
STEP_HEIGHT = 0.075
STEP_POSITION = 0.6
#: Logistic widths w (m) of terrains 4, 5, 6 [recon]: max |κ| ≈ 0.5, 1.0, 2.0 m⁻¹.
STEP_WIDTHS: tuple[float, float, float] = (0.12, 0.085, 0.06)


def step_path(width: float, *, name: str = "step", duration: float = 100.0) -> WheelPath:
    """Fig. 10 terrains 4–6: a 75 mm step up (half a wheel diameter) shaped by a logistic sigmoid [recon].

    z = h σ((x − x_s)/w), σ(u) = 1/(1 + e^(−u)), h = 75 mm, x_s = 0.6 m. The
    transition shrinks with w: 0.12 m (terrain 4), 0.085 m (5), 0.06 m (6);
    max |κ| ≈ 0.096 h/w² (0.5, 1.0, 2.0 m⁻¹) is below 1/l_w = 1.43 m⁻¹ on 4
    and 5 and above it on 6, which the paper excludes from the model fit for
    that reason (C.7); the steepest slope h/(4w) is 9°, 12°, 17°. 100 s carry
    the rear wheel over the step.
    """
    _check_positive("step_path", "width", width)
    height = STEP_HEIGHT

    def profile(x: Array) -> tuple[Array, Array, Array]:
        u = (x - STEP_POSITION) / width
        sigma = 0.5 * (1.0 + np.tanh(0.5 * u))  # logistic, overflow-free
        d1 = sigma * (1.0 - sigma)
        return height * sigma, height * d1 / width, height * d1 * (1.0 - 2.0 * sigma) / width**2

    def point(x: float) -> tuple[float, float, float]:
        sigma = 0.5 * (1.0 + math.tanh(0.5 * (x - STEP_POSITION) / width))
        d1 = sigma * (1.0 - sigma)
        return height * sigma, height * d1 / width, height * d1 * (1.0 - 2.0 * sigma) / width**2

    return WheelPath(
        name=name,
        description=f"75 mm sigmoid step, width {width:g} m",
        duration=duration,
        profile=profile,
        point=point,
    )


def undulated_path(path: WheelPath, amplitude: float, wavelength: float) -> WheelPath:
    """``path`` plus A (1 − cos(2π x/λ)) (m): the path-undulation effect (:class:`RoverEffects`).

    Level and unchanged at x = 0; adds at most 2A to the height and A (2π/λ)²
    to the curvature. Keeps the name and duration of ``path``.
    """
    _check_non_negative("undulated_path", "amplitude", amplitude)
    _check_positive("undulated_path", "wavelength", wavelength)
    k = 2.0 * math.pi / wavelength
    base_profile, base_point = path.profile, path.point

    def profile(x: Array) -> tuple[Array, Array, Array]:
        z, dz, d2z = base_profile(x)
        return (
            z + amplitude * (1.0 - np.cos(k * x)),
            dz + amplitude * k * np.sin(k * x),
            d2z + amplitude * k * k * np.cos(k * x),
        )

    def point(x: float) -> tuple[float, float, float]:
        z, dz, d2z = base_point(x)
        c, s = math.cos(k * x), math.sin(k * x)
        return z + amplitude * (1.0 - c), dz + amplitude * k * s, d2z + amplitude * k * k * c

    return WheelPath(
        name=path.name,
        description=f"{path.description}, undulation {amplitude:g} m / {wavelength:g} m",
        duration=path.duration,
        profile=profile,
        point=point,
    )


def _terrain(number: int, builder: Callable[[], WheelPath]) -> Callable[[], WheelPath]:
    def build() -> WheelPath:
        path = builder()
        return WheelPath(
            name=path.name,
            description=f"Fig. 10 terrain {number}: {path.description}" if number >= 4 else path.description,
            duration=path.duration,
            profile=path.profile,
            point=path.point,
        )

    return build


TERRAINS: Mapping[str, Callable[[], WheelPath]] = MappingProxyType(
    {
        "flat": flat_path,
        "rolling": rolling_path,
        "uphill": lambda: slope_path(1),
        "downhill": lambda: slope_path(-1),
        "step_wide": _terrain(4, lambda: step_path(STEP_WIDTHS[0], name="step_wide")),
        "step_medium": _terrain(5, lambda: step_path(STEP_WIDTHS[1], name="step_medium")),
        "step_sharp": _terrain(6, lambda: step_path(STEP_WIDTHS[2], name="step_sharp")),
    }
)
"""Named path constructors; Fig. 10's terrains 1–6 plus ``flat``."""

TERRAIN_NUMBERS: Mapping[int, str] = MappingProxyType(
    {1: "rolling", 2: "uphill", 3: "downhill", 4: "step_wide", 5: "step_medium", 6: "step_sharp"}
)
"""[RB] Fig. 10 terrain number → :data:`TERRAINS` key."""


# ---------------------------------------------------------------------------
# Controller, sensors, effects, scenario
# ---------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class RoverController:
    """Per-wheel discrete PID on the rim speed r_w q̇_j (Table III; form in the module docstring).

    Attributes:
        proportional_gain: K_p (N·m per m/s).
        integral_gain: K_i (N·m per m/s, per sample of the running sum).
        derivative_gain: K_d (N·m per m/s of change between samples).
        max_torque: saturation of τ_W at the wheel (N·m) [recon: the paper
            gives none; 10 N·m exceeds τ_R at 200 N and full slip, 7.9 N·m].
    """

    proportional_gain: float = 25.0
    integral_gain: float = 0.5
    derivative_gain: float = 12.5
    max_torque: float = 10.0

    def __post_init__(self) -> None:
        for name in ("proportional_gain", "integral_gain", "derivative_gain"):
            _check_non_negative("RoverController", name, getattr(self, name))
        _check_positive("RoverController", "max_torque", self.max_torque)


@dataclass(frozen=True, kw_only=True)
class RoverSensorNoise:
    """Sensor noise σ of [RB] Table IV in SI units (one LSB / 6 for the digital sensors).

    Attributes:
        bogie_angle_std: 16-bit absolute encoder, 9.155e-4° (rad).
        pitch_rate_std: IMU gyro, 0.56 °/s (rad/s).
        forward_velocity_std: optic-flow velocimeter, 1 mm/s (m/s).
        acceleration_std: IMU accelerometer per axis, 1.245e-3 m/s².
        wheel_angle_std: 500-count quadrature encoder behind 1400:1, 2.143e-5° (rad).
        load_cell_std: 200 N full scale, 10-bit ADC, 3.255e-2 N (both axes).
        quantise: round the encoders and load cells to their LSB (2π/2¹⁶,
            2π/(4·500·1400), 200 N/1024) instead of adding their Gaussian
            noise (the paper adds Gaussian noise).
    """

    bogie_angle_std: float = math.radians(9.155e-4)
    pitch_rate_std: float = math.radians(0.56)
    forward_velocity_std: float = 1.0e-3
    acceleration_std: float = 1.245e-3
    wheel_angle_std: float = math.radians(2.143e-5)
    load_cell_std: float = 3.255e-2
    quantise: bool = False

    def __post_init__(self) -> None:
        for name in (
            "bogie_angle_std",
            "pitch_rate_std",
            "forward_velocity_std",
            "acceleration_std",
            "wheel_angle_std",
            "load_cell_std",
        ):
            _check_non_negative("RoverSensorNoise", name, getattr(self, name))

    @classmethod
    def noiseless(cls) -> RoverSensorNoise:
        """No noise anywhere."""
        return cls(
            bogie_angle_std=0.0,
            pitch_rate_std=0.0,
            forward_velocity_std=0.0,
            acceleration_std=0.0,
            wheel_angle_std=0.0,
            load_cell_std=0.0,
        )


#: LSBs of the digital sensors (Table IV footnotes).
BOGIE_ENCODER_STEP = 2.0 * math.pi / 2**16
WHEEL_ENCODER_STEP = 2.0 * math.pi / (4 * 500 * 1400)
LOAD_CELL_STEP = 200.0 / 1024


@dataclass(frozen=True, kw_only=True)
class RoverEffects:
    """Sim-to-real effects, all off by default (the nominal plant).

    Attributes:
        load_cell_bias: constant offset of each axial load cell F_L (N), (rear, middle, front).
        load_cell_crosstalk: fraction c of each axis leaking into the other:
            F_L + c F_⊥ and F_⊥ + c F_L (–).
        imu_accel_bias: accelerometer bias (x, z) in the body frame (m/s²).
        imu_gyro_bias: pitch-rate gyro bias (rad/s).
        sensor_delay: latency of every measured channel (s), rounded to whole
            samples (20 ms); the effort (commanded torque) is not delayed.
        soil_change_distance: wheel-centre x (m) beyond which a wheel runs on
            ``soil_change_soil`` instead of the scenario's soil; None: no change.
        soil_change_soil: the soil after the change.
        slip_sinkage_coefficient: c of k_eff = k/(1 + c |i|) (–), module docstring.
        grouser_height: h_g, grouser height above the rim (m), module docstring.
        path_undulation_amplitude: A of the undulation A (1 − cos(2π x/λ)) added
            to the wheel-centre path (m); 0: none.
        path_undulation_wavelength: λ of that undulation (m).
    """

    load_cell_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    load_cell_crosstalk: float = 0.0
    imu_accel_bias: tuple[float, float] = (0.0, 0.0)
    imu_gyro_bias: float = 0.0
    sensor_delay: float = 0.0
    soil_change_distance: float | None = None
    soil_change_soil: WongReeceSoil | None = None
    slip_sinkage_coefficient: float = 0.0
    grouser_height: float = 0.0
    path_undulation_amplitude: float = 0.0
    path_undulation_wavelength: float = 0.5

    def __post_init__(self) -> None:
        owner = "RoverEffects"
        _check_non_negative(owner, "slip_sinkage_coefficient", self.slip_sinkage_coefficient)
        _check_non_negative(owner, "grouser_height", self.grouser_height)
        _check_non_negative(owner, "path_undulation_amplitude", self.path_undulation_amplitude)
        _check_positive(owner, "path_undulation_wavelength", self.path_undulation_wavelength)
        object.__setattr__(self, "load_cell_bias", _finite_tuple(owner, "load_cell_bias", self.load_cell_bias, 3))
        object.__setattr__(self, "imu_accel_bias", _finite_tuple(owner, "imu_accel_bias", self.imu_accel_bias, 2))
        _check_finite(owner, "load_cell_crosstalk", self.load_cell_crosstalk)
        _check_finite(owner, "imu_gyro_bias", self.imu_gyro_bias)
        _check_non_negative(owner, "sensor_delay", self.sensor_delay)
        if (self.soil_change_distance is None) != (self.soil_change_soil is None):
            raise ValueError(f"{owner}: soil_change_distance and soil_change_soil must be given together")
        if self.soil_change_distance is not None:
            _check_finite(owner, "soil_change_distance", self.soil_change_distance)

    @property
    def active(self) -> tuple[str, ...]:
        """Names of the effects that are switched on."""
        reference = RoverEffects()
        return tuple(name for name in self.__dataclass_fields__ if getattr(self, name) != getattr(reference, name))


@dataclass(frozen=True, kw_only=True)
class RoverScenario:
    """One run of the rover over a terrain of :data:`TERRAINS`.

    Attributes:
        terrain: key of :data:`TERRAINS`.
        duration: simulated time (s); None takes the terrain's.
        seed: seed of the sensor noise (the truth never depends on it).
        terramechanics: ``"surrogate"`` (the paper's simulation, 4th-order
            polynomial) or ``"wong_reece"`` (the full model, root-finding).
        desired_speed: v_d (m/s), Table III.
        params: rover parameters.
        soil: Wong–Reece soil (Table II); the surrogate is fitted to it.
        controller: wheel-speed PID.
        sensors: sensor noise.
        effects: sim-to-real effects.
        baumgarte_alpha, baumgarte_beta: α, β of eq. 31 (Table III).
        integration_step: largest RK4 step (s); 2 ms keeps the truth converged to ≤ 1e-4 N (module docstring).
        slip_stencil: δ of the per-step slip quadratic (module docstring).
        start_x: world x of O at t = 0 (m).
        simpson_points: rim nodes per flow region of the full model.
        wheel_sinkage: sink each wheel into the soil by its Wong–Reece sinkage
            (module docstring "Sinkage"); False: the wheel centres ride on the
            path offset r_w from the terrain (the plant before issue 21).
        sinkage_loading_time: time constant of the sinkage following a rising
            load or slip (s), > 0; 0.1 s by default (module docstring).
    """

    terrain: str = "rolling"
    duration: float | None = None
    seed: int = 0
    terramechanics: TerramechanicsName = "surrogate"
    desired_speed: float = 0.02
    params: RoverParams = field(default_factory=RoverParams)
    soil: WongReeceSoil = TABLE_II_SOIL
    controller: RoverController = field(default_factory=RoverController)
    sensors: RoverSensorNoise = field(default_factory=RoverSensorNoise)
    effects: RoverEffects = field(default_factory=RoverEffects)
    baumgarte_alpha: float = 500.0
    baumgarte_beta: float = 500.0
    integration_step: float = 2.0e-3
    slip_stencil: float = 0.02
    start_x: float = 0.0
    simpson_points: int = DEFAULT_SIMPSON_POINTS
    wheel_sinkage: bool = True
    sinkage_loading_time: float = 0.1

    def __post_init__(self) -> None:
        owner = "RoverScenario"
        _check_positive(owner, "sinkage_loading_time", self.sinkage_loading_time)
        if self.terrain not in TERRAINS:
            raise ValueError(f"{owner}.terrain must be one of {sorted(TERRAINS)}, got {self.terrain!r}")
        if self.duration is not None:
            _check_positive(owner, "duration", self.duration)
        if self.terramechanics not in ("surrogate", "wong_reece"):
            raise ValueError(f"{owner}.terramechanics must be 'surrogate' or 'wong_reece', got {self.terramechanics!r}")
        _check_positive(owner, "desired_speed", self.desired_speed)
        _check_non_negative(owner, "baumgarte_alpha", self.baumgarte_alpha)
        _check_non_negative(owner, "baumgarte_beta", self.baumgarte_beta)
        _check_positive(owner, "integration_step", self.integration_step)
        if not (0.0 < self.slip_stencil <= 0.1):
            raise ValueError(f"{owner}.slip_stencil must be in (0, 0.1], got {self.slip_stencil!r}")
        _check_finite(owner, "start_x", self.start_x)
        amplitude = self.effects.path_undulation_amplitude
        if amplitude > 0.0:
            curvature = amplitude * (2.0 * math.pi / self.effects.path_undulation_wavelength) ** 2
            if curvature * self.params.wheel_radius >= 1.0:
                raise ValueError(
                    f"{owner}.effects: path undulation curvature A (2π/λ)² = {curvature:.3g} 1/m must be below "
                    f"1/r_w = {1.0 / self.params.wheel_radius:.3g} 1/m"
                )

    @property
    def path(self) -> WheelPath:
        """The wheel-centre path of :attr:`terrain`, with the path-undulation effect if it is on."""
        path = TERRAINS[self.terrain]()
        amplitude = self.effects.path_undulation_amplitude
        if amplitude > 0.0:
            path = undulated_path(path, amplitude, self.effects.path_undulation_wavelength)
        return path

    @property
    def run_duration(self) -> float:
        """Simulated time (s): ``duration`` or the terrain's."""
        return self.path.duration if self.duration is None else self.duration

    @property
    def n_samples(self) -> int:
        """Samples of the run at 50 Hz (t = 0 … duration − T)."""
        return max(1, int(round(self.run_duration * CONTROL_RATE)))


# ---------------------------------------------------------------------------
# Samples and runs
# ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RoverSensors:
    """Sensor readings of one sample (scalars / (3,) / (2,)), or stacked (N, …) in a run.

    Attributes:
        bogie_angle: q̌1 (rad).
        pitch_rate: θ̇̌0y about +y (rad/s).
        forward_velocity: ẋ̌0^R along the body x axis (m/s).
        acceleration: (x, z) body-frame specific force (m/s², eqs. 72–73).
        wheel_angle: q̌2…q̌4 relative to the carriers (rad), (3,).
        load_axial: F̌_L per wheel (N), (3,), the single-axis cells.
        load_perpendicular: F̌_⊥ per wheel (N), (3,), the second axis.
        effort: applied wheel torque τ_W (N·m), (3,).
    """

    bogie_angle: Any
    pitch_rate: Any
    forward_velocity: Any
    acceleration: Any
    wheel_angle: Any
    load_axial: Any
    load_perpendicular: Any
    effort: Any


@dataclass(frozen=True, slots=True)
class RoverTruth:
    """What only the simulator knows; per-wheel arrays in :data:`WHEELS` order.

    Attributes:
        configuration: g (7,).
        velocity: ġ (7,).
        acceleration: g̈ (7,).
        pitch, pitch_rate, bogie_angle: θ (rad), θ̇ (rad/s), q1 (rad).
        forward_velocity: ẋ0^R (m/s), body x.
        vertical_velocity: ż0^R (m/s), body z (what eq. 45 assumes zero).
        specific_force: (x, z) body frame (m/s²), eqs. 72–73.
        slip: i per wheel (–), eqs. 1–2.
        normal_load: W per wheel (N), held over the step.
        drawbar_pull: DP per wheel (N) at (W, i).
        resistive_torque: τ_R per wheel (N·m) at (W, i).
        contact_angle: γ per wheel (rad), positive downhill: the slope of the
            undisturbed terrain surface under the wheel (the soil forces act
            in its frame), not the direction the sinking centre moves in.
        entry_angle: Wong–Reece θ0 per wheel (rad); NaN with the surrogate.
        sinkage: depth of each wheel centre below its path, i.e. of the rim's
            lowest point below the undisturbed surface (m), module docstring
            "Sinkage"; 0 without ``wheel_sinkage``.
        carrier_angle: ε per wheel (rad).
        wheel_rate: absolute wheel spin θ̇ (+ q̇1) + q̇_j (rad/s).
        wheel_centre: (3, 2) world (x, z) (m).
        wheel_centre_velocity: (3, 2) world (ẋ, ż) (m/s).
        path_curvature: κ of the wheel-centre path under each wheel (1/m).
        terrain_curvature: κ_t of the terrain under each wheel (1/m).
        constraint_residual: Ψ (m).
        vertical_reaction: λ (N), eq. 30.
        load_axial, load_perpendicular: noise-free F_L, F_⊥ (N), eqs. 81–82, of the
            contact force that acts at the sample (its normal load from λ, not the held W).
        wheel_torque: τ_W applied from this sample on (N·m).
        soil_index: 0 = scenario soil, 1 = changed soil (effect), per wheel.
        substeps: RK4 steps of the coming control step.
    """

    configuration: Any
    velocity: Any
    acceleration: Any
    pitch: Any
    pitch_rate: Any
    bogie_angle: Any
    forward_velocity: Any
    vertical_velocity: Any
    specific_force: Any
    slip: Any
    normal_load: Any
    drawbar_pull: Any
    resistive_torque: Any
    contact_angle: Any
    entry_angle: Any
    sinkage: Any
    carrier_angle: Any
    wheel_rate: Any
    wheel_centre: Any
    wheel_centre_velocity: Any
    path_curvature: Any
    terrain_curvature: Any
    constraint_residual: Any
    vertical_reaction: Any
    load_axial: Any
    load_perpendicular: Any
    wheel_torque: Any
    soil_index: Any
    substeps: Any


@dataclass(frozen=True, slots=True)
class RoverSample:
    """One 50 Hz sample: time, sensors, truth at t."""

    t: float
    sensors: RoverSensors
    truth: RoverTruth


@dataclass(frozen=True)
class RoverRun:
    """Stacked samples of one run (N = duration × 50 Hz, t = 0 … duration − T).

    Attributes:
        scenario: the scenario.
        time: (N,) s.
        sensors: readings with arrays (N,), (N, 2) or (N, 3).
        truth: truth with arrays (N, …).
    """

    scenario: RoverScenario
    time: Array
    sensors: RoverSensors
    truth: RoverTruth


# ---------------------------------------------------------------------------
# Terramechanics per step
# ---------------------------------------------------------------------------


class _Terramechanics:
    """(W, i, soil index) → (DP, τ_R, θ0) with the selected model, vectorised, overload saturated.

    The slip-sinkage and grouser effects act here (module docstring).
    """

    def __init__(self, scenario: RoverScenario) -> None:
        params = scenario.params
        effects = scenario.effects
        self.slip_sinkage = effects.slip_sinkage_coefficient
        self.grouser_height = effects.grouser_height
        # Slip at the grouser tips: i_g = 1 − (1 − i) r_w/(r_w + h_g).
        self.grouser_speed_ratio = params.wheel_radius / (params.wheel_radius + effects.grouser_height)
        self.wheel = RigidWheel(radius=params.wheel_radius + effects.grouser_height, width=params.wheel_width)
        soils = [scenario.soil]
        if scenario.effects.soil_change_soil is not None:
            soils.append(scenario.effects.soil_change_soil)
        self.soils = tuple(soils)
        self.kind = scenario.terramechanics
        self.simpson_points = scenario.simpson_points
        self._surrogates = (
            tuple(terramechanics_surrogate(soil, self.wheel) for soil in self.soils) if self.kind == "surrogate" else ()
        )

    def __call__(self, load: Array, slip: Array, soil_index: NDArray[np.int_]) -> tuple[Array, Array, Array]:
        load = np.maximum(load, 0.0)
        slip = np.clip(slip, -1.0, 1.0)
        model_load, model_slip = load, slip
        sinkage_scale: Array | None = None
        if self.slip_sinkage > 0.0:
            # k_eff = k/(1 + c|i|): forces at W are (model forces at W (1 + c|i|))/(1 + c|i|).
            sinkage_scale = 1.0 + self.slip_sinkage * np.abs(slip)
            model_load = load * sinkage_scale
        if self.grouser_height > 0.0:
            model_slip = 1.0 - (1.0 - slip) * self.grouser_speed_ratio
        dp = np.zeros_like(load)
        tau = np.zeros_like(load)
        entry = np.full_like(load, math.nan)
        for index in np.unique(soil_index):
            rows = soil_index == index
            if self.kind == "surrogate":
                # Saturated at the fitting grid's upper edge rather than extrapolated.
                capped = np.minimum(model_load[rows], SURROGATE_LOAD_RANGE[1])
                dp[rows], tau[rows] = self._surrogates[index].wheel_forces(capped, model_slip[rows])
            else:
                forces = wheel_forces(
                    model_load[rows],
                    model_slip[rows],
                    self.soils[index],
                    self.wheel,
                    simpson_points=self.simpson_points,
                    overload="saturate",
                )
                dp[rows], tau[rows], entry[rows] = forces
        if sinkage_scale is not None:
            dp /= sinkage_scale
            tau /= sinkage_scale
        lifted = load <= 0.0
        dp[lifted] = 0.0
        tau[lifted] = 0.0
        return dp, tau, entry

    def sinkage(self, load: Array, slip: Array, soil_index: NDArray[np.int_]) -> tuple[Array, Array]:
        """Steady sinkage z* (m) of the wheel centre below the undisturbed surface and the contact length (m).

        z* = r_e (1 − cos θ0(W, |i|)) − h_g from the Wong–Reece entry angle θ0 that
        carries the load at the slip (eq. 7; skid at |i|, as the forces of eqs.
        10–11), with the same slip-sinkage scaling and grouser cylinder
        (r_e = r_w + h_g) as the forces: the rim sinks once the grouser tips
        are h_g deep. The contact length is r_e sin θ0. Both models (full and
        surrogate) use the full model's θ0 here: the surrogate gives forces
        only. A lifted wheel (W ≤ 0) has z* = 0.
        """
        load = np.maximum(load, 0.0)
        model_slip = np.abs(np.clip(slip, -1.0, 1.0))
        model_load = load * (1.0 + self.slip_sinkage * model_slip) if self.slip_sinkage > 0.0 else load
        if self.grouser_height > 0.0:
            model_slip = 1.0 - (1.0 - model_slip) * self.grouser_speed_ratio
        theta0 = np.zeros_like(load)
        for index in np.unique(soil_index):
            rows = soil_index == index
            theta0[rows] = contact_angle(
                model_load[rows],
                model_slip[rows],
                self.soils[index],
                self.wheel,
                simpson_points=self.simpson_points,
                overload="saturate",
            )
        radius = self.wheel.radius
        depth: Array = np.maximum(radius * (1.0 - np.cos(theta0)) - self.grouser_height, 0.0)
        length: Array = radius * np.sin(theta0)
        return depth, length


@dataclass(frozen=True)
class _ForceModel:
    """What is held over one control step: wheel torques, loads and the slip quadratics of DP and τ_R.

    DP(i) = a0 + a1 (i − s) + a2 (i − s)², the same for τ_R, per wheel (evaluated in
    :meth:`_Equations._solve`).
    """

    wheel_torque: Array
    normal_load: Array
    centre: Array
    drawbar_pull: Array  # (3, 3): a0, a1, a2 per wheel
    resistive_torque: Array
    entry_angle: Array
    #: Sinkage over the step per wheel, (s0, ṡ0, z*, ω) of :func:`_sinkage_motion` (module docstring "Sinkage").
    sinkage: tuple[tuple[float, float, float, float], ...] = ((0.0, 0.0, 0.0, 0.0),) * _N_WHEELS
    wheel_torque_list: list[float] = field(init=False, repr=False)
    centre_list: list[float] = field(init=False, repr=False)
    drawbar_pull_list: list[list[float]] = field(init=False, repr=False)
    resistive_torque_list: list[list[float]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # Plain-float copies for the inner loop of :meth:`_Equations._solve`.
        object.__setattr__(self, "wheel_torque_list", np.asarray(self.wheel_torque, dtype=float).tolist())
        object.__setattr__(self, "centre_list", self.centre.tolist())
        object.__setattr__(self, "drawbar_pull_list", self.drawbar_pull.tolist())
        object.__setattr__(self, "resistive_torque_list", self.resistive_torque.tolist())

    def with_torque(self, torque: Array) -> _ForceModel:
        return replace(self, wheel_torque=torque)

    def sinkage_at(self, elapsed: float) -> tuple[Array, Array]:
        """(s, ṡ) per wheel (m, m/s), ``elapsed`` (s) from the start of the step."""
        motion = [_sinkage_motion(*row, elapsed) for row in self.sinkage]
        return np.array([m[0] for m in motion]), np.array([m[1] for m in motion])

    @classmethod
    def constant(
        cls,
        torque: Array,
        load: Array,
        drawbar_pull: Array,
        resistive_torque: Array,
        sinkage: Array | None = None,
    ) -> _ForceModel:
        zeros = np.zeros(_N_WHEELS)
        depth = zeros if sinkage is None else sinkage
        return cls(
            torque,
            load,
            zeros,
            np.stack([drawbar_pull, zeros, zeros], axis=1),
            np.stack([resistive_torque, zeros, zeros], axis=1),
            np.full(_N_WHEELS, math.nan),
            _static_sinkage(depth),
        )


def _static_sinkage(depth: Array) -> tuple[tuple[float, float, float, float], ...]:
    """Sinkage held at ``depth`` (m) over a step: (s0, ṡ0, z*, ω) = (s, 0, s, 0) per wheel."""
    return tuple((float(d), 0.0, float(d), 0.0) for d in depth)


def _sinkage_motion(
    start: float, rate: float, target: float, omega: float, elapsed: float
) -> tuple[float, float, float]:
    """(s, ṡ, s̈) at ``elapsed`` (s) of s̈ = ω² (z* − s) − 2ω ṡ from (s0, ṡ0) (m, m/s, m/s²).

    Critically damped: e = s − z* = (A + B τ) e^(−ωτ), A = e0, B = ė0 + ω e0. s and ṡ
    stay continuous from step to step (only s̈ changes with the held target), so the
    path constraint never sees a jump of velocity. ω = 0: the sinkage moves at
    constant ṡ0 (0 for a held depth).
    """
    if omega <= 0.0:
        return start + rate * elapsed, rate, 0.0
    a = start - target
    b = rate + omega * a
    decay = math.exp(-omega * elapsed)
    position = a + b * elapsed
    return (
        target + position * decay,
        (b - omega * position) * decay,
        omega * (omega * position - 2.0 * b) * decay,
    )


def _fit_force_model(
    terramechanics: _Terramechanics,
    torque: Array,
    load: Array,
    slip: Array,
    soil_index: NDArray[np.int_],
    stencil: float,
    sinkage: tuple[tuple[float, float, float, float], ...] = ((0.0, 0.0, 0.0, 0.0),) * _N_WHEELS,
) -> _ForceModel:
    """One vectorised terramechanics call at (W, s − δ), (W, s), (W, s + δ) per wheel → quadratics in slip."""
    centre = np.clip(slip, -1.0 + stencil, 1.0 - stencil)
    slips = np.concatenate([centre - stencil, centre, centre + stencil])
    dp, tau, entry = terramechanics(np.tile(load, 3), slips, np.tile(soil_index, 3))

    def quadratic(values: Array) -> Array:
        low, mid, high = values[:_N_WHEELS], values[_N_WHEELS : 2 * _N_WHEELS], values[2 * _N_WHEELS :]
        return np.stack([mid, (high - low) / (2 * stencil), (high - 2 * mid + low) / (2 * stencil**2)], axis=1)

    return _ForceModel(
        torque,
        np.maximum(load, 0.0),
        centre,
        quadratic(dp),
        quadratic(tau),
        entry[_N_WHEELS : 2 * _N_WHEELS],
        sinkage,
    )


# ---------------------------------------------------------------------------
# Equations of motion (eq. 32)
# ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Evaluation:
    g_ddot: Array
    vertical_reaction: Array
    slip: Array
    drawbar_pull: Array
    resistive_torque: Array
    slope: Array
    residual: Array
    centres: Array
    centre_velocity: Array
    tangent_speed: Array
    wheel_rate: Array


class _Equations:
    """Right-hand side of the constrained dynamics for a held :class:`_ForceModel`."""

    def __init__(self, scenario: RoverScenario, path: WheelPath) -> None:
        self.params = scenario.params
        self.path = path
        self.alpha = scenario.baumgarte_alpha
        self.beta = scenario.baumgarte_beta
        self._system = np.zeros((10, 10))

    def evaluate(self, state: Array, model: _ForceModel, elapsed: float = 0.0) -> _Evaluation:
        """Solve eq. 32 at ``state`` (14,) with the held ``model``, ``elapsed`` (s) into the step; sample quantities."""
        solution, wheels = self._solve(state, model, elapsed)
        return _Evaluation(
            g_ddot=solution[:7],
            vertical_reaction=-solution[7:],
            slip=np.array(wheels["slip"]),
            drawbar_pull=np.array(wheels["dp"]),
            resistive_torque=np.array(wheels["tau"]),
            slope=np.array(wheels["slope"]),
            residual=np.array(wheels["residual"]),
            centres=wheels["centres"],
            centre_velocity=wheels["velocity"],
            tangent_speed=np.array(wheels["tangent_speed"]),
            wheel_rate=np.array(wheels["wheel_rate"]),
        )

    def derivative(self, state: Array, model: _ForceModel, elapsed: float = 0.0) -> Array:
        """d[g, ġ]/dt ``elapsed`` (s) into the step (the sinkage moves with time)."""
        derivative = np.empty(_STATE_SIZE)
        derivative[:7] = state[7:]
        derivative[7:] = self._solve(state, model, elapsed)[0][:7]
        return derivative

    def _solve(self, state: Array, model: _ForceModel, elapsed: float = 0.0) -> tuple[Array, dict[str, Any]]:
        """The bordered system of eq. 32 → ([g̈, −λ], per-wheel quantities).

        Per-wheel work is done in Python floats: with three wheels that is
        several times faster than numpy on (3,) arrays, and this runs four
        times per integration step.
        """
        p = self.params
        g, g_dot = state[:7], state[7:]
        terms = dynamics_terms(p, g, g_dot)
        jac = terms.wheel_jacobian
        centres = terms.wheel_centres
        point = self.path.point
        path_z, slope, second = zip(*(point(x) for x in centres[:, 0].tolist()), strict=True)
        velocity = jac @ g_dot
        vx, vz = velocity[:, 0].tolist(), velocity[:, 1].tolist()
        z = centres[:, 1].tolist()
        bias = terms.wheel_bias.tolist()
        rates = g_dot.tolist()
        carrier_rate = rates[2] + rates[3]
        wheel_rate = (carrier_rate + rates[4], carrier_rate + rates[5], rates[2] + rates[6])
        radius = p.wheel_radius
        two_alpha, beta_squared = 2.0 * self.alpha, self.beta**2
        dp_coefficients = model.drawbar_pull_list
        tau_coefficients = model.resistive_torque_list
        centre = model.centre_list

        residual = [0.0] * 3
        zeta = [0.0] * 3
        slip = [0.0] * 3
        dp = [0.0] * 3
        tau = [0.0] * 3
        tangent_speed = [0.0] * 3
        along = [0.0] * 3
        across = [0.0] * 3
        for j in range(3):
            dz = slope[j]
            # Sinkage s_j(τ) (module docstring): Ψ_j = z_j − z_wc(x_j) + s_j(τ), whose explicit time
            # dependence adds ṡ to Ψ̇ and s̈ to the constraint acceleration.
            sink, sink_rate, sink_acceleration = _sinkage_motion(*model.sinkage[j], elapsed)
            residual[j] = z[j] - path_z[j] + sink
            residual_rate = vz[j] - dz * vx[j] + sink_rate
            zeta[j] = (
                -(bias[j][1] - dz * bias[j][0] - second[j] * vx[j] ** 2 + sink_acceleration)
                - two_alpha * residual_rate
                - beta_squared * residual[j]
            )
            norm = math.sqrt(1.0 + dz * dz)
            tangent_speed[j] = (vx[j] + dz * vz[j]) / norm
            slip[j] = slip_from_motion_scalar(wheel_rate[j], tangent_speed[j], radius)
            d = slip[j] - centre[j]
            a, b = dp_coefficients[j], tau_coefficients[j]
            dp[j] = a[0] + d * (a[1] + d * a[2])
            tau[j] = b[0] + d * (b[1] + d * b[2])
            # DP along the tangent (cos γ, −sin γ) = (1, z')/√(1 + z'²), eq. 39.
            along[j] = dp[j] / norm
            across[j] = along[j] * dz

        jx, jz = jac[:, 0, :], jac[:, 1, :]
        rhs = (np.dot(along, jx) + np.dot(across, jz) - terms.coriolis - terms.gravity).tolist()
        # −τ_R on the wheels (eq. 36) through their absolute spin; internal drive torque minus damping (eq. 40).
        torque, damping = model.wheel_torque_list, p.wheel_damping
        rhs[2] -= tau[0] + tau[1] + tau[2]
        rhs[3] -= tau[0] + tau[1]
        for j in range(3):
            rhs[4 + j] += torque[j] - damping * rates[4 + j] - tau[j]
        rhs.extend(zeta)

        constraint_jacobian = jz - np.array(slope)[:, None] * jx
        system = self._system
        system[:7, :7] = terms.mass_matrix
        system[:7, 7:] = constraint_jacobian.T
        system[7:, :7] = constraint_jacobian
        # LAPACK dgesv directly: np.linalg.solve's wrapper costs more than the 10×10 solve itself.
        _, _, solution, info = dgesv(system, np.array(rhs))
        if info != 0:
            raise np.linalg.LinAlgError(f"eq. 32 is singular (dgesv info {info}): the constraints are dependent")
        wheels = {
            "slip": slip,
            "dp": dp,
            "tau": tau,
            "slope": slope,
            "residual": residual,
            "centres": centres,
            "velocity": velocity,
            "tangent_speed": tangent_speed,
            "wheel_rate": wheel_rate,
        }
        return solution, wheels

    def stable_step(self, evaluation: _Evaluation, model: _ForceModel) -> float:
        """Largest RK4 step for the slip modes: 1.5/λ, λ ≈ Σ|dDP/di||∂i/∂v|/m + max|dτ_R/di||∂i/∂ω|/I_wg."""
        p = self.params
        rim = p.wheel_radius * np.abs(evaluation.wheel_rate)
        sensitivity = 1.0 / np.maximum(np.maximum(rim, np.abs(evaluation.tangent_speed)), 1e-4)  # |∂i/∂v| (s/m)
        translation = float(np.sum(np.abs(model.drawbar_pull[:, 1]) * sensitivity)) / p.total_mass
        spin = float(np.max(np.abs(model.resistive_torque[:, 1]) * p.wheel_radius * sensitivity)) / (
            p.wheel_gear_inertia
        )
        rate = translation + spin
        return math.inf if rate <= 0.0 else _SLIP_MODE_STEP_LIMIT / rate


def _rk4(equations: _Equations, state: Array, model: _ForceModel, dt: float, steps: int) -> Array:
    half, sixth = 0.5 * dt, dt / 6.0
    for m in range(steps):
        tau = m * dt
        k1 = equations.derivative(state, model, tau)
        k2 = equations.derivative(state + half * k1, model, tau + half)
        k3 = equations.derivative(state + half * k2, model, tau + half)
        k4 = equations.derivative(state + dt * k3, model, tau + dt)
        state = state + sixth * (k1 + 2.0 * (k2 + k3) + k4)
    return state


# ---------------------------------------------------------------------------
# Initial condition
# ---------------------------------------------------------------------------


def solve_configuration(
    params: RoverParams,
    path: WheelPath,
    x0: float,
    *,
    sinkage: ArrayLike | None = None,
    tolerance: float = 1e-13,
    max_iterations: int = 50,
) -> Array:
    """Configuration g with O at x0 and all three wheel centres on the path (Ψ = 0), by Newton on (z0, θ, q1).

    ``sinkage`` (3,) (m, default 0) lowers each wheel centre below the path:
    Ψ_j = z_j − z_wc(x_j) + s_j = 0. Wheel angles are 0. Raises RuntimeError
    if Newton does not converge.
    """
    depth = np.zeros(_N_WHEELS) if sinkage is None else np.asarray(sinkage, dtype=float).reshape(_N_WHEELS)
    g = np.zeros(7)
    g[0] = x0
    level = params.level_wheel_offsets
    g[1] = float(np.mean(path.height(x0 + level[:, 0]) - depth)) - float(np.mean(level[:, 1]))
    for _ in range(max_iterations):
        terms = dynamics_terms(params, g, np.zeros(7))
        x, z = terms.wheel_centres[:, 0], terms.wheel_centres[:, 1]
        path_z, dz, _ = path.evaluate(x)
        residual = z - path_z + depth
        if np.max(np.abs(residual)) < tolerance:
            return g
        jac = terms.wheel_jacobian[:, 1, :] - dz[:, None] * terms.wheel_jacobian[:, 0, :]
        g[1:4] -= np.linalg.solve(jac[:, 1:4], residual)
    raise RuntimeError(f"no configuration with all wheels on the path {path.name!r} at x0 = {x0} m")


def _manifold_direction(params: RoverParams, path: WheelPath, g: Array) -> Array:
    """ġ with ẋ0 = 1, wheel rates 0 and Ψ_g ġ = 0 (motion along the path)."""
    terms = dynamics_terms(params, g, np.zeros(7))
    dz = path.slope(terms.wheel_centres[:, 0])
    jac = terms.wheel_jacobian[:, 1, :] - dz[:, None] * terms.wheel_jacobian[:, 0, :]
    direction = np.zeros(7)
    direction[0] = 1.0
    direction[1:4] = np.linalg.solve(jac[:, 1:4], -jac[:, 0])
    return direction


# ---------------------------------------------------------------------------
# Simulator
# ---------------------------------------------------------------------------


class RoverSimulator:
    """Stepping truth simulator: one :meth:`step` = one 50 Hz control and sensor period.

    Each step computes the wheel torques (PID), the held normal loads and the
    terramechanics model at the current state, reports the sensors and truth
    at t, then integrates to t + 20 ms.

    Args:
        scenario: terrain, duration, seed, models, effects.
    """

    def __init__(self, scenario: RoverScenario) -> None:
        self.scenario = scenario
        self.path = scenario.path
        self._params = scenario.params
        self._period = 1.0 / CONTROL_RATE
        self._n_samples = scenario.n_samples
        self._equations = _Equations(scenario, self.path)
        self._terramechanics = _Terramechanics(scenario)
        streams = np.random.SeedSequence(scenario.seed).spawn(7)
        (
            self._bogie_rng,
            self._gyro_rng,
            self._velocity_rng,
            self._accel_rng,
            self._wheel_rng,
            self._axial_rng,
            self._perpendicular_rng,
        ) = (np.random.default_rng(s) for s in streams)
        delay = int(round(scenario.effects.sensor_delay * CONTROL_RATE))
        self._delay = delay
        self._history: deque[dict[str, Array]] = deque(maxlen=delay + 1)
        self._step_index = 0
        self._integral = np.zeros(_N_WHEELS)
        self._previous_error = np.zeros(_N_WHEELS)
        self._sinkage = np.zeros(_N_WHEELS)
        self._sinkage_rate = np.zeros(_N_WHEELS)
        self._model_elapsed = 0.0  # time into the held model's step where the state is (s)
        self._state, self._model = self._steady_start()

    # --- public state -------------------------------------------------------

    @property
    def t(self) -> float:
        """Time of the next sample (s)."""
        return self._step_index * self._period

    @property
    def step_index(self) -> int:
        """Samples produced so far."""
        return self._step_index

    @property
    def done(self) -> bool:
        """True once the scenario's duration has been simulated."""
        return self._step_index >= self._n_samples

    @property
    def state(self) -> Array:
        """Copy of [g, ġ] (14,)."""
        return self._state.copy()

    # --- start --------------------------------------------------------------

    def _soil_index(self, x: Array) -> NDArray[np.int_]:
        distance = self.scenario.effects.soil_change_distance
        if distance is None:
            return np.zeros(_N_WHEELS, dtype=int)
        return (x >= distance).astype(int)

    def _steady_start(self) -> tuple[Array, _ForceModel]:
        """Rolling steady state at start_x (module docstring "Start")."""
        scenario = self.scenario
        p = self._params
        g = solve_configuration(p, self.path, scenario.start_x)
        direction = _manifold_direction(p, self.path, g)
        wheel_rate = scenario.desired_speed / p.wheel_radius
        state = np.concatenate([g, np.zeros(7)])
        state[11:] = wheel_rate
        soil_index = self._soil_index(wheel_centres(p, g)[:, 0])

        slips = np.linspace(-0.6, 0.9, 61)
        load = self._equations.evaluate(
            state, _ForceModel.constant(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
        ).vertical_reaction
        slip0 = 0.0
        for _ in range(3):
            norm = np.sqrt(1.0 + self._equations.evaluate(state, self._null_model()).slope ** 2)
            load = np.maximum(load * norm, 0.0)
            n = slips.size
            dp, tau, _ = self._terramechanics(
                np.repeat(load[None, :], n, axis=0).ravel(), np.repeat(slips, 3), np.tile(soil_index, n)
            )
            dp, tau = dp.reshape(n, 3), tau.reshape(n, 3)
            drive = tau + p.wheel_damping * wheel_rate
            # Forward acceleration along the path for each common slip; the steady slip zeroes it.
            forward = np.array(
                [
                    self._equations.evaluate(state, _ForceModel.constant(drive[k], load, dp[k], tau[k])).g_ddot[0]
                    for k in range(n)
                ]
            )
            crossing = np.flatnonzero((forward[:-1] < 0.0) & (forward[1:] >= 0.0))
            if crossing.size:
                k = int(crossing[0])
                slip0 = float(slips[k] - forward[k] * (slips[k + 1] - slips[k]) / (forward[k + 1] - forward[k]))
            else:
                slip0 = float(slips[int(np.argmin(np.abs(forward)))])
            dp0, tau0, _ = self._terramechanics(load, np.full(3, slip0), soil_index)
            drive0 = tau0 + p.wheel_damping * wheel_rate
            load = self._equations.evaluate(state, _ForceModel.constant(drive0, load, dp0, tau0)).vertical_reaction

        if scenario.wheel_sinkage:
            # Sunk to the steady depth at the start load and slip; the loads are then re-evaluated there.
            self._sinkage = self._terramechanics.sinkage(load, np.full(3, slip0), soil_index)[0]
            g = solve_configuration(p, self.path, scenario.start_x, sinkage=self._sinkage)
            direction = _manifold_direction(p, self.path, g)
            state[:7] = g
        # Body speed for slip i0 at the wheels' mean tangent speed per unit ẋ0.
        unit = np.concatenate([g, direction])
        tangent = self._equations.evaluate(unit, self._null_model()).tangent_speed
        speed = scenario.desired_speed * (1.0 - slip0) / float(np.mean(tangent))
        state[7:14] = speed * direction
        state[11:] = wheel_rate
        self._integral = (tau0 + p.wheel_damping * wheel_rate) / max(scenario.controller.integral_gain, 1e-12)
        if scenario.controller.integral_gain == 0.0:
            self._integral[:] = 0.0
        self._previous_error = np.zeros(_N_WHEELS)
        evaluation = self._equations.evaluate(state, _ForceModel.constant(drive0, load, dp0, tau0, self._sinkage))
        model = _fit_force_model(
            self._terramechanics,
            drive0,
            evaluation.vertical_reaction * np.sqrt(1.0 + evaluation.slope**2),
            evaluation.slip,
            soil_index,
            scenario.slip_stencil,
            _static_sinkage(self._sinkage),
        )
        return state, model

    @staticmethod
    def _null_model() -> _ForceModel:
        zeros = np.zeros(_N_WHEELS)
        return _ForceModel.constant(zeros, zeros, zeros, zeros)

    # --- control ------------------------------------------------------------

    def _control(self, state: Array) -> Array:
        """Discrete PID on e = v_d − r_w q̇_j (module docstring), saturated, conditional integration."""
        c = self.scenario.controller
        error = self.scenario.desired_speed - self._params.wheel_radius * state[11:14]
        integral = self._integral + error
        torque = (
            c.proportional_gain * error
            + c.integral_gain * integral
            + c.derivative_gain * (error - self._previous_error)
        )
        saturated = np.abs(torque) > c.max_torque
        # Integrate only where not saturated (or where the error unwinds the saturation).
        keep = ~saturated | (np.sign(error) != np.sign(torque))
        self._integral = np.where(keep, integral, self._integral)
        self._previous_error = error
        clipped: Array = np.clip(torque, -c.max_torque, c.max_torque)
        return clipped

    # --- stepping -----------------------------------------------------------

    def step(self) -> RoverSample:
        """Report the sample at t and advance the plant to t + 20 ms."""
        scenario = self.scenario
        t = self._step_index * self._period
        state = self._state
        torque = self._control(state)

        # W held over the step: λ now, with the new torques and the previous DP/τ_R model.
        # (The previous model at the end of its step: the sinkage's own s, ṡ, s̈ continue, so no spurious
        # Baumgarte force from a sinking wheel enters W.)
        before = self._equations.evaluate(state, self._model.with_torque(torque), self._model_elapsed)
        normal_load = before.vertical_reaction * np.sqrt(1.0 + before.slope**2)
        soil_index = self._soil_index(before.centres[:, 0])
        sinkage = self._sinkage_over_step(normal_load, before, soil_index)
        model = _fit_force_model(
            self._terramechanics, torque, normal_load, before.slip, soil_index, scenario.slip_stencil, sinkage
        )
        evaluation = self._equations.evaluate(state, model)
        step = min(scenario.integration_step, self._equations.stable_step(evaluation, model))
        substeps = max(1, math.ceil(self._period / step - 1e-9))
        sample = self._sample(t, state, evaluation, model, torque, soil_index, substeps)

        self._state = _rk4(self._equations, state, model, self._period / substeps, substeps)
        self._model = model
        self._sinkage, self._sinkage_rate = model.sinkage_at(self._period)
        self._model_elapsed = self._period
        self._step_index += 1
        return sample

    def _sinkage_over_step(
        self, load: Array, before: _Evaluation, soil_index: NDArray[np.int_]
    ) -> tuple[tuple[float, float, float, float], ...]:
        """(s0, ṡ0, z*, ω) per wheel for the coming step (module docstring "Sinkage")."""
        if not self.scenario.wheel_sinkage:
            return _static_sinkage(np.zeros(_N_WHEELS))
        target, length = self._terramechanics.sinkage(np.where(load > 0.0, load, 0.0), before.slip, soil_index)
        loading = 1.0 / self.scenario.sinkage_loading_time
        rows = []
        for j in range(_N_WHEELS):
            start = float(self._sinkage[j])
            if target[j] >= start:
                omega = loading
            else:
                # Unloading: the compacted rut does not spring back; the rim climbs onto fresh soil over one
                # contact length of travel (the longer of the two contacts; ≥ 1 mm).
                contact = max(float(length[j]), self._contact_length(start), 1.0e-3)
                omega = min(abs(float(before.tangent_speed[j])) / contact, loading)
            rows.append((start, float(self._sinkage_rate[j]), float(target[j]), omega))
        return tuple(rows)

    def _contact_length(self, depth: float) -> float:
        """r_e sin θ0 of a rim sunk ``depth`` (m) below the surface (grouser tips h_g deeper)."""
        radius = self._terramechanics.wheel.radius
        cos_theta = 1.0 - min((depth + self._terramechanics.grouser_height) / radius, 1.0)
        return radius * math.sqrt(max(1.0 - cos_theta * cos_theta, 0.0))

    def _sample(
        self,
        t: float,
        state: Array,
        evaluation: _Evaluation,
        model: _ForceModel,
        torque: Array,
        soil_index: NDArray[np.int_],
        substeps: int,
    ) -> RoverSample:
        p = self._params
        g, g_dot = state[:7], state[7:]
        pitch = float(g[2])
        cos_p, sin_p = math.cos(pitch), math.sin(pitch)
        forward = float(g_dot[0] * cos_p - g_dot[1] * sin_p)
        vertical = float(g_dot[0] * sin_p + g_dot[1] * cos_p)
        specific = body_specific_force(p, g, evaluation.g_ddot)
        gamma = -np.arctan(evaluation.slope)
        epsilon = carrier_angles(p, g)
        load = np.where(model.normal_load > 0.0, model.normal_load, 0.0)
        # The cells read the contact force that acts: the normal load of the constraint reaction
        # at this sample with this step's DP model, not the W held for the soil model (computed
        # with the previous step's forces). The two agree to ≈ 4e-4 N (median) except where a
        # wheel enters another soil: there DP jumps and the reaction with it, 0.5-3 N in one step.
        acting = evaluation.vertical_reaction * np.sqrt(1.0 + evaluation.slope**2)
        acting = np.where(load > 0.0, np.maximum(acting, 0.0), 0.0)
        axial, perpendicular = load_cell_forces(acting, evaluation.drawbar_pull, gamma, epsilon)
        x = evaluation.centres[:, 0]
        truth = RoverTruth(
            configuration=g.copy(),
            velocity=g_dot.copy(),
            acceleration=evaluation.g_ddot.copy(),
            pitch=pitch,
            pitch_rate=float(g_dot[2]),
            bogie_angle=float(g[3]),
            forward_velocity=forward,
            vertical_velocity=vertical,
            specific_force=specific,
            slip=evaluation.slip,
            normal_load=load,
            drawbar_pull=evaluation.drawbar_pull,
            resistive_torque=evaluation.resistive_torque,
            contact_angle=gamma,
            entry_angle=model.entry_angle.copy(),
            sinkage=model.sinkage_at(0.0)[0],
            carrier_angle=epsilon,
            wheel_rate=evaluation.wheel_rate,
            wheel_centre=evaluation.centres.copy(),
            wheel_centre_velocity=evaluation.centre_velocity,
            path_curvature=self.path.curvature(x),
            terrain_curvature=self.path.terrain_curvature(x, p.wheel_radius),
            constraint_residual=evaluation.residual,
            vertical_reaction=evaluation.vertical_reaction,
            load_axial=axial,
            load_perpendicular=perpendicular,
            wheel_torque=torque.copy(),
            soil_index=soil_index,
            substeps=substeps,
        )
        clean = {
            "bogie_angle": np.array(g[3]),
            "pitch_rate": np.array(g_dot[2]),
            "forward_velocity": np.array(forward),
            "acceleration": specific,
            "wheel_angle": g[4:7].copy(),
            "load_axial": axial,
            "load_perpendicular": perpendicular,
        }
        return RoverSample(t=t, sensors=self._measure(clean, torque), truth=truth)

    def _measure(self, clean: dict[str, Array], torque: Array) -> RoverSensors:
        """Delay, effects and Table IV noise on the noise-free channels."""
        self._history.append(clean)
        delayed = self._history[0]  # sample k − d once filled, the first sample before
        noise = self.scenario.sensors
        effects = self.scenario.effects
        crosstalk = effects.load_cell_crosstalk
        axial = delayed["load_axial"] + crosstalk * delayed["load_perpendicular"] + np.asarray(effects.load_cell_bias)
        perpendicular = delayed["load_perpendicular"] + crosstalk * delayed["load_axial"]
        bogie = float(delayed["bogie_angle"])
        wheel = delayed["wheel_angle"]
        if noise.quantise:
            bogie = math.floor(bogie / BOGIE_ENCODER_STEP) * BOGIE_ENCODER_STEP
            wheel = np.floor(wheel / WHEEL_ENCODER_STEP) * WHEEL_ENCODER_STEP
            axial = np.round(axial / LOAD_CELL_STEP) * LOAD_CELL_STEP
            perpendicular = np.round(perpendicular / LOAD_CELL_STEP) * LOAD_CELL_STEP
        else:
            bogie += noise.bogie_angle_std * float(self._bogie_rng.standard_normal())
            wheel = wheel + noise.wheel_angle_std * self._wheel_rng.standard_normal(3)
            axial = axial + noise.load_cell_std * self._axial_rng.standard_normal(3)
            perpendicular = perpendicular + noise.load_cell_std * self._perpendicular_rng.standard_normal(3)
        pitch_rate = (
            float(delayed["pitch_rate"])
            + effects.imu_gyro_bias
            + noise.pitch_rate_std * float(self._gyro_rng.standard_normal())
        )
        forward = float(delayed["forward_velocity"]) + noise.forward_velocity_std * float(
            self._velocity_rng.standard_normal()
        )
        acceleration = (
            delayed["acceleration"]
            + np.asarray(effects.imu_accel_bias)
            + noise.acceleration_std * self._accel_rng.standard_normal(2)
        )
        return RoverSensors(
            bogie_angle=bogie,
            pitch_rate=pitch_rate,
            forward_velocity=forward,
            acceleration=acceleration,
            wheel_angle=wheel,
            load_axial=axial,
            load_perpendicular=perpendicular,
            effort=torque.copy(),
        )


def simulate_rover(scenario: RoverScenario) -> RoverRun:
    """Run a :class:`RoverSimulator` to the end of the scenario and stack the samples."""
    simulator = RoverSimulator(scenario)
    samples: list[RoverSample] = []
    while not simulator.done:
        samples.append(simulator.step())

    def stack(values: Sequence[Any]) -> Array:
        return np.array(values)

    sensors = RoverSensors(
        **{name: stack([getattr(s.sensors, name) for s in samples]) for name in RoverSensors.__dataclass_fields__}
    )
    truth = RoverTruth(
        **{name: stack([getattr(s.truth, name) for s in samples]) for name in RoverTruth.__dataclass_fields__}
    )
    return RoverRun(scenario=scenario, time=stack([s.t for s in samples]), sensors=sensors, truth=truth)
