"""The twin rule: reading a question shallowly must not help more when the same question shows 10
options than 4. If a reader lifts a 10-choice suite above its 4-choice twin (intervals apart), the
10-choice distractors are easier to reject than the 4-choice ones and the audit fails.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Sequence

from rsb_maniskill.audit.run import SuiteAudit


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


def twin_key(a: SuiteAudit) -> tuple[str, str] | None:
    """(suite id with its N replaced by "N", split) for a 4- or 10-choice suite; None otherwise.
    "RSB-HardMath-10-Objects [lang_layout=2]" and "RSB-HardMath-4-Objects [lang_layout=2]" match."""
    if a.n_choices not in (4, 10):
        return None
    key, hits = re.subn(rf"-{a.n_choices}(?=$|[-\s\[])", "-N", a.suite_id, count=1)
    return (key, a.split) if hits else None


def twin_pairs(audits: Sequence[SuiteAudit]) -> list[tuple[SuiteAudit, SuiteAudit]]:
    """(10-choice suite, its 4-choice twin) pairs in ``audits``."""
    fours = {twin_key(a): a for a in audits if a.n_choices == 4 and twin_key(a)}
    return [(ten, fours[twin_key(ten)]) for ten in audits if ten.n_choices == 10 and twin_key(ten) in fours]


def twin_failures(audits: Sequence[SuiteAudit]) -> list[TwinFailure]:
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
