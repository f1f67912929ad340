"""The report writer of the reproductions: header and provenance, seeds, claim table, figures, sections.

Each ``reproduce_*`` tool runs a plan on :mod:`terrain_analysis.experiment`
and writes a Markdown page with figures; this module holds everything the
pages have in common, so that every page states its command, revision, source
hashes and cost the same way and keeps only its paper-specific metrics and
text:

* :class:`Report` gathers a page's sections, figures, claims and "not
  reproduced" notes; :func:`write_page` assembles the page (title, the
  "written by the command" note, :func:`provenance_lines`, the page's own
  bullets such as run counts and seeds, the summary with
  :func:`claims_table` and :func:`claims_verdict`, the sections, the "What
  did not reproduce and why" tail) and keeps the sections other commands
  wrote into it;
* :func:`provenance_sentence` is the same provenance for a section that a
  command writes into another page (:func:`write_section`).
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "WRITTEN_BY",
    "Claim",
    "Provenance",
    "Report",
    "SummaryRow",
    "claims_table",
    "claims_verdict",
    "provenance_lines",
    "provenance_sentence",
    "source_digests",
    "write_page",
    "cpu_seconds",
    "format_number",
    "git_revision",
    "write_section",
    "keep_sections",
    "in_window",
    "pyplot",
    "reproduction_arguments",
    "summary_stats",
]


def in_window(t: NDArray[np.float64], t0: float, t1: float) -> NDArray[np.bool_]:
    """Samples with t0 < t ≤ t1 (1 ns tolerance on both ends)."""
    return (t > t0 + 1e-9) & (t <= t1 + 1e-9)


def summary_stats(values: Sequence[float]) -> dict[str, float]:
    """Mean, sample std (0 for one value), median, 90th percentile, max and count."""
    a = np.asarray(values, dtype=float)
    return {
        "mean": float(np.mean(a)),
        "std": float(np.std(a, ddof=1)) if a.size > 1 else 0.0,
        "median": float(np.median(a)),
        "p90": float(np.percentile(a, 90)),
        "max": float(np.max(a)),
        "n": float(a.size),
    }


def format_number(x: float, digits: int = 2) -> str:
    """Fixed-point with ``digits`` decimals; 3 significant digits for very large or small values."""
    if not math.isfinite(x):
        return "inf"
    if x != 0.0 and (abs(x) >= 1e5 or abs(x) < 10 ** (-digits)):
        return f"{x:.3g}"
    return f"{x:.{digits}f}"


@dataclass
class SummaryRow:
    """One line of a summary table with a numeric paper value."""

    case: str
    quantity: str
    computed: float
    paper: float
    criterion: str
    holds: bool | None  # None: informational, no claim
    censored: bool = False

    @property
    def verdict(self) -> str:
        if self.holds is None:
            return "info"
        if self.holds:
            return "yes"
        return "**no** (censored: lower bound)" if self.censored else "**no**"

    def cells(self) -> list[str]:
        """The row's cells in the claim table (the paper's value is a number: 3 significant digits)."""
        quantity = self.quantity.replace("|", "\\|")
        return [self.case, quantity, f"{self.computed:.3g}", f"{self.paper:g}", self.criterion, self.verdict]


@dataclass
class Claim:
    """One line of a summary table whose paper value may be qualitative (hence text)."""

    case: str
    quantity: str
    computed: float
    paper: str
    criterion: str
    holds: bool | None  # None: informational

    @property
    def verdict(self) -> str:
        return "info" if self.holds is None else ("yes" if self.holds else "**no**")

    def cells(self) -> list[str]:
        """The row's cells in the claim table (4 significant digits; every cell's pipes escaped)."""
        cells = [self.case, self.quantity, f"{self.computed:.4g}", self.paper, self.criterion, self.verdict]
        return [x.replace("|", "\\|") for x in cells]


def claims_table(claims: Sequence[Claim | SummaryRow]) -> str:
    """The summary as a Markdown table (case | quantity | computed | paper | criterion | holds?)."""
    out = ["| case | quantity | computed | paper | criterion | holds? |", "|---|---|---|---|---|---|"]
    out += ["| " + " | ".join(c.cells()) + " |" for c in claims]
    return "\n".join(out)


def claims_verdict(claims: Sequence[Claim | SummaryRow]) -> str:
    """The line under the claim table: how many claims hold, and where the failures are discussed."""
    failed = sum(c.holds is False for c in claims)
    return f"**{sum(c.holds is True for c in claims)} of {sum(c.holds is not None for c in claims)} claims hold**" + (
        f'; the {failed} rows marked **no** are discussed in "What did not reproduce and why" at the end.'
        if failed
        else "."
    )


@dataclass
class Report:
    """Markdown pieces, figures and summary rows gathered by a report's section writers."""

    out: Path
    fig_dir: Path
    rows: list[SummaryRow | Claim] = field(default_factory=list)
    sections: list[str] = field(default_factory=list)
    not_reproduced: list[str] = field(default_factory=list)
    figures: list[Path] = field(default_factory=list)

    @classmethod
    def for_page(cls, out_dir: str | os.PathLike[str], page: str) -> Report:
        """The report of the page ``out_dir/<page>.md``, its figures in ``out_dir/<page>/`` (created)."""
        fig_dir = Path(out_dir) / page
        fig_dir.mkdir(parents=True, exist_ok=True)
        return cls(out=Path(out_dir) / f"{page}.md", fig_dir=fig_dir)

    def row(
        self,
        case: str,
        quantity: str,
        computed: float,
        paper: float,
        criterion: Literal["<=", "<=1.5x", "<", ">=", "info"],
        censored: bool = False,
    ) -> bool | None:
        """Add a summary row; ``censored``: the computed value is only a lower bound."""
        if criterion == "<=":
            holds: bool | None = computed <= paper
            text = "computed ≤ paper"
        elif criterion == "<=1.5x":
            holds = computed <= 1.5 * paper
            text = "computed ≤ 1.5 × paper (paper: ≈)"
        elif criterion == "<":
            holds = computed < paper
            text = "computed < paper bound"
        elif criterion == ">=":
            holds = computed >= paper
            text = "computed ≥ paper"
        else:
            holds, text = None, "—"
        if censored and holds and criterion in ("<=", "<=1.5x", "<"):
            holds = False  # a lower bound at or below the paper shows nothing
        self.rows.append(SummaryRow(case, quantity, computed, paper, text, holds, censored))
        return holds

    def claim(
        self, case: str, quantity: str, computed: float, paper: str, criterion: str, holds: bool | None
    ) -> bool | None:
        """Add a summary row whose paper value is text (qualitative, or a number with its own criterion)."""
        self.rows.append(Claim(case, quantity, computed, paper, criterion, holds))
        return holds

    def fig(self, name: str) -> Path:
        path = self.fig_dir / name
        self.figures.append(path)
        return path

    def save_figure(self, fig: Any, name: str) -> Path:
        """Save a matplotlib figure as ``fig_dir/name`` (tight layout, 110 dpi), close it, return its path."""
        fig.tight_layout()
        path = self.fig(name)
        fig.savefig(path, dpi=110)
        pyplot().close(fig)
        return path

    def link(self, path: Path, alt: str) -> str:
        rel = os.path.relpath(path, self.out.parent)
        return f"![{alt}]({rel})"

    def add_section(self, lines: Sequence[str], *figures: tuple[Any, str, str]) -> None:
        """Append a section: its ``lines``, then each ``(figure, file name, alt text)`` saved
        (:meth:`save_figure`) and linked, each link followed by an empty line."""
        text = list(lines)
        for fig, name, alt in figures:
            text += [self.link(self.save_figure(fig, name), alt), ""]
        self.sections.append("\n".join(text))


