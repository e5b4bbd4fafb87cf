"""Counterfactual scenes, over records: does the policy's choice follow the instruction?

``rsb eval --instruction counterfactual`` runs K variants of every protocol scene (same seed,
layout and candidates; the answer on a different candidate in each, ``semantic/counterfactual.py``).
Its records carry ``variant``, ``variant_kind``, the variant's ``target_block`` and what was
grasped first, ``first_grasped`` (-1: nothing). Over them, per suite and pooled:

- **follow rate** = changed variants (k > 0) whose grasped candidate is the variant's target /
  changed variants with a grasp (``follow``); also over every grasped variant (``follow_grasped``),
  over all variants (``follow_all``: a variant without a grasp counts as
  not followed), and per kind (remap: the binding moved; requestion: the question changed).
- **switch rate** = pairs of variants of one scene, both with a grasp and with different targets,
  whose grasped candidates differ / such pairs. A policy that reads the instruction switches.
- **stuck rate** = scenes whose every variant (at least two) was grasped, all on the same candidate
  / scenes whose every variant was grasped: the policy ignores the instruction in that scene.

Chance, for a policy that grasps one of the N candidates uniformly at random, independently in
every variant: follow 1/N; switch 1 - 1/N; stuck (1/N)^(K-1) for a scene of K variants. Pooled
chances are the per-suite chances averaged with the weights of the pooled denominator, so they are
what such a policy would score on the same episodes.

The intervals count scenes: a scene's variants (and the K(K-1)/2 pairs of its variants) are not
independent (three of four ask the same question; a scene the policy is stuck in has all its pairs
unswitched). Follow and switch are the means over all variants / pairs, their intervals Wilson's at
the effective number of them (``stats.clustered_rate``: Kish's design effect over scenes, the
scenes' sizes where it cannot be estimated, at 0 % or 100 %, and Student's t over the scenes);
stuck counts one a scene. Each rate's ``detectable`` difference is the smallest one a paired
comparison on the same scenes finds 4 times in 5 (``stats.minimum_detectable_difference``: McNemar's
exact test at n over the same design effect).
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import Rate, num_choices
from rsb_maniskill.evaluation.records import COUNTERFACTUAL, dedupe, record_row
from rsb_maniskill.evaluation.stats import clustered_rate, design_effect, minimum_detectable_difference
from rsb_maniskill.reporting.blocks import Block, Grid, Heading, Inline, Note, Strong, to_markdown
from rsb_maniskill.reporting.cells import NA, NONE_AT_N, pct, points, rate_cell
from rsb_maniskill.reporting.figures import png_uri, png_with_legend_below, rate_bars
from rsb_maniskill.reporting.sections.base import Section, write_rows

POOLED = "pooled"  # the key of the pooled column, beside the suite ids
KINDS = ("remap", "requestion")  # the variants that move the answer (variant 0 is the protocol episode)
CHANCE_FORMULAS = {"follow": "1/N", "switch": "1 - 1/N", "stuck": "(1/N)^(K-1)"}


@dataclass(frozen=True)
class Counts:
    """The numerators and denominators of one suite (or of several, pooled), with chance sums."""

    scenes: int = 0
    variants: int = 0
    grasped: int = 0
    followed: int = 0
    kind_grasped: Mapping[str, int] = field(default_factory=dict)
    kind_followed: Mapping[str, int] = field(default_factory=dict)
    pairs: int = 0
    switched: int = 0
    full_scenes: int = 0  # scenes whose every variant was grasped (K >= 2)
    stuck: int = 0
    chance_followed: float = 0.0  # expected numerators of a uniform random grasper
    chance_switched: float = 0.0
    chance_stuck: float = 0.0
    # Per scene, its own numerators and denominators ("followed", "grasped", ...): the intervals count
    # scenes, not variants (three of a scene's four variants ask the same question).
    per_scene: tuple[Mapping[str, float], ...] = ()

    def __add__(self, o: "Counts") -> "Counts":
        kinds = set(self.kind_grasped) | set(o.kind_grasped)
        return Counts(**{k: getattr(self, k) + getattr(o, k) for k in _SUMMED}, per_scene=self.per_scene + o.per_scene,
                      kind_grasped={k: self.kind_grasped.get(k, 0) + o.kind_grasped.get(k, 0) for k in kinds},
                      kind_followed={k: self.kind_followed.get(k, 0) + o.kind_followed.get(k, 0) for k in kinds})


_SUMMED = ("scenes", "variants", "grasped", "followed", "pairs", "switched", "full_scenes", "stuck",
           "chance_followed", "chance_switched", "chance_stuck")


@dataclass(frozen=True)
class CounterfactualMetrics:
    """Follow, switch and stuck rates of one suite (or pooled), with the chance lines."""

    n_choices: int | None  # None when pooled over suites of different N
    variants_per_scene: int | None  # K, None when scenes differ
    counts: Counts
    follow: Rate  # the headline: over the changed variants (k > 0: remap, requestion) with a grasp
    follow_all: Rate  # over all variants
    follow_by_kind: dict[str, Rate]
    switch: Rate
    stuck: Rate
    chance_follow: float | None
    chance_switch: float | None
    chance_stuck: float | None
    follow_grasped: Rate = Rate(None, None, None)  # over every variant with a grasp, the protocol's (k = 0) too
    switched_and_followed: Rate = Rate(None, None, None)  # pairs with different targets, both grasps on target
    spread: Mapping[str, int] = field(default_factory=dict)  # scenes: all / some / none of their changed variants
    detectable: Mapping[str, float | None] = field(default_factory=dict)  # follow, switch: see scene_detectable

    @classmethod
    def of(cls, counts: Counts, n_choices: int | None, k: int | None) -> "CounterfactualMetrics":
        c = counts
        changed = sum(sc.get(f"{kind}_grasped", 0) for sc in c.per_scene for kind in KINDS)
        chance_changed = sum(sc.get("chance_changed", 0.0) for sc in c.per_scene)
        return cls(n_choices, k, c, scene_rate(c, "changed_followed", "changed_grasped"),
                   scene_rate(c, "followed", "variants"),
                   {kind: scene_rate(c, f"{kind}_followed", f"{kind}_grasped") for kind in KINDS},
                   scene_rate(c, "switched", "pairs"), Rate.of(c.stuck, c.full_scenes),
                   _ratio(chance_changed, changed), _ratio(c.chance_switched, c.pairs),
                   _ratio(c.chance_stuck, c.full_scenes), scene_rate(c, "followed", "grasped"),
                   scene_rate(c, "both_followed", "pairs"), spread(c),
                   {"follow": scene_detectable(c, "changed_followed", "changed_grasped"),
                    "switch": scene_detectable(c, "switched", "pairs")})

    def to_dict(self) -> dict[str, Any]:
        def rate(r: Rate) -> dict[str, float | None]:
            return {"value": r.value, "low": r.low, "high": r.high}

        c = self.counts
        return {"n_choices": self.n_choices, "variants_per_scene": self.variants_per_scene, "scenes": c.scenes,
                "variants": c.variants, "grasped": c.grasped, "pairs": c.pairs, "full_scenes": c.full_scenes,
                "follow": rate(self.follow), "follow_all": rate(self.follow_all),
                "follow_by_kind": {k: rate(r) for k, r in self.follow_by_kind.items()},
                "switch": rate(self.switch), "stuck": rate(self.stuck),
                "follow_grasped": rate(self.follow_grasped), "switched_and_followed": rate(self.switched_and_followed),
                "spread": dict(self.spread), "detectable_difference": dict(self.detectable),
                "chance": {"follow": self.chance_follow, "switch": self.chance_switch, "stuck": self.chance_stuck}}


def _ratio(x: float, n: int) -> float | None:
    return x / n if n else None


def spread(counts: Counts) -> dict[str, int]:
    """Scenes with a grasped changed variant, by how many of those followed: ``all``, ``some``, ``none``
    (a policy that follows half its variants everywhere differs from one that follows half its scenes)."""
    out = {"all": 0, "some": 0, "none": 0}
    for scene in counts.per_scene:
        n, k = scene.get("changed_grasped", 0), scene.get("changed_followed", 0)
        if n:
            out["all" if k == n else "none" if k == 0 else "some"] += 1
    return out


def scene_values(counts: Counts, hits: str, of: str) -> tuple[list[int], list[int]]:
    """The 0/1 outcomes behind ``sum(hits) / sum(of)`` over the scenes of ``counts``, and each one's scene."""
    values: list[int] = []
    clusters: list[int] = []
    for i, scene in enumerate(counts.per_scene):
        n, k = scene.get(of, 0), scene.get(hits, 0)
        values += [1] * k + [0] * (n - k)
        clusters += [i] * n
    return values, clusters


