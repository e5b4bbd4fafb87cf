"""``rsb report --compare A B`` over episodes: the two runs' records paired episode by episode.

Two runs of the same benchmark version on the same suite and seed (and instruction mode,
perturbation and counterfactual variant) saw the same episode, so their outcomes are *paired*.
Episodes of one seed share a scene (a counterfactual scene's K variants): they are not independent
pairs, so every test here counts scenes, by flipping whole scenes between the runs
(``stats.scene_permutation``). GSR and TSR: exact (McNemar's exact test when every scene is one
episode, as in a normal run). nSG, through its share of grasps on the target (successes over
grasps: nSG is that share rescaled), and for counterfactual rows the section's headline follow (over
the changed variants with a grasp) and switch: the same scene flips of a ratio, every flip enumerated
up to 16 scenes that differ, else drawn until the p-value's Monte Carlo interval holds no threshold
the correction may compare it with. The table is one family: Holm's correction over all its tests
(every suite, row and metric), so two identical policies get a mark anywhere on it at most 5 % of
the time. Only episodes both runs played are compared; how many were left out is said. Two runs that
share no suite, or no episode, are refused (:class:`NoPairs`).
"""
from __future__ import annotations

from collections import defaultdict
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from rsb_maniskill.evaluation.metrics import num_choices, suite_order
from rsb_maniskill.evaluation.records import COUNTERFACTUAL, DIGEST_FIELD, KEY_DEFAULTS, dedupe, perturb_label
from rsb_maniskill.evaluation.stats import ALPHA, holm_marks, scene_permutation
from rsb_maniskill.reporting.cells import NA, delta, markdown_table, p_value, pct

# What identifies an episode across two runs (the record key without the policy).
PAIR_KEY: tuple[str, ...] = ("suite_id", "instruction_mode", "perturb", "seed", "variant")
UNDECIDED = "?"  # a Monte Carlo p-value whose 99.9 % interval still holds alpha at the most draws


class NoPairs(ValueError):
    """The two runs share no suite or no episode: nothing can be compared."""


def pair_key(record: Mapping[str, Any]) -> tuple:
    return tuple(record.get(k, KEY_DEFAULTS.get(k)) for k in PAIR_KEY)


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


def _scenes(pairs: Sequence[tuple[Mapping[str, Any], Mapping[str, Any]]]) -> dict[Any, list]:
    """The pairs of each scene (a seed: a counterfactual scene's variants share it)."""
    out: dict[Any, list] = defaultdict(list)
    for p in pairs:
        out[p[0].get("seed")].append(p)
    return out


def _scene_counts(side: Sequence[Mapping[str, Any]], n: int) -> Mapping[str, float]:
    """A scene's follow and switch counts, as the counterfactual section defines them."""
    from rsb_maniskill.reporting.sections.counterfactual import scene_counts

    return scene_counts(sorted(side, key=lambda r: int(r.get("variant", 0))), n).per_scene[0]


def _tested(t: Any, a: float | None, b: float | None, scale: float = 1.0, **extra: Any) -> dict[str, Any]:
    """One row's test: the two values, the scene test's p (its Monte Carlo interval where drawn)."""
    singletons = extra.pop("singletons", False)
    test = ("McNemar (exact)" if t.scenes and singletons and t.exact else
            "scene permutation (exact)" if t.exact else "scene permutation (Monte Carlo)")
    return {"a": a, "b": b, "test": test, "p": t.p, "p_low": t.p_low, "p_high": t.p_high, "scenes": t.scenes,
            "draws": t.draws, **extra}


def family_size(pairs: Sequence[tuple[Mapping[str, Any], Mapping[str, Any]]]) -> int:
    """The tests :func:`paired_metrics` makes of ``pairs``: GSR, TSR, nSG, and follow and switch for a
    counterfactual row."""
    return 5 if any(p[0].get("instruction_mode") == COUNTERFACTUAL for p in pairs) else 3


