"""Option sets in which the answer is exchangeable with its distractors.

The principle (docs/semantic.md): every option of a set is a draw from the *same* distribution,
the distribution the answer itself comes from, and the set is chosen without looking at where the
answer sits in it. Then any rule that sees only the options (centre, rank, digits, parity,
roundness, length, how common a value is) finds the answer with probability 1/N.

Construction: the population (e.g. the answers of the split's addition questions, each value
weighted by how many questions have it) is cut once into fixed bins of neighbouring values. An
episode draws N members of the answer's bin by systematic sampling with inclusion probability
proportional to weight, conditioned on containing the answer. Because bin and inclusion
probabilities do not depend on which member is the answer, P(answer = x | set) = 1/N for every
member x (exactly, when no value's weight exceeds 1/N of its bin; the bins are cut so).
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Hashable, Iterable, Sequence

import numpy as np

LATTICE_SPREAD = 3  # fallback sets span about this many times N units around the answer


def inclusion_probabilities(weights: np.ndarray, n: int) -> np.ndarray:
    """pi_i proportional to weight with sum n and every pi_i <= 1 (largest ones capped at 1)."""
    w = np.asarray(weights, dtype=float)
    if len(w) < n:
        raise ValueError(f"need at least {n} members, got {len(w)}")
    pi = np.zeros_like(w)
    free = np.ones(len(w), dtype=bool)
    left = float(n)
    while True:
        pi[free] = left * w[free] / w[free].sum()
        over = free & (pi > 1.0)
        if not over.any():
            return pi
        pi[over] = 1.0
        free &= ~over
        left = n - float((~free).sum())


def systematic_sample(pi: np.ndarray, must: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of a systematic PPS sample (inclusion probabilities ``pi``, sum = sample size),
    conditioned on containing index ``must``; ``pi`` is laid out in a random order first."""
    order = rng.permutation(len(pi))
    cum = np.concatenate([[0.0], np.cumsum(pi[order])])
    pos = int(np.flatnonzero(order == must)[0])
    start = (cum[pos] + rng.random() * pi[must]) % 1.0
    points = start + np.arange(int(round(cum[-1])))
    return order[np.searchsorted(cum, points, side="right") - 1]


@dataclass(frozen=True)
class Bins:
    """A weighted population cut into bins of neighbouring members (in the given order)."""

    members: tuple[Hashable, ...]
    weights: np.ndarray
    edges: tuple[int, ...]  # bin k holds members[edges[k]:edges[k + 1]]
    index: dict[Hashable, int] = field(repr=False, compare=False)  # member -> position

    @classmethod
    def cut(cls, counts: Sequence[tuple[Hashable, int]], n: int, min_members: int | None = None) -> "Bins":
        """Greedy cut of ordered (member, weight) pairs: each bin gets at least ``min_members``
        members (default 2N) and enough weight that no member's share exceeds 1/N."""
        if len(counts) < n:
            raise ValueError(f"a population of {len(counts)} members cannot give {n} distinct options")
        k_min = max(n, 2 * n if min_members is None else min_members)
        members = tuple(m for m, _ in counts)
        w = np.array([c for _, c in counts], dtype=float)
        edges, start = [0], 0
        for i in range(len(w)):
            size, mass, top = i + 1 - start, w[start:i + 1].sum(), w[start:i + 1].max()
            if size >= k_min and mass >= n * top:
                edges.append(i + 1)
                start = i + 1
        if edges[-1] != len(w):
            if len(edges) > 1:
                edges[-1] = len(w)  # the short tail joins the last bin
            else:
                edges.append(len(w))
        return cls(members, w, tuple(edges), {m: i for i, m in enumerate(members)})

    def __contains__(self, member: Hashable) -> bool:
        return member in self.index

    def draw(self, member: Hashable, n: int, rng: np.random.Generator) -> list:
        """N distinct members of ``member``'s bin, ``member`` first."""
        i = self.index[member]
        k = int(np.searchsorted(self.edges, i, side="right") - 1)
        lo, hi = self.edges[k], self.edges[k + 1]
        pi = inclusion_probabilities(self.weights[lo:hi], n)
        idx = systematic_sample(pi, i - lo, rng)
        out = [self.members[lo + int(i)] for i in idx]
        out.remove(member)
        return [member, *out]


def value_bins(values: Iterable[int], n: int) -> Bins:
    """Bins over the magnitudes of a pool's numeric answers (weighted by question count)."""
    counts = Counter(abs(int(v)) for v in values)
    return Bins.cut(sorted(counts.items()), n)


def numeric_options(value: int, bins: Bins | None, n: int, rng: np.random.Generator) -> list[int]:
    """N distinct values, ``value`` first, all of its sign (negative answers mirror the bins of
    their magnitude). Populations too small for bins fall back to :func:`lattice_options`."""
    if bins is None or abs(value) not in bins:
        return lattice_options(value, n, rng)
    drawn = bins.draw(abs(value), n, rng)
    if value < 0 and 0 in drawn:  # zero has no negative mirror
        return lattice_options(value, n, rng)
    return [-int(m) if value < 0 else int(m) for m in drawn]


def lattice_options(value: int, n: int, rng: np.random.Generator) -> list[int]:
    """N distinct values on a random lattice around ``value`` (fallback for rare formats): the
    offsets are drawn around a latent centre and the answer is a uniformly chosen member, so
    rank and spread are exchangeable (digit features only as far as the lattice step allows)."""
    span = max(LATTICE_SPREAD * n, abs(value) // 2)
    while True:
        offs = rng.choice(2 * span + 1, size=n, replace=False) - span
        vals = [int(value + o - offs[0]) for o in offs]
        if value >= 0 and min(vals) < 0 or value < 0 and max(vals) >= 0:
            continue
        return vals


def weighted_options(answer: Hashable, candidates: Sequence[tuple[Hashable, float]], answer_weight: float,
                     n: int, rng: np.random.Generator) -> list:
    """N distinct members, ``answer`` first: a PPS draw from the answer and the candidates, each
    weighted by how often it is an answer itself, conditioned on containing the answer."""
    members = [answer, *(c for c, _ in candidates)]
    pi = inclusion_probabilities(np.array([answer_weight, *(w for _, w in candidates)], dtype=float), n)
    idx = systematic_sample(pi, 0, rng)
    return [answer, *(members[int(i)] for i in idx if i != 0)]
