"""Statistics a reviewer can defend: intervals that count clusters, paired tests that count scenes,
many-cell corrections, and how many episodes a claim needs.

Episodes are not always independent: the counterfactual variants of one scene, or the perturbed
episodes of one seed, move together, so an interval that counts them as independent is too narrow.
Such groups are *clusters*; :func:`clustered_rate` gives Wilson's interval at the effective sample
size (``n`` over the :func:`design_effect`), with Student's t quantile over the clusters. Two runs of
the same episodes (same suite and seed) are *paired*: :func:`scene_permutation` compares two rates
by flipping whole scenes between the runs (exact; McNemar's test when every scene is one episode),
:func:`mcnemar` is the exact test on independent pairs and :func:`paired_bootstrap` compares any
statistic of column means (nSG), drawing until its p-value's Monte Carlo error cannot move the
decision. :func:`holm` corrects the p-values of many cells at once. :func:`paired_sample_size` and
:func:`minimum_detectable_difference` say how many episodes a claim needs (Connor 1987, with the
design effect for clusters). numpy and scipy only: the reports and the audit import this.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable, Hashable, Sequence

import numpy as np

from rsb_maniskill.evaluation.metrics import Z95, Rate, wilson_interval

BOOTSTRAP_RESAMPLES = 2000  # paired bootstrap draws to start with
BOOTSTRAP_MAX_RESAMPLES = 256000  # at most this many while the p-value's Monte Carlo interval holds alpha
BOOTSTRAP_SEED = 0  # the bootstrap is seeded: a report is the same every time it is written
MC_Z = 3.29  # the p-value's Monte Carlo interval: 99.9 % (a mark decided outside it does not flip with the seed)
EXACT_SCENES = 16  # up to this many scenes a permutation test enumerates every flip (2^16 = 65,536)
PERMUTATIONS = 20000  # Monte Carlo flips a chunk beyond that, while the p-value's interval holds alpha
ALPHA, POWER = 0.05, 0.8  # a claim: two-sided 5 % test, 80 % power


# ---------------------------------------------------------------- clustered intervals
def _groups(clusters: Sequence[Hashable] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each value's cluster index, and the clusters' sizes."""
    if len(clusters) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    _, group = np.unique(np.asarray(clusters), return_inverse=True)
    return group, np.bincount(group)


def size_design_effect(sizes: Sequence[int] | np.ndarray) -> float:
    """The design effect of clusters whose members are all alike (intraclass correlation 1):
    ``sum(m_i^2) / n``, so the effective sample size is ``n^2 / sum(m_i^2)`` (the number of clusters
    when they are of one size). The most a design effect can be."""
    sizes = np.asarray(sizes, dtype=float)
    n = sizes.sum()
    return float((sizes ** 2).sum() / n) if n else 1.0


def design_effect(values: Sequence[float] | np.ndarray, clusters: Sequence[Hashable] | np.ndarray) -> float:
    """Cluster-robust variance of the mean of ``values`` over its variance were they independent:
    Kish's design effect estimated from the data, at least 1 (independent outcomes), about
    :func:`size_design_effect` when a cluster's outcomes are all alike (times the robust variance's
    small-sample ``c / (c - 1)``). Where the data cannot estimate it (one cluster, or every value
    alike: a rate of 0 % or 100 %) it is that bound: the clusters are counted, not their members."""
    values = np.asarray(values, dtype=float)
    n = len(values)
    group, sizes = _groups(clusters)
    c = len(sizes)
    bound = size_design_effect(sizes)
    if c < 2 or float(np.var(values)) == 0:
        return bound
    resid = np.bincount(group, weights=values - values.mean(), minlength=c)
    robust = c / (c - 1) * float(np.sum(resid ** 2)) / n ** 2
    return max(1.0, robust / (float(np.var(values)) / n))


@lru_cache(maxsize=4096)
def cluster_quantile(clusters: int) -> float:
    """The two-sided 95 % quantile for a rate over ``clusters`` clusters: Student's t with one degree
    of freedom fewer (the variance is estimated from that many), the normal's 1.96 for one cluster
    or independent outcomes (many clusters: t tends to it)."""
    from scipy.stats import t

    return Z95 if clusters < 2 else float(t.ppf(0.975, clusters - 1))