def pyplot() -> Any:
    """matplotlib.pyplot on the non-interactive Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def cpu_seconds() -> float:
    """User + system CPU time of this process and its finished children (s)."""
    import resource

    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def git_revision() -> str:
    """Short HEAD hash of the checkout holding this file, marked when tracked files are modified."""
    try:
        here = Path(__file__).resolve().parent
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10, check=True
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
        rev = out.stdout.strip()
        return rev + (" (working tree modified)" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


_PACKAGES = ("terrain_estimation", "terrain_analysis", "vehicle_sim")


def source_digests() -> dict[str, str]:
    """Per package of the project, the first 12 hex digits of the SHA-256 of its Python sources.

    The digest covers every ``*.py`` file of the package (relative path and bytes, in sorted order), so a
    page computed from a modified working tree still names the code that computed it; a package that
    cannot be imported is left out.
    """
    import hashlib
    import importlib.util

    out: dict[str, str] = {}
    for name in _PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            continue
        root = Path(next(iter(spec.submodule_search_locations)))
        digest = hashlib.sha256()
        for path in sorted(root.rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
        out[name] = digest.hexdigest()[:12]
    return out


@dataclass(frozen=True)
class Provenance:
    """How a page (or a section) was computed: the command, the code and the cost.

    Attributes:
        command: the command line as a user types it (``python -m ... --quick``).
        jobs: worker processes.
        wall_s: wall seconds of the command.
        cpu_s: CPU seconds of the command and of every job in its workers.
        runs: simulated runs (jobs of the plan).
        what: what a run is ("simulated rides").
        quick: a ``--quick`` smoke run (flagged: too few runs to compare).
    """

    command: str
    jobs: int
    wall_s: float
    cpu_s: float
    runs: int
    what: str = "simulated runs"
    quick: bool = False

    @classmethod
    def of(cls, module: str, argv: Sequence[str], runner: Any, *, what: str = "", quick: bool = False) -> Provenance:
        """The provenance of ``python -m module argv`` run on an :class:`~terrain_analysis.experiment.Runner`."""
        command = f"python -m {module} {' '.join(argv)}".strip()
        return cls(command, runner.jobs, runner.wall_s, runner.cpu_s, runner.n_tasks, what or runner.what, quick)


def _sources_text() -> str:
    return ", ".join(f"{name} `{digest}`" for name, digest in source_digests().items())


def provenance_lines(prov: Provenance) -> list[str]:
    """The header bullets of a page: command, git revision, source hashes, wall and CPU time."""
    return [
        f"- Command: `{prov.command}`" + ("  (**--quick smoke run: too few runs to compare**)" if prov.quick else ""),
        f"- Git revision: `{git_revision()}`",
        f"- Sources (SHA-256 of each package's Python files): {_sources_text()}",
        f"- Wall time: {prov.wall_s:.0f} s on {prov.jobs} worker process(es), {prov.runs} {prov.what}; CPU time "
        f"{prov.cpu_s:.0f} s (this process and the runs in its workers; the wall time is longer when the machine "
        "is shared)",
    ]


def provenance_sentence(prov: Provenance) -> str:
    """The same provenance as one sentence, for a section written into another command's page."""
    return (
        f"Written by `{prov.command}` at revision `{git_revision()}` (sources: {_sources_text()}) in "
        f"{prov.wall_s:.0f} s on {prov.jobs} process(es), {prov.runs} {prov.what}, CPU time {prov.cpu_s:.0f} s."
    )


