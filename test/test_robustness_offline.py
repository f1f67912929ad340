"""The offline runner applies the live node's input checks (issue 7: live and offline agree on bad input).

One body-IMU sample stamped a year ahead, one NaN and one in a wrong frame are
slipped into the bundled LRV bag. ``terrain-estimate`` (``estimate_bag``)
rejects the three, names them in its counts and estimates to the end of the
bag like the clean run; without the checks the future stamp stops the
estimator for good (every later sample is "out of order").
"""

from __future__ import annotations

import math
from pathlib import Path

from terrain_estimation.bag import AtomicBagWriter, read_bag
from terrain_estimation.ros.time import ns_to_stamp, stamp_to_ns
from terrain_estimation.tools.estimate import estimate_bag, run_adapter
from terrain_estimation.vehicles import VEHICLES, estimator_parameters

BAG = Path(__file__).resolve().parents[1] / "bags" / "lrv_regolith_iso_g_2ms"
YEAR_NS = 365 * 24 * 3600 * 1_000_000_000


def _tampered(out: Path) -> Path:
    body = 0
    with AtomicBagWriter(out) as writer:
        for item in read_bag(BAG):
            msg = item.msg
            if item.topic.endswith("imu/body"):
                body += 1
                if body == 100:
                    msg.header.stamp = ns_to_stamp(stamp_to_ns(msg.header.stamp) + YEAR_NS)
                elif body == 150:
                    msg.linear_acceleration.z = math.nan
                elif body == 200:
                    msg.header.frame_id = "somewhere_else"
            writer.write(item.topic, msg, item.log_time_ns)
    return out


def test_offline_run_rejects_bad_input_like_the_node(tmp_path: Path) -> None:
    bag = _tampered(tmp_path / "tampered")
    topic = "/lrv/soil_stiffness"
    clean = estimate_bag(BAG, "lrv").messages(topic)
    run = estimate_bag(bag, "lrv")
    got = run.messages(topic)
    reasons = " | ".join(run.rejected)
    assert sum(run.rejected.values()) == 3, run.rejected
    assert "stamp" in reasons and "frame" in reasons and "not finite" in reasons, reasons
    assert len(got) >= len(clean) - 3  # estimates to the end of the bag
    assert abs(got[-1].k_s / clean[-1].k_s - 1.0) < 0.01
    assert all(math.isfinite(m.k_s) for m in got)


def test_without_the_checks_the_future_stamp_stops_the_estimator(tmp_path: Path) -> None:
    bag = _tampered(tmp_path / "tampered")
    entry = VEHICLES["lrv"]
    adapter = entry.make_adapter(estimator_parameters(entry, None), entry.namespace)
    unguarded = run_adapter(adapter, entry.namespace, bag).messages("/lrv/soil_stiffness")
    clean = estimate_bag(BAG, "lrv").messages("/lrv/soil_stiffness")
    assert len(unguarded) < 0.5 * len(clean)
