"""Question-aware readers in `rsb audit`: what they pick, lift, the twin rule, --reader."""
from __future__ import annotations

import dataclasses
import json

import pytest

from rsb_maniskill.audit import audit_specs, lift, twin_failures
from rsb_maniskill.audit.readers import NumberReachabilityReader, SimilarityReader, bind, question_numbers
from rsb_maniskill.audit.twins import twin_key
from rsb_maniskill.cli import main
from rsb_maniskill.semantic import EpisodeSampler

EGGS = "A box holds 12 eggs. How many eggs are in 7 boxes?"


def _spec(question: str, options: tuple[str, ...], answer: int, suite_id: str = "RSB-Math-4"):
    """A real episode spec with the question, options and answer replaced."""
    sp = EpisodeSampler(suite_id, "test").episode(10_000_000)
    return dataclasses.replace(sp, question=question, options=options, answer_slot=answer,
                               correct_letter=sp.letters[answer])


def _math(suite_id: str, n: int = 150):
    s = EpisodeSampler(suite_id, "test")
    return [s.episode(10_000_000 + i) for i in range(n)]


def test_number_reachability_picks_the_product_of_two_question_numbers():
    r = NumberReachabilityReader()
    assert question_numbers(EGGS) == [12.0, 7.0]
    assert r.score(EGGS, ["90", "84", "61", "100"]) == [0.0, 2.0, 0.0, 0.0]
    a = audit_specs("RSB-Math-4", [], [_spec(EGGS, ("90", "84", "61", "100"), 1)], readers=[bind(r, r.name)])
    (row,) = a.readers
    assert row.accuracy == 1.0 and row.applies == 1 and row.lift == 1.0


def test_number_reachability_two_operations_score_below_one():
    q = "Tom has 3 bags of 4 apples and eats 2 of them. How many are left?"
    # 3 x 4 - 2 = 10 takes two operations, 3 x 4 = 12 one; 99 is out of reach
    assert NumberReachabilityReader().score(q, ["10", "12", "99", "1000"]) == [1.0, 2.0, 0.0, 0.0]


def test_number_reachability_unreachable_and_text_options():
    r = NumberReachabilityReader()
    assert r.score(EGGS, ["90", "61", "100", "3"]) == [0.0] * 4
    assert r.score(EGGS, ["a dog", "a cat", "a cow", "a hen"]) is None  # does not apply
    specs = [_spec(EGGS, ("90", "61", "100", "3"), 0), _spec(EGGS, ("dog", "cat", "cow", "hen"), 2)]
    (row,) = audit_specs("RSB-Math-4", [], specs, readers=[bind(r, r.name)]).readers
    assert row.applies == 0 and row.accuracy == pytest.approx(0.25) and row.lift == pytest.approx(0.0)


def test_similarity_reader_picks_the_related_option():
    q = "Which animal barks and wags its tail when it is happy?"
    opts = ["a spreadsheet formula", "a dog", "the planet Saturn", "a tax refund"]
    s = SimilarityReader().score(q, opts)
    assert max(range(4), key=lambda i: s[i]) == 1
    assert SimilarityReader().score("", opts) is None  # Direct suites have no question


def test_lift_and_its_interval():
    assert lift(0.25, 4) == 0.0 and lift(1.0, 4) == 1.0 and lift(0.55, 10) == pytest.approx(0.5)
    assert lift(0.1, 10) == pytest.approx(0.0) and lift(0.0, 4) == pytest.approx(-1 / 3)
    r = NumberReachabilityReader()
    (row,) = audit_specs("RSB-Math-4", [], _math("RSB-Math-4"), readers=[bind(r, r.name)]).readers
    assert row.lift_low == pytest.approx(lift(row.low, 4)) and row.lift_high == pytest.approx(lift(row.high, 4))
    assert row.lift_low <= row.lift <= row.lift_high


class _OnlyTen:
    """Reads the question only when it shows 10 options: an injected twin-rule violation."""

    name = "number reachability"

    def __init__(self):
        self.inner = NumberReachabilityReader()

    def score(self, question, options):
        return self.inner.score(question, options) if len(options) == 10 else None


