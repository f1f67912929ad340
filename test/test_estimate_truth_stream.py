"""terrain-estimate's summary compares with the ground truth in one streaming pass (issue 23, memory).

The summary used to decode every ground-truth message of the bag into lists before comparing: an hour
of a 100 Hz truth topic held a few hundred MB (``python -m terrain_analysis.tools.bench_memory``). The
streamed comparison gives the same figures to the bit and leaves the truth unread into memory.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from terrain_estimation.tools.estimate import _summary_lines, estimate_bag, streamed_truth_errors, truth_errors

BAGS = Path(__file__).resolve().parents[1] / "bags"


@pytest.mark.parametrize(
    ("bag", "vehicle"),
    [("quarter_car_graneville_iso_d_10ms", "quarter_car"), ("skid_steer_small_radius_turn", "skid_steer")],
)
def test_streamed_errors_are_the_held_truths_to_the_bit_and_nothing_is_held(bag: str, vehicle: str) -> None:
    run = estimate_bag(BAGS / bag, vehicle)
    lines = list(_summary_lines(run))
    assert "_truth" not in run.__dict__, "the summary loaded the whole ground truth"
    assert any("vs ground truth" in line for line in lines)
    streamed = streamed_truth_errors(run)
    held = {
        t: truth_errors(run.messages(t), run.truth.get(t, []), run.truth_fields.get(t, ()))
        for t in sorted({t for t, _, _ in run.outputs})
    }
    assert streamed == held and any(streamed.values())
    # With the truth in memory (read before, or decoded during the run) the same figures come from it.
    assert streamed_truth_errors(run) == held
