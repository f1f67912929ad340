"""What an effect of the sim-to-real catalogue is (:class:`EffectParameter`, :class:`Effect`) and how a table is built.

The catalogue itself (every vehicle's effects) and the building of a plant's
effects object: :mod:`vehicle_sim.effects`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

__all__ = [
    "SWITCH_UNIT",
    "Effect",
    "EffectParameter",
    "Row",
    "axes",
    "components",
    "named",
    "parameter_count",
    "scalar",
    "switch",
    "table",
]

SWITCH_UNIT = "bool"


@dataclass(frozen=True, kw_only=True)
class EffectParameter:
    """One scalar parameter of an effect.

    Attributes:
        name: parameter name: the plant's effects field, or ``<field>_<component>``
            for a component of a tuple-valued field.
        unit: physical unit (SI; "–" dimensionless, "bool" a switch).
        off: value with which the parameter has no effect (the plant default).
        fit_range: (low, high) physical range for fitting, finite, contains ``off``.
        typical: typical magnitude of a real effect (a starting point / scale
            for a fit; inside ``fit_range``).
        description: what it is.
        field: the plant's effects field it sets ("" for the rover soil-change
            parameters, which build ``soil_change_soil``).
        index: component of a tuple-valued field, None for a scalar field.
        physical_range: (low, high) the values a real vehicle plausibly shows,
            inside ``fit_range`` (None: the fit range itself). A fit that ends
            outside it is not a physical explanation (:attr:`plausible_range`).
    """

    name: str
    unit: str
    off: float
    fit_range: tuple[float, float]
    typical: float
    description: str
    field: str = ""
    index: int | None = None
    physical_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        low, high = (float(v) for v in self.fit_range)
        object.__setattr__(self, "fit_range", (low, high))
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise ValueError(f"EffectParameter {self.name!r}: fit_range must be finite with low < high, got {self}")
        if self.physical_range is not None:
            p_low, p_high = (float(v) for v in self.physical_range)
            object.__setattr__(self, "physical_range", (p_low, p_high))
            if not (low <= p_low < p_high <= high and p_low <= self.off <= p_high):
                raise ValueError(
                    f"EffectParameter {self.name!r}: physical_range must lie in fit_range and contain off, got {self}"
                )
        if not (low <= self.off <= high and low <= self.typical <= high):
            raise ValueError(f"EffectParameter {self.name!r}: off and typical must lie in fit_range, got {self}")
        if not self.unit:
            raise ValueError(f"EffectParameter {self.name!r}: unit must be given")

    @property
    def switch(self) -> bool:
        """True for a boolean (on/off) parameter, which is not fitted."""
        return self.unit == SWITCH_UNIT

    @property
    def plausible_range(self) -> tuple[float, float]:
        """The physically plausible range (``physical_range``, or the fit range when none is stated)."""
        return self.physical_range if self.physical_range is not None else self.fit_range


@dataclass(frozen=True, kw_only=True)
class Effect:
    """One effect of the catalogue for one vehicle.

    Attributes:
        vehicle: key of :data:`CATALOGUE`.
        name: effect name (issue 6's catalogue names and additions).
        description: what the effect is in the plant.
        physical_meaning: which real-world mechanism it stands for.
        parameters: its parameters.
    """

    vehicle: str
    name: str
    description: str
    physical_meaning: str
    parameters: tuple[EffectParameter, ...]

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the parameters, in order."""
        return tuple(p.name for p in self.parameters)

    def parameter(self, name: str) -> EffectParameter:
        """The parameter called ``name`` (KeyError if none)."""
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(f"{self.vehicle} effect {self.name!r} has no parameter {name!r}; has {self.parameter_names}")

    def off_values(self) -> dict[str, float]:
        """{parameter: off value}."""
        return {p.name: p.off for p in self.parameters}

    def typical_values(self) -> dict[str, float]:
        """{parameter: typical value} (switches on)."""
        return {p.name: p.typical for p in self.parameters}


def parameter_count(effect: Effect) -> int:
    """Continuous parameters a fit of ``effect`` estimates (switches are not counted)."""
    return sum(1 for p in effect.parameters if not p.switch)


# ---------------------------------------------------------------------------
# Parameter helpers
# ---------------------------------------------------------------------------


def scalar(
    name: str,
    unit: str,
    off: float,
    fit_range: tuple[float, float],
    typical: float,
    description: str,
    physical_range: tuple[float, float] | None = None,
    *,
    field: str | None = None,
    index: int | None = None,
) -> EffectParameter:
    """A parameter that sets the plant field ``field`` (default: its own name), component ``index`` of a tuple."""
    return EffectParameter(
        name=name,
        unit=unit,
        off=off,
        fit_range=fit_range,
        typical=typical,
        description=description,
        field=name if field is None else field,
        index=index,
        physical_range=physical_range,
    )


def components(
    field: str,
    components: tuple[str, ...],
    unit: str,
    fit_range: tuple[float, float],
    typical: float,
    description: str,
) -> tuple[EffectParameter, ...]:
    return tuple(
        EffectParameter(
            name=f"{field}_{component}",
            unit=unit,
            off=0.0,
            fit_range=fit_range,
            typical=typical,
            description=f"{description} ({component})",
            field=field,
            index=index,
        )
        for index, component in enumerate(components)
    )


def switch(name: str, description: str) -> EffectParameter:
    return EffectParameter(
        name=name, unit=SWITCH_UNIT, off=0.0, fit_range=(0.0, 1.0), typical=1.0, description=description, field=name
    )


#: (name, description, physical meaning, parameters) of one effect.
Row = tuple[str, str, str, tuple[EffectParameter, ...]]


def table(vehicle: str, effects: tuple[Row, ...]) -> Mapping[str, Effect]:
    table: dict[str, Effect] = {}
    for name, description, meaning, parameters in effects:
        if name in table:
            raise ValueError(f"duplicate effect {name!r} for {vehicle}")
        table[name] = Effect(
            vehicle=vehicle, name=name, description=description, physical_meaning=meaning, parameters=parameters
        )
    return MappingProxyType(table)


def named(
    name: str,
    field: str,
    index: int | None,
    unit: str,
    fit_range: tuple[float, float],
    typical: float,
    description: str,
    physical_range: tuple[float, float] | None = None,
) -> EffectParameter:
    """A skid-steer parameter (off 0) with its field, component and plausible range given explicitly."""
    return scalar(name, unit, 0.0, fit_range, typical, description, physical_range, field=field, index=index)


def axes(
    field: str,
    unit: str,
    fit_range: tuple[float, float],
    typical: float,
    description: str,
    physical: tuple[float, float],
) -> tuple[EffectParameter, ...]:
    """One parameter per body axis x, y, z of a tuple field (``<field>_<axis>``), with a plausible range."""
    return tuple(
        named(f"{field}_{axis}", field, i, unit, fit_range, typical, f"{description} ({axis})", physical)
        for i, axis in enumerate("xyz")
    )
