"""The counterfactual-scenes table and plot: follow, switch and stuck rates beside their chance lines.

The numbers are ``evaluation/counterfactual.py``'s (a pure function of the records); this module
only writes them: Markdown for summary.md and report.html, flat rows for the CSV, and a PNG.
"""
from __future__ import annotations

from typing import Any

from rsb_maniskill.evaluation.counterfactual import CHANCE_FORMULAS, POOLED, CounterfactualMetrics, Table
from rsb_maniskill.reporting.cells import NA, markdown_table, pct, rate_cell
from rsb_maniskill.reporting.figures import png_uri, png_with_legend_below, rate_bars

RATES = ("follow", "switch", "stuck")  # the plotted rates, each beside its chance line
COLORS = {"follow": "#2171b5", "switch": "#41ab5d", "stuck": "#d94801"}
LABELS = {"follow": "follow (of grasped)", "switch": "switch", "stuck": "stuck"}
HEADER = ["Suite", "N", "K", "Scenes", "Follow", "chance", "Follow (all)", "remap", "requestion", "Switch",
          "chance", "Stuck", "chance"]
NOTE = ("Follow: the grasped candidate is the variant's target, over variants with a grasp (Follow (all): over "
        "every variant; remap / requestion: by the kind of variant). Switch: two variants of a scene with "
        "different targets, both grasped, got different candidates. Stuck: one candidate grasped in every variant "
        "of a scene, over scenes whose every variant was grasped. Chance: a policy grasping uniformly at random, "
        f"follow {CHANCE_FORMULAS['follow']}, switch {CHANCE_FORMULAS['switch']}, stuck "
        f"{CHANCE_FORMULAS['stuck']}. %, Wilson 95% intervals (switch: over the pairs of a scene that share no "
        "variant, K/2 a scene, as the pairs of a scene are not independent).")


def _n(value: int | None) -> str:
    return NA if value is None else str(value)


def _cells(suite: str, m: CounterfactualMetrics) -> list[str]:
    return [suite, _n(m.n_choices), _n(m.variants_per_scene), str(m.counts.scenes), rate_cell(m.follow),
            pct(m.chance_follow), rate_cell(m.follow_all), rate_cell(m.follow_by_kind["remap"]),
            rate_cell(m.follow_by_kind["requestion"]), rate_cell(m.switch), pct(m.chance_switch),
            rate_cell(m.stuck), pct(m.chance_stuck)]


def counterfactual_markdown(table: Table) -> str:
    """One table per policy row: each suite, then the pooled line."""
    parts = [f"### Counterfactual scenes: {row} (%)\n\n"
             + markdown_table(HEADER, [_cells("**Pooled**" if s == POOLED else s, m) for s, m in suites.items()])
             for row, suites in table.items()]
    return "\n\n".join(parts) + (f"\n\n{NOTE}\n" if parts else "")


def counterfactual_rows(table: Table) -> list[dict[str, Any]]:
    """Flat rows for ``<stem>_counterfactual.csv``: one per row and suite (and pooled)."""
    out = []
    for row, suites in table.items():
        for suite, m in suites.items():
            d = m.to_dict()
            flat: dict[str, Any] = {"row": row, "suite_id": suite}
            flat.update({k: d[k] for k in ("n_choices", "variants_per_scene", "scenes", "variants", "grasped",
                                           "pairs", "disjoint_pairs", "full_scenes")})
            for name in ("follow", "follow_all", "switch", "stuck"):
                flat.update({f"{name}{suffix}": d[name][key] for suffix, key in (("", "value"), ("_low", "low"),
                                                                                  ("_high", "high"))})
            for kind, r in d["follow_by_kind"].items():
                flat[f"follow_{kind}"] = r["value"]
            flat.update({f"chance_{k}": v for k, v in d["chance"].items()})
            out.append(flat)
    return out


def plot_counterfactual(table: Table) -> bytes:
    """PNG: one panel per policy row; per suite the follow, switch and stuck rates with Wilson 95 %
    whiskers, and each rate's chance as a dashed mark over its bar."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    width = max(6.0, 1.4 * max(len(s) for s in table.values()) + 2.5)
    fig = Figure(figsize=(width, 3.4 * len(table) + 0.5), dpi=110)
    FigureCanvasAgg(fig)
    w = 0.26
    for p, (row, suites) in enumerate(table.items()):
        ax = fig.add_subplot(len(table), 1, p + 1)
        names = list(suites)
        x = np.arange(len(names))
        for j, key in enumerate(RATES):
            pos = x + (j - 1) * w
            rate_bars(ax, pos, [getattr(suites[s], key) for s in names], w, COLORS[key], LABELS[key])
            chance = [getattr(suites[s], f"chance_{key}") for s in names]
            for xi, c in zip(pos, chance):
                if c is not None:
                    ax.hlines(100 * c, xi - w / 2, xi + w / 2, colors="#222", linestyles="--", linewidth=1.2,
                              label="chance" if (j, xi) == (0, pos[0]) else None)
        ax.set_xticks(x)
        ax.set_xticklabels([f"{'pooled' if s == POOLED else s.removeprefix('RSB-')}\n"
                            f"scenes: {suites[s].counts.scenes}" for s in names], fontsize=8)
        ax.set_ylim(0, 112)
        ax.set_ylabel("%")
        ax.set_title(row, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
        ax.set_axisbelow(True)
    return png_with_legend_below(fig, ncol=4, legend_height=0.45)


def plot_counterfactual_uri(table: Table) -> str:
    """The plot as a data URI, for report.html."""
    return png_uri(plot_counterfactual(table))
