"""`rsb audit` output: a summary table, one table per suite, JSON beside Markdown; the
question-aware readers in tables of their own (references), with the twin rule's verdict."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Sequence

from rsb_maniskill.audit.reference import ReaderResult
from rsb_maniskill.audit.run import LEXICAL_PROBE, SuiteAudit
from rsb_maniskill.audit.twins import TwinFailure, twin_failures, twin_pairs


def _pct(x: float | None) -> str:
    return "" if x is None else f"{100 * x:.1f}"


def _ci(lo: float | None, hi: float | None) -> str:
    return "" if lo is None else f"[{100 * lo:.1f}, {100 * hi:.1f}]"


def _split_cell(a: SuiteAudit) -> str:
    o = a.overlap
    return "clean" if o.clean else f"{len(o.exact)} same, {len(o.near)} near-duplicate, {len(o.facts)} facts"


def _lift(x: float | None) -> str:
    return "" if x is None else f"{100 * x:+.1f}"


def _lift_ci(lo: float | None, hi: float | None) -> str:
    return "" if lo is None else f"[{100 * lo:+.1f}, {100 * hi:+.1f}]"


def passed(a: SuiteAudit, twins: Sequence[TwinFailure]) -> bool:
    """The suite's own verdict and the twin rule's (which fails the 10-choice suite of a pair)."""
    return a.passed and not any(t.suite == a.suite_id for t in twins)


def to_dicts(audits: Sequence[SuiteAudit]) -> list[dict[str, Any]]:
    """audit.json: one object per suite; ``twin_failures`` and ``passed`` include the twin rule."""
    twins = twin_failures(audits)
    out = []
    for a in audits:
        d = a.to_dict()
        d["twin_failures"] = [dict(twin=t.twin, reader=t.reader, lift=t.lift, twin_lift=t.twin_lift)
                              for t in twins if t.suite == a.suite_id]
        d["passed"] = passed(a, twins)
        out.append(d)
    return out


def _probe_cell(a: SuiteAudit, name: str) -> str:
    g = next((g for g in a.guessers if g.name == name), None)
    if g:
        return f"{_pct(g.accuracy)} {_ci(g.low, g.high)}"
    return "n/a (train split)" if name == LEXICAL_PROBE and a.split == "train" else "n/a (too few train episodes)"


def summary_markdown(audits: Sequence[SuiteAudit]) -> str:
    """One row per suite: the worst named guesser, the learned probes, ambiguity, split overlap."""
    twins = twin_failures(audits)
    lines = ["| suite | episodes | chance % | worst named guesser | % [95 % CI] | learned probe % [95 % CI] "
             "| lexical probe % [95 % CI] | ambiguous sets | train/test overlap | verdict |",
             "|---|---:|---:|---|---|---|---|---:|---|---|"]
    for a in audits:
        named = [g for g in a.guessers if g.kind == "named"]
        worst = max(named, key=lambda g: g.low)
        verdict = "pass" if passed(a, twins) else "**FAIL** (twin rule)" if a.passed else "**FAIL**"
        lines.append(f"| {a.suite_id} | {a.episodes:,} | {_pct(a.chance)} | {worst.name} | {_pct(worst.accuracy)} "
                     f"{_ci(worst.low, worst.high)} | {_probe_cell(a, 'learned probe')} | "
                     f"{_probe_cell(a, LEXICAL_PROBE)} | {a.ambiguous} | {_split_cell(a)} | {verdict} |")
    return "\n".join(lines)


def token_lines(a: SuiteAudit) -> list[str]:
    """The lexical probe's heaviest n-grams, each side: what the words of the options give away."""
    def fmt(tokens: Sequence[Sequence]) -> str:
        return ", ".join(f"{t} ({w:+.2f}, {n:,} options)" for t, w, n in tokens) or "none"

    return [f"Lexical probe: n-grams marking the answer: {fmt(a.answer_tokens)}.",
            f"Lexical probe: n-grams marking a distractor: {fmt(a.distractor_tokens)}."]


