"""`sianms report`'s document: a list of blocks rendered once as Markdown and once as HTML.

Both renderings come from the same blocks, so ``report.md`` and ``report.html`` cannot
disagree. The HTML is self-contained: its style is inline, every picture is embedded as a
``data:`` URI, and it holds no script and no link to anything outside the file, so it reads
the same from a CI artefact, an e-mail or a laptop without network.
"""

from __future__ import annotations

import base64
import html
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence, Union


@dataclass(frozen=True)
class Heading:
    text: str


@dataclass(frozen=True)
class Paragraph:
    text: str


@dataclass(frozen=True)
class Table:
    """A table with a header row; its first ``labels`` columns are text (left-aligned), the rest figures;
    ``marked`` holds (row, column) of cells to emphasise (a regression)."""

    name: str  # the HTML id, for readers and tests
    header: Sequence[str]
    rows: Sequence[Sequence[str]]
    marked: frozenset[tuple[int, int]] = frozenset()
    labels: int = 1


@dataclass(frozen=True)
class Figure:
    """A PNG: linked by ``link`` (relative to the report folder) in Markdown, embedded from ``path`` in HTML."""

    caption: str
    path: Path
    link: str


Block = Union[Heading, Paragraph, Table, Figure]

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 75em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.8em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: right; }
th.label, td.label { text-align: left; }
th { background: #eee; }
td.regressed { background: #f8d0d0; font-weight: bold; }
figure { margin: 1em 0; } img { max-width: 100%; }
figcaption { font-size: 0.9em; color: #555; }
"""


def render_markdown(title: str, blocks: Sequence[Block]) -> str:
    """``report.md``: GitHub-flavoured Markdown; a regressed cell in bold."""
    lines = [f"# {title}", ""]
    for block in blocks:
        if isinstance(block, Heading):
            lines += [f"## {block.text}", ""]
        elif isinstance(block, Paragraph):
            lines += [block.text, ""]
        elif isinstance(block, Table):
            lines.append("| " + " | ".join(block.header) + " |")
            lines.append("|" + "---|" * len(block.header))
            for i, row in enumerate(block.rows):
                cells = [f"**{cell}**" if (i, j) in block.marked else cell for j, cell in enumerate(row)]
                lines.append("| " + " | ".join(cells) + " |")
            lines.append("")
        else:
            lines += [f"![{block.caption}]({block.link})", "", f"*{block.caption}*", ""]
    return "\n".join(lines)


def render_html(title: str, blocks: Sequence[Block]) -> str:
    """``report.html``: one file, inline CSS, pictures as base64 ``data:`` URIs, no script."""
    parts = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
             f"<title>{html.escape(title)}</title>", f"<style>{STYLE}</style>", "</head>", "<body>",
             f"<h1>{html.escape(title)}</h1>"]
    for block in blocks:
        if isinstance(block, Heading):
            parts.append(f"<h2>{html.escape(block.text)}</h2>")
        elif isinstance(block, Paragraph):
            parts.append(f"<p>{_inline(block.text)}</p>")
        elif isinstance(block, Table):
            parts.append(_table(block))
        else:
            data = base64.b64encode(block.path.read_bytes()).decode("ascii")
            parts.append(f'<figure><img alt="{html.escape(block.caption)}" src="data:image/png;base64,{data}">'
                         f"<figcaption>{html.escape(block.caption)}</figcaption></figure>")
    parts += ["</body>", "</html>", ""]
    return "\n".join(parts)


def _table(table: Table) -> str:
    def opening(tag: str, i: int | None, j: int) -> str:
        classes = ["label"] if j < table.labels else []
        if (i, j) in table.marked:
            classes.append("regressed")
        return f'<{tag} class="{" ".join(classes)}">' if classes else f"<{tag}>"

    rows = ["<tr>" + "".join(f"{opening('th', None, j)}{html.escape(cell)}</th>"
                             for j, cell in enumerate(table.header)) + "</tr>"]
    for i, row in enumerate(table.rows):
        rows.append("<tr>" + "".join(f"{opening('td', i, j)}{html.escape(cell)}</td>"
                                     for j, cell in enumerate(row)) + "</tr>")
    return f'<table id="{html.escape(table.name)}">\n' + "\n".join(rows) + "\n</table>"


def _inline(text: str) -> str:
    """The Markdown the paragraphs use (`code`, **bold**, *italic*) as HTML, everything else escaped."""
    escaped = html.escape(text)
    escaped = re.sub(r"`([^`]+)`", r"<code>\1</code>", escaped)
    escaped = re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", escaped)
    return re.sub(r"\*([^*]+)\*", r"<em>\1</em>", escaped)
