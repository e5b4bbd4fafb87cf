"""Public API of rsb_maniskill.semantic: constants, ids, EpisodeSpec, determinism."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from rsb_maniskill.objects.family import BLOCK_COLORS
from rsb_maniskill.semantic import (
    LETTERS_4,
    LETTERS_10,
    SUITE_IDS,
    DataNotFoundError,
    EpisodeSampler,
    EpisodeSpec,
    SemanticDataError,
    parse_suite_id,
)

FIXTURES = Path(__file__).parents[1] / "fixtures" / "semantic_data"
REPO = Path(__file__).resolve().parents[2]


def test_constants():
    assert LETTERS_4 == ("A", "B", "C", "D")
    assert LETTERS_10 == ("A", "B", "C", "D", "E", "F", "G", "H", "I", "K")
    assert tuple(BLOCK_COLORS) == ("red", "green", "blue", "yellow")
    assert SUITE_IDS == ("RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4", "RSB-HardMath-10",
                         "RSB-General-4", "RSB-General-10", "RSB-Direct-4", "RSB-Direct-10")
    assert issubclass(DataNotFoundError, FileNotFoundError) and issubclass(SemanticDataError, ValueError)


def test_parse_suite_id():
    assert parse_suite_id("RSB-HardMath-10") == ("HardMath", 10)
    assert parse_suite_id("RSB-Math-4") == ("Math", 4)
    for bad in ("RSB-Math-5", "rsb-math-4", "RSB-Poetry-4", "", None):
        with pytest.raises(ValueError, match="valid ids: RSB-Math-4"):
            parse_suite_id(bad)


def test_bad_arguments_are_clear():
    with pytest.raises(ValueError, match="unknown split 'val'"):
        EpisodeSampler("RSB-Math-4", "val")
    with pytest.raises(ValueError, match="instruction set"):
        EpisodeSampler("RSB-Math-4", instructions="novel")
    with pytest.raises(ValueError, match="color_map"):
        EpisodeSampler("RSB-Math-4", color_map="random")
    s = EpisodeSampler("RSB-Math-4")
    with pytest.raises(IndexError):
        s.sample(0, question_index=500)
    with pytest.raises(ValueError):
        s.sample(-1)


@pytest.mark.parametrize("suite_id", ["RSB-Math-4", "RSB-Math-10", "RSB-Direct-4", "RSB-Direct-10",
                                      "RSB-HardMath-10", "RSB-General-4", "RSB-General-10"])
def test_spec_fields_and_roundtrip(suite_id):
    s = EpisodeSampler(suite_id, "train", color_map="shuffle", data_dir=FIXTURES)
    for seed in range(30):
        spec = s.sample(seed)
        n = spec.n_choices
        assert spec.letters == (LETTERS_4 if n == 4 else LETTERS_10)
        assert len(spec.options) == n and len({o.casefold() for o in spec.options}) == n
        assert spec.correct_letter == spec.letters[spec.answer_slot]
        assert spec.target_block == spec.block_of_option[spec.answer_slot]
        assert sorted(spec.block_of_option) == list(range(n))
        if n == 10:
            assert spec.block_of_option == tuple(range(10))
            assert spec.block_names[5] == "block F"
        else:
            assert spec.block_names == ("red block", "green block", "blue block", "yellow block")
        assert spec.block_names[spec.target_block].split()[-1] in spec.rationale or \
            spec.block_names[spec.target_block] in spec.rationale
        d = json.loads(json.dumps(spec.to_dict()))
        assert EpisodeSpec.from_dict(d) == spec


def test_fixed_color_map_is_the_papers():
    s = EpisodeSampler("RSB-Math-4")
    for seed in range(20):
        spec = s.sample(seed)
        assert spec.block_of_option == (0, 1, 2, 3)
        assert spec.target_block == spec.answer_slot  # A=red, B=green, C=blue, D=yellow


def test_shuffle_color_map_varies():
    s = EpisodeSampler("RSB-Math-4", color_map="shuffle")
    maps = {s.sample(seed).block_of_option for seed in range(60)}
    assert len(maps) > 10


def test_spec_records_its_targets():
    for targets in ("blocks", "objects"):
        spec = EpisodeSampler("RSB-Math-4", targets=targets).sample(3)
        assert spec.targets == targets
        d = json.loads(json.dumps(spec.to_dict()))
        assert d["targets"] == targets and EpisodeSpec.from_dict(d) == spec
        old = {k: v for k, v in d.items() if k != "targets"}  # written before ``targets``
        assert EpisodeSpec.from_dict(old) == spec
        older = {k: v for k, v in old.items() if k != "candidates"}
        if targets == "blocks":  # written before ``candidates``: blocks
            assert EpisodeSpec.from_dict(older) == spec


def test_from_dict_rejects_bad_input():
    spec = EpisodeSampler("RSB-Math-4").sample(0)
    d = spec.to_dict()
    d.pop("rationale")
    with pytest.raises(ValueError, match="rationale"):
        EpisodeSpec.from_dict(d)
    d = spec.to_dict()
    d["family"] = "blocks"
    with pytest.raises(ValueError, match="family"):
        EpisodeSpec.from_dict(d)
    d = spec.to_dict()
    d["correct_letter"] = "Z"
    with pytest.raises(ValueError):
        EpisodeSpec.from_dict(d)


def test_deterministic_and_question_index():
    a = EpisodeSampler("RSB-Math-10", "test")
    b = EpisodeSampler("RSB-Math-10", "test")
    assert [a.sample(s) for s in range(20)] == [b.sample(s) for s in range(20)]
    assert len({a.sample(s).question_id for s in range(50)}) > 40
    for qi in (0, 7, 999):
        spec = a.sample(123, question_index=qi)
        assert spec.question_id == qi and spec.question == a.question(qi).text
    # the seed still drives the rest
    assert len({a.sample(s, question_index=3).options for s in range(10)}) > 5
    # train and test streams of the same seed differ
    assert EpisodeSampler("RSB-Math-10", "train").sample(5).question != a.sample(5).question


def test_identical_in_fresh_process():
    """Specs must not depend on PYTHONHASHSEED, import order or process state."""
    code = ("import json,sys;from rsb_maniskill.semantic import EpisodeSampler as E;"
            "print(json.dumps([E(s,sp,data_dir=sys.argv[1]).sample(k).to_dict() for s in "
            "('RSB-Math-4','RSB-General-10','RSB-HardMath-4','RSB-Direct-10') for sp in ('train','test') "
            "for k in (0,1,77)]))")
    outs = []
    for hashseed in ("1", "2"):
        res = subprocess.run([sys.executable, "-c", code, str(FIXTURES)], capture_output=True, text=True, cwd=REPO,
                             env={"PYTHONHASHSEED": hashseed, "PATH": "/usr/bin:/bin"}, check=True)
        outs.append(res.stdout)
    assert outs[0] == outs[1]
    here = [EpisodeSampler(s, sp, data_dir=FIXTURES).sample(k).to_dict() for s in
            ("RSB-Math-4", "RSB-General-10", "RSB-HardMath-4", "RSB-Direct-10") for sp in ("train", "test")
            for k in (0, 1, 77)]
    assert json.loads(outs[0]) == here


def test_direct_suites():
    for sid, n in (("RSB-Direct-4", 4), ("RSB-Direct-10", 10)):
        for split in ("train", "test"):
            s = EpisodeSampler(sid, split, color_map="shuffle")
            assert s.num_questions == n
            for seed in range(40):
                spec = s.sample(seed)
                name = spec.block_names[spec.target_block]
                assert name in spec.instruction
                assert spec.options[spec.answer_slot] == name
                assert spec.question_id == spec.target_block
                assert spec.question == ""
                others = [b for i, b in enumerate(spec.block_names) if i != spec.target_block]
                assert not any(re.search(rf"\b{o}\b", spec.instruction) for o in others)
    s = EpisodeSampler("RSB-Direct-10")
    assert s.sample(0, question_index=5).instruction.count("block F") == 1


def test_the_suite_registry_is_what_every_reader_reads(monkeypatch):
    """One registration per question source: ids, pools, Direct, `rsb stats`' column and the card."""
    from rsb_maniskill.semantic import pools, suites

    assert suites.SUITES == ("Math", "HardMath", "General", "Direct") == tuple(suites.SOURCES)
    assert SUITE_IDS == tuple(f"RSB-{s}-{n}" for s in suites.SUITES for n in (4, 10))
    assert [s.name for s in suites.SOURCES.values() if s.direct] == ["Direct"]
    assert [s.name for s in suites.SOURCES.values() if s.reads_data] == ["HardMath", "General"]
    assert EpisodeSampler("RSB-Direct-10").pool is None and EpisodeSampler("RSB-Math-10").pool.suite == "Math"
    with pytest.raises(ValueError, match="unknown question source 'Direct'; valid: Math, HardMath, General"):
        pools.get_pool("Direct", "train")
    with pytest.raises(ValueError, match="registered already"):
        suites.register_suite(suites.suite_source("Math"))
    with pytest.raises(ValueError, match="choices must be among"):
        suites.register_suite(suites.SuiteSource("Five", "x", "x", "MIT", choices=(5,)))
    # a new source: its pool builder is what get_pool calls, cached per split
    toy = suites.SuiteSource("Toy", "toy questions", "toy", "MIT", pool="rsb_maniskill.semantic.math_source:pool")
    monkeypatch.setitem(suites.SOURCES, "Toy", toy)
    assert pools.get_pool("Toy", "test") is pools.get_pool("Toy", "test")
    assert len(pools.get_pool("Toy", "test")) == 1000
    pools.clear_cache()
