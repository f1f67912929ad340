"""Ground of the skid-steer truth plant: an inclined plane, surfaces and terrain patches, support loads.

The observer of [SS] assumes flat, uniform ground. The truth plant can drive on
a plane inclined in two directions and over patches of other surfaces, each
wheel on whatever is under its own contact point.

Plane and coordinates
    The plant's pose ``(x, y, yaw)`` lives in the ground plane (as with the
    effect ``terrain_grade``). The plane is the horizontal plane rotated first
    by ``grade`` about the world y axis (its x axis then rises at ``grade``),
    then by ``cross_slope`` about its new x axis (its y axis rises at
    ``cross_slope``). Gravity in the plane's axes (x, y in the plane, z normal
    to it) is therefore::

        g_plane = −g (sin γ_x, cos γ_x sin γ_y, cos γ_x cos γ_y)

    and in the body's axes, heading ψ in the plane::

        g_bx =  g_px cos ψ + g_py sin ψ,   g_by = −g_px sin ψ + g_py cos ψ,   g_n = −g_pz

    With the plant's helical ramp ``terrain_grade`` γ (every heading climbs by
    γ: a body-fixed pitch) on top: ``g_bx ← g_bx cos γ − g_n sin γ``,
    ``g_n ← g_bx sin γ + g_n cos γ`` (the level plane gives back ``−g sin γ``
    and ``g cos γ``). The body equations gain ``g_bx, g_by``; the normal loads
    carry ``m g_n`` and the load transfer follows the specific force (ground
    forces / m), which on a bank includes the force holding the vehicle
    against the slope; the IMU reads that specific force and ``g_n`` on z.
    Parked on a 5° bank its y axis reads ``g sin 5°`` (ISO 8855 / REP 145:
    +g on z at rest).

Surfaces and patches
    A :class:`Surface` has a peak friction coefficient μ (at the tire's
    nominal load), a factor on the tire's slip stiffnesses and a
    rolling-resistance coefficient. The vehicle's own surface (μ of
    :class:`~terrain_estimation.models.skid_steer.SkidSteerParams`, f_rr of the
    plant's vehicle, stiffness × 1) covers the plane; :class:`TerrainPatch`
    rectangles ``[x_min, x_max] × [y_min, y_max]`` in plane coordinates
    (sides may be infinite: an interval of x, a half-plane, a strip) lay other
    surfaces over it, later patches over earlier ones. Each wheel reads the
    surface at its own contact point (``x + cos ψ x_i − sin ψ y_i``, …), so a
    wheel enters a patch when it reaches it. Across an edge the properties
    blend over ``transition`` metres centred on the edge with the weight
    ``3u² − 2u³``, u = ½ + d/transition clipped to [0, 1] (d the signed
    distance into the patch): the share of the load of a parabolic contact
    pressure on the new side while the contact patch (≈ 0.3 m long for a
    0.75 m off-road wheel) crosses the edge. Rectangle weights are products of
    their edge weights.

Surface presets (:data:`SURFACES`; dry unless stated; μ peak, f_rr of a tire
on the surface, stiffness factor)
    ``asphalt``  μ 0.80, f_rr 0.010, × 1.00 — dry asphalt: peak 0.8–0.9
    (Wong, *Theory of Ground Vehicles*, 4th ed. 2008, Table 1.3; skid 0.65,
    Noon 1994), truck tires on asphalt f_rr 0.006–0.01 (Carvill,
    *Mechanical Engineer's Data Handbook* 1993: new asphalt 0.01); the tire's
    datasheet stiffness (measured on a rigid surface).
    ``gravel``   μ 0.60, f_rr 0.020, × 0.80 — gravel/crushed stone 0.6–0.7
    dry (Wong Table 1.3), rolled gravel f_rr 0.02 (loose 0.04, Carvill).
    ``grass``    μ 0.40, f_rr 0.050, × 0.60 — short grass on firm soil:
    between a dry earth road (0.5–0.6) and a wet grassy field (0.20, Noon
    1994); f_rr of medium-hard soil 0.04–0.08 (Carvill).
    ``mud``      μ 0.25, f_rr 0.150, × 0.35 — wet cohesive soil a few cm deep:
    wet earth road 0.15–0.25; sinkage raises f_rr to that of soft soil and
    sand, 0.1–0.2 (Carvill).
    The stiffness factors are estimates: on deformable ground the soil's
    shear deformation (Janosi–Hanamoto modulus K ≈ 1–5 cm, Wong 2008 ch. 2)
    adds compliance in series with the tread, so the apparent slip
    stiffnesses fall as the ground softens. The catalogue effect
    ``friction_change`` multiplies the μ of every surface.

Support loads
    :func:`equal_spring_loads`: the rigid body on equal virtual springs of
    MODELS.md B.5, the plant's own implementation (the same statics as the
    observer's ``quasi_static_loads``, written with its arithmetic).

Units: m, rad, N, m/s².
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.checks import check_positive
from terrain_estimation.jit import compiled

__all__ = [
    "SURFACES",
    "GroundContact",
    "SkidSteerGround",
    "Surface",
    "TerrainPatch",
    "equal_spring_loads",
    "plane_gravity",
]

Array = NDArray[np.float64]

#: Largest |grade|, |cross_slope| (rad), as the plant's ``terrain_grade``.
MAX_SLOPE = math.pi / 4.0


@dataclass(frozen=True, kw_only=True)
class Surface:
    """One ground surface.

    Attributes:
        name: label.
        friction: peak tire–ground friction coefficient μ at the tire's
            nominal load (> 0).
        stiffness_scale: factor on the tire's longitudinal and cornering slip
            stiffnesses (> 0).
        rolling_resistance: motion-resistance coefficient f_rr, force per unit
            normal load (≥ 0).
    """

    name: str
    friction: float
    stiffness_scale: float = 1.0
    rolling_resistance: float = 0.02

    def __post_init__(self) -> None:
        owner = f"Surface {self.name!r}"
        for name in ("friction", "stiffness_scale"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{owner}: {name} must be finite and > 0, got {value}")
        rr = self.rolling_resistance
        if not (math.isfinite(rr) and 0.0 <= rr <= 1.0):
            raise ValueError(f"{owner}: rolling_resistance must be in [0, 1], got {rr}")


SURFACES: dict[str, Surface] = {
    "asphalt": Surface(name="asphalt", friction=0.80, stiffness_scale=1.00, rolling_resistance=0.010),
    "gravel": Surface(name="gravel", friction=0.60, stiffness_scale=0.80, rolling_resistance=0.020),
    "grass": Surface(name="grass", friction=0.40, stiffness_scale=0.60, rolling_resistance=0.050),
    "mud": Surface(name="mud", friction=0.25, stiffness_scale=0.35, rolling_resistance=0.150),
}
"""Surface presets by name (values and sources in the module docstring)."""


@dataclass(frozen=True, kw_only=True)
class TerrainPatch:
    """A rectangle of the ground plane covered by ``surface`` (plane coordinates, m; sides may be ±inf).

    Attributes:
        surface: what covers it.
        x_min, x_max: extent along the plane's x axis, x_min < x_max.
        y_min, y_max: extent along its y axis, y_min < y_max.
    """

    surface: Surface
    x_min: float = -math.inf
    x_max: float = math.inf
    y_min: float = -math.inf
    y_max: float = math.inf

    def __post_init__(self) -> None:
        if not isinstance(self.surface, Surface):
            raise ValueError(f"TerrainPatch.surface must be a Surface, got {self.surface!r}")
        for low, high in (("x_min", "x_max"), ("y_min", "y_max")):
            lo, hi = float(getattr(self, low)), float(getattr(self, high))
            if math.isnan(lo) or math.isnan(hi) or not lo < hi:
                raise ValueError(f"TerrainPatch.{low} must be < {high}, got {lo} and {hi}")
            if lo == math.inf or hi == -math.inf:
                raise ValueError(f"TerrainPatch.{low}, {high} leave no area: {lo}, {hi}")
            object.__setattr__(self, low, lo)
            object.__setattr__(self, high, hi)


@dataclass(frozen=True, kw_only=True)
class SkidSteerGround:
    """The ground the plant drives on: an inclined plane with surface patches (module docstring).

    The default is the level, uniform ground of the nominal model.

    Attributes:
        grade: inclination of the plane's x axis (rad, > 0: the plane rises
            along +x), |grade| < π/4.
        cross_slope: inclination of the plane's y axis (rad, > 0: rises along
            +y, so a vehicle heading +x stands on a bank with its left side
            up), |cross_slope| < π/4.
        patches: surfaces laid over the vehicle's own, later over earlier.
        transition: width of the blend across a patch edge (m, > 0).
    """

    grade: float = 0.0
    cross_slope: float = 0.0
    patches: tuple[TerrainPatch, ...] = ()
    transition: float = 0.3

    def __post_init__(self) -> None:
        owner = "SkidSteerGround"
        for name in ("grade", "cross_slope"):
            value = getattr(self, name)
            if not (math.isfinite(value) and abs(value) < MAX_SLOPE):
                raise ValueError(f"{owner}.{name} must be in (−π/4, π/4) rad, got {value}")
        patches = tuple(self.patches)
        for patch in patches:
            if not isinstance(patch, TerrainPatch):
                raise ValueError(f"{owner}.patches must hold TerrainPatch objects, got {patch!r}")
        object.__setattr__(self, "patches", patches)
        check_positive(owner, "transition", self.transition)

    @property
    def level(self) -> bool:
        """True when the plane is horizontal."""
        return self.grade == 0.0 and self.cross_slope == 0.0

    @property
    def uniform(self) -> bool:
        """True when no patch covers any of the plane."""
        return not self.patches


def plane_gravity(ground: SkidSteerGround, gravity: float) -> tuple[float, float, float]:
    """Gravity in the plane's axes ``(g_px, g_py, g_pz)`` (m/s²), module docstring."""
    cx, sx = math.cos(ground.grade), math.sin(ground.grade)
    cy, sy = math.cos(ground.cross_slope), math.sin(ground.cross_slope)
    return -gravity * sx, -gravity * cx * sy, -gravity * cx * cy


