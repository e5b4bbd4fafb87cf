"""Near-duplicate questions: same text up to wording slips ("0.6c ." vs "0.6c.", a dropped comma,
one changed word), found by word-trigram overlap of their normal forms."""
from __future__ import annotations

import math
from collections import Counter, defaultdict
from typing import Iterable, Sequence

from rsb_maniskill.semantic.normalize import question_key

NEAR_DUPLICATE_JACCARD = 0.8  # word-trigram Jaccard at or above which two questions count as one


def shingles(key: str) -> frozenset[str]:
    """Word trigrams of a normal form (the whole text when shorter)."""
    w = key.split()
    if len(w) < 3:
        return frozenset([" ".join(w)])
    return frozenset(" ".join(w[i:i + 3]) for i in range(len(w) - 2))


def near_duplicate_pairs(keys: Sequence[str], others: Sequence[str] | None = None,
                         threshold: float = NEAR_DUPLICATE_JACCARD) -> list[tuple[str, str, float]]:
    """Pairs of distinct normal forms with trigram Jaccard >= threshold: within ``keys``, or
    (key, other) across the two lists when ``others`` is given.

    Prefix filtering: with shingles ordered rarest first, two sets with Jaccard >= t share a
    shingle among the first ``len - ceil(t * len) + 1`` of each, so only those are indexed.
    """
    base = sorted(set(keys))
    probe = base if others is None else sorted(set(others) - set(base))
    sh = {k: shingles(k) for k in set(base) | set(probe)}
    freq = Counter(g for s in sh.values() for g in s)

    def prefix(k: str) -> list[str]:
        s = sorted(sh[k], key=lambda g: (freq[g], g))
        return s[: len(s) - math.ceil(threshold * len(s)) + 1]

    index: dict[str, list[str]] = defaultdict(list)
    for k in base:
        for g in prefix(k):
            index[g].append(k)
    out = []
    for k in probe:
        s = sh[k]
        for c in {c for g in prefix(k) for c in index.get(g, ())}:
            if c == k or (others is None and c > k):
                continue
            m = len(s & sh[c])
            j = m / (len(s) + len(sh[c]) - m)
            if j >= threshold:
                out.append((c, k, round(j, 3)))
    return sorted(out)


def duplicate_groups(texts: Iterable[str]) -> dict[str, str]:
    """Map each text's normal form to one representative of its group of (near-)duplicates."""
    keys = sorted({question_key(t) for t in texts})
    parent = {k: k for k in keys}

    def find(k: str) -> str:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for a, b, _ in near_duplicate_pairs(keys):
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return {k: find(k) for k in keys}
