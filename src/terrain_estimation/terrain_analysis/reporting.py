"""What the reproduction commands share: report assembly, summary claims, statistics, the CLI.

Each ``reproduce_*`` tool simulates, estimates and writes a Markdown report
with figures; this module holds the pieces they have in common so that every
report states its command, revision and cost the same way.
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
    "Claim",
    "Report",
    "SummaryRow",
    "claims_table",
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


def claims_table(claims: Sequence[Claim]) -> str:
    """The summary as a Markdown table (case | quantity | computed | paper | criterion | holds?)."""
    out = ["| case | quantity | computed | paper | criterion | holds? |", "|---|---|---|---|---|---|"]
    for c in claims:
        cells = [c.case, c.quantity, f"{c.computed:.4g}", c.paper, c.criterion, c.verdict]
        out.append("| " + " | ".join(x.replace("|", "\\|") for x in cells) + " |")
    return "\n".join(out)


@dataclass
class Report:
    """Markdown pieces, figures and summary rows gathered by a report's section writers."""

    out: Path
    fig_dir: Path
    rows: list[SummaryRow] = field(default_factory=list)
    sections: list[str] = field(default_factory=list)
    not_reproduced: list[str] = field(default_factory=list)
    figures: list[Path] = field(default_factory=list)

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

    def fig(self, name: str) -> Path:
        path = self.fig_dir / name
        self.figures.append(path)
        return path

    def link(self, path: Path, alt: str) -> str:
        rel = os.path.relpath(path, self.out.parent)
        return f"![{alt}]({rel})"


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
    """Parse a reproduction command's options (runs, out, jobs, quick and ``extra``); exit 2 on bad values.

    Returns the options and the argument list as given (for the report's header).
    """
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument(runs_flag, type=int, default=None, help=runs_help)
    parser.add_argument("--out", default="docs/results", help="output directory (default: docs/results)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default: 2)")
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


def write_section(path: str | os.PathLike[str], name: str, text: str, *, title: str | None = None) -> Path:
    """Put ``text`` in the page ``path`` as the section ``name``: replaced in place if there, else appended.

    ``title`` heads a page that does not exist yet (a new page otherwise starts with the section).

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