def clustered_rate(values: Sequence[bool] | np.ndarray, clusters: Sequence[Hashable] | np.ndarray) -> Rate:
    """The rate of ``values`` (0/1) with Wilson's 95 % interval at the effective sample size
    ``n / design_effect`` and Student's t quantile over the clusters: an interval over scenes, not
    over their variants. Ten scenes of four variants all followed: [72.2, 100] with the normal
    quantile, as ten episodes would; [66.1, 100] with t."""
    values = np.asarray(values, dtype=float)
    n = len(values)
    if n == 0:
        return Rate(None, None, None)
    p = float(values.mean())
    n_eff = n / design_effect(values, clusters)
    lo, hi = wilson_interval(p * n_eff, n_eff, cluster_quantile(len(_groups(clusters)[1])))
    return Rate(p, lo, hi)


# ---------------------------------------------------------------- paired tests
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
class ScenePermutation:
    """``rate(B) - rate(A)`` over scenes paired between two runs, and the two-sided p-value of
    flipping whole scenes between the runs. ``exact``: every flip enumerated (or the exact
    distribution of a sum); else ``p_low``..``p_high`` is the Monte Carlo p-value's 99.9 % interval."""

    difference: float | None
    p: float | None
    scenes: int
    exact: bool = True
    p_low: float | None = None
    p_high: float | None = None
    draws: int = 0

    @property
    def decided(self) -> bool:
        """Whether the p-value's Monte Carlo interval lies on one side of :data:`ALPHA`."""
        return self.exact or self.p_low is None or not self.p_low < ALPHA <= self.p_high


@lru_cache(maxsize=1024)
def _half_binomial(c: int) -> np.ndarray:
    """The Bin(c, 1/2) probabilities of 0..c."""
    from scipy.stats import binom

    return binom.pmf(np.arange(c + 1), c, 0.5)


def sign_flip_p(d: Sequence[int] | np.ndarray) -> float:
    """Exact two-sided p-value of ``sum(d)`` (integers, one per scene) against the distribution of
    ``sum(s_i d_i)`` with independent fair signs ``s_i``: a scene's episodes flip between the two
    runs together. With every ``|d_i|`` at most 1 it is McNemar's exact test. The ``c`` scenes of
    one magnitude ``j`` add ``j (2X - c)``, X binomial: one convolution a magnitude."""
    d = np.asarray(d, dtype=int)
    obs = abs(int(d.sum()))
    mags, counts = np.unique(np.abs(d[d != 0]), return_counts=True)
    if len(mags) == 0:
        return 1.0
    pmf = np.ones(1)  # over the values -total..total, total growing with each magnitude
    for j, c in zip(mags.tolist(), counts.tolist()):
        part = np.zeros(2 * j * c + 1)
        part[::2 * j] = _half_binomial(c)  # j (2x - c) for x = 0..c, from -jc
        pmf = np.convolve(pmf, part)
    total = (len(pmf) - 1) // 2
    values = np.abs(np.arange(-total, total + 1))
    return float(min(1.0, pmf[values >= obs].sum() * (1 + 1e-12)))


