"""Confusion matrices: which option (by letter) and which place (by position from the left) a policy
grasped first, against the correct one.

The bias section asks whether a policy favours a choice overall; these tables show *what it takes
for what*: a policy that reads the options but mixes up their binding puts its grasps off the
diagonal in a pattern (B for A), one that ignores the instruction spreads them evenly or piles them
in one column. Rows: the correct option / the correct candidate's position; columns: the first
candidate grasped, with ``none`` for episodes without a grasp. Rendered on the page from the rows
(:meth:`ConfusionSection.html`), not from its Markdown.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

from markupsafe import Markup, escape

from rsb_maniskill.evaluation.metrics import group_by_suite, num_choices, suite_order
from rsb_maniskill.evaluation.records import LEFT_RANK_FIELD, dedupe, record_row
from rsb_maniskill.evaluation.stats import confusion
from rsb_maniskill.reporting.cells import markdown_table
from rsb_maniskill.reporting.sections.base import Section, write_rows

LETTER, POSITION = "option letter", "position"
NONE = "none"  # the column of episodes without a grasp
HIT = '<td class="hit">'  # a diagonal cell: chosen = correct

Matrix = dict[str, dict[str, int]]  # {correct: {chosen: count}}
Table = dict[str, dict[str, dict[str, Matrix]]]  # {row label: {suite: {axis: matrix}}}


def suite_confusion(records: Sequence[Mapping[str, Any]], suite_id: str) -> dict[str, Matrix]:
    """The letter and position matrices of one policy row on one suite (an axis is left out when a
    record lacks what it needs: its spec, its left-to-right ranks)."""
    n = num_choices(suite_id)
    out: dict[str, Matrix] = {}
    if records and all(r.get("episode") for r in records):
        chosen, correct, letters = [], [], None
        for r in records:
            spec = r["episode"]
            letters = letters or list(spec["letters"])
            boo, g = list(spec["block_of_option"]), int(r.get("first_grasped", -1))
            chosen.append(spec["letters"][boo.index(g)] if g >= 0 else None)
            correct.append(spec["letters"][int(spec["answer_slot"])])
        out[LETTER] = confusion(chosen, correct, letters)
    if records and all(r.get(LEFT_RANK_FIELD) for r in records):
        chosen, correct = [], []
        for r in records:
            ranks, g = r[LEFT_RANK_FIELD], int(r.get("first_grasped", -1))
            chosen.append(int(ranks[g]) + 1 if g >= 0 else None)
            correct.append(int(ranks[int(r["target_block"])]) + 1)
        out[POSITION] = confusion(chosen, correct, list(range(1, n + 1)))
    return out


def confusion_table(records: Sequence[Mapping[str, Any]]) -> Table:
    """{row label: {suite: {axis: matrix}}} for every row of ``records`` (deduplicated)."""
    rows: dict[str, list[Mapping[str, Any]]] = {}
    for r in dedupe(records):
        rows.setdefault(record_row(r), []).append(r)
    out: Table = {}
    for label, recs in rows.items():
        groups = group_by_suite(recs)
        suites = {s: suite_confusion(groups[s], s) for s in suite_order(groups)}
        if any(suites.values()):
            out[label] = {s: m for s, m in suites.items() if m}
    return out


def _columns(matrix: Matrix) -> list[str]:
    return list(next(iter(matrix.values())))


def rows_of(table: Table) -> list[dict[str, Any]]:
    """One row per (policy row, suite, axis, correct value, chosen value): the CSV."""
    return [{"row": label, "suite_id": suite, "axis": axis, "correct": c, "chosen": ch, "episodes": k}
            for label, suites in table.items() for suite, axes in suites.items()
            for axis, matrix in axes.items() for c, cols in matrix.items() for ch, k in cols.items()]


class ConfusionSection(Section):
    key, anchor, title, nav = "confusion", "confusion", "Chosen against correct", "Confusion"
    summary_order, page_order = 55, 75
    note = ("The first candidate grasped in each episode against the correct one, by option letter and by position "
            "from the left in the head camera (rows: correct, columns: chosen; <em>none</em>: no grasp). A policy "
            "that solves the question grasps on the diagonal; one that mixes up the binding, in a pattern off it.")

    def compute(self, records: Sequence[Mapping[str, Any]], results_dir: Path) -> Table | None:
        return confusion_table(records) or None if records else None

    def to_json(self, table: Table) -> Any:
        return table

    def markdown(self, table: Table) -> str:
        blocks = ["## Chosen against correct (first grasp; rows: correct, columns: chosen)"]
        for label, suites in table.items():
            for suite, axes in suites.items():
                for axis, matrix in axes.items():
                    cols = _columns(matrix)
                    blocks.append(f"### {label}, {suite}: {axis}")
                    blocks.append(markdown_table(["correct \\ chosen", *cols],
                                                 [[c, *(str(matrix[c][k]) for k in cols)] for c in matrix]))
        return "\n\n".join(blocks) + "\n"

    def files(self, table: Table, out: Path, stem: str) -> dict[str, Path]:
        return {"csv:confusion": write_rows(rows_of(table), out / f"{stem}_confusion.csv")}

    def html(self, table: Table) -> Markup | None:
        parts = []
        for label, suites in table.items():
            for suite, axes in suites.items():
                for axis, matrix in axes.items():
                    cols = _columns(matrix)
                    head = "".join(f"<th>{escape(c)}</th>" for c in ["correct \\ chosen", *cols])
                    body = "".join(
                        "<tr><th>" + str(escape(c)) + "</th>"
                        + "".join((HIT if k == c else "<td>") + f"{matrix[c][k]}</td>" for k in cols)
                        + "</tr>" for c in matrix)
                    parts.append(f"<h3>{escape(label)}, {escape(suite)}: {escape(axis)}</h3>"
                                 f'<div class="scroll"><table><thead><tr>{head}</tr></thead>'
                                 f"<tbody>{body}</tbody></table></div>")
        return Markup("\n".join(parts))


SECTION = ConfusionSection()
