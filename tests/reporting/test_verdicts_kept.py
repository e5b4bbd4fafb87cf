"""A verdict proven once does not decay: a results folder whose results.json says its episodes are the
version's (``pinned``, checked when they ran) keeps it when a later ``rsb report`` finds no question data
to check them on, and says "not re-checked: no data"; the leaderboard names missing data as the reason
a row is unverified, not "records without episode digests" for records that carry them."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from verdict_runs import NOT_RECHECKED, episode, run_dir

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.records import DIGEST_FIELD


def report(capsys, folder: Path) -> tuple[str, dict, dict, str]:
    """``rsb report FOLDER``: its stdout, results.json, summary.json and the first line of summary.md."""
    capsys.readouterr()
    assert main(["report", str(folder)]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    return (out, json.loads((folder / "results.json").read_text()), json.loads((folder / "summary.json").read_text()),
            (folder / "summary.md").read_text().splitlines()[0])


@pytest.mark.usefixtures("no_data")
def test_a_report_without_data_keeps_pinned_and_says_so(tmp_path, capsys):
    folder = run_dir(tmp_path / "r", [episode(i) for i in range(3)])
    for _ in range(2):  # and a second report, of the file the first one wrote
        out, results, summary, first = report(capsys, folder)
        assert [row["episodes"] for row in results["rows"]] == ["pinned"] and summary["episodes"] == "pinned"
        assert NOT_RECHECKED in out.splitlines()[-1] and NOT_RECHECKED in first
        assert NOT_RECHECKED in (folder / "report.html").read_text()


@pytest.mark.usefixtures("no_data")
def test_episodes_the_file_did_not_prove_are_not_kept(tmp_path, capsys):
    """Run since (a fourth episode), or never pinned: the file proves nothing about them."""
    recs = [episode(i) for i in range(4)]
    out, results, summary, first = report(capsys, run_dir(tmp_path / "more", recs, filed=recs[:3]))
    assert results["rows"][0]["episodes"] == "unverified" and summary["episodes"] == "unverified"
    assert "episodes unverified: not checked, no data (4 of 4 records carry digests" in out
    out, results, _, _ = report(capsys, run_dir(tmp_path / "never", recs, verdict="unverified"))
    assert results["rows"][0]["episodes"] == "unverified" and NOT_RECHECKED not in out


@pytest.mark.usefixtures("no_data")
def test_the_leaderboard_names_the_true_reason(tmp_path, capsys):
    with_digests = run_dir(tmp_path / "a", [episode(i) for i in range(3)], verdict="unverified")
    without = run_dir(tmp_path / "b", [episode(i, digest=None, policy="old") for i in range(3)], verdict="unverified")
    filed = run_dir(tmp_path / "c", [episode(i, policy="shared") for i in range(3)], verdict="unverified")
    (filed / "episodes.jsonl").unlink()  # a results.json shared alone
    capsys.readouterr()
    assert main(["leaderboard", str(with_digests), str(without), str(filed / "results.json"), "--out",
                 str(tmp_path / "board")]) == 0, capsys.readouterr().err
    notes = [line.removeprefix("- ") for line in (tmp_path / "board" / "leaderboard.md").read_text().splitlines()
             if "unverified" in line or "not checked" in line]
    assert any(line.startswith("Episodes not checked: no question data at hand") and line.endswith(": pi05.")
               for line in notes), notes
    assert any("records without episode digests" in line and line.endswith(": old.") for line in notes), notes
    assert any("as their results.json says" in line and line.endswith(": shared.") for line in notes), notes
    assert not any("pi05" in line and "without episode digests" in line for line in notes), notes


@pytest.mark.data
def test_pinned_when_they_ran_kept_offline_and_the_check_wins_where_data_is(tmp_path, capsys, monkeypatch):
    """The whole story on the real GSM8K: episodes proven with the data, a report without it keeps the
    verdict, and one with the data checks again (a record edited since differs)."""
    from rsb_maniskill.evaluation.provenance import expected_digest

    real = Path(os.environ.get("RSB_DATA_DIR") or "no RSB_DATA_DIR")
    if not (real / "gsm8k" / "test.jsonl").exists():
        pytest.skip("needs the real GSM8K in RSB_DATA_DIR")
    monkeypatch.setenv("RSB_DATA_DIR", str(real))
    recs = [episode(i, digest="") for i in range(3)]
    recs = [{**r, DIGEST_FIELD: expected_digest(r)} for r in recs]
    folder = tmp_path / "r"
    folder.mkdir()
    (folder / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs))
    out, results, _, _ = report(capsys, folder)
    assert results["rows"][0]["episodes"] == "pinned" and "each checked against its digest" in out

    empty = tmp_path / "no-data"
    empty.mkdir()
    monkeypatch.setenv("RSB_DATA_DIR", str(empty))
    monkeypatch.setenv("RSB_OFFLINE", "1")
    out, results, _, _ = report(capsys, folder)
    assert results["rows"][0]["episodes"] == "pinned" and NOT_RECHECKED in out

    monkeypatch.setenv("RSB_DATA_DIR", str(real))
    edited = [recs[0], recs[1], {**recs[2], DIGEST_FIELD: "f" * 16}]
    (folder / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in edited))
    out, results, _, _ = report(capsys, folder)
    assert results["rows"][0]["episodes"] == "differ" and "episodes differ from" in out
