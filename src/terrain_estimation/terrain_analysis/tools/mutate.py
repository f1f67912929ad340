"""``python -m terrain_analysis.tools.mutate``: damage a bag every way a robot or a person can, run the tools.

A table of mutations — values, units, signs, frames, types, stamps, gaps,
bytes, metadata, truncation, missing topics, namespaces, output paths — is
applied to a recorded bag (with rosbags alone: the damage does not go through
the project's own reader or writer). Each damaged bag is given to both
offline tools, ``terrain-estimate`` and ``terrain-sim2real``, in-process, and
each run is held to what must happen:

* the exit status (``terrain_estimation.cli``: 0 ok, 1 a gap found, 2 the
  input cannot be used, 3 internal error — never 3) and a message that names
  the damage (a rejection reason in the summary, or the error);
* nothing non-finite in any bag or JSON the tools write;
* no input file or directory modified or removed (every file hashed before and
  after).

``--out DIR`` keeps the damaged bags and outputs (a new directory); the table
goes to stdout as Markdown. Exit status 0 when every row behaves as expected,
1 when one does not.

The cases and the damage are :mod:`~terrain_analysis.tools.mutations`; this
module runs the tools on each damaged bag and holds them to the rules.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import math
import os
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from terrain_analysis.tools.mutations import MUTATIONS, SAME, Case, Expect, damage

__all__ = ["Case", "Expect", "Outcome", "MUTATIONS", "damage", "run_case", "tree_digest", "main"]


def tree_digest(path: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every file under ``path`` (or of the file), directories as ``<dir>``."""
    if path.is_file():
        return {path.name: hashlib.sha256(path.read_bytes()).hexdigest()}
    out: dict[str, str] = {}
    for p in sorted(path.rglob("*")):
        rel = str(p.relative_to(path))
        out[rel] = "<dir>" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@dataclass
class ToolRun:
    """One tool's run on a damaged bag."""

    status: int
    stdout: str
    stderr: str
    seconds: float

    @property
    def text(self) -> str:
        return self.stdout + "\n" + self.stderr

    def headline(self) -> str:
        """The line that says most about the run: the error, a rejection, or the result."""
        for line in self.stderr.splitlines():
            if ": error: " in line or "internal error" in line:
                return line.split(": error: ", 1)[-1].strip()
        for line in self.stdout.splitlines():
            if line.strip().startswith("rejected") or "not decode" in line:
                return line.strip()
        for line in reversed(self.stdout.splitlines()):
            if line.startswith(("wrote", "verdict")):
                return line.strip()
        return (self.stdout.strip().splitlines() or [""])[-1]


def _run_tool(main: Callable[[Sequence[str]], int], argv: Sequence[str]) -> ToolRun:
    out, err = io.StringIO(), io.StringIO()
    started = time.monotonic()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(list(argv))
        except SystemExit as exc:  # argparse
            status = int(exc.code or 0)
        except Exception:  # a tool that lets an exception out: an internal error, and the table goes on
            traceback.print_exc()
            print("uncaught exception: internal error", file=sys.stderr)
            status = 3
    return ToolRun(status, out.getvalue(), err.getvalue(), time.monotonic() - started)


def nonfinite_in_outputs(path: Path) -> list[str]:
    """Where a bag or JSON under ``path`` holds a non-finite number (bags decoded with the definitions they carry)."""
    found: list[str] = []
    if not path.exists():
        return found
    for meta in sorted(path.rglob("metadata.yaml")):
        from rosbags.highlevel import AnyReader

        with AnyReader([meta.parent]) as reader:
            for conn, _t, raw in reader.messages():
                msg = reader.deserialize(raw, conn.msgtype)
                bad = _first_nonfinite(msg)
                if bad is not None:
                    found.append(f"{conn.topic}: {bad}")
                    break
    for js in sorted(path.rglob("*.json")):
        bad = _first_nonfinite(json.loads(js.read_text(), parse_constant=lambda c: float(c)))
        if bad is not None:
            found.append(f"{js.name}: {bad}")
    return found


def _first_nonfinite(obj: Any, path: str = "") -> str | None:
    import numpy as np

    if isinstance(obj, float):
        return None if math.isfinite(obj) else f"{path} = {obj}"
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f" and not np.all(np.isfinite(obj)):
            return f"{path}[{int(np.flatnonzero(~np.isfinite(obj))[0])}]"
        return None
    if isinstance(obj, dict):
        items: Any = obj.items()
    elif isinstance(obj, (list, tuple)):
        items = enumerate(obj)
    elif hasattr(obj, "__dataclass_fields__"):
        items = ((k, getattr(obj, k)) for k in obj.__dataclass_fields__)
    else:
        return None
    for key, value in items:
        bad = _first_nonfinite(value, f"{path}.{key}" if path else str(key))
        if bad is not None:
            return bad
    return None


