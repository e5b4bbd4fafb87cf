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
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import Rate, group_by_suite, nsg, num_choices, outcome, suite_order
from rsb_maniskill.evaluation.records import CATEGORIES_FIELD, dedupe, record_row
from rsb_maniskill.reporting.blocks import SMALL_MARK, Block, Cell, Grid, Heading, Inline, Note, Strong, to_markdown
from rsb_maniskill.reporting.cells import p_value, rate_cell
from rsb_maniskill.reporting.sections.base import Section, write_rows
from rsb_maniskill.semantic.categories import DIMENSIONS, SUITE_KIND, value_label, value_order

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

    def small_rates(self) -> dict[str, bool]:
        """Each rate against its own denominator: TSR over episodes, nSG over grasps, first grasp right
        over first grasps (a 100-episode cell with 3 grasps has a small nSG)."""
        return {"tsr": self.n_episodes < SMALL_CELL, "nsg": self.n_grasped < SMALL_CELL,
                "first_right": self.n_first < SMALL_CELL}

    def to_dict(self) -> dict[str, Any]:
        return {"n_episodes": self.n_episodes, "n_grasped": self.n_grasped, "n_success": self.n_success,
                "n_first_grasp": self.n_first, "n_first_grasp_right": self.n_first_right, "small": self.small,
                "small_rates": self.small_rates(),
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


# ---------------------------------------------------------------- written
Tables = Mapping[str, RowCategories]

HEADER = ["Category", "Episodes", "TSR", "nSG", "First grasp right", "First grasps"]
SMALL_NOTE = (f"{SMALL_MARK} after a count: fewer than {SMALL_CELL} episodes; after a rate: fewer than {SMALL_CELL} "
              "in its own denominator (TSR: episodes, nSG: grasps, first grasp right: first grasps). Shown, but "
              "its interval is wide; read it with care.")
RERUN = "Rerun `rsb eval` into a new `--out` directory to get them."
NONE_NOTE = ("The records carry no categories (written before records had them, or by a harness that does not "
             f"record them): no per-category table. {RERUN}")


FAMILY_ALPHA = 0.05  # the family-wise error rate of the tests across a dimension's values (Holm)


@dataclass(frozen=True)
class DimensionTest:
    """Does TSR differ across a dimension's values (one policy row, one suite)? A chi-square test of
    homogeneity of successes over the values; ``p_holm`` Holm-adjusted over every such test of the
    summary, so "differs" holds at ``FAMILY_ALPHA`` family-wise however many cells are shown."""

    row: str
    suite: str
    dimension: str
    n_values: int
    chi2: float | None
    p: float | None
    p_holm: float | None = None

    @property
    def name(self) -> str:
        """The dimension in a sentence: ``"answer size"``."""
        return DIMENSIONS[self.dimension].split(" (")[0].lower()

    @property
    def differs(self) -> bool:
        return self.p_holm is not None and self.p_holm < FAMILY_ALPHA

    def text(self) -> str:
        if self.p is None:
            return f"{self.name}: not tested (fewer than two values)"
        verdict = "TSR differs" if self.differs else "no difference shown"
        return (f"{self.name}: {verdict} (p = {p_value(self.p, FAMILY_ALPHA)}, Holm-adjusted "
                f"{p_value(self.p_holm, FAMILY_ALPHA)})")  # as many digits as the verdict needs

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "differs": self.differs}


def _homogeneity(counts: list[tuple[int, int]]) -> tuple[float | None, float | None]:
    """Chi-square test of homogeneity of (successes, failures) over the values (None: under two values)."""
    counts = [c for c in counts if sum(c)]
    if len(counts) < 2:
        return None, None
    if not sum(k for k, _ in counts) or not sum(f for _, f in counts):
        return 0.0, 1.0  # every value all success, or all failure: nothing differs
    from scipy.stats import chi2_contingency

    chi2, p, _, _ = chi2_contingency(counts, correction=False)
    return float(chi2), float(p)


def dimension_tests(tables: Tables) -> list[DimensionTest]:
    """One test per (row, suite, dimension), Holm-adjusted together."""
    from dataclasses import replace

    from rsb_maniskill.evaluation.stats import holm

    tests = []
    for label, t in tables.items():
        for s, dims in t.suites.items():
            for d, cells in dims.items():
                chi2, p = _homogeneity([(c.n_success, c.n_episodes - c.n_success) for c in cells.values()])
                tests.append(DimensionTest(label, s, d, len(cells), chi2, p))
    return [replace(t, p_holm=a) for t, a in zip(tests, holm([t.p for t in tests]))]


def _cells(c: CategoryCell) -> list[Inline | Cell]:
    small = c.small_rates()

    def rate(key: str) -> Cell:
        return Cell(rate_cell(getattr(c, key)), small=small[key])

    return [Cell(str(c.n_episodes), small=c.small), rate("tsr"), rate("nsg"), rate("first_right"), str(c.n_first)]


