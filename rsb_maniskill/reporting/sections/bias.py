"""Does a policy favour a place or a candidate, whatever the question?

A policy that ignores the question but always goes for the leftmost block, or the red one, has a
TSR at chance like a policy that picks at random; these tables tell the two apart. Over the
episodes with a grasp, the *first* grasped candidate is counted by

- ``position``: its rank from the left as the head camera sees the table (``positions.py``; the
  records' ``left_rank``);
- ``candidate``: which candidate it is (``spec.block_names``): the colour of a 4-choice block,
  the letter of a 10-choice block, the category of an everyday object;
- ``letter``: the option letter bound to it; left out when it always names the same candidate
  (the fixed colour map binds option A to the red block in every episode, and the 10 lettered
  blocks carry their option letter), since it is then the candidate axis again,

against what a choice blind to that axis gives (the layout and the option binding do not depend
on the answer): each candidate of an episode has 1/N of its grasp, so every position and letter
expects 1/N of the grasps, and an object category its share of the candidates. A chi-square
goodness-of-fit test (``scipy.stats.chisquare``; its p simulated where counts are small) gives the
p-value, and each row a one-line verdict. Pure functions of records.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import Rate, group_by_suite, num_choices, suite_order
from rsb_maniskill.evaluation.records import LEFT_RANK_FIELD, dedupe, record_row
from rsb_maniskill.objects.family import BLOCK_COLORS, split_env_id
from rsb_maniskill.reporting.blocks import SMALL_MARK, Block, Cell, Grid, Heading, Inline, Note, to_markdown
from rsb_maniskill.reporting.cells import NA, pct
from rsb_maniskill.reporting.sections.base import Section, write_rows

POSITION, CANDIDATE, LETTER = "position", "candidate", "letter"
AXES: dict[str, str] = {POSITION: "position", CANDIDATE: "candidate", LETTER: "option letter"}
MIN_GRASPS = 20  # fewer first grasps: shown, not tested
WRONG_SUFFIX = ", wrong grasps only"  # the row of the test among wrong first grasps (bias_table)
# A verdict calls a preference below this p-value. A report makes up to 3 tests per policy row and
# suite (18 on the six paper suites): at 0.05 a policy without any preference would be called
# biased somewhere in most reports.
ALPHA = 0.01
MIN_EXPECTED = 5.0  # a category expecting fewer grasps: p by simulation, not the chi-square law (Cochran's rule)
MC_DRAWS, MC_SEED = 20_000, 0xB1A5  # that simulation: p resolves to 1 / 20,001, the same on every run


def position_label(rank: int, n: int) -> str:
    """``"leftmost"``, ``"2nd from left"``, ..., ``"rightmost"``."""
    if rank == 0:
        return "leftmost"
    if rank == n - 1:
        return "rightmost"
    k = rank + 1
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix} from left"


def position_column(rank: int, n: int) -> str:
    """A table's column of a position: ``"1 (leftmost)"``, ``"2"``, ..., ``"10 (rightmost)"``."""
    return f"{rank + 1} ({position_label(rank, n)})" if rank in (0, n - 1) else str(rank + 1)


def p_text(p: float | None, alpha: float | None = None) -> str:
    """``"p < 0.001"``, ``"p = 0.004"``, ``"p = 0.42"``: two significant digits, more where rounding
    would carry ``p`` across the rule ``p < alpha`` (0.0123 is "p = 0.012", never "p = 0.01" beside a
    "p < 0.01" rule; 0.00996 is "p = 0.00996", not "p = 0.01")."""
    if p is None:
        return "p n/a"
    if p < 0.001:
        return "p < 0.001"
    alpha = ALPHA if alpha is None else alpha
    for digits in range(2, 8):
        text = f"{p:.{digits}g}"
        if (float(text) < alpha) == (p < alpha) and float(text) != alpha or digits == 7:
            return f"p = {text}"
    return f"p = {p}"


def chi_square(observed: Sequence[float], expected: Sequence[float]) -> tuple[float | None, float | None]:
    """(statistic, p) of the goodness of fit of ``observed`` counts to ``expected`` (scaled to the
    same total; categories expecting none are left out); (None, None) with fewer than
    :data:`MIN_GRASPS` counts or fewer than two categories. Where a category expects fewer than
    :data:`MIN_EXPECTED` (10 candidates and under 50 grasps; everyday objects) the chi-square law
    is a loose fit, so p is read off the statistic's own law instead: :data:`MC_DRAWS` multinomial
    draws under the expected shares, from a fixed seed (the same records, the same p)."""
    import numpy as np
    from scipy.stats import chisquare

    obs, exp = np.asarray(observed, dtype=float), np.asarray(expected, dtype=float)
    keep = exp > 0
    obs, exp = obs[keep], exp[keep]
    n = int(round(obs.sum()))
    if n < MIN_GRASPS or len(obs) < 2:
        return None, None
    exp = exp * n / exp.sum()
    stat, p = chisquare(obs, exp)
    if (exp < MIN_EXPECTED).any():
        draws = np.random.default_rng(MC_SEED).multinomial(n, exp / n, size=MC_DRAWS)
        stats = ((draws - exp) ** 2 / exp).sum(axis=1)
        p = (1 + int((stats >= stat * (1 - 1e-9)).sum())) / (MC_DRAWS + 1)
    return float(stat), float(p)


