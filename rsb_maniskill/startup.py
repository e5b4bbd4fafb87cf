"""Ctrl-C while the ``rsb`` command starts: before ``cli.main`` runs, its handling is not in place.

The package's own import (gymnasium, the env registry, the render device) comes first when ``rsb``
or ``python -m rsb_maniskill.cli`` starts, and takes a second or more on a busy machine; Python's
default Ctrl-C there is a KeyboardInterrupt traceback. :func:`guard` (called first thing by the
package, and only in the command) ends the process as ``cli.main`` does, "rsb: interrupted" and
130, until :func:`release` hands Ctrl-C back. Nothing has been written yet, so nothing is lost. A
leaf: it imports nothing of the pack.
"""
from __future__ import annotations

import os  # os, signal and sys are loaded by Python's own start-up: importing this module costs nothing more
import signal
import sys

CLI_MODULE = "rsb_maniskill.cli"
INTERRUPTED = 130  # the shell's code for a process ended by SIGINT (cli.main returns it too)


def is_command() -> bool:
    """Whether this process is the ``rsb`` command (console script or ``python -m``): not a library
    user, and not one of its workers (a spawned worker is given the parent's ``sys.argv``, so the
    interpreter's own command line, ``sys.orig_argv``, is what tells)."""
    orig = list(getattr(sys, "orig_argv", ()))
    if len(orig) > 1 and os.path.basename(orig[1]) == "rsb":
        return True
    return "-m" in orig[:-1] and orig[orig.index("-m") + 1] == CLI_MODULE


BARE_FLAGS = (["--version"], ["-h"], ["--help"])  # `rsb` with one of these alone needs no command and no plugin


def bare_command() -> bool:
    """Whether this process is ``rsb --version`` or ``rsb --help`` (the package skips its plugins:
    one that hangs or exits at import cannot stop them)."""
    return is_command() and sys.argv[1:] in BARE_FLAGS


def _interrupted(signum: int, frame: object) -> None:
    os.write(2, b"rsb: interrupted\n")
    os._exit(INTERRUPTED)


def guard() -> None:
    """In the ``rsb`` command only: Ctrl-C ends it quietly until :func:`release`."""
    if is_command() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _interrupted)


def release() -> None:
    """Ctrl-C raises KeyboardInterrupt again (``cli.main`` catches it from here on)."""
    try:
        if signal.getsignal(signal.SIGINT) is _interrupted:
            signal.signal(signal.SIGINT, signal.default_int_handler)
    except ValueError:  # not the main thread: it never installed the guard
        pass
