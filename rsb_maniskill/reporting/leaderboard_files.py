"""The files of ``rsb leaderboard``: ``leaderboard.md``, ``leaderboard.csv`` and ``index.html``.

All three show the same table (``leaderboard.py``): models as rows, suites as columns, GSR / TSR /
nSG with their Wilson 95 % intervals, the Avg over the paper's suites, each model's episodes,
checkpoint, protocol tags, benchmark version and run, and the Random line. The page is one
self-contained file (styles, script and data inline, nothing from the network): a click on a
header sorts by that column, buttons switch the metric shown. Its markup is the Jinja template
``templates/leaderboard.html.j2`` (with ``leaderboard.css`` and ``leaderboard.js``), rendered with
the environment of ``page.py``. Files are written whole or not at all.
"""
from __future__ import annotations

import csv
import io
import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping

from rsb_maniskill.evaluation.metrics import num_choices
from rsb_maniskill.reporting.cells import NA, NONE_AT_N, ci, markdown_table, p_value, pct, points
from rsb_maniskill.reporting.leaderboard import Entry, Leaderboard, protocol_text, unverified_notes

PAGE_TEMPLATE = "leaderboard.html.j2"
FILES = {"markdown": "leaderboard.md", "csv": "leaderboard.csv", "html": "index.html"}
METRICS = (  # key, short name, what it measures
    ("tsr", "TSR", "Task success rate: the correct block placed in the answer zone"),
    ("gsr", "GSR", "Grasp success rate: a candidate block grasped"),
    ("nsg", "nSG", "Normalized semantic grounding: the choice among grasps, 0 = random target, 1 = always the "
                   "right one"),
)
SHORT, OFF_SEEDS, PARTIAL = "\u2020", "\u2021", "*"  # the marks: dagger, double dagger, star
DIFFERS = "\u00a7"  # section sign: TSR differs significantly from the best row's
OTHER_EPISODES = "\u2260"  # the row's episodes are not the benchmark version's
MISSING = "\u2014"  # a suite the row did not run
UNDEFINED = "not defined"  # the Random line's GSR
CSV_FIELDS = (
    "model", "suite_id", "n_choices", "n_episodes", "protocol_seeds", "gsr", "gsr_low", "gsr_high", "tsr", "tsr_low",
    "tsr_high", "nsg", "nsg_low", "nsg_high", "avg_complete", "short", "off_seeds", "episodes", "differs_from_best",
    "vs_best_test", "vs_best_p", "vs_best_p_holm", "tsr_detectable_difference", "checkpoint", "instruction_mode",
    "perturb", "split",
    "instructions", "benchmark_version", "run",
)


def short_suite(suite_id: str) -> str:
    return suite_id.removeprefix("RSB-")


def marks(e: Entry, metric: str | None = "tsr") -> str:
    """``" †‡§"``: fewer episodes than the protocol's, other seeds than the protocol's, and, on the
    TSR table only (``metric``: the one tested), TSR significantly different from the best row's."""
    m = (SHORT if e.short else "") + (OFF_SEEDS if e.off_seeds else "") + (
        DIFFERS if e.differs and metric == "tsr" else "") + (
        OTHER_EPISODES if not e.random and e.provenance == "differ" else "")
    return f" {m}" if m else ""


def mde_text(e: Entry) -> str:
    """The TSR difference the row's episodes can detect, in points (``"±12.3"``; "none at this n" where
    McNemar's exact test cannot reach 80 % power at any difference)."""
    if e.random:
        return MISSING
    over = e.avg.present if e.avg and e.avg.present else list(e.row["suites"])
    if all(e.row["suites"][s]["tsr"]["value"] is None for s in over if s in e.row["suites"]):
        return NA
    return points(e.tsr_mde, NONE_AT_N)


