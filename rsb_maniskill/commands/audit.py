"""`rsb audit`: can a guesser that never solves the question beat chance? (no simulator imports)"""
from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

from rsb_maniskill.outdirs import writable_dir
from rsb_maniskill.semantic.counterfactual import MODE as COUNTERFACTUAL

MAX_AUDIT_EPISODES = 200_000  # every audited episode is held (~8 kB each, measured): more would not fit in memory
AUDIT_MODES = ("normal", COUNTERFACTUAL)  # the protocol episodes, their counterfactual variants


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "audit", help="shortcut audit: answer-blind guessers and learned probes against chance",
        description="Score answer-blind guessers (position, block, value rules, digits, length, word overlap with the "
                    "question, ...) and two learned probes trained on the train split to pick the answer from the "
                    "options alone (surface: gradient-boosted trees on each option's shape in its set; lexical: a "
                    "linear model on its word and character n-grams; for a failing suite the audit prints the n-grams "
                    "that give the answer away). Also counts option sets with two answers and questions or facts "
                    "shared by the splits. Exit status 1 when a suite fails (a guesser's 95 % interval wholly above "
                    "chance + 3 points, an ambiguous set, or split overlap). Question-aware readers (similarity to "
                    "the question, numbers reachable from the question's) are reference rows; a 10-choice suite fails "
                    "when a reader lifts it above its 4-choice twin, intervals apart (the twin rule).")
    from rsb_maniskill.commands.vocab import add_old_spelling
    from rsb_maniskill.env_ids import SUITES_HELP, add_suites_argument

    add_suites_argument(p, default=(), positional=True, help=SUITES_HELP + "; omit with --specs")
    p.add_argument("--split", default="test", choices=("train", "test"), help="split to audit (default test)")
    p.add_argument("-n", "--num-episodes", dest="episodes", metavar="N", type=int, default=3000,
                   help="episodes per suite: audited test episodes (default 3000)")
    add_old_spelling(p, "--episodes", "--num-episodes")
    p.add_argument("--train-episodes", type=int, default=None, help="train-split episodes for the probe (default: -n)")
    p.add_argument("--specs", nargs="+", default=None, metavar="FILE.jsonl",
                   help="audit your own episodes: EpisodeSpec JSON lines (e.g. `rsb questions --json`) with "
                        "split train (probe training) and test (audited), grouped by suite_id")
    p.add_argument("--data-dir", default=None,
                   help="directory with gsm8k/ and mmlu_pro/ (else $RSB_DATA_DIR, else hub cache)")
    p.add_argument("--perturb", nargs="+", default=[], metavar="AXIS=LEVEL",
                   help="audit the episodes worded under language robustness axes (lang_reference, lang_layout, "
                        "lang_distractor, lang_order; levels 0-3), e.g. --perturb lang_layout=3; 'all' audits "
                        "every language axis at every level 1-3, one after the other")
    p.add_argument("--instruction", nargs="+", default=None, choices=AUDIT_MODES, metavar="MODE",
                   help="what to audit of each suite: normal (the protocol episodes) and counterfactual (the "
                        "variants of the same scenes, rsb eval --instruction counterfactual; test split only); "
                        "default both")
    p.add_argument("--reader", action="append", default=[], metavar="MODULE:FACTORY",
                   help="also score your question-aware reader: factory() returns an object with "
                        "score(question, options) -> one score per option (or None), or such a callable; repeatable")
    p.add_argument("--no-readers", action="store_true",
                   help="skip the built-in readers (similarity, number reachability); --reader ones still run")
    p.add_argument("--out", default=None, metavar="DIR", help="write audit.json and audit.md there")
    p.add_argument("--json", action="store_true", help="print JSON instead of the Markdown tables")
    p.set_defaults(func=cmd_audit)


def _suite_ids(names: list[str]) -> list[tuple[str, str]]:
    """(suite id, targets) pairs named by ids and groups."""
    from rsb_maniskill.env_ids import resolve_env_ids
    from rsb_maniskill.objects.family import split_env_id

    return [split_env_id(eid) for eid in resolve_env_ids(names)]


def _read_specs(paths: list[str]) -> dict[str, dict[str, list]]:
    """suite_id -> split -> EpisodeSpecs, from JSON-lines files; errors name file and line."""
    from rsb_maniskill.semantic.spec import EpisodeSpec

    by: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for path in paths:
        p = Path(path)
        if not p.is_file():
            raise ValueError(f"--specs: {'not a regular file' if p.exists() else 'no such file'} {path}")
        with open(p, encoding="utf-8") as fh:
            for lineno, line in enumerate(fh, 1):
                if not line.strip():
                    continue
                try:
                    sp = EpisodeSpec.from_dict(json.loads(line))
                except (ValueError, TypeError) as err:
                    raise ValueError(f"{path}, line {lineno}: not an episode spec ({err})") from None
                by[sp.suite_id][sp.split].append(sp)
    return by


def _check_out(path: str) -> None:
    """``--out`` made and written to now, before the audit runs (minutes): ValueError otherwise."""
    out = Path(path)
    try:
        writable_dir(out)
    except OSError as err:
        raise ValueError(f"cannot write to --out {out}: {err.strerror or err}; choose another directory") from None


