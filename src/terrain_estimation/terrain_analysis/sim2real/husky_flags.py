"""Flags of the Husky fits: fitted values at a fit bound or outside their physical range."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from terrain_analysis.sim2real.husky_fit import PhysicsFit
from terrain_analysis.sim2real.model import FitParameter
from terrain_analysis.sim2real.skid_steer_replay import SkidSteerReplay
from terrain_analysis.sim2real.skid_steer_vehicle import ReplayVehicle

__all__ = [
    "BOUND_TOLERANCE",
    "DEFAULT_FRICTION",
    "STIFFNESS_PER_LOAD",
    "TERRAIN_FRICTION",
    "flag_engine",
    "flag_fit",
    "flag_value",
    "physical_ranges",
]

#: Physically plausible peak tire–ground friction μ of a lugged rubber tire per BorealTC terrain (low, high):
#: dry asphalt and concrete 0.8–0.9 peak, wet 0.5–0.7; gravel 0.6; earth road 0.5–0.7 dry; packed snow 0.2,
#: ice 0.1 (Wong, *Theory of Ground Vehicles*, 4th ed., Table 1.3), widened for lugs and the robot's small
#: tires; loose soils and sand 0.3–0.8 (traction coefficients of Wong ch. 2–4). Unknown terrains:
#: :data:`DEFAULT_FRICTION`.
TERRAIN_FRICTION: Mapping[str, tuple[float, float]] = {
    "ASPHALT": (0.5, 1.1),
    "FLOORING": (0.4, 1.1),
    "CROSSGRID": (0.3, 1.1),
    "SANDY_LOAM": (0.3, 0.9),
    "SILTY_LOAM": (0.3, 0.9),
    "QUARTZ_SAND": (0.3, 0.8),
    "SNOW": (0.1, 0.5),
    "ICE": (0.05, 0.3),
}
DEFAULT_FRICTION = (0.05, 1.1)
#: Slip stiffness per unit static wheel load, C_x / F_z (–) and C_α / F_z (1/rad): 1–30. Pneumatic tires on a
#: rigid surface 10–25 (Pacejka, *Tire and Vehicle Dynamics*, ch. 1; small tires 5–10 /rad); deformable ground
#: adds the soil's shear compliance in series and lowers it, but a slip stiffness under 1 (the full load only at
#: 100 % slip) is a soil that does not carry a tire.
STIFFNESS_PER_LOAD = (1.0, 30.0)
#: A fitted value within this fraction of its fit range's span from a bound is "at the bound".
BOUND_TOLERANCE = 0.01


def physical_ranges(vehicle: ReplayVehicle, terrain: str) -> dict[str, tuple[str, float, float, float, str]]:
    """Nuisance name → (physical quantity, factor scale → quantity, low, high, unit) on ``terrain``."""
    load = vehicle.mass * vehicle.gravity / (2 * vehicle.n_axles)
    mu_lo, mu_hi = TERRAIN_FRICTION.get(terrain, DEFAULT_FRICTION)
    lo, hi = STIFFNESS_PER_LOAD
    return {
        "friction_scale": ("μ", vehicle.friction, mu_lo, mu_hi, "–"),
        "longitudinal_stiffness_scale": ("C_x/F_z", vehicle.longitudinal_stiffness / load, lo, hi, "–"),
        "cornering_stiffness_scale": ("C_α/F_z", vehicle.cornering_stiffness / load, lo, hi, "1/rad"),
    }


def _flag(subject: str, parameter: str, quantity: str, value: float, unit: str, reason: str) -> dict[str, Any]:
    """One row of the flag table."""
    return {
        "subject": subject,
        "parameter": parameter,
        "quantity": quantity,
        "value": value,
        "unit": unit,
        "reason": reason,
    }


def flag_value(
    subject: str,
    name: str,
    value: float,
    bounds: tuple[float, float],
    *,
    off: float | None = None,
    physical: tuple[str, float, float, float, str] | None = None,
    bounds_are_laws: bool = False,
) -> list[dict[str, Any]]:
    """Flags of one fitted value: at a bound of its fit range (not at its off value), outside its physical range.

    ``physical`` = (quantity, factor, low, high, unit): the value × factor must lie in [low, high].
    ``bounds_are_laws``: both ends of the fit range are valid laws (:attr:`FitParameter.physical_bounds`, a
    shape parameter): a value there is no finding.
    """
    flags: list[dict[str, Any]] = []
    lo, hi = bounds
    quantity, factor, unit = name, 1.0, ""
    if physical is not None:
        quantity, factor, _, _, unit = physical
    shown = value * factor
    for bound in () if bounds_are_laws else (lo, hi):
        # 1 % of the span, and no more than 2 % of the bound itself (a scale range 0.05–10 spans 200×).
        tol = BOUND_TOLERANCE * (hi - lo)
        if bound != 0.0:
            tol = min(tol, 2.0 * BOUND_TOLERANCE * abs(bound))
        if abs(value - bound) <= tol and (off is None or abs(bound - off) > tol):
            reason = f"at the fit bound {bound * factor:.3g} of [{lo * factor:.3g}, {hi * factor:.3g}]"
            flags.append(_flag(subject, name, quantity, shown, unit, reason))
    if physical is not None:
        _, _, plo, phi, _ = physical
        if not plo <= shown <= phi:
            flags.append(
                _flag(subject, name, quantity, shown, unit, f"outside the physical range [{plo:.3g}, {phi:.3g}]")
            )
    return flags


def _effect_physical(effect: str, parameter: str) -> tuple[str, float, float, float, str] | None:
    """(quantity, 1, low, high, unit) of a catalogue parameter's plausible range (``vehicle_sim.effects``)."""
    from vehicle_sim.effects import CATALOGUE

    try:
        p = CATALOGUE["skid_steer"][effect].parameter(parameter)
    except KeyError:
        return None
    low, high = getattr(p, "plausible_range", p.fit_range)
    return (parameter, 1.0, float(low), float(high), p.unit)


