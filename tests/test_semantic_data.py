"""GSM8K / MMLU loading: data directory, hub path, parsing, clear errors naming file and line."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

import huggingface_hub
from rsb_maniskill.semantic import DataNotFoundError, EpisodeSampler, SemanticDataError, clear_cache
from rsb_maniskill.semantic import data as data_mod
from rsb_maniskill.semantic.gsm8k import clean_solution, gsm8k_pool, parse_final_answer
from rsb_maniskill.semantic.mmlu import exclusion_reason

FIXTURES = Path(__file__).parent / "fixtures" / "semantic_data"
REAL_DATA_DIR = os.environ.get("RSB_DATA_DIR")  # read before the autouse fixture clears it


@pytest.fixture(autouse=True)
def _fresh(monkeypatch):
    monkeypatch.delenv("RSB_DATA_DIR", raising=False)
    clear_cache()
    yield
    clear_cache()


def test_parse_final_answer():
    assert parse_final_answer("x\n#### 72") == (72, 0)
    assert parse_final_answer("x\n#### 1,200") == (1200, 0)
    assert parse_final_answer("x\n#### -5") == (-5, 0)
    assert parse_final_answer("x\n#### 1.5") == (15, 1)
    assert parse_final_answer("#### 3 #### 12,345,678") == (12345678, 0)
    for bad in ("no marker 12", "#### twelve", "#### 1,2,3", "#### "):
        with pytest.raises(ValueError):
            parse_final_answer(bad)


def test_clean_solution_strips_annotations():
    s = clean_solution("He read 6 * 5 = <<6*5=30>>30 pages\nThen 30 + 4 = <<30+4=34>>34.\n#### 34")
    assert s == "He read 6 * 5 = 30 pages. Then 30 + 4 = 34."


def test_gsm8k_fixture_pool():
    train = gsm8k_pool("train", FIXTURES)
    assert len(train) == 6
    assert [q.answer for q in train] == ["19", "1200", "-5", "34", "6", "0"]
    test = gsm8k_pool("test", FIXTURES)
    assert [q.answer for q in test] == ["120", "83", "1.5", "3"]


def test_gsm8k_options_keep_sign_and_format():
    for split in ("train", "test"):
        for n in (4, 10):
            s = EpisodeSampler(f"RSB-HardMath-{n}", split, data_dir=FIXTURES)
            for seed in range(60):
                spec = s.sample(seed)
                ans = spec.options[spec.answer_slot]
                vals = [float(o) for o in spec.options]
                assert len(set(vals)) == n
                if float(ans) < 0:
                    assert all(v < 0 for v in vals)
                else:
                    assert all(v >= 0 for v in vals)
                if "." in ans:  # decimals: every option has the same precision
                    assert all(len(o.split(".")[-1]) == len(ans.split(".")[-1]) for o in spec.options if "." in o)
                assert f"The answer is {ans}." in spec.rationale


@pytest.mark.parametrize("line, reason", [
    ('{"question": "q"}', "missing or empty field 'answer'"),
    ('{"question": "q", "answer": "so 4"}', "no '####'"),
    ('{"question": "q", "answer": "#### four"}', "cannot parse final answer"),
    ('{"question": "q", "answer": "#### 4"', "invalid JSON"),
])
def test_gsm8k_malformed_names_file_and_line(tmp_path, line, reason):
    d = tmp_path / "gsm8k"
    d.mkdir()
    good = json.dumps({"question": "q1", "answer": "#### 1"})
    (d / "train.jsonl").write_text(f"{good}\n{good}\n{line}\n")
    with pytest.raises(SemanticDataError) as err:
        gsm8k_pool("train", tmp_path)
    assert "train.jsonl, line 3" in str(err.value) and reason in str(err.value)
    assert err.value.line == 3


@pytest.mark.parametrize("row, reason", [
    ("q,a,b,c,A\n", "expected 6 columns"),
    ("q,a,b,c,d,E\n", "answer must be one of A-D"),
    ("q,a,b,c,d,e,A\n", "expected 6 columns"),
])
def test_mmlu_malformed_names_file_and_line(tmp_path, row, reason):
    d = tmp_path / "mmlu" / "test"
    d.mkdir(parents=True)
    f = d / "anatomy_test.csv"
    f.write_text('"multi\nline question",a,b,c,d,A\n' + row)
    with pytest.raises(SemanticDataError) as err:
        EpisodeSampler("RSB-General-4", data_dir=tmp_path)
    assert "anatomy_test.csv, line 3" in str(err.value) and reason in str(err.value)


def test_mmlu_filters():
    mk = lambda opts, q="q?": {"question": q, "choices": opts, "answer": 0}
    assert exclusion_reason(mk(["a", "b", "c", "d"])) is None
    assert exclusion_reason(mk(["a", "b", "All of the above", "d"])) == "option refers to other options"
    assert exclusion_reason(mk(["a", "b", "A and B", "d"])) == "option refers to other options"
    assert exclusion_reason(mk(["Only one", "b", "c", "d"])) is None
    assert exclusion_reason(mk(["a", "A", "c", "d"])) == "duplicate options"
    assert exclusion_reason(mk(["a", "b", "c", "d"], q="x" * 2000)) == "question too long"


def test_missing_data_names_both_ways(monkeypatch, tmp_path):
    def offline(*a, **k):
        raise OSError("network unreachable")
    monkeypatch.setattr(huggingface_hub, "hf_hub_download", offline)
    with pytest.raises(DataNotFoundError) as err:
        EpisodeSampler("RSB-HardMath-4")
    msg = str(err.value)
    assert "RSB_DATA_DIR" in msg and "rsb data download" in msg and "openai/gsm8k" in msg
    # an explicit directory without the files is an error too (no silent fallback)
    with pytest.raises(DataNotFoundError, match="gsm8k"):
        EpisodeSampler("RSB-HardMath-4", data_dir=tmp_path)
    with pytest.raises(DataNotFoundError, match="mmlu"):
        EpisodeSampler("RSB-General-4", data_dir=tmp_path)


def test_env_var_is_used(monkeypatch):
    monkeypatch.setenv("RSB_DATA_DIR", str(FIXTURES))
    assert EpisodeSampler("RSB-HardMath-4", "test").num_questions == 4


def test_hub_path_uses_pinned_revisions(monkeypatch, tmp_path):
    """No directory: files come from hf_hub_download at the pinned revisions (cache first)."""
    calls = []
    gsm_rows = {"train": [{"question": "Q1 has 3 and 4?", "answer": "3+4=<<3+4=7>>7\n#### 7"}],
                "test": [{"question": "Q2?", "answer": "#### 1,024"}]}
    mmlu_rows = [{"question": f"Question {i}?", "subject": "toy", "choices": [f"a{i}", f"bb{i}", f"c{i}", f"dd{i}"],
                  "answer": i % 4} for i in range(30)]

    def fake_download(repo_id, filename, repo_type=None, revision=None, local_files_only=False, **kw):
        calls.append((repo_id, filename, repo_type, revision, local_files_only))
        return str(tmp_path / repo_id.replace("/", "_") / filename)

    def fake_read(path):
        p = str(path)
        if "gsm8k" in p:
            return gsm_rows["train" if "train" in p else "test"]
        return mmlu_rows if "test-" in p else []

    monkeypatch.setattr(huggingface_hub, "hf_hub_download", fake_download)
    monkeypatch.setattr(data_mod, "read_parquet_rows", fake_read)
    assert [q.answer for q in gsm8k_pool("test")] == ["1024"]
    assert calls[0] == ("openai/gsm8k", "main/test-00000-of-00001.parquet", "dataset", data_mod.GSM8K_REVISION, True)
    s = EpisodeSampler("RSB-General-10", "train")
    assert s.pool.source_counts["mmlu"] > 0
    assert ("cais/mmlu", "all/test-00000-of-00001.parquet", "dataset", data_mod.MMLU_REVISION, True) in calls
    assert len(data_mod.GSM8K_REVISION) == 40 and len(data_mod.MMLU_REVISION) == 40


def test_hub_parquet_roundtrip(monkeypatch, tmp_path):
    """With pyarrow (the `hub` extra) the real parquet layout is read, and `rsb data download
    --export` writes a directory in the original formats."""
    pa = pytest.importorskip("pyarrow", reason="pyarrow not installed (pip install 'rsb_maniskill[hub]')")
    import pyarrow.parquet as pq
    files = {
        "main/train-00000-of-00001.parquet": {"question": ["Q a?"], "answer": ["#### 5"]},
        "main/test-00000-of-00001.parquet": {"question": ["Q b?"], "answer": ["#### -2"]},
        "all/test-00000-of-00001.parquet": {"question": ["M?"], "subject": ["toy"],
                                            "choices": [["w", "x", "y", "z"]], "answer": [2]},
        "all/dev-00000-of-00001.parquet": {"question": ["N?"], "subject": ["toy"],
                                           "choices": [["p", "q", "r", "s"]], "answer": [0]},
    }
    for fn, cols in files.items():
        out = tmp_path / "hub" / fn
        out.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table(cols), out)
    monkeypatch.setattr(huggingface_hub, "hf_hub_download", lambda repo, fn, **kw: str(tmp_path / "hub" / fn))
    assert [q.answer for q in gsm8k_pool("test")] == ["-2"]
    data_mod.download_hub_data(tmp_path / "export")
    assert (tmp_path / "export" / "mmlu" / "test" / "toy_test.csv").read_text().strip() == "M?,w,x,y,z,C"
    assert [q.answer for q in gsm8k_pool("train", tmp_path / "export")] == ["5"]


def _real_data_dir() -> Path:
    d = REAL_DATA_DIR
    if not d:
        pytest.skip("RSB_DATA_DIR is not set (CI sets RSB_DATA_DIR=../shared/data)")
    if not (Path(d) / "gsm8k" / "train.jsonl").is_file():
        pytest.skip(f"RSB_DATA_DIR={d} holds no gsm8k/train.jsonl")
    return Path(d)


@pytest.mark.data
def test_real_pool_sizes():
    d = _real_data_dir()
    assert EpisodeSampler("RSB-HardMath-4", "train", data_dir=d).num_questions == 7473
    assert EpisodeSampler("RSB-HardMath-10", "test", data_dir=d).num_questions == 1319
    train = EpisodeSampler("RSB-General-4", "train", data_dir=d)
    test = EpisodeSampler("RSB-General-10", "test", data_dir=d)
    # MMLU rows whose options repeat a question word, or are all numbers, are left out
    # (docs/semantic.md); the train pool takes every other eligible row, up to 10,000 questions
    assert 4000 < train.num_questions <= 10_000
    assert train.pool.excluded["option shares a word with the question"] > 5000
    assert test.num_questions > 1000  # the 500 evaluation episodes ask 500 different questions
    assert not {q.text for q in train.pool.questions} & {q.text for q in test.pool.questions}
    assert train.pool.source_counts["commonsense"] > 400