WRITTEN_BY = (
    "Written by the command, not by hand: every number below was computed by this project's simulator and "
    "estimator when the command ran; the paper's values are the comparison column only (DESIGN.md). Nothing "
    "in the truth plant, the noise or the seeds was tuned towards the paper."
)
"""The note under a reproduction page's title."""


def write_page(
    rep: Report,
    *,
    title: str,
    provenance: Provenance,
    bullets: Sequence[str],
    criteria: str,
    general_causes: str,
) -> Path:
    """Write a reproduction's page ``rep.out`` and return its path.

    The page: ``title``; :data:`WRITTEN_BY`; :func:`provenance_lines` and the page's own ``bullets`` (run
    counts, seeds, truth, estimator, definitions: each a ``"- ..."`` line); "## Summary" with ``criteria``,
    :func:`claims_table` of ``rep.rows`` and :func:`claims_verdict`; ``rep.sections``; "## What did not
    reproduce and why" with ``rep.not_reproduced`` and ``general_causes``. Sections written into the page
    by other commands (:func:`write_section`) are kept.
    """
    header = [
        title,
        "",
        WRITTEN_BY,
        "",
        *provenance_lines(provenance),
        *bullets,
        "",
        "## Summary",
        "",
        criteria,
        "",
        claims_table(rep.rows),
        "",
        claims_verdict(rep.rows),
        "",
    ]
    tail = [
        "## What did not reproduce and why",
        "",
        *(rep.not_reproduced or ["- Everything in the summary holds."]),
        "",
        general_causes,
        "",
    ]
    text = "\n".join(header) + "\n" + "\n\n".join(rep.sections) + "\n\n" + "\n".join(tail)
    if rep.out.exists():  # sections written by other commands (e.g. qc_consistency) stay
        text = keep_sections(rep.out.read_text(encoding="utf-8"), text)
    rep.out.parent.mkdir(parents=True, exist_ok=True)
    rep.out.write_text(text, encoding="utf-8")
    return rep.out


