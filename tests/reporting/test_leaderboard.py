"""`rsb leaderboard`: runs of the three harnesses (a real `rsb eval`, records as the LeRobot env writes them,
a vla-eval results file from vla-eval's own collector) and a full-protocol run side by side; what it refuses
(two benchmark versions, two protocols) and marks; the vla-eval export against vla-eval's own schema; and the
page in headless Chromium (intervals, sorting, the metric toggle)."""
from __future__ import annotations

import csv
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest
from vla_eval.results.collector import ResultCollector

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.metrics import PAPER_SUITES, wilson_interval
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
from rsb_maniskill.evaluation.records import LEROBOT_RUNNER, build_record
from rsb_maniskill.integrations.lerobot_env import append_record
from rsb_maniskill.integrations.vla_eval import RSBBenchmark
from rsb_maniskill.reporting.leaderboard import RANDOM, load_run
from rsb_maniskill.reporting.results import results_document
from rsb_maniskill.reporting.vla_eval_leaderboard import benchmark_entry, benchmark_key, vla_eval_document
from rsb_maniskill.semantic import EpisodeSampler
from rsb_maniskill.version import BENCHMARK_VERSION

from cdp_browser import Browser, _chromium, checked_screenshot

REPO = Path(__file__).resolve().parents[2]
VLA_EVAL_SCHEMAS = Path(__file__).resolve().parents[1] / "fixtures" / "vla_eval_leaderboard"


def outcomes(n_success: int, n_wrong: int, n_none: int) -> list[tuple[bool, bool]]:
    """(grasped, success) of each episode: successes, then wrong grasps, then no grasp."""
    return [(True, True)] * n_success + [(True, False)] * n_wrong + [(False, False)] * n_none


def records(policy: str, suite: str, n_success: int, n_wrong: int, n_none: int, *, mode: str = "normal",
            version: str = BENCHMARK_VERSION, first: int = EVAL_SEED_BASE, **extra) -> list[dict]:
    """Records with the fields `rsb eval` writes (without the episode spec)."""
    return [{"policy": policy, "suite_id": suite, "seed": first + i, "question_id": i, "instruction": "x",
             "instruction_mode": mode, "target_block": 0, "correct_letter": "A", "first_grasped": 0 if g else -1,
             "grasped_any": g, "grasped_correct": ok, "placed_correct": ok, "placed_wrong": False, "success": ok,
             "steps": 10, "benchmark_version": version, **extra}
            for i, (g, ok) in enumerate(outcomes(n_success, n_wrong, n_none))]


