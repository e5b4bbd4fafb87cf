"""`rsb leaderboard`: several runs side by side, as the paper's main table; vla-eval's records of them.

    rsb leaderboard results/pi05 results/act lerobot_records/ vla_eval_out/ --out board
    rsb leaderboard results/pi05 --protocol blank --out board-blank
    rsb leaderboard results/pi05 --vla-eval pi05.vla-eval.json --weight-type finetuned --curated-by @me

The table is ``reporting/leaderboard.py``, its files ``reporting/leaderboard_files.py``, the
vla-eval records ``reporting/vla_eval_leaderboard.py``. Everything is read and checked before
anything is written; the runs given are only read.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

DEFAULT_TITLE = "RSB leaderboard"


def register(subparsers: argparse._SubParsersAction) -> None:
    from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE
    from rsb_maniskill.evaluation.records import INSTRUCTION_MODES
    from rsb_maniskill.reporting.vla_eval_leaderboard import WEIGHT_TYPES

    p = subparsers.add_parser(
        "leaderboard", help="several runs side by side: index.html, leaderboard.md and .csv; vla-eval records",
        description="Puts the runs given side by side as the paper's main table: models as rows, suites as columns "
                    "(GSR, TSR, nSG with Wilson 95 % intervals, Avg over the paper's six suites), the Random line "
                    "(TSR = 1/N), each model's checkpoint, protocol and benchmark version; writes DIR/index.html "
                    "(self-contained, sortable), DIR/leaderboard.md and DIR/leaderboard.csv. A RESULTS is a "
                    "results.json, an `rsb eval` --out directory, a `lerobot-eval` records_dir or a `vla-eval run` "
                    "output of RSBBenchmark (or its *_aggregate.json). One leaderboard holds one benchmark version "
                    "and one protocol (instruction mode, perturbation): runs mixing them are refused (pick one with "
                    f"--protocol / --perturb); rows on fewer than {EPISODES_PER_SUITE} episodes a suite, or not on "
                    "the protocol's seeds, are marked. --vla-eval FILE writes the runs as entries of vla-eval's "
                    "leaderboard.json (docs/evaluation.md).")
    p.add_argument("runs", nargs="+", metavar="RESULTS", help="results.json files or results directories")
    p.add_argument("--out", metavar="DIR", default=None, help="directory for index.html, leaderboard.md, .csv")
    p.add_argument("--protocol", metavar="MODE", default=None,
                   help=f"keep the rows of this instruction mode ({', '.join(INSTRUCTION_MODES)}; a run may hold "
                        "several)")
    p.add_argument("--perturb", metavar="AXES", default=None,
                   help="keep the rows of this perturbation: none, or as the rows name it (camera=2)")
    p.add_argument("--allow-other-episodes", action="store_true",
                   help="show rows whose episodes differ from the benchmark version's (other question data), "
                        "marked; refused by default")
    p.add_argument("--title", default=DEFAULT_TITLE, help=f"page and Markdown title (default: {DEFAULT_TITLE})")
    p.add_argument("--vla-eval", metavar="FILE", default=None, dest="vla_eval",
                   help="write the runs as vla-eval leaderboard entries (a leaderboard.json) to FILE")
    p.add_argument("--weight-type", choices=WEIGHT_TYPES, default=None,
                   help="with --vla-eval: shared (the same checkpoint across benchmarks) or finetuned (trained on "
                        "RSB data)")
    p.add_argument("--curated-by", default="human", help="with --vla-eval: your @handle (default: human)")
    p.set_defaults(func=run_leaderboard)


def _check_args(args: argparse.Namespace) -> None:
    from rsb_maniskill.reporting.leaderboard import LeaderboardError

    if not args.out and not args.vla_eval:
        raise LeaderboardError("nothing to write: give --out DIR (the leaderboard) and/or --vla-eval FILE")
    if args.vla_eval and not args.weight_type:
        raise LeaderboardError("--vla-eval needs --weight-type shared (one checkpoint across benchmarks) or "
                               "finetuned (trained on RSB data)")
    if args.out:
        out = Path(args.out).resolve()
        inputs = {Path(r).resolve() for r in args.runs} | {Path(r).resolve().parent for r in args.runs
                                                           if Path(r).is_file()}
        if out in inputs:
            raise LeaderboardError(f"--out {args.out} is a run given: write the leaderboard to another directory")
    if args.vla_eval:
        target = Path(args.vla_eval)
        if target.is_dir() or not target.name:
            raise LeaderboardError(f"--vla-eval {args.vla_eval!r} is a folder: give a file to write, e.g. "
                                   f"{target / 'leaderboard.json'}")


def run_leaderboard(args: argparse.Namespace) -> int:
    from rsb_maniskill.reporting.leaderboard import (
        LeaderboardError,
        build_leaderboard,
        load_run,
        one_each,
        select_rows,
    )
    from rsb_maniskill.reporting.leaderboard_files import render_leaderboard, write_leaderboard, write_text
    from rsb_maniskill.reporting.vla_eval_leaderboard import vla_eval_document

    try:  # read, check and render everything first: a refusal writes nothing
        _check_args(args)
        runs = [load_run(r) for r in args.runs]
        board = contents = export = None
        if args.out:
            board = build_leaderboard(runs, args.protocol, args.perturb, args.allow_other_episodes)
            contents = render_leaderboard(board, args.title)
        if args.vla_eval:
            doc = vla_eval_document(one_each(select_rows(runs, args.protocol, args.perturb))[0], args.weight_type,
                                    args.curated_by)
            export = json.dumps(doc, indent=2, ensure_ascii=False) + "\n"
    except LeaderboardError as err:
        print(f"rsb leaderboard: error: {err}", file=sys.stderr)
        return 2
    target = args.out
    try:
        if board is not None:
            paths = write_leaderboard(contents, args.out)
            models = len(board.entries) - 1
            print(f"leaderboard: {models} model(s) on {len(board.suites)} suite(s): {paths['html']}, "
                  f"{paths['markdown']}, {paths['csv']}")
            for e in board.entries:
                if e.also:
                    print(f"  {e.label}: the same run in {e.run.source} and {', '.join(e.also)}: listed once")
        if export is not None:
            target = args.vla_eval
            Path(args.vla_eval).parent.mkdir(parents=True, exist_ok=True)
            print(f"vla-eval records: {write_text(Path(args.vla_eval), export)}")
    except OSError as err:  # named by the user's path, never the temporary file written beside it
        print(f"rsb leaderboard: error: cannot write {target}: {err.strerror or err}", file=sys.stderr)
        return 1
    return 0