def equal_spring_loads(
    axle_x: Array, track: float, mass: float, gravity: float, cg_height: float, f_x: Any, f_y: Any
) -> Array:
    """Wheel loads of a rigid body on equal virtual springs (MODELS.md B.5), floored at 0 (N).

    Axle loads ``F_i = p + q x_i`` carry ``m g`` and balance the pitch moment
    ``m f_x H`` of the ground forces; the roll moment ``m f_y H`` is split
    equally over the axles across the track. Wheel order: the left wheels
    front to rear, then the right ones. Inputs ``f_x, f_y`` (specific force,
    m/s²) broadcast; the output ends in a dimension of 2 × len(axle_x).
    """
    xa = np.asarray(axle_x, dtype=float)
    n = xa.size
    s1, s2 = float(np.sum(xa)), float(np.sum(xa**2))
    d = n * s2 - s1**2
    ax_ = np.asarray(f_x, dtype=float)[..., None]
    ay_ = np.asarray(f_y, dtype=float)[..., None]
    p0 = mass * (gravity * s2 + ax_ * cg_height * s1) / d
    q = -mass * (n * ax_ * cg_height + gravity * s1) / d
    axle = p0 + q * xa
    lateral = mass * ay_ * cg_height / (n * track)
    return np.maximum(np.concatenate([0.5 * axle - lateral, 0.5 * axle + lateral], axis=-1), 0.0)


