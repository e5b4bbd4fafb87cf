"""Summaries of evaluation results: JSON, CSV, Markdown tables in the paper's layout, a bar chart.

``results`` everywhere is ``{row label: {suite_id: SuiteMetrics}}``: one row per policy (and
instruction mode, for the language ablations), built from records by :func:`results_from_records`.
Markdown tables follow the paper: Table 3 (TSR), Table 4 (nSG), Table 6 (GSR/TSR), Table 7 (error
analysis), with suites as columns and Avg over the paper's six suites. ``writer.write_report``
writes them into a results directory with the other sections.
"""
from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import (
    PAPER_OBJECT_SUITES,
    PAPER_SUITES,
    Average,
    SuiteMetrics,
    average,
    suite_order,
    summarize,
)
from rsb_maniskill.evaluation.records import COUNTERFACTUAL, dedupe, one_version, record_row
from rsb_maniskill.objects.family import OBJECTS_SUFFIX
from rsb_maniskill.reporting.blocks import Block, Grid, Heading, Inline, Note, Strong, to_markdown
from rsb_maniskill.reporting.cells import NA, NONE_AT_N, ci, pct, points

Results = Mapping[str, Mapping[str, SuiteMetrics]]
# The heading of paper Table 7 (the last table): the page shows it in its error analysis section.
ERRORS_HEADING = Heading("Error analysis, all suites pooled (%, paper Table 7)")


def results_from_records(records: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, SuiteMetrics]]:
    """Group (deduplicated) records by policy and instruction mode, then by suite. Records of two
    benchmark versions do not pool: ``records.VersionMixError``, naming both."""
    records = dedupe(records)
    one_version(records)
    rows: dict[str, list[Mapping[str, Any]]] = {}
    for r in records:
        rows.setdefault(record_row(r), []).append(r)
    out = {label: summarize(recs) for label, recs in rows.items()}
    for label, recs in rows.items():
        if any(r.get("instruction_mode") == COUNTERFACTUAL for r in recs):
            for suite, m in out[label].items():
                out[label][suite] = by_scene(m, [r for r in recs if r["suite_id"] == suite])
    return out


def by_scene(m: SuiteMetrics, records: Sequence[Mapping[str, Any]]) -> SuiteMetrics:
    """A counterfactual row's GSR, TSR and nSG with intervals that count scenes (the K variants of a
    seed go one way together: ``stats.clustered_rate``), and each rate's design effect over scenes in
    ``extra["design_effect"]`` (its detectable difference counts n / design effect episodes)."""
    from dataclasses import replace

    import numpy as np

    from rsb_maniskill.evaluation.metrics import Rate, outcome
    from rsb_maniskill.evaluation.stats import clustered_rate, design_effect

    kinds = [outcome(r) for r in records]
    seeds = np.array([int(r["seed"]) for r in records])
    grasped = np.array([k != "no_grasp" for k in kinds])
    success = np.array([k == "success" for k in kinds])
    design = {"gsr": design_effect(grasped, seeds), "tsr": design_effect(success, seeds), "nsg": None}
    nsg = Rate(None, None, None)
    if grasped.any():
        share = clustered_rate(success[grasped], seeds[grasped])
        chance = 1.0 / m.n_choices
        nsg = Rate(*((x - chance) / (1 - chance) for x in (share.value, share.low, share.high)))
        design["nsg"] = design_effect(success[grasped], seeds[grasped])
    return replace(m, gsr=clustered_rate(grasped, seeds), tsr=clustered_rate(success, seeds), nsg=nsg,
                   extra={**m.extra, "scenes": len(set(seeds.tolist())), "design_effect": design})


def suite_columns(results: Results) -> list[str]:
    """Suites present in any row: the paper's order first, then the others (Direct) sorted."""
    return suite_order({s for row in results.values() for s in row})