@dataclass(frozen=True)
class Preference:
    """The first grasps of one policy row on one suite along one axis, against a blind choice."""

    axis: str
    labels: tuple[str, ...]  # categories, in table order
    phrases: tuple[str, ...]  # how a verdict names each: "the leftmost block", "the red block", "option A"
    observed: tuple[int, ...]
    expected: tuple[float, ...]  # grasps a choice blind to this axis would give each (same total)
    chi2: float | None
    p: float | None

    @property
    def n(self) -> int:
        return sum(self.observed)

    @property
    def uniform(self) -> bool:
        """Every category expects the same share (positions, letters, blocks)."""
        return max(self.expected) - min(self.expected) < 1e-9 * max(1.0, max(self.expected))

    @property
    def preferred(self) -> int:
        """Index of the category most over its expected count (Pearson residual)."""
        return max(range(len(self.labels)),
                   key=lambda i: (self.observed[i] - self.expected[i]) / max(self.expected[i], 1e-9) ** 0.5)

    @property
    def strongest(self) -> int:
        """Index of the category furthest from its expected count, either way (largest |Pearson residual|)."""
        return max(range(len(self.labels)),
                   key=lambda i: abs(self.observed[i] - self.expected[i]) / max(self.expected[i], 1e-9) ** 0.5)

    @property
    def significant(self) -> bool:
        return self.p is not None and self.p < ALPHA

    def verdict(self) -> str:
        """One line: ``prefers the leftmost block: 41 % of grasps, expected 25 %, p < 0.001`` (or
        ``avoids ...`` when the value furthest from its expected share is under it)."""
        if self.p is None:
            return f"too few grasps to test (n = {self.n})"
        if not self.significant:
            return f"no preference detected ({p_text(self.p)})"
        i = self.strongest  # worded from the data: a policy may shun one value more than it favours any
        verb = "prefers" if self.observed[i] >= self.expected[i] else "avoids"
        return (f"{verb} {self.phrases[i]}: {100 * self.observed[i] / self.n:.0f} % of grasps, "
                f"expected {100 * self.expected[i] / self.n:.0f} %, {p_text(self.p)}")

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "n": self.n, "verdict": self.verdict(), "significant": self.significant}


def preference(axis: str, observed: Mapping[str, int], expected: Mapping[str, float],
               phrases: Mapping[str, str], order: Sequence[str]) -> Preference:
    """A :class:`Preference` over the categories ``order`` (counts default to 0), tested."""
    obs = tuple(int(observed.get(k, 0)) for k in order)
    exp = tuple(float(expected.get(k, 0.0)) for k in order)
    chi2, p = chi_square(obs, exp)
    return Preference(axis, tuple(order), tuple(phrases[k] for k in order), obs, exp, chi2, p)


@dataclass(frozen=True)
class SuiteBias:
    """One policy row on one suite: how many first grasps were counted, and each axis tested."""

    suite_id: str
    n_choices: int
    n_episodes: int
    n_grasped: int  # episodes with a first grasp: the grasps counted
    axes: dict[str, Preference]
    missing: dict[str, str] = field(default_factory=dict)  # axis -> why the records cannot give it
    letter_is_candidate: bool = False  # each option letter always named the same candidate

    def to_dict(self) -> dict[str, Any]:
        return {"suite_id": self.suite_id, "n_choices": self.n_choices, "n_episodes": self.n_episodes,
                "n_grasped": self.n_grasped, "axes": {k: v.to_dict() for k, v in self.axes.items()},
                "missing": dict(self.missing), "letter_is_candidate": self.letter_is_candidate}


def axis_title(axis: str, suite_id: str) -> str:
    """What an axis counts on a suite: ``"position (left to right)"``, ``"colour"``, ``"letter
    block"``, ``"object category"``, ``"option letter"``."""
    if axis == POSITION:
        return "position (left to right, head camera)"
    if axis == CANDIDATE:
        if split_env_id(suite_id)[1] != "blocks":
            return "object category"
        return "letter block" if num_choices(suite_id) == 10 else "colour"
    return AXES[axis]


