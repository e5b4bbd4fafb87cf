"""The power of the tests the reports run, and what is built on it: the detectable differences are those of
McNemar's exact test (power computed exactly, "none" where it cannot reject), `rsb plan`'s counts reach the
power they print when simulated afresh (and 10 % fewer do not), and a page of many marks keeps its family-wise
error at 5 % for identical policies. Every simulation is vectorised with a fixed seed."""
from __future__ import annotations

import numpy as np
import pytest

from rsb_maniskill.evaluation.stats import (
    ALPHA,
    holm,
    holm_marks,
    mcnemar,
    mcnemar_power,
    minimum_detectable_difference,
    plan_paired,
    plan_scenes,
    plan_unpaired,
    scene_permutation,
    scene_power,
    sign_flip_p,
    sign_flip_pvalues,
    two_proportions,
    unpaired_power,
)


# ---------------------------------------------------------------- the tests' power, exactly
def test_the_batched_scene_test_is_the_scene_test():
    rng = np.random.default_rng(1)
    d = rng.integers(-3, 4, (400, 25)) * (rng.random((400, 25)) < 0.5)
    d[:5] = 0  # no difference at all: p = 1
    assert np.allclose(sign_flip_pvalues(d), [sign_flip_p(row) for row in d], atol=1e-12)
    wide = rng.integers(-9, 10, (50, 60))  # ten variants a scene
    assert np.allclose(sign_flip_pvalues(wide), [sign_flip_p(row) for row in wide], atol=1e-12)


def test_unpaired_power_is_the_z_tests_rejections_summed_over_every_outcome():
    from scipy.stats import binom

    for p_a, p_b, n in ((0.3, 0.45, 60), (0.05, 0.3, 30), (0.5, 0.5, 20), (0.9, 0.99, 100)):
        x = np.arange(n + 1)
        rejects = np.array([[(two_proportions(i, n, j, n) or 1.0) < ALPHA for j in x] for i in x])
        brute = float(binom.pmf(x, n, p_a) @ rejects @ binom.pmf(x, n, p_b))
        assert unpaired_power(p_a, p_b, n) == pytest.approx(brute, abs=1e-9), (p_a, p_b, n)
    assert two_proportions(0, 8, 8, 8) is None  # 4 expected successes a run: too few for the z test
    assert two_proportions(20, 100, 35, 100) == pytest.approx(0.01753, abs=1e-5)  # z = 0.15 / 0.0631 = 2.376


def test_scene_power_agrees_with_simulating_every_episode():
    rng = np.random.default_rng(2)
    for p_a, p_b, scenes, k, icc in ((0.3, 0.5, 40, 3, 0.5), (0.1, 0.3, 30, 3, 0.8), (0.2, 0.4, 25, 3, 0.0)):
        sims = 4000
        if icc:
            s = 1 / icc - 1
            qa = rng.beta(p_a * s, (1 - p_a) * s, (sims, scenes))
            qb = rng.beta(p_b * s, (1 - p_b) * s, (sims, scenes))
        else:
            qa, qb = np.full((sims, scenes), p_a), np.full((sims, scenes), p_b)
        direct = np.mean(sign_flip_pvalues(rng.binomial(k, qb) - rng.binomial(k, qa)) < ALPHA)
        est, se = scene_power(p_a, p_b, scenes, k, icc, sims=sims, seed=3)
        assert abs(est - direct) < 3.5 * np.sqrt(2) * se, (p_a, p_b, est, direct)


@pytest.mark.parametrize("rate", [0.0, 0.05, 0.3, 0.9])
def test_at_the_detectable_difference_the_exact_test_has_80_percent_power(rate):
    """The detectable difference is the exact test's: at it McNemar's exact test rejects at least 80 % of
    the time in each direction that stays within [0, 1] (Connor's formula gave 74-78 %), and 2 % less falls
    short in the harder one; at n = 4 (fewer than 6 discordant pairs possible) it is none."""
    for n in (10, 20, 100, 500):
        mde = minimum_detectable_difference(rate, n)
        assert mde is not None, (rate, n)
        powers = [mcnemar_power(rate, rate + s * mde, n) for s in (1, -1) if 0 <= rate + s * mde <= 1]
        assert powers and min(powers) >= 0.8 - 1e-9, (rate, n, mde, powers)
        short = [mcnemar_power(rate, rate + s * 0.98 * mde, n) for s in (1, -1) if 0 <= rate + s * mde <= 1]
        assert min(short) < 0.8, (rate, n, mde, short)
    assert minimum_detectable_difference(rate, 4) is None and minimum_detectable_difference(rate, 5) is None


