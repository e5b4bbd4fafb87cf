"""A report's text as blocks (headings, notes, lists, tables), written twice: summary.md and report.html.

A section builds its blocks once from its rows (``Section.blocks``); :func:`to_markdown` writes
them as summary.md has them and :func:`to_html` as the page shows them, so the page's tables come
from the rows, never parsed back from Markdown. Text in blocks is plain: each renderer escapes
it its own way (Markdown: pipes in cells, ``cells.cell``; HTML: ``html.escape``), so a ``|`` or a
``<`` in a run's ``--name`` stays in its column in both.
"""
from __future__ import annotations

import html
from dataclasses import dataclass
from typing import Sequence, Union

from markupsafe import Markup

from rsb_maniskill.reporting.cells import markdown_table

SMALL_MARK = "†"  # after the text of a cell too small to trust (the page greys its cell)


@dataclass(frozen=True)
class Strong:
    """Bold text, with an optional footnote sign after it (``*``: an Avg over only some suites).
    Markdown writes the sign escaped inside the emphasis (``**Avg\\***``), the page after it
    (``<strong>Avg</strong>*``), as both always did."""

    text: str
    mark: str = ""


Inline = Union[str, Strong, "tuple[str | Strong, ...]"]  # plain text, bold text, or a run of both


@dataclass(frozen=True)
class Cell:
    """A table cell with a flag: ``small`` puts :data:`SMALL_MARK` after its text and greys it on the page."""

    text: Inline
    small: bool = False


@dataclass(frozen=True)
class Heading:
    text: str
    level: int = 3


@dataclass(frozen=True)
class Note:
    """One paragraph of plain text under a heading or a table."""

    text: str


@dataclass(frozen=True)
class Bullets:
    """A list, one line per item (the page shows each as a note line starting with ``-``)."""

    items: tuple[str, ...]


@dataclass(frozen=True)
class Grid:
    """A table: its header, then its rows; a cell is :data:`Inline` or a :class:`Cell` (named Grid so
    that it stands beside the sections' own ``Table`` types)."""

    header: Sequence[Inline]
    rows: Sequence[Sequence[Inline | Cell]]


Block = Union[Heading, Note, Bullets, Grid]


# ---------------------------------------------------------------- Markdown
def _md(text: Inline | Cell) -> str:
    if isinstance(text, Cell):
        return _md(text.text) + (SMALL_MARK if text.small else "")
    if isinstance(text, Strong):
        return "**" + (text.text + text.mark).replace("*", "\\*") + "**"
    if isinstance(text, tuple):
        return "".join(map(_md, text))
    return text


def _block_md(block: Block) -> str:
    if isinstance(block, Heading):
        return "#" * block.level + " " + block.text
    if isinstance(block, Note):  # a leading * would start a list
        return "\\" + block.text if block.text.startswith("*") else block.text
    if isinstance(block, Bullets):
        return "\n".join(f"- {item}" for item in block.items)
    return markdown_table([_md(c) for c in block.header], [[_md(c) for c in row] for row in block.rows])


def to_markdown(blocks: Sequence[Block]) -> str:
    """The blocks as a part of summary.md: blank lines between them, a newline at the end ("" for none)."""
    return "\n\n".join(map(_block_md, blocks)) + "\n" if blocks else ""


# ---------------------------------------------------------------- HTML
def _html(text: Inline | Cell, strip: bool = True) -> str:
    if isinstance(text, Cell):
        return _html(text.text) + (SMALL_MARK if text.small else "")
    if isinstance(text, Strong):
        return f"<strong>{html.escape(text.text)}</strong>{html.escape(text.mark)}"
    if isinstance(text, tuple):  # a run: its spaces between parts kept
        return "".join(_html(part, strip=False) for part in text)
    return html.escape(text.strip() if strip else text)  # a cell's, heading's or note's text stripped


def _td(cell: Inline | Cell) -> str:
    small = isinstance(cell, Cell) and cell.small  # shown greyed, never hidden; each by its own count
    return ('<td class="small">' if small else "<td>") + _html(cell) + "</td>"


def _block_html(block: Block) -> str:
    if isinstance(block, Heading):
        return f"<h{block.level}>{_html(block.text)}</h{block.level}>"
    if isinstance(block, Note):
        return f'<p class="note">{_html(block.text)}</p>'
    if isinstance(block, Bullets):
        return "\n".join(f'<p class="note">- {_html(item)}</p>' for item in block.items)
    return ('<div class="scroll"><table><thead><tr>' + "".join(f"<th>{_html(c)}</th>" for c in block.header)
            + "</tr></thead><tbody>" + "".join("<tr>" + "".join(map(_td, row)) + "</tr>" for row in block.rows)
            + "</tbody></table></div>")


def to_html(blocks: Sequence[Block]) -> Markup:
    """The blocks as the page shows them (text escaped with ``html.escape``), one per line."""
    return Markup("\n".join(map(_block_html, blocks)))
