"""Statistics a reviewer can defend: intervals that count clusters, paired and unpaired tests,
one rule for a page of many marks, and how many episodes a claim needs, from the power of the
test that is actually run.

Episodes are not always independent: the counterfactual variants of one scene, or the perturbed
episodes of one seed, move together, so an interval that counts them as independent is too narrow.
Such groups are *clusters*; :func:`clustered_rate` gives Wilson's interval at the effective sample
size (``n`` over the :func:`design_effect`), with Student's t quantile over the clusters. Two runs of
the same episodes (same suite and seed) are *paired*: :func:`scene_permutation` compares two rates
by flipping whole scenes between the runs (exact; McNemar's test when every scene is one episode),
:func:`mcnemar` is the exact test on independent pairs. Two runs on other episodes are compared by
:func:`two_proportions` (the pooled two-proportion z test). A page that marks many tests controls
its family-wise error with Holm's step-down correction (:func:`holm`, :func:`holm_marks`).
:func:`mcnemar_power`, :func:`unpaired_power` and :func:`scene_power` are those tests' power (the
first two exact, the scene test's simulated); :func:`plan_paired`, :func:`plan_unpaired`,
:func:`plan_scenes` the fewest episodes that reach a power, and
:func:`minimum_detectable_difference` the smallest difference a run can detect. numpy and scipy
only: the reports and the audit import this.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable, Hashable, Sequence

import numpy as np

from rsb_maniskill.evaluation.metrics import Z95, Rate, wilson_interval

PERMUTATION_SEED = 0  # Monte Carlo permutations are seeded: a report is the same every time it is written
MC_Z = 3.29  # a Monte Carlo p-value's interval: 99.9 % (a mark decided outside it does not flip with the seed)
EXACT_SCENES = 16  # up to this many scenes a permutation test enumerates every flip (2^16 = 65,536)
PERMUTATIONS = 20000  # Monte Carlo flips a chunk beyond that, while the p-value's interval holds a level
MAX_PERMUTATIONS = 16 * PERMUTATIONS  # the most flips one test draws: its cost is bounded
ALPHA, POWER = 0.05, 0.8  # a claim: two-sided 5 % test, 80 % power
MAX_EPISODES = 1_000_000  # the most episodes a run a plan answers with; beyond, "more than" that
PLAN_SIMS = 10_000  # simulated run pairs behind a simulated power
PLAN_MC_Z = 3.0  # a simulated power reaches a target when the estimate less 3 standard errors does


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
    from scipy.special import stdtrit

    return Z95 if clusters < 2 else float(stdtrit(clusters - 1, 0.975))


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
    return _binom_pmf(np.arange(c + 1), c, 0.5)


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
                      den_b: Sequence[float], seed: int = PERMUTATION_SEED,
                      levels: Sequence[float] = (ALPHA,)) -> ScenePermutation:
    """Compare ``sum(num_b) / sum(den_b)`` with ``sum(num_a) / sum(den_a)`` (one entry per scene
    both runs played) by flipping whole scenes between A and B: under the null hypothesis that the
    runs are exchangeable within a scene, every flip is as likely. Where the denominators agree scene
    by scene (GSR, TSR: the same episodes) the difference is a sum of integers and the test is exact
    (:func:`sign_flip_p`); otherwise (follow, switch, nSG's share of grasps on the target: each run's
    grasps decide its denominator) every flip of the scenes that differ is enumerated up to
    :data:`EXACT_SCENES` of them, else drawn until the p-value's Monte Carlo interval holds none of
    ``levels`` (the thresholds a family's correction may compare it with), at most
    :data:`MAX_PERMUTATIONS` flips. Scenes alike in both runs flip to themselves and are left out
    of the flips (not of ``scenes``). With fewer than 6 scenes that differ no p is below 1/32."""
    na, da, nb, db = (np.asarray(x, dtype=float) for x in (num_a, den_a, num_b, den_b))
    keep = (da + db) > 0
    na, da, nb, db = na[keep], da[keep], nb[keep], db[keep]
    c = len(na)
    if c == 0 or da.sum() == 0 or db.sum() == 0:
        return ScenePermutation(None, None, c)
    diff = float(nb.sum() / db.sum() - na.sum() / da.sum())
    if np.array_equal(da, db) and np.allclose(na, np.round(na)) and np.allclose(nb, np.round(nb)):
        return ScenePermutation(diff, sign_flip_p(np.round(nb - na).astype(int)), c)
    moves = (na != nb) | (da != db)  # a scene alike in both runs adds the same to both sums under any flip
    fa, fda, fb, fdb = na[moves], da[moves], nb[moves], db[moves]
    sa0, sda0 = float(na[~moves].sum()), float(da[~moves].sum())
    k = int(moves.sum())

    def flipped(swap: np.ndarray) -> np.ndarray:  # swap: (draws, k) of 0/1, 1 = the scene's runs exchanged
        keep_ = 1.0 - swap
        sb, sdb = keep_ @ fb + swap @ fa + sa0, keep_ @ fdb + swap @ fda + sda0
        sa, sda = keep_ @ fa + swap @ fb + sa0, keep_ @ fda + swap @ fdb + sda0
        with np.errstate(invalid="ignore", divide="ignore"):
            return sb / sdb - sa / sda  # nan: a draw where a run grasped nothing (left out)

    tol = 1e-12
    if k <= EXACT_SCENES:
        swaps = ((np.arange(2 ** k)[:, None] >> np.arange(k)) & 1).astype(float)
        t = flipped(swaps)
        t = t[np.isfinite(t)]
        return ScenePermutation(diff, float(np.mean(np.abs(t) >= abs(diff) - tol)), c)
    rng = np.random.default_rng(seed)
    hits = draws = flips = 0
    rows = min(PERMUTATIONS, max(1000, 4_000_000 // k))  # a chunk: at most ~4M flips of a scene in memory
    while flips < MAX_PERMUTATIONS:
        bits = rng.integers(0, 256, (min(rows, MAX_PERMUTATIONS - flips), (k + 7) // 8), dtype=np.uint8)
        flips += len(bits)
        t = flipped(np.unpackbits(bits, axis=1, count=k).astype(float))
        t = t[np.isfinite(t)]
        hits, draws = hits + int(np.sum(np.abs(t) >= abs(diff) - tol)), draws + len(t)
        p = (hits + 1) / (draws + 1)
        half = MC_Z * math.sqrt(p * (1 - p) / max(draws, 1))
        if not any(p - half < level <= p + half for level in levels) or not len(t):
            break
    return ScenePermutation(diff, p, c, exact=False, p_low=max(0.0, p - half), p_high=min(1.0, p + half),
                            draws=draws)


MIN_EXPECTED = 5  # the z test's rule: at least this many expected successes and failures in each run


def two_proportions(k_a: int, n_a: int, k_b: int, n_b: int) -> float | None:
    """Two-sided p-value of the pooled two-proportion z test (Pearson's chi-square without
    continuity correction) of ``k_b / n_b`` against ``k_a / n_a``: runs on other episodes, nothing to
    pair. None (no test) where either run expects fewer than :data:`MIN_EXPECTED` successes or
    failures at the pooled rate: there the normal approximation's size is not its alpha."""
    from scipy.special import ndtr

    if n_a < 1 or n_b < 1:
        return None
    pooled = (k_a + k_b) / (n_a + n_b)
    if min(n_a, n_b) * min(pooled, 1 - pooled) < MIN_EXPECTED:
        return None
    z = abs(k_b / n_b - k_a / n_a) / math.sqrt(pooled * (1 - pooled) * (1 / n_a + 1 / n_b))
    return float(min(1.0, 2 * ndtr(-z)))


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


@dataclass(frozen=True)
class FamilyMark:
    """One test of a family after :func:`holm_marks`: its Holm-adjusted p, whether it is
    significant, and whether that is decided (a Monte Carlo p whose interval straddles its Holm
    threshold is not: the table prints ``?``)."""

    p_holm: float | None
    significant: bool
    decided: bool = True


def holm_marks(tests: Sequence[tuple[float | None, float | None, float | None]], alpha: float = ALPHA,
               ) -> list[FamilyMark]:
    """Holm's correction over one page's tests, each ``(p, p_low, p_high)`` (the Monte Carlo interval
    of a drawn p, else None, None). A test is significant where its adjusted p is below ``alpha``;
    decided where the same holds at the low and the high ends of every drawn interval (Holm's
    rejections only grow as p-values shrink, so the two ends bound every value in between)."""
    ps = [t[0] for t in tests]
    lows = [t[0] if t[1] is None else t[1] for t in tests]
    highs = [t[0] if t[2] is None else t[2] for t in tests]
    adjusted, low, high = holm(ps), holm(lows), holm(highs)
    return [FamilyMark(a, a is not None and a < alpha,
                       a is None or (lo is not None and hi is not None and (lo < alpha) == (hi < alpha)))
            for a, lo, hi in zip(adjusted, low, high)]


# ---------------------------------------------------------------- the power of the tests that are run
def _binom_pmf(k: np.ndarray | float, n: np.ndarray | float, p: float) -> np.ndarray:
    """Bin(n, p) probabilities of ``k`` (0 outside 0..n), from scipy.special (quick to import)."""
    from scipy.special import gammaln, xlog1py, xlogy

    k, n = np.asarray(k, dtype=float), np.asarray(n, dtype=float)
    inside = (k >= 0) & (k <= n)
    kk = np.clip(k, 0, n)
    log = gammaln(n + 1) - gammaln(kk + 1) - gammaln(n - kk + 1) + xlogy(kk, p) + xlog1py(n - kk, -p)
    return np.where(inside, np.exp(log), 0.0)


def _binom_cdf(k: np.ndarray | float, n: np.ndarray | float, p: float) -> np.ndarray:
    """P(X <= k) for X ~ Bin(n, p): 0 below 0, 1 from n on."""
    from scipy.special import bdtr

    k, n = np.floor(np.asarray(k, dtype=float)), np.asarray(n, dtype=float)
    if p <= 0 or p >= 1:
        return np.where(k < 0, 0.0, np.where(k >= n, 1.0, float(p <= 0)))
    kk, nn = np.broadcast_arrays(np.clip(k, 0, n).astype(np.int64), n.astype(np.int64))
    return np.where(k < 0, 0.0, np.where(k >= n, 1.0, bdtr(kk, nn, p)))


def _window(n: int, rate: float, width: float = 9.0) -> tuple[int, int]:
    """The counts 0..n of a Bin(n, rate) outside which less than ~1e-18 of its mass lies."""
    sd = math.sqrt(n * rate * (1 - rate))
    return max(0, math.floor(n * rate - width * sd - 1)), min(n, math.ceil(n * rate + width * sd + 1))


def _mcnemar_critical(d: np.ndarray, alpha: float) -> np.ndarray:
    """For ``d`` discordant pairs, the count of A-only pairs ``k`` below which the exact test rejects
    (``2 P(X <= k) < alpha``, X ~ Bin(d, 1/2)); by symmetry it also rejects above ``d - crit``."""
    from scipy.special import ndtri

    d = np.asarray(d, dtype=float)
    crit = np.clip(np.floor(d / 2 + ndtri(alpha / 2) * np.sqrt(d) / 2), 0, d)  # the normal's guess: then stepped
    while True:  # to the smallest k with P(X <= k) >= alpha / 2 (a few steps from the guess)
        down = (crit > 0) & (_binom_cdf(crit - 1, d, 0.5) >= alpha / 2)
        up = _binom_cdf(crit, d, 0.5) < alpha / 2
        if not down.any() and not up.any():
            return crit
        crit = crit - down + up


_BLOCK = 256  # discordant counts whose rejection probabilities are computed (and cached) together


@lru_cache(maxsize=1024)
def _critical_block(alpha: float, block: int) -> np.ndarray:
    """:func:`_mcnemar_critical` of one block of discordant counts (cached: it depends on alpha alone)."""
    return _mcnemar_critical(np.maximum(np.arange(block * _BLOCK, (block + 1) * _BLOCK, dtype=float), 1), alpha)


@lru_cache(maxsize=4096)
def _mcnemar_rejects(share: float, alpha: float, block: int) -> np.ndarray:
    """For d = block * _BLOCK ... (block + 1) * _BLOCK - 1 discordant pairs, each won by A with
    probability ``share``: the probability that the exact test at ``alpha`` rejects (cached: a plan's
    search asks for the same d at many n)."""
    d = np.arange(block * _BLOCK, (block + 1) * _BLOCK, dtype=float)
    crit = _critical_block(alpha, block)
    reject = _binom_cdf(crit - 1, d, share) + 1 - _binom_cdf(d - crit, d, share)
    return np.where((crit >= 1) & (d >= 1), reject, 0.0)


def mcnemar_power(p_a: float, p_b: float, n: int, alpha: float = ALPHA) -> float:
    """The exact probability that McNemar's exact test at ``alpha`` rejects on ``n`` paired episodes
    when run A succeeds with probability ``p_a``, run B with ``p_b``, independently on each episode:
    the sum over the number ``d ~ Bin(n, psi)`` of discordant pairs (``psi = p_a (1 - p_b) + p_b
    (1 - p_a)``) of the binomial test's rejection probability on ``d`` (``k`` of them won by A with
    ``2 P(X <= k) < alpha`` under X ~ Bin(d, 1/2), or the mirror). Under 6 discordant pairs a test at
    0.05 cannot reject: n < 6 has power 0. Counts where Bin(n, psi) has no mass (< 1e-18) are skipped."""
    psi = p_a * (1 - p_b) + p_b * (1 - p_a)
    if psi <= 0 or n < 1:
        return 0.0
    share = p_a * (1 - p_b) / psi  # of a discordant pair: A won
    lo, hi = _window(n, psi)
    lo = max(1, lo)
    if hi < lo:
        return 0.0
    first, last = lo // _BLOCK, hi // _BLOCK
    reject = np.concatenate([_mcnemar_rejects(share, alpha, b) for b in range(first, last + 1)])
    d = np.arange(lo, hi + 1)
    return float(min(1.0, np.sum(_binom_pmf(d, n, psi) * reject[d - first * _BLOCK])))


def unpaired_power(p_a: float, p_b: float, n: int, alpha: float = ALPHA) -> float:
    """The exact probability that :func:`two_proportions` rejects at ``alpha`` with ``n`` episodes in
    each run, A succeeding with probability ``p_a`` and B with ``p_b``: for each count ``x`` of A, the
    counts ``u`` of B where it rejects lie outside the two roots of a quadratic (``|z| > z_alpha``,
    squared) and where both runs expect enough successes and failures (``x + u`` within
    ``2 MIN_EXPECTED .. 2n - 2 MIN_EXPECTED``), so the power is one sum over ``x``."""
    from scipy.special import ndtri

    if n < 1:
        return 0.0
    lo, hi = _window(n, p_a)
    x = np.arange(lo, hi + 1, dtype=float)
    k = ndtri(alpha / 2) ** 2 / (2 * n)
    # (u - x)^2 > k (x + u)(2n - x - u): (1 + k) u^2 - (2x + k (2n - 2x)) u + x^2 - k x (2n - x) > 0
    qa, qb, qc = 1 + k, -(2 * x + k * (2 * n - 2 * x)), x * x - k * x * (2 * n - x)
    root = np.sqrt(np.maximum(qb * qb - 4 * qa * qc, 0.0))
    r1, r2 = (-qb - root) / (2 * qa), (-qb + root) / (2 * qa)
    least, most = np.maximum(0, 2 * MIN_EXPECTED - x), np.minimum(n, 2 * n - 2 * MIN_EXPECTED - x)

    def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # P(a <= u <= b), u ~ Bin(n, p_b)
        return np.where(b >= a, _binom_cdf(b, n, p_b) - _binom_cdf(a - 1, n, p_b), 0.0)

    reject = between(least, np.minimum(np.ceil(r1) - 1, most)) + between(np.maximum(np.floor(r2) + 1, least), most)
    return float(min(1.0, np.sum(_binom_pmf(x, n, p_a) * reject)))


def sign_flip_pvalues(d: np.ndarray) -> np.ndarray:
    """:func:`sign_flip_p` of every row of ``d`` (runs x scenes, integers) at once: the scene test of
    many simulated run pairs (``scene_power``, the tests). Equal to it within 1e-12."""
    d = np.asarray(d, dtype=np.int64)
    mags = np.abs(d)
    top = int(mags.max(initial=0))
    counts = np.stack([(mags == j).sum(1) for j in range(1, top + 1)], 1) if top else np.zeros((len(d), 0))
    return _sign_flip_from_counts(counts, np.abs(d.sum(1)))


def _sign_flip_from_counts(counts: np.ndarray, obs: np.ndarray, chunk: int = 1000) -> np.ndarray:
    """Exact two-sided sign-flip p-values from ``counts[r, j-1]``, the scenes of run pair ``r`` whose
    difference has magnitude ``j``, and ``obs[r] = |sum of the differences|``. Under the flips the sum
    is ``2U - M`` with ``U = sum_j j X_j``, X_j ~ Bin(c_j, 1/2) and ``M = sum_j j c_j``; U's law is
    read from its characteristic function ``prod_j ((1 + e^{ijt}) / 2)^{c_j}`` by one inverse FFT a
    row (rows of similar M share a chunk)."""
    sims = len(obs)
    out = np.ones(sims)
    if counts.shape[1] == 0:
        return out
    j = np.arange(1, counts.shape[1] + 1)
    counts = counts.astype(float)
    total = counts @ j
    order = np.argsort(total, kind="stable")
    for start in range(0, sims, chunk):
        rows = order[start:start + chunk]
        c, m, o = counts[rows], total[rows], obs[rows]
        size = 1 << int(math.ceil(math.log2(m.max() + 2)))  # U in 0..M: no wrap-around
        k = np.arange(size // 2 + 1)
        half = np.cos(np.pi * np.outer(j, k) / size)  # (1 + e^{ijt}) / 2 = e^{ijt/2} cos(jt/2), t = 2 pi k / size
        real = np.exp(c @ np.log(np.maximum(np.abs(half), 1e-300)))
        real *= 1 - 2 * ((c @ (half < 0)) % 2)
        # the phase e^{-iMt/2} (irfft sums e^{+iut}: the conjugate), from a table of the 2 size roots of unity
        turn = np.exp(-1j * np.pi * np.arange(2 * size) / size)
        pmf = np.fft.irfft(real * turn[np.outer(m.astype(np.int64), k) % (2 * size)], n=size, axis=1)
        # reject |2U - M| >= obs: U <= (M - obs) / 2 or U >= (M + obs) / 2; by symmetry twice one tail
        upper = np.ceil((m + o) / 2 - 1e-9).astype(int)
        p = 2 * np.sum(np.where(np.arange(size) >= upper[:, None], pmf, 0.0), axis=1)
        p = np.where(o == 0, 1.0, p)
        out[rows] = np.clip(p * (1 + 1e-12), 0.0, 1.0)
    return out


def scene_difference(p_a: float, p_b: float, size: int, icc: float) -> tuple[np.ndarray, np.ndarray]:
    """The law of a scene's difference ``d = X_b - X_a`` (values -size..size and their
    probabilities): each run's ``size`` counted episodes of a scene succeed with a probability drawn
    from a beta law of mean ``p_a`` (``p_b``) and intraclass correlation ``icc``: binomial at ICC 0,
    all or none of them at ICC 1 (beta-binomial between)."""
    from scipy.special import betaln, gammaln

    k = np.arange(size + 1)

    def law(p: float) -> np.ndarray:
        if p <= 0 or p >= 1 or icc <= 0:
            return _binom_pmf(k, size, p)
        if icc >= 1:
            out = np.zeros(size + 1)
            out[0], out[-1] = 1 - p, p
            return out
        s = 1 / icc - 1
        a, b = p * s, (1 - p) * s
        return np.exp(gammaln(size + 1) - gammaln(k + 1) - gammaln(size - k + 1) + betaln(k + a, size - k + b)
                      - betaln(a, b))

    pmf = np.convolve(law(p_b), law(p_a)[::-1])  # d = -size..size
    pmf = np.clip(pmf, 0.0, None)
    return np.arange(-size, size + 1), pmf / pmf.sum()


def scene_power(p_a: float, p_b: float, scenes: int, size: int, icc: float, alpha: float = ALPHA,
                sims: int = PLAN_SIMS, seed: int = 0) -> tuple[float, float]:
    """The share of ``sims`` simulated run pairs on which the exact scene test (:func:`sign_flip_p`,
    what ``rsb report --compare`` runs) rejects at ``alpha``, and its Monte Carlo standard error:
    ``scenes`` scenes of ``size`` counted episodes, drawn as :func:`scene_difference` says (a
    scene's differences are independent of other scenes', so a run pair's are one multinomial draw)."""
    values, pmf = scene_difference(p_a, p_b, size, icc)
    counts = np.random.default_rng(seed).multinomial(scenes, pmf, size=sims)
    obs = np.abs(counts @ values)
    mags = counts[:, size + 1:] + counts[:, size - 1::-1]  # magnitudes 1..size
    hits = _sign_flip_from_counts(mags, obs) < alpha
    est = float(hits.mean())
    return est, math.sqrt(max(est * (1 - est), 1.0 / sims) / sims)


def _scene_power_normal(values: np.ndarray, pmf: np.ndarray, scenes: float, alpha: float) -> float:
    """The scene test's power by the normal approximation of its statistic ``sum d / sqrt(sum d^2)``
    (delta method over a scene's moments): the search's starting point, and the answer where
    simulating would cost too much (many scenes, where the approximation is close)."""
    from scipy.special import ndtr, ndtri

    mu, m2, m3, m4 = (float(pmf @ values ** i) for i in (1, 2, 3, 4))
    if m2 <= 0:
        return 0.0
    var = m2 - mu * mu
    sd = math.sqrt(max(var / m2 + mu * mu * (m4 - m2 * m2) / (4 * m2 ** 3) - mu * (m3 - mu * m2) / m2 ** 2, 1e-12))
    shift, z = math.sqrt(scenes) * mu / math.sqrt(m2), -ndtri(alpha / 2)
    return float(ndtr((shift - z) / sd) + ndtr((-shift - z) / sd))


# ---------------------------------------------------------------- how many episodes a claim needs
@dataclass(frozen=True)
class Plan:
    """What a claim needs: ``scenes`` of ``size`` episodes each per run (None: more than
    :data:`MAX_EPISODES` episodes), and the power the test reaches there, ``how`` it was found."""

    scenes: int | None
    size: int
    power: float | None
    how: str  # "exact", "simulated" or "normal approximation"

    @property
    def episodes(self) -> int | None:
        return None if self.scenes is None else self.scenes * self.size


def _fewest(reaches: Callable[[int], bool], start: int, cap: int, step: float = 0.1) -> int | None:
    """The smallest n in [1, cap] where ``reaches(n)``, searched from ``start`` both ways: down while
    it reaches, up while it does not (steps of ``step`` times n), then bisected between the last miss
    and the first hit. None when ``cap`` does not reach."""
    seen: dict[int, bool] = {}

    def hit(n: int) -> bool:
        if n not in seen:
            seen[n] = reaches(n)
        return seen[n]

    n = min(max(1, start), cap)
    if hit(n):
        lo, hi = None, n
        while lo is None and hi > 1:
            down = max(1, int(hi * step))
            lo, hi = (None, hi - down) if hit(hi - down) else (hi - down, hi)
        if lo is None:
            return 1
    else:
        lo, hi = n, None
        while hi is None:
            if lo >= cap:
                return None
            up = min(cap, lo + max(1, int(lo * step)))
            lo, hi = (lo, up) if hit(up) else (up, None)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if hit(mid) else (mid, hi)
    return hi


def _connor(p_a: float, p_b: float, alpha: float, power: float) -> float:
    """Connor's (1987) McNemar sample size: the search's starting point."""
    from scipy.special import ndtri

    delta = abs(p_b - p_a)
    psi = p_a * (1 - p_b) + p_b * (1 - p_a)
    za, zb = -ndtri(alpha / 2), ndtri(power)
    return (za * math.sqrt(psi) + zb * math.sqrt(max(psi - delta ** 2, 0.0))) ** 2 / delta ** 2


def plan_paired(p_a: float, p_b: float, alpha: float = ALPHA, power: float = POWER, size: int = 1) -> Plan:
    """The fewest paired episodes (``size`` > 1: scenes whose ``size`` episodes all go one way) for
    McNemar's exact test at ``alpha`` to tell ``p_a`` from ``p_b`` with probability ``power``, its power
    computed exactly (:func:`mcnemar_power`), searched both ways from Connor's formula. The two runs'
    outcomes on an episode are taken as independent (runs that fail the same episodes need fewer)."""
    if p_a == p_b:
        raise ValueError("equal rates: no number of episodes tells a rate from itself")
    cap = MAX_EPISODES // size
    n = _fewest(lambda m: mcnemar_power(p_a, p_b, m, alpha) >= power,
                math.ceil(min(_connor(p_a, p_b, alpha, power), 2 * cap)), cap)
    return Plan(n, size, None if n is None else mcnemar_power(p_a, p_b, n, alpha), "exact")


def plan_unpaired(p_a: float, p_b: float, alpha: float = ALPHA, power: float = POWER) -> Plan:
    """The fewest episodes each of two runs on other episodes needs for :func:`two_proportions` at
    ``alpha`` to tell ``p_a`` from ``p_b`` with probability ``power``, its power computed exactly
    (:func:`unpaired_power`), searched both ways from the normal formula."""
    from scipy.special import ndtri

    if p_a == p_b:
        raise ValueError("equal rates: no number of episodes tells a rate from itself")
    bar, za, zb = (p_a + p_b) / 2, -ndtri(alpha / 2), ndtri(power)
    start = (za * math.sqrt(2 * bar * (1 - bar)) + zb * math.sqrt(p_a * (1 - p_a) + p_b * (1 - p_b))) ** 2 / (
        p_b - p_a) ** 2
    n = _fewest(lambda m: unpaired_power(p_a, p_b, m, alpha) >= power, math.ceil(min(start, 2 * MAX_EPISODES)),
                MAX_EPISODES)
    return Plan(n, 1, None if n is None else unpaired_power(p_a, p_b, n, alpha), "exact")


SIM_BUDGET = 15_000_000  # what one simulated power may cost: scenes x counted episodes x run pairs


def plan_scenes(p_a: float, p_b: float, alpha: float = ALPHA, power: float = POWER, size: int = 4,
                counted: int | None = None, icc: float = 0.5, sims: int = PLAN_SIMS, seed: int = 0) -> Plan:
    """The fewest scenes of ``size`` episodes, ``counted`` of them compared (default all; follow
    counts a counterfactual scene's K - 1 changed variants), each run needs for the exact scene test
    (:func:`sign_flip_p`, as ``rsb report --compare`` runs it) at ``alpha`` to tell ``p_a`` from ``p_b``
    with probability ``power``, a scene's episodes at intraclass correlation ``icc``
    (:func:`scene_difference`). One counted episode a scene, or ICC 1 (a scene's episodes all alike),
    is McNemar's test over scenes: exact. Otherwise the search starts at the normal approximation's
    answer and every n it tries is simulated (:func:`scene_power`, ``sims`` run pairs): an n reaches
    ``power`` when the estimate less :data:`PLAN_MC_Z` standard errors does, so Monte Carlo error
    cannot put the printed n under it. Where that would cost more than :data:`SIM_BUDGET` (many
    scenes, where the test's discreteness no longer matters) the normal approximation answers."""
    counted = size if counted is None else counted
    if not 1 <= counted <= size:
        raise ValueError(f"counted episodes a scene {counted} must lie in 1..{size}")
    if counted == 1 or icc >= 1:
        return plan_paired(p_a, p_b, alpha, power, size=size)
    values, pmf = scene_difference(p_a, p_b, counted, icc)
    cap = MAX_EPISODES // size
    # the approximation's answer for the target plus the margin a simulated power must clear
    margin = PLAN_MC_Z * math.sqrt(power * (1 - power) / sims)
    approx = _fewest(lambda c: _scene_power_normal(values, pmf, c, alpha) >= min(power + margin, 0.999), 8, cap)
    if approx is None:
        return Plan(None, size, None, "normal approximation")
    if approx * counted * sims > SIM_BUDGET:
        return Plan(approx, size, _scene_power_normal(values, pmf, approx, alpha), "normal approximation")
    cache: dict[int, tuple[float, float]] = {}

    def reach(c: int) -> bool:
        cache[c] = scene_power(p_a, p_b, c, counted, icc, alpha, sims, seed)
        return cache[c][0] - PLAN_MC_Z * cache[c][1] >= power

    n = _fewest(reach, approx, cap, step=0.03)
    return Plan(n, size, None if n is None else cache[n][0], "simulated")


def minimum_detectable_difference(p: float, n: int, alpha: float = ALPHA, power: float = POWER,
                                  design: float = 1.0) -> float | None:
    """The smallest difference from a rate ``p`` that McNemar's exact test on ``n`` paired episodes
    (over ``design``: clustered episodes count as ``n / design`` independent ones, the scene test's
    effective size) detects with probability ``power`` (:func:`mcnemar_power`, the two runs' outcomes
    on an episode independent): the larger of the differences up and down from ``p`` that stay within
    [0, 1] and can be detected. None ("none at this n") when no difference within [0, 1] can: under
    6 effective episodes the test at 0.05 cannot reject at all."""
    n_eff = int(n / design + 1e-9)
    if n_eff < 1:
        return None
    found = []
    for sign in (1, -1):
        room = 1 - p if sign > 0 else p
        if room <= 0:
            continue
        gap = lambda delta: mcnemar_power(p, p + sign * delta, n_eff, alpha) - power  # noqa: E731
        lo, hi, f_lo, f_hi = 0.0, room, -power, gap(room)
        if f_hi < 0:
            continue
        side = 0
        for _ in range(40):  # Illinois (regula falsi): keeps gap(lo) < 0 <= gap(hi), to a millionth of the room
            if hi - lo <= 1e-6 * room or f_hi == 0:
                break
            mid = min(max(hi - f_hi * (hi - lo) / (f_hi - f_lo), lo + 1e-9 * room), hi - 1e-9 * room)
            f_mid = gap(mid)
            if f_mid >= 0:
                hi, f_hi = mid, f_mid
                f_lo, side = (f_lo / 2 if side == 1 else f_lo), 1
            else:
                lo, f_lo = mid, f_mid
                f_hi, side = (f_hi / 2 if side == -1 else f_hi), -1
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
