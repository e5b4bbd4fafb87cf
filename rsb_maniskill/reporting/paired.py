"""``rsb report --compare A B`` over episodes: the two runs' records paired episode by episode.

Two runs of the same benchmark version on the same suite and seed (and instruction mode,
perturbation and counterfactual variant) saw the same episode, so their outcomes are *paired*:
the exact McNemar test (``evaluation/stats.py``) compares GSR, TSR and, for counterfactual rows,
follow (the grasped candidate is the variant's target) on the discordant pairs, and a paired
bootstrap (a scene's variants resampled together) compares nSG. That is far more sensitive than
asking whether two intervals overlap, and honest: only episodes both runs played are compared; how
many were left out is said. Two runs that share no suite, or no episode, are refused
(:class:`NoPairs`).
"""
from __future__ import annotations

from collections import defaultdict
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from rsb_maniskill.evaluation.metrics import nsg, num_choices, suite_order
from rsb_maniskill.evaluation.records import COUNTERFACTUAL, DIGEST_FIELD, KEY_DEFAULTS, dedupe, perturb_label
from rsb_maniskill.evaluation.stats import mcnemar, paired_bootstrap
from rsb_maniskill.reporting.cells import NA, delta, markdown_table, pct

# What identifies an episode across two runs (the record key without the policy).
PAIR_KEY: tuple[str, ...] = ("suite_id", "instruction_mode", "perturb", "seed", "variant")
ALPHA = 0.05  # a difference is "significant" below this p-value


class NoPairs(ValueError):
    """The two runs share no suite or no episode: nothing can be compared."""


def pair_key(record: Mapping[str, Any]) -> tuple:
    return tuple(record.get(k, KEY_DEFAULTS.get(k)) for k in PAIR_KEY)


def _followed(r: Mapping[str, Any]) -> bool:
    return int(r.get("first_grasped", -1)) == int(r.get("target_block", -2))


def pair_records(a: Iterable[Mapping[str, Any]], b: Iterable[Mapping[str, Any]],
                 ) -> tuple[list[tuple[Mapping[str, Any], Mapping[str, Any]]], int, int]:
    """The (A, B) record pairs of the same episode, and how many records of A and of B found none.
    Each run must hold one policy per episode (the first record of an episode is kept). Records of
    the same seed whose episode digests differ (one run on other question data) are not paired."""
    ia = {pair_key(r): r for r in reversed(dedupe(a))}
    ib = {pair_key(r): r for r in reversed(dedupe(b))}
    common = [k for k in ia if k in ib and ia[k].get(DIGEST_FIELD, ib[k].get(DIGEST_FIELD)) ==
              ib[k].get(DIGEST_FIELD, ia[k].get(DIGEST_FIELD))]
    return [(ia[k], ib[k]) for k in sorted(common, key=repr)], len(ia) - len(common), len(ib) - len(common)


def _nsg_stat(n_choices: int):
    def stat(rows: np.ndarray) -> float | None:  # rows: [grasped, success]
        if len(rows) == 0:
            return None
        return nsg(float(rows[:, 1].mean()), float(rows[:, 0].mean()), n_choices)
    return stat


def paired_metrics(pairs: Sequence[tuple[Mapping[str, Any], Mapping[str, Any]]], suite_id: str,
                   ) -> dict[str, Any]:
    """Per metric of one suite's pairs: A's and B's value, B - A, the test's p and its counts."""
    def flags(side: int, key: str) -> list[bool]:
        return [bool(p[side].get(key, False)) for p in pairs]

    out: dict[str, Any] = {}
    for name, key in (("GSR", "grasped_any"), ("TSR", "success")):
        t = mcnemar(flags(1, key), flags(0, key))  # B first: b_only = pairs where only A succeeded
        out[name] = {"a": sum(flags(0, key)) / len(pairs), "b": sum(flags(1, key)) / len(pairs),
                     "test": "McNemar (exact)", "p": t.p, "b_only": t.a_only, "a_only": t.b_only}
    if any(p[0].get("instruction_mode") == COUNTERFACTUAL for p in pairs):
        fa, fb = [_followed(p[0]) for p in pairs], [_followed(p[1]) for p in pairs]
        t = mcnemar(fb, fa)
        out["Follow"] = {"a": sum(fa) / len(pairs), "b": sum(fb) / len(pairs), "test": "McNemar (exact)",
                         "p": t.p, "b_only": t.a_only, "a_only": t.b_only}
    rows = [np.array([[bool(p[s].get("grasped_any")), bool(p[s].get("success"))] for p in pairs], dtype=float)
            for s in (0, 1)]
    stat = _nsg_stat(num_choices(suite_id))
    scenes = [f"{p[0].get('instruction_mode')}:{p[0].get('seed')}" for p in pairs]  # variants move together
    d = paired_bootstrap(rows[1], rows[0], stat, clusters=scenes)
    out["nSG"] = {"a": stat(rows[0]), "b": stat(rows[1]), "test": "paired bootstrap", "p": d.p,
                  "low": d.low, "high": d.high}
    return out


