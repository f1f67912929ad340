"""State and measurement layouts of the rover's Estimators 1–3 ([RB] eqs. 43, 62, 75, 78).

Names in order (:data:`GENERAL_STATES`, :data:`GENERAL_MEASUREMENTS`,
:data:`WHEEL_FORCE_STATES`, :data:`WHEEL_FORCE_MEASUREMENTS`), the indices of
Estimator 1's state (:class:`GeneralIndex`) and of the planar coordinates g
(:data:`FREE_COORDINATES`, :data:`WHEEL_COORDINATES`); re-exported by
:mod:`terrain_estimation.models.rover_estimators`.
"""

from __future__ import annotations

from typing import Final

from terrain_estimation.models.rover import WHEELS

__all__ = [
    "FREE_COORDINATES",
    "GENERAL_MEASUREMENTS",
    "GENERAL_STATES",
    "WHEEL_COORDINATES",
    "WHEEL_FORCE_MEASUREMENTS",
    "WHEEL_FORCE_STATES",
    "GeneralIndex",
]

#: Indices into g (models.rover.COORDINATES) of the free coordinates x0, z0, θ, q1 and of the wheels q2..q4.
FREE_COORDINATES: Final[tuple[int, ...]] = (0, 1, 2, 3)
WHEEL_COORDINATES: Final[tuple[int, ...]] = (4, 5, 6)


def _per_wheel(prefix: str) -> tuple[str, str, str]:
    return (f"{prefix}_{WHEELS[0]}", f"{prefix}_{WHEELS[1]}", f"{prefix}_{WHEELS[2]}")


#: Estimator 1 state x1 (eq. 43), in order.
GENERAL_STATES: Final[tuple[str, ...]] = (
    *_per_wheel("wheel_rate"),  # q̇2, q̇3, q̇4 (rad/s), joint rates relative to the carrier
    *_per_wheel("resistive_torque"),  # τ_R1..3 (N·m)
    "pitch",  # θ0y (rad), positive nose down
    "bogie_angle",  # q1 (rad)
    "pitch_rate",  # θ̇0y (rad/s)
    "bogie_rate",  # q̇1 (rad/s)
    "pitch_acceleration",  # θ̈0y (rad/s²)
    "bogie_acceleration",  # q̈1 (rad/s²)
    "x_acceleration",  # ẍ0, world (m/s²)
    "z_acceleration",  # z̈0, world (m/s²)
    "body_moment",  # M_0fw: moment of the wheel linear forces about O (N·m)
    "bogie_moment",  # M_1fw: their moment about the bogie joint (N·m)
    "wheel_force_x",  # F_xfw: their world-horizontal sum (N)
    "wheel_force_z",  # F_zfw: their world-vertical sum (N)
    "forward_speed",  # ẋ0^R, along the body x axis (m/s)
    *_per_wheel("slip"),  # i1..3 (–)
)

#: Estimator 1 measurement y1 (eq. 62), in order.
GENERAL_MEASUREMENTS: Final[tuple[str, ...]] = (
    *_per_wheel("wheel_rate"),  # eq. 63, finite difference of encoder angles
    "pitch",  # eq. 64, from the gravity direction
    "bogie_angle",
    "specific_force_x",  # ẍ0^R of eq. 72 (accelerometer, gravity included)
    "specific_force_z",  # z̈0^R of eq. 73
    "forward_speed",  # velocimeter
    *_per_wheel("slip"),  # eq. 68
)

#: Estimators 2/3 state x2 = x3 (eq. 75), in order.
WHEEL_FORCE_STATES: Final[tuple[str, ...]] = (
    *_per_wheel("contact_angle"),  # γ (rad) w.r.t. the world horizontal, positive descending forward
    *_per_wheel("normal_load"),  # W (N)
    *_per_wheel("drawbar_pull"),  # DP (N)
)

#: Estimators 2/3 measurement y2 = y3 (eqs. 78, 85), in order.
WHEEL_FORCE_MEASUREMENTS: Final[tuple[str, ...]] = (
    *_per_wheel("contact_angle"),  # eq. 79
    *_per_wheel("axial_force"),  # F_L, load-cell sensing axis
    *_per_wheel("perpendicular_force"),  # F_⊥, measured (E2) or synthesised (E3, eqs. 86–88)
)


class GeneralIndex:
    """Indices into the Estimator 1 state x1 (:data:`GENERAL_STATES`)."""

    WHEEL_RATE: Final = slice(0, 3)
    RESISTIVE_TORQUE: Final = slice(3, 6)
    PITCH: Final = 6
    BOGIE: Final = 7
    PITCH_RATE: Final = 8
    BOGIE_RATE: Final = 9
    PITCH_ACC: Final = 10
    BOGIE_ACC: Final = 11
    X_ACC: Final = 12
    Z_ACC: Final = 13
    BODY_MOMENT: Final = 14
    BOGIE_MOMENT: Final = 15
    FORCE_X: Final = 16
    FORCE_Z: Final = 17
    FORWARD_SPEED: Final = 18
    SLIP: Final = slice(19, 22)
    #: Accelerations of the free coordinates (x0, z0, θ, q1), in g order.
    FREE_ACC: Final[tuple[int, ...]] = (12, 13, 10, 11)
    #: Net wheel-force effects on the free coordinates (x0, z0, θ, q1), in g order.
    FREE_FORCE: Final[tuple[int, ...]] = (16, 17, 14, 15)
