"""Results that prove their episodes: every record carries an episode digest; report, --compare and
the leaderboard mark (or refuse) a run whose episodes are not the version's (GSM8K cut to 100 rows);
a resume on another question pool is refused; records without digests read as unverified."""
from __future__ import annotations

import csv
import io
import json
import os
import shutil
from pathlib import Path

import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.provenance import DIFFER, PINNED, UNVERIFIED, check_records
from rsb_maniskill.evaluation.records import DIGEST_FIELD

pytestmark = pytest.mark.data  # the real GSM8K (RSB_DATA_DIR), cut to 100 rows for the other pool
SUITE = "RSB-HardMath-4"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    real = Path(os.environ.get("RSB_DATA_DIR", "/work/shared/data"))
    if not (real / "gsm8k" / "test.jsonl").exists():
        pytest.skip("needs the real GSM8K in RSB_DATA_DIR")
    root = tmp_path_factory.mktemp("prov")
    cut = root / "data"
    (cut / "gsm8k").mkdir(parents=True)
    for name in ("test.jsonl", "train.jsonl"):
        lines = (real / "gsm8k" / name).read_text().splitlines(keepends=True)
        (cut / "gsm8k" / name).write_text("".join(lines[:100]))
    for other in real.iterdir():
        if other.is_dir() and other.name != "gsm8k":
            (cut / other.name).symlink_to(other)
    common = ["--suites", SUITE, "-n", "2", "--obs-mode", "state", "-q"]
    assert main(["eval", "random", *common, "--out", str(root / "full")]) == 0
    assert main(["eval", "random", *common, "--name", "random-cut", "--data-dir", str(cut),
                 "--out", str(root / "cut")]) == 0
    return {"full": root / "full", "cut": root / "cut", "data": cut, "root": root}


def records(d: Path) -> list[dict]:
    return [json.loads(x) for x in (d / "episodes.jsonl").read_text().splitlines()]


def test_records_carry_a_digest_checked_against_the_version(runs):
    full, cut = records(runs["full"]), records(runs["cut"])
    assert all(len(r[DIGEST_FIELD]) == 16 for r in full + cut)
    assert check_records(full).verdict == PINNED and check_records(cut).verdict == DIFFER
    assert [r[DIGEST_FIELD] for r in full] != [r[DIGEST_FIELD] for r in cut]  # same seeds, other questions
    old = [{k: v for k, v in r.items() if k != DIGEST_FIELD} for r in full]  # a run from before digests
    assert check_records(old).verdict == UNVERIFIED and "unverified" in check_records(old).text()


def test_report_and_compare_mark_the_other_pool(runs, capsys):
    assert main(["report", str(runs["cut"])]) == 0
    out = capsys.readouterr().out
    assert "episodes differ from RSB-MS 1.1" in out and SUITE in out.splitlines()[-1]
    row = json.loads((runs["cut"] / "results.json").read_text())["rows"][0]
    assert row["episodes"] == DIFFER
    assert main(["report", str(runs["full"])]) == 0
    assert "episodes: 2 of RSB-MS 1.1, each checked" in capsys.readouterr().out
    # same seeds, other questions: not pairs; refused with the reason
    assert main(["report", "--compare", str(runs["full"]), str(runs["cut"])]) == 2
    err = capsys.readouterr().err
    assert "same seeds but not the same episodes" in err and len(err.strip().splitlines()) == 1
    twin = runs["root"] / "full-copy"  # a run compared with itself is refused (test_faults): its copy stands in
    if not twin.exists():
        shutil.copytree(runs["full"], twin)
    assert main(["report", "--compare", str(runs["full"]), str(twin)]) == 0
    assert f"{runs['full']}: episodes: 2 of RSB-MS 1.1" in capsys.readouterr().out
    # a results.json shared alone: its rows' verdict
    alone = runs["root"] / "cut-results"
    alone.mkdir()
    (alone / "results.json").write_bytes((runs["cut"] / "results.json").read_bytes())
    assert main(["report", "--compare", str(alone), str(runs["full"])]) == 0
    assert f"{alone}: episodes differ (its results.json)" in capsys.readouterr().out


def test_the_leaderboard_refuses_the_other_pool_unless_allowed(runs, tmp_path, capsys):
    rc = main(["leaderboard", str(runs["full"]), str(runs["cut"]), "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert rc == 2 and "episodes differ from RSB-MS 1.1" in err and "--allow-other-episodes" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "b").exists()
    assert main(["leaderboard", str(runs["full"]), str(runs["cut"]), "--out", str(tmp_path / "b"),
                 "--allow-other-episodes"]) == 0
    md = (tmp_path / "b" / "leaderboard.md").read_text()
    assert "random-cut †\u2260" in md and "episodes differ from RSB-MS 1.1" in md
    assert "from the best row's (random)" in md  # a row of other episodes is never the yardstick
    rows = list(csv.DictReader(io.StringIO((tmp_path / "b" / "leaderboard.csv").read_text())))
    assert {r["model"]: r["episodes"] for r in rows if r["suite_id"] == SUITE} == \
        {"random": PINNED, "random-cut": DIFFER, "Random (1/N)": ""}


def test_a_resume_on_another_question_pool_is_refused(runs, capsys):
    before = (runs["cut"] / "episodes.jsonl").read_bytes()
    rc = main(["eval", "random", "--suites", SUITE, "-n", "3", "--obs-mode", "state", "-q", "--name", "random-cut",
               "--out", str(runs["cut"])])  # the full data now: the cut run's questions are not these
    err = capsys.readouterr().err
    assert rc == 2 and "two question pools" in err and len(err.strip().splitlines()) == 1
    assert (runs["cut"] / "episodes.jsonl").read_bytes() == before
    assert main(["eval", "random", "--suites", SUITE, "-n", "3", "--obs-mode", "state", "-q", "--name",
                 "random-cut", "--data-dir", str(runs["data"]), "--out", str(runs["cut"])]) == 0  # same pool: resumes
    assert len(records(runs["cut"])) == 3


def test_the_pinned_eval_digest_is_unchanged():
    """The canonical form moved to semantic/digest.py (one owner): rsb verify's pins still hold."""
    from rsb_maniskill.audit import golden

    assert golden.suite_digests("RSB-Math-4")["eval"] == golden.load()["suites"]["RSB-Math-4"]["eval"]


def test_the_pinned_pools_are_those_of_the_pinned_episodes():
    """provenance.PINNED_POOLS (the data a record is checked on must be the version's) hold the pools
    of the data whose evaluation episodes audit/golden_episodes.json pins."""
    import hashlib

    from rsb_maniskill.audit import golden
    from rsb_maniskill.evaluation.provenance import PINNED_POOLS, data_pinned, pool_digest
    from rsb_maniskill.semantic.pools import get_pool

    if not (Path(os.environ.get("RSB_DATA_DIR") or "/nonexistent") / "gsm8k" / "test.jsonl").exists():
        pytest.skip("needs the real GSM8K and MMLU-Pro in RSB_DATA_DIR")
    for name, suite in (("HardMath", "RSB-HardMath-4"), ("General", "RSB-General-4")):
        h = hashlib.sha256()
        for episode in golden.iter_episodes(suite, "eval"):
            h.update(golden.canonical_line(episode))
        assert h.hexdigest() == golden.load()["suites"][suite]["eval"]  # this data is the pinned one
        assert pool_digest(get_pool(name, "test")) == PINNED_POOLS[name]
        assert data_pinned(suite, None, os.environ.get("RSB_DATA_DIR"))