def scene_rate(counts: Counts, hits: str, of: str) -> Rate:
    """``sum(hits) / sum(of)`` over the scenes of ``counts``, with Wilson's 95 % interval at the
    effective sample size (the design effect over scenes, ``stats.clustered_rate``): a scene whose
    variants all went the same way counts about once, not K times."""
    values, clusters = scene_values(counts, hits, of)
    if not values:
        return Rate(None, None, None)
    return clustered_rate(values, clusters)


def scene_detectable(counts: Counts, hits: str, of: str) -> float | None:
    """The smallest difference from ``sum(hits) / sum(of)`` that a paired comparison on the same
    scenes detects with 80 % power at p < 0.05: McNemar's exact test at the effective sample size
    (n over this run's design effect over scenes). None where there is no rate, or none at this n."""
    values, clusters = scene_values(counts, hits, of)
    if not values:
        return None
    return minimum_detectable_difference(sum(values) / len(values), len(values),
                                         design=design_effect(values, clusters))


def grasped(record: Mapping[str, Any]) -> int | None:
    """The candidate grasped first in an episode, None when none was."""
    g = int(record.get("first_grasped", -1))
    return g if g >= 0 else None


def scene_counts(variants: Sequence[Mapping[str, Any]], n_choices: int) -> Counts:
    """The counts of one scene: its variants' records (one per variant index)."""
    picks = [grasped(r) for r in variants]
    targets = [int(r["target_block"]) for r in variants]
    kinds = [str(r.get("variant_kind", "")) for r in variants]
    kind_grasped: dict[str, int] = defaultdict(int)
    kind_followed: dict[str, int] = defaultdict(int)
    for g, t, kind in zip(picks, targets, kinds):
        if g is not None and kind in KINDS:
            kind_grasped[kind] += 1
            kind_followed[kind] += g == t
    pairs = [(a, b) for (a, ta), (b, tb) in combinations(zip(picks, targets), 2)
             if a is not None and b is not None and ta != tb]
    full = len(picks) >= 2 and all(g is not None for g in picks)
    n_grasped = sum(g is not None for g in picks)
    followed = sum(g == t for g, t in zip(picks, targets) if g is not None)
    both = sum(a == ta and b == tb for (a, ta), (b, tb) in combinations(zip(picks, targets), 2)
               if a is not None and b is not None and ta != tb)
    changed_grasped = sum(kind_grasped.values())
    own = {"followed": followed, "grasped": n_grasped, "variants": len(picks), "pairs": len(pairs),
           "both_followed": both, "changed_grasped": changed_grasped,
           "changed_followed": sum(kind_followed.values()), "chance_changed": changed_grasped / n_choices,
           "switched": sum(a != b for a, b in pairs),
           **{f"{kind}_{what}": d.get(kind, 0) for kind in KINDS
              for what, d in (("grasped", kind_grasped), ("followed", kind_followed))}}
    return Counts(
        scenes=1, variants=len(picks), grasped=n_grasped,
        followed=sum(g == t for g, t in zip(picks, targets) if g is not None),
        kind_grasped=dict(kind_grasped), kind_followed=dict(kind_followed),
        pairs=len(pairs), switched=sum(a != b for a, b in pairs),
        full_scenes=int(full), stuck=int(full and len(set(picks)) == 1),
        chance_followed=n_grasped / n_choices, chance_switched=len(pairs) * (1 - 1 / n_choices),
        chance_stuck=(1 / n_choices) ** (len(picks) - 1) if full else 0.0, per_scene=(own,))


