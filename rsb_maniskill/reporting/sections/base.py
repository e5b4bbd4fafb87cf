"""What a report section is: the interface every module of ``reporting/sections/`` implements.

A section turns the records (and the files beside them) into one table, then writes that table
everywhere it appears: a key of ``summary.json``, a block of ``summary.md`` (in
``summary_order``), its own CSV / PNG files, and a ``<section>`` of
``report.html`` (heading, note, an optional figure, the tables). ``writer.py`` and ``page.py`` only
loop over the registry, so adding a section is adding one module there.
"""
from __future__ import annotations

import csv
import html
import os
import re
from pathlib import Path
from typing import Any, ClassVar, Mapping, Sequence

from markupsafe import Markup

_PIPE = re.compile(r"(?<!\\)\|")  # a column's border, not an escaped pipe inside a cell (cells.cell)
SMALL_MARK = "†"  # after the count of a cell too small to trust (the page greys its line)


class Section:
    """One report section. Subclasses set the class attributes and :meth:`compute`; the defaults
    write nothing but the summary's JSON and Markdown, and the page's tables from the Markdown."""

    key: ClassVar[str]  # its key in summary.json
    anchor: ClassVar[str]  # the id of its <section> in report.html
    title: ClassVar[str]  # the page's heading
    note: ClassVar[str] = ""  # the page's text under the heading (HTML: inline markup only)
    nav: ClassVar[str | None] = None  # a link in the page's header, when set
    summary_order: ClassVar[int]  # where summary.md / summary.json put it (they append in this order)
    page_order: ClassVar[int]  # where the page shows it (the error analysis is at 50)
    # What stands before its <section> in the page's source (the first sections keep the none they
    # always had, so that pages stay byte-identical; new ones take the default).
    lead: ClassVar[str] = "\n"

    def compute(self, records: Sequence[Mapping[str, Any]], results_dir: Path) -> Any | None:
        """The section's table, or None where the records call for no section."""
        raise NotImplementedError

    def to_json(self, table: Any) -> Any:
        """The value of :attr:`key` in summary.json."""
        raise NotImplementedError

    def markdown(self, table: Any) -> str:
        """Its block of summary.md."""
        raise NotImplementedError

    def files(self, table: Any, out: Path, stem: str) -> dict[str, Path]:
        """Its own files beside the summary (``{"csv:NAME": path, "png:NAME": path}``)."""
        return {}

    def html(self, table: Any) -> Markup | None:
        """Its tables on the page (None: heading and note only)."""
        return markdown_to_html(self.markdown(table))

    def figure(self, table: Any) -> dict[str, str] | None:
        """An image above the tables: ``{"src": data URI, "alt": text}``."""
        return None

    def charts(self, table: Any) -> list[dict[str, Any]]:
        """Bar charts drawn by the page's ``bias_chart`` macro (see ``bias.py``)."""
        return []

    def page(self, records: Sequence[Mapping[str, Any]], results_dir: Path) -> dict[str, Any] | None:
        """What report.html.j2 renders of this section, or None when it is absent."""
        table = self.compute(records, results_dir)
        if table is None:
            return None
        return {"anchor": self.anchor, "title": self.title, "note": Markup(self.note), "lead": self.lead,
                "figure": self.figure(table), "charts": self.charts(table), "body": self.html(table)}


def write_rows(rows: Sequence[Mapping[str, Any]], path: str | os.PathLike) -> Path:
    """Rows of plain values as a CSV file, columns in the first row's order (None as empty)."""
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else [])
        w.writeheader()
        for r in rows:
            w.writerow({k: "" if v is None else v for k, v in r.items()})
    return path


# ---------------------------------------------------------------- Markdown tables -> HTML
def _inline(text: str) -> str:
    text = html.escape(text.strip()).replace("\\*", "*").replace("\\|", "|")
    return re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)


def _body_row(cells: Sequence[str]) -> str:
    # a cell marked with the small-cell dagger is greyed: shown, never hidden; each by its own count
    return "<tr>" + "".join(f'<td class="small">{_inline(c)}</td>' if SMALL_MARK in c else f"<td>{_inline(c)}</td>"
                            for c in cells) + "</tr>"


def markdown_to_html(md: str) -> Markup:
    """The subset ``summary.markdown_tables`` writes: ``###`` headings, pipe tables, paragraphs."""
    out, table = [], []

    def flush() -> None:
        if not table:
            return
        rows = [_PIPE.split(line.strip().removeprefix("|").removesuffix("|")) for line in table]
        head, body = rows[0], [r for r in rows[2:]]
        out.append('<div class="scroll"><table><thead><tr>' + "".join(f"<th>{_inline(c)}</th>" for c in head)
                   + "</tr></thead><tbody>" + "".join(_body_row(r) for r in body) + "</tbody></table></div>")
        table.clear()

    for line in md.splitlines():
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if line.startswith("### "):
            out.append(f"<h3>{_inline(line[4:])}</h3>")
        elif line.strip():
            out.append(f"<p class=\"note\">{_inline(line)}</p>")
    flush()
    return Markup("\n".join(out))