def _noun(spec: Mapping[str, Any]) -> str:
    return "object" if spec.get("targets") == "objects" else "block"


def _name_phrase(name: str) -> str:
    """"the red block", "block F", "the mug" (as the instructions name candidates)."""
    return name if name.startswith("block ") else f"the {name}"


def _position_phrase(rank: int, n: int, noun: str) -> str:
    label = position_label(rank, n)
    return f"the {label} {noun}" if rank in (0, n - 1) else f"the {noun} {label}"


def one_per_scene(records: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """The first variant of each scene (lowest ``variant``): a counterfactual scene's variants share
    one layout and candidates, so a policy that sticks to a candidate per scene would be counted K
    times; one episode a scene keeps the test's episodes independent (records without variants:
    unchanged)."""
    first: dict[Any, Mapping[str, Any]] = {}
    for r in records:
        key = (r.get("seed"), r.get("perturb", "none"))
        if key not in first or int(r.get("variant", 0)) < int(first[key].get("variant", 0)):
            first[key] = r
    return list(first.values()) if any("variant" in r for r in records) else list(records)


def suite_bias(records: Sequence[Mapping[str, Any]], suite_id: str, wrong_only: bool = False) -> SuiteBias:
    """The bias of the records of one policy row on one suite. ``wrong_only``: over the episodes whose
    first grasp was a wrong candidate, each of the N - 1 wrong candidates expected 1/(N - 1): a
    preference among the wrong ones (a policy with a favourite that is right half the time hides it
    in the all-grasps test, not here)."""
    n = num_choices(suite_id)
    records = one_per_scene(records)
    grasped = [r for r in records if int(r.get("first_grasped", -1)) >= 0]
    if wrong_only:
        grasped = [r for r in grasped if "target_block" in r and int(r["first_grasped"]) != int(r["target_block"])]
    counts: dict[str, Counter] = {a: Counter() for a in AXES}
    expect: dict[str, Counter] = {a: Counter() for a in AXES}
    phrases: dict[str, dict[str, str]] = {a: {} for a in AXES}
    first_index: dict[str, int] = {}  # candidate name -> lowest candidate index it had (table order)
    bindings: set[tuple[str, str]] = set()
    missing: dict[str, str] = {}
    n_ranked = sum(1 for r in grasped if r.get(LEFT_RANK_FIELD))
    n_spec = sum(1 for r in grasped if r.get("episode"))
    for r in grasped:
        g = int(r["first_grasped"])
        spec = r.get("episode") or {}
        noun = _noun(spec)
        ranks = r.get(LEFT_RANK_FIELD)
        wrong = int(r["target_block"]) if wrong_only else -1  # the candidate a wrong grasp cannot be
        share = 1 / (n - 1) if wrong_only else 1 / n
        if ranks and n_ranked == len(grasped):
            counts[POSITION][position_column(int(ranks[g]), n)] += 1
            for k in range(n):
                expect[POSITION][position_column(k, n)] += share
                phrases[POSITION][position_column(k, n)] = _position_phrase(k, n, noun)
            if wrong_only:  # the correct candidate's place is no wrong grasp's
                expect[POSITION][position_column(int(ranks[wrong]), n)] -= share
        if spec and n_spec == len(grasped):
            names, letters, boo = spec["block_names"], spec["letters"], list(spec["block_of_option"])
            counts[CANDIDATE][names[g]] += 1
            counts[LETTER][letters[boo.index(g)]] += 1
            for slot, b in enumerate(boo):
                expect[CANDIDATE][names[b]] += 0.0 if b == wrong else share
                expect[LETTER][letters[slot]] += 0.0 if b == wrong else share
                phrases[CANDIDATE][names[b]] = _name_phrase(names[b])
                phrases[LETTER][letters[slot]] = f"option {letters[slot]}"
                first_index[names[b]] = min(first_index.get(names[b], b), b)
                bindings.add((names[b], letters[slot]))
    if grasped and n_ranked < len(grasped):
        missing[POSITION] = f"{len(grasped) - n_ranked} of {len(grasped)} records without left-to-right ranks"
    if grasped and n_spec < len(grasped):
        missing[CANDIDATE] = missing[LETTER] = f"{len(grasped) - n_spec} of {len(grasped)} records without their spec"
    one_to_one = len({a for a, _ in bindings}) == len(bindings) == len({b for _, b in bindings})
    orders = {POSITION: [position_column(k, n) for k in range(n)],
              CANDIDATE: sorted(first_index, key=lambda k: (first_index[k], k)),
              LETTER: sorted(expect[LETTER])}
    axes = {a: preference(a, counts[a], expect[a], phrases[a], orders[a]) for a in AXES
            if expect[a] and not (a == LETTER and one_to_one)}
    return SuiteBias(suite_id, n, len(records), len(grasped), axes, missing, bool(bindings) and one_to_one)


def bias_table(records: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, SuiteBias]]:
    """{row label: {suite: its bias}} for every row of ``records`` (deduplicated), suites in the
    paper's order."""
    rows: dict[str, list[Mapping[str, Any]]] = {}
    for r in dedupe(records):
        rows.setdefault(record_row(r), []).append(r)
    out = {}
    for label, recs in rows.items():
        groups = group_by_suite(recs)
        out[label] = {s: suite_bias(groups[s], s) for s in suite_order(groups)}
        wrong = {s: suite_bias(groups[s], s, wrong_only=True) for s in suite_order(groups)}
        if any(b.n_grasped >= MIN_GRASPS for b in wrong.values()):  # enough wrong grasps to test
            out[f"{label}{WRONG_SUFFIX}"] = wrong
    return out


