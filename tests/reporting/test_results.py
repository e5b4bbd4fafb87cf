"""The benchmark version on results, results.json against its schema, `rsb report --compare`, and
no table pooling records of two benchmark versions."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import jsonschema
import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.metrics import PAPER_SUITES
from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE, EVAL_SEED_BASE
from rsb_maniskill.evaluation.records import VersionMixError, build_record
from rsb_maniskill.reporting import results as R
from rsb_maniskill.reporting.summary import results_from_records
from rsb_maniskill.reporting.writer import write_report
from rsb_maniskill.semantic import EpisodeSampler
from rsb_maniskill.version import BENCHMARK_VERSION

SCHEMA = json.loads(R.SCHEMA_FILE.read_text())


def records(policy, suite, n_success, n_wrong, n_none, mode="normal", version=BENCHMARK_VERSION, first=EVAL_SEED_BASE):
    out = []
    for i in range(n_success + n_wrong + n_none):
        ok, grasped = i < n_success, i < n_success + n_wrong
        r = {"policy": policy, "suite_id": suite, "seed": first + i, "question_id": i, "instruction": "x",
             "instruction_mode": mode, "target_block": 0, "correct_letter": "A", "first_grasped": 0 if grasped else -1,
             "grasped_any": grasped, "grasped_correct": ok, "placed_correct": ok, "placed_wrong": False, "success": ok,
             "steps": 10}
        if version is not None:
            r["benchmark_version"] = version
        out.append(r)
    return out


def write_dir(path: Path, recs: list[dict]) -> Path:
    """A results directory holding ``recs`` (as RecordWriter writes them, without its fsync per line)."""
    path.mkdir(parents=True, exist_ok=True)
    (path / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    return path


def full_run(policy: str, tsr_per_suite: int) -> list[dict]:
    """The whole protocol: the paper's six suites, 500 episodes each."""
    return [r for s in PAPER_SUITES for r in records(policy, s, tsr_per_suite, 400 - tsr_per_suite, 100)]


def test_every_record_carries_the_benchmark_version():
    spec = EpisodeSampler("RSB-Math-4", "test", "unseen").episode(EVAL_SEED_BASE)
    rec = build_record(suite_id="RSB-Math-4", seed=EVAL_SEED_BASE, spec=spec, instruction=spec.instruction,
                       instruction_mode="normal", info={"success": True}, steps=3, policy="p")
    assert rec["benchmark_version"] == BENCHMARK_VERSION


def test_results_json_follows_its_schema(tmp_path):
    recs = full_run("pi0", 250) + records("pi0", "RSB-Math-4", 10, 5, 5, mode="blank")
    d = write_dir(tmp_path, recs)
    (d / "run.json").write_text(json.dumps({"runs": {"pi0": {"checkpoint": "hf:me/pi0@abc", "rsb_version": "0.2.0",
                                                            "code_commit": None}}}))
    doc = json.loads(R.write_results(d, recs).read_text())
    jsonschema.validate(doc, SCHEMA)
    assert doc["benchmark_version"] == BENCHMARK_VERSION and doc["schema_version"] == R.SCHEMA_VERSION
    assert doc["protocol"] == {"split": "test", "instructions": "unseen", "first_seed": EVAL_SEED_BASE,
                               "episodes_per_suite": EPISODES_PER_SUITE, "avg_suites": list(PAPER_SUITES)}
    normal, blank = doc["rows"]
    assert normal["row"] == "pi0" and normal["checkpoint"] == "hf:me/pi0@abc" and normal["full_protocol"] is True
    math4 = normal["suites"]["RSB-Math-4"]
    assert math4["n"] == 500 and math4["protocol_seeds"] and math4["tsr"]["value"] == pytest.approx(0.5)
    assert math4["tsr"]["low"] < 0.5 < math4["tsr"]["high"] and normal["average"]["complete"]
    assert blank["row"] == "pi0 (blank)" and blank["full_protocol"] is False
    assert blank["suites"]["RSB-Math-4"]["n"] == 20
    broken = {**doc, "benchmark_version": 1.1}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(broken, SCHEMA)
    off = records("x", "RSB-Math-4", 1, 0, 0, first=0)  # not the protocol's seeds
    assert R.results_document(off)["rows"][0]["suites"]["RSB-Math-4"]["protocol_seeds"] is False


def test_summaries_name_the_benchmark_version(tmp_path):
    recs = records("good", "RSB-Math-4", 30, 60, 10)
    paths = write_report(results_from_records(recs), tmp_path, records=recs)
    assert json.loads(paths["json"].read_text())["benchmark_version"] == BENCHMARK_VERSION
    assert {r["benchmark_version"] for r in csv.DictReader(paths["csv"].open())} == {BENCHMARK_VERSION}
    head = paths["markdown"].read_text().splitlines()[:3]  # after the episodes' verdict, when it leads
    assert f"Benchmark: RSB-MS {BENCHMARK_VERSION}" in "\n".join(head)
    jsonschema.validate(json.loads(paths["results"].read_text()), SCHEMA)


@pytest.mark.parametrize("other, named", [("0.9", "RSB-MS 0.9"), (None, "unversioned records")])
def test_no_table_pools_two_benchmark_versions(tmp_path, capsys, other, named):
    recs = records("a", "RSB-Math-4", 5, 5, 0) + records("b", "RSB-Math-4", 5, 5, 0, version=other)
    with pytest.raises(VersionMixError):
        results_from_records(recs)
    write_dir(tmp_path, recs)
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and named in err and f"RSB-MS {BENCHMARK_VERSION}" in err
    assert not (tmp_path / "report.html").exists() and not (tmp_path / "results.json").exists()