def write_dir(path: Path, recs: list[dict], checkpoints: dict[str, str] | None = None) -> Path:
    """A results directory as `rsb eval` leaves it: its records, and run.json with the checkpoints."""
    path.mkdir(parents=True, exist_ok=True)
    (path / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    if checkpoints:
        runs = {p: {"policy": p, "checkpoint": c, "rsb_version": "0.2.0", "code_commit": None}
                for p, c in checkpoints.items()}
        (path / "run.json").write_text(json.dumps({"runs": runs}))
    return path


def snapshot(path: Path) -> dict[str, tuple[int, int]]:
    return {str(f.relative_to(path)): (f.stat().st_size, f.stat().st_mtime_ns) for f in path.rglob("*")}


def write_vla_eval(path: Path, counts: dict[str, tuple[int, int, int]], errored: int = 0) -> Path:
    """A `vla-eval run` output directory of RSBBenchmark, from vla-eval's own collector: its episodes'
    metrics are RSB records plus gsr / tsr; the last ``errored`` episodes of the first suite ended with an
    error (no metrics, a failure_reason)."""
    path.mkdir(parents=True)
    collector = ResultCollector("RSBBenchmark", metric_keys=RSBBenchmark("RSB-Math-4").get_metric_keys())
    for suite, (k, wrong, none) in counts.items():
        for i, r in enumerate(records("pi05-rsb", suite, k, wrong, none)):
            collector.record(suite, {"episode_id": i, "metrics": {**r, "gsr": r["grasped_any"], "tsr": r["success"]},
                                     "steps": 10})
    suite, n = next(iter(counts)), sum(next(iter(counts.values())))
    for i in range(n, n + errored):
        collector.record(suite, {"episode_id": i, "metrics": {"success": False}, "failure_reason": "timeout",
                                 "suite": suite, "episode_idx": i})
    result = collector.get_benchmark_result(config={"params": {"policy_name": "pi05-rsb"}})
    (path / "RSBBenchmark_aggregate.json").write_text(json.dumps(result))
    return path


# ---------------------------------------------------------------- the runs
@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("runs")
    # RSB's own: a real `rsb eval` (oracle; blind with normal and blank instructions: two protocols)
    rsb = root / "rsb"
    common = ["--suites", "RSB-Math-4", "RSB-Math-10", "-n", "2", "--out", str(rsb), "-q"]
    assert main(["eval", "oracle", "--checkpoint", "scripted-v1", *common]) == 0
    assert main(["eval", "blind", "--instruction", "normal", "blank", *common]) == 0

    # lerobot-eval's records_dir: the records RSBLeRobotEnv writes (build_record from the episode's spec and
    # the env's last info, runner lerobot-eval, appended under its file lock), 20 protocol episodes a suite
    lerobot = root / "lerobot_records"
    for suite, (k, wrong, none) in {"RSB-Math-4": (5, 10, 5), "RSB-Math-10": (2, 14, 4)}.items():
        sampler = EpisodeSampler(suite, "test", "unseen")
        for i, (grasped, ok) in enumerate(outcomes(k, wrong, none)):
            spec = sampler.episode(EVAL_SEED_BASE + i)
            info = {"success": ok, "grasped_any": grasped, "grasped_correct": ok, "placed_correct": ok,
                    "placed_wrong": False, "first_grasped": spec.target_block if ok else (-1 if not grasped else 9)}
            append_record(lerobot / "episodes.jsonl", build_record(
                suite_id=suite, seed=EVAL_SEED_BASE + i, spec=spec, instruction=spec.instruction,
                instruction_mode="normal", info=info, steps=120, policy="act-tiny",
                extra={"original_instruction": spec.instruction, "runner": LEROBOT_RUNNER}))

    # a `vla-eval run` output directory: vla-eval's own collector over RSBBenchmark's metrics (each an RSB
    # record plus gsr / tsr)
    vla = write_vla_eval(root / "vla_eval_out", {"RSB-Math-4": (12, 12, 7), "RSB-General-4": (20, 6, 4)})

    # the whole protocol: the paper's six suites, 500 episodes each
    full = write_dir(root / "full", [r for i, s in enumerate(PAPER_SUITES) for r in records("pi0", s, 100 + 20 * i,
                                                                                            300 - 20 * i, 100)],
                     {"pi0": "hf:me/pi0@3f2a"})
    return {"rsb": rsb, "lerobot": lerobot, "vla": vla, "full": full, "root": root}


def leaderboard(capsys, *argv: str) -> tuple[int, str, str]:
    rc = main(["leaderboard", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def md_row(md: str, label: str, table: int = 0) -> list[str]:
    """The cells of ``label``'s row in the ``table``-th table of leaderboard.md."""
    rows = [line for line in md.split("### ")[table + 1].splitlines() if line.startswith(f"| {label} ")]
    assert len(rows) == 1, (label, rows)
    return [c.strip() for c in rows[0].strip("|").split("|")]


def test_three_harnesses_side_by_side(runs, tmp_path, capsys):
    inputs = [runs["rsb"], runs["lerobot"], runs["vla"], runs["full"]]
    before = {p: snapshot(p) for p in inputs}
    out = tmp_path / "board"
    rc, shown, err = leaderboard(capsys, *inputs, "--out", out, "--protocol", "normal")
    assert rc == 0, err
    assert "5 model(s) on 6 suite(s)" in shown
    assert {p: snapshot(p) for p in inputs} == before  # the runs are only read
    md = (out / "leaderboard.md").read_text()
    assert "Benchmark: RSB-MS 1.1. Protocol: normal instructions, no perturbation" in md
    head = next(line for line in md.splitlines() if line.startswith("| Model"))
    assert head.split("|")[2:10] == [" Math-4 ", " Math-10 ", " HardMath-4 ", " HardMath-10 ", " General-4 ",
                                     " General-10 ", " Avg ", " Episodes / suite "]
    # the full-protocol run: no mark, a complete Avg, its checkpoint and protocol tags
    pi0 = md_row(md, "pi0")
    assert pi0[1] == "20.0 [16.7, 23.7]" and pi0[7] == "30.0" and pi0[8:12] == [
        "500", "hf:me/pi0@3f2a", "normal · unperturbed · test/unseen", "RSB-MS 1.1"]
    # short runs are marked, their Avg over the suites they ran is starred
    oracle = md_row(md, "oracle †")
    assert oracle[1:3] == ["100.0 [34.2, 100.0]"] * 2 and oracle[7] == "100.0\\*" and oracle[9] == "scripted-v1"
    assert md_row(md, "blind †")[8] == "2"
    lerobot = md_row(md, "act-tiny †")
    assert lerobot[1] == "25.0 [11.2, 46.9]" and lerobot[3] == "—" and lerobot[8] == "20"
    vla = md_row(md, "pi05-rsb †")
    assert vla[1] == "38.7 [23.7, 56.2]" and vla[5] == "66.7 [48.8, 80.8]" and vla[8] == "30–31"
    assert md_row(md, RANDOM)[1:8] == ["25.0", "10.0", "25.0", "10.0", "25.0", "10.0", "17.5"]
    assert md_row(md, RANDOM, 1)[1] == "not defined" and md_row(md, RANDOM, 2)[1] == "0.0"
    order = [line.split("|")[1].strip() for line in md.split("### ")[1].splitlines() if line.startswith("| ")][1:]
    assert order == ["oracle †", "pi05-rsb †", "pi0", "blind †", "act-tiny †", RANDOM]  # by Avg TSR, Random last

    rows = list(csv.DictReader(io.StringIO((out / "leaderboard.csv").read_text())))
    act = next(r for r in rows if r["model"] == "act-tiny" and r["suite_id"] == "RSB-Math-4")
    assert (float(act["tsr"]), int(act["n_episodes"]), act["short"]) == (0.25, 20, "True")
    assert (float(act["tsr_low"]), float(act["tsr_high"])) == pytest.approx(wilson_interval(5, 20))
    assert act["run"] == str(runs["lerobot"]) and act["benchmark_version"] == BENCHMARK_VERSION
    random10 = next(r for r in rows if r["model"] == RANDOM and r["suite_id"] == "RSB-General-10")
    assert (float(random10["tsr"]), float(random10["nsg"]), random10["gsr"]) == (0.1, 0.0, "")
    avg = next(r for r in rows if r["model"] == "pi0" and r["suite_id"] == "Avg")
    assert (float(avg["tsr"]), avg["avg_complete"], avg["short"]) == (pytest.approx(0.3), "True", "False")

    page = (out / "index.html").read_text()
    assert not re.search(r"https?://|<link|\ssrc=", page), "the page must load nothing"
    assert page.count("<tr") == 1 + 6 and 'id="board"' in page


def test_refuses_two_protocols_or_versions_in_one_line(runs, tmp_path, capsys):
    out = tmp_path / "board"
    rc, _, err = leaderboard(capsys, runs["rsb"], "--out", out)  # blind ran normal and blank instructions
    assert rc == 2 and err.count("\n") == 1 and not out.exists()
    assert "normal instructions (oracle, blind); blank instructions (blind (blank))" in err
    assert "pick one with --protocol normal (or blank)" in err and "a separate --out" in err

    old = write_dir(tmp_path / "old", records("pi0", "RSB-Math-4", 3, 2, 1, version="1.0"))
    rc, _, err = leaderboard(capsys, runs["full"], old, "--out", out)
    assert rc == 2 and err.count("\n") == 1 and not out.exists()
    assert f"cannot put RSB-MS 1.0 ({old}) and RSB-MS 1.1 ({runs['full']}) in one column" in err

    camera = write_dir(tmp_path / "camera", records("pi0-cam", "RSB-Math-4", 3, 2, 1, perturb="camera=2"))
    rc, _, err = leaderboard(capsys, runs["full"], camera, "--out", out)
    assert rc == 2 and "no perturbation (pi0); perturbation camera=2 (pi0-cam [camera=2])" in err
    assert "--perturb none (or camera=2)" in err and not out.exists()
    assert leaderboard(capsys, runs["full"], camera, "--out", out, "--perturb", "none")[0] == 0
    assert "pi0-cam" not in (out / "leaderboard.md").read_text()
    rc, _, err = leaderboard(capsys, runs["full"], "--out", out, "--protocol", "shuffled")
    assert rc == 2 and "no row of shuffled instructions in the runs given: they hold normal instructions" in err


def test_marks_and_labels(runs, tmp_path, capsys):
    a = write_dir(tmp_path / "a", records("pi05", "RSB-Math-4", 9, 1, 0), {"pi05": "step-1000"})
    b = write_dir(tmp_path / "b", records("pi05", "RSB-Math-4", 3, 7, 0), {"pi05": "step-2000"})
    c = write_dir(tmp_path / "c", records("pi05", "RSB-Math-4", 5, 5, 0, first=0), {"pi05": "step-2000"})
    assert leaderboard(capsys, a, b, "--out", tmp_path / "ab")[0] == 0
    md = (tmp_path / "ab" / "leaderboard.md").read_text()
    assert md_row(md, "pi05 @ step-1000 †")[1].startswith("90.0")
    assert md_row(md, "pi05 @ step-2000 †§")  # same seeds: paired, 6 of 6 discordant pairs for a (p = 0.031)
    assert leaderboard(capsys, b, c, "--out", tmp_path / "bc")[0] == 0  # same checkpoint: told apart by run
    md = (tmp_path / "bc" / "leaderboard.md").read_text()
    assert md_row(md, f"pi05 ({b}) †") and md_row(md, f"pi05 ({c}) †‡")  # c: not the protocol's seeds
    doc = results_document(records("pi05", "RSB-Math-4", 5, 5, 0))
    (a / "results.json").write_text(json.dumps(doc))  # a run shared as its results.json
    rc, _, err = leaderboard(capsys, a, a / "results.json", "--out", tmp_path / "twice")
    assert rc == 2 and f"{a} and {a / 'results.json'} are the same run" in err
    assert load_run(a / "results.json").doc["rows"][0]["suites"]["RSB-Math-4"]["n"] == 10


def test_a_vla_eval_run_with_an_errored_episode(tmp_path, capsys):
    """An episode vla-eval ended with an error counts as a failure of the run's benchmark version."""
    vla = write_vla_eval(tmp_path / "vla", {"RSB-Math-4": (12, 12, 6)}, errored=1)
    with pytest.warns(UserWarning, match="1 episode"):
        rc, _, err = leaderboard(capsys, vla, "--out", tmp_path / "board")
    assert rc == 0, err  # the errored episode counts as a failure: 12 of 31
    assert md_row((tmp_path / "board" / "leaderboard.md").read_text(), "pi05-rsb †")[1].startswith("38.7 [")


def test_bad_inputs_say_what_and_write_nothing(runs, tmp_path, capsys):
    out = tmp_path / "board"
    rc, _, err = leaderboard(capsys, tmp_path / "nowhere", "--out", out)
    assert rc == 2 and "nowhere: no such file or directory" in err
    (tmp_path / "summary.json").write_text(json.dumps({"rows": {}}))
    rc, _, err = leaderboard(capsys, tmp_path / "summary.json", "--out", out)
    assert rc == 2 and "not an RSB results.json" in err
    rc, _, err = leaderboard(capsys, runs["full"], "--out", runs["full"])
    assert rc == 2 and "is a run given" in err
    rc, _, err = leaderboard(capsys, runs["full"])
    assert rc == 2 and "give --out DIR" in err
    assert not out.exists() and not (runs["full"] / "index.html").exists()


# ---------------------------------------------------------------- vla-eval's leaderboard records
def test_vla_eval_records_follow_vla_eval_schema(runs, tmp_path, capsys):
    schema = json.loads((VLA_EVAL_SCHEMAS / "leaderboard.schema.json").read_text())
    target = tmp_path / "export" / "rsb.vla-eval.json"
    rc, shown, err = leaderboard(capsys, runs["rsb"], runs["full"], "--vla-eval", target, "--weight-type",
                                 "finetuned", "--curated-by", "@rsb-tests")
    assert rc == 0, err
    doc = json.loads(target.read_text())
    jsonschema.Draft7Validator(schema, format_checker=jsonschema.FormatChecker()).validate(doc)
    entries = {e["display_name"]: e for e in doc["results"]}
    assert list(entries) == ["blind", "oracle", "pi0"]  # sorted by (benchmark, model), as vla-eval keeps them
    key = benchmark_key(BENCHMARK_VERSION)
    assert key == "rsb_ms_v1_1" and {e["benchmark"] for e in entries.values()} == {key}
    pi0 = entries["pi0"]
    assert pi0["overall_score"] == 30.0 and pi0["suite_scores"]["math_4_normal"] == 20.0
    assert pi0["task_scores"]["math_4_gsr_normal"] == 80.0 and "Checkpoint: hf:me/pi0@3f2a." in pi0["notes"]
    assert entries["oracle"]["overall_score"] is None and "overall_score null" in entries["oracle"]["notes"]
    blind = entries["blind"]
    assert sorted(blind["suite_scores"]) == ["math_10_blank", "math_10_normal", "math_4_blank", "math_4_normal"]
    assert "blank: 2 episodes per suite (fewer than the protocol's)" in blind["notes"]
    # vla-eval's rules beyond the schema (validate.py): scores in [0, 100], every key ends in a declared protocol
    # suffix, one entry per (model, benchmark, weight_type), overall_score the mean of the aggregation keys
    registry = benchmark_entry(BENCHMARK_VERSION)
    jsonschema.validate(registry, json.loads((VLA_EVAL_SCHEMAS / "benchmarks.schema.json").read_text()))
    rule = registry[key]
    for e in entries.values():
        for scores in (e["suite_scores"], e["task_scores"]):
            assert all(0 <= v <= 100 and k.rsplit("_", 1)[1] in rule["score_key_suffixes"] for k, v in scores.items())
    assert len({(e["model"], e["benchmark"], e["weight_type"]) for e in entries.values()}) == 3
    mean = sum(pi0["suite_scores"][k] for k in rule["aggregation"]["keys"]) / len(rule["aggregation"]["keys"])
    assert abs(pi0["overall_score"] - round(mean, 1)) <= 0.25 and set(pi0["suite_scores"]) <= set(rule["suites"])
    # the schema can fail: an extra field, or a score that is not a number
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**doc, "results": [{**pi0, "nsg": 1.0}]}, schema)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({**doc, "results": [{**pi0, "suite_scores": {"math_4_normal": None}}]}, schema)


def test_vla_eval_export_needs_its_fields(runs, tmp_path, capsys):
    target = tmp_path / "x.json"
    rc, _, err = leaderboard(capsys, runs["full"], "--vla-eval", target)
    assert rc == 2 and "--vla-eval needs --weight-type shared" in err
    rc, _, err = leaderboard(capsys, runs["full"], "--vla-eval", target, "--weight-type", "shared",
                             "--curated-by", "me")
    assert rc == 2 and "curated_by 'me'" in err and not target.exists()
    unversioned = write_dir(tmp_path / "u", [{k: v for k, v in r.items() if k != "benchmark_version"}
                                             for r in records("old", "RSB-Math-4", 1, 1, 1)])
    rc, _, err = leaderboard(capsys, unversioned, "--vla-eval", target, "--weight-type", "shared")
    assert rc == 2 and "unversioned records" in err and not target.exists()
    doc = vla_eval_document([(load_run(runs["full"]), load_run(runs["full"]).doc["rows"][0])], "shared",
                            today="2026-11-25")
    assert doc["last_updated"] == doc["results"][0]["date_added"] == "2026-11-25"


def test_leaderboard_loads_no_simulator(runs, tmp_path):
    code = (f"import json, sys; from rsb_maniskill.cli import main; "
            f"rc = main(['leaderboard', {str(runs['full'])!r}, '--out', {str(tmp_path / 'b')!r}]); "
            "print(json.dumps([rc] + [m for m in ('torch', 'sapien', 'mani_skill') if m in sys.modules]))")
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert json.loads(got.stdout.strip().splitlines()[-1]) == [0], got.stderr[-2000:]


# ---------------------------------------------------------------- the page, in a real browser
def _order(b: Browser) -> list[str]:
    return b.evaluate('[...document.querySelectorAll("#board tbody tr")].map(r => r.cells[0].dataset.value)')


def _shown(b: Browser, model: str, column: int) -> str:
    """The visible text of a cell (innerText leaves out the metrics the page hides)."""
    return b.evaluate(f"""[...document.querySelectorAll("#board tbody tr")]
        .find(r => r.cells[0].dataset.value === {json.dumps(model)}).cells[{column}].innerText.replace(/\\s+/g, " ")""")


def _click(b: Browser, selector: str) -> None:
    b.evaluate(f"document.querySelector({json.dumps(selector)}).click()")


@pytest.mark.timeout(300)
def test_page_in_headless_chromium(runs, tmp_path, capsys):
    out = tmp_path / "board"
    assert leaderboard(capsys, runs["rsb"], runs["lerobot"], runs["vla"], runs["full"], "--out", out,
                       "--protocol", "normal")[0] == 0
    with Browser(_chromium(), width=1500, height=700) as b:
        b.open((out / "index.html").resolve().as_uri())
        default = ["oracle", "pi05-rsb", "pi0", "blind", "act-tiny", RANDOM]
        assert _order(b) == default
        assert _shown(b, "pi0", 1) == "20.0 [16.7, 23.7]" and _shown(b, RANDOM, 1) == "25.0 1/4"
        assert _shown(b, "act-tiny", 3) == "—"  # a suite it did not run
        # sorting: General-4 (column 5), highest first, rows without it last; again: lowest first
        _click(b, "#board thead th:nth-child(6)")
        assert _order(b) == ["pi05-rsb", "pi0", RANDOM, "oracle", "blind", "act-tiny"]
        _click(b, "#board thead th:nth-child(6)")
        assert _order(b) == [RANDOM, "pi0", "pi05-rsb", "oracle", "blind", "act-tiny"]
        # the metric toggle: cells show GSR, the sort follows it; Random's GSR is not defined
        _click(b, 'button[data-metric="gsr"]')
        pressed = 'document.querySelector(\'button[data-metric="gsr"]\').getAttribute("aria-pressed")'
        assert b.evaluate(pressed) == "true"
        assert _shown(b, "pi0", 1) == "80.0 [76.3, 83.3]" and _shown(b, RANDOM, 1) == "not defined"
        assert _order(b) == ["pi0", "pi05-rsb", RANDOM, "oracle", "blind", "act-tiny"]  # still lowest first
        _click(b, 'button[data-metric="nsg"]')
        assert _shown(b, RANDOM, 5) == "0.0 by definition" and _shown(b, "pi0", 1).startswith("0.0 [")
        _click(b, "#board thead th:nth-child(1)")  # by name
        assert _order(b) == ["act-tiny", "blind", "oracle", "pi0", "pi05-rsb", RANDOM]
        _click(b, 'button[data-metric="tsr"]')
        shot = checked_screenshot(b, tmp_path / "leaderboard.png", "RSB_LEADERBOARD_SCREENSHOT")
    import cv2

    img = cv2.imread(str(shot))
    assert img is not None and img.shape[1] >= 1400 and img.std() > 20