def suite_markdown(a: SuiteAudit) -> str:
    """Every guesser of one suite, furthest above chance first."""
    out = [f"### {a.suite_id} ({a.split} split, {a.episodes:,} episodes, chance {_pct(a.chance)} %)", "",
           "| guesser | reads question | % | 95 % CI | vs chance (points) | applies to | % where it applies | flag |",
           "|---|---|---:|---|---:|---:|---|---|"]
    for g in sorted(a.guessers, key=lambda g: -g.accuracy):
        where = "" if g.applies_accuracy is None else f"{_pct(g.applies_accuracy)} {_ci(g.applies_low, g.applies_high)}"
        flag = "**above chance**" if g.flagged else ""
        out.append(f"| {g.name} | {'yes' if g.reads_question else ''} | {_pct(g.accuracy)} | {_ci(g.low, g.high)} | "
                   f"{100 * (g.accuracy - a.chance):+.1f} | {g.applies:,} | {where} | {flag} |")
    if a.readers:
        out += ["", "#### question-aware readers (reference)", "",
                "| reader | % | 95 % CI | lift (points) | lift 95 % CI | applies to | what it reads |",
                "|---|---:|---|---:|---|---:|---|"]
        out += [_reader_row(r) for r in a.readers]
    if a.probe_features:
        feats = ", ".join(f"{name} ({imp:.3f})" for name, imp in a.probe_features)
        out += ["", f"Learned probe leans on: {feats} (permutation importance, log-loss)."]
    if a.answer_tokens or a.distractor_tokens:
        out += [""] + token_lines(a)
    if a.ambiguous:
        out += ["", f"{a.ambiguous} option sets hold a second option equal to the answer (normal form), e.g.:"]
        out += [f"- {' / '.join(s)}" for s in a.ambiguous_examples]
    if not a.overlap.clean:
        o = a.overlap
        out += ["", "Shared by train and test:"] + [f"- same question: {t}" for t in o.exact[:5]]
        out += [f"- near-duplicates ({j}): {x} / {y}" for x, y, j in o.near[:5]] + [f"- fact: {f}" for f in o.facts[:5]]
    return "\n".join(out)


def _reader_row(r: ReaderResult) -> str:
    if r.unavailable:
        return f"| {r.name} | unavailable: {r.unavailable} | | | | | {r.description} |"
    return (f"| {r.name} | {_pct(r.accuracy)} | {_ci(r.low, r.high)} | {_lift(r.lift)} | "
            f"{_lift_ci(r.lift_low, r.lift_high)} | {r.applies:,} | {r.description} |")


def readers_markdown(audits: Sequence[SuiteAudit]) -> str:
    """Compact reader summary (suite, reader, accuracy, lift) and the twin rule's verdict; "" without readers."""
    rows = [(a, r) for a in audits for r in a.readers]
    if not rows:
        return ""
    lines = ["## Question-aware readers (reference)", "",
             "Readers look at the question without solving it; they do not fail a suite by beating chance. "
             "Lift = (accuracy - 1/N) / (1 - 1/N), in points: 0 is chance, 100 always right.", "",
             "| suite | reader | % | 95 % CI | lift | lift 95 % CI |", "|---|---|---:|---|---:|---|"]
    for a, r in rows:
        if r.unavailable:
            lines.append(f"| {a.suite_id} | {r.name} | unavailable: {r.unavailable} | | | |")
        else:
            lines.append(f"| {a.suite_id} | {r.name} | {_pct(r.accuracy)} | {_ci(r.low, r.high)} | {_lift(r.lift)} | "
                         f"{_lift_ci(r.lift_low, r.lift_high)} |")
    twins = twin_failures(audits)
    if twins:
        lines += ["", "**Twin rule FAILS** (a reader lifts the 10-choice suite more than its 4-choice twin, "
                  "intervals apart):"] + [f"- {t}" for t in twins]
    elif twin_pairs(audits):
        pairs = ", ".join(f"{ten.suite_id} / {four.suite_id}" for ten, four in twin_pairs(audits))
        lines += ["", f"Twin rule: pass ({pairs}: no reader lifts the 10-choice suite above its 4-choice twin, "
                  "intervals apart)."]
    else:
        lines += ["", "Twin rule: no 4-choice / 10-choice twin pair in this audit."]
    return "\n".join(lines)


def markdown(audits: Sequence[SuiteAudit]) -> str:
    margin = audits[0].margin if audits else 0.03
    head = ["# RSB shortcut audit", "",
            "Answer-blind guessers pick an option without solving the question; the learned probes (surface: "
            "gradient-boosted trees on each option's shape in its set; lexical: a linear model on its words) are "
            "trained on the train split to pick the answer from the options alone. A suite fails when a guesser's "
            f"whole 95 % interval lies above chance + {100 * margin:.0f} points (overall, or on the episodes it "
            "applies to), when an option set holds two answers, or when train and test share a question or fact. "
            "Question-aware readers are references; a 10-choice suite fails only when a reader lifts it above its "
            "4-choice twin (the twin rule). Intervals count questions, not episodes: the episodes that ask one "
            "question are one dependent group, weighed by its effective size (design effect).", "",
            summary_markdown(audits), ""]
    readers = readers_markdown(audits)
    head += [readers, ""] if readers else []
    return "\n".join(head + [suite_markdown(a) + "\n" for a in audits])


def write(audits: Sequence[SuiteAudit], out_dir: str | os.PathLike) -> tuple[Path, Path]:
    """``audit.json`` and ``audit.md`` under ``out_dir`` (created); returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    js, md = out / "audit.json", out / "audit.md"
    tmp = js.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(to_dicts(audits), indent=1), encoding="utf-8")
    os.replace(tmp, js)
    md.write_text(markdown(audits), encoding="utf-8")
    return js, md
