"""Named answer-blind guessers: rules that score each option without solving the question.

A guesser maps an episode to one score per option (highest wins, ties split the credit) or to
None where it does not apply (a value rule on text options), in which case it guesses uniformly.
Only ``question``-reading guessers look at the question, and none of them solves it.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from rsb_maniskill.audit.text import digit_string, edit_distance, trailing_zeros
from rsb_maniskill.semantic.normalize import content_words, jaccard, leading_numbers, overlap, trigrams
from rsb_maniskill.semantic.spec import EpisodeSpec

Scores = Sequence[float] | None


@dataclass(frozen=True)
class Guesser:
    name: str
    description: str
    score: Callable[[EpisodeSpec], Scores]
    reads_question: bool = False


def credit(scores: Sequence[float], answer: int) -> float:
    """Expected accuracy of "pick a top-scoring option at random"."""
    s = np.asarray(scores, dtype=float)
    best = np.flatnonzero(s == s.max())
    return 1.0 / len(best) if answer in best else 0.0


def _values(sp: EpisodeSpec) -> np.ndarray | None:
    """Option values for the numeric guessers: plain numbers, and the number a text option starts
    with ("240 grams, 6.5 grams") when every option starts with one."""
    v = leading_numbers(sp.options)
    return None if v is None else np.asarray(v, dtype=float)


def _numeric(rule: Callable[[np.ndarray], Sequence[float]]) -> Callable[[EpisodeSpec], Scores]:
    def score(sp: EpisodeSpec) -> Scores:
        v = _values(sp)
        return None if v is None else rule(v)
    return score


def _share_count(keys: Sequence) -> list[float]:
    return [sum(k == o for o in keys) - 1.0 for k in keys]


def _edit_medoid(v: np.ndarray) -> list[float]:
    s = [digit_string(x) for x in v]
    return [-sum(edit_distance(a, b) for b in s) for a in s]


def _cluster(v: np.ndarray) -> list[float]:
    tol = 0.1 * np.maximum(np.abs(v), 1e-9)
    return [float(np.sum(np.abs(v - x) <= t)) for x, t in zip(v, tol)]


def made_of_others(v: np.ndarray) -> list[float]:
    """1 for an option equal to the sum, difference or product of two other options
    (how an intermediate result of the solution would give the answer away)."""
    v = np.asarray(v, dtype=float)
    n = len(v)
    a, b, x = v[:, None], v[None, :], v[:, None, None]  # x: each option against every pair (j, k)
    hit = np.isclose(x, a + b) | np.isclose(x, a - b) | np.isclose(x, a * b)  # (i, j, k), all options at once
    i, j, k = np.ogrid[:n, :n, :n]
    distinct = (i != j) & (i != k) & (j != k)  # two different options, neither of them the option itself
    return [float(h) for h in (hit & distinct).any(axis=(1, 2))]


_QNUM = re.compile(r"(?<![\d.])-?\d[\d,]*(?:\.\d+)?")


def _in_question(sp: EpisodeSpec) -> Scores:
    v = _values(sp)
    if v is None:
        return None
    qv = {float(m.group(0).replace(",", "")) for m in _QNUM.finditer(sp.question)}
    return [float(x in qv) for x in v]


def _lexical_overlap(sp: EpisodeSpec) -> list[float]:
    q = content_words(sp.question)
    return [float(len(q & content_words(o))) for o in sp.options]


def _stem_overlap(sp: EpisodeSpec) -> list[float]:
    return [float(overlap(o, sp.question)) for o in sp.options]


def _negate(score: Callable[[EpisodeSpec], Scores]) -> Callable[[EpisodeSpec], Scores]:
    def neg(sp: EpisodeSpec) -> Scores:
        s = score(sp)
        return None if s is None else [-x for x in s]
    return neg


def _text_medoid(sp: EpisodeSpec) -> Scores:
    g = [trigrams(o) for o in sp.options]
    return [sum(jaccard(a, b) for b in g) for a in g]


def named_guessers(n_choices: int, letters: Sequence[str]) -> list[Guesser]:
    """Every named guesser for an N-choice suite."""
    out = [Guesser(f"letter {L}", f"always option {L}", lambda sp, i=i: [float(j == i) for j in range(n_choices)])
           for i, L in enumerate(letters)]
    out += [Guesser(f"block {b}", f"always physical block {b} (its colour / letter)",
                    lambda sp, b=b: [float(x == b) for x in sp.block_of_option]) for b in range(n_choices)]
    out += [
        Guesser("largest", "largest value", _numeric(lambda v: v)),
        Guesser("smallest", "smallest value", _numeric(lambda v: -v)),
        Guesser("median", "value closest to the median of the options", _numeric(lambda v: -np.abs(v - np.median(v)))),
        Guesser("closest to mean", "value closest to the mean of the options",
                _numeric(lambda v: -np.abs(v - v.mean()))),
        Guesser("digit-edit medoid", "smallest total digit-edit distance to the other options", _numeric(_edit_medoid)),
        Guesser("last-digit majority", "last digit shared by most other options",
                _numeric(lambda v: _share_count([digit_string(x)[-1] for x in v]))),
        Guesser("parity majority", "parity shared by most other options",
                _numeric(lambda v: _share_count([x % 2 for x in v]))),
        Guesser("round number", "most trailing zeros", _numeric(lambda v: [trailing_zeros(x) for x in v])),
        Guesser("cluster centre", "most options within +-10 % of it", _numeric(_cluster)),
        Guesser("most digits", "longest digit string", _numeric(lambda v: [len(digit_string(x)) for x in v])),
        Guesser("made of others", "equals a sum, difference or product of two other options", _numeric(made_of_others)),
        Guesser("longest", "longest text", lambda sp: [len(o) for o in sp.options]),
        Guesser("shortest", "shortest text", lambda sp: [-len(o) for o in sp.options]),
        Guesser("text medoid", "most character trigrams shared with the other options", _text_medoid),
        Guesser("lexical overlap", "most content words shared with the question", _lexical_overlap, True),
        Guesser("least lexical overlap", "fewest content words shared with the question",
                _negate(_lexical_overlap), True),
        Guesser("stem overlap", "most words related to a question word (same stem, or one inside the other)",
                _stem_overlap, True),
        Guesser("least stem overlap", "fewest words whose stem is in the question", _negate(_stem_overlap), True),
        Guesser("number in question", "value that appears in the question text", _in_question, True),
        Guesser("number not in question", "value that does not appear in the question text",
                _negate(_in_question), True),
    ]
    return out


def candidate_guessers(specs: Sequence[EpisodeSpec]) -> list[Guesser]:
    """"Always the mug": one guesser per candidate category the episodes show (everyday objects;
    blocks have one category and are covered by the block guessers)."""
    cats = sorted({c.split(":", 1)[0] for sp in specs for c in sp.candidates})
    if len(cats) < 2:
        return []
    return [Guesser(f"category {c}", f"always the candidate that is a {c}",
                    lambda sp, c=c: [float(sp.candidates[b].split(":", 1)[0] == c) for b in sp.block_of_option])
            for c in cats]