def test_the_counterfactual_detectable_difference_counts_scenes():
    """With the design effect of scenes whose 4 variants all go one way, 40 variants are 10 scenes: the
    difference detectable is that of 10 episodes; with 4 variants a scene and fewer than 6 scenes, none."""
    assert minimum_detectable_difference(0.3, 40, design=4.0) == minimum_detectable_difference(0.3, 10)
    assert minimum_detectable_difference(0.3, 20, design=4.0) is None


# ---------------------------------------------------------------- rsb plan's counts
def test_the_paired_and_unpaired_counts_are_the_fewest_that_reach_the_power():
    for p_a, p_b in ((0.3, 0.4), (0.1, 0.3), (0.0, 0.05), (0.9, 0.97)):
        paired, unpaired = plan_paired(p_a, p_b), plan_unpaired(p_a, p_b)
        assert mcnemar_power(p_a, p_b, paired.episodes) >= 0.8 > mcnemar_power(p_a, p_b, paired.episodes - 1)
        assert unpaired_power(p_a, p_b, unpaired.episodes) >= 0.8 > unpaired_power(p_a, p_b, unpaired.episodes - 1)
        assert mcnemar_power(p_a, p_b, int(0.9 * paired.episodes)) < 0.8
    assert plan_paired(0.5, 0.5000001).episodes is None  # beyond a million episodes: said, not computed for ever


def _follow_power(p_a: float, p_b: float, scenes: int, k: int, icc: float, sims: int, seed: int) -> float:
    """Simulated afresh, as `rsb report --compare` runs follow: each scene's K - 1 changed variants (all
    grasped) succeed with a scene probability drawn from a beta law of ICC ``icc``; per scene the followed
    counts of A and B over the same denominator; the scene test on them."""
    rng = np.random.default_rng(seed)
    s = 1 / icc - 1
    qa = rng.beta(p_a * s, (1 - p_a) * s, (sims, scenes))
    qb = rng.beta(p_b * s, (1 - p_b) * s, (sims, scenes))
    na, nb = rng.binomial(k - 1, qa), rng.binomial(k - 1, qb)
    den = np.full(scenes, k - 1)
    for i in range(3):  # the report's own function on a few of them: the same p
        batched = sign_flip_pvalues(nb[i:i + 1] - na[i:i + 1])[0]
        assert scene_permutation(na[i], den, nb[i], den).p == pytest.approx(batched)
    return float(np.mean(sign_flip_pvalues(nb - na) < ALPHA))


@pytest.mark.parametrize("p_a, p_b, k, icc", [(0.3, 0.45, 4, 0.5), (0.1, 0.3, 4, 0.8)])
def test_the_follow_line_reaches_its_power_when_simulated_afresh(p_a, p_b, k, icc):
    """The printed scenes, re-simulated with 10,000 run pairs on another seed, reach 79.5 %; 10 % fewer
    scenes do not."""
    plan = plan_scenes(p_a, p_b, size=k, counted=k - 1, icc=icc)
    assert plan.how == "simulated" and plan.episodes == plan.scenes * k
    assert _follow_power(p_a, p_b, plan.scenes, k, icc, 10_000, seed=11) >= 0.795, plan
    assert _follow_power(p_a, p_b, int(0.9 * plan.scenes), k, icc, 10_000, seed=12) < 0.795, plan


def test_icc_one_and_one_counted_variant_are_mcnemar_over_scenes():
    """ICC 1 (the worst case: a scene's variants all alike) and K = 2 (one changed variant) need no
    simulation: the scene test is McNemar's over scenes, exact."""
    paired = plan_paired(0.3, 0.4)
    for plan in (plan_scenes(0.3, 0.4, size=4, counted=3, icc=1.0), plan_scenes(0.3, 0.4, size=2, counted=1)):
        assert plan.how == "exact" and plan.scenes == paired.episodes
    nearly = plan_scenes(0.1, 0.5, size=4, counted=3, icc=0.999999)  # simulated, all but alike: as ICC 1
    assert abs(nearly.scenes - plan_paired(0.1, 0.5).episodes) <= 2, nearly


# ---------------------------------------------------------------- one rule for a page of many marks
def test_holm_marks_leave_a_drawn_p_undecided_only_where_its_interval_matters():
    marks = holm_marks([(0.001, None, None), (0.02, 0.018, 0.022), (0.5, None, None)])  # 2 x 0.022 < 0.05
    assert [m.significant for m in marks] == [True, True, False] and all(m.decided for m in marks)
    marks = holm_marks([(0.001, None, None), (0.024, 0.022, 0.027), (0.5, None, None)])  # 2 x p straddles 0.05
    assert marks[1].p_holm == pytest.approx(0.048) and not marks[1].decided and marks[0].decided


