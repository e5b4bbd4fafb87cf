"""The robustness table: GSR / TSR / nSG per axis and level, with the change from level 0.

A perturbation that breaks the grasp shows as a GSR drop; one that breaks the choice as an nSG
drop with GSR intact. Level 0 of every axis is the unperturbed run of the same seeds (records
without ``perturb``), so a sweep runs it once for all its axes. The ``Breaks`` column names what
fell: ``grasp`` when the level's GSR interval lies wholly below level 0's, ``choice`` likewise for
nSG (Wilson 95 % intervals, metrics.py).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import SuiteMetrics, summarize
from rsb_maniskill.evaluation.records import dedupe, perturb_label, row_label
from rsb_maniskill.perturb import AXES
from rsb_maniskill.reporting.blocks import Block, Grid, Heading, to_markdown
from rsb_maniskill.reporting.cells import NA, delta, rate_cell
from rsb_maniskill.reporting.sections.base import Section

Table = dict[str, dict[str, dict[str, dict[int, SuiteMetrics]]]]  # row -> suite -> axis -> level -> metrics


def robustness_table(records: Iterable[Mapping[str, Any]]) -> Table:
    """Per policy row and suite: every single-axis perturbation swept, its levels' metrics, and
    level 0 (the unperturbed records of the same row and suite). Empty when nothing was perturbed."""
    by: dict[tuple[str, str], list] = {}
    for r in dedupe(records):
        p = perturb_label(r)
        if p == "none":
            axis, level = None, 0
        elif "perturb_axis" in r:
            axis, level = str(r["perturb_axis"]), int(r["perturb_level"])
        else:  # several axes at once: not a row of this table
            continue
        row = row_label(str(r.get("policy", "?")), r.get("instruction_mode", "normal"))  # levels 0-3 share the row
        by.setdefault((row, axis or ""), []).append((level, r))
    out: Table = {}
    for (row, axis), items in by.items():
        if not axis:
            continue
        levels: dict[int, list] = {}
        for level, r in items:
            levels.setdefault(level, []).append(r)
        for level, recs in [(0, [r for _, r in by.get((row, ""), [])]), *levels.items()]:
            for suite, m in summarize(recs).items():
                out.setdefault(row, {}).setdefault(suite, {}).setdefault(axis, {})[level] = m
    for row in out.values():  # axes in their declared order
        for suite, axes in row.items():
            row[suite] = {a: dict(sorted(axes[a].items())) for a in AXES if a in axes}
    return out


def breaks(m: SuiteMetrics, base: SuiteMetrics) -> str:
    """``grasp``, ``choice``, ``grasp, choice`` or ``-``: what fell below level 0 beyond both intervals."""
    out = []
    for attr, name in (("gsr", "grasp"), ("nsg", "choice")):
        a, b = getattr(m, attr), getattr(base, attr)
        if a.high is not None and b.low is not None and a.high < b.low:
            out.append(name)
    return ", ".join(out) or "-"


def _diff(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def robustness_rows(table: Table) -> list[dict[str, Any]]:
    """The table as flat JSON-able rows (summary.json's ``robustness``)."""
    rows = []
    for row, suites in table.items():
        for suite, axes in suites.items():
            for axis, levels in axes.items():
                base = levels.get(0)
                for level, m in levels.items():
                    rows.append({
                        "row": row, "suite_id": suite, "axis": axis, "level": level, "n_episodes": m.n_episodes,
                        **{k: getattr(m, k).value for k in ("gsr", "tsr", "nsg")},
                        **{f"{k}_low": getattr(m, k).low for k in ("gsr", "tsr", "nsg")},
                        **{f"{k}_high": getattr(m, k).high for k in ("gsr", "tsr", "nsg")},
                        **{f"d_{k}": _diff(getattr(m, k).value, None if base is None else getattr(base, k).value)
                           for k in ("gsr", "tsr", "nsg")},
                        "breaks": "-" if base is None else breaks(m, base),
                    })
    return rows


def robustness_blocks(table: Table) -> list[Block]:
    """One table per policy row and suite: axis, level, episodes, GSR / TSR / nSG with intervals,
    their change from level 0 (points) and what broke."""
    out: list[Block] = []
    head = ["Axis", "Level", "Episodes", "GSR", "TSR", "nSG", "ΔGSR", "ΔTSR", "ΔnSG", "Breaks"]
    for row, suites in table.items():
        for suite, axes in suites.items():
            rows = []
            for axis, levels in axes.items():
                base = levels.get(0)
                for level, m in levels.items():
                    d = [delta(getattr(m, k).value, getattr(base, k).value) if base else NA
                         for k in ("gsr", "tsr", "nsg")]
                    rows.append([axis, str(level), str(m.n_episodes), rate_cell(m.gsr), rate_cell(m.tsr),
                                 rate_cell(m.nsg), *d, "-" if base is None else breaks(m, base)])
            out += [Heading(f"Robustness: {row} on {suite} (%, Wilson 95% intervals; Δ in points from level 0)"),
                    Grid(head, rows)]
    return out


def robustness_markdown(table: Table) -> str:
    return to_markdown(robustness_blocks(table))


class RobustnessSection(Section):
    key, anchor, title, page_order, lead = "robustness", "robustness", "Robustness", 10, ""
    summary_order = 10
    note = ("Per axis and level: a GSR drop means the perturbation breaks the grasp, an nSG drop with GSR intact "
            "that it breaks the choice. Level 0 is the unperturbed run of the same seeds.")

    def compute(self, records: Sequence[Mapping[str, Any]], results_dir: Path) -> Table | None:
        return robustness_table(records) or None

    def to_json(self, table: Table) -> Any:
        return robustness_rows(table)

    def blocks(self, table: Table) -> list[Block]:
        return robustness_blocks(table)


SECTION = RobustnessSection()
