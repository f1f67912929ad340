"""A bag of the independent generator (``vehicle_sim.independent``, written apart from the diagnosis) through
the ``sim2real`` command line, for the tests that check an effect's physical generality on it (issue 22)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest


def diagnose_independent_bag(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    vehicle: str,
    effect: str,
    seed: int,
    *,
    per_effect: int = 1,
    plan_duration: float | None = None,
    plan_id: str | None = None,
    duration: float | None = None,
) -> tuple[int, str, dict[str, Any], dict[str, Any]]:
    """(exit status, printed text, the bag's label, diagnosis.json's attribution) of one generated bag.

    The suite of ``seed`` is drawn with ``per_effect`` bags of ``effect`` (and ``plan_duration``, the
    generator's fixed duration, when given); ``plan_id`` picks one of them (default: the only one), whose
    ``duration`` may then be cut. Only that bag is generated and diagnosed.
    """
    from terrain_analysis.tools.sim2real import main as sim2real_main
    from vehicle_sim.independent import suite

    plans = suite.plan_suite(
        seed,
        [vehicle],
        per_effect=per_effect,
        controls=0,
        structure_controls=0,
        out_of_catalogue=0,
        effects=[effect],
        duration=plan_duration,
    )
    (plan,) = [p for p in plans if plan_id is None or p.id == plan_id]
    if duration is not None:
        plan = dataclasses.replace(plan, duration=duration)
    suite.generate(tmp_path / "suite", [plan], jobs=1, signatures=False)
    ((_, label),) = json.loads((tmp_path / "suite" / "labels.json").read_text())["labels"].items()
    out = tmp_path / "report"
    code = sim2real_main(
        [str(tmp_path / "suite" / label["bag"]), "--vehicle", vehicle, "-o", str(out), "-q", "--no-figures"]
    )
    printed = capsys.readouterr().out
    return code, printed, label, json.loads((out / "diagnosis.json").read_text())["attribution"]
