"""Per-category results: which kinds of question a policy gets right.

TSR and nSG say whether a policy grounds the question; split by what kind of episode it was
(Math by operator and answer size, HardMath by reasoning steps, General by source and MMLU-Pro
category, every suite by instruction template, Direct against question suites) they say where it
does not. The categories are the records' own (``records.CATEGORIES_FIELD``, written by the runner
from the task's ``episode_categories``: the semantic engine's ``categories.py``), so the tables
need no data files. Each cell gives TSR, nSG and *first grasp right* (the first candidate grasped
was the target, over the episodes with a grasp) with Wilson 95 % intervals and counts; cells of
fewer than :data:`SMALL_CELL` episodes are kept but flagged. Pure functions of records, like
``metrics.py``.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Iterable, Mapping

from rsb_maniskill.evaluation.metrics import Rate, group_by_suite, nsg, num_choices, outcome, suite_order
from rsb_maniskill.evaluation.records import CATEGORIES_FIELD, dedupe, record_row
from rsb_maniskill.semantic.categories import DIMENSIONS, SUITE_KIND, value_order

SMALL_CELL = 20  # episodes: a cell with fewer is shown, marked as too small to read much into
PER_SUITE = tuple(d for d in DIMENSIONS if d != SUITE_KIND)  # suite kind is one value per suite: pooled


@dataclass(frozen=True)
class CategoryCell:
    """The episodes of one category: counts, and TSR, nSG and first-grasp-right from them."""

    n_choices: int
    n_episodes: int
    n_grasped: int
    n_success: int
    n_first: int  # episodes with a first grasp
    n_first_right: int  # ... whose first grasped candidate was the target

    @property
    def tsr(self) -> Rate:
        return Rate.of(self.n_success, self.n_episodes)

    @property
    def nsg(self) -> Rate:
        """nSG with the interval of ``metrics.suite_metrics``: Wilson on success among grasps, mapped."""
        if not self.n_grasped:
            return Rate(None, None, None)
        c = Rate.of(self.n_success, self.n_grasped)
        return Rate(*(nsg(v, 1.0, self.n_choices) for v in (c.value, c.low, c.high)))

    @property
    def first_right(self) -> Rate:
        return Rate.of(self.n_first_right, self.n_first)

    @property
    def small(self) -> bool:
        return self.n_episodes < SMALL_CELL

    def to_dict(self) -> dict[str, Any]:
        return {"n_episodes": self.n_episodes, "n_grasped": self.n_grasped, "n_success": self.n_success,
                "n_first_grasp": self.n_first, "n_first_grasp_right": self.n_first_right, "small": self.small,
                **{k: asdict(getattr(self, k)) for k in ("tsr", "nsg", "first_right")}}


def category_cell(records: Iterable[Mapping[str, Any]], n_choices: int) -> CategoryCell:
    """Counts of ``records`` (episodes of suites with ``n_choices`` candidates)."""
    n = grasped = success = first = first_right = 0
    for r in records:
        kind = outcome(r)
        n += 1
        grasped += kind != "no_grasp"
        success += kind == "success"
        g = int(r.get("first_grasped", -1))
        first += g >= 0
        first_right += g >= 0 and g == int(r.get("target_block", -2))
    return CategoryCell(n_choices, n, grasped, success, first, first_right)


@dataclass(frozen=True)
class RowCategories:
    """One table row's (policy, mode, perturbation) per-category cells.

    ``suites``: suite -> dimension -> value -> cell, dimensions in :data:`DIMENSIONS` order;
    ``kinds``: (suite kind, N) -> cell pooled over the suites of that kind and N (question suites
    against the Direct controls); ``n_without``: records of the row that carry no categories
    (written before records had them), left out of the cells.
    """

    suites: dict[str, dict[str, dict[str, CategoryCell]]]
    kinds: dict[tuple[str, int], CategoryCell]
    n_without: int

    def to_dict(self) -> dict[str, Any]:
        return {"suites": {s: {d: {v: c.to_dict() for v, c in cells.items()} for d, cells in dims.items()}
                           for s, dims in self.suites.items()},
                "suite_kinds": [{"suite_kind": k, "n_choices": n, **c.to_dict()} for (k, n), c in self.kinds.items()],
                "n_without_categories": self.n_without}


def _row_categories(records: list[Mapping[str, Any]]) -> RowCategories:
    with_cats = [r for r in records if r.get(CATEGORIES_FIELD)]
    suites: dict[str, dict[str, dict[str, CategoryCell]]] = {}
    groups = group_by_suite(with_cats)
    for s in suite_order(groups):
        n = num_choices(s)
        dims = {}
        for d in PER_SUITE:
            by_value: dict[str, list[Mapping[str, Any]]] = {}
            for r in groups[s]:
                if d in r[CATEGORIES_FIELD]:
                    by_value.setdefault(str(r[CATEGORIES_FIELD][d]), []).append(r)
            if by_value:
                dims[d] = {v: category_cell(by_value[v], n) for v in value_order(by_value)}
        suites[s] = dims
    kinds: dict[tuple[str, int], list[Mapping[str, Any]]] = {}
    for r in with_cats:
        kinds.setdefault((str(r[CATEGORIES_FIELD].get(SUITE_KIND, "?")), num_choices(r["suite_id"])), []).append(r)
    pooled = {k: category_cell(kinds[k], k[1]) for k in sorted(kinds, key=lambda k: (k[1], k[0] != "question"))}
    return RowCategories(suites, pooled, len(records) - len(with_cats))


def category_tables(records: Iterable[Mapping[str, Any]]) -> dict[str, RowCategories]:
    """{row label: its per-category cells} for every row of ``records`` (deduplicated), rows in
    first-seen order; a row whose records carry no categories has no cells and its count in
    ``n_without``."""
    rows: dict[str, list[Mapping[str, Any]]] = {}
    for r in dedupe(records):
        rows.setdefault(record_row(r), []).append(r)
    return {label: _row_categories(recs) for label, recs in rows.items()}
