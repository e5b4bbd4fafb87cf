"""RSB-Math pools: sizes, forms, disjointness, machine independence."""
from __future__ import annotations

import hashlib
import re

from rsb_maniskill.semantic.math_source import TEST_SIZE, TRAIN_SIZE, math_pool

_Q = re.compile(r"^What is (\d+) (plus|minus|times) (\d+)\?$")


def _parse(q):
    a, op, b = _Q.match(q.text).groups()
    return int(a), op, int(b)


def test_sizes_and_forms():
    train, test = math_pool("train"), math_pool("test")
    assert len(train) == TRAIN_SIZE == 500 and len(test) == TEST_SIZE
    for q in train + test:
        a, op, b = _parse(q)
        if op == "plus":
            assert 10 <= a <= 99 and 10 <= b <= 99 and q.value == a + b
        elif op == "minus":
            assert 10 <= a <= 99 and 10 <= b <= 99 and q.value == a - b and q.value >= 0
        else:
            assert 2 <= a <= 9 and 10 <= b <= 99 and q.value == a * b
        assert q.answer == str(q.value)
    ops = [_parse(q)[1] for q in train]
    assert {ops.count(o) for o in ("plus", "minus", "times")} <= {166, 167}


def test_pools_disjoint_by_text_and_commuted_pair():
    train, test = math_pool("train"), math_pool("test")
    assert not {q.text for q in train} & {q.text for q in test}
    assert len({q.text for q in train}) == len(train)

    def canon(q):
        a, op, b = _parse(q)
        return (op, min(a, b), max(a, b)) if op == "plus" else (op, a, b)
    assert not {canon(q) for q in train} & {canon(q) for q in test}


def test_pool_digest_is_pinned():
    """Pools are identical on every machine and Python version: pin their content."""
    digest = hashlib.sha256("\n".join(q.text for q in math_pool("train")).encode()).hexdigest()
    assert digest == PINNED_TRAIN_DIGEST


PINNED_TRAIN_DIGEST = "b6226449ad82c9ea45e2dfafb0ae260cd837a3127fe29624318e6cc2b122af8a"
