"""`rsb` command line: one entry point, sub-commands contributed by the package's modules.

Each module listed in ``_COMMAND_MODULES`` exposes ``register(subparsers)`` that adds its
sub-commands with ``set_defaults(func=...)``; ``func(args) -> int`` is the exit status.
The modules keep their heavy imports inside the commands, so ``rsb questions`` never loads the simulator.
"""
from __future__ import annotations

import argparse
import importlib
import sys

_COMMAND_MODULES = (
    "rsb_maniskill.demo",
    "rsb_maniskill.doctor",
    "rsb_maniskill.golden",
    "rsb_maniskill.semantic_cli",
    "rsb_maniskill.audit.cli",
    "rsb_maniskill.motionplan.cli",
    "rsb_maniskill.evaluation.cli.eval",
    "rsb_maniskill.evaluation.cli.backbone",
    "rsb_maniskill.evaluation.cli.report",
    "rsb_maniskill.export.cli",
)


def build_parser() -> argparse.ArgumentParser:
    from rsb_maniskill.version import version_line

    parser = argparse.ArgumentParser(prog="rsb", description="RoboSemanticBench on ManiSkill3")
    parser.add_argument("--version", action="version", version=version_line(),
                        help="print the package and benchmark versions and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Runs one command; returns its exit status (2 for a usage error, which argparse has printed)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as stop:  # --help, --version, a usage error: argparse printed it
        return stop.code if isinstance(stop.code, int) else 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("rsb: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
