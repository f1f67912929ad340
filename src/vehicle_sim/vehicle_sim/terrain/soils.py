"""Soils as equivalent vertical stiffness, and the series-spring algebra around it.

Reina, Leanza, Messina (Terrain estimation via vehicle vibration measurement and
Cubature Kalman Filtering) reduce a deformable soil to one number: the equivalent
stiffness ``k_s`` of the ground under a wheel, linearised about the static
sinkage (their eq. 1), working in series with the tire (eq. 3). This module
holds:

* the soils of the paper's Table 1 and the lunar regolith of section 5.3, with
  their tabulated ``k_s`` (the ground truth of every simulation);
* the series-spring relations ``k_tot(k_s, k)`` (eq. 3) and its inverse;
* :class:`SoilPath`, piecewise-constant soil along the distance travelled;
* Bekker pressure-sinkage utilities (MODELS.md A.2) that turn Bekker soil
  parameters into an equivalent stiffness. They are documentation-grade: with
  the commonly tabulated parameters they do **not** reproduce Table 1, and the
  parameters themselves are unverified against the book.

Units are SI throughout: N/m for stiffness, m for sinkage and geometry, N for
loads, Pa for pressures.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "BEKKER_PARAMETERS_UNVERIFIED",
    "GRANEVILLE_LOAM",
    "LETE_SAND",
    "LUNAR_REGOLITH",
    "NORTH_GOWER_CLAYEY_LOAM",
    "RUBICON_SANDY_LOAM",
    "SOILS",
    "TABLE1_SOILS",
    "UPLAND_SANDY_LOAM",
    "BekkerParameters",
    "Soil",
    "SoilPath",
    "bekker_pressure",
    "flat_contact_equivalent_stiffness",
    "flat_contact_static_sinkage",
    "k_s_error_amplification",
    "k_s_from_k_tot",
    "k_tot",
    "nearest_soil",
    "rigid_wheel_equivalent_stiffness",
    "rigid_wheel_load",
    "rigid_wheel_static_sinkage",
    "soil_by_name",
]


@dataclass(frozen=True)
class Soil:
    """A soil described by its equivalent vertical stiffness.

    Attributes:
        name: Identifier (snake_case), e.g. ``"graneville_loam"``.
        display_name: Human-readable name as printed in the source.
        k_s: Equivalent soil stiffness (N/m), linearised about the static
            sinkage of the reference wheel (paper eq. 1).
    """

    name: str
    display_name: str
    k_s: float

    def __post_init__(self) -> None:
        if not self.k_s > 0.0:
            raise ValueError(f"soil {self.name!r}: k_s must be > 0 N/m, got {self.k_s}")

    def k_tot(self, series_stiffness: float) -> float:
        """Combined stiffness of this soil in series with ``series_stiffness`` (N/m).

        Args:
            series_stiffness: Stiffness in series with the soil (N/m): the tire
                stiffness k_t for the 2-DOF quarter car, the combined
                suspension/tire stiffness k for the 1-DOF LRV.

        Returns:
            k_tot (N/m), paper eq. 3.
        """
        return float(k_tot(self.k_s, series_stiffness))


# Table 1 of the paper: cross-country vehicle, W = 4905 N, D = 0.777 m, b = 0.265 m.
UPLAND_SANDY_LOAM = Soil("upland_sandy_loam", "Upland sandy loam", 218.1e3)
LETE_SAND = Soil("lete_sand", "LETE sand", 2283.0e3)
RUBICON_SANDY_LOAM = Soil("rubicon_sandy_loam", "Rubicon sandy loam", 272.1e3)
NORTH_GOWER_CLAYEY_LOAM = Soil("north_gower_clayey_loam", "North Gower clayey loam", 221.9e3)
GRANEVILLE_LOAM = Soil("graneville_loam", "Graneville loam", 651.1e3)
# Section 5.3: LRV wheel, D = 1.016 m, b = 0.254 m, Earth load W = 735 N.
LUNAR_REGOLITH = Soil("lunar_regolith", "Lunar regolith", 28.487e3)

TABLE1_SOILS: tuple[Soil, ...] = (
    UPLAND_SANDY_LOAM,
    LETE_SAND,
    RUBICON_SANDY_LOAM,
    NORTH_GOWER_CLAYEY_LOAM,
    GRANEVILLE_LOAM,
)
"""The five soils of the paper's Table 1, in the table's order."""

SOILS: Mapping[str, Soil] = MappingProxyType({soil.name: soil for soil in (*TABLE1_SOILS, LUNAR_REGOLITH)})
"""Every known soil by :attr:`Soil.name` (read-only)."""


def soil_by_name(name: str) -> Soil:
    """Look a soil up by its identifier.

    Args:
        name: A key of :data:`SOILS`, e.g. ``"lete_sand"``.

    Returns:
        The soil.

    Raises:
        KeyError: With the list of known names when ``name`` is unknown.
    """
    try:
        return SOILS[name]
    except KeyError:
        raise KeyError(f"unknown soil {name!r}; known: {sorted(SOILS)}") from None


def nearest_soil(k_s: float, candidates: Iterable[Soil] = TABLE1_SOILS) -> Soil:
    """The candidate soil whose stiffness is nearest to ``k_s`` on a log scale.

    A log distance is used because the soils span a decade (218 to 2283 kN/m)
    and stiffness errors are relative.

    Args:
        k_s: Soil stiffness (N/m), > 0.
        candidates: Soils to choose from (default: Table 1).

    Returns:
        The nearest soil.
    """
    if not k_s > 0.0:
        raise ValueError(f"k_s must be > 0 N/m, got {k_s}")
    pool = tuple(candidates)
    if not pool:
        raise ValueError("no candidate soils")
    return min(pool, key=lambda soil: abs(math.log(soil.k_s / k_s)))


def k_tot(k_s: ArrayLike, k: ArrayLike) -> NDArray[np.float64] | float:
    """Series stiffness of soil and tire (paper eq. 3): k_tot = k_s k / (k_s + k).

    Args:
        k_s: Soil stiffness (N/m), > 0; ``inf`` means rigid ground (k_tot = k).
            Scalar or array.
        k: Stiffness in series with the soil (N/m), > 0 (tire stiffness k_t for
            the 2-DOF car, combined stiffness for the LRV). Broadcasts with k_s.

    Returns:
        k_tot (N/m), a float for scalar inputs, else an array of the broadcast shape.

    Raises:
        ValueError: If any k_s or k is not strictly positive.
    """
    k_s_arr = np.asarray(k_s, dtype=float)
    k_arr = np.asarray(k, dtype=float)
    if np.any(~(k_s_arr > 0.0)):
        raise ValueError(f"k_s must be > 0 N/m (inf allowed for rigid ground), got {k_s!r}")
    if np.any(~(k_arr > 0.0)) or np.any(~np.isfinite(k_arr)):
        raise ValueError(f"series stiffness k must be finite and > 0 N/m, got {k!r}")
    # Written as k / (1 + k/k_s) so that k_s = inf gives exactly k.
    result = k_arr / (1.0 + k_arr / k_s_arr)
    return float(result) if result.ndim == 0 else result


def k_s_from_k_tot(k_tot: ArrayLike, k: ArrayLike) -> NDArray[np.float64] | float:
    """Invert eq. 3: k_s = k_tot k / (k − k_tot), valid for 0 < k_tot < k.

    The inversion is ill-conditioned near k_tot → k (stiff soils): see
    :func:`k_s_error_amplification`. Callers that hold an estimate should clamp
    it into (0, k) themselves; this function refuses values outside.

    Args:
        k_tot: Combined stiffness (N/m), scalar or array.
        k: Stiffness in series with the soil (N/m), broadcast with k_tot.

    Returns:
        k_s (N/m), a float for scalar inputs, else an array.

    Raises:
        ValueError: If any k_tot is not inside the open interval (0, k).
    """
    k_tot_arr = np.asarray(k_tot, dtype=float)
    k_arr = np.asarray(k, dtype=float)
    if np.any(~(k_arr > 0.0)) or np.any(~np.isfinite(k_arr)):
        raise ValueError(f"series stiffness k must be finite and > 0 N/m, got {k!r}")
    valid = (k_tot_arr > 0.0) & (k_tot_arr < k_arr)
    if not np.all(valid):
        raise ValueError(
            f"k_tot must satisfy 0 < k_tot < k for a finite positive k_s; got k_tot={k_tot!r} N/m with k={k!r} N/m"
        )
    result = k_tot_arr * k_arr / (k_arr - k_tot_arr)
    return float(result) if result.ndim == 0 else result


def k_s_error_amplification(k_tot: ArrayLike, k: ArrayLike) -> NDArray[np.float64] | float:
    """Relative-error gain from k_tot to k_s: (dk_s/k_s) / (dk_tot/k_tot) = k / (k − k_tot).

    MODELS.md A.2: 2.25 for Upland sandy loam, 14.05 for LETE sand with
    k_t = 175 kN/m.

    Args:
        k_tot: Combined stiffness (N/m), 0 < k_tot < k.
        k: Stiffness in series with the soil (N/m).

    Returns:
        The dimensionless gain, float or array.
    """
    k_tot_arr = np.asarray(k_tot, dtype=float)
    k_arr = np.asarray(k, dtype=float)
    if not np.all((k_tot_arr > 0.0) & (k_tot_arr < k_arr)):
        raise ValueError(f"need 0 < k_tot < k, got k_tot={k_tot!r}, k={k!r}")
    result = k_arr / (k_arr - k_tot_arr)
    return float(result) if result.ndim == 0 else result


class SoilPath:
    """Piecewise-constant soil along the distance travelled.

    Built from ``(start distance (m), soil)`` pairs: each soil holds from its
    start up to the next start. The first start must be ≤ 0 so that every
    distance s ≥ 0 has a soil.

    Args:
        segments: ``[(start_m, Soil), ...]`` with strictly increasing starts,
            or a single :class:`Soil` for uniform ground.

    Attributes:
        starts: Start distances (m), shape (S,).
        soils: The soils, length S.
    """

    def __init__(self, segments: Soil | Sequence[tuple[float, Soil]]) -> None:
        if isinstance(segments, Soil):
            segments = ((0.0, segments),)
        pairs = tuple((float(start), soil) for start, soil in segments)
        if not pairs:
            raise ValueError("a soil path needs at least one segment")
        for _, soil in pairs:
            if not isinstance(soil, Soil):
                raise TypeError(f"soil path entries must be (distance, Soil), got {soil!r}")
        starts = np.array([start for start, _ in pairs])
        if starts[0] > 0.0:
            raise ValueError(f"the first soil must start at distance ≤ 0 m, got {starts[0]}")
        if np.any(np.diff(starts) <= 0.0):
            raise ValueError(f"soil start distances must increase strictly, got {starts}")
        self.segments: tuple[tuple[float, Soil], ...] = pairs
        self.starts: NDArray[np.float64] = starts
        self.soils: tuple[Soil, ...] = tuple(soil for _, soil in pairs)
        self._k_s = np.array([soil.k_s for soil in self.soils])

    def index_at(self, distance: ArrayLike) -> NDArray[np.intp]:
        """Segment index for each distance (m); shape of ``distance``."""
        idx = np.searchsorted(self.starts, np.asarray(distance, dtype=float), side="right") - 1
        return np.maximum(idx, 0)

    def soil_at(self, distance: float) -> Soil:
        """The soil under the wheel at one distance (m)."""
        return self.soils[int(self.index_at(distance))]

    def k_s_at(self, distance: ArrayLike) -> NDArray[np.float64]:
        """Soil stiffness (N/m) at each distance (m); shape of ``distance``."""
        return self._k_s[self.index_at(distance)]

    def __repr__(self) -> str:
        inner = ", ".join(f"({start:g} m, {soil.name})" for start, soil in self.segments)
        return f"SoilPath([{inner}])"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SoilPath) and self.segments == other.segments

    def __hash__(self) -> int:
        return hash(self.segments)


# ---------------------------------------------------------------------------
# Bekker-based equivalent stiffness (MODELS.md A.2, [recon]).
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class BekkerParameters:
    """Bekker pressure-sinkage parameters, p = (k_c/b + k_phi) z^n (SI units).

    Attributes:
        n: Sinkage exponent (dimensionless).
        k_c: Cohesive modulus (N/m^(n+1)).
        k_phi: Frictional modulus (N/m^(n+2)).
        source: Where the numbers come from, and how sure we are of them.
    """

    n: float
    k_c: float
    k_phi: float
    source: str = ""


_UNVERIFIED_WONG = (
    "UNVERIFIED: values as commonly tabulated after Wong, Theory of Ground Vehicles "
    "(2008), not checked against the book (MODELS.md A.2 [check])"
)

BEKKER_PARAMETERS_UNVERIFIED: Mapping[str, BekkerParameters] = MappingProxyType(
    {
        "lete_sand": BekkerParameters(0.79, 102e3, 5301e3, _UNVERIFIED_WONG),
        "upland_sandy_loam": BekkerParameters(1.10, 74.6e3, 2080e3, _UNVERIFIED_WONG),
        "rubicon_sandy_loam": BekkerParameters(0.66, 6.9e3, 752e3, _UNVERIFIED_WONG),
        "north_gower_clayey_loam": BekkerParameters(0.73, 41.6e3, 2471e3, _UNVERIFIED_WONG),
        "graneville_loam": BekkerParameters(1.01, 0.06e3, 5880e3, _UNVERIFIED_WONG),
        "lunar_regolith": BekkerParameters(
            1.0,
            1.4e3,
            820e3,
            "UNVERIFIED: lunar soil values as commonly quoted (MODELS.md A.2 [check])",
        ),
    }
)
"""Bekker parameters per soil name, as commonly tabulated — **unverified**.

