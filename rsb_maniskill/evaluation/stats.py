"""Statistics a reviewer can defend: intervals that count clusters, paired tests, many-cell corrections.

Episodes are not always independent: the counterfactual variants of one scene, or the episodes that
ask one question, move together, so an interval that counts them as independent is too narrow.
Such groups are *clusters*; :func:`clustered_rate` gives Wilson's interval at Kish's effective sample
size (``n`` over the :func:`design_effect`). Two runs of the same episodes (same suite and seed) are
*paired*: :func:`mcnemar` (exact, on the discordant pairs) compares rates and :func:`paired_bootstrap`
any statistic (nSG, a ratio of rates). :func:`holm` corrects the p-values of many cells at once.
numpy and scipy only: the reports and the audit import this.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Hashable, Sequence

import numpy as np

from rsb_maniskill.evaluation.metrics import Rate, wilson_interval

BOOTSTRAP_RESAMPLES = 2000  # paired bootstrap draws: the p-value's resolution is 1/2000
BOOTSTRAP_SEED = 0  # the bootstrap is seeded: a report is the same every time it is written


def design_effect(values: Sequence[float] | np.ndarray, clusters: Sequence[Hashable] | np.ndarray) -> float:
    """Cluster-robust variance of the mean of ``values`` over its variance were they independent, at
    least 1 (Kish's design effect estimated from the data: 1 for independent outcomes, up to the
    cluster size when a cluster's outcomes are all alike)."""
    values = np.asarray(values, dtype=float)
    n = len(values)
    _, group = np.unique(np.asarray(clusters), return_inverse=True)
    c = int(group.max()) + 1 if n else 0
    var = float(np.var(values)) if n else 0.0
    if c < 2 or var == 0:
        return 1.0
    resid = np.bincount(group, weights=values - values.mean(), minlength=c)
    robust = c / (c - 1) * float(np.sum(resid ** 2)) / n ** 2
    return max(1.0, robust / (var / n))


def clustered_rate(values: Sequence[bool] | np.ndarray, clusters: Sequence[Hashable] | np.ndarray) -> Rate:
    """The rate of ``values`` (0/1) with Wilson's 95 % interval at the effective sample size
    ``n / design_effect``: an interval over scenes, not over their variants."""
    values = np.asarray(values, dtype=float)
    n = len(values)
    if n == 0:
        return Rate(None, None, None)
    p = float(values.mean())
    n_eff = n / design_effect(values, clusters)
    lo, hi = wilson_interval(p * n_eff, n_eff)
    return Rate(p, lo, hi)


@dataclass(frozen=True)
class McNemar:
    """Two paired 0/1 outcomes: ``a_only`` pairs where only A succeeded, ``b_only`` only B; ``p`` the
    exact two-sided p-value (a binomial test of ``a_only`` among the discordant pairs at 1/2)."""

    n: int
    both: int
    a_only: int
    b_only: int
    neither: int
    p: float

    @property
    def difference(self) -> float | None:
        """Rate of A minus rate of B over the pairs (None without pairs)."""
        return (self.a_only - self.b_only) / self.n if self.n else None


def mcnemar(a: Sequence[bool], b: Sequence[bool]) -> McNemar:
    """Exact McNemar test of paired outcomes ``a[i]``, ``b[i]`` (the same episode under two runs)."""
    from scipy.stats import binomtest

    a, b = np.asarray(a, dtype=bool), np.asarray(b, dtype=bool)
    if a.shape != b.shape:
        raise ValueError(f"paired outcomes need equal lengths, got {a.shape} and {b.shape}")
    a_only, b_only = int(np.sum(a & ~b)), int(np.sum(~a & b))
    discordant = a_only + b_only
    p = 1.0 if discordant == 0 else float(binomtest(a_only, discordant, 0.5).pvalue)
    return McNemar(len(a), int(np.sum(a & b)), a_only, b_only, int(np.sum(~a & ~b)), p)


@dataclass(frozen=True)
class PairedDifference:
    """``statistic(A) - statistic(B)`` over paired rows, its 95 % bootstrap interval and two-sided p."""

    difference: float | None
    low: float | None
    high: float | None
    p: float | None
    resamples: int


def paired_bootstrap(a: np.ndarray, b: np.ndarray, statistic: Callable[[np.ndarray], float | None],
                     clusters: Sequence[Hashable] | None = None, resamples: int = BOOTSTRAP_RESAMPLES,
                     seed: int = BOOTSTRAP_SEED) -> PairedDifference:
    """Bootstrap of ``statistic(a) - statistic(b)`` where row ``i`` of ``a`` and of ``b`` are the same
    episode; rows are resampled together (by cluster when ``clusters`` is given: a scene's variants
    move together). ``statistic`` takes rows and returns a number or None (undefined, e.g. nSG
    without grasps); undefined draws are dropped. The p-value is the two-sided share of draws on
    the other side of 0 (percentile method), at least one draw's worth."""
    a, b = np.asarray(a), np.asarray(b)
    if len(a) != len(b):
        raise ValueError(f"paired rows need equal lengths, got {len(a)} and {len(b)}")
    full_a, full_b = statistic(a), statistic(b)
    if full_a is None or full_b is None or len(a) == 0:
        return PairedDifference(None, None, None, None, 0)
    groups = np.arange(len(a)) if clusters is None else np.unique(np.asarray(clusters), return_inverse=True)[1]
    members = [np.flatnonzero(groups == g) for g in range(int(groups.max()) + 1)]
    rng = np.random.default_rng(seed)
    diffs = []
    for _ in range(resamples):
        rows = np.concatenate([members[g] for g in rng.integers(0, len(members), len(members))])
        sa, sb = statistic(a[rows]), statistic(b[rows])
        if sa is not None and sb is not None:
            diffs.append(sa - sb)
    if not diffs:
        return PairedDifference(full_a - full_b, None, None, None, 0)
    d = np.asarray(diffs)
    lo, hi = (float(x) for x in np.percentile(d, [2.5, 97.5]))
    p = min(1.0, 2 * min(np.mean(d <= 0), np.mean(d >= 0)))
    return PairedDifference(full_a - full_b, lo, hi, max(float(p), 1.0 / len(d)), len(d))


def holm(pvalues: Sequence[float | None]) -> list[float | None]:
    """Holm's step-down adjusted p-values (None stays None): reject cell ``i`` at level alpha when its
    adjusted p is below alpha; the family-wise error stays at alpha over all the cells."""
    idx = [i for i, p in enumerate(pvalues) if p is not None]
    order = sorted(idx, key=lambda i: pvalues[i])
    m = len(order)
    out: list[float | None] = [None] * len(pvalues)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * float(pvalues[i])))
        out[i] = running
    return out


def confusion(chosen: Sequence[Hashable | None], correct: Sequence[Hashable], labels: Sequence[Hashable],
              ) -> dict[str, dict[str, int]]:
    """``{correct: {chosen: count}}`` over ``labels`` (rows: the correct value; columns: what was
    chosen, plus ``"none"`` for episodes where nothing was chosen). Keys are strings (JSON)."""
    cols = [*map(str, labels), "none"]
    table = {str(c): {k: 0 for k in cols} for c in labels}
    for ch, co in zip(chosen, correct):
        row = table.setdefault(str(co), {k: 0 for k in cols})
        row["none" if ch is None else str(ch)] = row.get("none" if ch is None else str(ch), 0) + 1
    return table