def counterfactual_records(records: Iterable[Mapping[str, Any]]) -> list[dict]:
    """The counterfactual-mode records, deduplicated (variant by variant)."""
    return [r for r in dedupe(records) if r.get("instruction_mode") == COUNTERFACTUAL]


Table = dict[str, dict[str, CounterfactualMetrics]]  # row -> suite (and POOLED) -> metrics


def counterfactual_table(records: Iterable[Mapping[str, Any]]) -> Table:
    """Per table row (``"oracle (counterfactual)"``) and suite, and pooled over the row's suites;
    empty without counterfactual records. Suites in the order first met."""
    scenes: dict[str, dict[str, dict[int, list]]] = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    for r in counterfactual_records(records):
        scenes[record_row(r)][str(r["suite_id"])][int(r["seed"])].append(r)
    out: Table = {}
    for row, suites in scenes.items():
        out[row] = {}
        pooled, ns, ks = Counts(), set(), set()
        for suite, by_seed in suites.items():
            n = num_choices(suite)
            total, sizes = Counts(), set()
            for variants in by_seed.values():
                variants.sort(key=lambda r: int(r.get("variant", 0)))
                total = total + scene_counts(variants, n)
                sizes.add(len(variants))
            k = sizes.pop() if len(sizes) == 1 else None
            out[row][suite] = CounterfactualMetrics.of(total, n, k)
            pooled, ns, ks = pooled + total, ns | {n}, ks | {k}
        if len(suites) > 1:
            out[row][POOLED] = CounterfactualMetrics.of(pooled, ns.pop() if len(ns) == 1 else None,
                                                        ks.pop() if len(ks) == 1 else None)
    return out


