"""The sim-to-real report read in a minute, and its self-contained HTML page (issue 22, item 9).

One short simulated bag with a body-accelerometer bias (a gap on the body
channel, none on the wheel) is diagnosed by the command line tool with ``-o``.
The HTML page it writes beside ``diagnosis.md`` is parsed with
:mod:`html.parser`: nothing it shows comes from outside the file, its first
screen holds the verdict, the effect table (whose rows are those of the JSON)
and a figure that decodes as a PNG, and neither page names a gain or a delay
of the channel without a gap as a finding.
"""

from __future__ import annotations

import base64
import io
import json
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest

from terrain_analysis.tools.sim2real import main as sim2real_main
from terrain_analysis.tools.sim2real_screenshot import main as screenshot_main
from vehicle_sim.tools.simulate import record

#: Attributes through which a page loads or links something.
URL_ATTRIBUTES = {"src", "href", "srcset", "poster", "data", "action", "formaction", "background", "xlink:href"}
#: Tags that load something from elsewhere (or run code) whatever their attributes.
EXTERNAL_TAGS = {"link", "script", "iframe", "object", "embed", "base", "frame", "audio", "video", "source"}


class Page(HTMLParser):
    """The page's sections (id → text), images (section id, src), style text, tables (id → rows of cell texts)."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.sections: dict[str, list[str]] = {}
        self.images: list[tuple[str | None, str]] = []
        self.style: list[str] = []
        self.tables: dict[str, list[list[str]]] = {}
        self._section: list[str] = []
        self._in_style = False
        self._table: str | None = None
        self._row: list[str] | None = None
        self._cell: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        self.tags.append((tag, a))
        if tag == "section":
            self._section.append(a.get("id", ""))
            self.sections.setdefault(a.get("id", ""), [])
        elif tag == "style":
            self._in_style = True
        elif tag == "img":
            self.images.append((self._section[-1] if self._section else None, a.get("src", "")))
        elif tag == "table":
            self._table = a.get("id", f"table{len(self.tables)}")
            self.tables[self._table] = []
        elif tag == "tr" and self._table is not None:
            self._row = []
        elif tag in ("td", "th") and self._row is not None:
            self._cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag == "section" and self._section:
            self._section.pop()
        elif tag == "style":
            self._in_style = False
        elif tag in ("td", "th") and self._cell is not None and self._row is not None:
            self._row.append(" ".join("".join(self._cell).split()))
            self._cell = None
        elif tag == "tr" and self._row is not None and self._table is not None:
            self.tables[self._table].append(self._row)
            self._row = None
        elif tag == "table":
            self._table = None

    def handle_data(self, data: str) -> None:
        if self._in_style:
            self.style.append(data)
        for section in self._section:
            self.sections[section].append(data)
        if self._cell is not None:
            self._cell.append(data)

    def text(self, section: str) -> str:
        return " ".join("".join(self.sections.get(section, [])).split())


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Page, dict[str, Any]]:
    tmp = tmp_path_factory.mktemp("s2r_html")
    bag = tmp / "bias"
    record("quarter_car", 4.0, bag, overrides={"seed": 3, "scenario.road_seed": 4, "effects.accel_bias_body": 0.3})
    out = tmp / "out"
    status = sim2real_main([str(bag), "--vehicle", "quarter_car", "-o", str(out), "-q"])
    assert status in (0, 1), status
    page = Page()
    page.feed((out / "diagnosis.html").read_text(encoding="utf-8"))
    page.close()
    return out, page, json.loads((out / "diagnosis.json").read_text(encoding="utf-8"))


def test_the_page_loads_nothing_from_outside(report: tuple[Path, Page, dict[str, Any]]) -> None:
    _, page, _ = report
    assert page.tags, "the page parsed to nothing"
    for tag, attrs in page.tags:
        assert tag not in EXTERNAL_TAGS, f"<{tag} {attrs}> loads or runs something"
        for name, value in attrs.items():
            if name in URL_ATTRIBUTES:
                assert value.startswith(("data:", "#")), f"<{tag} {name}={value[:80]!r}> points outside the file"
            assert "url(" not in value.lower(), f"<{tag} {name}=...> has a url()"
    style = "".join(page.style).lower()
    assert "url(" not in style and "@import" not in style and "@font-face" not in style


def test_the_first_screen_gives_the_verdict_and_a_figure(report: tuple[Path, Page, dict[str, Any]]) -> None:
    out, page, data = report
    first = page.text("first-screen")
    assert " ".join(f"Verdict: {data['verdict']}".split()) in first
    assert "Where the nominal model disagrees" in first and "body" in first
    figures = [src for section, src in page.images if section == "first-screen"]
    assert len(figures) == 1, "one figure on the first screen"
    prefix = "data:image/png;base64,"
    assert figures[0].startswith(prefix)
    png = base64.b64decode(figures[0][len(prefix) :], validate=True)
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
    from PIL import Image

    with Image.open(io.BytesIO(png)) as image:
        image.verify()
        assert image.format == "PNG" and min(image.size) > 100
    # Every figure written beside the report is in the page (the others in the appendix), byte for byte.
    embedded = {base64.b64decode(src[len(prefix) :]) for _, src in page.images}
    assert embedded == {p.read_bytes() for p in out.glob("*.png")}
    # The per-window table is in the appendix, not on the first screen.
    assert "Residual RMS per time window" in page.text("appendix")
    assert "Residual RMS per time window" not in first


def test_the_effect_table_rows_are_the_json_rows(report: tuple[Path, Page, dict[str, Any]]) -> None:
    _, page, data = report
    a = data["attribution"]
    table = page.tables["effects"]
    header, rows = table[0], table[1:]
    assert header[:3] == ["rank", "model", "held-out shrinkage"]
    models = [a["nominal"], *a["ranking"], *a["pairs"]]
    assert [r[1] for r in rows] == [m["name"] for m in models]
    assert [r[2] for r in rows] == [f"{100 * m['shrinkage']['overall']:.1f} %" for m in models]
    assert [r[5] == "yes" for r in rows] == [bool(m["significant"]) for m in models]
    # The first screen's table is the Markdown's, row for row.
    md = (report[0] / "diagnosis.md").read_text(encoding="utf-8")
    first_md = md.split("\n---\n")[0]
    assert f"**Verdict: {data['verdict']}**" in first_md
    for m in models:
        assert f"| {m['name']} |" in first_md or f"| **{m['name']}** |" in first_md


def test_no_gain_or_delay_is_shown_for_a_channel_without_a_gap(report: tuple[Path, Page, dict[str, Any]]) -> None:
    out, page, data = report
    where = data["where"]
    channels = {ch["name"]: ch for ch in where["channels"]}
    assert channels["body"]["gaps"], "the body bias is a gap"
    binned = {c for rows in [where["windows"], *where["regimes"].values()] for r in rows for c in r["gap"]}
    quiet = [name for name, ch in channels.items() if not ch["gaps"] and name not in binned]
    assert quiet == ["wheel"], "the wheel channel has no gap on this bag"
    first = page.text("first-screen")
    assert "gain" in first.split("body", 1)[1], "the gap channel's gain is named"
    md = (out / "diagnosis.md").read_text(encoding="utf-8").split("\n---\n")[0]
    for name in quiet:
        assert f"**{name}**" not in md, f"{name} has no gap: not a finding on the first screen"
        row = next(r for t in page.tables.values() for r in t if r and r[0].startswith(f"{name} ("))
        assert row[-2:] == ["–", "–"], f"{name}: gain and delay shown without a gap: {row}"


def test_the_screenshot_tool_without_chromium_says_how_to_get_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``make sim2real-screenshot`` on a machine without chromium: exit 2 and the command that installs it."""
    monkeypatch.setenv("PATH", str(tmp_path))  # nothing on PATH, chromium least of all
    page = tmp_path / "diagnosis.html"
    page.write_text("<!DOCTYPE html><html><body><p>report</p></body></html>", encoding="utf-8")
    assert screenshot_main([str(page)]) == 2
    assert screenshot_main(["--check"]) == 2
    err = capsys.readouterr().err
    assert "chromium not found" in err and "apt-get install chromium" in err
    assert not (tmp_path / "screenshot.png").exists()


@pytest.mark.parametrize("target", ["screenshot.png", "diagnosis.html"])
def test_the_screenshot_tool_never_replaces_a_file_without_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], target: str
) -> None:
    """An existing file at ``-o`` (a user's, or the page itself) is refused and left as it was."""
    page = tmp_path / "diagnosis.html"
    page.write_text("<!DOCTYPE html><html><body><p>report</p></body></html>", encoding="utf-8")
    existing = tmp_path / target
    if target != page.name:
        existing.write_bytes(b"somebody's file")
    before = existing.read_bytes()
    assert screenshot_main([str(page), "-o", str(existing)]) == 2
    assert existing.read_bytes() == before
    assert "exists" in capsys.readouterr().err or target == page.name
    # the page is one of the run's inputs: refused with --overwrite too
    if target == page.name:
        assert screenshot_main([str(page), "-o", str(existing), "--overwrite"]) == 2
        assert existing.read_bytes() == before
