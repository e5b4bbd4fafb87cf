"""Distractor generation without surface shortcuts.

Numbers: the answer's rank among the N option values is drawn first (uniform over the pool, see
:func:`rank_weights`), then that many distractors are drawn below and the rest above. They come
from typical slips (off by one or ten, digit swap, wrong operation, partial results) and, when
those run out, from near values of the same sign and magnitude. Hence "largest", "smallest" and
"median value" rules stay at chance.

Text: the answer's rank by length among the options is controlled the same way (commonsense),
or, for MMLU with 10 choices, the six added options are picked so that the answer is the longest
option with probability 1/N (MMLU's own answers are more often the longest of their four).
"""
from __future__ import annotations

import bisect
from typing import Sequence

import numpy as np


def length_key(text: str) -> tuple[int, str]:
    """Total order used for "longer than": length, then text."""
    return (len(text), text)


# ---------------------------------------------------------------------------------------------
# numbers (values in integer units)


def rank_range(value: int, n: int) -> tuple[int, int]:
    """Feasible numbers of distractors *below* the answer keeping every option's sign."""
    below_cap = value if value >= 0 else n  # non-negative answers: only 0..value-1 below
    above_cap = -value - 1 if value < 0 else n  # negative answers: only value+1..-1 above
    return max(0, n - 1 - above_cap), min(n - 1, below_cap)


def rank_weights(values: Sequence[int], n: int) -> np.ndarray:
    """Rank distribution for unconstrained answers so that the pool-wide marginal is uniform.

    Small answers (e.g. GSM8K's "3") cannot have nine smaller non-negative distractors; they get
    a uniform rank over what is feasible, and the other questions compensate.
    """
    deficit = np.zeros(n)
    free = 0
    for v in values:
        lo, hi = rank_range(v, n)
        if lo == 0 and hi == n - 1:
            free += 1
        else:
            deficit[lo:hi + 1] += 1.0 / (hi - lo + 1)
    if free == 0:
        return np.full(n, 1.0 / n)
    w = (len(values) / n - deficit) / free
    w = np.clip(w, 0.0, None)
    return w / w.sum()


def _digit_swaps(v: int) -> list[int]:
    s = str(abs(v))
    out = []
    for i in range(len(s) - 1):
        if s[i] != s[i + 1]:
            t = s[:i] + s[i + 1] + s[i] + s[i + 2:]
            if not (t[0] == "0" and len(t) > 1):
                out.append(int(t) * (1 if v >= 0 else -1))
    return out


def numeric_distractors(value: int, hints: Sequence[int], n: int, rank: int, rng: np.random.Generator) -> list[int]:
    """``n - 1`` distinct values, ``rank`` of them below ``value``, same sign, same magnitude."""
    need_below, need_above = rank, n - 1 - rank
    spread = max(10, abs(value) // 2)
    lo, hi = value - spread, value + spread
    if value >= 0:
        lo = max(lo, 0)
    else:
        hi = min(hi, -1)
    digits = len(str(abs(value)))
    step = 10 ** max(0, digits - 2)
    generic = [value + d for d in (1, -1, 2, -2, 10, -10, step, -step, 10 * step, -10 * step)] + _digit_swaps(value)
    slips = [s for s in dict.fromkeys(list(hints) + generic) if lo <= s <= hi and s != value]
    chosen: list[int] = []
    K_offsets = sorted(set(range(1, n + 4)) | {step * j for j in range(1, n + 4)})
    for need, sgn in ((need_below, -1), (need_above, 1)):
        if need == 0:
            continue
        side = [s for s in slips if (s - value) * sgn > 0]
        k = min(need, len(side))
        picked = [side[i] for i in rng.choice(len(side), size=k, replace=False)] if k else []
        rest = need - k
        if rest > 0:  # near values: small offsets and offsets in steps of the answer's magnitude
            near = [value + sgn * off for off in K_offsets
                    if lo <= value + sgn * off <= hi and value + sgn * off not in picked]
            if len(near) < rest:  # tight window (small answers): every value on that side
                rng_side = range(value - 1, lo - 1, -1) if sgn < 0 else range(value + 1, hi + 1)
                near = [c for c in rng_side if c not in picked]
            picked += [near[i] for i in sorted(rng.choice(len(near), size=rest, replace=False))]
        chosen += picked
    return chosen


# ---------------------------------------------------------------------------------------------
# text


def pick_by_length(answer: str, candidates: Sequence[str], k: int, rng: np.random.Generator) -> list[str]:
    """``k`` distractors with the answer's length rank among all k+1 options uniform (clipped
    to what the candidates allow)."""
    ak = length_key(answer)
    shorter = [c for c in candidates if length_key(c) < ak]
    longer = [c for c in candidates if length_key(c) > ak]
    r = int(rng.integers(0, k + 1))  # number of distractors shorter than the answer
    r = min(max(r, k - len(longer)), len(shorter))
    out = [shorter[i] for i in rng.choice(len(shorter), size=r, replace=False)] if r else []
    if k - r:
        out += [longer[i] for i in rng.choice(len(longer), size=k - r, replace=False)]
    return out


class SortedAnswers:
    """A subject's answer texts sorted by :func:`length_key`, for fast shorter/longer draws."""

    def __init__(self, texts: Sequence[str]) -> None:
        uniq: dict[str, str] = {}
        for t in texts:
            uniq.setdefault(t.casefold(), t)
        self.texts = sorted(uniq.values(), key=length_key)
        self.keys = [length_key(t) for t in self.texts]

    def draw(self, answer: str, exclude: set[str], n_longer: int, n_shorter: int,
             rng: np.random.Generator) -> list[str] | None:
        """Draw the requested numbers of texts longer / shorter than ``answer`` (None if impossible)."""
        cut = bisect.bisect_left(self.keys, length_key(answer))
        out: list[str] = []
        for lo, hi, need in ((cut, len(self.texts), n_longer), (0, cut, n_shorter)):
            if need == 0:
                continue
            if hi - lo < need:
                return None
            got: list[str] = []
            tries = 0
            while len(got) < need and tries < 8 * need + 20:
                tries += 1
                t = self.texts[int(rng.integers(lo, hi))]
                if t.casefold() not in exclude and t not in got and t != answer:
                    got.append(t)
            if len(got) < need:
                pool = [t for t in self.texts[lo:hi] if t.casefold() not in exclude and t not in got and t != answer]
                if len(pool) < need - len(got):
                    return None
                got += [pool[i] for i in rng.choice(len(pool), size=need - len(got), replace=False)]
            out += got
        return out
