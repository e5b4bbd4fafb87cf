"""`rsb leaderboard` refuses a results.json whose numbers cannot be: n = -5, TSR 750 %, NaN, an
interval that misses its value, a field the schema does not know; one line naming the file and field."""
from __future__ import annotations

import json

import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
from rsb_maniskill.reporting import results as R


def doc() -> dict:
    recs = [{"policy": "p", "suite_id": "RSB-Math-4", "seed": EVAL_SEED_BASE + i, "question_id": i, "instruction": "x",
             "instruction_mode": "normal", "target_block": 0, "correct_letter": "A", "first_grasped": 0,
             "grasped_any": True, "grasped_correct": i < 3, "placed_correct": i < 3, "placed_wrong": False,
             "success": i < 3, "steps": 5, "benchmark_version": "1.1"} for i in range(8)]
    return R.results_document(recs)


def suite(d: dict) -> dict:
    return d["rows"][0]["suites"]["RSB-Math-4"]


@pytest.mark.parametrize("spoil, field, words", [
    (lambda d: suite(d).update(n=-5), "rows[0].suites.RSB-Math-4.n", "-5 is not an episode count"),
    (lambda d: suite(d)["tsr"].update(value=7.5), "rows[0].suites.RSB-Math-4.tsr.value", "750 % is outside"),
    (lambda d: suite(d)["gsr"].update(low=float("nan")), "rows[0].suites.RSB-Math-4.gsr.low", "not a finite"),
    (lambda d: d["rows"][0]["average"].update(tsr=float("nan")), "rows[0].average.tsr", "not a finite"),
    (lambda d: suite(d)["tsr"].update(value="0.3"), "rows[0].suites.RSB-Math-4.tsr.value", "is not a number"),
    (lambda d: suite(d)["tsr"].update(low=0.9), "rows[0].suites.RSB-Math-4.tsr", "does not hold its value"),
    (lambda d: d["rows"][0].update(extra=1), "rows[0]", "'extra' was unexpected"),  # the shipped schema
])
def test_a_results_json_that_cannot_be_is_refused(tmp_path, capsys, spoil, field, words):
    good = tmp_path / "good.json"
    good.write_text(json.dumps(doc()))
    assert R.document_problem(json.loads(good.read_text())) is None
    bad_doc = doc()
    spoil(bad_doc)
    bad = tmp_path / "results.json"
    bad.write_text(json.dumps(bad_doc))  # NaN is written as NaN, which json reads back
    rc = main(["leaderboard", str(good), str(bad), "--out", str(tmp_path / "board")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and not (tmp_path / "board").exists()
    assert err.startswith(f"rsb leaderboard: error: {bad}: {field}") and words in err, err