def detectable(m: SuiteMetrics) -> dict[str, float | None]:
    """Per metric, the smallest difference from this suite's value that a paired comparison on the
    same episodes detects with 80 % power at p < 0.05: McNemar's exact test, its power computed
    exactly (``stats.minimum_detectable_difference``), at the run's design effect over scenes for a
    counterfactual row (the scene test: n / design effect effective episodes); nSG's through its share
    of grasps on the target (TSR / GSR over the grasped episodes), scaled like nSG. None where the
    rate is undefined, or where no difference within [0, 1] can be detected at this n (under 6
    effective episodes the test cannot reject at all)."""
    from rsb_maniskill.evaluation.stats import minimum_detectable_difference as mdd

    design = m.extra.get("design_effect") or {}
    out: dict[str, float | None] = {
        "gsr": None if m.gsr.value is None else mdd(m.gsr.value, m.n_episodes, design=design.get("gsr") or 1.0),
        "tsr": None if m.tsr.value is None else mdd(m.tsr.value, m.n_episodes, design=design.get("tsr") or 1.0),
        "nsg": None}
    if m.n_grasped:
        cond = mdd(m.n_success / m.n_grasped, m.n_grasped, design=design.get("nsg") or 1.0)
        out["nsg"] = None if cond is None else cond / (1 - 1 / m.n_choices)
    return out


DETECTABLE_NOTE = Note("Detectable difference (TSR, points): the smallest TSR difference from this run that a paired "
                       "comparison on the same episodes (McNemar's exact test, p < 0.05, its power computed exactly; "
                       "counterfactual rows: over scenes, at the run's design effect) finds 4 times in 5; "
                       f"{NONE_AT_N}: that test cannot reach it at any difference (under 6 episodes it cannot reject "
                       "at all). summary.json holds it for GSR and nSG too (detectable_difference). `rsb plan` gives "
                       "the episodes another claim needs. Counterfactual rows: Wilson 95 % intervals over scenes "
                       "(a seed's variants counted at the effective sample size).")


def summary_dict(results: Results, benchmark_version: str | None = None) -> dict[str, Any]:
    """Everything as plain JSON-able data: per-suite metrics with intervals and the differences the
    run can detect, and Avg per row (with the benchmark version of the episodes, when given)."""
    return {
        **({"benchmark_version": benchmark_version} if benchmark_version else {}),
        "avg_suites": list(PAPER_SUITES),
        "detectable_difference": "the smallest difference from the value that McNemar's exact test on the same "
                                 "episodes detects with 80 % power at p < 0.05, its power computed exactly "
                                 "(counterfactual rows: at n / design_effect, the scene test's effective size; "
                                 "fractions; null: the rate is undefined, or none at this n)",
        "rows": {
            label: {
                "suites": {s: {**m.to_dict(), "detectable_difference": detectable(m)} for s, m in row.items()},
                "avg": average(row).to_dict(),
            }
            for label, row in results.items()
        },
    }


def write_json(results: Results, path: str | os.PathLike, benchmark_version: str | None = None) -> Path:
    path = Path(path)
    path.write_text(json.dumps(summary_dict(results, benchmark_version), indent=2) + "\n", encoding="utf-8")
    return path


CSV_FIELDS = (
    "row", "suite_id", "n_choices", "n_episodes", "n_grasped", "n_success",
    "gsr", "gsr_low", "gsr_high", "tsr", "tsr_low", "tsr_high", "nsg", "nsg_low", "nsg_high",
    "err_not_placed", "err_wrong_target", "err_no_grasp", "benchmark_version",
)


def csv_rows(results: Results, benchmark_version: str | None = None) -> list[dict[str, Any]]:
    """One row per (row label, suite) plus an ``Avg`` row per label; rates as fractions in [0, 1]."""
    out = []
    for label, row in results.items():
        for s, m in row.items():
            f = m.errors.fractions()
            out.append({
                "row": label, "suite_id": s, "n_choices": m.n_choices, "n_episodes": m.n_episodes,
                "n_grasped": m.n_grasped, "n_success": m.n_success,
                "gsr": m.gsr.value, "gsr_low": m.gsr.low, "gsr_high": m.gsr.high,
                "tsr": m.tsr.value, "tsr_low": m.tsr.low, "tsr_high": m.tsr.high,
                "nsg": m.nsg.value, "nsg_low": m.nsg.low, "nsg_high": m.nsg.high,
                "err_not_placed": f["not_placed"], "err_wrong_target": f["wrong_target"], "err_no_grasp": f["no_grasp"],
                "benchmark_version": benchmark_version,
            })
        a = average(row)
        out.append({"row": label, "suite_id": "Avg", "gsr": a.gsr, "tsr": a.tsr, "nsg": a.nsg,
                    "n_episodes": sum(row[s].n_episodes for s in a.present), "benchmark_version": benchmark_version})
    return out


