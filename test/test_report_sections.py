"""Two commands share one results page: ``make mutate`` writes its section of robustness.md, ``make bench-load``
rewrites the rest and keeps it (``tools.reporting.write_section``, ``keep_sections``)."""

from __future__ import annotations

from pathlib import Path

from terrain_analysis.reporting import keep_sections, write_section


def test_a_section_is_appended_then_replaced_in_place(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("# Robustness\n\nload table\n")
    write_section(page, "mutate", "## Damage\nfirst\n")
    write_section(page, "other", "## Other\nkept\n")
    write_section(page, "mutate", "## Damage\nsecond\n")
    text = page.read_text()
    assert text.startswith("# Robustness\n\nload table\n")
    assert "second" in text and "first" not in text and text.count("## Damage") == 1
    assert text.index("## Damage") < text.index("## Other"), "replaced where it was"


def test_a_page_rewritten_whole_keeps_the_other_commands_sections(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("# Robustness\n\nold load table\n")
    write_section(page, "mutate", "## Damage\n| a | b |\n")
    new = keep_sections(page.read_text(), "# Robustness\n\nnew load table\n")
    assert "new load table" in new and "old load table" not in new
    assert new.count("| a | b |") == 1
    assert keep_sections(new, new) == new, "a section the new text already has is not repeated"


def test_only_a_markdown_page_is_written(tmp_path: Path) -> None:
    """A results --out that names a user's other file (a bag's metadata, a config) is refused, untouched."""
    import pytest

    from terrain_estimation.cli import InputError

    for name in ("metadata.yaml", "husky.yaml", "run.mcap"):
        other = tmp_path / name
        other.write_text("user data\n")
        with pytest.raises(InputError, match="must be a Markdown file"):
            write_section(other, "fair-comparison", "## Table\n")
        assert other.read_text() == "user data\n"
    with pytest.raises(InputError):
        write_section(tmp_path, "fair-comparison", "## Table\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["husky.yaml", "metadata.yaml", "run.mcap"]


# --- the report writer of the reproductions (reporting.write_page) and their shared runner (experiment.Runner) ---


def test_claim_table_formats_numeric_and_text_claims_as_the_pages_always_did() -> None:
    from terrain_analysis.reporting import Claim, SummaryRow, claims_table, claims_verdict

    numeric = SummaryRow("1", "RMSE |e| (%)", 3.14159, 3.26, "computed ≤ paper", True)
    censored = SummaryRow("1", "time (s)", 12.0, 0.5, "computed ≤ 1.5 × paper (paper: ≈)", False, censored=True)
    text = Claim("turn", "mean |e|", 0.0123456, "< 1|2", "≤ 0.5", None)
    lines = claims_table([numeric, censored, text]).splitlines()
    assert lines[0] == "| case | quantity | computed | paper | criterion | holds? |"
    # Quarter-car rows: 3 significant digits, the paper's number as given, only the quantity escaped.
    assert lines[2] == "| 1 | RMSE \\|e\\| (%) | 3.14 | 3.26 | computed ≤ paper | yes |"
    assert (
        lines[3] == "| 1 | time (s) | 12 | 0.5 | computed ≤ 1.5 × paper (paper: ≈) | **no** (censored: lower bound) |"
    )
    # Skid-steer rows: 4 significant digits, every cell escaped.
    assert lines[4] == "| turn | mean \\|e\\| | 0.01235 | < 1\\|2 | ≤ 0.5 | info |"
    assert claims_verdict([numeric, censored, text]) == (
        '**1 of 2 claims hold**; the 1 rows marked **no** are discussed in "What did not reproduce and why" at the end.'
    )
    assert claims_verdict([numeric, text]) == "**1 of 1 claims hold**."


def test_a_page_states_its_provenance_and_keeps_the_other_commands_sections(tmp_path: Path) -> None:
    from terrain_analysis.reporting import Provenance, Report, source_digests, write_page

    page = tmp_path / "page.md"
    write_section(page, "qc-consistency", "## Consistency\nkept\n")
    rep = Report(out=page, fig_dir=tmp_path / "figs")
    rep.row("1", "error (%)", 2.0, 3.0, "<=")
    rep.claim("2", "lag (s)", 0.5, "faster", "smaller", False)
    rep.sections += ["## Case 1\n\nfirst", "## Case 2\n\nsecond"]
    prov = Provenance("python -m tool --quick", 2, 12.4, 20.6, 14, "simulated rides", quick=True)
    write_page(
        rep, title="# Title", provenance=prov, bullets=["- Seeds: 1, 2"], criteria="Criteria.", general_causes="Why."
    )
    text = page.read_text(encoding="utf-8")
    head = text.split("## Summary")[0]
    assert head.startswith("# Title\n\nWritten by the command, not by hand")
    assert "- Command: `python -m tool --quick`  (**--quick smoke run" in head
    assert "- Git revision: `" in head and "- Wall time: 12 s on 2 worker process(es), 14 simulated rides" in head
    assert "CPU time 21 s" in head and head.index("- Wall time") < head.index("- Seeds: 1, 2")
    digests = source_digests()
    assert set(digests) == {"terrain_estimation", "terrain_analysis", "vehicle_sim"}
    assert all(len(d) == 12 and int(d, 16) >= 0 for d in digests.values())
    assert f"terrain_analysis `{digests['terrain_analysis']}`" in head
    assert "**1 of 2 claims hold**; the 1 rows marked **no**" in text
    assert text.index("## Case 1\n\nfirst\n\n## Case 2\n\nsecond") > text.index("## Summary")
    tail = text.split("## What did not reproduce and why\n\n", 1)[1]
    assert tail.startswith("- Everything in the summary holds.\n\nWhy.\n")
    assert text.count("## Consistency\nkept") == 1, "the section another command wrote stays"


def test_the_runner_returns_the_results_in_plan_order_on_a_local_cluster() -> None:
    """Two worker processes of a real Dask cluster, jobs submitted heaviest first: the results still in plan order."""
    import math

    from terrain_analysis.experiment import Runner

    plan = [float(x) for x in (9, 1, 16, 4, 25, 0)]
    with Runner(2, progress=False) as runner:
        out = runner.map(math.sqrt, plan, weight=lambda x: 1.0 + x)
    assert out == [3.0, 1.0, 4.0, 2.0, 5.0, 0.0]
    assert runner.n_tasks == len(plan) and runner.cpu_s > 0.0 and runner.wall_s > 0.0
    with Runner(1, progress=False) as runner:
        assert runner.map(math.sqrt, plan, weight=lambda x: 1.0 + x) == out


def test_the_runner_fails_the_plan_naming_every_failed_job() -> None:
    """A page is never written from part of its runs: a job that raises fails the plan, on a cluster or not."""
    import math

    import pytest

    from terrain_analysis.experiment import ExperimentError, Runner

    for jobs in (1, 2):
        with Runner(jobs, progress=False) as runner, pytest.raises(ExperimentError) as err:
            runner.map(math.sqrt, [4.0, -1.0, 9.0, -4.0], key=lambda x: f"x={x:g}")
        message = str(err.value)
        assert message.startswith("2 of 4 runs failed (1:x=-1, 3:x=-4): ValueError: math domain error"), message
        assert "Traceback" in message