def _kind_label(kind: str, n: int) -> str:
    return f"{value_label(SUITE_KIND, kind)}, {n} choices"


def has_categories(tables: Tables) -> bool:
    return any(t.suites for t in tables.values())


def categories_blocks(tables: Tables) -> list[Block]:
    """Per row and suite the category table, then Direct vs question suites where a row ran both."""
    parts: list[Block] = []
    if not has_categories(tables):
        return [Heading("No per-category tables"), Note(NONE_NOTE)]
    tests: dict[tuple[str, str], list[DimensionTest]] = {}
    for x in dimension_tests(tables):
        tests.setdefault((x.row, x.suite), []).append(x)
    for label, t in tables.items():
        for s, dims in t.suites.items():
            rows: list[list[Inline | Cell]] = []
            for d, cells in dims.items():
                rows.append([Strong(DIMENSIONS[d])] + [""] * (len(HEADER) - 1))
                rows += [[value_label(d, v)] + _cells(c) for v, c in cells.items()]
            across = "; ".join(x.text() for x in tests.get((label, s), []))
            parts += [Heading(f"{label} on {s}: by category (%)"), Grid(HEADER, rows)]
            parts += [Note(f"Across each dimension's values: {across}.")] if across else []
        if len({k for k, _ in t.kinds}) > 1:
            rows = [[_kind_label(k, n)] + _cells(c) for (k, n), c in t.kinds.items()]
            parts += [Heading(f"{label}: Direct vs question suites (%)"),
                      Note("Pooled over the suites of each kind and number of choices."),
                      Grid(["Suites"] + HEADER[1:], rows)]
    skipped = [f"{label} ({t.n_without})" for label, t in tables.items() if t.n_without]
    notes = ["TSR and nSG as in the paper tables, over the episodes of the category; first grasp right: the first "
             "candidate grasped was the target, of the episodes with a grasp (first grasps). In brackets: Wilson "
             "95% intervals.", SMALL_NOTE,
             "Across each dimension's values: does TSR differ between them? A chi-square test of homogeneity per "
             "policy, suite and dimension, its p-value Holm-adjusted over every such test of this summary; "
             f"\"TSR differs\" where the adjusted p is under {FAMILY_ALPHA} (family-wise). A single interval clear "
             "of the others with no difference shown is noise until more episodes say otherwise."]
    if skipped:
        notes.append("Records without categories, left out: " + ", ".join(skipped) + ". " + RERUN)
    return parts + [Note(n) for n in notes]


def categories_markdown(tables: Tables) -> str:
    return to_markdown(categories_blocks(tables))


def categories_json(tables: Tables) -> dict[str, Any]:
    return {"small_cell": SMALL_CELL, "rows": {label: t.to_dict() for label, t in tables.items()},
            "family_alpha": FAMILY_ALPHA, "dimension_tests": [x.to_dict() for x in dimension_tests(tables)],
            **({} if has_categories(tables) else {"note": NONE_NOTE})}


def _row(label: str, suite: str, n: int, dimension: str, value: str, c: CategoryCell) -> dict[str, Any]:
    out: dict[str, Any] = {"row": label, "suite_id": suite, "n_choices": n, "dimension": dimension, "value": value,
                           "n_episodes": c.n_episodes, "n_grasped": c.n_grasped, "n_success": c.n_success,
                           "n_first_grasp": c.n_first, "n_first_grasp_right": c.n_first_right, "small": c.small,
                           **{f"small_{k}": v for k, v in c.small_rates().items()}}
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


class CategoriesSection(Section):
    key, anchor, title, nav, page_order = "categories", "categories", "Per-category results", "By category", 60
    summary_order = 40
    note = ("Which kinds of question a policy gets right: per suite, TSR, nSG and first grasp right (the first "
            "candidate grasped was the target) by the episode's category, from the records (Math: operator, answer "
            "size; HardMath: GSM8K reasoning steps, answer size; General: source, MMLU-Pro category; every suite: "
            "instruction template). Grey lines: fewer than 20 episodes. In brackets: Wilson 95% intervals.")

    def compute(self, records: Sequence[Mapping[str, Any]], results_dir: Path) -> Tables | None:
        return category_tables(records) if records else None

    def to_json(self, table: Tables) -> Any:
        return categories_json(table)

    def blocks(self, table: Tables) -> list[Block]:
        return categories_blocks(table)

    def files(self, table: Tables, out: Path, stem: str) -> dict[str, Path]:
        rows = categories_rows(table)
        return {"csv:categories": write_rows(rows, out / f"{stem}_categories.csv")} if rows else {}


SECTION = CategoriesSection()
