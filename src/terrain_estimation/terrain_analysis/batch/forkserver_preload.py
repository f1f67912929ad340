"""What the forkserver of a local cluster imports (and runs) once, before it forks the workers.

:class:`terrain_analysis.batch.engine.Engine` starts the workers of a local
cluster from a forkserver (a clean process that Python's ``multiprocessing``
starts once per client process and forks every worker from). The forkserver
imports this module; the entries of :func:`~terrain_analysis.batch.engine.preload_workers`
reach it through the environment variable :data:`PRELOAD_ENV`: ``module`` (imported)
or ``module:function`` (imported, then ``function()`` called: a warm-up, e.g. loading
a compiled filter step from numba's cache). Every worker forked afterwards starts
with them done: the workers' imports and compilation are paid once, not once per
worker.

Only an optimisation: an entry that fails is skipped here (the forkserver must
not die) and done again, with its error reported, by the worker set-up
(:meth:`~terrain_analysis.batch.engine.Engine.setup_workers`) that the callers
keep. Importing this module outside a forkserver with the variable unset does
nothing.
"""

from __future__ import annotations

import importlib
import os

__all__ = ["PRELOAD_ENV", "run_preload"]

PRELOAD_ENV = "TERRAIN_ANALYSIS_WORKER_PRELOAD"
"""Comma-separated ``module`` or ``module:function`` entries."""


def run_preload(spec: str) -> list[str]:
    """Import (and call) every entry of ``spec``; the entries that failed, as ``"entry: error"``."""
    failed = []
    for entry in filter(None, (e.strip() for e in spec.split(","))):
        module, _, function = entry.partition(":")
        try:
            loaded = importlib.import_module(module)
            if function:
                getattr(loaded, function)()
        except Exception as exc:  # an optimisation only: the worker set-up redoes it and reports the error
            failed.append(f"{entry}: {type(exc).__name__}: {exc}")
    return failed


run_preload(os.environ.get(PRELOAD_ENV, ""))
