"""`rsb generate`, `rsb merge` and `rsb replay`: demonstration datasets (see docs/demos.md).

Heavy imports (simulator, planner) happen inside the commands so ``rsb --help`` stays quick.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
from typing import Any

from rsb_maniskill.commands.eval_args import ObsModeAction
from rsb_maniskill.commands.vocab import add_old_spelling
from rsb_maniskill.env_ids import add_suites_argument
from rsb_maniskill.motionplan.config import DEFAULT_EXPERT
from rsb_maniskill.parallel.plan import add_worker_args, executor_from_args, obs_mode_renders, resolve_workers

# The replay sub-parser must hand every argument, options included, to ManiSkill's own parser:
# a prefix character no option uses makes argparse treat them all as positionals.
_NO_PREFIX = "\x01"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "generate", help="scripted-expert demonstrations (ManiSkill .h5 + .json)",
        description="Runs the motion-planning expert and keeps only successful episodes, suite after suite. "
                    "Output: <out>/<ENV_ID>/motionplanning/<split>.<obs_mode>.pd_joint_pos.physx_cpu.h5 and .json.")
    add_suites_argument(p, default=(), positional=True)
    p.add_argument("--split", default="train", help="question pool: train (default) or test")
    p.add_argument("-n", "--num-episodes", dest="num", metavar="N", type=int, default=None,
                   help="episodes per suite: successful demos kept (failed attempts are not counted; the total "
                        "over all shards); with --questions: only the first N questions")
    add_old_spelling(p, "--num", "--num-episodes")
    p.add_argument("--questions", default=None, metavar="all|START:STOP",
                   help="one demo per question of the pool (seeds q, q+P, q+2P, ... for question q)")
    p.add_argument("--seed-start", type=int, default=0, help="first seed (seed mode; default 0)")
    p.add_argument("--out", default="demos", help="output root directory (default: demos)")
    p.add_argument("--traj-name", default=None, help="file name stem (default: the split)")
    p.add_argument("-o", "--obs-mode", default="state", action=ObsModeAction,  # refused as parsed, as by rsb eval
                   help="observations to record (default: state)")
    p.add_argument("--save-video", action="store_true", help="also write one mp4 per kept demo")
    p.add_argument("--shard", default="0/1", metavar="I/N",
                   help="make shard I of N (disjoint seeds/questions); merge shards with `rsb merge`")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--max-attempts", type=int, default=20,
                   help="seeds tried per question (--questions), or failures in a row before a "
                        "worker gives up (seed mode); default 20")
    p.add_argument("--instruction-set", dest="instructions", default=None,
                   help="env kwarg: seen / unseen instruction templates")
    add_old_spelling(p, "--instructions", "--instruction-set")
    p.add_argument("--color-map", default=None, help="env kwarg: fixed / shuffle (4-choice colours)")
    p.add_argument("--data-dir", default=None, help="env kwarg: GSM8K / MMLU-Pro directory")
    p.add_argument("--expert", default=DEFAULT_EXPERT, help=argparse.SUPPRESS)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("-v", "--verbose", action="store_true", help="log each failed seed with its reason")
    add_worker_args(p)  # --num-procs auto|N, --executor, --address
    p.set_defaults(func=run_generate)

    m = subparsers.add_parser("merge", help="merge trajectory files (parts, shards) into one",
                              description="Concatenates .h5/.json trajectory pairs of the same env and "
                                          "env kwargs, renumbering traj_<i>; writes atomically.")
    m.add_argument("inputs", nargs="+", help="input .h5 files (their .json next to them)")
    m.add_argument("--out", required=True, help="output .h5 path")
    m.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    m.add_argument("--sort-by-seed", action="store_true", help="order episodes by episode seed")
    m.set_defaults(func=run_merge)

    r = subparsers.add_parser(
        "replay", prefix_chars=_NO_PREFIX, add_help=False,
        help="ManiSkill's replay_trajectory with the RSB envs registered (same arguments)",
        description="rsb replay --traj-path X.h5 [-o rgb] [-c pd_joint_delta_pos] [--save-traj] ...")
    r.add_argument("replay_args", nargs="*")
    r.set_defaults(func=run_replay)


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def run_generate(args: argparse.Namespace) -> int:
    import signal

    try:
        executor = executor_from_args(args.executor, args.address)
    except (ValueError, ImportError) as err:
        print(f"rsb generate: error: {err}", file=sys.stderr)
        return 2
    # SIGTERM before the workers' own guard is up (start-up) stops the run like Ctrl-C, not silently
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        with executor or contextlib.nullcontext():
            return _generate(args, executor)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _generate(args: argparse.Namespace, executor: Any) -> int:
    from rsb_maniskill.motionplan.dataset import DatasetError
    from rsb_maniskill.motionplan.generate import GenerateConfig, GenerateError, describe, generate
    from rsb_maniskill.motionplan.shards import parse_shard

    if not args.suites:
        print("rsb generate: error: name at least one SUITE (e.g. RSB-Math-4)", file=sys.stderr)
        return 2
    if args.num is not None and args.num < 1:
        print(f"rsb generate: error: -n must be >= 1, got {args.num}", file=sys.stderr)
        return 2
    extra = {k: v for k, v in (("instructions", args.instructions), ("color_map", args.color_map),
                               ("data_dir", args.data_dir)) if v is not None}
    executor, num_procs = resolve_workers(args.num_procs, executor, obs_mode_renders(args.obs_mode) or args.save_video,
                                          episodes=_demos_a_shard(args))
    status = 0
    for env_id in args.suites:
        try:
            cfg = GenerateConfig(
                env_id=env_id, out=args.out, split=args.split, num=args.num, questions=args.questions,
                seed_start=args.seed_start, obs_mode=args.obs_mode, save_video=args.save_video,
                num_procs=num_procs, shard=parse_shard(args.shard), overwrite=args.overwrite,
                max_attempts=args.max_attempts, traj_name=args.traj_name, expert=args.expert,
                env_kwargs=extra, progress=not args.quiet, verbose=args.verbose)
            summary = generate(cfg, executor)
        except (GenerateError, DatasetError) as err:
            print(f"rsb generate: error: {env_id}: {err}" if len(args.suites) > 1 else f"rsb generate: error: {err}",
                  file=sys.stderr)
            return 2
        print(describe(summary, errors=False))
        for err in summary.errors:  # one line each, as every error; a worker's traceback with --debug
            _print_error(f"{env_id}: {err}" if len(args.suites) > 1 else err)
        status = status or summary.exit_code
        if summary.interrupted:
            break
    return status


def _print_error(text: str) -> None:
    from rsb_maniskill.debug import debug_enabled

    first, _, detail = text.partition("\n")
    if detail.strip() and debug_enabled():
        print(detail.rstrip(), file=sys.stderr)
    print(f"rsb generate: error: {first}", file=sys.stderr)


def _demos_a_shard(args: argparse.Namespace) -> int | None:
    """The demos one shard makes, where the arguments say (auto's worker count); None: unknown
    (``--questions all``: the pool's size), or the arguments are bad (checked later)."""
    n = args.num
    try:
        if args.questions is not None and args.questions != "all":
            start, stop = (int(x) for x in args.questions.split(":"))
            n = stop - start if n is None else min(n, stop - start)
        shards = int(args.shard.split("/")[1])
    except (ValueError, IndexError):
        return None
    return None if n is None or shards < 1 else -(-n // shards)


def run_merge(args: argparse.Namespace) -> int:
    from rsb_maniskill.motionplan.dataset import DatasetError, check_pair, merge_pairs
    from rsb_maniskill.motionplan.summary import combine_rsb_blocks

    try:
        blocks = []
        for path in args.inputs:
            data = check_pair(path)
            blocks.append(dict(file=str(path), episodes=len(data["episodes"]), rsb=data.get("rsb")))
        header = {"rsb": combine_rsb_blocks([b["rsb"] for b in blocks]), "rsb_merged_from": blocks}
        key = (lambda ep: ep["episode_seed"]) if args.sort_by_seed else None
        n = merge_pairs(args.inputs, args.out, overwrite=args.overwrite, sort_key=key, header=header)
    except (DatasetError, ValueError) as err:
        print(f"rsb merge: error: {err}", file=sys.stderr)
        return 2
    print(f"wrote {n} episodes to {args.out}")
    return 0


def run_replay(args: argparse.Namespace) -> int:
    from rsb_maniskill.motionplan.replay import main

    return main(args.replay_args)
