"""`terrain-estimate` compares estimates with ground truth field by field, arrays of messages included."""

from __future__ import annotations

from builtin_interfaces.msg import Time
from std_msgs.msg import Header

from terrain_estimation.tools.estimate import numeric_fields, truth_errors
from terrain_msgs.msg import WheelTerrain, WheelTerrainArray


def _array(t: float, slips: list[float]) -> WheelTerrainArray:
    stamp = Time(sec=int(t), nanosec=int(round((t % 1) * 1e9)))
    wheels = [
        WheelTerrain(wheel=name, slip=s, normal_load=50.0)
        for name, s in zip(("rear", "middle", "front"), slips, strict=True)
    ]
    return WheelTerrainArray(header=Header(stamp=stamp), wheels=wheels)


def test_arrays_of_messages_are_flattened_by_index():
    fields = numeric_fields(_array(1.0, [0.1, 0.2, 0.3]))
    assert fields["wheels[0].slip"] == 0.1
    assert fields["wheels[2].slip"] == 0.3
    assert fields["wheels[1].normal_load"] == 50.0
    assert not any(k.startswith("header") for k in fields)


def test_truth_errors_over_wheel_arrays():
    truths = [_array(0.0, [0.1, 0.1, 0.1]), _array(1.0, [0.2, 0.2, 0.2])]
    estimates = [_array(0.5, [0.15, 0.1, 0.1]), _array(1.5, [0.2, 0.2, 0.26])]
    errs = truth_errors(estimates, truths, ["wheels[0].slip", "wheels[2].slip"])
    rms0, final0, _ = errs["wheels[0].slip"]
    rms2, final2, rel2 = errs["wheels[2].slip"]
    assert abs(rms0 - (0.05**2 / 2) ** 0.5) < 1e-12 and final0 == 0.0
    assert abs(final2 - 0.06) < 1e-12 and abs(rel2 - 0.3) < 1e-12
