"""Issue 19's mutation suite: every kind of damage to a shipped bag, through both offline tools.

Each case of :data:`terrain_analysis.tools.mutate.MUTATIONS` damages a
shipped bag (with rosbags alone), runs ``terrain-estimate`` and
``terrain-sim2real`` on it and holds them to the case's exit status and
message, to "nothing non-finite written" and to "no input modified or
removed" (every file hashed before and after). The quarter car runs every
case through both tools; the other vehicles run every case through
``terrain-estimate`` and the input-level cases through ``terrain-sim2real``
(their diagnoses take longer), to keep the suite inside its time budget.

``python -m terrain_analysis.tools.mutate`` prints the same table for
``docs/results/robustness.md``.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import pytest

from terrain_analysis.tools.mutate import DEFAULT_BAGS, MUTATIONS, Case, run_case

BAGS = Path(__file__).resolve().parents[1] / "bags"

# Cases whose diagnosis the slower vehicles run too: the damage the diagnosis reads differently
# from the estimator (types, stamps, gaps, bytes, values).
SIM2REAL_EVERY_VEHICLE = {"type", "gap_1h", "garbage", "spike", "nan", "empty", "namespace"}


@cache
def _clean_statuses(vehicle: str, sim2real: bool, tmp: str) -> tuple[int, int | None]:
    clean = run_case(
        MUTATIONS[0],
        vehicle,
        BAGS / DEFAULT_BAGS[vehicle],
        Path(tmp) / f"clean-{vehicle}-{sim2real}",
        sim2real=sim2real,
    )
    assert clean.ok, clean.problems
    return clean.estimate.status, clean.sim2real.status if clean.sim2real else None


@pytest.fixture(scope="module")
def module_tmp(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("mutation-reference")


def _runs(vehicle: str, case: Case) -> bool:
    """The rover's bag is 24 s long: of values and units it runs one case each."""
    return vehicle != "rover" or case.kind not in ("values", "units") or case.name in ("spike", "in_g")


# Known and not yet fixed: strict, so that the fix shows.
KNOWN: dict[tuple[str, str], str] = {}


CASES = [
    pytest.param(
        vehicle,
        case,
        id=f"{vehicle}-{case.name}",
        marks=[pytest.mark.xfail(reason=KNOWN[(vehicle, case.name)], strict=True)]
        if (vehicle, case.name) in KNOWN
        else [],
    )
    for vehicle in ("quarter_car", "lrv", "skid_steer", "rover")
    for case in MUTATIONS[1:]
    if _runs(vehicle, case)
]


@pytest.mark.timeout(300)
@pytest.mark.parametrize(("vehicle", "case"), CASES)
def test_damage_is_refused_or_counted_and_nothing_is_destroyed(
    vehicle: str, case: Case, tmp_path: Path, module_tmp: Path
) -> None:
    sim2real = vehicle in ("quarter_car", "lrv") or case.name in SIM2REAL_EVERY_VEHICLE
    statuses = _clean_statuses(vehicle, sim2real, str(module_tmp))
    outcome = run_case(
        case, vehicle, BAGS / DEFAULT_BAGS[vehicle], tmp_path / "case", clean_status=statuses, sim2real=sim2real
    )
    detail = f"\nterrain-estimate said:\n{outcome.estimate.text[-3000:]}"
    if outcome.sim2real is not None:
        detail += f"\nterrain-sim2real said:\n{outcome.sim2real.text[-3000:]}"
    assert outcome.input_unchanged, detail
    assert not outcome.nonfinite, detail
    assert outcome.ok, "; ".join(outcome.problems) + detail


# One case of each kind again on bags simulated now (the simulator as it is, not the shipped recordings).
FRESH_CASES = (
    "nan", "spike", "in_g", "upside_down", "frame", "type", "reorder", "gap_1h", "garbage",
    "bad_metadata", "truncated", "missing", "namespace", "out_is_input",
)  # fmt: skip


@pytest.fixture(scope="module")
def fresh_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, tuple[int, int | None]]]:
    """4 s of each vehicle simulated now, with both tools' statuses on the undamaged bag."""
    from vehicle_sim.tools.simulate import record

    root = tmp_path_factory.mktemp("fresh")
    out = {}
    for vehicle in ("quarter_car", "skid_steer"):
        assert record(vehicle, 4.0, root / vehicle) > 0
        clean = run_case(
            MUTATIONS[0], vehicle, root / vehicle, root / f"clean-{vehicle}", sim2real=vehicle == "quarter_car"
        )
        assert clean.ok, clean.problems
        out[vehicle] = (root / vehicle, (clean.estimate.status, clean.sim2real.status if clean.sim2real else None))
    return out


@pytest.mark.timeout(300)
@pytest.mark.parametrize("vehicle", ["quarter_car", "skid_steer"])
@pytest.mark.parametrize("name", FRESH_CASES)
def test_damage_to_a_freshly_simulated_bag(
    vehicle: str, name: str, fresh_bags: dict[str, tuple[Path, tuple[int, int | None]]], tmp_path: Path
) -> None:
    case = next(c for c in MUTATIONS if c.name == name)
    bag, statuses = fresh_bags[vehicle]
    outcome = run_case(case, vehicle, bag, tmp_path / "case", clean_status=statuses, sim2real=vehicle == "quarter_car")
    detail = f"\nterrain-estimate said:\n{outcome.estimate.text[-3000:]}"
    if outcome.sim2real is not None:
        detail += f"\nterrain-sim2real said:\n{outcome.sim2real.text[-3000:]}"
    assert outcome.input_unchanged and not outcome.nonfinite, detail
    assert outcome.ok, "; ".join(outcome.problems) + detail
