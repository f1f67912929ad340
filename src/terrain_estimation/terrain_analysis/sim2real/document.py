"""A report as a list of blocks, rendered as Markdown or as one self-contained HTML page.

The diagnosis report (:mod:`~terrain_analysis.sim2real.report`) is written
once, as sections of blocks (headings, paragraphs, lists, tables, figures),
and rendered twice: Markdown beside its PNG figures, and an HTML page that
holds everything it shows (figures as base64 PNG data URIs, its style inline;
no script, no font, no link to anything outside the file). Inline markup in
the text is the Markdown subset the reports use: ``**strong**`` and
```code```.
"""

from __future__ import annotations

import base64
import html
import re
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Bullets", "Figure", "Heading", "Paragraph", "Section", "Table", "html_page", "markdown_text"]


@dataclass
class Heading:
    level: int
    text: str


@dataclass
class Paragraph:
    text: str
    css: str = ""  # class of the HTML paragraph


@dataclass
class Bullets:
    items: list[str]


@dataclass
class Table:
    header: list[str]
    rows: list[list[str]]
    id: str = ""  # id of the HTML table


@dataclass
class Figure:
    """A PNG written beside the report (Markdown links it; HTML embeds its bytes)."""

    path: Path
    caption: str


Block = Heading | Paragraph | Bullets | Table | Figure


@dataclass
class Section:
    """A part of the page (HTML: ``<section id=...>``; Markdown: its blocks, a rule before all but the first)."""

    id: str
    blocks: list[Block] = field(default_factory=list)


# ---------------------------------------------------------------------------
# Markdown
# ---------------------------------------------------------------------------


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _md_block(block: Block) -> str:
    if isinstance(block, Heading):
        return f"{'#' * block.level} {block.text}"
    if isinstance(block, Paragraph):
        return block.text
    if isinstance(block, Bullets):
        return "\n".join(f"- {item}" for item in block.items)
    if isinstance(block, Table):
        lines = ["| " + " | ".join(_md_cell(h) for h in block.header) + " |", "|" + "---|" * len(block.header)]
        lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in block.rows]
        return "\n".join(lines)
    return f"![{block.caption}]({block.path.name})"


def markdown_text(sections: list[Section]) -> str:
    """The sections as Markdown (figures linked by file name: the PNGs sit beside the page)."""
    parts: list[str] = []
    for i, section in enumerate(sections):
        if i:
            parts.append("---")
        parts += [_md_block(b) for b in section.blocks]
    return "\n\n".join(parts) + "\n"


# ---------------------------------------------------------------------------
# HTML
# ---------------------------------------------------------------------------

_CODE = re.compile(r"`([^`]*)`")
_STRONG = re.compile(r"\*\*(.+?)\*\*")

_STYLE = """
body { font: 14px/1.4 system-ui, sans-serif; color: #222; margin: 1em auto; max-width: 1200px; padding: 0 1em; }
h1 { font-size: 1.35em; margin: 0 0 .4em; } h2 { font-size: 1.15em; margin: 1em 0 .3em; }
h3 { font-size: 1.02em; margin: .9em 0 .3em; }
p, ul { margin: .35em 0; } ul { padding-left: 1.4em; }
p.verdict { font-size: 1.12em; padding: .45em .7em; border-left: 5px solid #c0392b; background: #fbeeed; }
p.verdict.ok { border-color: #2e8540; background: #eef7ef; }
p.small { color: #555; font-size: .92em; }
table { border-collapse: collapse; margin: .35em 0; font-size: .9em; }
th, td { border: 1px solid #ccc; padding: 2px 6px; text-align: left; vertical-align: top; }
table#effects td:nth-child(n+3) { white-space: nowrap; }
th { background: #f2f2f2; } code { font-size: .92em; background: #f4f4f4; padding: 0 2px; }
figure { margin: .5em 0; } figure img { max-width: 100%; } figcaption { color: #555; font-size: .9em; }
section#first-screen { border-bottom: 2px solid #999; padding-bottom: .6em; }
section#first-screen .columns { display: flex; flex-wrap: wrap; gap: 1em; align-items: flex-start; }
section#first-screen .columns > div { flex: 1 1 480px; min-width: 0; overflow-x: auto; }
section#first-screen .columns > div:first-child { flex-basis: 600px; }
"""


def _inline(text: str) -> str:
    """Escape ``text`` for HTML and turn its ``**strong**`` and ```code``` into tags (code first)."""
    out = []
    for i, part in enumerate(_CODE.split(text)):
        if i % 2:
            out.append(f"<code>{html.escape(part)}</code>")
        else:
            out.append(_STRONG.sub(r"<strong>\1</strong>", html.escape(part)))
    return "".join(out)


def _html_block(block: Block) -> str:
    if isinstance(block, Heading):
        return f"<h{block.level}>{_inline(block.text)}</h{block.level}>"
    if isinstance(block, Paragraph):
        css = f' class="{html.escape(block.css)}"' if block.css else ""
        return f"<p{css}>{_inline(block.text)}</p>"
    if isinstance(block, Bullets):
        return "<ul>" + "".join(f"<li>{_inline(item)}</li>" for item in block.items) + "</ul>"
    if isinstance(block, Table):
        ident = f' id="{html.escape(block.id)}"' if block.id else ""
        head = "<tr>" + "".join(f"<th>{_inline(h)}</th>" for h in block.header) + "</tr>"
        body = "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in row) + "</tr>" for row in block.rows)
        return f"<table{ident}><thead>{head}</thead><tbody>{body}</tbody></table>"
    data = base64.b64encode(block.path.read_bytes()).decode("ascii")
    return (
        f'<figure><img alt="{html.escape(block.caption)}" src="data:image/png;base64,{data}">'
        f"<figcaption>{_inline(block.caption)}</figcaption></figure>"
    )


def html_page(title: str, sections: list[Section], *, columns: dict[str, int] | None = None) -> str:
    """One self-contained HTML page of ``sections`` (figures embedded, style inline, nothing external).

    ``columns``: section id → index of the block from which that section's
    blocks go into a second column beside the first (a wide screen then
    shows the figure next to the tables).
    """
    columns = columns or {}
    body = []
    for section in sections:
        blocks = [_html_block(b) for b in section.blocks]
        split = columns.get(section.id)
        if split is not None and 0 < split < len(blocks):
            # The title and verdict stay above both columns.
            top = next((i for i, b in enumerate(section.blocks) if isinstance(b, Heading) and b.level == 2), split)
            top = min(top, split)
            blocks = (
                blocks[:top]
                + ['<div class="columns"><div>']
                + blocks[top:split]
                + ["</div><div>"]
                + blocks[split:]
                + ["</div></div>"]
            )
        body.append(f'<section id="{html.escape(section.id)}">\n' + "\n".join(blocks) + "\n</section>")
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
        + "\n".join(body)
        + "\n</body>\n</html>\n"
    )
