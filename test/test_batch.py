"""``terrain-batch`` (issue 23): vehicle detection, and a real 2-worker Dask cluster over a few bags.

The cluster test starts a real :class:`distributed.LocalCluster` (two worker
processes, no mock) through the command's ``main``, over copies of three short
shipped bags of three vehicles and one corrupt bag (a truncated MCAP file). It
checks that the corrupt bag is a failure with its reason while the others are
estimated, that the estimates bags hold what ``terrain-estimate`` gives for the
same bag, that the input bags are untouched, and that a second run skips
everything without starting a cluster.
"""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
from pathlib import Path

import pytest
import yaml

from terrain_analysis.batch.bags import UnknownVehicleError, detect_vehicle, find_bags
from terrain_estimation.bag import bag_contents, read_bag
from terrain_estimation.cli import EXIT_FINDING, EXIT_INPUT

BAGS = Path(__file__).resolve().parents[1] / "bags"
SHORT = ("quarter_car_graneville_iso_d_10ms", "lrv_regolith_iso_g_2ms", "skid_steer_s_shape")


def _topics(bag: Path) -> dict[str, str]:
    return {t.topic: t.msgtype for t in bag_contents(bag).values() if t.count > 0}


def test_detects_the_vehicle_of_every_shipped_bag() -> None:
    """The vehicle detected from each shipped bag's topics is the one expectations.yaml names."""
    expected = yaml.safe_load((BAGS / "expectations.yaml").read_text())
    found, missing = find_bags([BAGS])
    assert not missing and {rel for _, rel in found} == set(expected)
    for bag, rel in found:
        vehicle, namespace, _how = detect_vehicle(_topics(bag))
        assert vehicle == expected[rel]["vehicle"], rel
        assert namespace == "/" + vehicle


def test_detection_without_the_vehicle_namespace_and_its_failures() -> None:
    """Under a neutral namespace the topics decide (the most specific complete set); unknown and ambiguous fail."""
    qc = _topics(BAGS / "quarter_car_graneville_iso_d_10ms")
    lrv = _topics(BAGS / "lrv_regolith_iso_g_2ms")
    rover = _topics(BAGS / "rover_terrain_1")
    skid = _topics(BAGS / "skid_steer_s_shape")

    def moved(topics: dict[str, str], old: str, new: str) -> dict[str, str]:
        return {t.replace(old, new, 1): m for t, m in topics.items()}

    # the quarter car's inputs include the LRV's, the rover's the skid steer's: the larger set wins
    assert detect_vehicle(moved(qc, "/quarter_car", "/robot7"))[:2] == ("quarter_car", "/robot7")
    assert detect_vehicle(moved(lrv, "/lrv", "/robot7"))[:2] == ("lrv", "/robot7")
    assert detect_vehicle(moved(rover, "/rover", "/fleet/r2"))[:2] == ("rover", "/fleet/r2")
    assert detect_vehicle(moved(skid, "/skid_steer", "/a"))[:2] == ("skid_steer", "/a")
    # a vehicle's name as the namespace decides, even with a topic missing
    partial = {t: m for t, m in qc.items() if not t.endswith("imu/wheel")}
    assert detect_vehicle(partial)[0] == "quarter_car"
    with pytest.raises(UnknownVehicleError, match="no known vehicle"):
        detect_vehicle({"/clock": "rosgraph_msgs/msg/Clock"})
    # a topic of the right name but the wrong type does not count
    wrong = {
        t: ("std_msgs/msg/String" if t.endswith("/imu") else m) for t, m in moved(skid, "/skid_steer", "/a").items()
    }
    with pytest.raises(UnknownVehicleError):
        detect_vehicle(wrong)
    # two robots in one bag: refused, not guessed
    with pytest.raises(UnknownVehicleError, match="several"):
        detect_vehicle({**moved(skid, "/skid_steer", "/a"), **moved(skid, "/skid_steer", "/b")})
    # --namespace narrows it down
    both = {**moved(skid, "/skid_steer", "/a"), **moved(skid, "/skid_steer", "/b")}
    assert detect_vehicle(both, namespace="b")[:2] == ("skid_steer", "/b")


