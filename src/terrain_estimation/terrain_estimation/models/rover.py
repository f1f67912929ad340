"""Planar multibody model of one side of the Kapvik rocker-bogie rover ([RB] section III, MODELS.md C.3).

Shared physics of the rocker-bogie paper, imported both by the truth plant
(``vehicle_sim.plants.rover``, which adds the path constraints, the
terramechanics, the wheel controller and the sensors) and by the estimators
(MODELS.md C.5–C.6, which use H, ∂V/∂g and the wheel Jacobians). Plain numpy;
every function takes one configuration.

Coordinates
    The paper's configuration Φ (eq. 12) has 10 entries, three of which
    (y0, θ0x, θ0z) are unused in the vertical plane. This module works with
    the 7 planar generalised coordinates ``g`` of :data:`COORDINATES`::

        g = [x0, z0, θ, q1, q2, q3, q4]        (Φ entries 1, 3, 5, 7, 8, 9, 10)

    x0, z0 = world position of O, the combined body + rocker centre of mass
    (the rocker "joint" is rigid in 2-D); θ = θ0y, body pitch; q1 = bogie angle
    relative to the body; q2, q3, q4 = wheel angles relative to their carrier
    link. :data:`PAPER_INDEX` maps ``g`` into Φ (1-based, as the paper indexes
    H and J_w in eqs. 55–58).

Sign conventions (REP 103: x forward, y left, z up)
    Angles are rotations about +y, so a positive pitch is nose DOWN. A vector
    with body-frame components (b_x, b_z) has world components
    ``R(θ) b = (b_x cos θ + b_z sin θ, −b_x sin θ + b_z cos θ)``: the body x
    axis is (cos θ, −sin θ), the body z axis (sin θ, cos θ). The bogie frame
    is at θ + q1, and a wheel turning forward (top moving forward) has a
    positive spin about +y. The body accelerometer reads eqs. 72–73 (see
    :func:`body_specific_force`). Carrier angles ε_j (eqs. 81–82) are θ + q1 for
    the bogie wheels and θ for the front wheel (:func:`carrier_angles`).

Wheels (:data:`WHEELS`, MODELS.md C.3)
    Paper wheel 1 = rear (joint q2) and wheel 2 = middle (q3) are on the bogie,
    wheel 3 = front (q4) on the rocker. Every per-wheel array is in this order.

Geometry [recon — the paper does not give the link vectors l_kl]
    On level ground with θ = q1 = 0 the three wheel centres lie on one
    horizontal line, rear → front ``wheelbase`` long; O is ``body_cm_height``
    above that line, midway between the rear and the front wheel. The bogie
    carries the rear and the middle wheel ``2 b`` apart (b =
    ``bogie_half_length``) and pivots ``a`` (= ``bogie_joint_height``) above
    their centres, midway between them. The bogie centre of mass is c11 from
    the bogie joint (Table III), in the bogie frame. With the defaults the
    middle wheel sits right below O.

Inertia of the drive train
    I_wg (Table III) is the wheel plus its gearbox and motor rotor referred to
    the wheel: the rotor turns at N q̇_j relative to its carrier (N = 1400), so
    its kinetic energy ½ I_rotor (φ̇_carrier + N q̇_j)² ≈ ½ (I_wg − I_w) q̇_j² is
    a function of the *relative* wheel rate only (the carrier-rate part is
    N times smaller and dropped). :func:`mass_matrix` therefore uses I_w for
    the wheel as a rigid body (coupled to θ and q1) and adds I_wg − I_w on the
    diagonal entry of the wheel coordinate alone, so H[q_j, q_j] = I_wg, the
    value the estimator's eq. 49 divides by.

Equations of motion (eq. 24, unconstrained part)::

    H(g) g̈ + c(g, ġ) + ∂V/∂g = Q

with H = Σ m J_vᵀ J_v + Σ I J_ωᵀ J_ω (eq. 14), c = Ḣ ġ − ∂T/∂g (exact for a
planar chain: Σ m J_vᵀ J̇_v ġ, :func:`coriolis_forces`), V = g Σ m z (eq. 15)
and Q the generalised applied forces (eqs. 33–40,
:func:`generalised_wheel_forces`).

Units: SI throughout (m, kg, rad, N, N·m, s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from terrain_estimation.models.rover_contact import contact_angle_from_velocity as contact_angle_from_velocity
from terrain_estimation.models.rover_contact import load_cell_forces as load_cell_forces
from terrain_estimation.models.rover_contact import slip_from_motion as slip_from_motion
from terrain_estimation.models.rover_contact import slip_from_motion_scalar as slip_from_motion_scalar
from terrain_estimation.models.rover_contact import terrain_contact_force_world as terrain_contact_force_world
from terrain_estimation.models.rover_contact import wheel_forces_from_load_cell as wheel_forces_from_load_cell

Array = NDArray[np.float64]

__all__ = [
    "COORDINATES",
    "N_COORDINATES",
    "PAPER_INDEX",
    "WHEELS",
    "DynamicsTerms",
    "RoverParams",
    "body_specific_force",
    "carrier_angles",
    "contact_angle_from_velocity",
    "coriolis_forces",
    "dynamics_gravity",
    "dynamics_terms",
    "generalised_wheel_forces",
    "gravity_gradient",
    "kinetic_energy",
    "load_cell_forces",
    "mass_matrix",
    "mass_point_positions",
    "bogie_joint_position",
    "potential_energy",
    "slip_from_motion",
    "slip_from_motion_scalar",
    "terrain_contact_force_world",
    "wheel_angular_velocity_jacobian",
    "wheel_centre_bias_acceleration",
    "wheel_centre_jacobian",
    "wheel_centre_velocities",
    "wheel_centres",
    "wheel_forces_from_load_cell",
]

#: Wheel order of every per-wheel array: paper wheels 1, 2, 3 (joints q2, q3, q4).
WHEELS: Final[tuple[str, str, str]] = ("rear", "middle", "front")

#: Planar generalised coordinates g (7), in this order.
COORDINATES: Final[tuple[str, ...]] = ("x0", "z0", "pitch", "bogie", "q_rear", "q_middle", "q_front")

#: 1-based index of each entry of g in the paper's 10-entry Φ (eq. 12).
PAPER_INDEX: Final[tuple[int, ...]] = (1, 3, 5, 7, 8, 9, 10)

N_COORDINATES: Final[int] = 7

# Indices into g.
_X0, _Z0, _PITCH, _BOGIE = 0, 1, 2, 3
_WHEEL_COORDINATE = (4, 5, 6)

# Mass points (body, bogie, rear, middle, front) and the links whose rotation moves them.
_N_POINTS = 5


@dataclass(frozen=True, kw_only=True)
class RoverParams:
    """One side of Kapvik: [RB] Tables I and III plus the geometry the paper omits (MODELS.md C.3).

    Attributes:
        body_mass: m0, body + rocker (kg), Table III.
        bogie_mass: m1, bogie link (kg), Table III.
        wheel_mass: m2 = m3 = m4, one wheel (kg), Table III.
        body_inertia: I0 about y through O (kg·m²), Table III.
        bogie_inertia: I1 about y through the bogie CM (kg·m²), Table III.
        wheel_inertia: I_w of a wheel about its axle (kg·m²), Table III.
        wheel_gear_inertia: I_wg, wheel + gear train referred to the wheel
            (kg·m²), Table III; see the module docstring for where it enters H.
        wheel_damping: b_d, viscous damping of a wheel joint (N·m·s/rad), eq. 40.
        wheel_radius: r_w (m), Table I.
        wheel_width: b_w (m), Table I.
        wheelbase: l_w, rear to front wheel centre (m), Table I.
        bogie_half_length: b, bogie joint to each bogie wheel along the bogie (m) [recon].
        bogie_joint_height: a, bogie joint above the bogie wheel centres (m) [recon].
        body_cm_height: O above the wheel centres on level ground (m) [recon].
        bogie_cm_offset: c11 = (x, z) from the bogie joint to the bogie CM in
            the bogie frame (m), Table III.
        gravity: g (m/s²).
    """

    body_mass: float = 12.49
    bogie_mass: float = 1.562
    wheel_mass: float = 0.3174
    body_inertia: float = 0.5045
    bogie_inertia: float = 0.05248
    wheel_inertia: float = 0.003584
    wheel_gear_inertia: float = 1.082
    wheel_damping: float = 2.28855
    wheel_radius: float = 0.075
    wheel_width: float = 0.070
    wheelbase: float = 0.70
    bogie_half_length: float = 0.175
    bogie_joint_height: float = 0.10
    body_cm_height: float = 0.20
    bogie_cm_offset: tuple[float, float] = (0.0, -0.07322)
    gravity: float = 9.81

    def __post_init__(self) -> None:
        positive = (
            "body_mass",
            "bogie_mass",
            "wheel_mass",
            "body_inertia",
            "bogie_inertia",
            "wheel_inertia",
            "wheel_gear_inertia",
            "wheel_radius",
            "wheel_width",
            "wheelbase",
            "bogie_half_length",
            "gravity",
        )
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"RoverParams.{name} must be finite and > 0, got {value!r}")
        for name in ("wheel_damping", "bogie_joint_height", "body_cm_height"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ValueError(f"RoverParams.{name} must be finite and ≥ 0, got {value!r}")
        if self.wheel_gear_inertia < self.wheel_inertia:
            raise ValueError(
                f"RoverParams.wheel_gear_inertia ({self.wheel_gear_inertia}) must be ≥ wheel_inertia "
                f"({self.wheel_inertia}): it is the wheel plus its gear train"
            )
        if 2.0 * self.bogie_half_length >= self.wheelbase:
            raise ValueError(
                f"RoverParams.bogie_half_length ({self.bogie_half_length}) must be < wheelbase/2 "
                f"({0.5 * self.wheelbase}): the middle wheel lies between the rear and the front wheel"
            )
        offset = self.bogie_cm_offset
        if len(offset) != 2 or not all(math.isfinite(float(v)) for v in offset):
            raise ValueError(f"RoverParams.bogie_cm_offset must be two finite numbers (x, z), got {offset!r}")

    @property
    def total_mass(self) -> float:
        """m0 + m1 + 3 m_w (kg)."""
        return self.body_mass + self.bogie_mass + 3.0 * self.wheel_mass

    @property
    def front_wheel_offset(self) -> tuple[float, float]:
        """Front-wheel centre from O in the body frame (x, z) (m)."""
        return (0.5 * self.wheelbase, -self.body_cm_height)

    @property
    def bogie_joint_offset(self) -> tuple[float, float]:
        """Bogie joint from O in the body frame (x, z) (m)."""
        return (-0.5 * self.wheelbase + self.bogie_half_length, -self.body_cm_height + self.bogie_joint_height)

    @property
    def bogie_wheel_offsets(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """Rear and middle wheel centres from the bogie joint in the bogie frame (x, z) (m)."""
        b, a = self.bogie_half_length, self.bogie_joint_height
        return ((-b, -a), (b, -a))

    @property
    def level_wheel_offsets(self) -> Array:
        """Wheel centres from O on level ground (θ = q1 = 0), (3, 2) world (x, z) (m)."""
        joint = np.array(self.bogie_joint_offset)
        rear, middle = (joint + np.array(w) for w in self.bogie_wheel_offsets)
        return np.array([rear, middle, self.front_wheel_offset])


# ---------------------------------------------------------------------------
# Chain kinematics
# ---------------------------------------------------------------------------


_Vec = tuple[float, float]


def _rotate(angle: float, vector: _Vec) -> _Vec:
    """World (x, z) of a link-frame vector for a link at ``angle`` about +y (nose-down positive)."""
    c, s = math.cos(angle), math.sin(angle)
    bx, bz = vector
    return bx * c + bz * s, -bx * s + bz * c


def _sum(vectors: list[_Vec]) -> _Vec:
    """``sum(vectors, np.zeros(2))`` in floats: the same additions, from 0, in order."""
    x = z = 0.0
    for vx, vz in vectors:
        x += vx
        z += vz
    return x, z


def _perp_sum(vectors: list[_Vec]) -> _Vec:
    """Σ ⊥r over ``vectors`` from 0 (:func:`_sum`), ⊥(x, z) = (z, −x) = d(R(φ) b)/dφ for r = R(φ) b: the
    velocity of a point at r for a unit rate about +y."""
    return _sum([(rz, -rx) for rx, rz in vectors])


def _check_g(g: ArrayLike, name: str = "g") -> Array:
    arr = np.asarray(g, dtype=float)
    if arr.shape != (N_COORDINATES,):
        raise ValueError(f"{name} must have shape ({N_COORDINATES},), got {arr.shape}")
    return arr


class _Chain:
    """World vectors of the chain's segments at one configuration, as (x, z) floats.

    Segments: O → bogie joint (body), O → front wheel (body), bogie joint →
    bogie CM, → rear wheel, → middle wheel (bogie). A mass point is O plus a
    sum of segments; each segment turns with its link's absolute angle
    (θ for the body, θ + q1 for the bogie). Plain floats, not 2-vectors: every
    estimator step evaluates the chain at a dozen configurations, and the
    additions are those numpy made on the vectors (from 0, in order).
    """

    def __init__(self, params: RoverParams, g: Array) -> None:
        pitch, bogie = g[_PITCH], g[_BOGIE]
        self.origin: _Vec = (float(g[_X0]), float(g[_Z0]))
        self.joint = _rotate(pitch, params.bogie_joint_offset)
        self.front = _rotate(pitch, params.front_wheel_offset)
        carrier = pitch + bogie
        rear, middle = params.bogie_wheel_offsets
        self.bogie_cm = _rotate(carrier, params.bogie_cm_offset)
        self.rear = _rotate(carrier, rear)
        self.middle = _rotate(carrier, middle)

    def points(self) -> list[tuple[list[_Vec], list[_Vec]]]:
        """(body segments, bogie segments) of body, bogie CM, rear, middle, front."""
        return [
            ([], []),
            ([self.joint], [self.bogie_cm]),
            ([self.joint], [self.rear]),
            ([self.joint], [self.middle]),
            ([self.front], []),
        ]


def _point_jacobians(chain: _Chain) -> Array:
    """d(x, z)/dg of the five mass points (body, bogie, rear, middle, front), shape (5, 2, 7)."""
    rows = []
    for body_segments, bogie_segments in chain.points():
        qx, qz = _perp_sum(bogie_segments)
        px, pz = _perp_sum(body_segments)
        row_x = [0.0] * N_COORDINATES
        row_z = [0.0] * N_COORDINATES
        row_x[_X0] = 1.0
        row_z[_Z0] = 1.0
        row_x[_PITCH], row_z[_PITCH] = px + qx, pz + qz
        row_x[_BOGIE], row_z[_BOGIE] = qx, qz
        rows.append([row_x, row_z])
    return np.array(rows)


def _point_bias(chain: _Chain, g_dot: Array) -> Array:
    """J̇ ġ of the five mass points: −Σ r_k φ̇_k² (centripetal), shape (5, 2)."""
    body_rate = g_dot[_PITCH]
    bogie_rate = g_dot[_PITCH] + g_dot[_BOGIE]
    bias = []
    for body_segments, bogie_segments in chain.points():
        x = z = 0.0
        for rx, rz in body_segments:
            x -= rx * body_rate**2
            z -= rz * body_rate**2
        for rx, rz in bogie_segments:
            x -= rx * bogie_rate**2
            z -= rz * bogie_rate**2
        bias.append((x, z))
    return np.array(bias, dtype=float)


def _point_positions(chain: _Chain) -> Array:
    ox, oz = chain.origin
    rows = []
    for body_segments, bogie_segments in chain.points():
        bx, bz = _sum(body_segments)
        cx, cz = _sum(bogie_segments)
        rows.append(((ox + bx) + cx, (oz + bz) + cz))
    return np.array(rows)


def _angular_jacobians() -> Array:
    """Absolute rotation rate of body, bogie, rear, middle, front wheel w.r.t. ġ, shape (5, 7) (eq. 20)."""
    jac = np.zeros((_N_POINTS, N_COORDINATES))
    jac[:, _PITCH] = 1.0
    jac[1:4, _BOGIE] = 1.0
    for k, coordinate in zip((2, 3, 4), _WHEEL_COORDINATE, strict=True):
        jac[k, coordinate] = 1.0
    return jac


_ANGULAR_JACOBIANS: Final[Array] = _angular_jacobians()
_ANGULAR_JACOBIANS.setflags(write=False)


def _masses(params: RoverParams) -> Array:
    m_w = params.wheel_mass
    return np.array([params.body_mass, params.bogie_mass, m_w, m_w, m_w])


def _inertias(params: RoverParams) -> Array:
    i_w = params.wheel_inertia
    return np.array([params.body_inertia, params.bogie_inertia, i_w, i_w, i_w])


def mass_point_positions(params: RoverParams, g: ArrayLike) -> Array:
    """World (x, z) of the mass centres of body (O), bogie, rear, middle, front wheel (m), shape (5, 2)."""
    return _point_positions(_Chain(params, _check_g(g)))


def bogie_joint_position(params: RoverParams, g: ArrayLike) -> Array:
    """World (x, z) of the bogie joint (m), shape (2,)."""
    chain = _Chain(params, _check_g(g))
    (ox, oz), (jx, jz) = chain.origin, chain.joint
    return np.array([ox + jx, oz + jz])


def wheel_centres(params: RoverParams, g: ArrayLike) -> Array:
    """World (x, z) of the wheel centres p2, p3, p4 in :data:`WHEELS` order (m), shape (3, 2)."""
    return mass_point_positions(params, g)[2:]


#: The last wheel-centre Jacobians by (id(params), the bytes of θ, q1 — so −0.0 is not 0.0): one estimator step
#: evaluates the same configuration several times (the contact angles, their derivatives, the slips); a hit
#: returns the very same (read-only) array.
_CENTRE_JACOBIANS: dict[tuple[int, bytes], tuple[RoverParams, Array]] = {}
_CENTRE_JACOBIANS_SIZE = 32


def wheel_centre_jacobian(params: RoverParams, g: ArrayLike) -> Array:
    """d(x_j, z_j)/dg of the wheel centres: the J_v rows of the paper's J_a (eqs. 19, 21), shape (3, 2, 7).

    Depends on θ and q1 alone (planar rotations); the result is read-only and may be shared between calls.
    """
    arr = _check_g(g)
    key = (id(params), arr[_PITCH : _BOGIE + 1].tobytes())
    hit = _CENTRE_JACOBIANS.get(key)
    if hit is not None and hit[0] is params:
        return hit[1]
    jac = _point_jacobians(_Chain(params, arr))[2:]
    jac.setflags(write=False)
    if len(_CENTRE_JACOBIANS) >= _CENTRE_JACOBIANS_SIZE:
        _CENTRE_JACOBIANS.clear()
    _CENTRE_JACOBIANS[key] = (params, jac)
    return jac


def wheel_centre_bias_acceleration(params: RoverParams, g: ArrayLike, g_dot: ArrayLike) -> Array:
    """J̇ ġ of the wheel centres (m/s²), shape (3, 2), so that p̈_j = J_j g̈ + J̇_j ġ.

    Only the centripetal terms −r φ̇² of the rotating segments (body at θ̇,
    bogie at θ̇ + q̇1) appear: the planar Jacobians depend on θ and q1 alone.
    """
    return _point_bias(_Chain(params, _check_g(g)), _check_g(g_dot, "g_dot"))[2:]


def wheel_centre_velocities(params: RoverParams, g: ArrayLike, g_dot: ArrayLike) -> Array:
    """World (ẋ, ż) of the wheel centres (m/s), shape (3, 2): J ġ (eq. 67)."""
    return wheel_centre_jacobian(params, g) @ _check_g(g_dot, "g_dot")


def carrier_angles(params: RoverParams, g: ArrayLike) -> Array:
    """ε_j, world angle of each wheel's carrier link = load-cell axis (rad), shape (3,), eqs. 81–82.

    θ + q1 for the bogie wheels (rear, middle), θ for the front wheel.
    """
    del params  # kept for a uniform signature; the angles do not depend on the geometry
    arr = _check_g(g)
    carrier = arr[_PITCH] + arr[_BOGIE]
    return np.array([carrier, carrier, arr[_PITCH]])


def wheel_angular_velocity_jacobian(params: RoverParams, g: ArrayLike) -> Array:
    """Absolute wheel spin rate about +y w.r.t. ġ, shape (3, 7): the M_y rows of J_w (eqs. 20, 34).

    Rows: θ̇ + q̇1 + q̇2 (rear), θ̇ + q̇1 + q̇3 (middle), θ̇ + q̇4 (front).
    """
    del params
    _check_g(g)
    return _ANGULAR_JACOBIANS[2:].copy()


# ---------------------------------------------------------------------------
# Dynamics
# ---------------------------------------------------------------------------


def mass_matrix(params: RoverParams, g: ArrayLike) -> Array:
    """System inertia matrix H (eq. 14), shape (7, 7), symmetric positive definite.

    H = Σ m J_vᵀ J_v + Σ I J_ωᵀ J_ω over body, bogie and the three wheels
    (wheel inertia I_w), plus (I_wg − I_w) on each wheel coordinate's diagonal
    entry: the reflected gear-train inertia turns with the wheel relative to
    its carrier (module docstring), so H[q_j, q_j] = I_wg.
    """
    chain = _Chain(params, _check_g(g))
    jac = _point_jacobians(chain)
    masses = _masses(params)
    H = np.einsum("k,kai,kaj->ij", masses, jac, jac)
    H += np.einsum("k,ki,kj->ij", _inertias(params), _ANGULAR_JACOBIANS, _ANGULAR_JACOBIANS)
    for coordinate in _WHEEL_COORDINATE:
        H[coordinate, coordinate] += params.wheel_gear_inertia - params.wheel_inertia
    return 0.5 * (H + H.T)


def coriolis_forces(params: RoverParams, g: ArrayLike, g_dot: ArrayLike) -> Array:
    """Velocity-dependent generalised forces c = Ḣ ġ − ∂T/∂g (N or N·m), shape (7,).

    For point masses and planar rotations c = Σ m J_vᵀ J̇_v ġ exactly (the
    angular Jacobians are constant). The paper drops ∂T/∂g in its simulation
    and both terms in the estimator; the truth plant keeps them.
    """
    chain = _Chain(params, _check_g(g))
    g_dot_ = _check_g(g_dot, "g_dot")
    jac = _point_jacobians(chain)
    bias = _point_bias(chain, g_dot_)
    result: Array = np.einsum("k,kai,ka->i", _masses(params), jac, bias)
    return result


def gravity_gradient(params: RoverParams, g: ArrayLike) -> Array:
    """∂V/∂g of V = g Σ m z (eq. 15), shape (7,) (N or N·m)."""
    jac = _point_jacobians(_Chain(params, _check_g(g)))
    result: Array = params.gravity * np.einsum("k,ki->i", _masses(params), jac[:, 1, :])
    return result


class DynamicsTerms(NamedTuple):
    """Everything the equations of motion need at one (g, ġ), from one pass over the chain.

    Attributes:
        mass_matrix: H (7, 7), as :func:`mass_matrix`.
        coriolis: c = Ḣ ġ − ∂T/∂g (7,), as :func:`coriolis_forces`.
        gravity: ∂V/∂g (7,), as :func:`gravity_gradient`.
        wheel_centres: (3, 2) world (x, z) (m).
        wheel_jacobian: (3, 2, 7) d(x, z)/dg of the wheel centres.
        wheel_bias: (3, 2) J̇ ġ of the wheel centres (m/s²).
    """

    mass_matrix: Array
    coriolis: Array
    gravity: Array
    wheel_centres: Array
    wheel_jacobian: Array
    wheel_bias: Array


def dynamics_terms(params: RoverParams, g: ArrayLike, g_dot: ArrayLike) -> DynamicsTerms:
    """H, c, ∂V/∂g and the wheel-centre kinematics at (g, ġ) in one pass (see :class:`DynamicsTerms`).

    Equal to :func:`mass_matrix`, :func:`coriolis_forces`,
    :func:`gravity_gradient`, :func:`wheel_centres`,
    :func:`wheel_centre_jacobian` and :func:`wheel_centre_bias_acceleration`
    (tested), written out in scalars for speed: the truth plant calls it at
    every integration stage.

    With P_k the vector from O to mass point k and B_k its part along the
    bogie (zero for body and front wheel), the point Jacobian has columns
    x0 → (1, 0), z0 → (0, 1), θ → ⊥P_k, q1 → ⊥B_k with ⊥(x, z) = (z, −x), and
    J̇ ġ = −(P_k − B_k) θ̇² − B_k (θ̇ + q̇1)².
    """
    g_ = _check_g(g)
    v = _check_g(g_dot, "g_dot")
    P, B = _mass_point_vectors(params, g_)
    m = (params.body_mass, params.bogie_mass, params.wheel_mass, params.wheel_mass, params.wheel_mass)
    rate0 = float(v[_PITCH]) ** 2
    rate1 = float(v[_PITCH] + v[_BOGIE]) ** 2

    total = sum_pz = sum_px = sum_bz = sum_bx = 0.0
    h_tt = h_tq = h_qq = 0.0
    c_x = c_z = c_t = c_q = 0.0
    bias = []
    for mk, (px, pz), (bx, bz) in zip(m, P, B, strict=True):
        ax = -(px - bx) * rate0 - bx * rate1
        az = -(pz - bz) * rate0 - bz * rate1
        bias.append((ax, az))
        total += mk
        sum_pz += mk * pz
        sum_px += mk * px
        sum_bz += mk * bz
        sum_bx += mk * bx
        h_tt += mk * (px * px + pz * pz)
        h_tq += mk * (px * bx + pz * bz)
        h_qq += mk * (bx * bx + bz * bz)
        c_x += mk * ax
        c_z += mk * az
        c_t += mk * (pz * ax - px * az)
        c_q += mk * (bz * ax - bx * az)

    Hl = [row[:] for row in _ROTATIONAL_INERTIA_CACHE.get_list(params)]
    Hl[0][0] += total
    Hl[1][1] += total
    Hl[0][2] += sum_pz
    Hl[1][2] -= sum_px
    Hl[0][3] += sum_bz
    Hl[1][3] -= sum_bx
    Hl[2][2] += h_tt
    Hl[2][3] += h_tq
    Hl[3][3] += h_qq
    for i, j in ((0, 2), (1, 2), (0, 3), (1, 3), (2, 3)):
        Hl[j][i] = Hl[i][j]
    weight = params.gravity
    gravity = np.array([0.0, weight * total, -weight * sum_px, -weight * sum_bx, 0.0, 0.0, 0.0])
    coriolis = np.array([c_x, c_z, c_t, c_q, 0.0, 0.0, 0.0])
    rows = []
    for j in range(3):
        (px, pz), (bx, bz) = P[2 + j], B[2 + j]
        rows.append([[1.0, 0.0, pz, bz, 0.0, 0.0, 0.0], [0.0, 1.0, -px, -bx, 0.0, 0.0, 0.0]])
    x0, z0 = float(g_[_X0]), float(g_[_Z0])
    centres = np.array([[x0 + px, z0 + pz] for px, pz in P[2:]])
    return DynamicsTerms(np.array(Hl), coriolis, gravity, centres, np.array(rows), np.array(bias[2:]))


def _mass_point_vectors(params: RoverParams, g: Array) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
    """(P_k, B_k) of :func:`dynamics_terms` for the five mass points (body, bogie CM, rear, middle, front)."""
    pitch, carrier = float(g[_PITCH]), float(g[_PITCH] + g[_BOGIE])
    c0, s0 = math.cos(pitch), math.sin(pitch)
    c1, s1 = math.cos(carrier), math.sin(carrier)

    def rot(vector: tuple[float, float], c: float, s: float) -> tuple[float, float]:
        return vector[0] * c + vector[1] * s, -vector[0] * s + vector[1] * c

    lx, lz = rot(params.bogie_joint_offset, c0, s0)
    fx, fz = rot(params.front_wheel_offset, c0, s0)
    rear, middle = params.bogie_wheel_offsets
    bogie_vectors = (
        rot(params.bogie_cm_offset, c1, s1),
        rot(rear, c1, s1),
        rot(middle, c1, s1),
    )
    P = [(0.0, 0.0)] + [(lx + bx, lz + bz) for bx, bz in bogie_vectors] + [(fx, fz)]
    B = [(0.0, 0.0), *bogie_vectors, (0.0, 0.0)]
    return P, B


def dynamics_gravity(params: RoverParams, g: ArrayLike) -> Array:
    """``dynamics_terms(params, g, ġ).gravity`` (∂V/∂g, (7,)), bit for bit, without H, c and the wheel kinematics.

    The estimator's gravity stiffness differentiates ∂V/∂g at four configurations per step.
    """
    P, B = _mass_point_vectors(params, _check_g(g))
    m = (params.body_mass, params.bogie_mass, params.wheel_mass, params.wheel_mass, params.wheel_mass)
    total = sum_px = sum_bx = 0.0
    for mk, (px, _), (bx, _) in zip(m, P, B, strict=True):
        total += mk
        sum_px += mk * px
        sum_bx += mk * bx
    weight = params.gravity
    return np.array([0.0, weight * total, -weight * sum_px, -weight * sum_bx, 0.0, 0.0, 0.0])


class _RotationalInertia:
    """Σ I J_ωᵀ J_ω plus the gear-train diagonal: constant for given parameters, cached per params."""

    def __init__(self) -> None:
        self._params: RoverParams | None = None
        self._value: Array = np.zeros((N_COORDINATES, N_COORDINATES))
        self._list: list[list[float]] = self._value.tolist()

    def get(self, params: RoverParams) -> Array:
        if params is not self._params:
            value = np.einsum("k,ki,kj->ij", _inertias(params), _ANGULAR_JACOBIANS, _ANGULAR_JACOBIANS)
            for coordinate in _WHEEL_COORDINATE:
                value[coordinate, coordinate] += params.wheel_gear_inertia - params.wheel_inertia
            value.setflags(write=False)
            self._params, self._value, self._list = params, value, value.tolist()
        return self._value

    def get_list(self, params: RoverParams) -> list[list[float]]:
        self.get(params)
        return self._list


_ROTATIONAL_INERTIA_CACHE = _RotationalInertia()


def potential_energy(params: RoverParams, g: ArrayLike) -> float:
    """V = g Σ m_i z_i (J), eq. 15."""
    z = mass_point_positions(params, g)[:, 1]
    return float(params.gravity * np.dot(_masses(params), z))


def kinetic_energy(params: RoverParams, g: ArrayLike, g_dot: ArrayLike) -> float:
    """T = ½ ġᵀ H ġ (J), eq. 14."""
    v = _check_g(g_dot, "g_dot")
    return float(0.5 * v @ mass_matrix(params, g) @ v)


def generalised_wheel_forces(
    params: RoverParams,
    g: ArrayLike,
    force_x: ArrayLike,
    force_z: ArrayLike,
    wheel_moment: ArrayLike,
    *,
    drive_torque: ArrayLike | None = None,
) -> Array:
    """Generalised forces of loads on the wheels (eqs. 33–40), shape (7,).

    Q = Σ_j J_v,jᵀ (F_x,j, F_z,j) + J_ω,jᵀ M_j + τ_W,j e_{q_j}

    Args:
        params: rover parameters.
        g: configuration (7,).
        force_x, force_z: world force on each wheel centre (N), shape (3,)
            (e.g. DP along the terrain tangent, eqs. 37–39, and the normal
            load if it is applied rather than a constraint reaction).
        wheel_moment: external moment about +y on each wheel (N·m), shape (3,);
            the soil's resistive torque enters as −τ_R (eq. 36). It acts on
            the wheel's absolute rotation, so it also loads θ and q1 (eq. 34).
        drive_torque: internal torque between each wheel and its carrier
            (N·m), shape (3,), e.g. τ_W − b_d q̇_j of eq. 40. It turns the wheel
            forward and its reaction turns the carrier backward, so only the
            wheel coordinate q_j receives it.
    """
    arr = _check_g(g)
    fx = np.broadcast_to(np.asarray(force_x, dtype=float), (3,))
    fz = np.broadcast_to(np.asarray(force_z, dtype=float), (3,))
    moment = np.broadcast_to(np.asarray(wheel_moment, dtype=float), (3,))
    jac = wheel_centre_jacobian(params, arr)
    q = np.einsum("jai,ja->i", jac, np.stack([fx, fz], axis=1))
    q += _ANGULAR_JACOBIANS[2:].T @ moment
    if drive_torque is not None:
        torque = np.broadcast_to(np.asarray(drive_torque, dtype=float), (3,))
        q[list(_WHEEL_COORDINATE)] += torque
    return q


def body_specific_force(params: RoverParams, g: ArrayLike, g_ddot: ArrayLike) -> Array:
    """Body-frame specific force (f_x, f_z) at O (m/s²), eqs. 72–73 (gravity included, REP 145).

    f_x = ẍ0 cos θ − (z̈0 + g) sin θ,  f_z = ẍ0 sin θ + (z̈0 + g) cos θ.
    A rover at rest on level ground reads (0, +g).
    """
    arr = _check_g(g)
    acc = _check_g(g_ddot, "g_ddot")
    c, s = math.cos(arr[_PITCH]), math.sin(arr[_PITCH])
    up = acc[_Z0] + params.gravity
    return np.array([acc[_X0] * c - up * s, acc[_X0] * s + up * c])
