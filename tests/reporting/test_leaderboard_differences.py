"""`rsb leaderboard` marks rows whose TSR differs significantly from the best row's: paired (exact
McNemar) where their records share seeds, else the pooled two-proportion z test, Holm-corrected over every
pair of rows, and says which test and which family. (Its family-wise error over five identical rows:
tests/evaluation/test_power.py.)"""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from scipy.stats import binomtest

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
from rsb_maniskill.evaluation.stats import two_proportions
from rsb_maniskill.reporting.results import results_document


def records(policy, n_success, n_fail, first=EVAL_SEED_BASE):
    return [{"policy": policy, "suite_id": "RSB-Math-4", "seed": first + i, "question_id": i, "instruction": "x",
             "instruction_mode": "normal", "target_block": 0, "correct_letter": "A", "first_grasped": 0,
             "grasped_any": True, "grasped_correct": i < n_success, "placed_correct": i < n_success,
             "placed_wrong": False, "success": i < n_success, "steps": 5, "benchmark_version": "1.1"}
            for i in range(n_success + n_fail)]


def write_dir(path: Path, recs) -> Path:
    path.mkdir(parents=True)
    (path / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    return path


def board(tmp_path, capsys, *runs):
    out = tmp_path / "board"
    assert main(["leaderboard", *map(str, runs), "--out", str(out)]) == 0, capsys.readouterr().err
    rows = list(csv.DictReader(io.StringIO((out / "leaderboard.csv").read_text())))
    return (out / "leaderboard.md").read_text(), {r["model"]: r for r in rows if r["suite_id"] == "Avg"}, out


def test_paired_where_seeds_match(tmp_path, capsys):
    best = write_dir(tmp_path / "best", records("good", 14, 6))
    close = write_dir(tmp_path / "close", records("close", 12, 8))  # 2 discordant pairs: p = 0.5
    far = write_dir(tmp_path / "far", records("poor", 4, 16))  # 10 discordant pairs: p = 0.002
    md, avg, out = board(tmp_path, capsys, best, close, far)
    assert avg["poor"]["differs_from_best"] == "True" and avg["poor"]["vs_best_test"] == "paired"
    p = binomtest(10, 10, 0.5).pvalue
    assert abs(float(avg["poor"]["vs_best_p"]) - p) < 1e-9
    # Holm over the 3 pairs of rows (good-poor 2 / 2^10, close-poor 2 / 2^8, good-close 1 / 2): 3 x poor's p
    assert abs(float(avg["poor"]["vs_best_p_holm"]) - 3 * p) < 1e-9
    assert avg["close"]["differs_from_best"] == "False" and float(avg["close"]["vs_best_p"]) == 1.0 / 2
    assert avg["good"]["differs_from_best"] == "" and avg["good"]["vs_best_test"] == ""
    assert "| poor †§ |" in md and "| close † |" in md and "poor §: paired, exact McNemar p = 0.002, Holm p = " \
        "0.006" in md and "Family: every pair of the 3 rows (3 tests), Holm's correction" in md
    assert "Episodes unverified (records without episode digests" in md  # these records carry none
    assert "poor §" in (out / "index.html").read_text()


def test_from_the_intervals_without_shared_seeds(tmp_path, capsys):
    best = write_dir(tmp_path / "best", records("good", 18, 2))
    other = tmp_path / "other.json"  # a results.json alone: no records to pair
    other.write_text(json.dumps(results_document(records("poor", 3, 17, first=0))))
    md, avg, _ = board(tmp_path, capsys, best, other)
    assert avg["poor"]["differs_from_best"] == "True" and avg["poor"]["vs_best_test"] == "unpaired"
    assert float(avg["poor"]["vs_best_p"]) == two_proportions(18, 20, 3, 20)
    assert "poor §: unpaired, two-proportion" in md
    assert "Overlap" not in md and "intervals separate" not in md


def test_the_mark_stands_on_tsr_only_and_each_row_says_what_it_can_detect(tmp_path, capsys):
    """Issue 59: § stood beside the model in the GSR and nSG tables too (GSR 100 vs 100), though only TSR was
    tested. Each row's detectable TSR difference is the stats module's at its episodes."""
    from rsb_maniskill.evaluation.stats import minimum_detectable_difference

    best = write_dir(tmp_path / "best", records("good", 14, 6))
    far = write_dir(tmp_path / "far", records("poor", 4, 16))
    md, avg, out = board(tmp_path, capsys, best, far)
    tsr, gsr, nsg = (md.split(f"### {name}")[1].split("###")[0].split("\n- ")[0] for name in ("TSR", "GSR", "nSG"))
    assert "| poor †§ |" in tsr and "| poor † |" in gsr and "| poor † |" in nsg and "§" not in gsr + nsg
    page = (out / "index.html").read_text()
    assert '<span class="marks m tsr"' in page  # shown when the page shows TSR only
    mde = minimum_detectable_difference(4 / 20, 20)
    assert f"±{100 * mde:.1f} |" in tsr.split("| poor")[1].splitlines()[0]
    rows = list(csv.DictReader(io.StringIO((out / "leaderboard.csv").read_text())))
    poor = next(r for r in rows if r["model"] == "poor" and r["suite_id"] == "RSB-Math-4")
    assert float(poor["tsr_detectable_difference"]) == mde
    assert "Detectable TSR difference" in md and "`rsb plan`" in md
