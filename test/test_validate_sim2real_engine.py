"""validate-sim2real's diagnoses on the project's engine (issue 23): each bag isolated, failures recorded.

A real 2-worker Dask cluster (no mock) runs an isolated plan in which one job
raises: it comes back failed with its reason and the others finish; a job
that kills its worker is a failed result too, and the cluster goes on. Then
``diagnose_suite`` on the cluster over a small manifest: a bag already
diagnosed is taken from the earlier run (``--reuse``), bags whose diagnosis
fails (missing, unreadable) are recorded as errors with their reason, each
with its JSON, and the results come back in manifest order; the scorer joins
them with the labels.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from terrain_analysis.experiment import ExperimentError, Runner  # noqa: E402
from terrain_analysis.tools.validate_sim2real import diagnose_suite, score  # noqa: E402


def test_run_each_on_a_real_cluster_records_a_failing_job_and_finishes_the_others() -> None:
    plan = [4.0, -1.0, 9.0, 16.0]
    with Runner(2, what="roots", progress=False) as runner:
        assert runner.distributed
        runner.setup_workers(math.sqrt, 2.0)  # runs in every worker (a pool's initializer)
        found = dict(runner.run_each(math.sqrt, plan, key=str))
        assert sorted(found) == [0, 1, 2, 3]
        assert [found[i].value for i in (0, 2, 3)] == [2.0, 3.0, 4.0]
        assert not found[1].ok and found[1].error.startswith("ValueError") and "math domain" in found[1].error
        assert found[1].key == "1:-1.0" and found[1].traceback
        assert all(found[i].ok and found[i].worker for i in (0, 2, 3))
        with pytest.raises(ExperimentError, match=r"1 of 4 roots failed \(1:-1.0\): ValueError"):
            runner.map(math.sqrt, plan, key=str)
        ((i, died),) = runner.run_each(os._exit, [3])  # kills its worker (twice: allowed_failures=1)
        assert i == 0 and not died.ok and "KilledWorker" in died.error
        assert runner.map(math.sqrt, [1.0, 4.0]) == [1.0, 2.0]  # the nanny replaced the worker: the run goes on
    assert runner.n_tasks == 11


def _suite(tmp_path: Path) -> tuple[Path, Path]:
    suite = tmp_path / "suite"
    (suite / "bags" / "corrupt").mkdir(parents=True)
    (suite / "bags" / "corrupt" / "corrupt_0.mcap").write_bytes(b"not an mcap file")
    bags = [
        {"id": "done0", "vehicle": "quarter_car", "bag": "bags/done0"},
        {"id": "missing", "vehicle": "quarter_car", "bag": "bags/missing"},
        {"id": "corrupt", "vehicle": "quarter_car", "bag": "bags/corrupt"},
        {"id": "other", "vehicle": "lrv", "bag": "bags/other"},
    ]
    (suite / "manifest.json").write_text(json.dumps({"bags": bags}), encoding="utf-8")
    control = {"kind": "control", "scenario": {}}
    labels = {b["id"]: control for b in bags}
    (suite / "labels.json").write_text(json.dumps({"labels": labels}), encoding="utf-8")
    out = tmp_path / "diagnoses"
    out.mkdir()
    earlier = {
        "id": "done0",
        "vehicle": "quarter_car",
        "verdict": "no significant gap",
        "kind": "no_gap",
        "explained_by": [],
        "indistinguishable": [],
        "ranking": [],
        "best": None,
        "seconds": 1.0,
    }
    (out / "done0.json").write_text(json.dumps(earlier), encoding="utf-8")
    return suite, out


@pytest.mark.parametrize("jobs", [2, 1])
def test_diagnose_suite_on_the_engine_records_failing_bags_and_reuses_finished_ones(tmp_path: Path, jobs: int) -> None:
    suite, out = _suite(tmp_path)
    results = diagnose_suite(suite, out, jobs, ["quarter_car"], reuse=True)
    assert [r["id"] for r in results] == ["done0", "missing", "corrupt"]  # manifest order, lrv left out
    assert results[0]["kind"] == "no_gap" and results[0]["seconds"] == 1.0  # taken from the earlier run
    for r in results[1:]:
        assert r["kind"] == "error" and r["verdict"].startswith("error: BagError: ")
        assert r["id"] in r["verdict"] or "corrupt" in r["verdict"] or "missing" in r["verdict"]
        assert json.loads((out / f"{r['id']}.json").read_text(encoding="utf-8")) == r  # written, as --reuse needs
    assert not (out / "other.json").exists()
    assert diagnose_suite(suite, out, jobs, ["quarter_car"], reuse=True) == results  # all reused: no cluster
    scores = score(suite, results)
    assert scores["quarter_car"]["bags"] == 3 and scores["quarter_car"]["errors"] == 2