def test_twin_rule_fails_when_ten_choices_lift_more():
    reader = bind(_OnlyTen(), "only ten")
    audits = [audit_specs(s, [], _math(s), readers=[reader]) for s in ("RSB-Math-4", "RSB-Math-10")]
    (fail,) = twin_failures(audits)
    assert (fail.suite, fail.twin, fail.reader) == ("RSB-Math-10", "RSB-Math-4", "number reachability")
    assert fail.lift[1] > fail.twin_lift[2]


def test_twin_rule_passes_when_lifts_are_equal():
    r = NumberReachabilityReader()  # solves RSB-Math on both (lift ~1 on 4 and 10 choices)
    audits = [audit_specs(s, [], _math(s), readers=[bind(r, r.name)]) for s in ("RSB-Math-4", "RSB-Math-10")]
    assert audits[0].readers[0].lift > 0.9 and audits[1].readers[0].lift > 0.9
    assert twin_failures(audits) == []


def test_twin_key_matches_objects_and_perturbed_names():
    a4, a10 = (audit_specs(s, [], _math(s, 5)) for s in ("RSB-Math-4", "RSB-Math-10"))
    for name4, name10 in [("RSB-Math-4-Objects", "RSB-Math-10-Objects"),
                          ("RSB-Math-4 [lang_layout=2]", "RSB-Math-10 [lang_layout=2]")]:
        a4.suite_id, a10.suite_id = name4, name10
        assert twin_key(a4) == twin_key(a10) is not None
    a4.suite_id = "RSB-Math-4 [lang_layout=1]"
    assert twin_key(a4) != twin_key(a10)


READERS_MODULE = '''
class Longest:
    name = "longest option reader"
    description = "test reader: the longest option"

    def score(self, question, options):
        return [len(o) for o in options]


def make():
    return Longest()


def missing():
    def score(question, options):
        import no_such_package_rsb  # noqa: F401
    return score
'''


@pytest.fixture
def reader_module(tmp_path, monkeypatch):
    (tmp_path / "my_rsb_readers.py").write_text(READERS_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    return "my_rsb_readers"


def test_cli_reader_factory_appears_as_a_row(reader_module, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["audit", "RSB-Math-4", "-n", "100", "--train-episodes", "0", "--no-readers", "--instruction", "normal",
               "--reader", f"{reader_module}:make", "--reader", f"{reader_module}:missing", "--out", str(out)])
    md = capsys.readouterr().out
    assert rc == 0
    (d,) = json.loads((out / "audit.json").read_text())
    rows = {r["name"]: r for r in d["readers"]}
    assert set(rows) == {"longest option reader", f"{reader_module}:missing"}
    assert rows["longest option reader"]["applies"] > 0 and rows["longest option reader"]["unavailable"] == ""
    assert "no_such_package_rsb" in rows[f"{reader_module}:missing"]["unavailable"]
    assert "| RSB-Math-4 | longest option reader |" in md and "question-aware readers (reference)" in md


def test_cli_twin_rule_exit_status(monkeypatch, tmp_path, capsys):
    (tmp_path / "tests_reader_helpers.py").write_text(
        "from rsb_maniskill.audit.readers import NumberReachabilityReader\n\n\n"
        "class OnlyTen:\n    name = 'number reachability'\n\n    def __init__(self):\n"
        "        self.inner = NumberReachabilityReader()\n\n    def score(self, q, o):\n"
        "        return self.inner.score(q, o) if len(o) == 10 else None\n\n\ndef make():\n    return OnlyTen()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    rc = main(["audit", "RSB-Math-4", "RSB-Math-10", "-n", "150", "--train-episodes", "0", "--no-readers",
               "--instruction", "normal", "--reader", "tests_reader_helpers:make", "--json"])
    cap = capsys.readouterr()
    data = json.loads(cap.out)
    assert rc == 1 and "twin rule fails: number reachability" in cap.err
    assert [d["passed"] for d in data] == [True, False] and data[1]["twin_failures"][0]["twin"] == "RSB-Math-4"


@pytest.mark.parametrize("spec, fix", [("no_such_module_rsb:make", "cannot import 'no_such_module_rsb'"),
                                       ("no_colon", "'no_colon' is not module:factory"),
                                       ("json:no_such_factory", "'json' has no callable 'no_such_factory'")])
def test_cli_bad_reader_is_a_one_line_error(spec, fix, capsys):
    rc = main(["audit", "RSB-Math-4", "-n", "10", "--reader", spec])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and fix in err
    assert "give module:factory, e.g. mypkg.readers:make" in err
