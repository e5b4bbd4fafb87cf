"""Question-aware readers: rules that look at the question, without solving it, to score options.

They are *references*, not guessers: a reader is allowed to beat chance (shallow reading is part
of what a policy may do), and its row tells a user how much task success shallow reading alone
buys on a suite. The twin rule (``twins.twin_failures``) is their only verdict.

A reader is anything with ``score(question, options) -> Sequence[float] | None`` (one score per
option, highest wins, ties split the credit; None where it does not apply: a uniform guess), or a
plain callable ``reader(question, options)``. Optional attributes: ``name``, ``description`` and a
batched ``score_batch(questions, option_sets) -> list[Sequence[float] | None]`` that the audit
prefers (one model call for a whole suite). A reader that raises ImportError (a missing optional
package) gets an "unavailable" row. ``rsb audit --reader module:factory`` calls ``factory()`` for one.

The similarity reader also answers as a backbone (:class:`SimilarityBackbone`, ``rsb backbone
similarity``), reading the question and options from the instruction a policy is given.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from rsb_maniskill.resolve import resolve
from rsb_maniskill.semantic.normalize import numeric_values

Scores = Sequence[float] | None
SPEC_HINT = "give module:factory, e.g. mypkg.readers:make"


@runtime_checkable
class Reader(Protocol):
    def score(self, question: str, options: Sequence[str]) -> Scores: ...


@dataclass
class BoundReader:
    """A reader as the audit runs it: a name, a description and a batched scorer."""

    name: str
    description: str
    batch: Callable[[Sequence[str], Sequence[Sequence[str]]], Sequence[Scores]]


def bind(obj: Any, name: str, description: str = "") -> BoundReader:
    """The audit's view of a reader object or callable (see the module docstring)."""
    name = getattr(obj, "name", None) or name
    description = getattr(obj, "description", None) or description or f"user reader {name}"
    if callable(getattr(obj, "score_batch", None)):
        return BoundReader(name, description, obj.score_batch)
    one = obj.score if callable(getattr(obj, "score", None)) else obj
    if not callable(one):
        raise TypeError(f"{name}: not a reader (needs score(question, options) or to be callable)")
    return BoundReader(name, description, lambda qs, opts: [one(q, o) for q, o in zip(qs, opts)])


def load_reader(spec: str) -> BoundReader:
    """``module:factory`` -> the reader ``factory()`` returns; ValueError with a one-line fix."""
    mod_name, sep, attr = spec.partition(":")
    if not sep or not mod_name or not attr:
        raise ValueError(f"--reader: '{spec}' is not module:factory; {SPEC_HINT}")
    try:
        factory = resolve(spec, "reader")
    except ImportError as err:
        raise ValueError(f"--reader: cannot import '{mod_name}' ({err.__cause__}); {SPEC_HINT}") from None
    except (AttributeError, TypeError):
        raise ValueError(f"--reader: '{mod_name}' has no callable '{attr}'; {SPEC_HINT}") from None
    try:
        return bind(factory(), spec)
    except TypeError as err:
        raise ValueError(f"--reader: {spec}() returned no reader ({err}); return an object with "
                         "score(question, options) or a callable") from None


def _free_cores(most: int) -> int:
    """Threads worth running on a shared machine: the idle cores (+1 for this process's own load),
    at least 1. On 2 busy cores, 2 threads took twice the wall time of 1 (they wait on each other)."""
    try:
        idle = (os.cpu_count() or 1) - os.getloadavg()[0] + 1
    except OSError:  # no load average on this platform
        return most
    return max(1, min(most, int(idle)))


class SimilarityReader:
    """The option whose all-MiniLM-L6-v2 embedding is closest (cosine) to the question's: what a
    frozen sentence encoder, the usual language input of a policy, links without reasoning."""

    name = "similarity"
    description = "option most similar to the question (cosine of all-MiniLM-L6-v2 embeddings)"

    def __init__(self) -> None:
        self._encoder = None  # loaded on first use: the audit imports no torch until it reads

    def _encode(self, texts: list[str]) -> np.ndarray:
        if self._encoder is None:
            from rsb_maniskill.baselines.diffusion_policy.text import TextEncoder  # the baseline's encoder

            self._encoder = TextEncoder()  # cached per text; raises MissingExtraError (ImportError)
        import torch

        threads = torch.get_num_threads()
        torch.set_num_threads(_free_cores(threads))
        try:
            return self._encoder.encode(texts)
        finally:
            torch.set_num_threads(threads)

    def score_batch(self, questions: Sequence[str], option_sets: Sequence[Sequence[str]]) -> list[Scores]:
        if not any(q.strip() for q in questions):
            return [None] * len(questions)  # Direct suites: no question to read
        texts = list(dict.fromkeys([q for q in questions if q.strip()] + [o for opts in option_sets for o in opts]))
        emb = dict(zip(texts, self._encode(texts)))
        return [None if not q.strip() else [float(emb[q] @ emb[o]) for o in opts]
                for q, opts in zip(questions, option_sets)]

    def score(self, question: str, options: Sequence[str]) -> Scores:
        return self.score_batch([question], [options])[0]


