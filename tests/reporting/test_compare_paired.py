"""`rsb report --compare A B` pairs episodes: tests that count scenes for GSR / TSR (McNemar's exact test when
every scene is one episode) and, for counterfactual runs, the headline follow and switch; nSG by the same
scene flips of its share of grasps on the target; Holm's correction over the table; the paired and unpaired
counts; a refusal when nothing pairs; type I error at most alpha with clustered variants (simulated)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

from rsb_maniskill.cli import main
from rsb_maniskill.reporting.paired import NoPairs, compare_paired, pair_records


def rec(policy, suite, seed, grasped, success, mode="normal", variant=None):
    r = {"policy": policy, "suite_id": suite, "seed": seed, "question_id": seed, "instruction": "x",
         "instruction_mode": mode, "target_block": 0, "correct_letter": "A",
         "first_grasped": 0 if success else (1 if grasped else -1), "grasped_any": grasped,
         "grasped_correct": success, "placed_correct": success, "placed_wrong": False, "success": success,
         "steps": 5, "benchmark_version": "1.1"}
    if variant is not None:
        r.update(variant=variant, variant_kind="remap" if variant else "protocol")
    return r


def run_dir(path: Path, recs: list[dict]) -> Path:
    path.mkdir(parents=True)
    (path / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    return path


def test_compare_prints_exact_mcnemar_on_the_discordant_pairs(tmp_path, capsys):
    # 20 shared seeds: A succeeds on 0-3, B on 0-13 -> 10 pairs only B won, none only A
    a = run_dir(tmp_path / "a", [rec("blind", "RSB-Math-4", s, True, s < 4) for s in range(20)])
    b = run_dir(tmp_path / "b", [rec("leftmost", "RSB-Math-4", s, True, s < 14) for s in range(22)])
    assert main(["report", "--compare", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "Paired: 20 episodes" in out and "unpaired: 0 of A, 2 of B" in out
    row = next(ln for ln in out.splitlines() if ln.startswith("| RSB-Math-4 | TSR | 20 / 20 |"))
    p = binomtest(0, 10, 0.5).pvalue
    # Holm over the table's 3 tests: TSR and nSG (every episode grasped: the same flips) at p, GSR at 1
    assert "| 0 / 10 |" in row and "McNemar" in row and row.endswith(f"| {p:.3f} | {3 * p:.3f} * |") and "+50.0" in row
    gsr = next(ln for ln in out.splitlines() if ln.startswith("| RSB-Math-4 | GSR | 20 / 20 |"))
    assert "| 0 / 0 |" in gsr and gsr.endswith("| 1.000 | 1.000 |")
    nsg = next(ln for ln in out.splitlines() if ln.startswith("| RSB-Math-4 | nSG | 20 / 20 |"))
    assert "scene permutation" in nsg and "| of 20 / 20 |" in nsg and nsg.endswith(f"| {p:.3f} | {3 * p:.3f} * |")
    assert "Family: the 3 tests of this table, Holm's correction" in out


def test_compare_refuses_runs_that_share_no_suite_or_no_episode(tmp_path, capsys):
    a = run_dir(tmp_path / "a", [rec("p", "RSB-Math-4", s, True, s < 2) for s in range(5)])
    b = run_dir(tmp_path / "b", [rec("q", "RSB-HardMath-4", s, True, s < 4) for s in range(5)])
    c = run_dir(tmp_path / "c", [rec("q", "RSB-Math-4", 100 + s, True, s < 4) for s in range(5)])
    assert main(["report", "--compare", str(a), str(b)]) == 2
    cap = capsys.readouterr()
    assert "share no suite" in cap.err and len(cap.err.strip().splitlines()) == 1 and "Avg" not in cap.out
    assert main(["report", "--compare", str(a), str(c)]) == 2
    cap = capsys.readouterr()
    assert "share no episode" in cap.err and len(cap.err.strip().splitlines()) == 1 and cap.out == ""


def test_counterfactual_rows_get_follow_and_pair_by_variant():
    a = [rec("p", "RSB-Math-4", s, True, v == 0, mode="counterfactual", variant=v) for s in range(6) for v in range(4)]
    b = [rec("q", "RSB-Math-4", s, True, True, mode="counterfactual", variant=v) for s in range(6) for v in range(3)]
    pairs, only_a, only_b = pair_records(a, b)
    assert len(pairs) == 18 and (only_a, only_b) == (6, 0)
    assert all(x["variant"] == y["variant"] and x["seed"] == y["seed"] for x, y in pairs)
    out = compare_paired(a, b)
    follow = next(ln for ln in out.splitlines() if "| Follow |" in ln)
    # the section's headline follow: changed variants (k > 0) with a grasp, 12 in each run; 6 scenes
    assert "RSB-Math-4 (counterfactual)" in follow and "| 18 / 6 |" in follow and "| of 12 / 12 |" in follow
    assert "| 0.0 | 100.0 | +100.0 |" in follow
    # all 6 scenes went B's way: the exact scene permutation's p is 2 / 2^6, not McNemar's 2 / 2^12 over variants;
    # Holm over the table's 5 tests (GSR at 1, the other four at 2 / 2^6) leaves no mark
    assert "scene permutation (exact)" in follow and follow.endswith("| 0.031 | 0.125 |")
    tsr = next(ln for ln in out.splitlines() if "| TSR |" in ln)
    assert "| 0 / 12 |" in tsr and tsr.endswith("| 0.031 | 0.125 |")


def test_no_pairs_is_a_value_error():
    try:
        compare_paired([rec("p", "RSB-Math-4", 1, True, True)], [rec("p", "RSB-Math-4", 2, True, True)])
    except NoPairs as err:
        assert isinstance(err, ValueError) and "share no episode" in str(err)
    else:
        raise AssertionError("no pairs must be refused")


def test_same_seed_other_question_is_not_a_pair():
    a = [rec("p", "RSB-Math-4", s, True, True) | {"episode_digest": f"q{s}"} for s in range(4)]
    b = [rec("q", "RSB-Math-4", s, True, False) | {"episode_digest": f"q{s}" if s < 2 else "other"}
         for s in range(4)]
    pairs, only_a, only_b = pair_records(a, b)
    assert [p[0]["seed"] for p in pairs] == [0, 1] and (only_a, only_b) == (2, 2)
    old = [{k: v for k, v in r.items() if k != "episode_digest"} for r in b]  # no digest: paired by seed
    assert len(pair_records(a, old)[0]) == 4


def test_compare_reaches_counterfactual_runs_from_the_command_line(tmp_path, capsys):
    """Issue 59: two counterfactual-only runs have no results.json row; --compare pairs their records."""
    def cf(policy, s, v, grasp):  # variant v's target is candidate v; the policy grasps `grasp`
        return rec(policy, "RSB-Math-4", s, True, grasp == v, mode="counterfactual", variant=v) | {
            "target_block": v, "first_grasped": grasp}

    a = run_dir(tmp_path / "cf_blind", [cf("leftmost", s, v, 0) for s in range(8) for v in range(4)])
    b = run_dir(tmp_path / "cf_oracle", [cf("oracle", s, v, v) for s in range(8) for v in range(4)])
    assert main(["report", "--compare", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "No rows to put side by side" in out and "### Paired comparison" in out
    for metric in ("GSR", "TSR", "Follow", "Switch", "nSG"):
        assert f"| RSB-Math-4 (counterfactual) | {metric} | 32 / 8 |" in out, metric
    follow = next(ln for ln in out.splitlines() if "| Follow |" in ln)
    assert "| 0.0 | 100.0 | +100.0 |" in follow and follow.rstrip(" |").endswith("*")
    switch = next(ln for ln in out.splitlines() if "| Switch |" in ln)
    assert "| 0.0 | 100.0 | +100.0 |" in switch and "of 48 / 48" in switch  # 6 pairs a scene
    assert switch.endswith("| 0.008 | 0.039 * |")  # 2 / 2^8, the 8 scenes' flips enumerated; Holm: 5 x that


def _clustered_pairs(rng: np.random.Generator, scenes: int, k: int, icc: float, rate: float):
    """A and B alike (the null hypothesis): each run's success probability in a scene drawn from one beta law
    of intraclass correlation ``icc`` (a policy knows a scene's question or not), each variant from it."""
    s = 1 / icc - 1
    qa, qb = (np.repeat(rng.beta(rate * s, (1 - rate) * s, scenes), k) for _ in range(2))
    return rng.random(scenes * k) < qa, rng.random(scenes * k) < qb


def test_scene_tests_hold_their_type_one_error_with_clustered_variants():
    """20 scenes x 4 variants, ICC 0.8, A and B alike: McNemar over variants (the old test) rejects far more
    than 5 % of the time; the scene permutation at most 5 % (plus Monte Carlo slack: 2,000 runs, SE 0.5)."""
    from rsb_maniskill.evaluation.stats import mcnemar, scene_permutation

    rng = np.random.default_rng(5)
    scenes, k, runs = 20, 4, 2000
    scene_rejects = naive_rejects = 0
    for _ in range(runs):
        a, b = _clustered_pairs(rng, scenes, k, 0.8, 0.4)
        per_a, per_b = a.reshape(scenes, k).sum(1), b.reshape(scenes, k).sum(1)
        scene_rejects += scene_permutation(per_a, np.full(scenes, k), per_b, np.full(scenes, k)).p < 0.05
        naive_rejects += mcnemar(a, b).p < 0.05
    assert scene_rejects / runs <= 0.05 + 2 * np.sqrt(0.05 * 0.95 / runs), scene_rejects / runs
    assert naive_rejects / runs > 0.15, naive_rejects / runs


def test_follow_test_holds_its_type_one_error_when_grasps_differ():
    """Follow's denominators differ between runs (each run's own grasps): the ratio's scene permutation
    (every flip of 10 scenes enumerated) stays at most 5 % when A and B are alike."""
    from rsb_maniskill.evaluation.stats import scene_permutation

    rng = np.random.default_rng(6)
    scenes, k, runs, rejects = 10, 3, 600, 0
    for _ in range(runs):
        fa, fb = _clustered_pairs(rng, scenes, k, 0.8, 0.5)
        ga, gb = rng.random(scenes * k) < 0.8, rng.random(scenes * k) < 0.8  # grasped: the denominators
        sums = [x.reshape(scenes, k).sum(1) for x in (fa & ga, ga, fb & gb, gb)]
        rejects += (scene_permutation(*sums).p or 1.0) < 0.05
    assert rejects / runs <= 0.05 + 2 * np.sqrt(0.05 * 0.95 / runs), rejects / runs


def test_nsg_is_not_marked_where_too_few_scenes_differ():
    """Issue 64: the paired bootstrap marked nSG `<0.001 *` on 2 episodes (oracle against leftmost), where no
    test on 2 pairs can reject. nSG's scene flips of its share of grasps on the target cannot go below
    2 / 2^2; and on 0/1 outcomes with every episode grasped they are McNemar's exact test (the bootstrap gave
    0.045 where McNemar gives 0.061)."""
    a = [rec("leftmost", "RSB-Math-4", s, True, False) for s in range(2)]
    b = [rec("oracle", "RSB-Math-4", s, True, True) for s in range(2)]
    nsg = next(ln for ln in compare_paired(a, b).splitlines() if "| nSG |" in ln)
    assert nsg.endswith("| 0.500 | 1.000 |"), nsg
    # A alone wins episodes 0-8, B alone 9-28, both 29-68
    a = [rec("p", "RSB-Math-4", s, True, s < 9 or 29 <= s < 69) for s in range(120)]
    b = [rec("q", "RSB-Math-4", s, True, 9 <= s < 69) for s in range(120)]
    rows = {ln.split("|")[2].strip(): ln for ln in compare_paired(a, b).splitlines() if ln.startswith("| RSB")}
    p = binomtest(9, 29, 0.5).pvalue
    assert f"| {p:.3f} |" in rows["TSR"] and f"| {p:.3f} |" in rows["nSG"] and p > 0.05


def test_a_drawn_p_stops_where_no_holm_threshold_is_in_doubt():
    """Beyond 16 differing scenes a ratio's flips are drawn; a family of m tests asks whether p clears any
    of alpha / m .. alpha, so the draws go on until the p-value's 99.9 % interval holds none of them (at most
    320,000 flips: bounded), and the mark is the same under every seed."""
    from rsb_maniskill.evaluation.stats import MAX_PERMUTATIONS, scene_permutation

    rng = np.random.default_rng(3)
    c = 60
    den_a, den_b = rng.integers(1, 4, c), rng.integers(1, 4, c)
    num_a, num_b = rng.binomial(den_a, 0.35), rng.binomial(den_b, 0.6)
    levels = tuple(0.05 / i for i in range(1, 19))
    runs = [scene_permutation(num_a, den_a, num_b, den_b, seed=s, levels=levels) for s in range(4)]
    for r in runs:
        assert not r.exact and r.p_low <= r.p <= r.p_high and r.draws <= MAX_PERMUTATIONS
        assert r.draws == MAX_PERMUTATIONS or not any(r.p_low < lv <= r.p_high for lv in levels)
