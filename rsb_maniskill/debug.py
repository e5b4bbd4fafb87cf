"""``rsb --debug``: whether a failed command shows its traceback, and the one way a command prints
an error (a leaf: every command module may import it), with :func:`plural` for the counts in its lines.

Without ``--debug`` a command prints one line, ``rsb <command>: error: <what is wrong and how to
fix it>``. With it (``rsb --debug eval ...``, or ``RSB_DEBUG=1`` in the environment, which worker
processes inherit) the traceback comes first: the exception's own, or the one an error carries
from a worker process in its ``detail`` attribute.
"""
from __future__ import annotations

import os
import sys
import traceback
from contextlib import contextmanager
from typing import Iterator

DEBUG_ENV = "RSB_DEBUG"
DEBUG_HINT = "rsb --debug {command} ... shows the traceback"


def plural(n: int, word: str) -> str:
    """``1 row``, ``3 rows``: a count in a message line."""
    return f"{n} {word}{'' if n == 1 else 's'}"


def debug_enabled() -> bool:
    return os.environ.get(DEBUG_ENV, "").strip().lower() not in ("", "0", "false", "no")


@contextmanager
def debug_mode(on: bool) -> Iterator[None]:
    """``--debug`` for the block (``RSB_DEBUG=1``, restored after); nothing when ``on`` is False."""
    old = os.environ.get(DEBUG_ENV)
    if on:
        os.environ[DEBUG_ENV] = "1"
    try:
        yield
    finally:
        if on and old is None:
            os.environ.pop(DEBUG_ENV, None)
        elif on:
            os.environ[DEBUG_ENV] = old


def print_error(command: str, err: BaseException | str, status: int = 1, *, hint: bool = False,
                unexpected: bool = False, then: str | None = None) -> int:
    """Print ``rsb <command>: error: <err>`` on stderr and return ``status``. With ``--debug`` the
    traceback of ``err`` (or the ``detail`` it carries from a worker) comes first; ``hint`` adds
    how to see it to the line when it is not shown; ``unexpected`` (an error no check foresaw)
    names the exception's type too; ``then`` is what to do next."""
    if isinstance(err, BaseException) and debug_enabled():
        detail = getattr(err, "detail", None)
        text = detail or "".join(traceback.format_exception(type(err), err, err.__traceback__))
        print(text.rstrip(), file=sys.stderr)
    what = f"{type(err).__name__}: {err}" if unexpected and isinstance(err, BaseException) else str(err)
    line = f"rsb {command}: error: {what}" + (f"; {then}" if then else "")
    if hint and not debug_enabled():
        line += f" ({DEBUG_HINT.format(command=command)})"
    print(line, file=sys.stderr)
    return status
