"""`rsb report --compare A B` pairs episodes: exact McNemar for GSR / TSR (and follow), a paired
bootstrap for nSG, the paired and unpaired counts, and a refusal when nothing pairs."""
from __future__ import annotations

import json
from pathlib import Path

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
        r.update(variant=variant, variant_kind="remap")
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
    row = next(ln for ln in out.splitlines() if ln.startswith("| RSB-Math-4 | TSR | 20 |"))
    p = binomtest(0, 10, 0.5).pvalue
    assert "| 0 / 10 |" in row and "McNemar" in row and f"{p:.3f} *" in row and "+50.0" in row
    gsr = next(ln for ln in out.splitlines() if ln.startswith("| RSB-Math-4 | GSR | 20 |"))
    assert "| 0 / 0 |" in gsr and "1.000" in gsr
    nsg = next(ln for ln in out.splitlines() if ln.startswith("| RSB-Math-4 | nSG | 20 |"))
    assert "paired bootstrap" in nsg and nsg.rstrip(" |").endswith("*")


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
    assert "RSB-Math-4 (counterfactual)" in follow and "| 0 / 12 |" in follow


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
