"""The shared runner of the reproductions: a plan of independent jobs, run on the batch engine, results in order.

A reproduction is a plan (scenario × filters × seeds, one job per simulated
run), a function that runs one job, metrics and page text. This module runs
the plan; :mod:`terrain_analysis.reporting` writes the page.

Usage::

    from terrain_analysis.experiment import Runner

    with Runner(jobs=2, what="rides") as runner:           # jobs=1: in this process, no cluster
        results = runner.map(run_one, plan, weight=lambda spec: spec.duration)
    # results[i] is run_one(plan[i]); runner.wall_s, runner.cpu_s, runner.n_tasks for the page's header

What it guarantees:

* **the engine** — with ``jobs > 1`` (or a ``scheduler`` address) the jobs run
  on :class:`terrain_analysis.batch.engine.Engine` (Dask distributed: a local
  cluster of ``jobs`` single-threaded worker processes); with ``jobs == 1``
  they run one after another in this process (no cluster to start, the same
  code path as a debugger sees);
* **deterministic results** — ``map`` returns the results in the order of the
  plan whatever order the workers finish in; every job is independent and
  seeds itself, so the numbers do not depend on ``jobs``;
* **longest first** — jobs are submitted in decreasing ``weight`` (the tail of
  a run is not one long job on one worker);
* **progress** — a bar with an ETA weighted by ``weight`` on stderr
  (:class:`~terrain_analysis.batch.engine.Progress`);
* **no silent gaps** — a job that raises (or whose worker dies) fails the
  whole ``map`` with :class:`ExperimentError` naming every failed job and the
  first traceback: a results page is never written from part of its runs;
* **isolated plans** — :meth:`Runner.run_each` is the same plan with every
  job isolated instead: each job's result or failure (with its reason) as it
  finishes, the others going on (``validate-sim2real``: a bag whose diagnosis
  fails is a result to score);
* **worker set-up** — :meth:`Runner.setup_workers` runs a function once in
  every worker (a pool's ``initializer``: warm-ups, process-wide settings);
* **accounting** — wall time, and CPU time of this process plus that of every
  job in its worker (``time.process_time``), over every ``map`` of the runner.

Job functions and their arguments must be picklable (module-level functions
of an installed package, frozen dataclasses of plain values).

A whole reproduction command is a :class:`Reproduction`: counts → plan →
jobs on the runner → results → the paper-specific sections → the page
(:func:`terrain_analysis.reporting.write_page`); :func:`run_reproduction` is
its ``main``::

    REPRODUCTION = Reproduction(
        module="terrain_analysis.tools.reproduce_qc", page="quarter_car", what="simulated rides",
        runs_help=..., quick_help=..., counts=Counts, plan=build_plan, job=lambda counts: run_one,
        weight=lambda spec: spec.cost, key=lambda spec: f"{spec.key}-{spec.run}", collect=collect,
        sections=(case1, case2, ...), write=write_report,
    )

    main = reproduction_main(REPRODUCTION, "reproduce-qc", __doc__)
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from terrain_analysis.batch.engine import Engine, Progress, Task, TaskResult, run_isolated
from terrain_analysis.reporting import Provenance, Report, claims_table, reproduction_arguments
from terrain_estimation.cli import Main, cli_main

__all__ = [
    "ExperimentError",
    "Reproduction",
    "Runner",
    "print_claims",
    "reproduction_main",
    "run_plan",
    "run_reproduction",
]

S = TypeVar("S")
R = TypeVar("R")


class ExperimentError(RuntimeError):
    """One or more jobs of a plan failed (the message names them and shows the first traceback)."""


class Runner:
    """Runs plans of jobs on the batch engine (``jobs > 1``) or in this process (``jobs == 1``).

    Args:
        jobs: worker processes of the local cluster (≥ 1); 1 runs in this process.
        scheduler: address of a running Dask scheduler (``tcp://host:8786``) instead of a local cluster.
        what: what a job is, for the progress text ("rides", "runs").
        progress: draw the progress bar on stderr.

    Attributes:
        wall_s: wall seconds since the runner started.
        cpu_s: CPU seconds of this process since the runner started plus those of every job run in a worker.
        n_tasks: jobs run so far.
    """

    def __init__(self, jobs: int = 1, *, scheduler: str | None = None, what: str = "runs", progress: bool = True):
        if jobs < 1:
            raise ValueError(f"jobs must be >= 1, got {jobs}")
        self.jobs = jobs
        self.scheduler = scheduler
        self.what = what
        self.progress = progress
        self.n_tasks = 0
        self._engine: Engine | None = None
        self._worker_cpu = 0.0
        self._cpu0 = time.process_time()
        self._wall0 = time.monotonic()
        self._ended: tuple[float, float] | None = None

    @property
    def distributed(self) -> bool:
        """True when the jobs run on a cluster (``jobs > 1`` or a scheduler address)."""
        return self.jobs > 1 or self.scheduler is not None

    def __enter__(self) -> Runner:
        self._cpu0 = time.process_time()
        self._wall0 = time.monotonic()
        self._ended = None
        if self.distributed:
            self._engine = Engine(self.scheduler, workers=self.jobs).__enter__()
        return self

    def __exit__(self, *_exc: object) -> None:
        engine, self._engine = self._engine, None
        if engine is not None:
            engine.close()
        self._ended = (time.monotonic(), time.process_time())

    @property
    def wall_s(self) -> float:
        end = self._ended[0] if self._ended is not None else time.monotonic()
        return end - self._wall0

    @property
    def cpu_s(self) -> float:
        end = self._ended[1] if self._ended is not None else time.process_time()
        return end - self._cpu0 + self._worker_cpu

    @property
    def worker_cpu_s(self) -> float:
        """CPU seconds of the jobs run in workers (0 when they run in this process: they are in ``cpu_s``)."""
        return self._worker_cpu

    def setup_workers(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` once in every worker process before the plans (a pool's ``initializer``: imports,
        warm-ups, process-wide settings the jobs read); a worker restarted after a crash runs it again. Without a
        cluster (``jobs == 1``) it runs in this process.
        """
        if self._engine is None:
            if self.distributed:
                raise ExperimentError("the runner is not started: use it as a context manager")
            fn(*args)
        else:
            self._engine.setup_workers(fn, *args)

    def run_each(
        self,
        fn: Callable[[S], R],
        plan: Sequence[S],
        *,
        weight: Callable[[S], float] | None = None,
        key: Callable[[S], str] | None = None,
        what: str | None = None,
    ) -> Iterator[tuple[int, TaskResult[R]]]:
        """Every job of ``plan``, isolated, heaviest first: ``(its index in plan, its TaskResult)`` as each finishes.

        The batch engine's isolated mode: a job that raises, or whose worker dies, is a failed
        :class:`~terrain_analysis.batch.engine.TaskResult` with its reason, and the other jobs go on (for plans
        whose failures are results to report, one per bag). Arguments as for :meth:`map`.
        """
        weights = [float(weight(s)) if weight is not None else 1.0 for s in plan]
        keys = [f"{i}:{key(s)}" if key is not None else str(i) for i, s in enumerate(plan)]
        index = {k: i for i, k in enumerate(keys)}
        order = sorted(range(len(plan)), key=lambda i: -weights[i])  # stable: ties keep plan order
        bar = Progress(len(plan), what or self.what, total_weight=sum(weights) or None) if self.progress else None
        if self._engine is None:
            if self.distributed:
                raise ExperimentError("the runner is not started: use it as a context manager")
            for i in order:
                res = run_isolated(keys[i], fn, (plan[i],))
                self.n_tasks += 1
                if bar is not None:
                    bar.update(res.ok, weights[i], note="" if res.ok else f"FAILED {keys[i]}")
                yield i, res
        else:
            tasks = [Task(keys[i], fn, (plan[i],), weights[i] or 1.0) for i in order]
            for res in self._engine.run(tasks, progress=bar):
                self._worker_cpu += res.cpu_s
                self.n_tasks += 1
                yield index[res.key], res

    def map(
        self,
        fn: Callable[[S], R],
        plan: Sequence[S],
        *,
        weight: Callable[[S], float] | None = None,
        key: Callable[[S], str] | None = None,
        what: str | None = None,
    ) -> list[R]:
        """``[fn(job) for job in plan]``, run heaviest first on the engine; the results in plan order.

        Args:
            fn: a picklable module-level function of one job.
            plan: the jobs.
            weight: expected cost of a job (> 0; e.g. its simulated seconds) for the order and the ETA;
                default 1 for every job.
            key: a job's name in progress lines and failures (default: its index in the plan).
            what: overrides the runner's ``what`` for this plan.

        Raises:
            ExperimentError: a job raised, or its worker died.
        """
        results = dict(self.run_each(fn, plan, weight=weight, key=key, what=what))
        failed = [results[i] for i in range(len(plan)) if not results[i].ok]
        if failed:
            first = failed[0]
            raise ExperimentError(
                f"{len(failed)} of {len(plan)} {what or self.what} failed ({', '.join(r.key for r in failed[:10])}"
                f"{', …' if len(failed) > 10 else ''}): {first.error}\n{first.traceback}"
            )
        return [results[i].value for i in range(len(plan))]  # type: ignore[misc]


def run_plan(
    fn: Callable[[S], R],
    plan: Sequence[S],
    *,
    jobs: int = 1,
    weight: Callable[[S], float] | None = None,
    key: Callable[[S], str] | None = None,
    what: str = "runs",
    scheduler: str | None = None,
) -> tuple[list[R], Runner]:
    """One plan on its own runner: the results in plan order and the (closed) runner for its time accounting."""
    with Runner(jobs, scheduler=scheduler, what=what) as runner:
        results = runner.map(fn, plan, weight=weight, key=key)
    return results, runner


@dataclass(frozen=True)
class Reproduction:
    """A reproduction command as a description: what to run, how to reduce it, what to write.

    Attributes:
        module: the command's module (``python -m <module>``, shown in the page's header).
        page: the page's stem: ``<out>/<page>.md``, its figures in ``<out>/<page>/``.
        what: what a job is ("simulated rides").
        runs_help: ``--runs`` help text; quick_help: ``--quick`` help text.
        counts: the run counts' type: ``counts()`` the full run, ``counts.quick()`` the smoke run,
            ``c.with_runs(n)`` every count set to ``n``.
        plan: counts → the jobs (scenario × filters × seeds).
        job: counts → the picklable function of one job run on the workers.
        weight: a job's expected cost (its simulated seconds) for the order and the ETA.
        key: a job's name in progress lines and failures.
        collect: (plan, the jobs' results in plan order) → the results the sections read.
        sections: writers ``(report, results, counts)`` of the page's sections, in page order.
        write: ``(report, results, counts, provenance)`` → the page written (its header bullets, criteria
            and general causes: :func:`~terrain_analysis.reporting.write_page`).
    """

    module: str
    page: str
    what: str
    runs_help: str
    quick_help: str
    counts: Any
    plan: Callable[[Any], Sequence[Any]]
    job: Callable[[Any], Callable[[Any], Any]]
    weight: Callable[[Any], float]
    key: Callable[[Any], str]
    collect: Callable[[Sequence[Any], list[Any]], Any]
    sections: Sequence[Callable[[Report, Any, Any], None]]
    write: Callable[[Report, Any, Any, Provenance], Path]


def run_reproduction(spec: Reproduction, argv: Sequence[str] | None, doc: str | None) -> int:
    """The ``main`` of a reproduction command: options, plan, runs on the runner, sections, page; exit status.

    Options (:func:`~terrain_analysis.reporting.reproduction_arguments`): ``--runs``, ``--out`` (directory),
    ``--jobs`` (worker processes of a local cluster; 1 runs in this process), ``--scheduler`` (a running
    cluster instead), ``--quick``. The claim table is printed on stdout.
    """
    args, argv_list = reproduction_arguments(
        f"python -m {spec.module}",
        (doc or "").splitlines()[0] if doc else spec.module,
        argv,
        runs_help=spec.runs_help,
        quick_help=spec.quick_help,
    )
    counts = spec.counts.quick() if args.quick else spec.counts()
    if args.runs is not None:
        counts = counts.with_runs(args.runs)
    rep = Report.for_page(args.out, spec.page)
    plan = spec.plan(counts)
    name = spec.module.rpartition(".")[2]
    print(f"{name}: {len(plan)} {spec.what} on {args.jobs} process(es)", file=sys.stderr, flush=True)
    with Runner(args.jobs, scheduler=args.scheduler, what=spec.what) as runner:
        results = spec.collect(plan, runner.map(spec.job(counts), plan, weight=spec.weight, key=spec.key))
        for writer in spec.sections:
            writer(rep, results, counts)
        provenance = Provenance.of(spec.module, argv_list, runner, quick=args.quick)
    print_claims(rep, spec.write(rep, results, counts, provenance), provenance)
    return 0


def print_claims(rep: Report, path: Path, provenance: Provenance) -> None:
    """The end of a reproduction command: the claim table on stdout; the page written and the wall time on
    stderr."""
    print(claims_table(rep.rows))
    print(f"\nreport: {path} (wall time {provenance.wall_s:.0f} s)", file=sys.stderr)


def reproduction_main(spec: Reproduction, command: str, doc: str | None) -> Main:
    """A reproduction module's ``main(argv)``: :func:`run_reproduction` of ``spec`` with the project's exit
    statuses (:func:`terrain_estimation.cli.cli_main` named ``command``); ``doc``: the module's docstring."""

    def main(argv: Sequence[str] | None = None) -> int:
        """Command-line entry point; returns the exit status."""
        return run_reproduction(spec, argv, doc)

    return cli_main(command)(main)
