"""`rsb export lerobot`: demonstrations as a LeRobot dataset (no simulator import until it runs)."""
from __future__ import annotations

import argparse
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("export", help="export demonstrations to another format (LeRobot)")
    sub = p.add_subparsers(dest="export_format", metavar="FORMAT")
    lr = sub.add_parser("lerobot", help="a LeRobot dataset (format v3.0)",
                        description="Write demos (rsb generate output, merged or converted) as one LeRobot v3.0 "
                                    "dataset: Aloha 14-number state and action, one video per camera, each "
                                    "episode's instruction as its task, RSB metadata in the episodes table. State "
                                    "demos are re-rendered from their recorded env states.")
    lr.add_argument("demos", nargs="+", metavar="DEMOS.h5", help="trajectory files (X.h5 with X.json beside it)")
    lr.add_argument("--out", required=True, metavar="DIR", help="dataset directory (created; must not hold files)")
    lr.add_argument("--fps", type=int, default=None, help="frame rate; must divide the 25 Hz control rate (default 25)")
    lr.add_argument("--cameras", default="head,left_wrist,right_wrist",
                    help="comma-separated: head, left_wrist, right_wrist (LeRobot keys cam_high, cam_left_wrist, "
                         "cam_right_wrist)")
    lr.add_argument("--overwrite", action="store_true", help="replace an existing dataset at --out")
    lr.set_defaults(func=cmd_lerobot)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def cmd_lerobot(args: argparse.Namespace) -> int:
    from .lerobot import ExportError, export_lerobot

    cameras = [c.strip() for c in args.cameras.split(",") if c.strip()]
    try:
        summary = export_lerobot(args.demos, args.out, fps=args.fps, cameras=cameras, overwrite=args.overwrite,
                                 progress=sys.stderr.isatty())
    except ExportError as err:
        print(f"rsb export: error: {err}", file=sys.stderr)
        return 2
    print(f"rsb export: {summary['episodes']} episodes, {summary['frames']} frames, {summary['tasks']} tasks at "
          f"{summary['fps']} fps -> {summary['out']}")
    return 0
