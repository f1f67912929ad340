"""A small API over Dask distributed: map a function over tasks, isolated, with progress and results.

Why Dask distributed (not Ray, not a home-made pool): see the ``batch_engine``
section of ``docs/results/performance.md`` (``python -m
terrain_analysis.tools.batch_engine_choice``): about a sixth of Ray's install
size, a faster local start-up, and a plain scheduler/worker pair over TCP that
runs a cluster from ssh, SLURM or Kubernetes alike.

Usage (any long job of the project)::

    from terrain_analysis.batch.engine import Engine, Task

    tasks = [Task(key=f"run-{i}", fn=simulate_one, args=(seed,), weight=1.0) for i, seed in enumerate(seeds)]
    with Engine(workers=2) as engine:                    # or Engine(scheduler="tcp://host:8786")
        for result in engine.run(tasks, progress=Progress(len(tasks), "rides")):
            if result.ok: use(result.value)
            else: print(result.key, result.error)       # the others go on

What the engine guarantees:

* **isolation** — each task runs through :func:`run_isolated` in a worker: an
  exception becomes a failed :class:`TaskResult` (type, message, traceback);
  a worker process that dies under a task (a crash, the memory limit) is
  replaced by the nanny and the task is reported failed after
  ``allowed_failures`` deaths, never retried forever;
* **accounting** — CPU time (``time.process_time`` of the worker process, so
  numba's and numpy's threads count) and wall time of each task, and the
  worker that ran it;
* **progress** — :class:`Progress` draws a bar with an ETA on stderr
  (weighted by each task's ``weight``, e.g. its bag size), or prints plain
  lines when stderr is not a terminal;
* **local default** — a :class:`distributed.LocalCluster` of one
  single-threaded worker *process* per core (the estimators hold the GIL),
  its dashboard on a free port, BLAS/OpenMP threads pinned to 1 by Dask's
  nanny, and each worker given one task at a time (so that a worker dying
  under a task blames that task only);
* **warm workers** — where Python has the ``forkserver`` start method
  (Linux, macOS), the local workers are forked from a forkserver that
  imported ``distributed`` once and anything :func:`preload_workers` named
  (``"terrain_analysis.tools.qc_runs"``, or a warm-up such as
  ``"terrain_estimation.estimators.soil_stiffness_sckf:warm_up"``), so that
  the imports and numba's compilation or cache loads are paid once per
  client process, not once per worker (nor again for the next cluster).
  The forkserver starts with the environment Dask's nanny gives a spawned
  worker (``OMP_NUM_THREADS=1``, ``PYTHONHASHSEED``, ...): a forked worker
  computes what a spawned one does. :meth:`Engine.setup_workers` stays the
  guarantee (a preload entry that fails is only skipped).

Functions and their arguments must be picklable (module-level functions of an
installed package: the workers import them by name); on a remote cluster the
workers need the same packages and see the same paths.
"""

from __future__ import annotations

import logging
import os
import socket
import sys
import time
import traceback
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import IO, Any, Generic, TypeVar

__all__ = [
    "Engine",
    "EngineError",
    "Progress",
    "Task",
    "TaskResult",
    "map_isolated",
    "preload_workers",
    "run_isolated",
]

T = TypeVar("T")

_preload: tuple[str, ...] = ()


def preload_workers(*entries: str) -> None:
    """What the forkserver of this process's local clusters imports before it forks their workers.

    Each entry is ``"module"`` (imported) or ``"module:function"`` (imported, then ``function()`` called
    without arguments: a warm-up). Effective for the first local cluster this process starts (the
    forkserver lives as long as the process and keeps what it imported); later calls only matter once a
    forkserver has to be started again. A speed-up only: the workers' set-up
    (:meth:`Engine.setup_workers`) must still import what the tasks need.
    """
    global _preload
    _preload = tuple(entries)


def _forkserver_workers() -> Callable[[], None] | None:
    """Local clusters fork their workers from a warm forkserver (module docstring); returns the function that
    undoes the environment set for the forkserver's start once the cluster runs (None: no forkserver here)."""
    import multiprocessing

    import dask
    from distributed.utils import get_mp_context

    from terrain_analysis.batch.forkserver_preload import PRELOAD_ENV

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return None
    dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"})
    # Dask's own preload list first (it sets it once per process), then ours: distributed and the entries,
    # which reach the forkserver through its environment (it starts with the nanny's first worker).
    get_mp_context().set_forkserver_preload(["distributed", "terrain_analysis.batch.forkserver_preload"])
    before = os.environ.get(PRELOAD_ENV)
    os.environ[PRELOAD_ENV] = ",".join(_preload)

    def restore() -> None:
        if before is None:
            os.environ.pop(PRELOAD_ENV, None)
        else:
            os.environ[PRELOAD_ENV] = before

    return restore


