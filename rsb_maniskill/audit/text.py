"""Surface readings of an option set that answer-blind guessers and the learned probe use."""
from __future__ import annotations

from functools import lru_cache


def digit_string(value: float) -> str:
    """Digits of a value as written ("162", "3.75"), sign dropped."""
    s = f"{abs(value):.6f}".rstrip("0").rstrip(".")
    return s or "0"


def trailing_zeros(value: float) -> int:
    """Roundness: trailing zeros of the integer part (0 for non-integers and for 0)."""
    if value != int(value) or value == 0:
        return 0
    s = str(abs(int(value)))
    return len(s) - len(s.rstrip("0"))


@lru_cache(maxsize=65536)
def edit_distance(a: str, b: str) -> int:
    """Levenshtein distance (insert, delete, substitute), for short digit strings."""
    prev = list(range(len(b) + 1))
    for i, ca in enumerate(a, 1):
        cur = [i]
        for j, cb in enumerate(b, 1):
            cur.append(min(prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (ca != cb)))
        prev = cur
    return prev[-1]

