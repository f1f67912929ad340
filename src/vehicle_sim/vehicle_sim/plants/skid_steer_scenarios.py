"""Scenarios of the fair skid-steer reproduction (issue 20, item 6) on the independent truth plant.

Every scenario runs the truth plant with its own magic-formula tire
(:meth:`SkidSteerVehicle.truth_default`, :mod:`vehicle_sim.plants.tire_laws`)
and the truth effects of the estimator tests (roll/pitch load-transfer
dynamics, tire relaxation: :meth:`SkidSteerEffects.truth_default`), so the
brush-tire observer never meets its own model. The paper's three manoeuvres
(:data:`~vehicle_sim.plants.skid_steer.MANOEUVRES`, MODELS.md B.11) give the
motion:

=============================  ===================================================================
name                           scenario
=============================  ===================================================================
``nominal``                    the paper's small-radius turn (5 km/h, 0.2 rad/s, R ≈ 7 m, 45 s);
                               already a tire-law mismatch for the brush observer
``cornering_stiffness_plus_30``  the turn, true C_α = 1.3 × nominal (effect
                               ``cornering_stiffness_change``)
``cornering_stiffness_minus_30`` the turn, true C_α = 0.7 × nominal
``friction_patch``             the turn; μ halves on the far half of the turning circle
                               (half-plane y ≥ 7 m): each wheel enters it a quarter turn in
                               (≈ 15 s) and leaves it half a turn later (≈ 31 s), within
                               ``transition`` = 0.3 m
``bank_5deg``                  the turn on a plane inclined 5° across the start heading: a 5° bank
                               (left side up) on the run-in, then grade and bank trading places
                               with the heading
``sharp_turn``                 the turn at 3 m/s and 0.6 rad/s (R = 5 m, lateral acceleration
                               1.8 m/s²)
``s_shape``                    the paper's S-shape at 30 km/h (30 s)
``straight_acceleration``      the paper's 0 → 30 km/h run (20 s)
=============================  ===================================================================

:data:`MISMATCH_SCENARIOS` names the mismatch set of the issue's criteria
(tire law, ±30 % C_α, μ patch, bank, sharp turn). The sensors are the
defaults (noisy, as the paper's experiment); seeds are the caller's.
"""

from __future__ import annotations

import math
from dataclasses import replace

from vehicle_sim.plants.skid_steer_ground import SkidSteerGround, Surface, TerrainPatch
from vehicle_sim.plants.skid_steer_manoeuvres import (
    SkidSteerScenario,
    s_shape,
    small_radius_turn,
    straight_acceleration,
)
from vehicle_sim.plants.skid_steer_vehicle import SkidSteerEffects, SkidSteerSensors, SkidSteerVehicle

__all__ = [
    "BANK_ANGLE",
    "FRICTION_PATCH_FACTOR",
    "MISMATCH_SCENARIOS",
    "REPRODUCTION_SCENARIO_NAMES",
    "friction_patch_ground",
    "reproduction_scenarios",
]

BANK_ANGLE = math.radians(5.0)
"""Cross slope of ``bank_5deg`` (rad)."""

FRICTION_PATCH_FACTOR = 0.5
"""μ on the patch of ``friction_patch`` relative to the vehicle's surface."""

#: Edge of the low-friction half-plane of ``friction_patch`` (m): the turning circle's centre line (R ≈ 7 m).
_PATCH_EDGE_Y = 7.0

REPRODUCTION_SCENARIO_NAMES: tuple[str, ...] = (
    "nominal",
    "cornering_stiffness_plus_30",
    "cornering_stiffness_minus_30",
    "friction_patch",
    "bank_5deg",
    "sharp_turn",
    "s_shape",
    "straight_acceleration",
)
"""Names of :func:`reproduction_scenarios`, in order."""

MISMATCH_SCENARIOS: tuple[str, ...] = tuple(
    name for name in REPRODUCTION_SCENARIO_NAMES if name not in ("s_shape", "straight_acceleration")
)
"""The issue's mismatch set: tire law (the nominal turn), ±30 % C_α, μ patch, bank, sharp turn."""


def friction_patch_ground(vehicle: SkidSteerVehicle, factor: float = FRICTION_PATCH_FACTOR) -> SkidSteerGround:
    """Level ground whose half-plane y ≥ 7 m has ``factor`` × the vehicle's μ (same stiffness and f_rr).

    Args:
        vehicle: whose surface (μ of ``nominal``, f_rr) the patch changes.
        factor: μ ratio on the patch (> 0).
    """
    if not (math.isfinite(factor) and factor > 0.0):
        raise ValueError(f"friction_patch_ground: factor must be finite and > 0, got {factor}")
    surface = Surface(
        name=f"friction x{factor:g}",
        friction=vehicle.nominal.friction * factor,
        stiffness_scale=1.0,
        rolling_resistance=vehicle.rolling_resistance,
    )
    return SkidSteerGround(patches=(TerrainPatch(surface=surface, y_min=_PATCH_EDGE_Y),))


def reproduction_scenarios(
    *,
    vehicle: SkidSteerVehicle | None = None,
    sensors: SkidSteerSensors | None = None,
) -> dict[str, SkidSteerScenario]:
    """The named scenarios of the fair reproduction (module docstring), in :data:`REPRODUCTION_SCENARIO_NAMES` order.

    Args:
        vehicle: the plant's vehicle; default :meth:`SkidSteerVehicle.truth_default`
            (magic-formula tire). A brush-tire vehicle gives the paper's
            idealised versions.
        sensors: sensor models; default :class:`SkidSteerSensors` (noisy).

    Returns:
        name → scenario, every one with :meth:`SkidSteerEffects.truth_default`
        (plus the scenario's own change).
    """
    vehicle = SkidSteerVehicle.truth_default() if vehicle is None else vehicle
    sensors = SkidSteerSensors() if sensors is None else sensors
    truth = SkidSteerEffects.truth_default()
    turn = small_radius_turn(vehicle=vehicle, effects=truth, sensors=sensors)
    scenarios = {
        "nominal": turn,
        "cornering_stiffness_plus_30": small_radius_turn(
            vehicle=vehicle, effects=replace(truth, cornering_stiffness_change=1.3), sensors=sensors
        ),
        "cornering_stiffness_minus_30": small_radius_turn(
            vehicle=vehicle, effects=replace(truth, cornering_stiffness_change=0.7), sensors=sensors
        ),
        "friction_patch": replace(turn, ground=friction_patch_ground(vehicle)),
        "bank_5deg": replace(turn, ground=SkidSteerGround(cross_slope=BANK_ANGLE)),
        "sharp_turn": small_radius_turn(vehicle=vehicle, effects=truth, sensors=sensors, speed=3.0, yaw_rate=0.6),
        "s_shape": s_shape(vehicle=vehicle, effects=truth, sensors=sensors),
        "straight_acceleration": straight_acceleration(vehicle=vehicle, effects=truth, sensors=sensors),
    }
    assert tuple(scenarios) == REPRODUCTION_SCENARIO_NAMES
    return scenarios
