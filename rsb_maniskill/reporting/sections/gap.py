"""The semantic gap: what a policy's backbone answers beside what the policy's arm does, episode for episode.

``rsb backbone`` writes one answer per episode (``backbone.jsonl``), ``rsb eval`` one outcome
(``episodes.jsonl``). A backbone row and a policy row are joined on a suite when they hold the
same episodes: the same instruction mode, no perturbation, the same seeds, and for every seed the
same question and the same instruction given (so a run on other question data, or another
``--env-arg``, is not joined; it is listed with the reason). Per joined suite:

- the backbone's accuracy, the policy's TSR, TSR/GSR and nSG (Wilson 95 % intervals);
- over the episodes where a block was grasped, the crossing of the backbone's answer with the
  arm's choice (the correct block grasped, or only wrong ones): *backbone right, arm wrong* is the
  semantic gap; *backbone wrong, arm right* a shortcut or luck.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import Rate, outcome, suite_metrics, suite_order
from rsb_maniskill.evaluation.records import dedupe, perturb_label, row_label
from rsb_maniskill.reporting.blocks import Block, Bullets, Grid, Heading, Note, to_markdown
from rsb_maniskill.reporting.cells import rate_cell
from rsb_maniskill.reporting.figures import png_uri, png_with_legend_below, rate_bars
from rsb_maniskill.reporting.sections.base import Section, write_rows

CROSSING = ("right/right", "right/wrong", "wrong/right", "wrong/wrong")  # backbone / arm, over grasped episodes


@dataclass(frozen=True)
class Gap:
    """One backbone row beside one policy row on one suite."""

    backbone: str
    policy: str
    suite_id: str
    n_choices: int
    n_episodes: int
    n_backbone_right: int
    n_grasped: int
    crossing: dict[str, int]  # CROSSING -> grasped episodes
    tsr: Rate
    tsr_gsr: Rate
    nsg: Rate

    @property
    def accuracy(self) -> Rate:
        return Rate.of(self.n_backbone_right, self.n_episodes)

    @property
    def gap(self) -> Rate:
        """Backbone right, arm wrong: share of the grasped episodes."""
        return Rate.of(self.crossing["right/wrong"], self.n_grasped)

    @property
    def shortcut(self) -> Rate:
        """Backbone wrong, arm right: share of the grasped episodes."""
        return Rate.of(self.crossing["wrong/right"], self.n_grasped)

    def to_dict(self) -> dict[str, Any]:
        return {"backbone": self.backbone, "policy": self.policy, "suite_id": self.suite_id,
                "n_episodes": self.n_episodes, "n_grasped": self.n_grasped, "crossing": dict(self.crossing),
                **{k: vars(getattr(self, k)) for k in ("accuracy", "tsr", "tsr_gsr", "nsg", "gap", "shortcut")}}


@dataclass(frozen=True)
class NotJoined:
    backbone: str
    policy: str
    suite_id: str
    reason: str


def backbone_row(record: Mapping[str, Any]) -> str:
    """A backbone row's label: ``"arithmetic"``, ``"arithmetic (blank)"``."""
    return row_label(str(record.get("backbone", "?")), record.get("instruction_mode", "normal"))


def _rows(records: Iterable[Mapping[str, Any]], label: Any) -> dict[str, dict[str, dict[int, Mapping[str, Any]]]]:
    out: dict[str, dict[str, dict[int, Mapping[str, Any]]]] = {}
    for r in records:
        out.setdefault(label(r), {}).setdefault(r["suite_id"], {})[int(r["seed"])] = r
    return out


def _differs(episodes: Mapping[int, Mapping[str, Any]], answers: Mapping[int, Mapping[str, Any]]) -> str | None:
    if set(episodes) != set(answers):
        return (f"seeds differ ({len(episodes)} episodes run, {len(answers)} asked; run both with the same -n)")
    for seed in sorted(episodes):
        e, a = episodes[seed], answers[seed]
        if (e.get("question_id"), e.get("instruction"), e.get("correct_letter")) != (
                a.get("question_id"), a.get("instruction"), a.get("correct_letter")):
            return f"episodes differ (seed {seed}: another question or instruction; other data or --env-arg?)"
    return None