def _p(p: float | None) -> str:
    if p is None:
        return NA
    return "<0.001" if p < 0.001 else f"{p:.3f}"


def compare_paired(a: Iterable[Mapping[str, Any]], b: Iterable[Mapping[str, Any]],
                   names: tuple[str, str] = ("A", "B")) -> str:
    """Markdown: per suite (and row of instruction mode / perturbation) and metric, A, B, B - A, the
    discordant counts and the paired p-value. :class:`NoPairs` (one line) without a common suite
    or episode."""
    a, b = list(a), list(b)
    suites_a, suites_b = {r["suite_id"] for r in a}, {r["suite_id"] for r in b}
    if not suites_a & suites_b:
        raise NoPairs(f"{names[0]} ({', '.join(suite_order(suites_a)) or 'no records'}) and {names[1]} "
                      f"({', '.join(suite_order(suites_b)) or 'no records'}) share no suite: nothing to compare")
    pairs, only_a, only_b = pair_records(a, b)
    if not pairs and {pair_key(r) for r in a} & {pair_key(r) for r in b}:
        raise NoPairs(f"{names[0]} and {names[1]} ran the same seeds but not the same episodes (their episode "
                      "digests differ: one ran on other question data): nothing to pair; `rsb report` on each "
                      "says whose episodes are the benchmark version's")
    if not pairs:
        raise NoPairs(f"{names[0]} and {names[1]} share no episode (suite, seed, instruction mode, "
                      "perturbation, variant, and the same question: episode digest): evaluate both on the same "
                      "seeds and question data")
    groups: dict[tuple, list] = defaultdict(list)
    for pa, pb in pairs:
        groups[(pa["suite_id"], pa.get("instruction_mode", "normal"), perturb_label(pa))].append((pa, pb))
    order = {s: i for i, s in enumerate(suite_order({k[0] for k in groups}))}
    rows = []
    for key in sorted(groups, key=lambda k: (order[k[0]], k[1], k[2])):
        suite, mode, perturb = key
        label = suite + ("" if mode == "normal" else f" ({mode})") + ("" if perturb == "none" else f" [{perturb}]")
        for metric, m in paired_metrics(groups[key], suite).items():
            counts = (f"{m['a_only']} / {m['b_only']}" if "a_only" in m
                      else NA if m["low"] is None else f"[{100 * m['low']:+.1f}, {100 * m['high']:+.1f}]")
            sig = "" if m["p"] is None or m["p"] >= ALPHA else " *"
            rows.append([label, metric, str(len(groups[key])), pct(m["a"]), pct(m["b"]), delta(m["b"], m["a"]),
                         counts, m["test"], _p(m["p"]) + sig])
    head = (f"A = {names[0]}, B = {names[1]}. Paired: {len(pairs)} episodes (same suite, seed, instruction "
            f"mode, perturbation, variant); unpaired: {only_a} of A, {only_b} of B (left out). "
            "A only / B only: the discordant pairs (McNemar); for nSG the paired bootstrap's 95 % interval "
            f"of B - A (a scene's variants resampled together). * : p < {ALPHA}.")
    table = markdown_table(["Suite", "Metric", "Pairs", "A %", "B %", "B - A", "A only / B only (nSG: 95 % CI)",
                            "Test", "p"], rows)
    return f"### Paired comparison\n\n{head}\n\n{table}\n"
