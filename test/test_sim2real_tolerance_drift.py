"""Two verdict rules of the sim-to-real attribution (issue 22, items 2-3, follow-up on the independent suite).

* nominal tolerance of a parameter whose error is a catalogue effect (the skid steer's effective wheel
  radius, its cornering stiffness): an explanation by that effect fitted within 2 tolerances (1 sigma) of
  its off value is "no significant gap (within nominal tolerance ...)", not "explained by" it; beyond, it
  is still the explanation;
* the drift rule (a best effect whose refits on the two halves of an operating regime differ): the halves
  are compared with their own intervals (Student's t at the Welch-Satterthwaite degrees of freedom of
  their batch-means variances), not with the normal quantile.

The toy is the one of ``test_sim2real_attribution`` (y = A sin(2 pi 1.7 t) + sin(2 pi 0.3 t), white noise).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_sim2real_attribution import SIGMA, ToyModel, _signal

import terrain_analysis.sim2real.structure as structure
from terrain_analysis.sim2real.attribution import AttributionSettings, attribute
from terrain_analysis.sim2real.fitting import FittedModel, _block_ids, _problem, held_out_mask
from terrain_analysis.sim2real.tolerance import SPECS, ToleratedModel, tolerances

REPO = Path(__file__).resolve().parents[1]
FAST = AttributionSettings(bootstrap=100)
WITHIN_TARGETS = {"tolerance.gain": ("within", "gain.s")}


def _toy(gain: float, seed: int) -> ToyModel:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 30.0, 0.01)
    return ToyModel(_signal(t, 1.3, {"gain": {"s": gain}}) + SIGMA * rng.standard_normal(t.size), t)


# --- nominal tolerance of an effect's parameter ("within" targets) -----------------------------------


def test_an_effect_fitted_within_its_nominal_tolerance_is_no_gap() -> None:
    """A 2 % gain error against a 1.5 % (1 sigma) tolerance: the old engine said "explained by gain"; the
    gain is within 2 sigma of nominal, so the bag shows no sim-to-real gap, and the verdict says why."""
    model = _toy(0.02, seed=41)
    plain = attribute(model, FAST)
    assert plain.kind == "explained" and plain.explained_by == ("gain",), plain.verdict
    tolerated = ToleratedModel(model, {"tolerance.gain": 0.015}, targets=WITHIN_TARGETS)
    assert tolerated.within == {"gain.s": (0.0, 0.015)} and tolerated.nuisance == model.nuisance
    report = attribute(tolerated, FAST)
    assert report.kind == "no_gap" and report.explained_by == (), report.verdict
    assert report.verdict.startswith("no significant gap (within nominal tolerance: gain.s = 0.0")
    row = next(r for r in report.tolerances if r.get("explanation"))
    assert row["parameter"] == "gain.s" and row["within"] and row["fitted"] == pytest.approx(0.02, abs=0.004)


def test_an_effect_beyond_its_nominal_tolerance_is_still_the_explanation() -> None:
    """A 10 % gain error against the same tolerance (beyond 2 sigma = 3 %): explained by gain, as before."""
    report = attribute(ToleratedModel(_toy(0.10, seed=42), {"tolerance.gain": 0.015}, targets=WITHIN_TARGETS), FAST)
    assert report.kind == "explained" and report.explained_by == ("gain",), report.verdict


def test_skid_steer_states_wheel_radius_and_cornering_stiffness_tolerances() -> None:
    """The config (rendered from the specs) states them; the Husky config has no section: the defaults."""
    specs = {s.name: s.default for s in SPECS["skid_steer"]}
    assert specs["tolerance.wheel_radius"] == pytest.approx(0.015)
    assert specs["tolerance.cornering_stiffness"] == pytest.approx(0.15)
    for config in ("skid_steer.yaml", "husky.yaml"):
        values = tolerances("skid_steer", REPO / "config" / config)
        assert values["tolerance.wheel_radius"] == pytest.approx(0.015), config
        assert values["tolerance.cornering_stiffness"] == pytest.approx(0.15), config


# --- the drift rule compares the halves with their own intervals ------------------------------------


def _half(value: float, sd: float, batches: int, settings: AttributionSettings, dof: float) -> FittedModel:
    from scipy import stats

    q = float(stats.t.ppf(0.5 + 0.5 * settings.confidence, dof)) if np.isfinite(dof) else 1.6448536269514722
    return FittedModel(
        ("gain",),
        {"gain": {"s": value}},
        {"gain": {"s": sd}},
        {"amplitude": 1.3},
        1,
        0.0,
        0.0,
        0.0,
        {},
        interval={"gain": {"s": (value - q * sd, value + q * sd)}},
        batches=batches,
    )


def _stability_with_halves(monkeypatch: Any, halves: list[FittedModel]) -> list[str]:
    """:func:`structure._stability` on a toy bag, the two refits replaced by ``halves`` (low, high)."""
    model = _toy(0.03, seed=43)
    settings = replace(FAST, stability_regimes=1)
    train, test = held_out_mask(model, settings)
    problem = _problem(model, settings, train, test, _block_ids(model, settings, test))
    best = _half(0.03, 0.002, 30, settings, 29.0)
    queue = list(halves)
    monkeypatch.setattr(structure, "fit", lambda *args, **kwargs: queue.pop(0))
    return structure._stability(model, problem, best, settings)


def test_a_difference_inside_the_refits_own_intervals_is_not_drift(monkeypatch: Any) -> None:
    """Halves 0.020 and 0.035 with standard errors 0.003 from 4 batches each (3 degrees of freedom):
    3.5 sigma apart, beyond the normal quantile (3.29 at 0.999, two-sided) that read "structure
    differs", inside Student's t at the halves' 6 Welch degrees of freedom (5.96)."""
    settings = FAST
    halves = [_half(0.020, 0.003, 4, settings, 3.0), _half(0.035, 0.003, 4, settings, 3.0)]
    assert _stability_with_halves(monkeypatch, halves) == []


def test_a_difference_beyond_well_determined_refits_is_drift(monkeypatch: Any) -> None:
    """The same values from well-determined refits (white intervals from every sample, or many batches)."""
    settings = FAST
    for dof, batches in ((np.inf, 40), (39.0, 40)):
        halves = [_half(0.020, 0.003, batches, settings, dof), _half(0.035, 0.003, batches, settings, dof)]
        reasons = _stability_with_halves(monkeypatch, halves)
        assert len(reasons) == 1 and "depends on time (s)" in reasons[0], (dof, reasons)
