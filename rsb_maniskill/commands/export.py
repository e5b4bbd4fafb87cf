"""`rsb export lerobot` and `rsb dataset build` (no simulator import until they run)."""
from __future__ import annotations

import argparse
import sys

from rsb_maniskill.env_ids import CONTROL_FREQ
from rsb_maniskill.export.build import BuildConfig
from rsb_maniskill.export.naming import DEFAULT_NAMING, NAMINGS, camera_key
from rsb_maniskill.parallel.plan import add_worker_args
from rsb_maniskill.robot import CAMERAS


def _keys(naming: str) -> str:
    return ", ".join(camera_key(c, naming) for c in CAMERAS)


CAMERAS_HELP = (f"comma-separated: {', '.join(CAMERAS)} (keys {_keys(DEFAULT_NAMING)}; "
                + "; ".join(f"with --naming {n} {_keys(n)}" for n in NAMINGS if n != DEFAULT_NAMING) + ")")
BUILD = BuildConfig()  # the defaults of `rsb dataset build`


def _add_format_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fps", type=int, default=None,
                   help=f"frame rate; must divide the {CONTROL_FREQ} Hz control rate (default {CONTROL_FREQ})")
    p.add_argument("--cameras", default=",".join(CAMERAS), help=CAMERAS_HELP)
    p.add_argument("--naming", choices=NAMINGS, default=DEFAULT_NAMING,
                   help="feature keys: rsb (LeRobot's Aloha names, openpi's) or robotwin (LeRobot's RoboTwin env)")
    add_worker_args(p)  # --num-procs auto|N, --executor, --address


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("export", help="export demonstrations to another format (LeRobot)",
                              description="Writes demonstrations (rsb generate output) in another format: rsb "
                                          "export lerobot DEMOS.h5 ... --out DIR for a LeRobot v3.0 dataset.")
    sub = p.add_subparsers(dest="export_format", metavar="FORMAT")
    lr = sub.add_parser("lerobot", help="a LeRobot dataset (format v3.0)",
                        description="Write demos (rsb generate output, merged or converted) as one LeRobot v3.0 "
                                    "dataset: Aloha 14-number state and action, one video per camera, each "
                                    "episode's instruction as its task, RSB metadata in the episodes table. State "
                                    "demos are re-rendered from their recorded env states, in parallel with "
                                    "--num-procs; a rerun after an interruption keeps the finished shards.")
    lr.add_argument("demos", nargs="+", metavar="DEMOS.h5", help="trajectory files (X.h5 with X.json beside it)")
    lr.add_argument("--out", required=True, metavar="DIR", help="dataset directory (created; must not hold files)")
    _add_format_args(lr)
    lr.add_argument("--overwrite", action="store_true", help="replace an existing dataset at --out")
    lr.set_defaults(func=cmd_lerobot)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])

    d = subparsers.add_parser("dataset", help="build the training sets as LeRobot datasets (expert + rendering)",
                              description="The training sets as LeRobot datasets: rsb dataset build --out DIR runs "
                                          "the scripted expert on every training question and renders its frames.")
    dsub = d.add_subparsers(dest="dataset_command", metavar="COMMAND")
    b = dsub.add_parser("build", help="expert demos of every training question, rendered, as one LeRobot dataset "
                                      "per suite",
                        description="From nothing to LeRobot v3.0 datasets of the training sets: the scripted "
                                    "expert on every question of the split, camera frames rendered from its "
                                    "states, in shards written whole by parallel workers; rerun the same command "
                                    "to resume. One dataset per suite at OUT/<suite> with its dataset card.")
    from rsb_maniskill.env_ids import add_suites_argument
    from rsb_maniskill.objects.family import target_names

    add_suites_argument(b)

    b.add_argument("--targets", choices=target_names(), default=BUILD.targets,
                   help="blocks, or the Beyond Blocks everyday objects (the -Objects ids)")
    b.add_argument("--split", default=BUILD.split, help=f"question split (default {BUILD.split})")
    b.add_argument("--questions", default=BUILD.questions,
                   help=f"'all' or START:STOP of the split's questions (default {BUILD.questions})")
    b.add_argument("--out", required=True, metavar="DIR", help="OUT/<suite> per suite; OUT/.work holds the shards")
    b.add_argument("--shard-size", type=int, default=BUILD.shard_size,
                   help="questions a shard (a stopped run loses at most the shards in flight; "
                        f"default {BUILD.shard_size})")
    b.add_argument("--data-dir", default=None, help="question data directory (default $RSB_DATA_DIR or the hub cache)")
    _add_format_args(b)
    b.set_defaults(func=cmd_build)
    d.set_defaults(func=lambda args: (d.print_help(), 2)[1])


def _executor(args: argparse.Namespace):
    from rsb_maniskill.parallel.plan import executor_from_args, resolve_workers

    return resolve_workers(args.num_procs, executor_from_args(args.executor, args.address), renders=True)


def _cameras(text: str) -> list[str]:
    return [c.strip() for c in text.split(",") if c.strip()]


def cmd_lerobot(args: argparse.Namespace) -> int:
    from rsb_maniskill.export.build import export_lerobot
    from rsb_maniskill.export.lerobot import ExportError

    try:
        executor, num_procs = _executor(args)
        summary = export_lerobot(args.demos, args.out, fps=args.fps, cameras=_cameras(args.cameras),
                                 naming=args.naming, overwrite=args.overwrite, progress=sys.stderr.isatty(),
                                 num_procs=num_procs, executor=executor)
    except (ExportError, ValueError, ImportError) as err:
        print(f"rsb export: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as err:
        print(f"rsb export: {err or 'interrupted'}", file=sys.stderr)
        return 130
    print(f"rsb export: {summary['episodes']} episodes, {summary['frames']} frames, {summary['tasks']} tasks at "
          f"{summary['fps']} fps -> {summary['out']}")
    return 0


def cmd_build(args: argparse.Namespace) -> int:
    from rsb_maniskill.export.build import BuildConfig, build_datasets
    from rsb_maniskill.export.lerobot import ExportError

    try:
        executor, num_procs = _executor(args)
        cfg = BuildConfig(suites=args.suites, out=args.out, targets=args.targets,
                          split=args.split, questions=args.questions, cameras=_cameras(args.cameras), fps=args.fps,
                          naming=args.naming, num_procs=num_procs, shard_size=args.shard_size,
                          data_dir=args.data_dir, progress=sys.stderr.isatty())
        summaries = build_datasets(cfg, executor)
    except (ExportError, ValueError, ImportError) as err:
        print(f"rsb dataset build: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as err:
        print(f"rsb dataset build: {err or 'interrupted; rerun the same command to continue'}", file=sys.stderr)
        return 130
    *suites, totals = summaries
    for s in suites:
        state = "already built" if s["already_built"] else "built"
        print(f"rsb dataset: {s['env_id']}: {s['episodes']} episodes, {s['frames']} frames ({state}) -> {s['out']}")
    print(f"rsb dataset: rendered {totals['rendered_frames']} frames of {totals['rendered_episodes']} episodes in "
          f"{totals['wall_s']:.0f} s")
    return 0