# ---------------------------------------------------------------- written
Table = Mapping[str, Mapping[str, SuiteBias]]
BAR_COLOR = "#6baed6"  # bars of positions, letters and objects (a 4-choice block's bar takes its colour)
NOTE = (f"Over the episodes with a grasp, the first candidate grasped. Expected: the share a choice blind to the "
        f"axis gives (each position and option letter 1/N; an object category its share of the candidates). "
        f"Verdicts: chi-square goodness of fit (scipy.stats.chisquare; p simulated where a category expects "
        f"fewer than 5 grasps), a preference called at p < {ALPHA}; "
        f"{SMALL_MARK} fewer than {MIN_GRASPS} grasps, not tested. Positions are ranks from the left in the head "
        f"camera's image; records without ranks (written before records had them) are not counted there.")
COINCIDE = ("Option letters are not a separate axis where each always named the same candidate: with the fixed "
            "colour map option A is the red block in every 4-choice episode (B green, C blue, D yellow), and each "
            "10-choice block carries its option letter, so colour or letter and option letter coincide there.")


def _verdict_cell(b: SuiteBias, axis: str) -> str:
    if axis in b.axes:
        return b.axes[axis].verdict()
    return f"n/a: {b.missing[axis]}" if axis in b.missing else "n/a"


def _share_cells(p: Preference, uniform: bool) -> list[str]:
    if not p.n:
        return [NA] * len(p.labels)
    obs = [pct(o / p.n) for o in p.observed]
    return obs if uniform else [f"{o} ({pct(e / p.n)})" for o, e in zip(obs, p.expected)]


def bias_blocks(table: Table) -> list[Block]:
    """The verdicts, then per suite and axis the shares of first grasps."""
    if not table:
        return []
    axes = [a for a in AXES if any(a in b.axes or a in b.missing for row in table.values() for b in row.values())]
    verdicts = [[label, s, str(b.n_grasped)] + [_verdict_cell(b, a) for a in axes]
                for label, row in table.items() for s, b in row.items()]
    parts: list[Block] = [Heading("Position and candidate preferences: verdicts"),
                          Grid(["Policy", "Suite", "First grasps"] + [AXES[a].capitalize() for a in axes], verdicts)]
    suites = suite_order({s for row in table.values() for s in row})
    for s in suites:
        for a in axes:
            prefs = {label: row[s].axes[a] for label, row in table.items() if s in row and a in row[s].axes}
            if not prefs:
                continue
            labels = next(iter(prefs.values())).labels
            same = all(p.labels == labels for p in prefs.values())
            uniform = same and all(p.uniform for p in prefs.values())
            if not same:  # object categories: each row its own columns' union
                labels = tuple(dict.fromkeys(k for p in prefs.values() for k in p.labels))
                prefs = {label: _widen(p, labels) for label, p in prefs.items()}
            rows: list[list[Inline | Cell]] = []
            if uniform:
                rows.append(["expected (blind choice)", ""] + [pct(1 / len(labels))] * len(labels) + [""])
            for label, p in prefs.items():
                rows.append([label, Cell(str(p.n), small=p.n < MIN_GRASPS)] + _share_cells(p, uniform) + [p.verdict()])
            how = "" if uniform else "; in brackets: expected"
            parts += [Heading(f"First grasp by {axis_title(a, s)} on {s} (% of first grasps{how})"),
                      Grid(["Policy", "First grasps", *labels, "Verdict"], rows)]
    notes = [NOTE]
    if any(b.letter_is_candidate for row in table.values() for b in row.values()):
        notes.append(COINCIDE)
    return parts + [Note(n) for n in notes]


