"""What every section of the benchmark (:mod:`terrain_analysis.tools.bench`) shares.

The run's size (:class:`BenchConfig`), the machine's description, percentiles of per-step times, a bag's
duration, the speed rows (simulated or recorded seconds over wall seconds) with their table, and a row measured
in a fresh process (:func:`run_in_fresh_process`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing
import os
import platform
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "BAGS_DIR",
    "DT",
    "SUBSTEPS",
    "BenchConfig",
    "FilterProxy",
    "bag_duration_s",
    "machine_info",
    "percentiles_us",
    "run_in_fresh_process",
    "speed_fields",
    "speed_table",
]

DT = 0.01  # filter step (s): 100 Hz, the estimator's rate
SUBSTEPS = 10  # 1 kHz road sub-steps per step (MODELS.md A.10)
BAGS_DIR = Path(__file__).resolve().parents[4] / "bags"  # the repository's bags/


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """How much to measure.

    Attributes:
        steps: timed filter steps per filter (after the warm-up).
        warmup: untimed filter steps first (caches, branch predictors, lazy imports).
        drive_s: simulated drive (s) of the core and simulator rows.
        repeats: timed repetitions of each bag run (the median is reported).
        seed: seed of the simulated drives.
    """

    steps: int = 2000
    warmup: int = 200
    drive_s: float = 10.0
    repeats: int = 3
    seed: int = 12

    @classmethod
    def quick(cls) -> BenchConfig:
        return cls(steps=200, warmup=20, drive_s=2.0, repeats=1)


class FilterProxy:
    """Stands in for a filter inside an estimator: delegates to ``inner`` (``initial_state`` untimed); the
    sections' subclasses time the calls they wrap."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def initial_state(self, x0: Any, P0: Any) -> Any:  # noqa: N803
        return self.inner.initial_state(x0, P0)


def machine_info() -> dict[str, Any]:
    """CPU count, platform, Python, numpy and BLAS thread settings."""
    load: float | None
    try:
        load = os.getloadavg()[0]  # other processes share the CPUs: p90s grow with it
    except (AttributeError, OSError):  # not on every platform
        load = None
    return {
        "cpu_count": os.cpu_count(),
        "load_avg_1min": load,
        "platform": f"{platform.system()} {platform.machine()}",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "unset"),
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "unset"),
    }


def percentiles_us(samples_ns: Sequence[int]) -> tuple[float, float]:
    """(median, 90th percentile) in µs of per-step times in ns."""
    arr = np.asarray(samples_ns, dtype=float) * 1e-3
    return float(np.median(arr)), float(np.percentile(arr, 90))


def bag_duration_s(path: Path) -> tuple[float, int]:
    """(last − first log stamp (s), message count) of a bag."""
    from terrain_estimation.bag import read_bag

    first = last = None
    count = 0
    for item in read_bag(path):
        first = item.log_time_ns if first is None else min(first, item.log_time_ns)
        last = item.log_time_ns if last is None else max(last, item.log_time_ns)
        count += 1
    if first is None or last is None:
        return 0.0, 0
    return (last - first) * 1e-9, count


def speed_fields(sim_s: float, wall_s: float, steps: int) -> dict[str, Any]:
    """The figures of a speed row: simulated (or recorded) and wall seconds, the multiple of real time, the steps
    and the wall µs per step."""
    return {
        "sim_s": sim_s,
        "wall_s": wall_s,
        "x_real_time": sim_s / wall_s if wall_s > 0 else math.inf,
        "steps": steps,
        "us_per_step": 1e6 * wall_s / steps if steps else math.nan,
    }


def speed_table(title: str, rows: Sequence[dict[str, Any]], *, filter_column: bool) -> list[str]:
    """A speed table of the readable report: its title, header and one line per row; ``filter_column``: with the
    time of the filter step inside each row (``-`` for a row without it)."""
    header = f"  {'what':<44}{'sim s':>7}{'wall s':>9}{'× real time':>13}{'µs/step':>10}"
    lines = [title, header + (f"{'filter µs/step':>16}" if filter_column else "")]
    for r in rows:
        line = (
            f"  {r['row']:<44}{r['sim_s']:>7.2f}{r['wall_s']:>9.3f}{r['x_real_time']:>13.1f}{r['us_per_step']:>10.0f}"
        )
        if filter_column:
            filt = (
                f"{r['filter_us_per_step']:.0f} ({100 * r['filter_share']:.0f} %)" if "filter_us_per_step" in r else "-"
            )
            line += f"{filt:>16}"
        lines.append(line)
    return lines


def add_json_arguments(parser: argparse.ArgumentParser) -> None:
    """``--json PATH`` and ``--overwrite``: the benchmarks' figures as a JSON file, never over a user's file."""
    parser.add_argument("--json", metavar="PATH", help="also write every figure to this JSON file (a new file)")
    parser.add_argument("--overwrite", action="store_true", help="--json may replace an existing regular file")


def parse_bench_arguments(parser: argparse.ArgumentParser, argv: Sequence[str] | None) -> argparse.Namespace:
    """Parse a benchmark's command line (with :func:`add_json_arguments`); a ``--json`` path that would be refused
    is refused now, before the run, not after it."""
    from terrain_estimation.outputs import check_output_path

    args = parser.parse_args(argv)
    if args.json:
        check_output_path(args.json, overwrite=args.overwrite, kind="file")
    return args


def write_json(path: str | os.PathLike[str], figures: Any, *, overwrite: bool = False) -> Path:
    """Write ``figures`` to ``path``: refused (nothing written) where something exists and ``overwrite`` is not
    given, and where the path is a directory (:func:`terrain_estimation.outputs.check_output_path`)."""
    from terrain_estimation.outputs import check_output_path

    out = check_output_path(path, overwrite=overwrite, kind="file")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(figures, indent=2) + "\n")
    return out


def _fresh_child(conn: Any, fn: Callable[..., dict[str, Any]], args: tuple[Any, ...], error_key: str) -> None:
    try:
        conn.send(fn(*args))
    except Exception as exc:  # a bench row, not a crash
        conn.send({error_key: f"{type(exc).__name__}: {exc}"})
    finally:
        conn.close()


def run_in_fresh_process(
    fn: Callable[..., dict[str, Any]], args: tuple[Any, ...], *, error_key: str, what: str
) -> dict[str, Any]:
    """The row ``fn(*args)`` computed in a fresh (spawned) process: nothing of this process's imports, caches or
    heap in its figures. ``fn`` (module level, picklable, as its arguments) returns the row; where it raises, the
    row is ``{error_key: "<exception type>: <message>"}``, and where the process dies, ``{error_key: "the <what>
    process died (exit code <n>)"}``."""
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_fresh_child, args=(child, fn, args, error_key))
    proc.start()
    child.close()
    try:
        row: dict[str, Any] = parent.recv()
    except EOFError:
        row = {error_key: f"the {what} process died (exit code {proc.exitcode})"}
    proc.join()
    return row
