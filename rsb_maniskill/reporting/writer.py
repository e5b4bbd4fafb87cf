"""Writing a results directory's reports: the summary files with every section, and report.html.

:func:`write_report` writes ``summary.{json,csv,md}`` (``summary.py``: the paper's tables), then
appends the sections the records call for: robustness (``robustness.py``), reasoning following
(``reasoning.py``) and, with ``rsb backbone`` answers beside the records, the semantic gap
(``gap.py``); and ``results.json`` (``results.py``). :func:`write_html_report` writes the page
``page.py`` builds. Both write from the records alone, so they always agree.
"""
from __future__ import annotations

import csv
import html
import json
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.records import one_version
from rsb_maniskill.evaluation.store import BACKBONE_FILE, RECORDS_FILE, read_backbone_records, read_records, safe_name
from rsb_maniskill.reporting.reasoning import reasoning_json, reasoning_markdown, reasoning_rows, reasoning_table
from rsb_maniskill.reporting.results import write_results
from rsb_maniskill.reporting.robustness import robustness_markdown, robustness_rows, robustness_table
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
    from rsb_maniskill.version import BENCHMARK_VERSION

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    records = list(records) if records is not None else []
    version = one_version(records) or BENCHMARK_VERSION
    paths = {
        "json": write_json(results, out / f"{stem}.json", version),
        "csv": write_csv(results, out / f"{stem}.csv", version),
        "markdown": write_markdown(results, out / f"{stem}.md", version),
    }
    if partial:
        mark_partial(paths, partial)
    if records:
        paths["results"] = write_results(out, records)
    table = robustness_table(records)
    if table:
        append_section(paths, "robustness", robustness_rows(table), robustness_markdown(table))
    reasoning = reasoning_table(records)
    if reasoning:
        append_section(paths, "reasoning_following", reasoning_json(reasoning), reasoning_markdown(reasoning))
        paths["csv:reasoning"] = write_rows(reasoning_rows(reasoning), out / f"{stem}_reasoning.csv")
    paths.update(_write_gap(paths, out, stem, records))
    paths.update(_write_why(paths, out, stem, records))
    paths.update(_write_counterfactual(paths, out, stem, records))
    for label, row in results.items():
        if row:
            png = out / f"{stem}_{safe_name(label)}.png"
            paths[f"png:{label}"] = plot_summary(row, png, title=f"{label}: GSR and TSR")
    return paths


def _write_gap(paths: Mapping[str, Path], out: Path, stem: str, records: Sequence[Mapping[str, Any]]
               ) -> dict[str, Path]:
    """The backbone section when ``out`` holds ``rsb backbone`` answers; the gap's CSV and plot."""
    from rsb_maniskill.reporting.gap import backbone_markdown, gap_json, gap_markdown, gap_rows, gap_table, plot_gap

    if not (out / BACKBONE_FILE).exists():
        return {}
    answers = read_backbone_records(out / BACKBONE_FILE)
    table = gap_table(records, answers)
    append_section(paths, "backbone", gap_json(answers, table), backbone_markdown(answers) + "\n" + gap_markdown(table))
    if not table[0]:
        return {}
    png = out / f"{stem}_gap.png"
    png.write_bytes(plot_gap(table[0]))
    return {"csv:gap": write_rows(gap_rows(table[0]), out / f"{stem}_gap.csv"), "png:gap": png}


def _write_why(paths: Mapping[str, Path], out: Path, stem: str, records: Sequence[Mapping[str, Any]]
               ) -> dict[str, Path]:
    """Why a policy fails: the per-category tables (``categories``, ``<stem>_categories.csv``; a
    note instead when the records carry no categories) and the bias tables (``bias``,
    ``<stem>_bias.csv``)."""
    from rsb_maniskill.evaluation.bias import bias_table
    from rsb_maniskill.evaluation.categories import category_tables
    from rsb_maniskill.reporting.bias import bias_json, bias_markdown, bias_rows
    from rsb_maniskill.reporting.categories import categories_json, categories_markdown, categories_rows

    if not records:
        return {}
    tables = category_tables(records)
    append_section(paths, "categories", categories_json(tables), categories_markdown(tables))
    bias = bias_table(records)
    append_section(paths, "bias", bias_json(bias), bias_markdown(bias))
    written = {"csv:bias": write_rows(bias_rows(bias), out / f"{stem}_bias.csv")}
    rows = categories_rows(tables)
    if rows:
        written["csv:categories"] = write_rows(rows, out / f"{stem}_categories.csv")
    return written


def _write_counterfactual(paths: Mapping[str, Path], out: Path, stem: str, records: Sequence[Mapping[str, Any]]
                          ) -> dict[str, Path]:
    """The counterfactual section when the records hold ``--instruction counterfactual`` runs: the
    summary's ``counterfactual`` section, ``<stem>_counterfactual.csv`` and ``.png``."""
    from rsb_maniskill.evaluation.counterfactual import counterfactual_json, counterfactual_table
    from rsb_maniskill.reporting.counterfactual import counterfactual_markdown, counterfactual_rows, plot_counterfactual

    table = counterfactual_table(records)
    if not table:
        return {}
    append_section(paths, "counterfactual", counterfactual_json(table), counterfactual_markdown(table))
    png = out / f"{stem}_counterfactual.png"
    png.write_bytes(plot_counterfactual(table))
    return {"csv:counterfactual": write_rows(counterfactual_rows(table), out / f"{stem}_counterfactual.csv"),
            "png:counterfactual": png}


def mark_partial(paths: Mapping[str, Path], partial: str) -> None:
    """Say on the summaries that they cover part of the run asked for: the JSON's ``partial``, the
    Markdown's first line."""
    summary = json.loads(paths["json"].read_text(encoding="utf-8"))
    paths["json"].write_text(json.dumps({"partial": partial, **summary}, indent=2) + "\n", encoding="utf-8")
    paths["markdown"].write_text(f"**{partial}**\n\n" + paths["markdown"].read_text(encoding="utf-8"),
                                 encoding="utf-8")


def append_section(paths: Mapping[str, Path], key: str, data: Any, markdown: str) -> None:
    """Add ``data`` under ``key`` to the summary JSON and ``markdown`` to the end of its Markdown."""
    summary = json.loads(paths["json"].read_text(encoding="utf-8"))
    summary[key] = data
    paths["json"].write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    with open(paths["markdown"], "a", encoding="utf-8") as f:
        f.write("\n" + markdown)


def write_rows(rows: Sequence[Mapping[str, Any]], path: str | os.PathLike) -> Path:
    """Rows of plain values as a CSV file, columns in the first row's order (None as empty)."""
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else [])
        w.writeheader()
        for r in rows:
            w.writerow({k: "" if v is None else v for k, v in r.items()})
    return path


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
    path = Path(out) if out is not None else results_dir / REPORT_FILE
    page = build_html(records, results_dir, title)
    if partial:  # under the title, before the page's own line
        page = page.replace("</h1>", f'</h1><p class="meta"><b>{html.escape(partial)}</b></p>', 1)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(page, encoding="utf-8")
    os.replace(tmp, path)  # a reader never sees half a page
    return path
