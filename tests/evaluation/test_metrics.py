"""GSR / TSR / nSG, Wilson intervals, averages and the error analysis on hand-made records."""
from __future__ import annotations

import math

import pytest

from rsb_maniskill.evaluation.metrics import (
    PAPER_OBJECT_SUITES,
    PAPER_SUITES,
    average,
    avg_suites,
    nsg,
    num_choices,
    suite_metrics,
    summarize,
    wilson_interval,
)


def rec(suite="RSB-Math-4", seed=0, grasped=False, correct=False, placed=False, placed_wrong=False, success=None):
    """A minimal record; ``success`` defaults to placed-correct."""
    return {
        "suite_id": suite, "seed": seed, "grasped_any": grasped, "grasped_correct": correct,
        "placed_correct": placed, "placed_wrong": placed_wrong, "success": placed if success is None else success,
    }


def make(suite, n_success, n_not_placed, n_wrong, n_no_grasp):
    out, seed = [], 0
    for kind, count in (("ok", n_success), ("np", n_not_placed), ("wt", n_wrong), ("ng", n_no_grasp)):
        for _ in range(count):
            if kind == "ok":
                out.append(rec(suite, seed, grasped=True, correct=True, placed=True))
            elif kind == "np":
                out.append(rec(suite, seed, grasped=True, correct=True))
            elif kind == "wt":
                out.append(rec(suite, seed, grasped=True, placed_wrong=True))
            else:
                out.append(rec(suite, seed))
            seed += 1
    return out


# ---------------------------------------------------------------- Wilson
def _wilson_by_score_inversion(k, n, z=1.959963984540054):
    """Independent computation: the Wilson interval is {p : |k - n p| <= z sqrt(n p (1-p))}; find its
    ends by bisection on the score statistic instead of the closed form."""
    def inside(p):
        return (k - n * p) ** 2 <= z * z * n * p * (1 - p)

    phat = k / n

    def bisect(lo, hi):  # lo inside, hi outside (or the reverse), 200 halvings
        for _ in range(200):
            mid = (lo + hi) / 2
            if inside(mid) == inside(lo):
                lo = mid
            else:
                hi = mid
        return (lo + hi) / 2

    low = 0.0 if k == 0 else bisect(phat, 0.0)
    high = 1.0 if k == n else bisect(phat, 1.0)
    return low, high


@pytest.mark.parametrize(
    "k,n", [(0, 1), (1, 1), (0, 20), (3, 20), (81, 263), (15, 148), (250, 500), (499, 500), (500, 500)]
)
def test_wilson_matches_score_test_inversion(k, n):
    lo, hi = wilson_interval(k, n)
    rlo, rhi = _wilson_by_score_inversion(k, n)
    assert lo == pytest.approx(rlo, abs=1e-9) and hi == pytest.approx(rhi, abs=1e-9)
    assert 0.0 <= lo <= k / n <= hi <= 1.0


@pytest.mark.parametrize("k,n", [(0, 10), (1, 29), (81, 263), (15, 148), (37, 500), (498, 500)])
def test_wilson_matches_scipy(k, n):
    import scipy.stats as stats

    ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    lo, hi = wilson_interval(k, n)
    assert lo == pytest.approx(ci.low, abs=1e-12) and hi == pytest.approx(ci.high, abs=1e-12)


def test_wilson_published_values():
    # Newcombe (1998), Stat. Med. 17:857, Table I, method 3 (Wilson score without correction).
    assert wilson_interval(81, 263) == pytest.approx((0.2553, 0.3662), abs=5e-5)
    assert wilson_interval(15, 148) == pytest.approx((0.0624, 0.1605), abs=5e-5)
    assert wilson_interval(0, 20) == pytest.approx((0.0, 0.1611), abs=5e-5)


def test_wilson_edge_cases():
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    with pytest.raises(ValueError):
        wilson_interval(3, 2)
    with pytest.raises(ValueError):
        wilson_interval(-1, 2)


# ---------------------------------------------------------------- nSG
def test_nsg_formula_and_undefined():
    assert nsg(0.25, 1.0, 4) == pytest.approx(0.0)  # random selection among perfect grasps
    assert nsg(0.5, 0.5, 10) == pytest.approx(1.0)  # every grasp on the right block
    assert nsg(0.0, 0.8, 4) == pytest.approx(-1 / 3)  # never right: worse than random
    # Paper Table 4 / 6 consistency: pi0.5 on RSB-Math-4: GSR 98.0, TSR 32.8 -> nSG 11.3
    assert 100 * nsg(0.328, 0.98, 4) == pytest.approx(11.3, abs=0.05)
    assert nsg(0.0, 0.0, 4) is None


def test_num_choices():
    assert num_choices("RSB-Math-4") == 4 and num_choices("RSB-General-10") == 10
    with pytest.raises(ValueError):
        num_choices("RSB-Math")