def scene_permutation(num_a: Sequence[float], den_a: Sequence[float], num_b: Sequence[float],
                      den_b: Sequence[float], seed: int = BOOTSTRAP_SEED) -> ScenePermutation:
    """Compare ``sum(num_b) / sum(den_b)`` with ``sum(num_a) / sum(den_a)`` (one entry per scene
    both runs played) by flipping whole scenes between A and B: under the null hypothesis that the
    runs are exchangeable within a scene, every flip is as likely. Where the denominators agree scene
    by scene (GSR, TSR: the same episodes) the difference is a sum of integers and the test is exact
    (:func:`sign_flip_p`); otherwise (follow, switch: each run's grasps decide its denominator) every
    flip is enumerated up to :data:`EXACT_SCENES` scenes, else drawn until the p-value's Monte Carlo
    interval leaves :data:`ALPHA` (at most 16 x :data:`PERMUTATIONS` flips)."""
    na, da, nb, db = (np.asarray(x, dtype=float) for x in (num_a, den_a, num_b, den_b))
    keep = (da + db) > 0
    na, da, nb, db = na[keep], da[keep], nb[keep], db[keep]
    c = len(na)
    if c == 0 or da.sum() == 0 or db.sum() == 0:
        return ScenePermutation(None, None, c)
    diff = float(nb.sum() / db.sum() - na.sum() / da.sum())
    if np.array_equal(da, db) and np.allclose(na, np.round(na)) and np.allclose(nb, np.round(nb)):
        return ScenePermutation(diff, sign_flip_p(np.round(nb - na).astype(int)), c)

    def flipped(swap: np.ndarray) -> np.ndarray:  # swap: (draws, c) of 0/1, 1 = the scene's runs exchanged
        keep_ = 1.0 - swap
        sb, sdb = keep_ @ nb + swap @ na, keep_ @ db + swap @ da
        sa, sda = keep_ @ na + swap @ nb, keep_ @ da + swap @ db
        with np.errstate(invalid="ignore", divide="ignore"):
            return sb / sdb - sa / sda  # nan: a draw where a run grasped nothing (left out)

    tol = 1e-12
    if c <= EXACT_SCENES:
        swaps = ((np.arange(2 ** c)[:, None] >> np.arange(c)) & 1).astype(float)
        t = flipped(swaps)
        t = t[np.isfinite(t)]
        return ScenePermutation(diff, float(np.mean(np.abs(t) >= abs(diff) - tol)), c)
    rng = np.random.default_rng(seed)
    hits = draws = 0
    rows = min(PERMUTATIONS, max(1000, 4_000_000 // c))  # a chunk: at most ~4M flips of a scene in memory
    while draws < 16 * PERMUTATIONS:
        t = flipped(rng.integers(0, 2, (rows, c)).astype(float))
        t = t[np.isfinite(t)]
        hits, draws = hits + int(np.sum(np.abs(t) >= abs(diff) - tol)), draws + len(t)
        p = (hits + 1) / (draws + 1)
        half = MC_Z * math.sqrt(p * (1 - p) / max(draws, 1))
        if not p - half < ALPHA <= p + half or not len(t):
            break
    return ScenePermutation(diff, p, c, exact=False, p_low=max(0.0, p - half), p_high=min(1.0, p + half),
                            draws=draws)


@dataclass(frozen=True)
class PairedDifference:
    """``statistic(a) - statistic(b)`` over paired rows, its 95 % bootstrap interval and two-sided p,
    with that p's Monte Carlo 99.9 % interval (``p_low``, ``p_high``)."""

    difference: float | None
    low: float | None
    high: float | None
    p: float | None
    resamples: int
    p_low: float | None = None
    p_high: float | None = None

    @property
    def decided(self) -> bool:
        """Whether the p-value's Monte Carlo interval lies on one side of :data:`ALPHA`."""
        return self.p_low is None or not self.p_low < ALPHA <= self.p_high


def paired_bootstrap(a: np.ndarray, b: np.ndarray, statistic: Callable[[np.ndarray], np.ndarray],
                     clusters: Sequence[Hashable] | None = None, resamples: int = BOOTSTRAP_RESAMPLES,
                     seed: int = BOOTSTRAP_SEED, max_resamples: int = BOOTSTRAP_MAX_RESAMPLES,
                     ) -> PairedDifference:
    """Bootstrap of ``statistic(a) - statistic(b)`` where row ``i`` of ``a`` and of ``b`` are the same
    episode; rows are resampled together (by cluster when ``clusters`` is given: a scene's variants
    move together). ``statistic`` maps column means, an array ``(..., k)``, to values (nan where
    undefined, e.g. nSG without grasps; such draws are dropped), so every draw is one matrix product.
    The p-value is the two-sided share of draws on the other side of 0 (percentile method); draws
    are added (doubling, up to ``max_resamples``) while its Monte Carlo 99.9 % interval holds
    :data:`ALPHA`, so a mark decided on it does not depend on the seed."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if len(a) != len(b):
        raise ValueError(f"paired rows need equal lengths, got {len(a)} and {len(b)}")
    if len(a) == 0:
        return PairedDifference(None, None, None, None, 0)
    a2, b2 = a.reshape(len(a), -1), b.reshape(len(b), -1)
    full = statistic(a2.mean(0)) - statistic(b2.mean(0))
    if not np.all(np.isfinite(full)):
        return PairedDifference(None, None, None, None, 0)
    group = np.arange(len(a)) if clusters is None else _groups(clusters)[0]
    c = int(group.max()) + 1
    sums_a = np.stack([np.bincount(group, weights=col, minlength=c) for col in a2.T], axis=1)
    sums_b = np.stack([np.bincount(group, weights=col, minlength=c) for col in b2.T], axis=1)
    sizes = np.bincount(group, minlength=c).astype(float)
    rng = np.random.default_rng(seed)
    diffs: list[np.ndarray] = []
    todo, drawn = resamples, 0
    while True:
        for start in range(0, todo, 2000):  # chunks: a (draws x clusters) weight matrix each
            w = rng.multinomial(c, np.full(c, 1.0 / c), size=min(2000, todo - start)).astype(float)
            n = (w @ sizes)[:, None]
            with np.errstate(invalid="ignore", divide="ignore"):
                d = statistic(w @ sums_a / n) - statistic(w @ sums_b / n)
            diffs.append(np.asarray(d, dtype=float).reshape(-1))
        drawn += todo
        d = np.concatenate(diffs)
        d = d[np.isfinite(d)]
        if len(d) == 0:
            return PairedDifference(float(full), None, None, None, 0)
        share = min(np.mean(d <= 0), np.mean(d >= 0))
        p = max(min(1.0, 2 * float(share)), 1.0 / len(d))
        half = 2 * MC_Z * math.sqrt(max(share * (1 - share), 0.25 / len(d)) / len(d))
        if not p - half < ALPHA <= p + half or drawn >= max_resamples:
            break
        todo = min(drawn, max_resamples - drawn)
    lo, hi = (float(x) for x in np.percentile(d, [2.5, 97.5]))
    return PairedDifference(float(full), lo, hi, p, len(d), max(0.0, p - half), min(1.0, p + half))


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


# ---------------------------------------------------------------- how many episodes a claim needs
def _z(q: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(q))


def paired_sample_size(p_a: float, p_b: float, alpha: float = ALPHA, power: float = POWER,
                       design: float = 1.0) -> int | None:
    """Episodes each run needs (the same episodes in both) for a two-sided paired test at ``alpha``
    to tell ``p_a`` from ``p_b`` with probability ``power``: Connor's (1987) McNemar sample size over
    the discordant share ``psi = p_a (1 - p_b) + p_b (1 - p_a)`` (the runs' outcomes on an episode
    taken as independent: any positive correlation between them only shrinks it), times the
    ``design`` effect of clustered episodes. None when the rates are equal."""
    delta = abs(p_b - p_a)
    if delta == 0:
        return None
    psi = p_a * (1 - p_b) + p_b * (1 - p_a)
    za, zb = _z(1 - alpha / 2), _z(power)
    n = (za * math.sqrt(psi) + zb * math.sqrt(max(psi - delta ** 2, 0.0))) ** 2 / delta ** 2
    return max(1, math.ceil(n * design))


def unpaired_sample_size(p_a: float, p_b: float, alpha: float = ALPHA, power: float = POWER,
                         design: float = 1.0) -> int | None:
    """Episodes each run needs when the two runs share no episode (two published rows on other
    seeds): the two-proportion sample size, times the ``design`` effect. None when the rates are equal."""
    delta = abs(p_b - p_a)
    if delta == 0:
        return None
    bar = (p_a + p_b) / 2
    za, zb = _z(1 - alpha / 2), _z(power)
    n = (za * math.sqrt(2 * bar * (1 - bar)) + zb * math.sqrt(p_a * (1 - p_a) + p_b * (1 - p_b))) ** 2 / delta ** 2
    return max(1, math.ceil(n * design))


def mcnemar_power(p_a: float, p_b: float, n: int, alpha: float = ALPHA) -> float:
    """The exact probability that McNemar's exact test at ``alpha`` rejects on ``n`` paired episodes
    when run A succeeds with probability ``p_a``, run B with ``p_b``, independently on each episode:
    over the number ``d`` of discordant pairs, the binomial test's rejection region (``k`` of them
    won by A with ``2 P(X <= k) < alpha`` under X ~ Bin(d, 1/2), or the mirror)."""
    from scipy.stats import binom

    psi = p_a * (1 - p_b) + p_b * (1 - p_a)
    if psi == 0 or n < 1:
        return 0.0
    share = p_a * (1 - p_b) / psi  # of a discordant pair: A won
    d = np.arange(1, n + 1)
    crit = binom.ppf(alpha / 2, d, 0.5)  # the smallest k with P(X <= k) >= alpha / 2: reject below it
    crit = np.where(binom.cdf(crit, d, 0.5) < alpha / 2, crit + 1, crit)  # float round-off at the edge
    reject = binom.cdf(crit - 1, d, share) + binom.sf(d - crit, d, share)
    return float(np.sum(binom.pmf(d, n, psi) * np.where(crit >= 1, reject, 0.0)))


def clustered_power(p_a: float, p_b: float, scenes: int, size: int, icc: float, alpha: float = ALPHA,
                    sims: int = 1000, seed: int = 0) -> float:
    """The share of simulated run pairs on which the scene test (:func:`sign_flip_p`) rejects at
    ``alpha``: ``scenes`` scenes of ``size`` episodes each, each run's success probability a scene
    drawn from a beta law of mean ``p_a`` (``p_b``) and intraclass correlation ``icc``."""
    rng = np.random.default_rng(seed)
    if icc > 0:
        s = 1 / icc - 1
        qa = rng.beta(max(p_a, 1e-9) * s, max(1 - p_a, 1e-9) * s, (sims, scenes))
        qb = rng.beta(max(p_b, 1e-9) * s, max(1 - p_b, 1e-9) * s, (sims, scenes))
    else:
        qa, qb = np.full((sims, scenes), p_a), np.full((sims, scenes), p_b)
    d = rng.binomial(size, qb) - rng.binomial(size, qa)
    return float(np.mean([sign_flip_p(row) < alpha for row in d]))


@dataclass(frozen=True)
class Plan:
    """What a claim needs: ``scenes`` of ``size`` episodes each (``episodes`` in all) per run, and the
    power that the test reaches there (exact, or simulated where ``simulated``)."""

    scenes: int
    size: int
    episodes: int
    power: float
    simulated: bool


def plan_episodes(p_a: float, p_b: float, alpha: float = ALPHA, power: float = POWER, size: int = 1,
                  icc: float = 0.0, seed: int = 0) -> Plan | None:
    """The fewest scenes (of ``size`` episodes sharing a scene, at intraclass correlation ``icc``)
    each run needs for the paired scene test at ``alpha`` to tell ``p_a`` from ``p_b`` with
    probability ``power``: Connor's formula with the design effect ``1 + (size - 1) icc`` to start,
    then stepped up until the test's power (exact for independent episodes, else simulated with
    2,000 run pairs) reaches ``power`` (the exact tests are conservative: the formula alone falls
    2-5 points short). None when the rates are equal."""
    design = 1 + (size - 1) * icc
    n = paired_sample_size(p_a, p_b, alpha, power, design)
    if n is None:
        return None
    simulated = size > 1

    def reach(scenes: int) -> float:
        return (clustered_power(p_a, p_b, scenes, size, icc, alpha, 2000, seed) if simulated
                else mcnemar_power(p_a, p_b, scenes, alpha))

    low, high = None, max(2, math.ceil(n / size))
    while reach(high) < power:  # grow 10 % at a time past the formula's answer
        low, high = high, math.ceil(high * 1.1)
    while low is not None and high - low > 1:  # then the fewest scenes that reach it, between a miss and a hit
        mid = (low + high) // 2
        low, high = (low, mid) if reach(mid) >= power else (mid, high)
    return Plan(high, size, high * size, reach(high), simulated)


def minimum_detectable_difference(p: float, n: int, alpha: float = ALPHA, power: float = POWER,
                                  design: float = 1.0) -> float | None:
    """The smallest difference from a rate ``p`` that a paired comparison on ``n`` episodes (as
    :func:`paired_sample_size`) detects with probability ``power``: the larger of the differences up
    and down from ``p`` (the harder direction), where that stays within [0, 1]. None when no
    difference within [0, 1] can be told at this ``n``."""
    if n < 1:
        return None
    found = []
    for sign in (1, -1):
        room = 1 - p if sign > 0 else p
        if room <= 0 or (paired_sample_size(p, p + sign * room, alpha, power, design) or n + 1) > n:
            continue
        lo, hi = 0.0, room  # bisect: need(lo) > n >= need(hi)
        for _ in range(40):
            mid = (lo + hi) / 2
            if paired_sample_size(p, p + sign * mid, alpha, power, design) <= n:
                hi = mid
            else:
                lo = mid
        found.append(hi)
    return max(found) if found else None


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