def gap_table(episodes: Iterable[Mapping[str, Any]], answers: Iterable[Mapping[str, Any]]
              ) -> tuple[list[Gap], list[NotJoined]]:
    """Every (backbone row, policy row, suite) holding the same episodes, and those that do not."""
    unperturbed = [r for r in dedupe(episodes) if perturb_label(r) == "none"]
    policies = _rows(unperturbed, lambda r: row_label(str(r.get("policy", "?")), r.get("instruction_mode", "normal")))
    mode_of = {row_label(str(r.get("policy", "?")), r.get("instruction_mode", "normal")): r.get("instruction_mode")
               for r in unperturbed}
    backbones = _rows(answers, backbone_row)
    mode_of_backbone = {backbone_row(r): r.get("instruction_mode") for r in answers}
    gaps, skipped = [], []
    for b, b_suites in backbones.items():
        for p, p_suites in policies.items():
            if mode_of[p] != mode_of_backbone[b]:
                continue
            for suite in suite_order(set(b_suites) & set(p_suites)):
                reason = _differs(p_suites[suite], b_suites[suite])
                if reason:
                    skipped.append(NotJoined(b, p, suite, reason))
                else:
                    gaps.append(_gap(b, p, suite, p_suites[suite], b_suites[suite]))
    return gaps, skipped


def _gap(backbone: str, policy: str, suite: str, episodes: Mapping[int, Mapping[str, Any]],
         answers: Mapping[int, Mapping[str, Any]]) -> Gap:
    m = suite_metrics(list(episodes.values()), suite)
    crossing = dict.fromkeys(CROSSING, 0)
    for seed, e in episodes.items():
        kind = outcome(e)
        if kind != "no_grasp":
            crossing[f"{'right' if answers[seed]['correct'] else 'wrong'}/"
                     f"{'wrong' if kind == 'wrong_target' else 'right'}"] += 1
    return Gap(backbone, policy, suite, m.n_choices, m.n_episodes, sum(bool(a["correct"]) for a in answers.values()),
               m.n_grasped, crossing, m.tsr, Rate.of(m.n_success, m.n_grasped), m.nsg)


# ---------------------------------------------------------------- tables
def backbone_blocks(answers: Iterable[Mapping[str, Any]]) -> list[Block]:
    """The backbone rows' accuracy per suite: right, and no option stated, with intervals."""
    rows = []
    for label, suites in _rows(answers, backbone_row).items():
        for suite in suite_order(suites):
            recs = list(suites[suite].values())
            n = len(recs)
            rows.append([label, suite, str(n), rate_cell(Rate.of(sum(bool(r["correct"]) for r in recs), n)),
                         rate_cell(Rate.of(sum(r.get("stated_letter") is None for r in recs), n))])
    return [Heading("Backbone accuracy (%, Wilson 95% intervals)"),
            Note("Right: the answer states the correct option; no option: it states none, or several."),
            Grid(["Backbone", "Suite", "Episodes", "Right", "No option"], rows)]


def backbone_markdown(answers: Iterable[Mapping[str, Any]]) -> str:
    return to_markdown(backbone_blocks(answers))


def gap_blocks(table: tuple[Sequence[Gap], Sequence[NotJoined]]) -> list[Block]:
    gaps, skipped = table
    out: list[Block] = []
    if gaps:
        rows = [[g.backbone, g.policy, g.suite_id, str(g.n_episodes)]
                + [rate_cell(r) for r in (g.accuracy, g.tsr, g.tsr_gsr, g.nsg, g.gap, g.shortcut)] + [str(g.n_grasped)]
                for g in gaps]
        out += [Heading("The semantic gap (%, Wilson 95% intervals)"),
                Note("The backbone's answers beside the policy's actions on the same episodes. Over the grasped "
                     "episodes: backbone right, arm wrong (a wrong block grasped) is the semantic gap; backbone "
                     "wrong, arm right (the correct block grasped) is a shortcut or luck."),
                Grid(["Backbone", "Policy", "Suite", "Episodes", "Backbone right", "TSR", "TSR/GSR", "nSG",
                      "Backbone right, arm wrong", "Backbone wrong, arm right", "Grasped"], rows)]
    if skipped:
        out += [Note("Not joined (their episodes differ):"),
                Bullets(tuple(f"{s.backbone} / {s.policy} / {s.suite_id}: {s.reason}" for s in skipped))]
    return out


def gap_markdown(table: tuple[Sequence[Gap], Sequence[NotJoined]]) -> str:
    return to_markdown(gap_blocks(table))


def gap_rows(gaps: Sequence[Gap]) -> list[dict[str, Any]]:
    """One CSV row per joined (backbone, policy, suite); rates as fractions with their bounds."""
    out = []
    for g in gaps:
        row: dict[str, Any] = {"backbone": g.backbone, "policy": g.policy, "suite_id": g.suite_id,
                               "n_episodes": g.n_episodes, "n_grasped": g.n_grasped}
        for key in ("accuracy", "tsr", "tsr_gsr", "nsg", "gap", "shortcut"):
            rate = getattr(g, key)
            row.update({key: rate.value, f"{key}_low": rate.low, f"{key}_high": rate.high})
        row.update({f"grasped_{k.replace('/', '_')}": v for k, v in g.crossing.items()})
        out.append(row)
    return out