@compiled
def _edge_weight(distance: float, inverse_width: float) -> float:
    """Share 3u² − 2u³ of the new surface, u = ½ + d/width clipped to [0, 1]."""
    u = 0.5 + distance * inverse_width
    if u <= 0.0:
        return 0.0
    if u >= 1.0:
        return 1.0
    return u * u * (3.0 - 2.0 * u)


@compiled
def _surfaces_under(x, y, cos_yaw, sin_yaw, wheel_x, wheel_y, bounds, values, base, inverse_width, out):
    """Per-wheel (μ, stiffness scale, f_rr) into ``out`` (3, n_wheels) from the pose and the patches."""
    for i in range(wheel_x.shape[0]):
        px = x + cos_yaw * wheel_x[i] - sin_yaw * wheel_y[i]
        py = y + sin_yaw * wheel_x[i] + cos_yaw * wheel_y[i]
        mu, scale, rr = base[0], base[1], base[2]
        for j in range(bounds.shape[0]):
            w = _edge_weight(px - bounds[j, 0], inverse_width)
            if w > 0.0:
                w *= _edge_weight(bounds[j, 1] - px, inverse_width)
            if w > 0.0:
                w *= _edge_weight(py - bounds[j, 2], inverse_width)
            if w > 0.0:
                w *= _edge_weight(bounds[j, 3] - py, inverse_width)
            if w > 0.0:
                mu += w * (values[j, 0] - mu)
                scale += w * (values[j, 1] - scale)
                rr += w * (values[j, 2] - rr)
        out[0, i] = mu
        out[1, i] = scale
        out[2, i] = rr