With these, :func:`rigid_wheel_equivalent_stiffness` gives about 113 / 384 /
103 / 244 / 236 kN/m for Table 1's soils (in the table's order) and about
36.7 kN/m for regolith under the LRV wheel: not the paper's Table 1 values.
Use :class:`Soil` ``k_s`` as ground truth.
"""


def bekker_pressure(sinkage: ArrayLike, width: float, params: BekkerParameters) -> ArrayLike:
    """Bekker pressure-sinkage law p = (k_c/b + k_phi) z^n.

    Args:
        sinkage: Sinkage z (m), ≥ 0, scalar or array.
        width: Contact width b (m), the smaller plate dimension.
        params: Bekker parameters (unverified when taken from
            :data:`BEKKER_PARAMETERS_UNVERIFIED`).

    Returns:
        Pressure p (Pa), shape of ``sinkage``.
    """
    z = np.asarray(sinkage, dtype=float)
    return (params.k_c / width + params.k_phi) * z**params.n


def rigid_wheel_load(sinkage: ArrayLike, diameter: float, width: float, params: BekkerParameters) -> ArrayLike:
    """Load carried by a rigid wheel at a given sinkage (Bekker 1969).

    W(z) = ((3 − n)(k_c + b k_phi) √D / 3) · z^((2n+1)/2), the load-sinkage law of
    the derivation behind the static-sinkage formula (Wong 2008, ch. 2).

    Args:
        sinkage: z (m), ≥ 0.
        diameter: Wheel diameter D (m).
        width: Wheel width b (m).
        params: Bekker parameters (unverified when tabulated here).

    Returns:
        W (N), shape of ``sinkage``.
    """
    z = np.asarray(sinkage, dtype=float)
    n = params.n
    coeff = (3.0 - n) * (params.k_c + width * params.k_phi) * math.sqrt(diameter) / 3.0
    return coeff * z ** ((2.0 * n + 1.0) / 2.0)


def rigid_wheel_static_sinkage(load: float, diameter: float, width: float, params: BekkerParameters) -> float:
    """Static sinkage of a rigid wheel (Bekker): z0 = [3W/((3−n)(k_c + b k_phi)√D)]^(2/(2n+1)).

    Args:
        load: Vertical wheel load W (N).
        diameter: Wheel diameter D (m).
        width: Wheel width b (m).
        params: Bekker parameters (unverified when tabulated here).

    Returns:
        z0 (m).
    """
    n = params.n
    base = 3.0 * load / ((3.0 - n) * (params.k_c + width * params.k_phi) * math.sqrt(diameter))
    return base ** (2.0 / (2.0 * n + 1.0))


def rigid_wheel_equivalent_stiffness(load: float, diameter: float, width: float, params: BekkerParameters) -> float:
    """Linearised rigid-wheel soil stiffness k_s = dW/dz at z0 = ((2n+1)/2) W/z0.

    MODELS.md A.2: with the unverified tabulated Bekker parameters this does not
    reproduce the paper's Table 1 (e.g. ≈ 236 kN/m for Graneville loam against
    651.1 kN/m), which is why the tabulated k_s are the simulation truth.

    Args:
        load: Vertical wheel load W (N).
        diameter: Wheel diameter D (m).
        width: Wheel width b (m).
        params: Bekker parameters (unverified when tabulated here).

    Returns:
        k_s (N/m).
    """
    z0 = rigid_wheel_static_sinkage(load, diameter, width, params)
    return (2.0 * params.n + 1.0) / 2.0 * load / z0


def flat_contact_static_sinkage(ground_pressure: float, width: float, params: BekkerParameters) -> float:
    """Sinkage of a flexible tire in the elastic mode: z0 = (p_g/(k_c/b + k_phi))^(1/n).

    Args:
        ground_pressure: Average ground pressure p_g (Pa), roughly inflation
            plus carcass pressure.
        width: Contact width b (m).
        params: Bekker parameters (unverified when tabulated here).

    Returns:
        z0 (m).
    """
    return (ground_pressure / (params.k_c / width + params.k_phi)) ** (1.0 / params.n)


def flat_contact_equivalent_stiffness(
    load: float, ground_pressure: float, width: float, params: BekkerParameters
) -> float:
    """Linearised flat-contact soil stiffness k_s = n W / z0.

    Holds when the contact area A = W/p_g does not change with a small extra
    sinkage (MODELS.md A.2). With p_g ≈ 37–43 kPa it comes within ~10 % of four
    Table 1 entries; North Gower clayey loam would need p_g ≈ 129 kPa.

    Args:
        load: Vertical wheel load W (N).
        ground_pressure: Average ground pressure p_g (Pa).
        width: Contact width b (m).
        params: Bekker parameters (unverified when tabulated here).

    Returns:
        k_s (N/m).
    """
    z0 = flat_contact_static_sinkage(ground_pressure, width, params)
    return params.n * load / z0
