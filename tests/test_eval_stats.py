"""evaluation/stats.py: intervals that count clusters hold their coverage, paired tests and Holm's
correction give the textbook numbers."""
from __future__ import annotations

import numpy as np
import pytest

from rsb_maniskill.evaluation.metrics import Rate
from rsb_maniskill.evaluation.stats import clustered_rate, confusion, design_effect, holm, mcnemar, paired_bootstrap


def _coverage(interval, truth: float, trials: int, scenes: int, variants: int, seed: int) -> float:
    """Share of simulated runs whose interval holds ``truth``: a policy that knows a scene's question
    (success in every variant) with probability ``truth``, else fails every variant."""
    rng = np.random.default_rng(seed)
    held = 0
    for _ in range(trials):
        per_scene = rng.random(scenes) < truth
        values = np.repeat(per_scene, variants)
        clusters = np.repeat(np.arange(scenes), variants)
        rate = interval(values, clusters)
        held += rate.low <= truth <= rate.high
    return held / trials


def test_the_clustered_interval_holds_95_percent_where_counting_variants_does_not():
    """The issue's case: 4 variants a scene, a policy that is right in all or none of them. Counting
    the 4 variants as independent covers the truth far less than 95 %; counting scenes holds it."""
    naive = lambda v, c: Rate.of(int(v.sum()), len(v))  # noqa: E731
    covered = _coverage(clustered_rate, 0.4, trials=2000, scenes=100, variants=4, seed=1)
    nominal = _coverage(naive, 0.4, trials=2000, scenes=100, variants=4, seed=1)
    assert abs(covered - 0.95) <= 0.02, covered
    assert nominal < 0.85, nominal


def test_independent_outcomes_keep_the_plain_wilson_interval():
    rng = np.random.default_rng(3)
    values = rng.random(400) < 0.3
    assert design_effect(values, np.arange(400)) == pytest.approx(400 / 399)  # c / (c - 1): the small-sample term
    rate, plain = clustered_rate(values, np.arange(400)), Rate.of(int(values.sum()), 400)
    assert (rate.low, rate.high) == pytest.approx((plain.low, plain.high), abs=1e-3)
    assert clustered_rate([], []) == Rate(None, None, None)


def test_mcnemar_is_the_exact_binomial_test_on_discordant_pairs():
    a = [1] * 10 + [1] * 8 + [0] * 2 + [0] * 5
    b = [1] * 10 + [0] * 8 + [1] * 2 + [0] * 5
    m = mcnemar(a, b)
    assert (m.n, m.both, m.a_only, m.b_only, m.neither) == (25, 10, 8, 2, 5)
    assert m.p == pytest.approx(0.109375)  # 2 * P(X <= 2), X ~ Bin(10, 1/2) = 2 * 56/1024
    assert m.difference == pytest.approx(6 / 25)
    assert mcnemar([1, 0], [1, 0]).p == 1.0
    with pytest.raises(ValueError, match="equal lengths"):
        mcnemar([1], [1, 0])


def test_holm_steps_down_and_keeps_none():
    assert holm([0.01, 0.04, 0.03, None]) == pytest.approx([0.03, 0.06, 0.06, None])
    assert holm([0.5, 0.9]) == pytest.approx([1.0, 1.0])  # 2 x 0.5, then never below it
    assert holm([]) == []


def test_paired_bootstrap_finds_a_real_difference_and_not_a_null_one():
    rng = np.random.default_rng(0)
    base = rng.random(300) < 0.5
    better = base | (rng.random(300) < 0.3)  # the same episodes, more successes
    mean = lambda rows: float(np.mean(rows))  # noqa: E731
    d = paired_bootstrap(better, base, mean, resamples=500)
    assert d.difference > 0 and d.low > 0 and d.p < 0.01
    same = paired_bootstrap(base, base.copy(), mean, resamples=200)
    assert same.difference == 0 and same.p == 1.0
    undefined = paired_bootstrap(base, base, lambda rows: None)
    assert undefined.difference is None and undefined.resamples == 0


def test_confusion_counts_chosen_against_correct():
    table = confusion(["A", "B", None, "A"], ["A", "A", "B", "B"], ["A", "B"])
    assert table == {"A": {"A": 1, "B": 1, "none": 0}, "B": {"A": 1, "B": 0, "none": 1}}
