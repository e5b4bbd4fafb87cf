"""The per-category tables (``evaluation/categories.py``) as Markdown, JSON and CSV rows.

Per policy row and suite, one table: the suite's dimensions one under the other (Math: operator,
answer size; HardMath: reasoning steps, answer size; General: source, MMLU-Pro category; every
suite: instruction template), each value a line of TSR, nSG and first grasp right with Wilson 95 %
intervals and counts; then, for a row that ran both, question suites against the Direct controls.
Cells of fewer than ``SMALL_CELL`` episodes are marked with a dagger (greyed on the page), never
hidden. Written into ``summary.{md,json}``, ``summary_categories.csv`` and ``report.html``.
"""
from __future__ import annotations

from typing import Any, Mapping

from rsb_maniskill.evaluation.categories import SMALL_CELL, CategoryCell, RowCategories
from rsb_maniskill.reporting.cells import markdown_table, rate_cell
from rsb_maniskill.semantic.categories import DIMENSIONS, SUITE_KIND, value_label

Tables = Mapping[str, RowCategories]
SMALL_MARK = "†"  # after the episode count of a cell under SMALL_CELL episodes (the page greys its line)
HEADER = ["Category", "Episodes", "TSR", "nSG", "First grasp right", "First grasps"]
SMALL_NOTE = (f"{SMALL_MARK} fewer than {SMALL_CELL} episodes: shown, but its interval is wide; read it with care.")
RERUN = "Rerun `rsb eval` into a new `--out` directory to get them."
NONE_NOTE = ("The records carry no categories (written before records had them, or by a harness that does not "
             f"record them): no per-category table. {RERUN}")


def _cells(c: CategoryCell) -> list[str]:
    return [f"{c.n_episodes}{SMALL_MARK if c.small else ''}", rate_cell(c.tsr), rate_cell(c.nsg),
            rate_cell(c.first_right), str(c.n_first)]


def _kind_label(kind: str, n: int) -> str:
    return f"{value_label(SUITE_KIND, kind)}, {n} choices"


def has_categories(tables: Tables) -> bool:
    return any(t.suites for t in tables.values())


def categories_markdown(tables: Tables) -> str:
    """Per row and suite the category table, then Direct vs question suites where a row ran both."""
    parts = []
    if not has_categories(tables):
        return "### No per-category tables\n\n" + NONE_NOTE + "\n"
    for label, t in tables.items():
        for s, dims in t.suites.items():
            rows = []
            for d, cells in dims.items():
                rows.append([f"**{DIMENSIONS[d]}**"] + [""] * (len(HEADER) - 1))
                rows += [[value_label(d, v)] + _cells(c) for v, c in cells.items()]
            parts.append(f"### {label} on {s}: by category (%)\n\n" + markdown_table(HEADER, rows))
        if len({k for k, _ in t.kinds}) > 1:
            rows = [[_kind_label(k, n)] + _cells(c) for (k, n), c in t.kinds.items()]
            parts.append(f"### {label}: Direct vs question suites (%)\n\n"
                         "Pooled over the suites of each kind and number of choices.\n\n"
                         + markdown_table(["Suites"] + HEADER[1:], rows))
    skipped = [f"{label} ({t.n_without})" for label, t in tables.items() if t.n_without]
    notes = ["TSR and nSG as in the paper tables, over the episodes of the category; first grasp right: the first "
             "candidate grasped was the target, of the episodes with a grasp (first grasps). In brackets: Wilson "
             "95% intervals.", SMALL_NOTE]
    if skipped:
        notes.append("Records without categories, left out: " + ", ".join(skipped) + ". " + RERUN)
    return "\n\n".join(parts) + "\n\n" + "\n\n".join(notes) + "\n"


def categories_json(tables: Tables) -> dict[str, Any]:
    return {"small_cell": SMALL_CELL, "rows": {label: t.to_dict() for label, t in tables.items()},
            **({} if has_categories(tables) else {"note": NONE_NOTE})}


def _row(label: str, suite: str, n: int, dimension: str, value: str, c: CategoryCell) -> dict[str, Any]:
    out: dict[str, Any] = {"row": label, "suite_id": suite, "n_choices": n, "dimension": dimension, "value": value,
                           "n_episodes": c.n_episodes, "n_grasped": c.n_grasped, "n_success": c.n_success,
                           "n_first_grasp": c.n_first, "n_first_grasp_right": c.n_first_right, "small": c.small}
    for k in ("tsr", "nsg", "first_right"):
        rate = getattr(c, k)
        out.update({k: rate.value, f"{k}_low": rate.low, f"{k}_high": rate.high})
    return out


def categories_rows(tables: Tables) -> list[dict[str, Any]]:
    """Long format, one row per (policy row, suite, dimension, value); the pooled Direct vs
    question cells have ``suite_id`` ``"(pooled)"``."""
    out = []
    for label, t in tables.items():
        for s, dims in t.suites.items():
            for d, cells in dims.items():
                out += [_row(label, s, c.n_choices, d, v, c) for v, c in cells.items()]
        out += [_row(label, "(pooled)", n, SUITE_KIND, k, c) for (k, n), c in t.kinds.items()]
    return out