def write_csv(results: Results, path: str | os.PathLike, benchmark_version: str | None = None) -> Path:
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        w.writeheader()
        for r in csv_rows(results, benchmark_version):
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in CSV_FIELDS})
    return path


# ---------------------------------------------------------------- Markdown
AVG_NOTE = Note("* Avg over the paper's suites that were run, not all six.")
NO_AVG_NOTE = Note("Avg: n/a: it is over the paper's six suites, and none was run (the Direct suites are controls).")


def _avg_label(avgs: Sequence[Average]) -> tuple[Strong, list[Block]]:
    # The paper reports Avg only over all six suites; mark a partial Avg instead of hiding it.
    if all(a.complete for a in avgs):
        return Strong("Avg"), []
    if not any(a.suites for a in avgs):
        return Strong("Avg"), [NO_AVG_NOTE]
    return Strong("Avg", mark="*"), [AVG_NOTE]


def summary_blocks(results: Results, benchmark_version: str | None = None) -> list[Block]:
    """Paper Tables 3, 4, 6 and 7 (plus per-suite intervals), under a line naming the benchmark
    version when given: summary.md's first part and the page's tables."""
    suites = suite_columns(results)
    labels = list(results)
    avgs = {label: average(results[label]) for label in labels}
    avg_head, avg_note = _avg_label(list(avgs.values()))

    def cell(label: str, s: str, attr: str) -> str:
        m = results[label].get(s)
        return "" if m is None else pct(getattr(m, attr).value)

    out: list[Block] = []
    for title, attr in (("Task Success Rate (TSR, %) (paper Table 3)", "tsr"),
                        ("Normalized Semantic Grounding (nSG, %) (paper Table 4)", "nsg")):
        rows = [[label] + [cell(label, s, attr) for s in suites] + [Strong(pct(getattr(avgs[label], attr)))]
                for label in labels]
        out += [Heading(title), Grid(["Policy"] + suites + [avg_head], rows), *avg_note]

    header: list[Inline] = ["Policy", *(f"{s} {k}" for s in suites for k in ("GSR", "TSR")),
                            (avg_head, " GSR"), (avg_head, " TSR")]
    rows = [[label] + [cell(label, s, k) for s in suites for k in ("gsr", "tsr")]
            + [Strong(pct(avgs[label].gsr)), Strong(pct(avgs[label].tsr))] for label in labels]
    out += [Heading("Full GSR/TSR decomposition (%) (paper Table 6)"), Grid(header, rows), *avg_note]

    for label in labels:
        row = results[label]
        detail = [[s, str(m.n_episodes), ci(m.gsr.value, m.gsr.low, m.gsr.high),
                   ci(m.tsr.value, m.tsr.low, m.tsr.high), ci(m.nsg.value, m.nsg.low, m.nsg.high),
                   f"{100 / m.n_choices:.1f}", _points(detectable(m)["tsr"], m.tsr.value)] for s, m in row.items()]
        out += [Heading(f"{label}: per suite with Wilson 95% intervals (%)"),
                Grid(["Suite", "Episodes", "GSR", "TSR", "nSG", "Random TSR (1/N)", "Detectable TSR difference"],
                     detail)]
    out.append(DETECTABLE_NOTE)

    err_rows = []
    for key, name in (("not_placed", "Grasped correct block but not placed"),
                      ("wrong_target", "Wrong target after grasp"),
                      ("no_grasp", "No grasp (% of all episodes)")):
        vals = []
        for label in labels:
            errs = [m.errors for m in results[label].values()]
            pooled = _pool_errors(errs)
            vals.append(pct(pooled[key], 2))
        err_rows.append([name] + vals)
    out += _beyond_blocks_tables(results)
    n_failed = [str(sum(m.errors.n_grasped_failed for m in results[label].values())) for label in labels]
    err_rows.append(["Grasped-but-failed episodes (count)"] + n_failed)
    out += [ERRORS_HEADING,
            Note("Shares of the grasped-but-failed episodes, except no-grasp (share of all episodes)."),
            Grid(["Error type"] + labels, err_rows)]
    if benchmark_version:
        from rsb_maniskill.version import benchmark_label

        out.insert(0, Note(f"Benchmark: {benchmark_label(benchmark_version)} (docs/versions.md)"))
    return out


def _points(x: float | None, rate: float | None = 0.0) -> str:
    return NA if rate is None else points(x, NONE_AT_N)


