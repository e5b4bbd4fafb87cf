"""`rsb` command line: one entry point, sub-commands contributed by the package's modules.

Each module listed in ``_COMMAND_MODULES`` exposes ``register(subparsers)`` that adds its
sub-commands with ``set_defaults(func=...)``; ``func(args) -> int`` is the exit status.
The modules keep their heavy imports inside the commands, so ``rsb questions`` never loads the simulator.
A command prints its own errors in one line; one it lets through is printed the same way here, and
``rsb --debug`` (or ``RSB_DEBUG=1``) adds the traceback (``debug.py``).
"""
from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import os
import signal
import sys
import warnings
from typing import Any, Iterator, NoReturn

from rsb_maniskill.debug import DEBUG_ENV, debug_mode, print_error
from rsb_maniskill.plugins import skip_plugins
from rsb_maniskill.startup import BARE_FLAGS
from rsb_maniskill.startup import release as release_startup_guard

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
    "rsb_maniskill.commands.plan",
    "rsb_maniskill.commands.serve",
)


class Parser(argparse.ArgumentParser):
    """argparse with a usage error in one line, as every other error: what is wrong, and where the
    help is (its sub-parsers are of this class too)."""

    top = False  # the `rsb` parser itself; its sub-parsers refuse what they do not know themselves

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        """A sub-command refuses an unknown option itself, in one line naming the command and its
        help (argparse would hand it up to `rsb`, whose error names no command)."""
        namespace, extras = super().parse_known_args(args, namespace)
        if extras and not self.top:
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
    """Runs one command; returns its exit status (2 for a usage error, which argparse has printed).

    Ctrl-C at any point ends with "rsb: interrupted" and 130, no traceback (during the package's
    import too: ``startup.py``; only Python's own first ~50 ms are not ours); a
    reader that stops reading (``rsb questions ... | head``) ends it quietly with 0, as unix tools do."""
    release_startup_guard()  # from here on Ctrl-C is a KeyboardInterrupt, caught below
    _text_in_any_locale()
    try:
        return _main(sys.argv[1:] if argv is None else argv)
    except KeyboardInterrupt:
        print("rsb: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        _quiet_stdout()
        return 0


@contextlib.contextmanager
def _noting_sigint() -> Iterator[list[int]]:
    """Ctrl-C raises KeyboardInterrupt as usual, and is noted in the list yielded: a library that
    turns it into another error (matplotlib's "Invalid bounding box") cannot make it look like one."""
    received: list[int] = []

    def handler(signum: int, frame: Any) -> None:
        received.append(signum)
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main thread: leave Ctrl-C as it is
        yield received
        return
    try:
        yield received
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _warnings_in_one_line(command: str) -> Iterator[None]:
    """A warning of the pack's own (a torn last record skipped, ...) is one line, ``rsb <command>:
    warning: ...``, as errors are: not Python's two, with the file, the line number and the code."""
    original = warnings.formatwarning
    package = os.path.dirname(os.path.abspath(__file__)) + os.sep

    def one_line(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                 line: str | None = None) -> str:
        if os.path.abspath(filename).startswith(package):
            return f"rsb {command}: warning: {message}\n"
        return original(message, category, filename, lineno, line)

    warnings.formatwarning = one_line
    try:
        yield
    finally:
        warnings.formatwarning = original


def _text_in_any_locale() -> None:
    """A locale that is not UTF-8 (``LC_ALL=POSIX`` with ``PYTHONUTF8=0``, a Latin-1 one) must not turn a
    name typed in UTF-8 into an error: the arguments' bytes are read as UTF-8 where they are, and what
    the console cannot show is written escaped, not raised."""
    for i, arg in enumerate(sys.argv):
        if any("\udc80" <= ch <= "\udcff" for ch in arg):  # bytes the locale's codec could not decode
            try:
                sys.argv[i] = os.fsencode(arg).decode("utf-8")
            except UnicodeDecodeError:
                pass
    for stream in (sys.stdout, sys.stderr):
        if (getattr(stream, "encoding", None) or "").lower().replace("-", "") != "utf8":
            with contextlib.suppress(AttributeError, ValueError):
                stream.reconfigure(errors="backslashreplace")


def _quiet_stdout() -> None:
    """stdout's reader is gone: point it at /dev/null, so the exit's flush raises nothing more."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _main(argv: list[str] | None) -> int:
    if (sys.argv[1:] if argv is None else argv) in BARE_FLAGS:
        skip_plugins()  # the version and the command list need none: a plugin that hangs cannot stop them
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as stop:  # --help, --version, a usage error: argparse printed it
        return stop.code if isinstance(stop.code, int) else 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    # debug: in the environment, for workers too
    with debug_mode(args.debug), _noting_sigint() as received, _warnings_in_one_line(args.command):
        try:
            status = int(args.func(args) or 0)
        except (KeyboardInterrupt, BrokenPipeError):
            raise
        except Exception as err:  # noqa: BLE001  (a command let it through: one line, the traceback with --debug)
            if received:  # Ctrl-C cut a library call short, which raised something else: say what happened
                raise KeyboardInterrupt from None
            from rsb_maniskill.outdirs import write_error_line

            line = write_error_line(err)  # a full disk, a read-only folder: the path and the fix, not a bug
            if line is not None:  # a name too long is bad input (2), as any other
                return print_error(args.command, line, 2 if err.errno == errno.ENAMETOOLONG else 1)
            return print_error(args.command, err, 1, hint=True, unexpected=True)
        if status not in (0, 130) and received:  # the command reported the cut-short call as an error
            print(f"rsb {args.command}: the error above came from the interruption (Ctrl-C)", file=sys.stderr)
            raise KeyboardInterrupt
        return status


if __name__ == "__main__":
    sys.exit(main())
