"""Table 5 of the paper for policies that talk: what they stated against what their arm grasped.

Rows are the policy rows of ``summary.py`` whose records carry a text (``statements.py``); each
suite gets the paper's layout (error types down, policies across) over the grasped-but-failed
episodes, and a second table crosses the statement with the grasp over all grasped episodes.
Shares are percentages with Wilson 95 % intervals. Written into ``summary.{md,json}``,
``summary_reasoning.csv`` and ``report.html``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import Rate, group_by_suite, suite_order
from rsb_maniskill.evaluation.records import dedupe, perturb_label, row_label
from rsb_maniskill.evaluation.statements import (
    FAILURE_LABELS,
    FAILURES,
    STATEMENTS,
    ReasoningFollowing,
    reasoning_following,
    talks,
)
from rsb_maniskill.reporting.blocks import Block, Grid, Heading, Note, to_markdown
from rsb_maniskill.reporting.cells import rate_cell
from rsb_maniskill.reporting.sections.base import Section, write_rows

Table = Mapping[str, Mapping[str, ReasoningFollowing]]
STATED = {"right": "Stated right", "wrong": "Stated wrong", "none": "No statement"}


def reasoning_table(records: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, ReasoningFollowing]]:
    """{row label: {suite: Table 5}} for the rows whose policy talked in any episode."""
    rows: dict[str, list[Mapping[str, Any]]] = {}
    for r in dedupe(records):
        rows.setdefault(row_label(str(r.get("policy", "?")), r.get("instruction_mode", "normal"), perturb_label(r)),
                        []).append(r)
    out = {}
    for label, recs in rows.items():
        if talks(recs):
            groups = group_by_suite(recs)
            out[label] = {s: reasoning_following(groups[s], s) for s in suite_order(groups)}
    return out


def reasoning_blocks(table: Table) -> list[Block]:
    """Per suite, Table 5 (error types x policies), then the statement x grasp crossing."""
    if not table:
        return []
    labels = list(table)
    suites = suite_order({s for row in table.values() for s in row})
    out: list[Block] = []
    for s in suites:
        present = [label for label in labels if s in table[label]]
        rows = [[FAILURE_LABELS[k]] + [rate_cell(table[label][s].failure_rates()[k]) for label in present]
                for k in FAILURES]
        rows.append(["Grasped-but-failed episodes (count)"] + [str(table[label][s].n_grasped_failed)
                                                                 for label in present])
        out += [Heading(f"Reasoning following on {s} (%, paper Table 5)"),
                Note("Shares of the grasped-but-failed episodes: what the policy's text stated against the "
                     "block it grasped."),
                Grid(["Error type"] + present, rows)]
    cells = [(said, grasp) for said in STATEMENTS for grasp in ("right", "wrong")]
    header = ["Policy", "Suite"] + [f"{STATED[said]} · grasped {grasp}" for said, grasp in cells] + [
        "Grasped episodes", "Stated right (% of episodes)"]
    rows = [[label, s] + [rate_cell(t.crossing_rates()[f"{said}/{grasp}"]) for said, grasp in cells]
            + [str(t.n_grasped), rate_cell(t.stated_right_rate())]
            for label in labels for s, t in table[label].items()]
    return out + [Heading("Statement and grasp (% of grasped episodes)"),
                  Note("Grasped right: the correct block was grasped (placed or not); grasped wrong: only wrong "
                       "blocks."),
                  Grid(header, rows)]


def reasoning_markdown(table: Table) -> str:
    return to_markdown(reasoning_blocks(table))


def reasoning_rows(table: Table) -> list[dict[str, Any]]:
    """Long format, one row per (policy row, suite, cell): ``part`` is ``failures`` (of the
    grasped-but-failed), ``crossing`` (of the grasped) or ``stated`` (of all episodes)."""
    out = []
    for label, row in table.items():
        for s, t in row.items():
            parts = [("failures", k, t.failures[k], t.n_grasped_failed) for k in FAILURES]
            parts += [("crossing", k, v, t.n_grasped) for k, v in t.crossing.items()]
            parts.append(("stated", "right", t.n_stated_right, t.n_episodes))
            for part, cell, k, n in parts:
                rate = Rate.of(k, n)
                out.append({"row": label, "suite_id": s, "part": part, "cell": cell, "count": k, "n": n,
                            "value": rate.value, "low": rate.low, "high": rate.high})
    return out


def reasoning_json(table: Table) -> dict[str, Any]:
    return {label: {s: t.to_dict() for s, t in row.items()} for label, row in table.items()}


class ReasoningSection(Section):
    key, anchor, title, page_order, lead = "reasoning_following", "reasoning", "Reasoning following", 20, ""
    summary_order = 20
    note = ("For policies that return text: of the episodes where a block was grasped and the task failed, did the "
            "text state the right option while the arm took a wrong block (the reasoning-following failure), a "
            "wrong option, or none? In brackets: Wilson 95% intervals.")

    def compute(self, records: Sequence[Mapping[str, Any]], results_dir: Path) -> Table | None:
        return reasoning_table(records) or None

    def to_json(self, table: Table) -> Any:
        return reasoning_json(table)

    def blocks(self, table: Table) -> list[Block]:
        return reasoning_blocks(table)

    def files(self, table: Table, out: Path, stem: str) -> dict[str, Path]:
        return {"csv:reasoning": write_rows(reasoning_rows(table), out / f"{stem}_reasoning.csv")}


SECTION = ReasoningSection()