def protocol_tag(board: Leaderboard) -> tuple[str, str]:
    """The protocol in a cell: ``("normal · unperturbed", "test/unseen")``: the instruction mode and
    the perturbation, then the split and the instruction templates."""
    p = board.protocol
    perturb = "unperturbed" if p["perturb"] == "none" else p["perturb"]
    return f"{p['instruction_mode']} \u00b7 {perturb}", f"{p['split']}/{p['instructions']}"


def episodes_text(e: Entry) -> str:
    if e.episodes is None:
        return MISSING
    lo, hi = e.episodes
    return str(lo) if lo == hi else f"{lo}\u2013{hi}"


def cell_text(e: Entry, suite: str, key: str) -> tuple[str, str]:
    """A cell as (value, interval): ``("25.0", "[21.4, 29.0]")``; the Random line's exact values."""
    s = e.row["suites"].get(suite)
    if s is None:
        return MISSING, ""
    r = s[key]
    if e.random:
        return {"gsr": (UNDEFINED, ""), "tsr": (pct(r["value"]), f"1/{s['n_choices']}"),
                "nsg": (pct(r["value"]), "by definition")}[key]
    if r["value"] is None:
        return NA, "no grasp"
    return pct(r["value"]), ci(r["value"], r["low"], r["high"]).partition(" ")[2]


def avg_text(e: Entry, key: str) -> str:
    if e.avg is None:
        return MISSING
    value = getattr(e.avg, key)
    if value is None:
        return UNDEFINED if e.random and key == "gsr" else NA
    return pct(value) + ("" if e.avg.complete else PARTIAL)


# ---------------------------------------------------------------- Markdown and CSV
def _md(text: str) -> str:
    """Text in a Markdown table: its pipes and stars escaped."""
    return text.replace("|", "\\|").replace("*", "\\*")


def _md_cell(value: str, interval: str) -> str:
    return f"{value} {interval}" if interval.startswith("[") else value  # the Random line: its exact value


def notes(board: Leaderboard) -> list[str]:
    """What the marks and the Random line mean."""
    from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE
    from rsb_maniskill.version import benchmark_label

    out = [f"{SHORT} fewer episodes than the protocol's {EPISODES_PER_SUITE} in a suite: wider intervals, not a "
           f"full-protocol row. {OFF_SEEDS} a suite's episodes are not the protocol's seeds.",
           f"{PARTIAL} Avg over the suites the row ran of the {len(board.avg_suites)} it is over "
           f"({', '.join(map(short_suite, board.avg_suites))}), not all; nSG over those where it is defined.",
           f"{board.entries[-1].label}: random target selection among the N candidates: TSR = 1/N and nSG = 0 by "
           "definition; GSR is not defined for it."]
    if any(not e.random and e.provenance == "differ" for e in board.entries):
        out.append(f"{OTHER_EPISODES} episodes differ from {benchmark_label(board.benchmark_version)}: its records "
                   "asked other questions (other question data), not comparable with the others.")
    out += unverified_notes(board)  # each reason the true one: no data at hand, no digests, as a file says
    out += difference_notes(board)
    out.append("Detectable TSR difference: the smallest difference from a row's TSR (pooled over its Avg suites) that "
               "a paired comparison on its episodes (the same seeds, McNemar's exact test at p < 0.05, its power "
               f"computed exactly) finds 4 times in 5; {NONE_AT_N}: that test cannot reach it at any difference "
               "(under 6 episodes it cannot reject at all); a smaller one needs more episodes (`rsb plan`).")
    twice = [f"{e.label} ({e.run.source}; also in {', '.join(e.also)})" for e in board.entries if e.also]
    if twice:
        out.append("The same run given twice, listed once: " + "; ".join(twice) + ".")
    return out if board.avg_suites else [n for n in out if not n.startswith(PARTIAL)]