def _flag_effect(subject: str, effect: str, parameter: FitParameter, value: float) -> list[dict[str, Any]]:
    """Flags of one fitted effect parameter (its fit range, its off value, the catalogue's plausible range)."""
    return flag_value(
        subject,
        f"{effect}.{parameter.name}",
        value,
        parameter.bounds,
        off=parameter.off,
        physical=_effect_physical(effect, parameter.name),
        bounds_are_laws=parameter.physical_bounds,
    )


def flag_fit(subject: str, fit: PhysicsFit, model: SkidSteerReplay, terrain: str) -> list[dict[str, Any]]:
    """Flags of every parameter of a :class:`PhysicsFit` (nuisance and effect)."""
    ranges = physical_ranges(model.replay_vehicle, terrain)
    flags: list[dict[str, Any]] = []
    for p in model.nuisance:
        flags += flag_value(subject, p.name, fit.values[p.name], p.bounds, physical=ranges.get(p.name))
    for name, sd in fit.std_corrected.items():
        value = fit.values.get(name, fit.effects.get(next(iter(fit.effects), ""), {}).get(name, math.nan))
        if not (math.isfinite(sd) and sd < abs(value)):
            reason = f"not identified by the training runs (corrected σ {sd:.3g} ≥ |value|)"
            flags.append(_flag(subject, name, name, value, "", reason))
    for effect, values in fit.effects.items():
        for p in model.candidates[effect].parameters:
            if p.name in values:  # a parameter the physics fit left at its nominal value is not a finding
                flags += _flag_effect(subject, effect, p, values[p.name])
    return flags


def flag_engine(
    subject: str, model: SkidSteerReplay, terrain: str, fitted: Any, top: Sequence[Any]
) -> list[dict[str, Any]]:
    """Flags of the engine's fitted parameters: the verdict's model and the top of its ranking."""
    ranges = physical_ranges(model.replay_vehicle, terrain)
    bounds = {p.name: p.bounds for p in model.nuisance}
    flags: list[dict[str, Any]] = []
    seen: set[tuple[str, str]] = set()
    for m in [fitted, *top]:
        if m is None:
            continue
        label = f"{subject}: {' + '.join(m.effects) if m.effects else 'nominal'}"
        for name, value in m.nuisance.items():
            if ("nuisance", name) in seen or name not in bounds:
                continue
            seen.add(("nuisance", name))
            flags += flag_value(label, name, float(value), bounds[name], physical=ranges.get(name))
        for effect, values in m.parameters.items():
            for p in model.candidates[effect].parameters:
                if p.name in values and (effect, p.name) not in seen:
                    seen.add((effect, p.name))
                    flags += _flag_effect(label, effect, p, float(values[p.name]))
    return flags
