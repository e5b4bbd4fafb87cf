"""Results folders for the verdict tests (tests/reporting/test_verdicts_kept.py, test_compare_verdicts.py):
records of one suite whose results.json was written with a given verdict per row."""
from __future__ import annotations

import json
from pathlib import Path

from rsb_maniskill.evaluation.records import DIGEST_FIELD
from rsb_maniskill.reporting.results import results_document
from rsb_maniskill.version import BENCHMARK_VERSION

SUITE = "RSB-HardMath-4"  # reads GSM8K: its episodes are checked on the question data at hand
NOT_RECHECKED = "not re-checked: no data"


def episode(i: int, digest: str | None = "0" * 16, policy: str = "pi05") -> dict:
    r = {"policy": policy, "suite_id": SUITE, "seed": 10_000_000 + i, "question_id": i, "instruction": "x",
         "instruction_mode": "normal", "target_block": 0, "correct_letter": "A", "first_grasped": 0,
         "grasped_any": True, "grasped_correct": i % 2 == 0, "placed_correct": i % 2 == 0, "placed_wrong": False,
         "success": i % 2 == 0, "steps": 5, "benchmark_version": BENCHMARK_VERSION}
    return {**r, DIGEST_FIELD: digest} if digest else r


def run_dir(path: Path, recs: list[dict], filed: list[dict] | None = None, verdict: str = "pinned") -> Path:
    """A results folder: ``recs`` in episodes.jsonl, and a results.json written from ``filed`` (default:
    the same records) whose rows said ``verdict`` when it was written."""
    path.mkdir(parents=True)
    (path / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    doc = results_document(recs if filed is None else filed)
    for row in doc["rows"]:
        row["episodes"] = verdict
    (path / "results.json").write_text(json.dumps(doc))
    return path