def test_report_writes_results_json_beside_the_page(tmp_path, capsys):
    write_dir(tmp_path, records("a", "RSB-Math-4", 5, 5, 0))
    assert main(["report", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"results: {tmp_path / 'results.json'}" in out and f"RSB-MS {BENCHMARK_VERSION}" in \
        (tmp_path / "report.html").read_text()
    jsonschema.validate(json.loads((tmp_path / "results.json").read_text()), SCHEMA)


def test_compare_two_runs(tmp_path, capsys):
    a = write_dir(tmp_path / "control", full_run("pi0-control", 100))
    b = write_dir(tmp_path / "tuned", full_run("pi0-tuned", 300))
    c = write_dir(tmp_path / "same", full_run("pi0-again", 105))
    assert main(["report", "--compare", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    row = next(ln for ln in out.splitlines() if ln.startswith("| RSB-Math-4 | TSR |"))
    assert "20.0 [" in row and "60.0 [" in row and row.endswith("| +40.0 |")  # paired: tested below, not here
    assert "### pi0-control (A) vs pi0-tuned (B)" in out and f"RSB-MS {BENCHMARK_VERSION}" in out
    assert "| Avg | TSR | 20.0 | 60.0 | +40.0 |" in out
    R.write_results(b, full_run("pi0-tuned", 300))  # a shared results.json alone serves too
    (b / "episodes.jsonl").unlink()
    assert main(["report", "--compare", str(c), str(b)]) == 0
    unpaired = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| RSB-Math-4 | TSR |"))
    assert unpaired.endswith("| <0.001 | <0.001 * |")  # no records to pair: the two-proportion z test, Holm
    assert main(["report", "--compare", str(a), str(c)]) == 0
    out = capsys.readouterr().out  # 20 % against 21 %: the paired test sees 5 of 5 discordant pairs
    paired = next(ln for ln in out.splitlines()[::-1] if ln.startswith("| RSB-Math-4 | TSR | 500 / 500 |"))
    assert "| 0 / 5 |" in paired and "McNemar" in paired
    old = write_dir(tmp_path / "old", records("pi0", "RSB-Math-4", 5, 5, 0, version="0.9"))
    assert main(["report", "--compare", str(a), str(old)]) == 2
    err = capsys.readouterr().err
    assert "cannot compare" in err and "RSB-MS 0.9" in err and len(err.strip().splitlines()) == 1


def test_eval_records_the_checkpoint_and_keeps_one_version_a_directory(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["eval", "random", "--suites", "RSB-Math-4", "-n", "1", "--max-steps", "2", "-q", "--out", str(out)]
    assert main([*args, "--checkpoint", "ckpt-7"]) == 0
    doc = json.loads((out / "results.json").read_text())
    jsonschema.validate(doc, SCHEMA)
    assert doc["rows"][0]["checkpoint"] == "ckpt-7" and doc["rows"][0]["rsb_maniskill_version"]
    run = json.loads((out / "run.json").read_text())["runs"]["random"]
    assert run["benchmark_version"] == BENCHMARK_VERSION and "code_commit" in run
    assert f"Benchmark: RSB-MS {BENCHMARK_VERSION}" in capsys.readouterr().out
    assert main([*args, "--checkpoint", "ckpt-8"]) == 2  # another checkpoint is another row
    assert "checkpoint: 'ckpt-7' before, 'ckpt-8' now" in capsys.readouterr().err
    old = write_dir(tmp_path / "old", records("random", "RSB-Math-4", 1, 0, 0, version=None))
    before = (old / "episodes.jsonl").read_bytes()
    assert main([*args[:-1], str(old)]) == 2
    err = capsys.readouterr().err
    assert "unversioned records" in err and "Use another --out" in err and len(err.strip().splitlines()) == 1
    assert (old / "episodes.jsonl").read_bytes() == before and not (old / "run.json").exists()


def test_a_direct_only_run_has_no_avg_anywhere(tmp_path, capsys):
    """Avg is over the paper's suites: a run of the Direct controls alone shows n/a in summary.md,
    results.json, the page and the leaderboard alike (one rule, metrics.avg_suites)."""
    run = write_dir(tmp_path / "direct", records("a", "RSB-Direct-4", 8, 2, 0))
    assert main(["report", str(run)]) == 0
    md = (run / "summary.md").read_text()
    tsr_row = next(line for line in md.splitlines() if line.startswith("| a |"))
    assert tsr_row.rstrip().endswith("| **n/a** |"), tsr_row
    assert "Avg: n/a" in md and "Avg\\*" not in md
    avg = json.loads((run / "results.json").read_text())["rows"][0]["average"]
    assert avg["tsr"] is None and avg["suites"] == [] and avg["complete"] is False
    assert "Avg: n/a (over the paper's suites" in (run / "report.html").read_text()
    capsys.readouterr()
    assert main(["leaderboard", str(run), "--out", str(tmp_path / "board")]) == 0
    board = next((tmp_path / "board").glob("*.md")).read_text()
    assert "Avg" not in board.splitlines()[[i for i, s in enumerate(board.splitlines()) if s.startswith("| Model")][0]]