def bias_markdown(table: Table) -> str:
    return to_markdown(bias_blocks(table))


def _widen(p: Preference, labels: tuple[str, ...]) -> Preference:
    """``p`` over ``labels`` (categories it never met: 0 observed, 0 expected)."""
    obs = dict(zip(p.labels, p.observed))
    exp = dict(zip(p.labels, p.expected))
    phr = dict(zip(p.labels, p.phrases))
    return Preference(p.axis, labels, tuple(phr.get(k, k) for k in labels), tuple(obs.get(k, 0) for k in labels),
                      tuple(exp.get(k, 0.0) for k in labels), p.chi2, p.p)


def bias_json(table: Table) -> dict[str, Any]:
    return {"alpha": ALPHA, "min_grasps": MIN_GRASPS,
            "rows": {label: {s: b.to_dict() for s, b in row.items()} for label, row in table.items()}}


def bias_rows(table: Table) -> list[dict[str, Any]]:
    """Long format, one row per (policy row, suite, axis, category)."""
    out = []
    for label, row in table.items():
        for s, b in row.items():
            for a, p in b.axes.items():
                for k, o, e in zip(p.labels, p.observed, p.expected):
                    out.append({"row": label, "suite_id": s, "axis": a, "category": k, "observed": o,
                                "share": o / p.n if p.n else None, "expected": e,
                                "expected_share": e / p.n if p.n else None, "n": p.n, "chi2": p.chi2, "p": p.p,
                                "verdict": p.verdict()})
    return out


def bias_plots(table: Table) -> list[dict[str, Any]]:
    """What the page draws per policy row and suite: for each axis a bar per category (share of
    first grasps with its Wilson 95 % interval, a 4-choice block in its colour) and the expected
    share, the verdict, and the scale (``ymax``: a multiple of 20 % above the highest whisker or line;
    ``rotate``: tick labels too long to stand under their bar)."""
    out = []
    for label, row in table.items():
        for s, b in row.items():
            charts = []
            for a, p in b.axes.items():
                if not p.n:
                    continue
                bars = []
                for i, (k, o, e) in enumerate(zip(p.labels, p.observed, p.expected)):
                    rate = Rate.of(o, p.n)
                    bars.append({"label": k, "short": _short(a, k, i), "share": rate.value, "low": rate.low,
                                 "high": rate.high, "expected": e / p.n, "count": o, "color": _color(k)})
                top = max(max(x["high"] for x in bars), max(x["expected"] for x in bars))
                charts.append({"axis": a, "title": axis_title(a, s), "bars": bars, "verdict": p.verdict(),
                               "significant": p.significant, "n": p.n, "ymax": min(1.0, math.ceil(top * 5 + 0.25) / 5),
                               "rotate": max(len(x["short"]) for x in bars) > (6 if len(bars) <= 4 else 2)})
            if charts:
                out.append({"label": label, "suite": s, "charts": charts})
    return out


def _short(axis: str, label: str, index: int) -> str:
    """A bar's tick: positions 1..N from the left, "red", "F", "A", an object's name."""
    if axis == POSITION:
        return str(index + 1)
    return label.removesuffix(" block").removeprefix("block ")


def _color(label: str) -> str:
    rgb = BLOCK_COLORS.get(label.removesuffix(" block"))
    return "#" + "".join(f"{round(255 * c):02x}" for c in rgb) if rgb else BAR_COLOR


class BiasSection(Section):
    key, anchor, title, nav, page_order = "bias", "bias", "Position and candidate preferences", "Preferences", 70
    summary_order = 50
    note = ("Does a policy go for a place or a candidate whatever the question? The first candidate grasped in each "
            "episode with a grasp, by its position from the left in the head camera, by candidate (colour, letter "
            "block or object) and by option letter, against the share a choice blind to it gets (dashed red). A "
            "policy with a favourite shows here even when its TSR is at chance.")

    def compute(self, records: Sequence[Mapping[str, Any]], results_dir: Path) -> Table | None:
        return bias_table(records) if records else None

    def to_json(self, table: Table) -> Any:
        return bias_json(table)

    def blocks(self, table: Table) -> list[Block]:
        return bias_blocks(table)

    def files(self, table: Table, out: Path, stem: str) -> dict[str, Path]:
        return {"csv:bias": write_rows(bias_rows(table), out / f"{stem}_bias.csv")}

    def charts(self, table: Table) -> list[dict[str, Any]]:
        return bias_plots(table)


SECTION = BiasSection()