class GroundContact:
    """What the ground gives the plant at each evaluation: surfaces under the wheels and body-frame gravity.

    Args:
        ground: the ground.
        base: the vehicle's own surface (μ already with the effects' change).
        friction_factor: the effect ``friction_change``, applied to the
            patches' μ.
        wheel_x, wheel_y: contact points in the body frame (m), wheel order.
        gravity: g (m/s²).
        terrain_grade: the plant's helical-ramp grade γ (rad).
    """

    def __init__(
        self,
        ground: SkidSteerGround,
        base: Surface,
        friction_factor: float,
        wheel_x: Array,
        wheel_y: Array,
        gravity: float,
        terrain_grade: float,
    ) -> None:
        self.ground = ground
        self.base = base
        self.uniform = ground.uniform
        self.level = ground.level
        self._wheel_x = np.ascontiguousarray(wheel_x, dtype=float)
        self._wheel_y = np.ascontiguousarray(wheel_y, dtype=float)
        self._bounds = np.array([[p.x_min, p.x_max, p.y_min, p.y_max] for p in ground.patches], dtype=float).reshape(
            -1, 4
        )
        self._values = np.array(
            [
                [p.surface.friction * friction_factor, p.surface.stiffness_scale, p.surface.rolling_resistance]
                for p in ground.patches
            ],
            dtype=float,
        ).reshape(-1, 3)
        self._base = np.array((base.friction, base.stiffness_scale, base.rolling_resistance))
        self._inverse_width = 1.0 / ground.transition
        self._plane = plane_gravity(ground, gravity)
        self._cos_grade, self._sin_grade = math.cos(terrain_grade), math.sin(terrain_grade)
        self.max_stiffness_scale = max([base.stiffness_scale] + [p.surface.stiffness_scale for p in ground.patches])

    def surfaces(self, x: float, y: float, cos_yaw: float, sin_yaw: float) -> tuple[Array, Array, Array]:
        """(μ, stiffness scale, f_rr) per wheel at the pose (x, y in the plane, m; heading cos/sin)."""
        out = np.empty((3, self._wheel_x.size))
        _surfaces_under(
            x, y, cos_yaw, sin_yaw, self._wheel_x, self._wheel_y, self._bounds, self._values, self._base,
            self._inverse_width, out,
        )  # fmt: skip
        return out[0], out[1], out[2]

    def gravity(self, cos_yaw: float, sin_yaw: float) -> tuple[float, float, float]:
        """Gravity along body x and y and its normal component g_n (m/s²) at the heading."""
        gx, gy, gz = self._plane
        hx = gx * cos_yaw + gy * sin_yaw
        hy = -gx * sin_yaw + gy * cos_yaw
        normal = -gz
        return (
            hx * self._cos_grade - normal * self._sin_grade,
            hy,
            hx * self._sin_grade + normal * self._cos_grade,
        )
