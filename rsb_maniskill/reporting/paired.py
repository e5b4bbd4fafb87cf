"""``rsb report --compare A B`` over episodes: the two runs' records paired episode by episode.

Two runs of the same benchmark version on the same suite and seed (and instruction mode,
perturbation and counterfactual variant) saw the same episode, so their outcomes are *paired*.
Episodes of one seed share a scene (a counterfactual scene's K variants): they are not independent
pairs, so every test here counts scenes. GSR and TSR: the exact test of flipping whole scenes between
the runs (``stats.scene_permutation``; McNemar's exact test when every scene is one episode, as in a
normal run); for counterfactual rows the section's headline follow (over the changed variants with a
grasp) and switch, by the same scene flips (every flip enumerated up to 16 scenes, else drawn until
the p-value's Monte Carlo interval leaves alpha); nSG by a paired bootstrap over scenes, drawn until
the same holds. That is far more sensitive than asking whether two intervals overlap, and honest:
only episodes both runs played are compared; how many were left out is said. Two runs that share no
suite, or no episode, are refused (:class:`NoPairs`).
"""
from __future__ import annotations

from collections import defaultdict
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from rsb_maniskill.evaluation.metrics import num_choices, suite_order
from rsb_maniskill.evaluation.records import COUNTERFACTUAL, DIGEST_FIELD, KEY_DEFAULTS, dedupe, perturb_label
from rsb_maniskill.evaluation.stats import ALPHA, paired_bootstrap, scene_permutation
from rsb_maniskill.reporting.cells import NA, delta, markdown_table, pct

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


