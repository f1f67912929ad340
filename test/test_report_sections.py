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
