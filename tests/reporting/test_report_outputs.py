"""`rsb report` writes where it is told and nothing else (issue 50), and the page's words (issue 51): its
title names the runs, p-values are worded on the side of the rule they fall, the README's video claim."""
from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.store import RecordWriter
from rsb_maniskill.reporting import writer
from rsb_maniskill.reporting.page import build_html, default_title
from rsb_maniskill.reporting.sections.bias import ALPHA, p_text

ROOT = Path(__file__).resolve().parents[2]


def _results(tmp_path: Path, policy: str = "pi0-ft") -> Path:
    out = tmp_path / "eval"
    out.mkdir()
    with RecordWriter(out / "episodes.jsonl") as w:
        for i in range(6):
            ok = i < 3
            w.write({"policy": policy, "suite_id": "RSB-Math-4", "seed": 10_000_000 + i, "instruction_mode": "normal",
                     "grasped_any": i < 5, "grasped_correct": ok, "placed_correct": ok, "placed_wrong": False,
                     "success": ok, "first_grasped": 0 if i < 5 else -1, "target_block": 0, "steps": 40,
                     "question_id": i, "instruction": "Pick the block.", "correct_letter": "A",
                     "benchmark_version": "1.1"})
    return out


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_out_an_existing_folder_puts_the_page_in_it_and_leaves_no_temp_file(tmp_path, capsys):
    src = _results(tmp_path)
    (src / "pages").mkdir()
    assert main(["report", str(src), "--out", str(src / "pages")]) == 0
    assert (src / "pages" / "report.html").read_text().startswith("<!DOCTYPE html>")
    assert not [p for p in src.rglob(".*tmp*")]


def test_a_page_that_cannot_be_written_fails_before_anything_is_written(tmp_path, capsys):
    src = _results(tmp_path)
    assert main(["report", str(src)]) == 0
    before = _tree(src)
    assert main(["report", str(src), "--out", str(tmp_path / "no" / "such" / "page.html")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rsb report: error: cannot write the page") and "not a folder" in err
    assert _tree(src) == before  # results.json and the summaries not rewritten, no stray file


def test_a_failed_page_write_leaves_no_temp_file(tmp_path, monkeypatch):
    path = tmp_path / "report.html"
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError("disk full")))
    with pytest.raises(OSError):
        writer.write_text(path, "page")
    assert list(tmp_path.iterdir()) == []


def test_a_read_only_results_folder_reports_to_a_writable_page(tmp_path, monkeypatch, capsys):
    src = _results(tmp_path)
    before = _tree(src)
    page = tmp_path / "site" / "page.html"
    page.parent.mkdir()
    if os.geteuid() == 0:  # root writes into read-only folders: say the folder is read-only as a user's would be
        monkeypatch.setattr(writer, "writable", lambda folder: Path(folder).resolve() != src.resolve())
    else:
        src.chmod(0o555)
    try:
        assert main(["report", str(src), "--out", str(page)]) == 0
    finally:
        src.chmod(0o755)
    out = capsys.readouterr().out
    assert "is read-only" in out and f"report: {page}" in out
    assert page.read_text().startswith("<!DOCTYPE html>")
    assert _tree(src) == before


def test_the_title_names_the_runs_not_the_folder(tmp_path):
    src = _results(tmp_path, policy="pi0-ft")
    from rsb_maniskill.evaluation.store import read_records

    page = build_html(read_records(src / "episodes.jsonl"), src)
    assert "<title>RSB evaluation: pi0-ft</title>" in page and "RSB evaluation: eval<" not in page
    assert default_title(["a", "b", "c", "d", "e"]) == "RSB evaluation: a, b, c and 2 more"


@pytest.mark.parametrize("p", [0.0123, 0.00996, 0.0101, 0.0149, 0.009, 0.05, 0.42, 0.0049])
def test_a_p_value_is_worded_on_its_side_of_the_rule(p):
    text = p_text(p)
    shown = float(re.fullmatch(r"p = ([0-9.e-]+)", text)[1])
    assert (shown < ALPHA) == (p < ALPHA), text
    assert abs(shown - p) / p < 0.05


def test_the_readme_promises_the_videos_the_demo_films():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    demo = (ROOT / "rsb_maniskill/commands/demo.py").read_text(encoding="utf-8")
    assert "a video each (`eval/`)" not in readme
    films = re.search(r"num_videos=(\d+)", demo)[1]
    assert films == "1" and "a video of each baseline's first episode" in readme