def paired_metrics(pairs: Sequence[tuple[Mapping[str, Any], Mapping[str, Any]]], suite_id: str,
                   levels: Sequence[float] = (ALPHA,)) -> dict[str, Any]:
    """Per metric of one suite's pairs: A's and B's value, the scene test's p (a drawn p's Monte
    Carlo interval holds none of ``levels``: the thresholds Holm's correction may compare it with)
    and, for GSR / TSR, the discordant episode counts; for the ratios, their denominators."""
    scenes = _scenes(pairs)
    singletons = all(len(v) == 1 for v in scenes.values())
    out: dict[str, Any] = {}
    for name, key in (("GSR", "grasped_any"), ("TSR", "success")):
        per = [(sum(bool(pa.get(key)) for pa, _ in v), sum(bool(pb.get(key)) for _, pb in v), len(v))
               for v in scenes.values()]
        na, nb, den = (np.array(x, dtype=float) for x in zip(*per))
        t = scene_permutation(na, den, nb, den, levels=levels)
        a_only = sum(bool(pa.get(key)) and not bool(pb.get(key)) for pa, pb in pairs)
        b_only = sum(bool(pb.get(key)) and not bool(pa.get(key)) for pa, pb in pairs)
        out[name] = _tested(t, na.sum() / len(pairs), nb.sum() / len(pairs), a_only=a_only, b_only=b_only,
                            singletons=singletons)
    if any(p[0].get("instruction_mode") == COUNTERFACTUAL for p in pairs):
        n = num_choices(suite_id)
        counts = [(_scene_counts([pa for pa, _ in v], n), _scene_counts([pb for _, pb in v], n))
                  for v in scenes.values()]
        for name, hits, of in (("Follow", "changed_followed", "changed_grasped"), ("Switch", "switched", "pairs")):
            ca = [(c[0].get(hits, 0), c[0].get(of, 0)) for c in counts]
            cb = [(c[1].get(hits, 0), c[1].get(of, 0)) for c in counts]
            (na, da), (nb, db) = (np.array(x, dtype=float).reshape(-1, 2).T for x in (ca, cb))
            t = scene_permutation(na, da, nb, db, levels=levels)
            out[name] = _tested(t, na.sum() / da.sum() if da.sum() else None,
                                nb.sum() / db.sum() if db.sum() else None, of=(int(da.sum()), int(db.sum())))
    # nSG = (successes / grasps - 1/N) / (1 - 1/N): tested as that share of grasps on the target
    chance = 1 / num_choices(suite_id)
    per = [[sum(bool(p[s].get(k)) for p in v) for s in (0, 1) for k in ("success", "grasped_any")]
           for v in scenes.values()]
    sa, ga, sb, gb = (np.array(x, dtype=float) for x in zip(*per))
    t = scene_permutation(sa, ga, sb, gb, levels=levels)

    def nsg(s: np.ndarray, g: np.ndarray) -> float | None:
        return None if g.sum() == 0 else float((s.sum() / g.sum() - chance) / (1 - chance))

    out["nSG"] = _tested(t, nsg(sa, ga), nsg(sb, gb), of=(int(ga.sum()), int(gb.sum())))
    return out


def p_cell(m: Mapping[str, Any]) -> str:
    """The p-value, with its Monte Carlo interval where it was drawn."""
    text = p_value(m["p"])
    if m.get("p_low") is not None and m["p"] is not None and m["p"] >= 0.001:
        text += f" [{p_value(m['p_low'])}, {p_value(m['p_high'])}]"
    return text


def mark_cell(m: Mapping[str, Any]) -> str:
    """The Holm-adjusted p and the mark: ``*`` significant over the family, ``?`` undecided (a drawn
    p's interval straddles its Holm threshold at the most draws), nothing otherwise."""
    mark = m.get("mark")
    if m["p"] is None or mark is None:
        return NA
    text = p_value(mark.p_holm)
    if not mark.decided:
        return text + " " + UNDECIDED
    return text + (" *" if mark.significant else "")


def _counts(m: Mapping[str, Any]) -> str:
    if "a_only" in m:
        return f"{m['a_only']} / {m['b_only']}"
    return f"of {m['of'][0]} / {m['of'][1]}"


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
    keys = sorted(groups, key=lambda k: (order[k[0]], k[1], k[2]))
    m = sum(family_size(groups[k]) for k in keys)
    levels = tuple(ALPHA / i for i in range(1, m + 1))  # the thresholds Holm's correction compares p with
    tested = [(k, metric, t) for k in keys for metric, t in paired_metrics(groups[k], k[0], levels).items()]
    for (_, _, t), mark in zip(tested, holm_marks([(t["p"], t["p_low"], t["p_high"]) for _, _, t in tested])):
        t["mark"] = mark
    rows = []
    for (suite, mode, perturb), metric, t in tested:
        label = suite + ("" if mode == "normal" else f" ({mode})") + ("" if perturb == "none" else f" [{perturb}]")
        rows.append([label, metric, f"{len(groups[(suite, mode, perturb)])} / {t['scenes']}", pct(t["a"]),
                     pct(t["b"]), delta(t["b"], t["a"]), _counts(t), t["test"], p_cell(t), mark_cell(t)])
    head = (f"A = {names[0]}, B = {names[1]}. Paired: {len(pairs)} episodes (same suite, seed, instruction "
            f"mode, perturbation, variant); unpaired: {only_a} of A, {only_b} of B (left out). Every test counts "
            "scenes (the episodes of one seed: a counterfactual scene's variants) and flips a whole scene between "
            "the runs; with one episode a scene it is McNemar's exact test. A only / B only: the discordant "
            "episodes; Follow / Switch / nSG: their denominators in A / B (changed variants with a grasp; pairs of "
            "variants with different targets; grasps: nSG is tested as the share of grasps on the target). "
            "[low, high] after a Monte Carlo p: its 99.9 % interval. "
            f"Family: the {len(tested)} tests of this table, Holm's correction (family-wise error at most "
            f"{ALPHA} over the table); Holm p: the adjusted p; * : Holm p < {ALPHA}; {UNDECIDED} : undecided at "
            "the most draws.")
    table = markdown_table(["Suite", "Metric", "Pairs / scenes", "A %", "B %", "B - A", "A only / B only",
                            "Test", "p", "Holm p"], rows)
    return f"### Paired comparison\n\n{head}\n\n{table}\n"
