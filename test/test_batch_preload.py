"""The engine's local workers are forked from one forkserver that imported (and warmed) what
:func:`~terrain_analysis.batch.engine.preload_workers` named, with the environment a spawned worker gets.

The cluster test runs in a fresh interpreter: the forkserver lives as long as the process that started it,
so in the test session an earlier cluster's forkserver (started without these entries) would be reused.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

from terrain_analysis.batch.forkserver_preload import PRELOAD_ENV, run_preload


def test_run_preload_imports_calls_and_skips_what_fails() -> None:
    failed = run_preload("colorsys, math:nope, no_such_module_xyz, os.path:sep,  ,json")
    assert "colorsys" in sys.modules and "json" in sys.modules
    assert [f.split(":")[0] for f in failed] == ["math", "no_such_module_xyz", "os.path"]
    assert "AttributeError" in failed[0] and "ModuleNotFoundError" in failed[1] and "TypeError" in failed[2]
    assert run_preload("") == []


_CHILD = textwrap.dedent(
    """
    import json, os, sys
    from terrain_analysis.batch.engine import Engine, preload_workers

    def probe(_i):
        return {
            "pid": os.getpid(),
            "colorsys": "colorsys" in sys.modules,
            "hashseed": os.environ.get("PYTHONHASHSEED"),
            "omp": os.environ.get("OMP_NUM_THREADS"),
        }

    if __name__ == "__main__":
        preload_workers("colorsys", "no_such_module_xyz", "math:nope")  # the failing entries are skipped
        with Engine(workers=2) as engine:
            results = engine.map(probe, [(i,) for i in range(4)])
        print(json.dumps({"ok": [r.ok for r in results], "values": [r.value for r in results],
                          "env_left": os.environ.get("PRELOAD_ENV")}))
    """
).replace("PRELOAD_ENV", PRELOAD_ENV)


def test_local_workers_start_from_the_preloaded_forkserver(tmp_path) -> None:
    script = tmp_path / "child.py"
    script.write_text(_CHILD)
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["ok"] == [True] * 4
    values = out["values"]
    # Every task ran in a worker forked after the forkserver imported the preloaded module ...
    assert all(v["colorsys"] for v in values)
    assert len({v["pid"] for v in values}) <= 2
    # ... with the environment Dask's nanny gives a spawned worker, and the client's environment restored.
    assert {v["hashseed"] for v in values} == {"6640"} and {v["omp"] for v in values} == {"1"}
    assert out["env_left"] is None