def test_compare_over_six_suites_keeps_the_family_wise_error_at_five_percent():
    """Two identical policies on the six suites (500 episodes each, TSR 40 %, GSR 70 %): at an unadjusted
    0.05 some GSR / TSR test is marked in about a third of comparisons; with Holm over the 12 tests, at most
    5 % (4,000 comparisons, Monte Carlo standard error 0.35 points)."""
    rng = np.random.default_rng(7)
    sims, n = 4000, 500
    p_raw = []
    for _ in range(6):
        g = rng.random((2, sims, n)) < 0.7
        s = g & (rng.random((2, sims, n)) < 0.4 / 0.7)
        for x in (g, s):  # one episode a scene: the exact scene test is McNemar's
            p_raw.append(sign_flip_pvalues(x[1].astype(int) - x[0].astype(int)))
    p_raw = np.array(p_raw).T  # (sims, 12)
    unadjusted = np.mean((p_raw < ALPHA).any(axis=1))
    family = np.mean([any(m.significant for m in holm_marks([(p, None, None) for p in row])) for row in p_raw])
    assert unadjusted > 0.25, unadjusted
    assert family <= ALPHA + 2 * np.sqrt(ALPHA * (1 - ALPHA) / sims), family


def test_the_compare_table_marks_identical_policies_rarely_end_to_end():
    """The whole table (GSR, TSR and nSG of six suites, 18 tests, through `compare_paired`), identical
    policies, 120 comparisons: a mark in at most 5 % of them plus twice the Monte Carlo error."""
    from rsb_maniskill.reporting.paired import compare_paired

    suites = ["RSB-Math-4", "RSB-HardMath-4", "RSB-General-4", "RSB-Math-10", "RSB-HardMath-10", "RSB-General-10"]
    rng = np.random.default_rng(8)
    runs, marked = 120, 0
    for _ in range(runs):
        recs = []
        for policy in ("a", "b"):
            g = rng.random((6, 12)) < 0.7
            s = g & (rng.random((6, 12)) < 0.5)
            recs.append([{"policy": policy, "suite_id": suite, "seed": i, "instruction_mode": "normal",
                          "target_block": 0, "first_grasped": 0 if s[j, i] else (1 if g[j, i] else -1),
                          "grasped_any": bool(g[j, i]), "success": bool(s[j, i]), "benchmark_version": "1.1"}
                         for j, suite in enumerate(suites) for i in range(12)])
        table = compare_paired(*recs).split("| Holm p |")[1]
        marked += " *" in table
    assert marked / runs <= ALPHA + 2 * np.sqrt(ALPHA * (1 - ALPHA) / runs), marked / runs


def test_the_leaderboard_keeps_the_family_wise_error_over_five_identical_rows():
    """Five identical rows on the same 600 episodes (TSR 45 %): the best is the observed maximum. Holm over
    the four comparisons with it alone marks some row in about 7-8 % of leaderboards; the leaderboard's
    family, every pair of rows, at most 5 % (3,000 leaderboards)."""
    from rsb_maniskill.reporting.leaderboard import differences_from_best

    rng = np.random.default_rng(9)
    sims, n, rows = 3000, 600, 5
    won = rng.random((sims, rows, n)) < 0.45
    pairs = [(i, j) for i in range(rows) for j in range(i + 1, rows)]
    p = np.stack([sign_flip_pvalues(won[:, j].astype(int) - won[:, i].astype(int)) for i, j in pairs], 1)
    best = won.sum(2).argmax(1)
    family = best_only = 0
    for s in range(sims):
        found = differences_from_best(dict(zip(pairs, p[s])), int(best[s]))
        family += any(adjusted < ALPHA for _, adjusted in found.values())
        best_only += any(a < ALPHA for a in holm([raw for raw, _ in found.values()]))
    assert best_only / sims > ALPHA + 2 * np.sqrt(ALPHA * (1 - ALPHA) / sims), best_only / sims
    assert family / sims <= ALPHA + 2 * np.sqrt(ALPHA * (1 - ALPHA) / sims), family / sims
    assert mcnemar([1, 0, 1], [0, 0, 1]).p == sign_flip_pvalues(np.array([[-1, 0, 0]]))[0]  # the same test
