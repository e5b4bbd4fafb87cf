"""The bias tables (``evaluation/bias.py``) as Markdown, JSON and CSV rows.

First the verdicts, one line per policy row, suite and axis; then per suite and axis the share of
first grasps each position / candidate / option letter got, policies as rows, against the share a
choice blind to that axis expects. Written into ``summary.{md,json}``, ``summary_bias.csv`` and
``report.html`` (with a bar per category and the expected line).
"""
from __future__ import annotations

import math
from typing import Any, Mapping

from rsb_maniskill.evaluation.bias import ALPHA, AXES, MIN_GRASPS, POSITION, Preference, SuiteBias, axis_title
from rsb_maniskill.evaluation.metrics import Rate, suite_order
from rsb_maniskill.objects.family import BLOCK_COLORS
from rsb_maniskill.reporting.categories import SMALL_MARK
from rsb_maniskill.reporting.cells import NA, markdown_table, pct

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


def bias_markdown(table: Table) -> str:
    """The verdicts, then per suite and axis the shares of first grasps."""
    if not table:
        return ""
    axes = [a for a in AXES if any(a in b.axes or a in b.missing for row in table.values() for b in row.values())]
    verdicts = [[label, s, str(b.n_grasped)] + [_verdict_cell(b, a) for a in axes]
                for label, row in table.items() for s, b in row.items()]
    parts = ["### Position and candidate preferences: verdicts\n\n"
             + markdown_table(["Policy", "Suite", "First grasps"] + [AXES[a].capitalize() for a in axes], verdicts)]
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
            rows = []
            if uniform:
                rows.append(["expected (blind choice)", ""] + [pct(1 / len(labels))] * len(labels) + [""])
            for label, p in prefs.items():
                mark = SMALL_MARK if p.n < MIN_GRASPS else ""
                rows.append([label, f"{p.n}{mark}"] + _share_cells(p, uniform) + [p.verdict()])
            how = "" if uniform else "; in brackets: expected"
            parts.append(f"### First grasp by {axis_title(a, s)} on {s} (% of first grasps{how})\n\n"
                         + markdown_table(["Policy", "First grasps", *labels, "Verdict"], rows))
    notes = [NOTE]
    if any(b.letter_is_candidate for row in table.values() for b in row.values()):
        notes.append(COINCIDE)
    return "\n\n".join(parts) + "\n\n" + "\n\n".join(notes) + "\n"


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
