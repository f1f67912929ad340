"""Lost samples of the 1 kHz terrain profile are detected and reported, not silently absorbed.

A node that falls behind a 1 kHz profiler (a loaded machine, a fast replay)
loses profile messages from its sensor-data queue in bursts; the road between
the filter's steps is then interpolated and k_s is biased (MODELS.md A.10).
The adapter must say so in its diagnostics.
"""

from __future__ import annotations

from pathlib import Path

from terrain_estimation.bag import read_bag
from terrain_estimation.tools.estimate import topic_name
from terrain_estimation.vehicles import estimator_parameters, get_vehicle

BAG = Path(__file__).resolve().parents[1] / "bags" / "quarter_car_graneville_iso_d_10ms"


def _run(drop_profile_burst: bool) -> tuple[list[str], int]:
    entry = get_vehicle("quarter_car")
    ns = entry.namespace
    adapter = entry.make_adapter(estimator_parameters(entry, None, None), ns)
    inputs = {topic_name(ns, s.topic): s.key for s in adapter.inputs}
    profile = topic_name(ns, "terrain/profile")
    warnings: list[str] = []
    for item in read_bag(BAG, list(inputs)):
        stamp = item.msg.header.stamp.sec + 1e-9 * item.msg.header.stamp.nanosec
        # Lose 30 ms of profile in every 100 ms (what a starved queue does).
        if drop_profile_burst and item.topic == profile and (stamp % 0.1) < 0.03:
            continue
        adapter.handle(inputs[item.topic], item.msg)
        warnings.extend(w for w in adapter.health.warnings if w not in warnings)
    return warnings, int(adapter.health.values.get("profile_gappy_steps", -1))


def test_intact_profile_raises_no_warning():
    warnings, gappy = _run(drop_profile_burst=False)
    assert warnings == []
    assert gappy == 0


def test_lost_profile_bursts_turn_diagnostics_warn():
    warnings, gappy = _run(drop_profile_burst=True)
    assert any(w.startswith("terrain/profile:") and "lost profile samples" in w for w in warnings), warnings
    assert gappy > 0