def reproduction_arguments(
    prog: str,
    description: str,
    argv: Sequence[str] | None,
    *,
    runs_flag: str = "--runs",
    runs_help: str,
    quick_help: str,
    extra: Sequence[tuple[str, dict[str, Any]]] = (),
) -> tuple[argparse.Namespace, list[str]]:
    """Parse a reproduction command's options (runs, out, jobs, scheduler, quick and ``extra``); exit 2 on bad values.

    Returns the options and the argument list as given (for the report's header).
    """
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument(runs_flag, type=int, default=None, help=runs_help)
    parser.add_argument("--out", default="docs/results", help="output directory (default: docs/results)")
    parser.add_argument(
        "--jobs", type=int, default=2, help="worker processes of a local Dask cluster; 1: in this process (default: 2)"
    )
    parser.add_argument(
        "--scheduler", default=None, help="address of a running Dask scheduler (tcp://host:8786) instead of --jobs"
    )
    for flag, options in extra:
        parser.add_argument(flag, **options)
    parser.add_argument("--quick", action="store_true", help=quick_help)
    args = parser.parse_args(argv)
    runs = getattr(args, runs_flag.lstrip("-").replace("-", "_"))
    if runs is not None and runs < 1:
        parser.error(f"{runs_flag} must be ≥ 1")
    if args.jobs < 1:
        parser.error("--jobs must be ≥ 1")
    return args, list(sys.argv[1:] if argv is None else argv)


_SECTION = "<!-- {edge}: {name} (written by its command; the rest of the page by another) -->"


def _section_re(name: str) -> Any:
    import re

    begin = re.escape(_SECTION.format(edge="begin", name=name))
    end = re.escape(_SECTION.format(edge="end", name=name))
    return re.compile(rf"\n*{begin}\n.*?\n{end}\n", re.DOTALL)


def write_section(
    path: str | os.PathLike[str], name: str, text: str, *, title: str | None = None, note: bool = False
) -> Path:
    """Put ``text`` in the page ``path`` as the section ``name``: replaced in place if there, else appended.

    ``title`` heads a page that does not exist yet (a new page otherwise starts with the section); ``note``:
    say on stderr which section of which page was written.

    Two commands can then share one results page (``make bench-load`` writes
    ``robustness.md`` whole and keeps the sections of others: :func:`keep_sections`).

    Only a Markdown page (``.md``) is written: a command's ``--out`` that names a bag's
    ``metadata.yaml``, a config file or a directory is refused before anything is touched.
    The page is replaced atomically, so an interrupted write leaves the old page whole.

    Raises:
        InputError: ``path`` is not a Markdown file.
    """
    from terrain_estimation.cli import InputError

    page = Path(path)
    if page.suffix.lower() not in (".md", ".markdown") or page.is_dir():
        raise InputError(f"{page}: a results page must be a Markdown file (.md); nothing written")
    block = f"{_SECTION.format(edge='begin', name=name)}\n{text.rstrip()}\n{_SECTION.format(edge='end', name=name)}\n"
    old = page.read_text() if page.exists() else (title.rstrip() + "\n" if title else "")
    pattern = _section_re(name)
    new = pattern.sub(lambda _m: "\n\n" + block, old, count=1) if pattern.search(old) else old.rstrip() + "\n\n" + block
    page.parent.mkdir(parents=True, exist_ok=True)
    partial = page.with_name(f".{page.name}.partial-{os.getpid()}")
    partial.write_text(new.lstrip("\n"))
    os.replace(partial, page)
    if note:
        print(f"wrote section {name!r} of {page}", file=sys.stderr)
    return page


def keep_sections(old: str, new: str) -> str:
    """``new`` with every section of other commands found in ``old`` (:func:`write_section`) appended."""
    import re

    names = re.findall(re.escape(_SECTION.format(edge="begin", name="@@")).replace("@@", "(.+?)"), old)
    for name in names:
        if _section_re(name).search(new) is None:
            match = _section_re(name).search(old)
            assert match is not None
            new = new.rstrip() + "\n\n" + match.group(0).lstrip("\n")
    return new