def gap_json(answers: Sequence[Mapping[str, Any]], table: tuple[Sequence[Gap], Sequence[NotJoined]]) -> dict:
    gaps, skipped = table
    accuracy = {}
    for label, suites in _rows(answers, backbone_row).items():
        accuracy[label] = {s: vars(Rate.of(sum(bool(r["correct"]) for r in suites[s].values()), len(suites[s])))
                           for s in suite_order(suites)}
    return {"accuracy": accuracy, "gap": [g.to_dict() for g in gaps], "not_joined": [vars(s) for s in skipped]}


# ---------------------------------------------------------------- plot
BAR_COLORS = {"accuracy": "#6a51a3", "tsr_gsr": "#2171b5", "gap": "#d62728"}
BAR_LABELS = {"accuracy": "backbone right", "tsr_gsr": "TSR/GSR (arm)", "gap": "backbone right, arm wrong"}


def plot_gap(gaps: Sequence[Gap]) -> bytes:
    """PNG: one panel per (backbone, policy), per suite the backbone's accuracy, the policy's
    TSR/GSR and the semantic gap with Wilson 95 % whiskers, and each suite's 1/N line."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    pairs: dict[tuple[str, str], list[Gap]] = {}
    for g in gaps:
        pairs.setdefault((g.backbone, g.policy), []).append(g)
    width = max(6.0, 1.3 * max(len(v) for v in pairs.values()) + 2.5)
    fig = Figure(figsize=(width, 3.4 * len(pairs) + 0.5), dpi=110)
    FigureCanvasAgg(fig)
    w = 0.26
    for k, ((backbone, policy), row) in enumerate(pairs.items()):
        ax = fig.add_subplot(len(pairs), 1, k + 1)
        x = np.arange(len(row))
        for j, key in enumerate(BAR_COLORS):
            pos = x + (j - 1) * w
            vals, hi = rate_bars(ax, pos, [getattr(g, key) for g in row], w, BAR_COLORS[key], BAR_LABELS[key])
            for xi, v, top in zip(pos, vals, hi):
                if np.isfinite(v):
                    ax.text(xi, (top if np.isfinite(top) else v) + 1.5, f"{v:.0f}", ha="center", fontsize=7)
        for i, g in enumerate(row):
            ax.hlines(100 / g.n_choices, i - 1.6 * w, i + 1.6 * w, colors="#555", linestyles="--", linewidth=1.2,
                      label="chance (1/N)" if i == 0 else None)
        ax.set_xticks(x)
        ax.set_xticklabels([f"{g.suite_id.removeprefix('RSB-')}\nn = {g.n_episodes}" for g in row], fontsize=8)
        ax.set_ylim(0, 112)
        ax.set_ylabel("%")
        ax.set_title(f"{backbone} (backbone) vs {policy} (policy)", fontsize=10)
        ax.grid(axis="y", alpha=0.3)
        ax.set_axisbelow(True)
    return png_with_legend_below(fig, ncol=2, legend_height=0.55)


def plot_gap_uri(gaps: Sequence[Gap]) -> str:
    return png_uri(plot_gap(gaps))


class GapSection(Section):
    """With ``rsb backbone`` answers beside the records: the backbone's accuracy and the semantic gap."""

    key, anchor, title, page_order, lead = "backbone", "gap", "The semantic gap", 30, ""
    summary_order = 30
    note = ("What the policy's backbone answers (<code>rsb backbone</code>, the same episodes asked as the policy "
            "gets them) beside what its arm does. In brackets: Wilson 95% intervals.")

    def compute(self, records: Sequence[Mapping[str, Any]], results_dir: Path) -> tuple | None:
        from rsb_maniskill.evaluation.store import BACKBONE_FILE, read_backbone_records

        if not (results_dir / BACKBONE_FILE).exists():
            return None
        answers = read_backbone_records(results_dir / BACKBONE_FILE)
        return answers, gap_table(records, answers)

    def to_json(self, table: tuple) -> Any:
        answers, gap = table
        return gap_json(answers, gap)

    def blocks(self, table: tuple) -> list[Block]:
        answers, gap = table
        return backbone_blocks(answers) + gap_blocks(gap)

    def markdown(self, table: tuple) -> str:
        # a blank line after the accuracy table even when nothing follows it, as summary.md always had
        return super().markdown(table) + ("" if gap_blocks(table[1]) else "\n")

    def files(self, table: tuple, out: Path, stem: str) -> dict[str, Path]:
        gap = table[1]
        if not gap[0]:
            return {}
        png = out / f"{stem}_gap.png"
        png.write_bytes(plot_gap(gap[0]))
        return {"csv:gap": write_rows(gap_rows(gap[0]), out / f"{stem}_gap.csv"), "png:gap": png}

    def figure(self, table: tuple) -> dict[str, str] | None:
        gap = table[1]
        return {"src": plot_gap_uri(gap[0]), "alt": "the semantic gap per suite"} if gap[0] else None


SECTION = GapSection()