@dataclass
class Outcome:
    """A case's result: both tools' runs, and whether every rule held."""

    case: Case
    vehicle: str
    estimate: ToolRun
    sim2real: ToolRun | None
    input_unchanged: bool
    nonfinite: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def _check(tool: str, run: ToolRun, expect: Expect, clean_status: int | None) -> list[str]:
    """What ``run`` did against ``expect``; ``clean_status`` None: this is the reference run (SAME is what it did)."""
    allowed = {(run.status if clean_status is None else clean_status) if s == SAME else s for s in expect.statuses}
    problems = []
    if run.status not in allowed:
        problems.append(f"{tool} exited {run.status}, expected {' or '.join(str(s) for s in sorted(allowed, key=str))}")
    if run.status == 3:
        problems.append(f"{tool} hit an internal error")
    if expect.text and expect.text.lower() not in run.text.lower():
        problems.append(f"{tool} did not say {expect.text!r}")
    return problems


def run_case(
    case: Case,
    vehicle: str,
    source: Path,
    workdir: Path,
    *,
    clean_status: tuple[int | None, int | None] = (None, None),
    sim2real: bool = True,
) -> Outcome:
    """Damage ``source`` by ``case`` in ``workdir`` (a new directory), run both tools, check the rules.

    Args:
        clean_status: both tools' exit statuses on the undamaged bag (what SAME means); None:
            this is the undamaged bag's run.
        sim2real: run terrain-sim2real too.
    """
    from terrain_analysis.tools import sim2real as sim2real_tool
    from terrain_estimation.tools import estimate as estimate_tool
    from terrain_estimation.vehicles import estimator_parameters, get_vehicle

    entry = get_vehicle(vehicle)
    adapter = entry.make_adapter(estimator_parameters(entry), entry.namespace)
    accel = next(s.topic for s in adapter.inputs if s.gravity_fields)
    workdir.mkdir(parents=True)
    bag = damage(case, source, workdir / "input", accel)
    before = tree_digest(bag)
    source_before = tree_digest(source)
    ns = ["--namespace", case.namespace] if case.namespace else []
    output = workdir / "estimates"
    if case.output == "input":
        output = bag
    elif case.output == "existing":
        output.mkdir()
        (output / "notes.txt").write_text("a user's file\n")
    out_before = tree_digest(output) if output.exists() else {}
    est = _run_tool(estimate_tool.main, [str(bag), "--vehicle", vehicle, "-o", str(output), *ns])
    s2r = None
    if sim2real:
        s2r = _run_tool(
            sim2real_tool.main,
            [str(bag), "--vehicle", vehicle, "-o", str(workdir / "diagnosis"), "-q", "--no-figures", *ns],
        )
    unchanged = tree_digest(bag) == before and tree_digest(source) == source_before
    problems = _check("terrain-estimate", est, case.estimate, clean_status[0])
    if s2r is not None:
        problems += _check("terrain-sim2real", s2r, case.sim2real, clean_status[1])
    if not unchanged:
        problems.append("an input was modified")
    if case.output != "new" and tree_digest(output) != out_before:
        problems.append(f"the existing output path {output.name} was modified")
    if est.status == 0 and _message_count(output) == 0:
        problems.append("terrain-estimate exited 0 without writing an estimate")
    if est.status != 0 and case.output == "new" and output.exists():
        problems.append("terrain-estimate failed but left an output")
    nonfinite = [] if case.output != "new" else nonfinite_in_outputs(output)
    nonfinite += nonfinite_in_outputs(workdir / "diagnosis")
    problems += [f"non-finite value written: {n}" for n in nonfinite]
    return Outcome(case, vehicle, est, s2r, unchanged, nonfinite, problems)


def _message_count(bag: Path) -> int:
    from rosbags.rosbag2 import Reader

    if not (bag / "metadata.yaml").exists():
        return 0
    with Reader(bag) as reader:
        return int(reader.message_count)


def _status(run: ToolRun | None, workdir: str) -> str:
    if run is None:
        return "—"
    head = run.headline().replace("|", "\\|")
    if workdir:
        head = head.replace(workdir, "DIR")
    head = head if len(head) <= 110 else head[:107] + "…"
    return f"{run.status}: {head}"


def table(outcomes: Sequence[Outcome], workdir: str | os.PathLike[str] = "") -> list[str]:
    """The outcomes as Markdown table lines (``workdir`` written as DIR)."""
    lines = [
        "| vehicle | kind | damage | terrain-estimate (exit: message) | terrain-sim2real (exit: message) "
        "| input unchanged | as required |",
        "|---|---|---|---|---|---|---|",
    ]
    wd = str(workdir)
    for o in outcomes:
        verdict = "yes" if o.ok else "**no**: " + "; ".join(o.problems)
        lines.append(
            f"| {o.vehicle} | {o.case.kind} | {o.case.what} | {_status(o.estimate, wd)} | {_status(o.sim2real, wd)} | "
            f"{'yes' if o.input_unchanged else '**no**'} | {verdict} |"
        )
    return lines