def _nsg_stat(n_choices: int):
    def stat(means: np.ndarray) -> np.ndarray:  # means (..., 2): [grasped, success]
        g, s = means[..., 0], means[..., 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            out = (s / g - 1 / n_choices) / (1 - 1 / n_choices)
        return np.where(g > 0, out, np.nan)
    return stat


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


def _tested(name: str, a: float | None, b: float | None, t: Any, **extra: Any) -> dict[str, Any]:
    test = ("McNemar (exact)" if t.scenes and extra.get("singletons") else
            "scene permutation (exact)" if t.exact else "scene permutation (Monte Carlo)")
    extra.pop("singletons", None)
    return {"a": a, "b": b, "test": test, "p": t.p, "decided": t.decided, "p_low": t.p_low, "p_high": t.p_high,
            "scenes": t.scenes, **extra}


def paired_metrics(pairs: Sequence[tuple[Mapping[str, Any], Mapping[str, Any]]], suite_id: str,
                   ) -> dict[str, Any]:
    """Per metric of one suite's pairs: A's and B's value, the test's p (counting scenes) and, for
    GSR / TSR, the discordant episode counts."""
    scenes = _scenes(pairs)
    singletons = all(len(v) == 1 for v in scenes.values())
    out: dict[str, Any] = {}
    for name, key in (("GSR", "grasped_any"), ("TSR", "success")):
        per = [(sum(bool(pa.get(key)) for pa, _ in v), sum(bool(pb.get(key)) for _, pb in v), len(v))
               for v in scenes.values()]
        na, nb, den = (np.array(x, dtype=float) for x in zip(*per))
        t = scene_permutation(na, den, nb, den)
        a_only = sum(bool(pa.get(key)) and not bool(pb.get(key)) for pa, pb in pairs)
        b_only = sum(bool(pb.get(key)) and not bool(pa.get(key)) for pa, pb in pairs)
        out[name] = _tested(name, na.sum() / len(pairs), nb.sum() / len(pairs), t, a_only=a_only, b_only=b_only,
                            singletons=singletons)
    if any(p[0].get("instruction_mode") == COUNTERFACTUAL for p in pairs):
        n = num_choices(suite_id)
        counts = [(_scene_counts([pa for pa, _ in v], n), _scene_counts([pb for _, pb in v], n))
                  for v in scenes.values()]
        for name, hits, of in (("Follow", "changed_followed", "changed_grasped"), ("Switch", "switched", "pairs")):
            ca = [(c[0].get(hits, 0), c[0].get(of, 0)) for c in counts]
            cb = [(c[1].get(hits, 0), c[1].get(of, 0)) for c in counts]
            (na, da), (nb, db) = (np.array(x, dtype=float).reshape(-1, 2).T for x in (ca, cb))
            t = scene_permutation(na, da, nb, db)
            out[name] = _tested(name, na.sum() / da.sum() if da.sum() else None,
                                nb.sum() / db.sum() if db.sum() else None, t, of=(int(da.sum()), int(db.sum())))
    rows = [np.array([[bool(p[s].get("grasped_any")), bool(p[s].get("success"))] for p in pairs], dtype=float)
            for s in (0, 1)]
    stat = _nsg_stat(num_choices(suite_id))
    clusters = [str(p[0].get("seed")) for p in pairs]  # a scene's variants move together
    d = paired_bootstrap(rows[1], rows[0], stat, clusters=clusters)

    def value(r: np.ndarray) -> float | None:
        v = float(stat(r.mean(0)))
        return None if np.isnan(v) else v

    out["nSG"] = {"a": value(rows[0]), "b": value(rows[1]), "test": "paired bootstrap", "p": d.p,
                  "decided": d.decided, "p_low": d.p_low, "p_high": d.p_high, "low": d.low, "high": d.high,
                  "scenes": len(set(clusters)), "resamples": d.resamples}
    return out


def _p(p: float | None) -> str:
    if p is None:
        return NA
    return "<0.001" if p < 0.001 else f"{p:.3f}"


def p_cell(m: Mapping[str, Any]) -> str:
    """The p-value, its Monte Carlo interval where it has one, and the mark: ``*`` significant, ``?``
    undecided (the interval still holds alpha after the most draws), nothing otherwise."""
    text = _p(m["p"])
    if m.get("p_low") is not None and m["p"] is not None and m["p"] >= 0.001:
        text += f" [{m['p_low']:.3f}, {m['p_high']:.3f}]"
    if m["p"] is None:
        return text
    if not m.get("decided", True):
        return text + " " + UNDECIDED
    return text + (" *" if m["p"] < ALPHA else "")


def _counts(m: Mapping[str, Any]) -> str:
    if "a_only" in m:
        return f"{m['a_only']} / {m['b_only']}"
    if "of" in m:
        return f"of {m['of'][0]} / {m['of'][1]}"
    return NA if m.get("low") is None else f"[{100 * m['low']:+.1f}, {100 * m['high']:+.1f}]"


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
            rows.append([label, metric, f"{len(groups[key])} / {m['scenes']}", pct(m["a"]), pct(m["b"]),
                         delta(m["b"], m["a"]), _counts(m), m["test"], p_cell(m)])
    head = (f"A = {names[0]}, B = {names[1]}. Paired: {len(pairs)} episodes (same suite, seed, instruction "
            f"mode, perturbation, variant); unpaired: {only_a} of A, {only_b} of B (left out). Every test counts "
            "scenes (the episodes of one seed: a counterfactual scene's variants) and flips a whole scene between "
            "the runs; with one episode a scene it is McNemar's exact test. A only / B only: the discordant "
            "episodes; Follow / Switch: their denominators in A / B (changed variants with a grasp; pairs of "
            "variants with different targets); nSG: the paired bootstrap's 95 % interval of B - A over scenes. "
            "[low, high] after a Monte Carlo p: its 99.9 % interval (draws are added until it leaves alpha). "
            f"* : p < {ALPHA}; {UNDECIDED} : undecided at the most draws.")
    table = markdown_table(["Suite", "Metric", "Pairs / scenes", "A %", "B %", "B - A",
                            "A only / B only (nSG: 95 % CI)", "Test", "p"], rows)
    return f"### Paired comparison\n\n{head}\n\n{table}\n"
