"""RSB runs as records of vla-eval's leaderboard (``rsb leaderboard --vla-eval FILE``).

vla-eval (allenai/vla-evaluation-harness) keeps its leaderboard in ``leaderboard/data/
leaderboard.json``, whose schema (``leaderboard.schema.json``) takes one entry per model and
benchmark: ``model``, ``display_name``, ``benchmark``, ``weight_type``, ``curated_by``,
``date_added``, ``overall_score``, ``suite_scores``, ``task_scores``, ``notes``, nothing else.
Scores are percentages. A benchmark with several protocols lists them in ``score_key_suffixes``:
every score key ends in ``_<protocol>``, and ``overall_score`` is set only for an entry run with the
benchmark's standard protocol (null otherwise); scores are never aggregated across protocols.

How RSB maps onto it (docs/evaluation.md, "Leaderboard from several runs"):

- ``benchmark``: ``rsb_ms_v1_1`` (RSB-MS 1.1): each benchmark version is its own benchmark, as
  vla-eval keeps ``robotwin_v1`` and ``robotwin_v2`` apart, since their episodes differ;
- one entry per policy (and perturbation) of a run; its instruction modes are the protocols,
  ``normal``, ``blank`` and ``shuffled`` the key suffixes;
- ``suite_scores["math_4_normal"]``: TSR (%) on RSB-Math-4 with normal instructions;
  ``task_scores["math_4_gsr_normal"]``: GSR (%); nSG, which may be negative, goes into ``notes``;
- ``overall_score``: the paper's Avg TSR over its six suites, only for the standard protocol
  (normal instructions, no perturbation, each suite's protocol episodes); else null;
- ``notes``: the protocol, the checkpoint, the episodes per suite and the per-suite nSG.

:func:`benchmark_entry` is the registry entry (``benchmarks.json``) these records assume.
"""
from __future__ import annotations

import re
from collections import defaultdict
from datetime import datetime, timezone
from typing import Any, Mapping, Sequence

from rsb_maniskill.evaluation.metrics import PAPER_SUITES
from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE
from rsb_maniskill.evaluation.records import INSTRUCTION_MODES, row_label
from rsb_maniskill.reporting.cells import pct
from rsb_maniskill.reporting.leaderboard import LeaderboardError, Run, told_apart

BENCHMARK_KEY = "rsb_ms"  # + "_v1_1": the benchmark version
WEIGHT_TYPES = ("shared", "finetuned")  # vla-eval: the same checkpoint across benchmarks / trained on RSB data
# vla-eval's leaderboard.schema.json, results[].curated_by: an AI extraction, a human's @handle, or "human".
CURATED_BY = re.compile(r"^((opus|sonnet|haiku) \d+\.\d+|@[\w-]+|human)$")
STANDARD_MODE = "normal"  # the protocol overall_score ranks: normal instructions, no perturbation, full protocol
GSR_KEY = "gsr"  # task_scores key part: "<suite>_gsr_<mode>"


def benchmark_key(version: str) -> str:
    """``"1.1"`` -> ``"rsb_ms_v1_1"``."""
    from rsb_maniskill.version import UNVERSIONED

    if version == UNVERSIONED:
        raise LeaderboardError("unversioned records (written before benchmark versions existed) cannot be exported: "
                               "their episodes are not known; rerun with this rsb_maniskill")
    return f"{BENCHMARK_KEY}_v{version.replace('.', '_')}"


def suite_key(suite_id: str) -> str:
    """``"RSB-HardMath-10-Objects"`` -> ``"hardmath_10_objects"``."""
    return re.sub(r"[^a-z0-9]+", "_", suite_id.lower().removeprefix("rsb-")).strip("_")


def model_key(label: str) -> str:
    """A label as vla-eval's lower-case model key: ``"pi05 @ hf:me/pi05"`` -> ``"pi05_hf_me_pi05"``."""
    return re.sub(r"[^a-z0-9]+", "_", label.lower()).strip("_") or "policy"


def _score(x: float | None) -> float | None:
    return None if x is None else round(100.0 * x, 1)


def _notes(run: Run, rows: Mapping[str, Mapping[str, Any]], perturb: str, overall: float | None) -> str:
    """What a reader of the entry needs to know: the protocol, how the keys read, episodes, nSG."""
    from rsb_maniskill.version import benchmark_label

    doc, proto = run.doc, run.doc["protocol"]
    first = next(iter(rows.values()))
    parts = [f"{benchmark_label(doc['benchmark_version'])} (RoboSemanticBench on ManiSkill3, "
             f"rsb_maniskill {first.get('rsb_maniskill_version') or doc['rsb_maniskill_version']}). Protocol: split "
             f"{proto['split']}, {proto['instructions']} instruction templates, seeds {proto['first_seed']:,} + i, "
             f"{EPISODES_PER_SUITE} episodes per suite; "
             + ("no perturbation." if perturb == "none" else f"perturbation {perturb} (robustness, not ranked)."),
             "Key suffix = instruction mode (normal: the episode's instruction; blank: none; shuffled: another "
             "episode's), never averaged across modes. suite_scores: TSR %; task_scores <suite>_gsr_<mode>: GSR %."]
    for mode, row in rows.items():
        ns = sorted({s["n"] for s in row["suites"].values()})
        short = " (fewer than the protocol's)" if ns[0] < EPISODES_PER_SUITE else ""
        seeds = "" if all(s["protocol_seeds"] for s in row["suites"].values()) else ", not the protocol's seeds"
        nsg = ", ".join(f"{suite_key(s)} {pct(v['nsg']['value'])}" for s, v in row["suites"].items())
        parts.append(f"{mode}: {'/'.join(map(str, ns))} episodes per suite{short}{seeds}; nSG %: {nsg}.")
    ckpt = first.get("checkpoint")
    parts.append(f"Checkpoint: {ckpt}." if ckpt else "Checkpoint: not given (rsb eval --checkpoint).")
    if overall is None:
        parts.append("overall_score null: not the standard protocol (normal instructions, no perturbation, the six "
                     f"paper suites with {EPISODES_PER_SUITE} protocol episodes each).")
    else:
        parts.append("overall_score: Avg TSR over the six paper suites, normal instructions.")
    return " ".join(parts)


