"""`rsb` command line: one entry point, sub-commands contributed by the package's modules.

Each module listed in ``_COMMAND_MODULES`` exposes ``register(subparsers)`` that adds its
sub-commands with ``set_defaults(func=...)``; ``func(args) -> int`` is the exit status.
The modules keep their heavy imports inside the commands, so ``rsb questions`` never loads the simulator.
A command prints its own errors in one line; one it lets through is printed the same way here, and
``rsb --debug`` (or ``RSB_DEBUG=1``) adds the traceback (``debug.py``).
"""
from __future__ import annotations

import argparse
import importlib
import sys
from typing import NoReturn

from rsb_maniskill.debug import DEBUG_ENV, debug_mode, print_error

_COMMAND_MODULES = (
    "rsb_maniskill.commands.demo",
    "rsb_maniskill.commands.doctor",
    "rsb_maniskill.commands.verify",
    "rsb_maniskill.commands.questions",
    "rsb_maniskill.commands.audit",
    "rsb_maniskill.commands.generate",
    "rsb_maniskill.commands.eval",
    "rsb_maniskill.commands.backbone",
    "rsb_maniskill.commands.report",
    "rsb_maniskill.commands.leaderboard",
    "rsb_maniskill.commands.export",
)


class Parser(argparse.ArgumentParser):
    """argparse with a usage error in one line, as every other error: what is wrong, and where the
    help is (its sub-parsers are of this class too)."""

    top = False  # the `rsb` parser itself; its sub-parsers refuse what they do not know themselves

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        """A sub-command refuses an unknown option with its own usage (argparse would hand it up
        to `rsb`, whose error names no command)."""
        namespace, extras = super().parse_known_args(args, namespace)
        if extras and not self.top:
            self.print_usage(sys.stderr)
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return namespace, extras


def build_parser() -> argparse.ArgumentParser:
    from rsb_maniskill.version import version_line

    parser = Parser(prog="rsb", description="RoboSemanticBench on ManiSkill3")
    parser.top = True
    parser.add_argument("--version", action="version", version=version_line(),
                        help="print the package and benchmark versions and exit")
    parser.add_argument("--debug", action="store_true",
                        help=f"on an error, print the traceback before the one-line message (also: {DEBUG_ENV}=1)")
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
    with debug_mode(args.debug):  # in the environment, for worker processes too
        try:
            return int(args.func(args) or 0)
        except KeyboardInterrupt:
            print("rsb: interrupted", file=sys.stderr)
            return 130
        except Exception as err:  # noqa: BLE001  (a command let it through: one line, the traceback with --debug)
            return print_error(args.command, err, 1, hint=True, unexpected=True)


if __name__ == "__main__":
    sys.exit(main())
