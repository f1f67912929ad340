"""Nominal tolerances of the sim-to-real diagnosis (issue 22, item 2).

A vehicle's nominal parameters are never known exactly: a mass is weighed to
a few per cent, a rolling resistance is a handbook value, a tire stiffness a
datasheet's. A bag whose vehicle differs from the config by less than that is
not a sim-to-real gap. The vehicle config therefore states a *tolerance* for
each uncertain nominal parameter (section ``"/**/sim2real"`` of
``config/<vehicle>.yaml``, rendered by
:mod:`terrain_analysis.tools.config_template` from :data:`SPECS`), and the
diagnosis fits every such parameter as a *nuisance* in every model, the
nominal one included, with a Gaussian prior of that standard deviation about
the config value (:attr:`~terrain_analysis.sim2real.model.FitParameter.prior_std`)
and bounds at 3× the tolerance. Within the tolerance a mismatch costs almost
nothing and is absorbed; a catalogue effect is credited only with what lies
beyond it; a parameter the bag drives to 3× its tolerance is named as a
structure gap (:func:`terrain_analysis.sim2real.attribution._structure_reasons`).

Two kinds of targets (:data:`TARGETS`):

* a nuisance parameter the vehicle's replay model can fit (e.g. the skid
  steer's ``rolling_resistance``, :data:`terrain_analysis.sim2real.skid_steer.NUISANCE`):
  the diagnosis asks the replay for it and sets its prior;
* a catalogue effect's parameter that *is* a nominal parameter's error (e.g.
  ``sprung_mass_change``, the relative error of the sprung mass): a copy of
  it becomes a nuisance (:class:`ToleratedModel`), which the effect's own fit
  overrides when that effect is the candidate.

A third kind, for a nominal parameter whose error *is* a catalogue effect
that costs a re-run of the replay to fit (the skid steer's effective wheel
radius, its cornering stiffness): fitting it as a nuisance in every model
would make every fit dearer, so instead

* ("within", "effect.parameter"): an explanation by that effect whose fitted
  value lies within :data:`WITHIN` × the tolerance of its off value is a
  mismatch inside the nominal tolerance, reported as "no significant gap
  (within nominal tolerance …)", not as "explained by" the effect
  (:func:`within_tolerance`). Beyond it, the effect is a gap as before.

A tolerance is one standard deviation: a real vehicle's parameter lies
within 2 σ of the config value in 95 % of cases, hence :data:`WITHIN` = 2.

A tolerance of 0 means "known exactly": not fitted.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import Candidate, Channel, FitParameter, ReplayModel
from terrain_estimation.params import ParamSpec, default_config_path, load_parameter_file, resolve_parameters

__all__ = [
    "LOCATION_PARAMETERS",
    "SECTION",
    "SPECS",
    "TARGETS",
    "WITHIN",
    "ToleratedModel",
    "nuisance_names",
    "tolerances",
    "with_tolerances",
    "within_tolerance",
]

FloatArray = NDArray[np.float64]

WITHIN = 2.0
"""An effect fitted within this many tolerances (1 σ) of its off value is within nominal tolerance."""

SECTION = "sim2real"
"""Node name of the config section (``"/**/sim2real"``) that holds the tolerances."""

#: Where each tolerance applies: ("nuisance", replay nuisance name), ("effect", "effect.parameter") or
#: ("within", "effect.parameter") (module docstring).
TARGETS: Mapping[str, tuple[str, str]] = {
    "tolerance.sprung_mass": ("effect", "sprung_mass_change.sprung_mass_change"),
    "tolerance.rolling_resistance": ("nuisance", "rolling_resistance"),
    "tolerance.longitudinal_stiffness": ("nuisance", "longitudinal_stiffness_scale"),
    "tolerance.wheel_radius": ("within", "wheel_radius_error.wheel_radius_error"),
    "tolerance.cornering_stiffness": ("within", "cornering_stiffness_change.cornering_stiffness_change"),
    "tolerance.friction": ("nuisance", "friction_scale"),
    "tolerance.yaw_inertia": ("nuisance", "yaw_inertia_scale"),
    "tolerance.sinkage": ("nuisance", "sinkage_scale"),
    "tolerance.soil_cohesion": ("within", "soil_change.soil_change_cohesion_scale"),
    "tolerance.soil_friction_angle": ("within", "soil_change.soil_change_friction_angle_change"),
    "tolerance.soil_modulus": ("within", "soil_change.soil_change_modulus_scale"),
    "tolerance.soil_shear_modulus": ("within", "soil_change.soil_change_shear_modulus_scale"),
}

#: Parameters that say *where* an effect acts, not how large it is: free in the within-tolerance test of the
#: effect's magnitudes (:func:`within_tolerance`). A soil that changes beyond some distance by less than the
#: soil's tolerances is a soil within its tolerance wherever the change sits (at 0: the config's soil itself).
LOCATION_PARAMETERS: frozenset[str] = frozenset({"soil_change.soil_change_distance"})

_MASS = ParamSpec(
    "tolerance.sprung_mass",
    0.03,
    "[-] relative tolerance (1 sigma) of the sprung mass vehicle.sprung_mass: a mismatch within it is fitted as a "
    "nuisance (sprung_mass_change with a Gaussian prior), not reported as a sim-to-real gap; a weighed vehicle "
    "is known to a few per cent; 0: known exactly",
    0.0,
    0.5,
)

#: Tolerance specs per vehicle (rendered into the config's "/**/sim2real" section).
SPECS: Mapping[str, tuple[ParamSpec, ...]] = {
    "quarter_car": (_MASS,),
    "lrv": (_MASS,),
    "skid_steer": (
        ParamSpec(
            "tolerance.rolling_resistance",
            0.02,
            "[-] absolute tolerance (1 sigma) of the motion-resistance coefficient f_rr (simulator "
            "rolling_resistance; a handbook value the vehicle's reference does not state): a mismatch within it is "
            "fitted as a nuisance, not a gap; 0: known exactly",
            0.0,
            0.1,
        ),
        ParamSpec(
            "tolerance.longitudinal_stiffness",
            0.2,
            "[-] relative tolerance (1 sigma) of the longitudinal slip stiffness C_x (vehicle.longitudinal_stiffness; "
            "tire data vary by tens of per cent with pressure and wear); 0: known exactly",
            0.0,
            1.0,
        ),
        ParamSpec(
            "tolerance.wheel_radius",
            0.015,
            "[-] relative tolerance (1 sigma) of the effective rolling radius R (vehicle.wheel_radius): on "
            "deformable ground a tire's effective radius differs from its unloaded one by 2-3 % (deflection "
            "under load, sinkage, tread), so +-3 % is 2 sigma; a wheel_radius_error fitted within 2 sigma reads "
            "'no significant gap (within nominal tolerance)'; 0: known exactly",
            0.0,
            0.2,
        ),
        ParamSpec(
            "tolerance.cornering_stiffness",
            0.15,
            "[-] relative tolerance (1 sigma) of the cornering stiffness C_a (vehicle.cornering_stiffness): "
            "a datasheet C_a holds on one surface at one load and pressure, on real ground it is uncertain by "
            "about +-30 % (2 sigma); a cornering_stiffness_change factor fitted within 1 +- 2 sigma reads "
            "'no significant gap (within nominal tolerance)'; 0: known exactly, any mismatch is the catalogue's "
            "cornering_stiffness_change",
            0.0,
            1.0,
        ),
        ParamSpec(
            "tolerance.friction",
            0.0,
            "[-] relative tolerance (1 sigma) of the friction coefficient mu (vehicle.friction); 0 (default): "
            "known exactly, a mismatch is the catalogue's friction_change",
            0.0,
            1.0,
        ),
        ParamSpec(
            "tolerance.yaw_inertia",
            0.0,
            "[-] relative tolerance (1 sigma) of the yaw inertia I_z (vehicle.yaw_inertia); 0 (default): known exactly",
            0.0,
            1.0,
        ),
    ),
    "rover": (
        ParamSpec(
            "tolerance.sinkage",
            0.2,
            "[-] relative tolerance (1 sigma) of the wheels' steady sinkage z* (the factor sinkage_scale on the "
            "sinkage of the simulator's soil.*): the k_c, k_phi and n of a real soil are known to tens of per cent "
            "(z* goes as (k_c/b + k_phi)^(-2/(2n+1))); a mismatch within it is fitted as a nuisance, not a gap; "
            "0: known exactly",
            0.0,
            1.0,
        ),
        # The soil's own parameters (the scenario soil the replay runs on): a handbook entry for the soil type, and
        # a natural soil varies along a traverse. Inherent variability of strength parameters, as coefficients of
        # variation (Phoon & Kulhawy 1999, Can. Geotech. J. 36; Cherubini 1997): friction angle of sands 5-15 %,
        # cohesion / undrained strength 10-55 %; the moduli follow the sinkage tolerance. A soil_change whose
        # after-soil is within 2 of these of the soil before it reads "no significant gap (within nominal
        # tolerance)", not "explained by soil_change": wherever it sits (at 0 it is the config's soil itself).
        ParamSpec(
            "tolerance.soil_cohesion",
            0.5,
            "[-] relative tolerance (1 sigma) of the soil's cohesion c (soil.cohesion; the soil_change effect's "
            "cohesion scale): handbook cohesions of one soil type differ by a factor 2 between tests and a "
            "traverse's soil varies along it (strength COV 10-55 %); within 2 sigma a soil_change is the soil's "
            "tolerance, not a gap; 0: known exactly",
            0.0,
            2.0,
        ),
        ParamSpec(
            "tolerance.soil_friction_angle",
            0.035,
            "[rad] absolute tolerance (1 sigma) of the soil's internal friction angle phi (soil.friction_angle; the "
            "soil_change effect's friction-angle change): 2 deg, the lower end of a sand's inherent variability "
            "(COV 5-15 % of 30-35 deg); within 2 sigma a soil_change is the soil's tolerance, not a gap; 0: known "
            "exactly",
            0.0,
            0.3,
        ),
        ParamSpec(
            "tolerance.soil_modulus",
            0.3,
            "[-] relative tolerance (1 sigma) of the pressure-sinkage moduli k1, k2 (soil.pressure_sinkage_k1/_k2; "
            "the soil_change effect's modulus scale): the steady sinkage goes as k^(-2/(2n+1)), so with n near 1 "
            "this is the 0.2 of tolerance.sinkage; within 2 sigma a soil_change is the soil's tolerance, not a gap; "
            "0: known exactly",
            0.0,
            2.0,
        ),
        ParamSpec(
            "tolerance.soil_shear_modulus",
            0.3,
            "[-] relative tolerance (1 sigma) of the shear deformation modulus K (soil.shear_deformation_modulus; the "
            "soil_change effect's shear-modulus scale): measured K of one soil type spread by tens of per cent; "
            "within 2 sigma a soil_change is the soil's tolerance, not a gap; 0: known exactly",
            0.0,
            2.0,
        ),
    ),
}


def tolerances(vehicle: str, config: str | Path | None = None) -> dict[str, float]:
    """The vehicle's tolerances {``tolerance.<name>``: value} from ``config`` (default: the vehicle's config).

    Only the ``"/**/sim2real"`` section's ``tolerance.*`` names are read (other
    sections belong to the nodes); unknown ``tolerance.*`` names or values out of
    range are a :class:`~terrain_estimation.params.ParameterError` naming the
    file. A config without the section gives the defaults of :data:`SPECS`.
    """
    specs = SPECS.get(vehicle, ())
    if not specs:
        return {}
    path = Path(config) if config is not None else default_config_path(vehicle)
    values: dict[str, Any] = {}
    if path.exists():
        raw = load_parameter_file(path, [SECTION])
        values = {k: v for k, v in raw.items() if k.startswith("tolerance.")}
    resolved = resolve_parameters(specs, values, strict=True, source=f"{path}, section '/**/{SECTION}'")
    return {k: float(cast(float, v)) for k, v in resolved.items()}


def nuisance_names(values: Mapping[str, float]) -> tuple[str, ...]:
    """Replay nuisance parameters the tolerances ask for (tolerance > 0)."""
    return tuple(TARGETS[k][1] for k, v in values.items() if v > 0.0 and k in TARGETS and TARGETS[k][0] == "nuisance")


class ToleratedModel:
    """A replay model whose uncertain nominal parameters are nuisance parameters with a prior.

    Wraps any :class:`~terrain_analysis.sim2real.model.ReplayModel` (every
    attribute it does not override is the wrapped model's). Nuisance
    parameters named by a tolerance get ``prior_std`` = the tolerance and
    bounds narrowed to ``off`` ± 3× it; an effect parameter named by one
    (``"effect.parameter"``) becomes an extra nuisance parameter of that name,
    passed to the wrapped model as that effect's parameter unless the effect is
    itself among the predicted ones (then its own value wins).

    Args:
        model: the replay model.
        values: tolerances {``tolerance.<name>``: value} (:func:`tolerances`).
        targets: where each applies (default :data:`TARGETS`).
    """

    def __init__(
        self, model: ReplayModel, values: Mapping[str, float], targets: Mapping[str, tuple[str, str]] | None = None
    ) -> None:
        targets = TARGETS if targets is None else targets
        self._model = model
        self.applied: list[str] = []
        self.skipped: list[str] = []
        self._effect_nuisance: dict[str, tuple[str, str]] = {}
        #: "effect.parameter" → (off, tolerance) of the ("within", …) targets (:func:`within_tolerance`).
        self.within: dict[str, tuple[float, float]] = {}
        #: The :data:`LOCATION_PARAMETERS` of the effects with a within target: free in the within test.
        self.within_free: set[str] = set()
        by_name = {p.name: p for p in model.nuisance}
        nuisance: list[FitParameter] = []
        tolerated: dict[str, float] = {}
        for key, tol in values.items():
            if tol <= 0.0 or key not in targets:
                continue
            kind, target = targets[key]
            if kind == "nuisance":
                if target in by_name:
                    tolerated[target] = tol
                    self.applied.append(f"{target} ± {tol:g}")
                else:
                    self.skipped.append(f"{key} ({target} is not a nuisance parameter of this replay)")
                continue
            effect, param = target.split(".", 1)
            cand = model.candidates.get(effect)
            p = next((q for q in cand.parameters if q.name == param), None) if cand is not None else None
            if cand is None or p is None:
                self.skipped.append(f"{key} ({target} is not a candidate of this replay)")
                continue
            if kind == "within":
                self.within[target] = (p.off, tol)
                self.within_free |= {f"{effect}.{q.name}" for q in cand.parameters} & LOCATION_PARAMETERS
                self.applied.append(f"{target} within {WITHIN:g} × {tol:g}")
                continue
            lo, hi = max(p.bounds[0], p.off - 3.0 * tol), min(p.bounds[1], p.off + 3.0 * tol)
            nuisance.append(FitParameter(target, p.unit, p.off, (lo, hi), tol, prior_std=tol))
            self._effect_nuisance[target] = (effect, param)
            self.applied.append(f"{target} ± {tol:g}")
        own = []
        for p in model.nuisance:
            stated = tolerated.get(p.name)
            if stated is None:
                own.append(p)
                continue
            lo, hi = max(p.bounds[0], p.off - 3.0 * stated), min(p.bounds[1], p.off + 3.0 * stated)
            own.append(FitParameter(p.name, p.unit, p.off, (lo, hi), min(p.scale, stated), prior_std=stated))
        self.nuisance: list[FitParameter] = own + nuisance
        self.notes: list[str] = list(model.notes)
        if self.applied:
            self.notes.append(
                "nominal tolerances (config section /**/sim2real) fitted as nuisance with a Gaussian prior: "
                + ", ".join(self.applied)
            )
        if self.skipped:
            self.notes.append("tolerances not applicable to this replay: " + ", ".join(self.skipped))

        if self.within:
            self.notes.append(
                "an explanation by "
                + ", ".join(sorted(self.within))
                + f" fitted within {WITHIN:g} × its nominal tolerance is reported as within nominal tolerance, "
                "not as a gap"
            )

    # --- the protocol -----------------------------------------------------

    @property
    def vehicle(self) -> str:
        return self._model.vehicle

    @property
    def channels(self) -> Sequence[Channel]:
        return self._model.channels

    @property
    def times(self) -> Mapping[str, FloatArray]:
        return self._model.times

    @property
    def measured(self) -> Mapping[str, FloatArray]:
        return self._model.measured

    @property
    def candidates(self) -> Mapping[str, Candidate]:
        return self._model.candidates

    @property
    def regimes(self) -> Mapping[str, tuple[FloatArray, FloatArray]]:
        return self._model.regimes

    @property
    def warmup(self) -> float:
        return self._model.warmup

    @property
    def wrapped(self) -> ReplayModel:
        """The replay model without the tolerances."""
        return self._model

    def _split(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
        inner = {k: v for k, v in nuisance.items() if k not in self._effect_nuisance}
        merged: dict[str, dict[str, float]] = {k: dict(v) for k, v in effects.items()}
        for name, (effect, param) in self._effect_nuisance.items():
            if effect in effects or name not in nuisance:
                continue
            merged.setdefault(effect, {})[param] = float(nuisance[name])
        return merged, inner

    def predict(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, FloatArray]:
        """The wrapped model's prediction with the tolerated effect parameters passed as effects."""
        merged, inner = self._split(effects, nuisance)
        return self._model.predict(merged, inner)

    def __getattr__(self, name: str) -> Any:
        if name == "noise_std_for":
            budget = cast(Any, self._model).noise_std_for

            def noise_std_for(effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]) -> Any:
                merged, inner = self._split(effects, nuisance)
                return budget(merged, inner)

            return noise_std_for
        if name.startswith("__") or name == "_model":
            raise AttributeError(name)
        return getattr(self._model, name)


