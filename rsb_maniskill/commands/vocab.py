"""The command line's one vocabulary, and the old spellings it keeps for one release.

Every command that writes takes ``--out``; ``-o`` / ``--obs-mode`` is the observation mode;
``-n`` / ``--num-episodes`` counts episodes per suite; suites are ``--suites`` (or positional
``SUITE ...``, ``env_ids.add_suites_argument``); ``--instruction`` is the evaluation protocol's
instruction mode and ``--instruction-set`` the seen / unseen templates. ``tests/test_cli_vocabulary.py``
walks every parser and holds these rules. An old spelling still works until ``GOES_IN`` and prints
one line on stderr naming the new one.
"""
from __future__ import annotations

import argparse
import sys
from typing import Any

GOES_IN = "0.4"


class _OldSpelling(argparse.Action):
    """Prints ``rsb CMD: OLD is now NEW; ...`` once per use, then does what NEW does."""

    def __init__(self, option_strings: list[str], dest: str, new: argparse.Action, new_name: str,
                 **kwargs: Any) -> None:
        super().__init__(option_strings, dest, **kwargs)
        self.new, self.new_name = new, new_name

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(f"{parser.prog}: {option_string} is now {self.new_name}; the old spelling goes in {GOES_IN}",
              file=sys.stderr)
        self.new(parser, namespace, values, self.new_name)


def add_old_spelling(parser: argparse.ArgumentParser, old: str, new: str) -> None:
    """Keeps ``old`` as a hidden alias of the option ``new`` (already added to ``parser``)."""
    action = next(a for a in parser._actions if new in a.option_strings)
    parser.add_argument(old, dest=action.dest, nargs=action.nargs, type=action.type, choices=action.choices,
                        metavar=action.metavar, default=argparse.SUPPRESS, help=argparse.SUPPRESS,
                        action=_OldSpelling, new=action, new_name=new)


def is_old_spelling(action: argparse.Action) -> bool:
    """For the vocabulary test: an alias kept for one release."""
    return isinstance(action, _OldSpelling)
