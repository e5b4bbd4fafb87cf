"""RSB-Math: procedurally generated arithmetic, identical on every machine.

The full question space is enumerated and ordered by SHA-256 of a canonical key, so the pools
depend on nothing but this file. Forms (paper section 3.2):

* a + b, both two-digit;
* a - b, both two-digit, with a - b >= 10 (never negative; the two-digit result also leaves nine
  non-negative values below every answer, so the answer's rank among the options can be uniform);
* d x b, d one-digit in 2..9 (x1 is trivial), b two-digit.

a + b and b + a (same unordered pair) always land in the same split, so the evaluation pool holds
no commuted copy of a training question.
"""
from __future__ import annotations

import operator
import os
import re
from functools import lru_cache

from rsb_maniskill.semantic.pools import Pool
from rsb_maniskill.semantic.records import Question
from rsb_maniskill.semantic.stable import stable_key

TRAIN_SIZE = 500
TEST_SIZE = 1000
_OPS = {"plus": operator.add, "minus": operator.sub, "times": operator.mul}
QUESTION = re.compile(r"What is (\d+) (plus|minus|times) (\d+)\?")  # the form _question writes


def solve(text: str) -> tuple[int, str, int, int] | None:
    """(a, op, b, value) of the first RSB-Math question in ``text``, else None."""
    m = QUESTION.search(text)
    if m is None:
        return None
    a, op, b = int(m.group(1)), m.group(2), int(m.group(3))
    return a, op, b, _OPS[op](a, b)


def _question(op: str, a: int, b: int) -> Question:
    v = _OPS[op](a, b)
    word = op
    return Question(
        text=f"What is {a} {word} {b}?",
        answer=str(v),
        source="math",
        group=op,
        value=v,
        solution=f"{a} {word} {b} equals {v}.",
        origin=f"math generator ({a} {word} {b})",
        fact=f"{op}:{min(a, b)},{max(a, b)}" if op == "plus" else f"{op}:{a},{b}",
    )


def _groups(op: str) -> list[list[tuple[int, int]]]:
    """Operand pairs grouped by canonical key, in stable hash order."""
    groups: dict[tuple[int, int], list[tuple[int, int]]] = {}
    if op == "plus":
        for a in range(10, 100):
            for b in range(10, 100):
                groups.setdefault((min(a, b), max(a, b)), []).append((a, b))
    elif op == "minus":
        for a in range(10, 100):
            for b in range(10, 100):
                if a - b >= 10:
                    groups[(a, b)] = [(a, b)]
    else:
        for d in range(2, 10):
            for b in range(10, 100):
                groups[(d, b)] = [(d, b)]
    keys = sorted(groups, key=lambda k: stable_key("rsb-math", op, *k))
    return [groups[k] for k in keys]


def _take(groups: list[list[tuple[int, int]]], start: int, count: int) -> tuple[list[tuple[int, int]], int]:
    """Take whole groups from ``start`` until ``count`` pairs (a group is cut, its rest discarded)."""
    out: list[tuple[int, int]] = []
    i = start
    while len(out) < count and i < len(groups):
        out.extend(groups[i][: count - len(out)])
        i += 1
    return out, i


@lru_cache(maxsize=None)
def math_pool(split: str) -> tuple[Question, ...]:
    """Training (500) or evaluation (1,000) arithmetic questions, disjoint by text and by operand pair."""
    per_train = [TRAIN_SIZE // 3 + (1 if i < TRAIN_SIZE % 3 else 0) for i in range(3)]
    per_test = [TEST_SIZE // 3 + (1 if i < TEST_SIZE % 3 else 0) for i in range(3)]
    chosen: list[Question] = []
    for op, n_train, n_test in zip(_OPS, per_train, per_test):
        groups = _groups(op)
        train, nxt = _take(groups, 0, n_train)
        pairs = train if split == "train" else _take(groups, nxt, n_test)[0]
        chosen.extend(_question(op, a, b) for a, b in pairs)
    chosen.sort(key=lambda q: stable_key("rsb-math-order", q.text))  # mix the operations
    return tuple(chosen)


def pool(split: str, data_dir: str | os.PathLike | None = None) -> Pool:
    """The Math pool of ``split`` (no data needed: ``data_dir`` is ignored)."""
    qs = math_pool(split)
    return Pool("Math", split, qs, (None,) * len(qs), {"math": len(qs)})


def clear_cache() -> None:
    math_pool.cache_clear()