def difference_notes(board: Leaderboard) -> list[str]:
    """How each row was tested against the best row, the family, and what the test said."""
    from rsb_maniskill.reporting.leaderboard import ALPHA, PAIRED

    tested = [e for e in board.entries if e.test_best]
    if not tested:
        return []
    best = next(e for e in board.entries if not e.random and not e.test_best and e.provenance != "differ")
    models = sum(not e.random for e in board.entries)
    words = []
    for e in tested:
        how = "paired, exact McNemar" if e.test_best == PAIRED else "unpaired, two-proportion z test"
        if e.p_best is None:
            words.append(f"{e.label}: {how}: not tested (under 5 expected successes or failures a run)")
            continue
        words.append(f"{e.label}{' ' + DIFFERS if e.differs else ''}: {how} p = {p_value(e.p_best)}, "
                     f"Holm p = {p_value(e.p_holm)}")
    return [f"{DIFFERS} TSR differs significantly from the best row's ({best.label}): Holm p < {ALPHA}. Test: paired "
            "(McNemar's exact test over the episodes both ran, in the suites both ran) where their records share "
            "episodes, else unpaired (the pooled two-proportion z test of their TSR over those suites; none where a "
            f"run expects under 5 successes or failures). Family: every pair of the {models} rows "
            f"({max(e.family for e in tested)} tests), Holm's correction: the best row is picked from the data, "
            "so only a correction over all pairs keeps the chance of any mark between identical rows at "
            f"{ALPHA}. " + "; ".join(words) + "."]


def leaderboard_markdown(board: Leaderboard, title: str) -> str:
    """Three tables (TSR, GSR, nSG), each cell with its interval; the TSR table with each model's
    episodes per suite, checkpoint, protocol, benchmark version and run."""
    from rsb_maniskill.version import benchmark_label

    tag, version = " \u00b7 ".join(protocol_tag(board)), benchmark_label(board.benchmark_version)
    head = ["Model", *map(short_suite, board.suites)] + (["Avg"] if board.avg_suites else [])
    out = [f"# {_md(title)}", "",
           f"Benchmark: {version}. Protocol: {protocol_text(board.protocol)}. Cells: rate in % and its Wilson 95 % "
           "interval.", ""]
    for key, name, what in METRICS:
        rows = []
        for e in board.entries:
            cells = [_md_cell(*cell_text(e, s, key)) for s in board.suites]
            extra = [_md(avg_text(e, key))] if board.avg_suites else []
            if key == "tsr":
                extra += [episodes_text(e), _md(e.row.get("checkpoint") or MISSING),
                          MISSING if e.random else tag, MISSING if e.random else version,
                          _md(e.run.source) if e.run else MISSING]
                extra.append(mde_text(e))
            rows.append([_md(e.label) + marks(e, key), *cells, *extra])
        more = (["Episodes / suite", "Checkpoint", "Protocol", "Benchmark", "Run", "Detectable TSR difference"]
                if key == "tsr" else [])
        out += [f"### {name} (%): {what}", "", markdown_table([*head, *more], rows), ""]
    return "\n".join(out + [f"- {_md(n)}" for n in notes(board)]) + "\n"


def csv_rows(board: Leaderboard) -> list[dict[str, Any]]:
    """One line per (model, suite) and an ``Avg`` line per model; rates as fractions."""
    p, out = board.protocol, []
    for e in board.entries:
        common = {"model": e.label, "checkpoint": e.row.get("checkpoint"), "short": e.short, "off_seeds": e.off_seeds,
                  "episodes": None if e.random else e.provenance, "differs_from_best": e.differs,
                  "vs_best_test": e.test_best, "vs_best_p": e.p_best, "vs_best_p_holm": e.p_holm,
                  "tsr_detectable_difference": e.tsr_mde,
                  "instruction_mode": p["instruction_mode"], "perturb": p["perturb"], "split": p["split"],
                  "instructions": p["instructions"], "benchmark_version": board.benchmark_version,
                  "run": e.run.source if e.run else None}
        for suite, s in e.row["suites"].items():
            rates = {f"{k}{part}": s[k][v] for k in ("gsr", "tsr", "nsg")
                     for part, v in (("", "value"), ("_low", "low"), ("_high", "high"))}
            out.append({**common, "suite_id": suite, "n_choices": s["n_choices"], "n_episodes": s["n"],
                        "protocol_seeds": s["protocol_seeds"], **rates})
        if e.avg is not None:
            out.append({**common, "suite_id": "Avg", "gsr": e.avg.gsr, "tsr": e.avg.tsr, "nsg": e.avg.nsg,
                        "avg_complete": e.avg.complete})
    return out


