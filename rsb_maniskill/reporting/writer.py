"""Writing a results directory's reports: the summary files with every section, and report.html.

:func:`write_report` writes ``summary.{json,csv,md}`` (``summary.py``: the paper's tables) and
``results.json`` (``results.py``), then appends each section of the registry
(``sections.SECTIONS``) the records call for, with its own files. :func:`write_html_report`
writes the page ``page.py`` builds. Both write from the records alone, so they always agree.
"""
from __future__ import annotations

import html
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.records import one_version
from rsb_maniskill.evaluation.store import RECORDS_FILE, folder_name, read_records
from rsb_maniskill.outdirs import naming
from rsb_maniskill.reporting import sections
from rsb_maniskill.reporting.leaderboard_files import write_text
from rsb_maniskill.reporting.results import run_provenance, write_results
from rsb_maniskill.reporting.summary import Results, plot_summary, write_csv, write_json, write_markdown

REPORT_FILE = "report.html"


class ReportError(RuntimeError):
    """The results directory holds nothing to report."""


def write_report(results: Results, out_dir: str | os.PathLike, stem: str = "summary",
                 records: Iterable[Mapping[str, Any]] | None = None, partial: str | None = None) -> dict[str, Path]:
    """Write ``<stem>.json``, ``<stem>.csv``, ``<stem>.md`` and one ``<stem>_<row>.png`` per row,
    each naming the benchmark version (of ``records``, else this code's); with ``records``, also
    ``results.json`` (``results.py``); when they hold perturbed episodes, the robustness tables go
    into the JSON (``robustness``) and the Markdown too; with records of a policy that talks, Table 5
    goes into them (``reasoning_following``) and into ``<stem>_reasoning.csv``; with ``rsb backbone``
    answers in ``out_dir``, the backbone's accuracy and the semantic gap (``backbone``,
    ``<stem>_gap.csv``, ``<stem>_gap.png``); with records, the per-category and bias tables
    (``categories``, ``bias``, ``<stem>_categories.csv``, ``<stem>_bias.csv``);
    with counterfactual-scene records, the follow / switch /
    stuck rates (``counterfactual``, ``<stem>_counterfactual.csv``, ``<stem>_counterfactual.png``).
    ``partial`` (a run stopped before its end: ``"partial: interrupted, 12 of 30 episodes"``) heads
    the Markdown and is the JSON's ``partial``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    # every file is written into a hidden folder first and moved into place at the end: a full disk
    # or a kill leaves the previous summaries whole, never a half-written (or 0-byte) one
    records = list(records) if records is not None else []
    for stale in out.glob(f".{stem}.tmp*"):  # a killed run's
        shutil.rmtree(stale, ignore_errors=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{stem}.tmp", dir=out))
    try:
        with naming(out):  # an error writing an open file (ENOSPC) names the folder
            staged = _write_report(results, out, stage, stem, records, partial)
            for done in sorted(stage.iterdir()):
                os.replace(done, out / done.name)
            paths = {key: out / path.name if path is not None else None for key, path in staged.items()}
            if records:  # (whole, as its own; it reads the run's settings in out)
                paths["results"] = write_results(out, records)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return paths


def _write_report(results: Results, out: Path, stage: Path, stem: str, records: list[Mapping[str, Any]],
                  partial: str | None) -> dict[str, Path]:
    """:func:`write_report`'s summaries, written into ``stage`` (``out`` is read: rsb backbone's answers)."""
    from rsb_maniskill.version import BENCHMARK_VERSION

    version = one_version(records) or BENCHMARK_VERSION
    paths = {
        "json": write_json(results, stage / f"{stem}.json", version),
        "csv": write_csv(results, stage / f"{stem}.csv", version),
        "markdown": write_markdown(results, stage / f"{stem}.md", version),
    }
    if partial:
        mark_partial(paths, partial)
    if records:
        mark_episodes(paths, records, out)
    for section in sections.SECTIONS:  # each appends to summary.{json,md} and writes its own files
        table = section.compute(records, out)
        if table is not None:
            append_section(paths, section.key, section.to_json(table), section.markdown(table))
            paths.update(section.files(table, stage, stem))
    for label, row in results.items():
        if row:
            png = stage / f"{stem}_{folder_name(label, strict=False)}.png"  # a file a row, never two rows
            paths[f"png:{label}"] = plot_summary(row, png, title=f"{label}: GSR and TSR")
    return paths


def mark_partial(paths: Mapping[str, Path], partial: str) -> None:
    """Say on the summaries that they cover part of the run asked for: the JSON's ``partial``, the
    Markdown's first line."""
    summary = json.loads(paths["json"].read_text(encoding="utf-8"))
    paths["json"].write_text(json.dumps({"partial": partial, **summary}, indent=2) + "\n", encoding="utf-8")
    paths["markdown"].write_text(f"**{partial}**\n\n" + paths["markdown"].read_text(encoding="utf-8"),
                                 encoding="utf-8")