# ---------------------------------------------------------------- per suite
def test_suite_metrics_counts_and_intervals():
    # 100 episodes: 20 success, 5 grasped-correct-not-placed, 55 wrong target, 20 no grasp.
    m = suite_metrics(make("RSB-Math-4", 20, 5, 55, 20), "RSB-Math-4")
    assert (m.n_episodes, m.n_grasped, m.n_success) == (100, 80, 20)
    assert m.gsr.value == pytest.approx(0.80) and m.tsr.value == pytest.approx(0.20)
    assert (m.gsr.low, m.gsr.high) == pytest.approx(wilson_interval(80, 100))
    assert (m.tsr.low, m.tsr.high) == pytest.approx(wilson_interval(20, 100))
    # nSG = (0.2/0.8 - 0.25)/0.75 = 0: random selection among grasps
    assert m.nsg.value == pytest.approx(0.0, abs=1e-12)
    # its interval: Wilson of success | grasped (20 of 80) mapped through the nSG formula
    clo, chi = wilson_interval(20, 80)
    assert m.nsg.low == pytest.approx((clo - 0.25) / 0.75) and m.nsg.high == pytest.approx((chi - 0.25) / 0.75)
    assert m.nsg.low < 0 < m.nsg.high
    e = m.errors
    assert (e.n_grasped_failed, e.not_placed, e.wrong_target, e.no_grasp) == (60, 5, 55, 20)
    f = e.fractions()
    assert f["not_placed"] == pytest.approx(5 / 60) and f["wrong_target"] == pytest.approx(55 / 60)
    assert f["no_grasp"] == pytest.approx(0.20)


def test_nsg_none_when_nothing_grasped():
    m = suite_metrics(make("RSB-HardMath-10", 0, 0, 0, 30), "RSB-HardMath-10")
    assert m.gsr.value == 0.0 and m.tsr.value == 0.0
    assert m.nsg.value is None and m.nsg.low is None and m.nsg.high is None
    assert m.errors.fractions()["not_placed"] is None
    assert m.to_dict()["nsg"] == {"value": None, "low": None, "high": None}


def test_success_without_grasp_flag_counts_as_grasp():
    records = [rec(success=True), rec(grasped=True, correct=True, placed=True)]
    m = suite_metrics(records, "RSB-Math-4")
    assert m.n_grasped == 2 and m.n_success_without_grasp == 1
    assert m.nsg.value == pytest.approx(1.0)


def test_suite_mismatch_is_an_error():
    with pytest.raises(ValueError, match="RSB-Math-10"):
        suite_metrics([rec("RSB-Math-10")], "RSB-Math-4")


# ---------------------------------------------------------------- averages
def test_summarize_orders_like_the_paper_and_averages():
    records = (make("RSB-Direct-4", 10, 0, 0, 0) + make("RSB-General-10", 1, 0, 9, 0)
               + make("RSB-Math-4", 5, 0, 5, 0) + make("RSB-Math-10", 0, 0, 0, 10))
    ms = summarize(records)
    assert list(ms) == ["RSB-Math-4", "RSB-Math-10", "RSB-General-10", "RSB-Direct-4"]
    a = average(ms)
    # Direct is a control: out of Avg; not all six paper suites: incomplete
    assert a.present == ("RSB-Math-4", "RSB-Math-10", "RSB-General-10") and not a.complete
    assert a.gsr == pytest.approx((1.0 + 0.0 + 1.0) / 3)
    assert a.tsr == pytest.approx((0.5 + 0.0 + 0.1) / 3)
    # nSG averages the suites where it is defined (Math-10 has GSR 0)
    assert a.nsg_suites == 2
    assert a.nsg == pytest.approx((nsg(0.5, 1.0, 4) + nsg(0.1, 1.0, 10)) / 2)


def test_average_complete_over_six_suites_and_direct_only():
    ms = summarize([r for s in PAPER_SUITES for r in make(s, 1, 0, 1, 0)])
    assert average(ms).complete
    direct = summarize(make("RSB-Direct-10", 3, 0, 1, 0))
    a = average(direct)  # no paper suite run: no Avg (Direct suites are controls), as the leaderboard says
    assert a.suites == () and a.present == () and not a.complete
    assert (a.gsr, a.tsr, a.nsg) == (None, None, None)


def test_average_of_objects_runs_is_over_the_beyond_blocks_six():
    ms = summarize(make("RSB-Math-4-Objects", 2, 0, 2, 0) + make("RSB-Direct-4-Objects", 4, 0, 0, 0))
    a = average(ms)  # the Direct control stays out here too
    assert a.suites == PAPER_OBJECT_SUITES and a.present == ("RSB-Math-4-Objects",) and not a.complete
    assert a.tsr == pytest.approx(0.5)
    assert avg_suites(["RSB-Direct-4", "RSB-Math-10-Objects", "RSB-Math-4"]) == PAPER_SUITES


def test_wilson_always_brackets_the_rate():
    for n in range(1, 301):
        for k in range(n + 1):
            lo, hi = wilson_interval(k, n)
            assert 0.0 <= lo <= k / n <= hi <= 1.0
        assert wilson_interval(0, n)[0] == 0.0 and wilson_interval(n, n)[1] == 1.0