def markdown_tables(results: Results, benchmark_version: str | None = None) -> str:
    """:func:`summary_blocks` as one Markdown document (summary.md's first part, what ``rsb eval`` prints)."""
    return to_markdown(summary_blocks(results, benchmark_version))


def _beyond_blocks_tables(results: Results) -> list[Block]:
    """Paper appendix tables (Beyond Blocks): Scene | GSR | TSR over the objects suites, with Avg."""
    out: list[Block] = []
    for label, row in results.items():
        suites = [s for s in PAPER_OBJECT_SUITES if s in row]
        if not suites:
            continue
        avg = average(row, PAPER_OBJECT_SUITES)
        head, note = _avg_label([avg])
        rows: list[list[Inline]] = [[s.removesuffix(OBJECTS_SUFFIX), pct(row[s].gsr.value), pct(row[s].tsr.value)]
                                    for s in suites]
        rows.append([head, Strong(pct(avg.gsr)), Strong(pct(avg.tsr))])
        out += [Heading(f"Beyond Blocks: {label} (everyday objects, paper appendix tables)"),
                Grid(["Scene", "GSR", "TSR"], rows), *note]
    return out


def _pool_errors(errs: Sequence[Any]) -> dict[str, float | None]:
    failed = sum(e.n_grasped_failed for e in errs)
    total = sum(e.n_episodes for e in errs)
    return {
        "not_placed": sum(e.not_placed for e in errs) / failed if failed else None,
        "wrong_target": sum(e.wrong_target for e in errs) / failed if failed else None,
        "no_grasp": sum(e.no_grasp for e in errs) / total if total else None,
    }


def write_markdown(results: Results, path: str | os.PathLike, benchmark_version: str | None = None) -> Path:
    path = Path(path)
    path.write_text(markdown_tables(results, benchmark_version), encoding="utf-8")
    return path


# ---------------------------------------------------------------- chart
def plot_summary(metrics: Mapping[str, SuiteMetrics], path: str | os.PathLike, title: str | None = None) -> Path:
    """Bar chart of GSR and TSR per suite (Wilson 95% error bars) with each suite's 1/N line.

    The dashed 1/N line is the TSR of a policy that always grasps and picks a candidate at random:
    TSR bars near it mean grasping without semantic target selection.
    """
    # Figure + Agg canvas, no pyplot: no global backend switch, safe in threads and notebooks.
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    suites = suite_order(metrics)
    x = np.arange(len(suites))
    w = 0.38
    fig = Figure(figsize=(max(5.0, 1.25 * len(suites) + 2.0), 4.2), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for offset, attr, label, color in ((-w / 2, "gsr", "GSR", "#9ecae1"), (w / 2, "tsr", "TSR", "#2171b5")):
        vals = np.array([_nan(getattr(metrics[s], attr).value) for s in suites]) * 100
        lo = np.array([_nan(getattr(metrics[s], attr).low) for s in suites]) * 100
        hi = np.array([_nan(getattr(metrics[s], attr).high) for s in suites]) * 100
        yerr = np.clip(np.vstack([vals - lo, hi - vals]), 0, None)
        ax.bar(x + offset, vals, w, label=label, color=color, edgecolor="black", linewidth=0.5)
        ax.errorbar(x + offset, vals, yerr=yerr, fmt="none", ecolor="black", elinewidth=0.8, capsize=3)
        for xi, v, top in zip(x + offset, vals, hi):
            if np.isfinite(v):  # the value above its error bar
                ax.text(xi, (top if np.isfinite(top) else v) + 1.0, f"{v:.0f}", ha="center", va="bottom", fontsize=7)
    for i, s in enumerate(suites):
        ax.hlines(100.0 / metrics[s].n_choices, i - w - 0.05, i + w + 0.05, colors="#d62728", linestyles="--",
                  linewidth=1.4, label="random selection (1/N)" if i == 0 else None)
    ax.set_xticks(x)
    ax.set_xticklabels([s.removeprefix("RSB-") for s in suites], rotation=20 if len(suites) > 4 else 0)
    ax.set_ylim(0, 108)
    ax.set_ylabel("% of episodes")
    fig.suptitle(title or "GSR and TSR per suite", fontsize=11)
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), fontsize=8, ncol=3, frameon=False)
    ax.grid(axis="y", alpha=0.3)
    ax.set_axisbelow(True)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, format="png")
    return path


def _nan(x: float | None) -> float:
    return float("nan") if x is None else float(x)
