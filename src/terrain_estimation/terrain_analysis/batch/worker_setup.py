"""A function run once in every worker process of a cluster, including workers that join later.

The engine's counterpart of a ``multiprocessing.Pool``'s ``initializer``
(:meth:`terrain_analysis.batch.engine.Engine.setup_workers`): a Dask worker
plugin, so that a worker the nanny restarts after a crash runs it too before
its next task. Imported only once a cluster runs (it imports ``distributed``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

__all__ = ["SetupPlugin"]


class SetupPlugin(WorkerPlugin):
    """Calls ``fn(*args)`` when attached to a worker (picklable: a module-level ``fn`` and plain ``args``)."""

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self.fn = fn
        self.args = args

    def setup(self, worker: Any) -> None:
        self.fn(*self.args)