class EngineError(RuntimeError):
    """The cluster cannot be started or reached (the message names the address)."""


@dataclass(frozen=True)
class Task:
    """One unit of work.

    Attributes:
        key: unique name of the task in the run (a bag's relative path, ``"seed-17"``); shown in progress
            and failures.
        fn: a picklable module-level function.
        args: its positional arguments (picklable).
        weight: expected cost, > 0, in any unit shared by the run's tasks (bytes of bag, seconds of
            simulation); used for the ETA only.
    """

    key: str
    fn: Callable[..., Any]
    args: tuple[Any, ...] = ()
    weight: float = 1.0


@dataclass
class TaskResult(Generic[T]):
    """What one task gave: its value, or why it failed.

    Attributes:
        key: the task's key.
        ok: True when ``fn`` returned.
        value: what ``fn`` returned (None on failure).
        error: ``"ExceptionType: message"`` on failure ("" when ok).
        traceback: the formatted traceback on failure ("" when ok, or when the worker died).
        cpu_s: CPU seconds of the worker process during the task (all its threads); 0 when the worker died.
        wall_s: wall seconds of the task in the worker.
        worker: ``host:pid`` of the worker process that ran it.
    """

    key: str
    ok: bool
    value: T | None = None
    error: str = ""
    traceback: str = ""
    cpu_s: float = 0.0
    wall_s: float = 0.0
    worker: str = ""


def run_isolated(key: str, fn: Callable[..., T], args: tuple[Any, ...]) -> TaskResult[T]:
    """Run ``fn(*args)`` in this process and return a :class:`TaskResult`; never raises an ``Exception``.

    Executed in the worker, so that a task's exception is data (with its
    traceback) rather than a failed future. ``KeyboardInterrupt`` and
    ``SystemExit`` still propagate.
    """
    worker = f"{socket.gethostname()}:{os.getpid()}"
    cpu0, wall0 = time.process_time(), time.perf_counter()
    try:
        value = fn(*args)
    except Exception as exc:  # isolation is the point: every failure is recorded, none stops the run
        return TaskResult(
            key,
            False,
            error=f"{type(exc).__name__}: {exc}",
            traceback=traceback.format_exc(),
            cpu_s=time.process_time() - cpu0,
            wall_s=time.perf_counter() - wall0,
            worker=worker,
        )
    return TaskResult(
        key, True, value, cpu_s=time.process_time() - cpu0, wall_s=time.perf_counter() - wall0, worker=worker
    )


def _clock(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m:02d}:{s:02d}"


@dataclass
class Progress:
    """A progress bar with an ETA on ``stream`` (stderr); plain lines when it is not a terminal.

    The ETA is the elapsed time scaled by the weight still to do over the
    weight done (``Task.weight``: bytes of bag make a fair ETA for bags of
    mixed lengths).

    Attributes:
        total: the number of tasks (≥ 0).
        what: what a task is, for the text ("bags").
        total_weight: the sum of the tasks' weights (> 0), or None to count tasks.
        stream: where to draw (default ``sys.stderr``).
        width: bar width in characters (10-80).
        every_s: plain-line mode: at most one line per this many seconds, besides failures and the last.
    """

    total: int
    what: str = "tasks"
    total_weight: float | None = None
    stream: IO[str] | None = None
    width: int = 30
    every_s: float = 5.0
    done: int = 0
    failed: int = 0
    weight_done: float = 0.0
    started: float = field(default_factory=time.monotonic)
    _last_line: float = 0.0

    def _out(self) -> IO[str]:
        return self.stream if self.stream is not None else sys.stderr

    @property
    def is_tty(self) -> bool:
        isatty = getattr(self._out(), "isatty", None)
        return bool(isatty()) if callable(isatty) else False

    def eta(self) -> float | None:
        """Seconds left, or None before the first task ends."""
        elapsed = time.monotonic() - self.started
        if self.total_weight:
            if self.weight_done <= 0:
                return None
            return elapsed * max(self.total_weight - self.weight_done, 0.0) / self.weight_done
        if self.done == 0:
            return None
        return elapsed * (self.total - self.done) / self.done

    def line(self, note: str = "") -> str:
        frac = self.done / self.total if self.total else 1.0
        filled = int(round(frac * self.width))
        eta = self.eta()
        text = (
            f"[{'#' * filled}{'.' * (self.width - filled)}] {self.done}/{self.total} {self.what}"
            f" ({self.failed} failed) {_clock(time.monotonic() - self.started)} elapsed, "
            f"ETA {_clock(eta) if eta is not None else '--:--'}"
        )
        return f"{text}  {note}" if note else text

    def update(self, ok: bool, weight: float = 1.0, note: str = "") -> None:
        """Count one finished task and redraw."""
        self.done += 1
        self.failed += 0 if ok else 1
        self.weight_done += weight
        out = self._out()
        if self.is_tty:
            shown = self.line(note[:60])
            out.write("\r" + shown + " " * max(0, 110 - len(shown)))
            if self.done >= self.total:
                out.write("\n")
        else:
            now = time.monotonic()
            if not ok or self.done >= self.total or now - self._last_line >= self.every_s:
                self._last_line = now
                out.write(self.line(note) + "\n")
        out.flush()