def leaderboard_csv(board: Leaderboard) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_FIELDS, lineterminator="\n")
    w.writeheader()
    for r in csv_rows(board):
        w.writerow({k: "" if r.get(k) is None else r[k] for k in CSV_FIELDS})
    return buf.getvalue()


# ---------------------------------------------------------------- the page
def _sort_value(x: float | None) -> str:
    return "" if x is None else repr(round(x, 6))


def _cell(e: Entry, suite: str) -> dict[str, Any]:
    s = e.row["suites"].get(suite)
    return {"missing": s is None, "n": s and s["n"],
            "sort": {k: _sort_value(s[k]["value"] if s else None) for k, _, _ in METRICS},
            "text": {k: cell_text(e, suite, k) for k, _, _ in METRICS}}


def page_rows(board: Leaderboard) -> list[dict[str, Any]]:
    """What the template shows of each entry."""
    from rsb_maniskill.version import benchmark_label

    rows = []
    for e in board.entries:
        avg = {"missing": e.avg is None, "n": None,
               "sort": {k: _sort_value(getattr(e.avg, k) if e.avg else None) for k, _, _ in METRICS},
               "text": {k: (avg_text(e, k), "") for k, _, _ in METRICS}}
        rows.append({"label": e.label, "marks": marks(e, None).strip(), "tsr_marks": DIFFERS if e.differs else "",
                     "random": e.random,
                     "cells": [_cell(e, s) for s in board.suites], "avg": avg,
                     "episodes": episodes_text(e), "episodes_sort": e.episodes[0] if e.episodes else "",
                     "checkpoint": e.row.get("checkpoint") or "", "tag": "" if e.random else protocol_tag(board),
                     "version": "" if e.random else benchmark_label(board.benchmark_version),
                     "source": e.run.source if e.run else ""})
    return rows


def leaderboard_html(board: Leaderboard, title: str) -> str:
    from rsb_maniskill.reporting.page import templates
    from rsb_maniskill.version import benchmark_label, code_label

    return templates().get_template(PAGE_TEMPLATE).render(
        title=title, version=benchmark_label(board.benchmark_version), protocol=protocol_text(board.protocol),
        code=code_label(), stamp=datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        suites=[{"id": s, "short": short_suite(s), "n": num_choices(s)} for s in board.suites],
        has_avg=bool(board.avg_suites),
        avg_over=len(board.avg_suites), metrics=[{"key": k, "name": n, "what": w} for k, n, w in METRICS],
        rows=page_rows(board), n_models=len(board.entries) - 1, notes=notes(board))


# ---------------------------------------------------------------- writing
def write_text(path: Path, text: str) -> Path:
    """``text`` into ``path`` whole: a reader never sees half of it."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def render_leaderboard(board: Leaderboard, title: str = "RSB leaderboard") -> dict[str, str]:
    """The three files' contents, by ``FILES`` key (rendered before anything is written)."""
    return {"markdown": leaderboard_markdown(board, title), "csv": leaderboard_csv(board),
            "html": leaderboard_html(board, title)}


def write_leaderboard(contents: Mapping[str, str], out_dir: str | os.PathLike) -> dict[str, Path]:
    """Write ``render_leaderboard``'s files into ``out_dir``; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return {key: write_text(out / FILES[key], text) for key, text in contents.items()}
