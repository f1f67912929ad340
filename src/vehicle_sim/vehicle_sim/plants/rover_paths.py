"""Wheel-centre paths of the rover's terrains ([RB] Fig. 10, MODELS.md C.1): z_wc(x), its slope and curvature.

The plant (:mod:`vehicle_sim.plants.rover`, whose docstring is the "plant
docstring" referred to below) constrains the three wheel centres to one of
these paths; :data:`TERRAINS` names them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vehicle_sim.plants.checks import check_float_non_negative, check_float_positive

__all__ = [
    "ROLLING_COMPONENTS",
    "SLOPE_TRANSITIONS",
    "SLOPE_TRANSITION_LENGTH",
    "STEP_HEIGHT",
    "STEP_POSITION",
    "STEP_WIDTHS",
    "TERRAINS",
    "TERRAIN_NUMBERS",
    "PointProfile",
    "Profile",
    "WheelPath",
    "flat_path",
    "rolling_path",
    "slope_path",
    "step_path",
    "undulated_path",
]

Array = NDArray[np.float64]

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
        """γ = −atan(dz_wc/dx) (rad), positive downhill (plant docstring)."""
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
    check_float_positive("step_path", "width", width)
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
    check_float_non_negative("undulated_path", "amplitude", amplitude)
    check_float_positive("undulated_path", "wavelength", wavelength)
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