class Engine:
    """A Dask distributed client: a local cluster of worker processes, or a running cluster.

    Args:
        scheduler: address of a running scheduler (``tcp://host:8786``, or a scheduler-file path ending in
            ``.json``); None starts a local cluster.
        workers: local cluster only: worker processes (1-1024; default: one per core, ``os.cpu_count()``).
        memory_limit: local cluster only: per-worker memory limit (Dask syntax, ``"2GiB"``; default
            ``"auto"``: the machine's memory shared equally). A worker over it is restarted and its task
            reported failed.
        allowed_failures: worker deaths a task may cause before it is reported failed (0-10; default 1:
            a bag that kills its worker is tried once more on a fresh one). Local cluster only: a running
            cluster's scheduler keeps its own setting.
        quiet: silence the cluster's own log lines below ERROR.

    Raises:
        EngineError: ``distributed`` is not installed, the scheduler cannot be reached, or a parameter is out
            of range.
    """

    def __init__(
        self,
        scheduler: str | None = None,
        *,
        workers: int | None = None,
        memory_limit: str = "auto",
        allowed_failures: int = 1,
        quiet: bool = True,
    ) -> None:
        if workers is not None and not 1 <= workers <= 1024:
            raise EngineError(f"workers must be in [1, 1024], got {workers}")
        if not 0 <= allowed_failures <= 10:
            raise EngineError(f"allowed_failures must be in [0, 10], got {allowed_failures}")
        self.scheduler = scheduler
        self.n_local = workers if workers is not None else (os.cpu_count() or 1)
        self.memory_limit = memory_limit
        self.allowed_failures = allowed_failures
        self.quiet = quiet
        self._cluster: Any = None
        self._client: Any = None

    def __enter__(self) -> Engine:
        try:
            import dask
            import distributed
        except ImportError as exc:
            raise EngineError(
                f"the batch engine needs Dask distributed ({exc}): pip install -c constraints.txt distributed"
            ) from exc
        level = logging.ERROR if self.quiet else logging.WARNING
        # A worker that dies takes the blame to every task it holds: with a saturation of 1.0 it holds only the
        # one it runs (the scheduler queues the rest), so a crashing bag never fails an innocent one.
        dask.config.set(
            {
                "distributed.scheduler.allowed-failures": self.allowed_failures,
                "distributed.scheduler.worker-saturation": 1.0,
            }
        )
        try:
            if self.scheduler is None:
                restore = _forkserver_workers()
                try:
                    self._cluster = distributed.LocalCluster(
                        n_workers=self.n_local,
                        threads_per_worker=1,
                        processes=True,
                        memory_limit=self.memory_limit,
                        dashboard_address=":0",  # any free port: never a clash with another cluster's 8787
                        silence_logs=level,
                    )
                finally:
                    if restore is not None:
                        restore()
                self._client = distributed.Client(self._cluster)
            elif self.scheduler.endswith(".json"):
                self._client = distributed.Client(scheduler_file=self.scheduler, timeout="30s")
            else:
                self._client = distributed.Client(self.scheduler, timeout="30s")
        except (OSError, TimeoutError) as exc:
            self.close()
            where = self.scheduler or "a local cluster"
            raise EngineError(f"cannot start or reach {where}: {type(exc).__name__}: {exc}") from exc
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the client, and the local cluster if this engine started it (never a remote one)."""
        client, cluster = self._client, self._cluster
        self._client = self._cluster = None
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()

    @property
    def client(self) -> Any:
        if self._client is None:
            raise EngineError("the engine is not started: use it as a context manager")
        return self._client

    @property
    def address(self) -> str:
        """The scheduler's address."""
        return str(self.client.scheduler.address)

    def n_workers(self) -> int:
        """Workers connected to the scheduler now."""
        return len(self.client.scheduler_info().get("workers", {}))

    def wait_for_workers(self, n: int = 1, timeout_s: float = 60.0) -> None:
        """Block until ``n`` workers are connected (a running cluster may still be starting them)."""
        try:
            self.client.wait_for_workers(n, timeout=timeout_s)
        except TimeoutError as exc:
            raise EngineError(
                f"{self.address}: {self.n_workers()} worker(s) after {timeout_s:g} s, {n} wanted"
            ) from exc

    def setup_workers(self, fn: Callable[..., Any], *args: Any, name: str = "setup") -> None:
        """Run ``fn(*args)`` once in every worker process, now and in any worker that joins later.

        The ``initializer`` of a ``multiprocessing.Pool``: imports and warm-ups before the first task, process-wide
        settings the tasks read. A worker the nanny restarts after a crash runs it again before its next task.
        A second call with the same ``name`` replaces the first (and runs on every worker again).

        Raises:
            Exception: what ``fn`` raised in a worker.
        """
        from terrain_analysis.batch.worker_setup import SetupPlugin

        self.client.register_plugin(SetupPlugin(fn, tuple(args)), name=f"terrain-analysis-{name}")

    def run(
        self,
        tasks: Sequence[Task],
        *,
        progress: Progress | None = None,
        failed: Callable[[TaskResult[Any]], bool] | None = None,
    ) -> Iterator[TaskResult[Any]]:
        """Run every task on the cluster; yield each :class:`TaskResult` as it completes (any order).

        A task whose worker died ``allowed_failures + 1`` times (a crash, the memory limit) is yielded failed
        with the scheduler's reason; the other tasks go on. ``failed`` tells the progress bar which results
        count as failures besides ``not ok`` (a task that returns its own failure record).
        """
        import distributed

        keys = [t.key for t in tasks]
        if len(set(keys)) != len(keys):
            raise EngineError("task keys must be unique in a run")
        weights = {t.key: t.weight for t in tasks}
        # Dask keys unique to this run: a key of an earlier run (another plan's "0") may still be known to the
        # scheduler, with that run's result or failure.
        run_id = uuid.uuid4().hex[:12]
        futures = {}
        for t in tasks:
            fut = self.client.submit(run_isolated, t.key, t.fn, t.args, key=f"task-{run_id}-{t.key}", pure=False)
            futures[fut] = t.key
        for fut in distributed.as_completed(list(futures)):
            key = futures[fut]
            try:
                result: TaskResult[Any] = fut.result()
            except Exception as exc:  # the task never returned: its worker died (KilledWorker), or it was cancelled
                result = TaskResult(key, False, error=f"{type(exc).__name__}: {exc}")
            fut.release()
            if progress is not None:
                bad = not result.ok or (failed is not None and failed(result))
                progress.update(not bad, weights[key], note=f"FAILED {key}" if bad else "")
            yield result

    def map(
        self, fn: Callable[..., T], args: Iterable[tuple[Any, ...]], *, progress: Progress | None = None
    ) -> list[TaskResult[T]]:
        """``fn(*a)`` for every ``a`` of ``args``, isolated; the results in the order of ``args``."""
        tasks = [Task(str(i), fn, tuple(a)) for i, a in enumerate(args)]
        found = {r.key: r for r in self.run(tasks, progress=progress)}
        return [found[t.key] for t in tasks]


def map_isolated(
    fn: Callable[..., T],
    args: Iterable[tuple[Any, ...]],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    what: str = "tasks",
) -> list[TaskResult[T]]:
    """One call for a long job: start an :class:`Engine`, map ``fn`` over ``args`` with a progress bar, stop.

    The replacement for a ``multiprocessing.Pool.imap_unordered`` loop: results in the order of ``args``,
    each with its CPU time and its failure, if any.
    """
    items = [tuple(a) for a in args]
    with Engine(scheduler, workers=workers) as engine:
        return engine.map(fn, items, progress=Progress(len(items), what))
