"""The rig's replay model: the candidate effects of a single wheel and how they act (single-wheel check)."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from terrain_analysis.sim2real.model import Candidate, Channel, FitParameter
from terrain_analysis.sim2real.single_wheel_data import RigTrials, pooled_replicate_std
from terrain_analysis.sim2real.single_wheel_physics import NOMINAL, RIG_WHEEL, WheelGeometry, WheelSoil, steady_state

__all__ = ["PHYSICAL_RANGES", "SingleWheelModel", "candidates"]

FloatArray = NDArray[np.float64]


def _catalogue_parameter(effect: str, name: str) -> FitParameter:
    from vehicle_sim.effects import CATALOGUE

    p = CATALOGUE["rover"][effect].parameter(name)
    scale = abs(p.typical - p.off) or 0.1 * (p.fit_range[1] - p.fit_range[0])
    return FitParameter(p.name, p.unit, float(p.off), p.fit_range, float(scale))


_SOIL_PARAMETERS = {
    "soil_change_cohesion": "soil_change_cohesion_scale",
    "soil_change_friction_angle": "soil_change_friction_angle_change",
    "soil_change_modulus": "soil_change_modulus_scale",
    "soil_change_shear_modulus": "soil_change_shear_modulus_scale",
}


#: Physically plausible range of each rig candidate parameter, where narrower than its fit range:
#: a fit outside it is flagged in the report (it is not a physical explanation).
PHYSICAL_RANGES: dict[str, tuple[float, float]] = {
    "load_cell_bias_dp": (-3.0, 3.0),  # zero drift of a 100 N-class load cell after taring
    "load_cell_crosstalk": (-0.05, 0.05),
    "soil_change_cohesion_scale": (0.0, 3.0),  # dry granular soil: c of 0–3 kPa
    "soil_change_friction_angle_change": (-0.1, 0.1),
    "sinkage_offset": (-5.0, 5.0),  # mm: zeroing on a prepared surface
    "bulldozing_coefficient": (0.0, 1.5),  # up to the full passive wedge, with some surcharge
    "max_stress_angle_c1": (0.2, 0.5),  # Wong & Reece's measurements: 0.18–0.43
}


def candidates(base: WheelSoil = NOMINAL, geometry: WheelGeometry = RIG_WHEEL) -> dict[str, Candidate]:
    """The candidate effects of the rig (module docstring), with their fit ranges.

    ``grousers`` only for a grousered wheel (``geometry``): its effective
    height h_e in [0, h_g] (0: the smooth-rim nominal; h_g: all soil between
    the grousers trapped).
    """
    from vehicle_sim.effects import CATALOGUE

    rover = CATALOGUE["rover"]
    soil = tuple(_catalogue_parameter("soil_change", name) for name in _SOIL_PARAMETERS.values())
    out = {
        "slip_sinkage": Candidate(
            "slip_sinkage",
            (_catalogue_parameter("slip_sinkage", "slip_sinkage_coefficient"),),
            rover["slip_sinkage"].description,
        ),
    }
    for cand, pname in _SOIL_PARAMETERS.items():
        p = next(q for q in soil if q.name == pname)
        out[cand] = Candidate(cand, (p,), f"{rover['soil_change'].description}: {p.name} only")
    out["load_cell_bias"] = Candidate(
        "load_cell_bias",
        (FitParameter("load_cell_bias_dp", "N", 0.0, (-10.0, 10.0), 1.0),),
        "constant offset of the drawbar-pull axis of the force sensor",
    )
    out["load_cell_crosstalk"] = Candidate(
        "load_cell_crosstalk",
        (_catalogue_parameter("load_cell_crosstalk", "load_cell_crosstalk"),),
        rover["load_cell_crosstalk"].description,
    )
    out["sinkage_exponent"] = Candidate(
        "sinkage_exponent",
        (FitParameter("sinkage_exponent", "–", base.n, (0.6, 2.2), 0.2),),
        "sinkage exponent n of σ = k z^n (k's value in N/m^(n+2) kept)",
    )
    out["slip_exponent"] = Candidate(
        "slip_exponent",
        (
            FitParameter("exponent_slip_rate", "–", 0.0, (-0.5, 1.5), 0.3),
            FitParameter("exponent_skid_rate", "–", 0.0, (-0.5, 1.5), 0.3),
        ),
        "slip-dependent sinkage exponent n = n0 + n1 i (drive), n0 + n2 |i| (skid) (Ding et al.; the rig authors)",
    )
    out["rear_contact"] = Candidate(
        "rear_contact",
        (FitParameter("rear_angle_ratio", "–", 0.0, (0.0, 1.0), 0.2),),
        "soil rebound behind the wheel: exit angle θ_r = −λ θ0",
    )
    out["max_stress_angle"] = Candidate(
        "max_stress_angle",
        (
            FitParameter("max_stress_angle_c1", "–", base.c1, (0.02, 0.6), 0.1),
            FitParameter("max_stress_angle_c2", "–", base.c2, (0.0, 0.4), 0.1),
        ),
        "position of the maximum normal stress θ_m = θ0 (c1 + c2 i)",
    )
    out["skid_stresses"] = Candidate(
        "skid_stresses",
        (),
        "braking: Wong–Reece stresses evaluated at the skid itself (shear reversed) instead of the anti-symmetry "
        "DP(i) = −DP(−i) + 2 DP(0)",
    )
    out["sinkage_offset"] = Candidate(
        "sinkage_offset",
        (FitParameter("sinkage_offset", "mm", 0.0, (-10.0, 10.0), 2.0),),
        "zero of the sinkage measurement (wheel touching the prepared surface) off by a constant",
    )
    out["bulldozing"] = Candidate(
        "bulldozing",
        (FitParameter("bulldozing_coefficient", "–", 0.0, (0.0, 3.0), 0.5),),
        "braking resistance of the soil wedge a skidding wheel pushes ahead: κ × Wong's bulldozing resistance "
        "b (0.67 c z K_pc + 0.5 γ z² K_pγ), mobilised by the skid as 1 − exp(−|i| r θ0 / K)",
    )
    if geometry.grousered:
        h = geometry.grouser_height
        out["grousers"] = Candidate(
            "grousers",
            (FitParameter("grouser_effective_height", "m", 0.0, (0.0, h), 0.5 * h),),
            f"{rover['grousers'].description}; effective height h_e in [0, {h:g} m] (the wheel's grousers)",
        )
    return out


def _apply(
    base: WheelSoil, effects: Mapping[str, Mapping[str, float]], geometry: WheelGeometry = RIG_WHEEL
) -> tuple[WheelSoil, dict[str, float]]:
    """Wheel–soil parameters with ``effects`` applied, and the sensor-level terms (bias, crosstalk, offset)."""
    sensor = {"bias": 0.0, "crosstalk": 0.0, "offset": 0.0}
    changes: dict[str, Any] = {}

    def value(effect: str, name: str, default: float) -> float:
        return float(effects[effect].get(name, default))

    for effect in effects:
        if effect == "slip_sinkage":
            changes["slip_sinkage"] = value(effect, "slip_sinkage_coefficient", 0.0)
        elif effect in _SOIL_PARAMETERS:
            cohesion = changes.get("cohesion", base.cohesion) * value(effect, "soil_change_cohesion_scale", 1.0)
            phi = changes.get("friction_angle", base.friction_angle) + value(
                effect, "soil_change_friction_angle_change", 0.0
            )
            modulus = value(effect, "soil_change_modulus_scale", 1.0)
            changes["cohesion"] = cohesion
            changes["friction_angle"] = phi
            changes["k_c"] = changes.get("k_c", base.k_c) * modulus
            changes["k_phi"] = changes.get("k_phi", base.k_phi) * modulus
            changes["shear_modulus"] = changes.get("shear_modulus", base.shear_modulus) * value(
                effect, "soil_change_shear_modulus_scale", 1.0
            )
        elif effect == "load_cell_bias":
            sensor["bias"] += value(effect, "load_cell_bias_dp", 0.0)
        elif effect == "load_cell_crosstalk":
            sensor["crosstalk"] += value(effect, "load_cell_crosstalk", 0.0)
        elif effect == "sinkage_exponent":
            changes["n"] = value(effect, "sinkage_exponent", base.n)
        elif effect == "slip_exponent":
            changes["n_slip"] = value(effect, "exponent_slip_rate", 0.0)
            changes["n_skid"] = value(effect, "exponent_skid_rate", 0.0)
        elif effect == "rear_contact":
            changes["rear_ratio"] = value(effect, "rear_angle_ratio", 0.0)
        elif effect == "max_stress_angle":
            changes["c1"] = value(effect, "max_stress_angle_c1", base.c1)
            changes["c2"] = value(effect, "max_stress_angle_c2", base.c2)
        elif effect == "sinkage_offset":
            sensor["offset"] += value(effect, "sinkage_offset", 0.0)
        elif effect == "skid_stresses":
            changes["skid_stresses"] = True
        elif effect == "bulldozing":
            changes["bulldozing"] = value(effect, "bulldozing_coefficient", 0.0)
        elif effect == "grousers":
            if not geometry.grousered:
                raise ValueError(
                    "single-wheel effect 'grousers' does not apply: the wheel is smooth "
                    "(give the wheel's grouser count and height)"
                )
            changes["grouser_height"] = min(
                max(value(effect, "grouser_effective_height", 0.0), 0.0), 0.49 * base.radius
            )
        else:
            raise ValueError(f"unknown single-wheel effect {effect!r}; known: {sorted(candidates(base))}")
    if changes.get("friction_angle", base.friction_angle) <= 0.0:
        changes["friction_angle"] = 1e-6
    return dataclasses.replace(base, **changes), sensor


@dataclass
class SingleWheelModel:
    """Replay model of the rig's β = 0 trials (module docstring)."""

    trials: RigTrials
    base: WheelSoil = NOMINAL
    noise: Mapping[str, tuple[float, int]] | None = None
    geometry: WheelGeometry = RIG_WHEEL
    vehicle: str = "cmu_single_wheel"
    channels: Sequence[Channel] = field(init=False)
    times: Mapping[str, FloatArray] = field(init=False)
    measured: Mapping[str, FloatArray] = field(init=False)
    nuisance: Sequence[FitParameter] = field(init=False)
    candidates: Mapping[str, Candidate] = field(init=False)
    regimes: Mapping[str, tuple[FloatArray, FloatArray]] = field(init=False)
    warmup: float = 0.0
    notes: list[str] = field(init=False)
    noise_dof: dict[str, int] = field(init=False)

    def __post_init__(self) -> None:
        t = self.trials
        g = self.geometry
        if (self.base.radius, self.base.width) != (g.radius, g.width):
            self.base = dataclasses.replace(self.base, radius=g.radius, width=g.width)
        if self.noise is None:
            sd_dp, dof_dp = pooled_replicate_std(t.drawbar_pull, t.group)
            sd_z, dof_z = pooled_replicate_std(t.sinkage, t.group)
        else:
            (sd_dp, dof_dp), (sd_z, dof_z) = self.noise["drawbar_pull"], self.noise["sinkage"]
        source = Path(t.source).name
        self.channels = [
            Channel("drawbar_pull", f"{source}: -avg_Fy", "N", sd_dp),
            Channel("sinkage", f"{source}: -avg_Z", "mm", sd_z),
        ]
        index = np.arange(t.size, dtype=float)
        self.times = {"drawbar_pull": index, "sinkage": index}
        self.measured = {"drawbar_pull": t.drawbar_pull, "sinkage": t.sinkage}
        self.nuisance = []
        self.candidates = candidates(self.base, g)
        self.regimes = {"slip (–)": (index, t.slip), "load (N)": (index, t.load)}
        self.noise_dof = {"drawbar_pull": dof_dp, "sinkage": dof_z}
        self.notes = [
            f"{t.size} trials at beta = 0 of {t.total_trials} (beta = {', '.join(f'{b:g}' for b in t.betas)} deg); "
            "the others are left out: the model is planar",
            f"samples are trials ordered by slip; noise budget = pooled spread of repeated trials: "
            f"DP {sd_dp:.3f} N, sinkage {sd_z:.3f} mm ({dof_dp} degrees of freedom)",
            f"wheel: {g.describe()}"
            + (
                "; the nominal model shears on the rim, the grousers effect on the tip cylinder"
                if g.grousered
                else "; the grousers effect does not apply (smooth wheel)"
            ),
        ]

    def predict(
        self, effects: Mapping[str, Mapping[str, float]], nuisance: Mapping[str, float]
    ) -> dict[str, FloatArray]:
        """DP (N) and sinkage (mm) of every trial with ``effects`` added (nuisance: none)."""
        del nuisance
        p, sensor = _apply(self.base, effects, self.geometry)
        w_meas = self.trials.load
        c = sensor["crosstalk"]
        load = w_meas
        dp, z = steady_state(load, self.trials.slip, p)
        if c != 0.0:
            # W_meas = W + c DP: the true load from the measured one (contraction for |c| ≤ 0.1).
            for _ in range(4):
                load = np.maximum(w_meas - c * dp, 0.0)
                dp, z = steady_state(load, self.trials.slip, p)
        dp_meas = dp + c * load + sensor["bias"]
        z_mm = 1000.0 * z + sensor["offset"]
        return {
            "drawbar_pull": np.nan_to_num(dp_meas, nan=0.0, posinf=1e6, neginf=-1e6),
            "sinkage": np.nan_to_num(z_mm, nan=0.0, posinf=1e6, neginf=-1e6),
        }
