"""Results files a reviewer can break, read by `rsb report --compare` and `rsb leaderboard`: a string schema
version, an n its own intervals contradict, JSON nested 10,000 deep or not JSON at all: one true line
naming the file and the field (exit 2). A copy of a run compared with it gets a first line that says so.
p-values printed so that the number agrees with its mark; counterfactual rows' intervals count scenes."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
from rsb_maniskill.reporting.results import results_document

SUITE = "RSB-Math-4"


def records(policy: str, wins: int, n: int, mode: str = "normal", variants: int = 1) -> list[dict]:
    return [{"policy": policy, "suite_id": SUITE, "seed": EVAL_SEED_BASE + i, "question_id": i, "instruction": "x",
             "instruction_mode": mode, "target_block": 0, "correct_letter": "A", "first_grasped": 0 if i < wins else 1,
             "grasped_any": True, "grasped_correct": i < wins, "placed_correct": i < wins, "placed_wrong": False,
             "success": i < wins, "steps": 5, "benchmark_version": "1.1",
             **({"variant": v, "variant_kind": "remap" if v else "protocol"} if mode == "counterfactual" else {})}
            for i in range(n) for v in range(variants)]


def results_file(path: Path, doc: dict | str) -> Path:
    path.mkdir(parents=True)
    (path / "results.json").write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return path


@pytest.fixture
def good(tmp_path) -> Path:
    return results_file(tmp_path / "good", results_document(records("p", 3, 10)))


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


@pytest.mark.parametrize("command", ["report", "leaderboard"])
def test_a_string_schema_version_gets_one_true_line(command, good, tmp_path, capsys):
    doc = results_document(records("q", 4, 10))
    doc["schema_version"] = "1"
    bad = results_file(tmp_path / "bad", doc)
    argv = (["report", "--compare", str(good), str(bad)] if command == "report" else
            ["leaderboard", str(bad / "results.json"), "--out", str(tmp_path / "board")])
    assert main(argv) == 2
    err = _one_line(capsys)
    assert 'schema_version: "1" is a string where the number 1 is due' in err and str(bad / "results.json") in err
    assert "reads 1" not in err and "1 was expected" not in err  # the old lines said 1 is not 1


@pytest.mark.parametrize("command", ["report", "leaderboard"])
def test_an_n_its_own_intervals_contradict_is_named(command, good, tmp_path, capsys):
    doc = results_document(records("q", 1, 2))
    doc["rows"][0]["suites"][SUITE]["n"] = 10 ** 30  # beside the intervals of 2 episodes
    bad = results_file(tmp_path / "bad", doc)
    argv = (["report", "--compare", str(good), str(bad)] if command == "report" else
            ["leaderboard", str(bad / "results.json"), "--out", str(tmp_path / "board")])
    assert main(argv) == 2
    err = _one_line(capsys)
    assert f"rows[0].suites.{SUITE}.n: 1,000,000,000,000,000,000,000,000,000,000 episodes do not fit" in err, err
    assert str(bad / "results.json") in err and not (tmp_path / "board").exists()


@pytest.mark.parametrize("command", ["report", "leaderboard"])
@pytest.mark.parametrize("text, words", [("[" * 10000 + "]" * 10000, "nested over 32 levels deep"),
                                         ('{"rows": [', "not a results document: Expecting")])
def test_deep_or_broken_json_is_one_line_not_a_traceback(command, text, words, good, tmp_path, capsys):
    bad = results_file(tmp_path / "bad", text)
    argv = (["report", "--compare", str(good), str(bad)] if command == "report" else
            ["leaderboard", str(bad / "results.json"), "--out", str(tmp_path / "board")])
    assert main(argv) == 2
    err = _one_line(capsys)
    assert words in err and str(bad / "results.json") in err, err


def test_a_copy_of_a_run_compared_with_it_is_said_to_be_one(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records("p", 6, 12)))
    copy = tmp_path / "copy"
    shutil.copytree(run, copy)
    assert main(["report", "--compare", str(run), str(copy)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"Note: {run} and {copy} hold the same episode records (a copy of one run?)")
    other = tmp_path / "other"
    other.mkdir()
    (other / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records("q", 7, 12)))
    assert main(["report", "--compare", str(run), str(other)]) == 0
    assert "Note:" not in capsys.readouterr().out


def test_p_is_printed_so_that_it_agrees_with_its_mark():
    from rsb_maniskill.reporting.cells import p_value

    assert p_value(0.0498) == "0.0498" and p_value(0.0501) == "0.0501" and p_value(0.05) == "0.050"
    assert p_value(0.049999) == "0.049999" and p_value(0.0004) == "<0.001" and p_value(0.123) == "0.123"
    for p in np.linspace(0.04, 0.06, 2001):
        assert (float(p_value(p)) < 0.05) == (p < 0.05) and (float(p_value(p)) != 0.05 or p == 0.05), p


def test_a_counterfactual_row_counts_scenes():
    """Its GSR / TSR / nSG intervals are Wilson's over scenes (a scene whose 4 variants all go one way counts
    about once), and its detectable differences are the exact test's at n / design effect."""
    from rsb_maniskill.evaluation.stats import clustered_rate, minimum_detectable_difference
    from rsb_maniskill.reporting.summary import detectable, results_from_records

    recs = records("p", 6, 20, mode="counterfactual", variants=4)  # 20 scenes, each all success or all failure
    m = results_from_records(recs)["p (counterfactual)"][SUITE]
    want = clustered_rate(np.repeat(np.arange(20) < 6, 4), np.repeat(np.arange(20), 4))
    assert (m.tsr.low, m.tsr.high) == pytest.approx((want.low, want.high))
    plain = results_from_records(records("p", 24, 80))["p"][SUITE].tsr
    assert m.tsr.high - m.tsr.low > 1.5 * (plain.high - plain.low)
    design = m.extra["design_effect"]["tsr"]
    assert 3.5 < design <= 4.3 and detectable(m)["tsr"] == minimum_detectable_difference(0.3, 80, design=design)
    assert detectable(m)["tsr"] > minimum_detectable_difference(0.3, 80)
