"""Reader rows (references beside the guessers), lift over chance, and the twin rule.

Lift = (accuracy - 1/N) / (1 - 1/N): 0 at chance, 1 when always right, so a 4- and a 10-choice
suite compare on one scale. The twin rule: reading a question shallowly must not help more when
the same question shows 10 options than 4; if it does (intervals apart), the 10-choice distractors
are easier to reject than the 4-choice ones and the audit fails.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from rsb_maniskill.evaluation.metrics import wilson_interval
from rsb_maniskill.semantic.spec import EpisodeSpec

from .guessers import credit
from .readers import BoundReader

if TYPE_CHECKING:
    from .run import SuiteAudit


def rate(credits: np.ndarray) -> tuple[float, float, float]:
    """Mean credit and its Wilson 95 % interval (credit is a 0/1 outcome or a tie share, whose
    variance is at most the binomial one, so the interval is conservative)."""
    n = len(credits)
    s = float(credits.sum())
    lo, hi = wilson_interval(int(round(s)), n)
    return s / n, lo, hi


def lift(accuracy: float, n_choices: int) -> float:
    """(accuracy - 1/N) / (1 - 1/N); monotone, so it maps an accuracy interval to a lift interval."""
    c = 1.0 / n_choices
    return (accuracy - c) / (1.0 - c)


@dataclass
class ReaderResult:
    name: str
    description: str
    accuracy: float | None = None
    low: float | None = None
    high: float | None = None
    lift: float | None = None
    lift_low: float | None = None
    lift_high: float | None = None
    applies: int = 0  # episodes where the reader told options apart (others: uniform guess)
    unavailable: str = ""  # why the reader could not run (a missing optional package), else ""


def read(reader: BoundReader, specs: Sequence[EpisodeSpec]) -> ReaderResult:
    """Score one reader on ``specs`` (all with the same N)."""
    n = specs[0].n_choices
    try:
        scores = list(reader.batch([sp.question for sp in specs], [sp.options for sp in specs]))
    except ImportError as err:
        return ReaderResult(reader.name, reader.description, unavailable=str(err).splitlines()[0] or repr(err))
    if len(scores) != len(specs):
        raise ValueError(f"reader {reader.name}: {len(scores)} score lists for {len(specs)} episodes")
    cr, ap = np.full(len(specs), 1.0 / n), np.zeros(len(specs), dtype=bool)
    for i, (sp, s) in enumerate(zip(specs, scores)):
        if s is None:
            continue
        s = [float(x) for x in s]
        if len(s) != n:
            raise ValueError(f"reader {reader.name}: {len(s)} scores for {n} options")
        if len(set(s)) > 1:
            cr[i], ap[i] = credit(s, sp.answer_slot), True
    acc, lo, hi = rate(cr)
    return ReaderResult(reader.name, reader.description, acc, lo, hi, lift(acc, n), lift(lo, n), lift(hi, n),
                        int(ap.sum()))


@dataclass(frozen=True)
class TwinFailure:
    suite: str  # the 10-choice suite
    twin: str  # its 4-choice twin
    reader: str
    lift: tuple[float, float, float]  # 10-choice lift, low, high
    twin_lift: tuple[float, float, float]

    def __str__(self) -> str:
        f = "{:+.1f} [{:+.1f}, {:+.1f}]".format
        return (f"{self.reader} lifts {self.suite} by {f(*(100 * x for x in self.lift))} points, above "
                f"{self.twin}'s {f(*(100 * x for x in self.twin_lift))}")


def twin_key(a: "SuiteAudit") -> tuple[str, str] | None:
    """(suite id with its N replaced by "N", split) for a 4- or 10-choice suite; None otherwise.
    "RSB-HardMath-10-Objects [lang_layout=2]" and "RSB-HardMath-4-Objects [lang_layout=2]" match."""
    if a.n_choices not in (4, 10):
        return None
    key, hits = re.subn(rf"-{a.n_choices}(?=$|[-\s\[])", "-N", a.suite_id, count=1)
    return (key, a.split) if hits else None


def twin_pairs(audits: Sequence["SuiteAudit"]) -> list[tuple["SuiteAudit", "SuiteAudit"]]:
    """(10-choice suite, its 4-choice twin) pairs in ``audits``."""
    fours = {twin_key(a): a for a in audits if a.n_choices == 4 and twin_key(a)}
    return [(ten, fours[twin_key(ten)]) for ten in audits if ten.n_choices == 10 and twin_key(ten) in fours]


def twin_failures(audits: Sequence["SuiteAudit"]) -> list[TwinFailure]:
    """Readers that give a 10-choice suite a larger lift than its 4-choice twin, intervals apart
    (the 10-choice lift's low end above the 4-choice lift's high end)."""
    out = []
    for ten, four in twin_pairs(audits):
        theirs = {r.name: r for r in four.readers if not r.unavailable}
        for r in ten.readers:
            t = theirs.get(r.name)
            if t is not None and not r.unavailable and r.lift_low > t.lift_high:
                out.append(TwinFailure(ten.suite_id, four.suite_id, r.name, (r.lift, r.lift_low, r.lift_high),
                                       (t.lift, t.lift_low, t.lift_high)))
    return out