def mark_episodes(paths: Mapping[str, Path], records: Sequence[Mapping[str, Any]], out: Path) -> None:
    """The records' verdict (``evaluation/provenance.py``) as results.json and the page give it: the
    JSON's ``episodes``; a run whose episodes are not the version's, or were not re-checked (no
    question data at hand, the version's as the results.json in ``out`` proved), says so on the
    Markdown's first line."""
    from rsb_maniskill.evaluation.provenance import PINNED

    found = run_provenance(records, out)  # (before write_results replaces the results.json it reads)
    summary = json.loads(paths["json"].read_text(encoding="utf-8"))
    paths["json"].write_text(json.dumps({"episodes": found.verdict, **summary}, indent=2) + "\n", encoding="utf-8")
    if found.verdict != PINNED or found.kept:
        paths["markdown"].write_text(f"**{found.text()}**\n\n" + paths["markdown"].read_text(encoding="utf-8"),
                                     encoding="utf-8")


def append_section(paths: Mapping[str, Path], key: str, data: Any, markdown: str) -> None:
    """Add ``data`` under ``key`` to the summary JSON and ``markdown`` to the end of its Markdown."""
    summary = json.loads(paths["json"].read_text(encoding="utf-8"))
    summary[key] = data
    paths["json"].write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    with open(paths["markdown"], "a", encoding="utf-8") as f:
        f.write("\n" + markdown)


def write_html_report(results_dir: str | os.PathLike, out: str | os.PathLike | None = None,
                      records: Sequence[Mapping[str, Any]] | None = None, title: str | None = None,
                      partial: str | None = None) -> Path:
    """Write ``report.html`` for the episodes of ``results_dir`` (or ``records``); returns its path.
    ``partial`` (as :func:`write_report`'s) is shown under the page's title."""
    from rsb_maniskill.reporting.page import build_html

    results_dir = Path(results_dir)
    if records is None:
        if not (results_dir / RECORDS_FILE).exists():
            raise ReportError(f"{results_dir} has no {RECORDS_FILE}: give the --out directory of an `rsb eval` run")
        records = read_records(results_dir / RECORDS_FILE)
    if not records:
        raise ReportError(f"{results_dir / RECORDS_FILE} holds no episode records yet")
    path = page_path(results_dir, out)
    page = build_html(records, results_dir, title)
    if partial:  # under the title, before the page's own line
        page = page.replace("</h1>", f'</h1><p class="meta"><b>{html.escape(partial)}</b></p>', 1)
    write_text(path, page)  # through a temporary file beside it, removed on every path
    return path


def page_path(results_dir: str | os.PathLike, out: str | os.PathLike | None = None) -> Path:
    """Where the page goes: ``out`` (a folder: ``out/report.html``), else ``RESULTS_DIR/report.html``.
    Checked before anything is written: its folder must exist and take files."""
    path = Path(out) if out is not None else Path(results_dir) / REPORT_FILE
    if path.is_dir():
        path = path / REPORT_FILE
    if not path.parent.is_dir():
        raise ReportError(f"cannot write the page {path}: {path.parent} is not a folder; give a page path in an "
                          "existing folder")
    if not writable(path.parent):
        raise ReportError(f"cannot write the page {path}: {path.parent} is read-only; give a page path in a "
                          "writable folder")
    return path


def writable(folder: str | os.PathLike) -> bool:
    """Whether files can be created in ``folder``."""
    return os.access(folder, os.W_OK | os.X_OK)
