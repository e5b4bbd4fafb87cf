"""The confusion section: chosen against correct by option letter and by position, in summary.json,
its CSV and the page (built from the rows)."""
from __future__ import annotations

import json

from rsb_maniskill.reporting.sections.confusion import LETTER, POSITION, SECTION, confusion_table, suite_confusion
from rsb_maniskill.reporting.summary import results_from_records
from rsb_maniskill.reporting.writer import write_report

LETTERS = ["A", "B", "C", "D"]


def record(seed: int, answer_slot: int, grasped_slot: int | None, boo=(2, 0, 3, 1), policy="p") -> dict:
    """A 4-choice episode whose option k is block ``boo[k]``; block b stands b-th from the left."""
    target = boo[answer_slot]
    return {"policy": policy, "suite_id": "RSB-Math-4", "seed": seed, "instruction_mode": "normal",
            "target_block": target, "first_grasped": -1 if grasped_slot is None else boo[grasped_slot],
            "grasped_any": grasped_slot is not None, "grasped_correct": grasped_slot == answer_slot,
            "placed_correct": grasped_slot == answer_slot, "placed_wrong": False,
            "success": grasped_slot == answer_slot, "left_rank": [0, 1, 2, 3],
            "episode": {"letters": LETTERS, "block_of_option": list(boo), "answer_slot": answer_slot,
                        "block_names": ["red block", "green block", "blue block", "yellow block"]}}


def test_a_policy_that_swaps_a_and_b_shows_off_the_diagonal():
    recs = [record(0, 0, 1), record(1, 1, 0), record(2, 2, 2), record(3, 3, None)]
    m = suite_confusion(recs, "RSB-Math-4")
    assert m[LETTER]["A"]["B"] == 1 and m[LETTER]["B"]["A"] == 1 and m[LETTER]["C"]["C"] == 1
    assert m[LETTER]["D"]["none"] == 1 and sum(sum(row.values()) for row in m[LETTER].values()) == 4
    # positions: option A is block 2 (3rd from left), B block 0 (1st): the swap is 3 <-> 1
    assert m[POSITION]["3"]["1"] == 1 and m[POSITION]["1"]["3"] == 1 and m[POSITION]["4"]["4"] == 1


def test_records_without_ranks_or_spec_leave_that_axis_out():
    r = record(0, 0, 0)
    del r["left_rank"]
    assert list(suite_confusion([r], "RSB-Math-4")) == [LETTER]
    assert confusion_table([{**r, "episode": None}]) == {}


def test_summary_json_csv_and_page_carry_the_matrices(tmp_path):
    recs = [record(i, i % 4, (i + 1) % 4) for i in range(8)]  # always the next option
    write_report(results_from_records(recs), tmp_path, records=recs)
    summary = json.loads((tmp_path / "summary.json").read_text())
    letter = summary["confusion"]["p"]["RSB-Math-4"][LETTER]
    assert letter["A"]["B"] == 2 and letter["A"]["A"] == 0
    assert (tmp_path / "summary_confusion.csv").read_text().count("\n") == 1 + 2 * 4 * 5
    page = SECTION.page(recs, tmp_path)  # what report.html.j2 renders of the section
    assert page["anchor"] == "confusion" and str(page["body"]).count('<td class="hit">0</td>') == 8  # 2 empty diagonals
    body = str(SECTION.html(confusion_table(recs)))
    assert "<th>correct \\ chosen</th>" in body and "|" not in body  # built from rows, not from Markdown