DEFAULT_BAGS = {
    "quarter_car": "quarter_car_graneville_iso_d_10ms",
    "lrv": "lrv_regolith_iso_g_2ms",
    "skid_steer": "skid_steer_s_shape",
    "rover": "rover_terrain_2",
}


def _write_report(page: str, lines: Sequence[str], summary: str, argv: Sequence[str] | None, seconds: float) -> None:
    """The table as the ``mutate`` section of ``page`` (the rest of the page is another command's)."""
    from terrain_analysis.reporting import git_revision, write_section

    command = "python -m terrain_analysis.tools.mutate " + " ".join(sys.argv[1:] if argv is None else argv)
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    text = [
        "## Damaged input: what the offline tools do with it (issue 19)",
        "",
        f"Produced by `{command.strip()}` on {when} at revision {git_revision()} in {seconds:.0f} s. Each row "
        "damages a shipped bag (with rosbags alone) and runs `terrain-estimate` and `terrain-sim2real` on it; "
        '"as required" holds each run to the exit status and message of its case '
        "(`terrain_analysis.tools.mutate.MUTATIONS`; 0 ok, 1 a gap found, 2 the input cannot be used, 3 a bug), "
        "to nothing non-finite written and to every input file hashed unchanged. DIR is the working directory. "
        "`test/test_mutation_suite.py` runs the same cases, and one of each kind on freshly simulated bags.",
        "",
        *lines,
        "",
        summary + ".",
    ]
    write_section(page, "terrain_analysis.tools.mutate", "\n".join(text))


def main(argv: Sequence[str] | None = None) -> int:
    from terrain_estimation.cli import EXIT_FINDING, EXIT_OK, run_cli

    parser = argparse.ArgumentParser(prog="terrain-mutate", description=__doc__.splitlines()[0])
    parser.add_argument("--vehicle", action="append", choices=sorted(DEFAULT_BAGS), help="vehicles (default: all)")
    parser.add_argument("--bags", default="bags", help="directory of the recorded bags (default: bags)")
    parser.add_argument("--only", action="append", help="run only these cases (by name)")
    parser.add_argument("--no-sim2real", action="store_true", help="run terrain-estimate only")
    parser.add_argument("--out", help="keep the damaged bags and outputs in this new directory")
    parser.add_argument(
        "--report", metavar="PAGE", help="also write the table as a section of this Markdown page (replaced if there)"
    )
    args = parser.parse_args(argv)

    def body() -> int:
        cases = [c for c in MUTATIONS if not args.only or c.name in args.only]
        outcomes: list[Outcome] = []
        keep = Path(args.out) if args.out else None
        if keep is not None and keep.exists():
            raise FileExistsError(f"--out {str(keep)!r} exists: give a new directory")
        started = time.monotonic()
        with tempfile.TemporaryDirectory(prefix="terrain-mutate-") as tmp:
            root = keep or Path(tmp)
            for vehicle in args.vehicle or sorted(DEFAULT_BAGS):
                source = Path(args.bags) / DEFAULT_BAGS[vehicle]
                clean = run_case(  # the reference: what SAME means
                    MUTATIONS[0], vehicle, source, root / vehicle / "clean_reference", sim2real=not args.no_sim2real
                )
                statuses = (clean.estimate.status, clean.sim2real.status if clean.sim2real else None)
                outcomes.append(clean)
                for case in cases:
                    if case is MUTATIONS[0]:
                        continue
                    o = run_case(
                        case,
                        vehicle,
                        source,
                        root / vehicle / case.name,
                        clean_status=statuses,
                        sim2real=not args.no_sim2real,
                    )
                    outcomes.append(o)
                    mark = "ok" if o.ok else "FAIL: " + "; ".join(o.problems)
                    print(f"  {vehicle:11s} {case.name:13s} {mark}", file=sys.stderr, flush=True)
            lines = table(outcomes, root)
        failed = [o for o in outcomes if not o.ok]
        summary = f"{len(outcomes) - len(failed)} of {len(outcomes)} cases as required"
        print("\n".join(lines) + f"\n\n{summary}")
        if args.report:
            _write_report(args.report, lines, summary, argv, time.monotonic() - started)
        return EXIT_OK if not failed else EXIT_FINDING

    return run_cli("terrain-mutate", body)


if __name__ == "__main__":
    sys.exit(main())