def counterfactual_json(table: Table) -> dict[str, Any]:
    """The ``counterfactual`` section of summary.json."""
    return {"definitions": {"follow": "grasped candidate == the variant's target, over the changed variants "
                                      "(k > 0) with a grasp (follow_grasped: every variant with a grasp; "
                                      "follow_all: every variant)",
                            "switched_and_followed": "both grasps on their targets, over pairs of variants of a "
                                                     "scene with different targets, both grasped",
                            "spread": "scenes with a grasped changed variant: all, some or none of those followed",
                            "switch": "grasped candidates differ, over pairs of variants of a scene with different "
                                      "targets, both grasped",
                            "stuck": "one candidate grasped in every variant of a scene, over scenes whose every "
                                     "variant was grasped",
                            "chance": CHANCE_FORMULAS},
            "rows": {row: {suite: m.to_dict() for suite, m in suites.items()} for row, suites in table.items()}}


# ---------------------------------------------------------------- written
RATES = ("follow", "switch", "stuck")  # the plotted rates, each beside its chance line
COLORS = {"follow": "#2171b5", "switch": "#41ab5d", "stuck": "#d94801"}
LABELS = {"follow": "follow (changed, of grasped)", "switch": "switch", "stuck": "stuck"}
HEADER = ["Suite", "N", "K", "Scenes", "Follow", "chance", "Follow (all)", "remap", "requestion", "Switch",
          "chance", "Switched & followed", "Stuck", "chance", "Scenes followed: all / some / none",
          "Detectable: follow / switch"]
NOTE = ("Follow: the grasped candidate is the variant's target, over the changed variants (k > 0: the answer "
        "moved) with a grasp (Follow (all): over every variant, the protocol's k = 0 too; remap / requestion: by "
        "the kind of variant). Switched & followed: pairs of variants with different targets, both grasps on "
        "their targets (a policy that always grasps one option scores switch, never this). Scenes followed: "
        "scenes with a grasped changed variant, by whether all, some or none of those followed. Switch: two "
        "variants of a scene with "
        "different targets, both grasped, got different candidates. Stuck: one candidate grasped in every variant "
        "of a scene, over scenes whose every variant was grasped. Chance: a policy grasping uniformly at random, "
        f"follow {CHANCE_FORMULAS['follow']}, switch {CHANCE_FORMULAS['switch']}, stuck "
        f"{CHANCE_FORMULAS['stuck']}. %, Wilson 95% intervals over scenes: a scene's variants (and its pairs) are "
        "not independent, so follow and switch are counted at their effective number of scenes (Kish's design "
        "effect; at 0 % or 100 % the scenes' sizes: a scene counts once) with Student's t over the scenes; stuck "
        "counts one a scene. Detectable: the smallest difference in follow / switch a paired comparison on the "
        "same scenes finds 4 times in 5 (points): McNemar's exact test's power, computed exactly, at the effective "
        f"number of them (n / design effect, as the scene test counts them); {NONE_AT_N}: that test cannot reach "
        "it at any difference.")


