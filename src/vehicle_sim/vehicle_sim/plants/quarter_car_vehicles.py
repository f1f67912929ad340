"""The vehicles of the soil-stiffness plant: the 2-DOF quarter car (Table 2) and the 1-DOF LRV corner (Table 5).

Equations of motion and contact: :mod:`vehicle_sim.plants.quarter_car`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from terrain_estimation.checks import check_fields
from vehicle_sim.terrain.soils import k_tot

__all__ = ["STANDARD_GRAVITY", "LRVVehicle", "QuarterCarVehicle", "Vehicle"]

STANDARD_GRAVITY = 9.80665
"""Standard gravity (m/s²)."""


# ---------------------------------------------------------------------------
# Vehicles
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class QuarterCarVehicle:
    """2-DOF quarter car of the paper's Table 2 (reference off-road vehicle).

    Attributes:
        sprung_mass: m_s (kg).
        unsprung_mass: m_ns (kg).
        suspension_stiffness: k (N/m).
        suspension_damping: c (N·s/m).
        tire_stiffness: k_t (N/m); the soil is in series with it.
        wheel_radius: Rolling radius (m) converting speed to wheel rate;
            default D/2 of Table 1's wheel (D = 0.777 m).
    """

    sprung_mass: float = 455.0
    unsprung_mass: float = 45.5
    suspension_stiffness: float = 25.0e3
    suspension_damping: float = 2.0e3
    tire_stiffness: float = 175.0e3
    wheel_radius: float = 0.3885

    def __post_init__(self) -> None:
        check_fields(self, ("sprung_mass", "unsprung_mass", "suspension_stiffness", "tire_stiffness"))
        check_fields(self, ("suspension_damping",), rule="non_negative")
        check_fields(self, ("wheel_radius",))

    @property
    def series_stiffness(self) -> float:
        """Stiffness in series with the soil (N/m): the tire stiffness k_t."""
        return self.tire_stiffness

    @property
    def total_mass(self) -> float:
        """m_s + m_ns (kg), carried by the ground at rest."""
        return self.sprung_mass + self.unsprung_mass

    @property
    def has_wheel_accelerometer(self) -> bool:
        """True: the 2-DOF car carries an accelerometer on the unsprung mass."""
        return True

    def k_tot(self, k_s: float) -> float:
        """Soil in series with the tire (eq. 3), N/m."""
        return float(k_tot(k_s, self.tire_stiffness))

    def undamped_natural_frequencies(self, k_s: float) -> tuple[float, float]:
        """Closed-form undamped natural frequencies (Hz), (body, wheel hop).

        Roots of m_s m_ns ω⁴ − (m_s (k + k_tot) + m_ns k) ω² + k k_tot = 0. The
        "body ≈ 1.18 Hz" of MODELS.md A.1 is the uncoupled √(k/m_s)/2π; the
        coupled body mode is 1.05–1.10 Hz on Table 1's soils.

        Args:
            k_s: Soil stiffness (N/m).

        Returns:
            (f_body, f_wheel) in Hz, f_body < f_wheel.
        """
        m1, m2, k = self.sprung_mass, self.unsprung_mass, self.suspension_stiffness
        kt = self.k_tot(k_s)
        a = m1 * m2
        b = m1 * (k + kt) + m2 * k
        disc = math.sqrt(b * b - 4.0 * a * k * kt)
        w_low = math.sqrt((b - disc) / (2.0 * a))
        w_high = math.sqrt((b + disc) / (2.0 * a))
        return w_low / (2.0 * math.pi), w_high / (2.0 * math.pi)

    def state_matrix(self, k_s: float) -> NDArray[np.float64]:
        """Continuous-time state matrix for x = [y1, ẏ1, y2, ẏ2] on a level road (4×4)."""
        m1, m2 = self.sprung_mass, self.unsprung_mass
        k, c, kt = self.suspension_stiffness, self.suspension_damping, self.k_tot(k_s)
        return np.array(
            [
                [0.0, 1.0, 0.0, 0.0],
                [-k / m1, -c / m1, k / m1, c / m1],
                [0.0, 0.0, 0.0, 1.0],
                [k / m2, c / m2, -(k + kt) / m2, -c / m2],
            ]
        )


@dataclass(frozen=True)
class LRVVehicle:
    """1-DOF Lunar Roving Vehicle corner of the paper's Table 5.

    Suspension and tire stiffness are combined in k and sprung and unsprung
    masses lumped in m (section 5.3).

    Attributes:
        sprung_mass: Lumped mass m (kg); 75 kg gives the paper's Earth load
            W = 735 N.
        combined_stiffness: k (N/m), suspension and tire in series; the soil is
            in series with it.
        damping: c (N·s/m).
        wheel_radius: Rolling radius (m); LRV wheel D = 1.016 m.
        damper_reference: ``"ground"`` (physical, default): damper force
            c(ḣ − ẏ1) between body and ground; ``"inertial"``: −c ẏ1, the
            paper's literal reduction of the 2-DOF matrices (MODELS.md A.7).
    """

    sprung_mass: float = 75.0
    combined_stiffness: float = 15.0e3
    damping: float = 1.5e3
    wheel_radius: float = 0.508
    damper_reference: Literal["ground", "inertial"] = "ground"

    def __post_init__(self) -> None:
        check_fields(self, ("sprung_mass", "combined_stiffness", "wheel_radius"))
        check_fields(self, ("damping",), rule="non_negative")
        if self.damper_reference not in ("ground", "inertial"):
            raise ValueError(f"damper_reference must be 'ground' or 'inertial', got {self.damper_reference!r}")

    @property
    def series_stiffness(self) -> float:
        """Stiffness in series with the soil (N/m): the combined stiffness k."""
        return self.combined_stiffness

    @property
    def total_mass(self) -> float:
        """m (kg), carried by the ground at rest."""
        return self.sprung_mass

    @property
    def has_wheel_accelerometer(self) -> bool:
        """False: the LRV model has no unsprung mass, hence no wheel accelerometer."""
        return False

    def k_tot(self, k_s: float) -> float:
        """Soil in series with the combined stiffness, N/m (9.826 kN/m on regolith)."""
        return float(k_tot(k_s, self.combined_stiffness))

    def undamped_natural_frequency(self, k_s: float) -> float:
        """√(k_tot/m)/2π (Hz): ≈ 1.82 Hz on regolith."""
        return math.sqrt(self.k_tot(k_s) / self.sprung_mass) / (2.0 * math.pi)


Vehicle = QuarterCarVehicle | LRVVehicle