class SimilarityBackbone:
    """The similarity reader as a backbone (``rsb backbone similarity``) on the question and options
    the instruction shows: "option <letter>" of the option nearest the question; "" when it cannot
    read them (Direct, blank)."""

    name = "similarity"

    def __init__(self) -> None:
        self.reader = SimilarityReader()

    def answer(self, instruction: str, images: Mapping[str, np.ndarray]) -> str:
        from rsb_maniskill.semantic.answers import read_instruction

        reading = read_instruction(instruction)
        scores = None if reading is None else self.reader.score(reading.question, reading.options)
        if scores is None:
            return ""
        return f"option {reading.letters[int(np.argmax(scores))]}"


_QNUM = re.compile(r"(?<![\d.])-?\d[\d,]*(?:\.\d+)?")
_WORDS = {w: float(i) for i, w in enumerate(
    "zero one two three four five six seven eight nine ten eleven twelve thirteen fourteen fifteen sixteen "
    "seventeen eighteen nineteen twenty".split()) if i >= 2}  # "one" is mostly a pronoun
_WORDS.update(thirty=30, forty=40, fifty=50, sixty=60, seventy=70, eighty=80, ninety=90, hundred=100, thousand=1000,
              dozen=12, twice=2, double=2, half=2, triple=3, thrice=3, quarter=4)
_WORD = re.compile(r"\b(" + "|".join(_WORDS) + r")\b", re.IGNORECASE)
MAX_NUMBERS = 12  # of a question's numbers; 12 give ~30k two-operation results


def question_numbers(question: str) -> list[float]:
    """Numbers written in the question (digits, and number words such as "twelve", "twice",
    "half", "dozen"), in order; each value at most twice (so "5 ... 5" can give 5 + 5)."""
    found = [(m.start(), float(m.group(0).replace(",", ""))) for m in _QNUM.finditer(question)]
    found += [(m.start(), _WORDS[m.group(1).lower()]) for m in _WORD.finditer(question)]
    out: list[float] = []
    for _, v in sorted(found):
        if out.count(v) < 2:
            out.append(v)
    return out[:MAX_NUMBERS]


def _ops(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Every a + b, a - b, b - a, a x b, a / b, b / a (non-finite where undefined)."""
    with np.errstate(all="ignore"):
        return np.stack(np.broadcast_arrays(a + b, a - b, b - a, a * b, a / b, b / a))


def _keep(r: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Finite results that are not one of their operands (x 1, + 0 do nothing)."""
    return np.isfinite(r) & ~np.isclose(r, a) & ~np.isclose(r, b)


def reachable(numbers: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Sorted values reachable in exactly one and in two operations (+ - x /) from ``numbers``,
    each number used at most once per expression."""
    q = np.asarray(numbers, dtype=float)
    k = len(q)
    if k < 2:
        return np.zeros(0), np.zeros(0)
    i, j = np.triu_indices(k, 1)
    r1 = _ops(q[i], q[j])  # (6, pairs)
    keep1 = _keep(r1, q[i], q[j])
    ii, jj = np.broadcast_to(i, r1.shape)[keep1], np.broadcast_to(j, r1.shape)[keep1]
    one = r1[keep1]
    if k < 3 or not len(one):
        return np.unique(one), np.zeros(0)
    x, c = one[:, None], q[None, :]
    r2 = _ops(x, c)  # (6, len(one), k)
    free = (np.arange(k)[None, :] != ii[:, None]) & (np.arange(k)[None, :] != jj[:, None])
    keep2 = _keep(r2, x, c) & free
    return np.unique(one), np.unique(r2[keep2])


def _hits(sorted_vals: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Which of ``v`` lie within float tolerance of a member of ``sorted_vals``."""
    if not len(sorted_vals):
        return np.zeros(len(v), dtype=bool)
    pos, last = np.searchsorted(sorted_vals, v), len(sorted_vals) - 1
    below, above = sorted_vals[np.clip(pos - 1, 0, last)], sorted_vals[np.clip(pos, 0, last)]
    return np.isclose(below, v, rtol=1e-6, atol=1e-9) | np.isclose(above, v, rtol=1e-6, atol=1e-9)


class NumberReachabilityReader:
    """Options that one or two operations on the question's numbers give: what a reader that
    combines the numbers it sees, without understanding the question, would pick."""

    name = "number reachability"
    description = ("numeric option reachable from the question's numbers in one (score 2) or two (score 1) "
                   "operations of + - x /; unreachable 0; text options: does not apply")

    def __init__(self) -> None:
        self._cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def score(self, question: str, options: Sequence[str]) -> Scores:
        vals = numeric_values(list(options))
        if vals is None:
            return None
        if question not in self._cache:
            self._cache[question] = reachable(question_numbers(question))
        one, two = self._cache[question]
        v = np.asarray(vals, dtype=float)
        return list(np.where(_hits(one, v), 2.0, np.where(_hits(two, v), 1.0, 0.0)))


def default_readers() -> list[BoundReader]:
    """The readers ``rsb audit`` runs unless ``--no-readers``."""
    return [bind(r, r.name, r.description) for r in (SimilarityReader(), NumberReachabilityReader())]