def with_tolerances(model: ReplayModel, values: Mapping[str, float]) -> ReplayModel:
    """``model`` with the tolerances applied (itself when none applies)."""
    if not any(v > 0.0 for v in values.values()):
        return model
    wrapped = ToleratedModel(model, values)
    return cast(ReplayModel, wrapped) if wrapped.applied else model


def within_tolerance(model: ReplayModel, parameters: Mapping[str, Mapping[str, float]]) -> list[dict[str, Any]]:
    """Rows {parameter, nominal, tolerance, fitted} when every fitted parameter is within nominal tolerance.

    ``parameters``: a fitted explanation ({effect: {parameter: value}}). Each of
    its parameters must be the error of a nominal parameter with a ("within",
    …) tolerance (:attr:`ToleratedModel.within`) and lie within
    :data:`WITHIN` × that tolerance of its off value, or say where the effect
    acts (:data:`LOCATION_PARAMETERS`, free); otherwise ``[]`` (the
    explanation is a gap).
    """
    within: Mapping[str, tuple[float, float]] = getattr(model, "within", None) or {}
    free: set[str] = getattr(model, "within_free", None) or set()
    rows: list[dict[str, Any]] = []
    for effect, values in parameters.items():
        for name, value in values.items():
            key = f"{effect}.{name}"
            if key in free:
                continue
            if key not in within:
                return []
            off, tol = within[key]
            if not abs(float(value) - off) <= WITHIN * tol:
                return []
            rows.append({"parameter": key, "nominal": off, "tolerance": tol, "fitted": float(value)})
    return rows
