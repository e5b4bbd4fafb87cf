"""`rsb questions`, `rsb stats` and `rsb data download`: the semantic engine's commands (no simulator imports).

A command module, as ``demo.py`` and ``verify.py``: it takes suites the way every command
does (``env_ids.add_suites_argument``), which the engine itself (``semantic/``) never imports.
"""
from __future__ import annotations

import argparse
import json
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the semantic engine's sub-commands to the `rsb` dispatcher."""
    from rsb_maniskill.commands.vocab import add_old_spelling
    from rsb_maniskill.env_ids import add_suites_argument
    from rsb_maniskill.semantic.suites import COLOR_MAPS, INSTRUCTION_SETS, SPLITS

    p = subparsers.add_parser(
        "questions", help="print sample episodes of a suite",
        description="Print sample episode specifications (question, options, instruction, answer).")
    add_suites_argument(p, default=(), positional=True)
    p.add_argument("--split", default="train", help=f"{' | '.join(SPLITS)} (test = evaluation pool)")
    p.add_argument("-n", "--num-episodes", dest="num", metavar="N", type=int, default=5,
                   help="episodes per suite (default 5)")
    add_old_spelling(p, "--num", "--num-episodes")
    p.add_argument("--seed", type=int, default=0, help="first seed (episodes use seed, seed+1, ...)")
    p.add_argument("--instruction-set", dest="instructions", choices=INSTRUCTION_SETS, default=None,
                   help="template set (default: seen for train, unseen for test)")
    add_old_spelling(p, "--instructions", "--instruction-set")
    p.add_argument("--color-map", choices=COLOR_MAPS, default="fixed")
    p.add_argument("--data-dir", default=None,
                   help="directory with gsm8k/ and mmlu_pro/ (else $RSB_DATA_DIR, else hub cache)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.set_defaults(func=cmd_questions)

    s = subparsers.add_parser("stats", help="print question pool sizes per suite and split",
                              description="Prints, for each suite, how many questions its train and test pools "
                                          "hold on the question data at hand (GSM8K / MMLU-Pro for the suites "
                                          "that read data).")
    add_suites_argument(s, default=("all",))
    s.add_argument("--data-dir", default=None)
    s.set_defaults(func=cmd_stats)

    d = subparsers.add_parser("data", help="question data (GSM8K, MMLU-Pro)",
                              description="The question data of the suites that read data (GSM8K, MMLU-Pro): "
                                          "rsb data download fetches the pinned revisions once, for offline use.")
    dsub = d.add_subparsers(dest="data_command", metavar="ACTION")
    dl = dsub.add_parser("download", help="fetch and cache the pinned hub data for offline use",
                         description="Fetches GSM8K and MMLU-Pro at the revisions this benchmark version pins into "
                                     "the hub cache, so that later commands run offline (RSB_OFFLINE=1); with "
                                     "--out, also writes them in their original formats (usable as RSB_DATA_DIR).")
    dl.add_argument("--out", dest="export", default=None, metavar="DIR",
                    help="also write the data in its original formats under DIR (usable as RSB_DATA_DIR)")
    add_old_spelling(dl, "--export", "--out")
    dl.set_defaults(func=cmd_data_download)
    d.set_defaults(func=lambda args: (d.print_help(), 2)[1])


def _fail(command: str, err: Exception | str, status: int = 1) -> int:
    print(f"rsb {command}: error: {err}", file=sys.stderr)
    return status


def cmd_questions(args: argparse.Namespace) -> int:
    """Print ``-n`` episodes of each suite named."""
    from rsb_maniskill.objects.family import split_env_id
    from rsb_maniskill.semantic.errors import SemanticError
    from rsb_maniskill.semantic.sampler import EpisodeSampler

    if not args.suites:
        return _fail("questions", "name at least one SUITE (e.g. RSB-Math-4)", 2)
    if args.num < 1:
        return _fail("questions", f"-n must be >= 1, got {args.num}", 2)
    try:
        for env_id in args.suites:
            suite_id, targets = split_env_id(env_id)
            sampler = EpisodeSampler(suite_id, args.split, args.instructions, args.color_map, args.data_dir,
                                     targets=targets)
            for seed in range(args.seed, args.seed + args.num):
                spec = sampler.sample(seed)
                if args.json:
                    print(json.dumps(spec.to_dict()))
                    continue
                print(f"=== {env_id} {spec.split} seed={seed} question_id={spec.question_id} "
                      f"template={spec.template_id}")
                print(f"instruction: {spec.instruction}")
                for letter, opt, blk in zip(spec.letters, spec.options, spec.block_of_option):
                    mark = "*" if letter == spec.correct_letter else " "
                    print(f"  {mark} ({letter}) {opt}  -> {spec.block_names[blk]}")
                print(f"answer: {spec.correct_letter} (block {spec.target_block}: "
                      f"{spec.block_names[spec.target_block]})")
                print(f"rationale: {spec.rationale}")
    except SemanticError as err:  # the question data: missing or damaged
        return _fail("questions", err)
    except ValueError as err:  # the arguments (a split, a suite): a usage error, 2 as elsewhere
        return _fail("questions", err, 2)
    return 0


def cmd_stats(args: argparse.Namespace) -> int:
    """Pool sizes per suite and split (reads like the paper's Table 2, plus evaluation pools)."""
    from rsb_maniskill.objects.family import split_env_id
    from rsb_maniskill.semantic.data import data_source_label
    from rsb_maniskill.semantic.errors import DataNotFoundError, EmptyDataError
    from rsb_maniskill.semantic.pools import get_pool
    from rsb_maniskill.semantic.suites import parse_suite_id, suite_source

    print(f"data: {data_source_label(args.data_dir)}")
    print(f"{'suite':<18}{'source':<32}{'choices':>8}{'train':>9}{'test':>9}")
    notes: list[str] = []
    status = 0
    for sid in dict.fromkeys(split_env_id(eid)[0] for eid in args.suites):  # pools do not depend on targets
        suite, n = parse_suite_id(sid)
        source = suite_source(suite)
        sizes = []
        for split in ("train", "test"):
            if source.direct:
                sizes.append(f"{n:,}")
                continue
            try:
                pool = get_pool(suite, split, args.data_dir)
            except DataNotFoundError as err:
                sizes.append("empty" if isinstance(err, EmptyDataError) else "n/a")
                if not status:  # one message: every source it lacks is found the same ways
                    notes.append(str(err))
                status = 1
                continue
            sizes.append(f"{len(pool):,}")
            if suite == "General" and n == 4:
                mix = ", ".join(f"{k} {v:,}" for k, v in pool.source_counts.items())
                notes.append(f"General {split} mix: {mix}")
        print(f"{sid:<18}{source.summary:<32}{n:>8}{sizes[0]:>9}{sizes[1]:>9}")
    for note in notes:
        print(f"note: {note}")
    return status


def cmd_data_download(args: argparse.Namespace) -> int:
    """Fetch the pinned GSM8K / MMLU-Pro hub files into the huggingface_hub cache."""
    from rsb_maniskill.semantic.data import download_hub_data
    from rsb_maniskill.semantic.errors import SemanticError

    try:
        paths = download_hub_data(args.export)
    except SemanticError as err:
        return _fail("data download", err)
    for name, path in paths.items():
        print(f"{name}: {path}")
    if args.export:
        print(f"exported to {args.export} (set RSB_DATA_DIR={args.export})")
    return 0
