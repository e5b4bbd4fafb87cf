"""Question files that are there but hold no usable question: the engine says which file, that it is
empty, and how to replace it; every command turns that into one line (no ZeroDivisionError)."""
from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.semantic import DataNotFoundError, EpisodeSampler, SemanticError, get_pool, pools
from rsb_maniskill.semantic.errors import EmptyDataError
from rsb_maniskill.semantic.pools import Pool
from rsb_maniskill.semantic.suites import SuiteSource

FIXTURES = Path(__file__).parents[1] / "fixtures" / "semantic_data"
GSM8K_TEST = "gsm8k/test.jsonl"
MMLU_PRO = "mmlu_pro/data/test-00000-of-00001.parquet"


def _few_options(table: pa.Table) -> pa.Table:
    """Every row with three options: none can enter the pool (it takes ten)."""
    rows = table.to_pylist()
    for r in rows:
        r.update(options=r["options"][:3], answer_index=0, answer="A")
    return pa.Table.from_pylist(rows, schema=table.schema)


# case -> (file spoilt, how, suite whose pool reads it, what the message says is wrong)
CASES = {
    "gsm8k empty": (GSM8K_TEST, lambda p: p.write_text(""), "HardMath", "GSM8K questions (the file is empty)"),
    "gsm8k blank lines": (GSM8K_TEST, lambda p: p.write_text("\n  \n\n"), "HardMath", "only blank lines"),
    "mmlu-pro empty": (MMLU_PRO, lambda p: p.write_bytes(b""), "General", "the file is empty"),
    "mmlu-pro cut": (MMLU_PRO, lambda p: p.write_bytes(p.read_bytes()[:100]), "General", "not a readable parquet"),
    "mmlu-pro no rows": (MMLU_PRO, lambda p: pq.write_table(pq.read_table(p).slice(0, 0), p), "General",
                         "MMLU-Pro questions (a parquet table without rows)"),
    "mmlu-pro all unusable": (MMLU_PRO, lambda p: pq.write_table(_few_options(pq.read_table(p)), p), "General",
                              "rows left out: 54 fewer than 10 options"),
}


pytestmark = pytest.mark.usefixtures("no_data_dir")  # RSB_DATA_DIR unset, pools uncached


def spoilt_copy(tmp_path: Path, case: str) -> tuple[Path, Path]:
    """A copy of the fixture data directory with one file spoilt as ``case`` says: (dir, file)."""
    rel, spoil, _, _ = CASES[case]
    root = tmp_path / "data"
    shutil.copytree(FIXTURES, root)
    spoil(root / rel)
    return root, root / rel


def _assert_names_file_and_fix(msg: str, path: Path, why: str) -> None:
    assert msg.startswith(f"{path} holds no usable ") and why in msg and "pools built from it would be empty" in msg
    assert "rsb data download" in msg and "--data-dir" in msg and "RSB_DATA_DIR" in msg and "\n" not in msg


@pytest.mark.parametrize("case", CASES)
def test_the_engine_names_the_file_and_the_fix(tmp_path, case):
    root, path = spoilt_copy(tmp_path, case)
    _, _, suite, why = CASES[case]
    with pytest.raises(EmptyDataError) as err:
        get_pool(suite, "test", root)
    assert isinstance(err.value, DataNotFoundError) and isinstance(err.value, SemanticError)
    _assert_names_file_and_fix(str(err.value), path, why)
    with pytest.raises(EmptyDataError):  # the sampler (and so the env) reads through the same pools
        EpisodeSampler(f"RSB-{suite}-4", "test", data_dir=root)
    assert len(get_pool("Math", "test", root)) == 1000  # a source without data is not affected


def test_any_empty_pool_is_refused(monkeypatch):
    """A source whose builder returns no question (a registered plugin, say) fails the same way,
    instead of dividing a seed by zero later."""
    source = SuiteSource("Nothing", "none", "none", "MIT", pool=f"{__name__}:_empty_pool")
    monkeypatch.setattr(pools, "suite_source", lambda name: source)
    with pytest.raises(EmptyDataError, match=r"the Nothing test question pool \(built by .*:_empty_pool\) holds no "
                                             r"question: fetch a full copy"):
        get_pool("Nothing", "test")


def _empty_pool(split: str, data_dir: str | None) -> Pool:
    return Pool("Nothing", split, ())


def _commands(suite: str, root: Path, tmp_path: Path) -> dict[str, list[str]]:
    d = ["--data-dir", str(root)]
    return {
        "eval": ["eval", "random", "--suites", suite, "-n", "1", "--out", str(tmp_path / "eval"), "-q", *d],
        "verify": ["verify", suite, *d],
        "generate": ["generate", suite, "--split", "test", "-n", "1", "--out", str(tmp_path / "demos"), "-q", *d],
        "audit": ["audit", suite, "--split", "test", "-n", "4", *d],
        "backbone": ["backbone", "arithmetic", "--suites", suite, "-n", "1", "--out", str(tmp_path / "bb"), "-q", *d],
        "questions": ["questions", suite, "--split", "test", *d],
    }


@pytest.mark.parametrize("case, suite", [("gsm8k empty", "RSB-HardMath-4"),
                                         ("mmlu-pro all unusable", "RSB-General-10")])
@pytest.mark.parametrize("command", ["eval", "verify", "generate", "audit", "backbone", "questions"])
def test_each_command_says_it_in_one_line(tmp_path, capsys, case, suite, command):
    root, path = spoilt_copy(tmp_path, case)
    status = main(_commands(suite, root, tmp_path)[command])
    out, err = capsys.readouterr()
    assert status in (1, 2) and "Traceback" not in out + err
    said = [line for line in (out + err).splitlines() if str(path) in line]
    assert len(said) == 1, out + err
    _assert_names_file_and_fix(said[0][said[0].index(str(path)):], path, CASES[case][3])
    assert not (tmp_path / "demos").exists() and not (tmp_path / "eval").exists()


def test_stats_says_the_pool_is_empty_instead_of_zero(tmp_path, capsys, monkeypatch):
    root, path = spoilt_copy(tmp_path, "gsm8k empty")
    monkeypatch.setenv("RSB_DATA_DIR", str(root))  # the environment variable, this time
    assert main(["stats"]) == 1
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith("RSB-")}
    assert rows["RSB-HardMath-4"][-2:] == ["6", "empty"]  # the train file is whole, the test file empty
    assert rows["RSB-Math-4"][-2:] == ["500", "1,000"]
    notes = [line for line in out.splitlines() if line.startswith("note:") and str(path) in line]
    assert len(notes) == 1
    _assert_names_file_and_fix(notes[0][len("note: "):], path, "the file is empty")