def _perturbs(items: list[str]) -> list[dict[str, int] | None]:
    """``--perturb``: one perturbation (its axes together), every language axis and level ("all"),
    or none. Only language axes change what the audit reads; a visual axis is a clear error."""
    from rsb_maniskill.perturb import LANGUAGE_AXES, LEVELS, PerturbError, parse_perturb

    if items == ["all"]:
        return [{a: lv} for a in LANGUAGE_AXES for lv in LEVELS if lv]
    perturb = parse_perturb(",".join(items))
    visual = [a for a in perturb if a not in LANGUAGE_AXES]
    if visual:
        raise PerturbError(f"--perturb {', '.join(visual)}: the audit reads text; give a language axis "
                           f"({', '.join(LANGUAGE_AXES)}) or 'all'")
    return [perturb or None]


def _modes(asked: list[str] | None, split: str) -> list[str]:
    """``--instruction``: what to audit; by default the protocol episodes and, on the test split,
    their counterfactual variants (evaluation scenes: there are none on the train split)."""
    if asked is None:
        return ["normal", COUNTERFACTUAL] if split == "test" else ["normal"]
    if COUNTERFACTUAL in asked and split != "test":
        raise ValueError("--instruction counterfactual audits the variants of the evaluation scenes: use --split test")
    return asked


def _readers(args: argparse.Namespace) -> list:
    """Built-in readers (unless --no-readers), then each --reader (ValueError with the fix)."""
    from rsb_maniskill.audit.readers import default_readers, load_reader

    return ([] if args.no_readers else default_readers()) + [load_reader(spec) for spec in args.reader]


def cmd_audit(args: argparse.Namespace) -> int:
    from rsb_maniskill.audit import report
    from rsb_maniskill.audit.counterfactual import audit_variants
    from rsb_maniskill.audit.run import LEXICAL_PROBE, audit_specs, audit_suite
    from rsb_maniskill.audit.twins import twin_failures
    from rsb_maniskill.semantic.errors import SemanticError

    if args.episodes < 1:
        print("rsb audit: error: -n must be >= 1", file=sys.stderr)
        return 2
    for flag, n in (("-n", args.episodes), ("--train-episodes", args.train_episodes or 0)):
        if n > MAX_AUDIT_EPISODES:  # an audit holds every episode it reads: refuse before memory runs out
            print(f"rsb audit: error: {flag} {n} is more than an audit can hold in memory (it keeps every episode "
                  f"it audits); use at most {MAX_AUDIT_EPISODES:,}", file=sys.stderr)
            return 2
    audits = []
    try:
        if args.out:
            _check_out(args.out)
        readers = _readers(args)
        if args.specs:
            specs = _read_specs(args.specs)
            if not specs:
                raise ValueError(f"--specs {args.specs} holds no episodes: give a file of EpisodeSpec JSON lines "
                                 "(e.g. `rsb questions RSB-Math-4 --json -n 100 > specs.jsonl`)")
            for suite_id, splits in sorted(specs.items()):
                if not splits.get(args.split):
                    raise ValueError(f"--specs: no {args.split}-split episodes of {suite_id}")
                audits.append(audit_specs(suite_id, splits.get("train", []), splits[args.split], split=args.split,
                                          readers=readers))
        else:
            suites = _suite_ids(args.suites)
            if not suites:
                print("rsb audit: error: name at least one SUITE (or 'paper', 'all'), or pass --specs", file=sys.stderr)
                return 2
            modes = _modes(args.instruction, args.split)
            for sid, targets in suites:
                for perturb in _perturbs(args.perturb):
                    print(f"rsb audit: {sid} ({targets}{', ' + str(perturb) if perturb else ''}) ...",
                          file=sys.stderr, flush=True)
                    if "normal" in modes:
                        audits.append(audit_suite(sid, args.split, args.episodes, n_train=args.train_episodes,
                                                  data_dir=args.data_dir, targets=targets, perturb=perturb,
                                                  readers=readers))
                    if COUNTERFACTUAL in modes:
                        audits.append(audit_variants(sid, args.episodes, n_train=args.train_episodes,
                                                     data_dir=args.data_dir, targets=targets, perturb=perturb,
                                                     readers=readers))
    except (ValueError, SemanticError) as err:
        print(f"rsb audit: error: {err}", file=sys.stderr)
        return 2
    if args.out:
        js, md = report.write(audits, args.out)
        print(f"rsb audit: wrote {js} and {md}", file=sys.stderr)
    print(json.dumps(report.to_dicts(audits), indent=1) if args.json else report.markdown(audits))
    twins = twin_failures(audits)
    for t in twins:
        print(f"rsb audit: twin rule fails: {t}", file=sys.stderr)
    for a in audits:
        if any(g.name == LEXICAL_PROBE for g in a.flagged):  # why: the words that give the answer away
            for line in report.token_lines(a):
                print(f"rsb audit: {a.suite_id}: {line}", file=sys.stderr)
    return 0 if all(a.passed for a in audits) and not twins else 1
