"""Guessers that read the instruction's wording (for the language robustness axes, ``rsb audit --perturb``).

A language axis rewrites only how the instruction says things; if a rewording put the correct
option somewhere special (first, last, repeated, next to an added sentence), these would find it.
None solves the question; each scores the options by where their text stands in the instruction,
and each abstains on an instruction that does not write every option (Direct suites: the
instruction names the target, by design).
"""
from __future__ import annotations

from typing import Sequence

from rsb_maniskill.audit.guessers import Guesser, Scores
from rsb_maniskill.semantic.records import normalize_text
from rsb_maniskill.semantic.spec import EpisodeSpec
from rsb_maniskill.semantic.wording import DISTRACTORS


def _positions(sp: EpisodeSpec) -> list[int] | None:
    """Where each option's text first stands in the instruction (None if one is not found)."""
    pos = [sp.instruction.find(normalize_text(o)) for o in sp.options]
    return None if min(pos) < 0 else pos


def _first(sp: EpisodeSpec) -> Scores:
    pos = _positions(sp)
    return None if pos is None else [-float(p) for p in pos]


def _last(sp: EpisodeSpec) -> Scores:
    pos = _positions(sp)
    return None if pos is None else [float(p) for p in pos]


def _repeated(sp: EpisodeSpec) -> Scores:
    # Only where the instruction lists every option: a Direct instruction names its target and no
    # other candidate (the task, not a shortcut), so counting there would read the answer itself.
    if _positions(sp) is None:
        return None
    return [float(sp.instruction.count(normalize_text(o))) for o in sp.options]


def _near_distractor(sp: EpisodeSpec) -> Scores:
    pos = _positions(sp)
    marks = [sp.instruction.find(s) for s in DISTRACTORS if s in sp.instruction]
    if pos is None or not marks:
        return None
    return [-float(min(abs(p - m) for m in marks)) for p in pos]


def instruction_guessers(specs: Sequence[EpisodeSpec]) -> list[Guesser]:
    return [
        Guesser("mentioned first", "the option whose text comes first in the instruction", _first),
        Guesser("mentioned last", "the option whose text comes last in the instruction", _last),
        Guesser("mentioned most", "the option whose text the instruction repeats most", _repeated),
        Guesser("next to an added sentence", "the option nearest an irrelevant sentence (lang_distractor)",
                _near_distractor),
    ]
