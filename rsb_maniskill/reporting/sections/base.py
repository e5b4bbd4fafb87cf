"""What a report section is: the interface every module of ``reporting/sections/`` implements.

A section turns the records (and the files beside them) into one table, then writes that table
everywhere it appears: a key of ``summary.json``, a block of ``summary.md`` (in
``summary_order``), its own CSV / PNG files, and a ``<section>`` of
``report.html`` (heading, note, an optional figure, the tables). Its summary.md block and its tables
on the page are both rendered from its :meth:`Section.blocks` (``reporting/blocks.py``). ``writer.py``
and ``page.py`` only loop over the registry, so adding a section is adding one module there.
"""
from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any, ClassVar, Mapping, Sequence

from markupsafe import Markup

from rsb_maniskill.reporting.blocks import Block, to_html, to_markdown


class Section:
    """One report section. Subclasses set the class attributes, :meth:`compute`, :meth:`to_json` and
    :meth:`blocks`; summary.md and the page's tables are both written from the blocks."""

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

    def blocks(self, table: Any) -> list[Block]:
        """Its headings, notes and tables (``reporting/blocks.py``), built once from the table's rows."""
        raise NotImplementedError

    def markdown(self, table: Any) -> str:
        """Its block of summary.md."""
        return to_markdown(self.blocks(table))

    def files(self, table: Any, out: Path, stem: str) -> dict[str, Path]:
        """Its own files beside the summary (``{"csv:NAME": path, "png:NAME": path}``)."""
        return {}

    def html(self, table: Any) -> Markup | None:
        """Its tables on the page (None: heading and note only), from the same blocks as its Markdown."""
        return to_html(self.blocks(table))

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