def _n(value: int | None) -> str:
    return NA if value is None else str(value)


def _cells(suite: Inline, m: CounterfactualMetrics) -> list[Inline]:
    return [suite, _n(m.n_choices), _n(m.variants_per_scene), str(m.counts.scenes), rate_cell(m.follow),
            pct(m.chance_follow), rate_cell(m.follow_all), rate_cell(m.follow_by_kind["remap"]),
            rate_cell(m.follow_by_kind["requestion"]), rate_cell(m.switch), pct(m.chance_switch),
            rate_cell(m.switched_and_followed), rate_cell(m.stuck), pct(m.chance_stuck),
            " / ".join(str(m.spread.get(k, 0)) for k in ("all", "some", "none")),
            " / ".join(NA if getattr(m, k).value is None else points(m.detectable.get(k), NONE_AT_N)
                       for k in ("follow", "switch"))]


def counterfactual_blocks(table: Table) -> list[Block]:
    """One table per policy row: each suite, then the pooled line."""
    out: list[Block] = []
    for row, suites in table.items():
        out += [Heading(f"Counterfactual scenes: {row} (%)"),
                Grid(HEADER, [_cells(Strong("Pooled") if s == POOLED else s, m) for s, m in suites.items()])]
    return out + [Note(NOTE)] if out else []


def counterfactual_markdown(table: Table) -> str:
    return to_markdown(counterfactual_blocks(table))


def counterfactual_rows(table: Table) -> list[dict[str, Any]]:
    """Flat rows for ``<stem>_counterfactual.csv``: one per row and suite (and pooled)."""
    out = []
    for row, suites in table.items():
        for suite, m in suites.items():
            d = m.to_dict()
            flat: dict[str, Any] = {"row": row, "suite_id": suite}
            flat.update({k: d[k] for k in ("n_choices", "variants_per_scene", "scenes", "variants", "grasped",
                                           "pairs", "full_scenes")})
            flat.update({f"{k}_detectable_difference": v for k, v in d["detectable_difference"].items()})
            for name in ("follow", "follow_all", "follow_grasped", "switch", "switched_and_followed", "stuck"):
                flat.update({f"{name}{suffix}": d[name][key] for suffix, key in (("", "value"), ("_low", "low"),
                                                                                  ("_high", "high"))})
            for kind, r in d["follow_by_kind"].items():
                flat[f"follow_{kind}"] = r["value"]
            flat.update({f"chance_{k}": v for k, v in d["chance"].items()})
            flat.update({f"scenes_followed_{k}": v for k, v in d["spread"].items()})
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


class CounterfactualSection(Section):
    key, anchor, title, page_order = "counterfactual", "counterfactual", "Counterfactual scenes", 40
    summary_order = 60
    note = ("Each protocol scene run K times, same layout and candidates, the answer on a different candidate each "
            "time (remap: the same question with the answer bound to another candidate; requestion: another "
            "question). Follow: the grasp went to the variant's target; switch: variants with different targets got "
            "different grasps; stuck: one candidate grasped in every variant, whatever the instruction. Dashed "
            "marks: a policy grasping at random. Whiskers and brackets: Wilson 95% intervals over scenes.")

    def compute(self, records: Sequence[Mapping[str, Any]], results_dir: Path) -> Table | None:
        return counterfactual_table(records) or None

    def to_json(self, table: Table) -> Any:
        return counterfactual_json(table)

    def blocks(self, table: Table) -> list[Block]:
        return counterfactual_blocks(table)

    def files(self, table: Table, out: Path, stem: str) -> dict[str, Path]:
        png = out / f"{stem}_counterfactual.png"
        png.write_bytes(plot_counterfactual(table))
        return {"csv:counterfactual": write_rows(counterfactual_rows(table), out / f"{stem}_counterfactual.csv"),
                "png:counterfactual": png}

    def figure(self, table: Table) -> dict[str, str] | None:
        return {"src": plot_counterfactual_uri(table), "alt": "follow, switch and stuck rates per suite"}


SECTION = CounterfactualSection()
