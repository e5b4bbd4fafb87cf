"""`rsb questions`, `rsb stats`, `rsb data` through the real dispatcher."""
from __future__ import annotations

import json
import os
from pathlib import Path

import huggingface_hub
import pytest

from rsb_maniskill import network
from rsb_maniskill.cli import main
from rsb_maniskill.semantic import EpisodeSampler

FIXTURES = Path(__file__).parents[1] / "fixtures" / "semantic_data"
REAL_DATA_DIR = os.environ.get("RSB_DATA_DIR")  # read before the autouse fixture clears it


pytestmark = pytest.mark.usefixtures("no_data_dir")  # RSB_DATA_DIR unset, pools uncached


def test_questions_prints_episodes(capsys):
    assert main(["questions", "RSB-HardMath-10", "--split", "test", "-n", "3", "--data-dir", str(FIXTURES)]) == 0
    out = capsys.readouterr().out
    assert out.count("=== RSB-HardMath-10 test") == 3
    assert out.count("instruction: ") == 3 and out.count("answer: ") == 3
    assert "(K)" in out and "(J)" not in out


def test_questions_json(capsys):
    assert main(["questions", "RSB-Math-4", "-n", "2", "--seed", "5", "--json"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [json.loads(line)["seed"] for line in lines] == [5, 6]


def test_questions_errors(capsys):
    assert main(["questions", "RSB-Poetry-4"]) == 2  # a usage error, as in every command naming suites
    assert "unknown suite 'RSB-Poetry-4'; valid: a suite id (RSB-Math-4" in capsys.readouterr().err
    assert main(["questions"]) == 2
    assert "rsb questions: error: name at least one SUITE" in capsys.readouterr().err
    assert main(["questions", "RSB-Math-4", "--split", "validation"]) == 2  # a usage error (issue 60: 2 as elsewhere)
    assert "unknown split" in capsys.readouterr().err


def test_suites_by_spaces_commas_and_release_names(capsys):
    """One suite list form everywhere: space- or comma-separated ids, groups, release task names."""
    assert main(["questions", "rsb_math_10blocks,RSB-Direct-4", "RSB-Math-4-Objects", "-n", "1"]) == 0
    heads = [ln.split()[1] for ln in capsys.readouterr().out.splitlines() if ln.startswith("=== ")]
    assert heads == ["RSB-Math-10", "RSB-Direct-4", "RSB-Math-4-Objects"]
    assert main(["stats", "--suites", "RSB-Math-4,", "RSB-Direct-10-Objects"]) == 0
    rows = [ln.split()[0] for ln in capsys.readouterr().out.splitlines() if ln.startswith("RSB-")]
    assert rows == ["RSB-Math-4", "RSB-Direct-10"]


def test_stats_with_fixtures(capsys):
    assert main(["stats", "--data-dir", str(FIXTURES)]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith("RSB-")}
    assert set(rows) == {"RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4", "RSB-HardMath-10", "RSB-General-4",
                         "RSB-General-10", "RSB-Direct-4", "RSB-Direct-10"}
    assert rows["RSB-Math-4"][-2:] == ["500", "1,000"]
    assert rows["RSB-HardMath-10"][-2:] == ["6", "4"]
    assert rows["RSB-Direct-10"][-2:] == ["10", "10"]
    assert "General train mix: commonsense" in out


def test_stats_without_data_says_how(capsys, monkeypatch):
    monkeypatch.setattr(huggingface_hub, "try_to_load_from_cache", lambda *a, **k: None)
    monkeypatch.setenv("RSB_OFFLINE", "1")
    assert main(["stats"]) == 1
    out = capsys.readouterr().out
    assert "RSB-Math-4" in out and "n/a" in out and "RSB_DATA_DIR" in out and "rsb data download" in out
    assert out.count("note: ") == 1 and "offline (RSB_OFFLINE" in out  # one message, not one per pool


def test_data_download_reports_failure(capsys, monkeypatch):
    monkeypatch.setattr(huggingface_hub, "try_to_load_from_cache", lambda *a, **k: None)
    monkeypatch.setattr(network, "unreachable", lambda url: None)  # the hub answers, the download fails
    monkeypatch.setattr(huggingface_hub, "hf_hub_download", lambda *a, **k: (_ for _ in ()).throw(OSError("offline")))
    assert main(["data", "download"]) == 1
    assert "hub download" in capsys.readouterr().err


@pytest.mark.data
def test_stats_real_data(capsys):
    d = REAL_DATA_DIR
    if not d or not Path(d, "gsm8k", "train.jsonl").is_file():
        pytest.skip("RSB_DATA_DIR is not set or holds no data (CI sets RSB_DATA_DIR=../shared/data)")
    assert main(["stats", "--data-dir", d]) == 0
    rows = {line.split()[0]: line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("RSB-")}
    assert rows["RSB-HardMath-4"][-2:] == ["7,473", "1,319"]
    assert rows["RSB-General-10"][-2] == f"{EpisodeSampler('RSB-General-10', 'train', data_dir=d).num_questions:,}"