def _entry(name: str, run: Run, by_mode: Mapping[str, Mapping[str, Any]], perturb: str, weight_type: str,
           curated_by: str, today: str) -> dict[str, Any]:
    order = [*INSTRUCTION_MODES, *sorted(set(by_mode) - set(INSTRUCTION_MODES))]
    rows = {m: by_mode[m] for m in order if m in by_mode}
    standard = rows.get(STANDARD_MODE)
    overall = (_score(standard["average"]["tsr"])
               if standard is not None and perturb == "none" and standard["full_protocol"] else None)
    suite_scores, task_scores = {}, {}
    for mode, row in rows.items():
        for suite, s in row["suites"].items():
            suite_scores[f"{suite_key(suite)}_{mode}"] = _score(s["tsr"]["value"])
            task_scores[f"{suite_key(suite)}_{GSR_KEY}_{mode}"] = _score(s["gsr"]["value"])
    return {"model": model_key(name), "display_name": name, "name_in_paper": None,
            "benchmark": benchmark_key(run.doc["benchmark_version"]), "weight_type": weight_type,
            "overall_score": overall, "suite_scores": suite_scores, "task_scores": task_scores,
            "curated_by": curated_by, "date_added": today, "notes": _notes(run, rows, perturb, overall)}


def vla_eval_entries(pairs: Sequence[tuple[Run, Mapping[str, Any]]], weight_type: str, curated_by: str = "human",
                     today: str | None = None) -> list[dict[str, Any]]:
    """vla-eval leaderboard entries of ``pairs`` (run, results.json row): one per run, policy and
    perturbation, its instruction modes as key suffixes; sorted by (benchmark, model) as vla-eval
    keeps them."""
    if weight_type not in WEIGHT_TYPES:
        raise LeaderboardError(f"weight type {weight_type!r}: give one of {', '.join(WEIGHT_TYPES)}")
    if not CURATED_BY.match(curated_by):
        raise LeaderboardError(f"curated_by {curated_by!r}: vla-eval takes '@your-handle' (or 'human')")
    today = today or datetime.now(timezone.utc).strftime("%Y-%m-%d")
    # one entry per (run, policy, perturbation): its rows by instruction mode
    groups: dict[tuple[int, str, str], dict[str, Mapping[str, Any]]] = defaultdict(dict)
    runs = {id(run): run for run, _ in pairs}
    for run, row in pairs:
        groups[(id(run), row["policy"], row["perturb"])][row["instruction_mode"]] = row
    names = told_apart([(row_label(policy, "normal", perturb), runs[rid].source,
                         next(iter(rows.values())).get("checkpoint"))
                        for (rid, policy, perturb), rows in groups.items()])
    entries = [_entry(name, runs[rid], rows, perturb, weight_type, curated_by, today)
               for name, ((rid, _, perturb), rows) in zip(names, groups.items())]
    seen = defaultdict(list)
    for e in entries:
        seen[(e["model"], e["benchmark"])].append(e["display_name"])
    clash = next((labels for labels in seen.values() if len(labels) > 1), None)
    if clash:
        raise LeaderboardError(f"{' and '.join(clash)} would get the same vla-eval model key: rename a policy "
                               "(rsb eval --name) or export them apart")
    return sorted(entries, key=lambda e: (e["benchmark"], e["model"]))


def vla_eval_document(pairs: Sequence[tuple[Run, Mapping[str, Any]]], weight_type: str, curated_by: str = "human",
                      today: str | None = None) -> dict[str, Any]:
    """A ``leaderboard.json`` of vla-eval holding the entries of ``pairs`` (what ``--vla-eval`` writes)."""
    today = today or datetime.now(timezone.utc).strftime("%Y-%m-%d")
    return {"last_updated": today, "results": vla_eval_entries(pairs, weight_type, curated_by, today)}


def benchmark_entry(version: str) -> dict[str, dict[str, Any]]:
    """The ``benchmarks.json`` entry vla-eval's registry would need for these records: TSR in %,
    the instruction modes as key suffixes, overall_score the mean of the six paper suites' normal
    TSR (vla-eval's ``aggregation`` rule)."""
    from rsb_maniskill.env_ids import OBJECT_ENV_IDS, SUITE_IDS
    from rsb_maniskill.version import benchmark_label

    return {benchmark_key(version): {
        "display_name": benchmark_label(version),
        "metric": {"name": "success_rate", "unit": "%", "range": [0, 100], "higher_is_better": True},
        "suites": [f"{suite_key(s)}_{m}" for m in INSTRUCTION_MODES
                   for s in SUITE_IDS + OBJECT_ENV_IDS],
        "score_key_suffixes": list(INSTRUCTION_MODES),
        "aggregation": {"container": "suite_scores", "keys": [f"{suite_key(s)}_{STANDARD_MODE}" for s in PAPER_SUITES]},
        "detail_notes": "TSR per suite; key suffix = instruction mode (normal / blank / shuffled), never averaged "
                        "across modes. overall_score: Avg TSR of the six paper suites with normal instructions, "
                        f"{EPISODES_PER_SUITE} protocol episodes each. GSR in task_scores (<suite>_gsr_<mode>), nSG "
                        "in notes.",
    }}