def _digest(root: Path) -> dict[str, tuple[str, int]]:
    return {
        str(p.relative_to(root)): (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _rows(out: Path) -> dict[str, dict[str, str]]:
    with (out / "summary.csv").open(newline="", encoding="utf-8") as f:
        return {r["bag"]: r for r in csv.DictReader(f)}


def test_batch_on_a_real_local_cluster_isolates_a_corrupt_bag_and_resumes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from terrain_analysis.tools import batch
    from terrain_estimation.tools.estimate import estimate_bag

    inputs = tmp_path / "fleet"
    for name in SHORT:
        shutil.copytree(BAGS / name, inputs / "day1" / name)
    corrupt = inputs / "day2" / "corrupt"
    corrupt.mkdir(parents=True)
    source = BAGS / SHORT[0]
    shutil.copy(source / "metadata.yaml", corrupt / "metadata.yaml")
    data = (source / f"{SHORT[0]}.mcap").read_bytes()
    (corrupt / f"{SHORT[0]}.mcap").write_bytes(data[: len(data) // 3])  # a recording cut short
    before = _digest(inputs)
    out = tmp_path / "out"

    status = batch.main([str(inputs), "-o", str(out), "--workers", "2"])

    assert status == EXIT_FINDING  # some bags failed, the others done
    rows = _rows(out)
    assert set(rows) == {f"day1/{n}" for n in SHORT} | {"day2/corrupt"}
    bad = rows["day2/corrupt"]
    assert bad["status"] == "failed" and bad["reason"].startswith("reading the bag:"), bad
    expected_vehicle = {"quarter_car_graneville_iso_d_10ms": "quarter_car", "lrv_regolith_iso_g_2ms": "lrv"}
    for name in SHORT:
        row = rows[f"day1/{name}"]
        assert row["status"] == "done", row
        assert row["vehicle"] == expected_vehicle.get(name, "skid_steer")
        assert float(row["duration_s"]) > 3.0 and float(row["cpu_s"]) > 0.0
        assert json.loads(row["rejections"]) == {} and row["rejected"] == "0"
        # the batch's estimates are terrain-estimate's for the same bag
        reference = estimate_bag(BAGS / name, row["vehicle"])
        written = list(read_bag(out / "bags" / "day1" / name / "estimates"))
        assert int(row["estimates"]) == len(reference.outputs) == len(written) > 0
        assert [m.topic for m in written] == [t for t, _, _ in reference.outputs]
    assert "corrupt" in (out / "summary.md").read_text() and (out / "summary.html").is_file()
    assert _digest(inputs) == before, "the input bags were modified"

    # second run: everything up to date or unchanged since it failed; no cluster is even started
    import terrain_analysis.batch.engine as engine

    def no_cluster(*_a: object, **_k: object) -> None:
        raise AssertionError("the second run started a cluster: something was not skipped")

    monkeypatch.setattr(engine, "Engine", no_cluster)
    status = batch.main([str(inputs), "-o", str(out), "--workers", "2"])
    assert status == EXIT_FINDING
    again = _rows(out)
    assert {r["status"] for b, r in again.items() if b != "day2/corrupt"} == {"skipped"}
    assert again["day2/corrupt"]["status"] == "failed"
    assert again["day2/corrupt"]["reason"].startswith("unchanged since it failed")
    for name in SHORT:  # the earlier figures are kept
        assert again[f"day1/{name}"]["estimates"] == rows[f"day1/{name}"]["estimates"]
    assert _digest(inputs) == before


def test_batch_refuses_an_output_directory_it_did_not_make_and_an_empty_input(tmp_path: Path) -> None:
    """Nothing is written into a foreign non-empty directory; no bag found is exit 2 (no cluster needed)."""
    from terrain_analysis.tools import batch

    foreign = tmp_path / "results"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    bag = tmp_path / "in" / SHORT[0]
    shutil.copytree(BAGS / SHORT[0], bag)
    assert batch.main([str(bag), "-o", str(foreign)]) == EXIT_INPUT
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert batch.main([str(empty), "-o", str(tmp_path / "out")]) == EXIT_INPUT
    assert not (tmp_path / "out").exists()
    # the output inside the input tree is refused (it would be read as input next time)
    assert batch.main([str(tmp_path / "in"), "-o", str(tmp_path / "in" / "out")]) == EXIT_INPUT
