"""`rsb audit`: every suite passes; a known shortcut, injected, makes it fail."""
from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest

from rsb_maniskill.audit import audit_specs, audit_suite, credit
from rsb_maniskill.audit.guessers import named_guessers
from rsb_maniskill.audit.text import digit_string, edit_distance
from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.metrics import wilson_interval
from rsb_maniskill.semantic import EpisodeSampler

REAL_DATA_DIR = os.environ.get("RSB_DATA_DIR")
# About +-2 points at 95 % on 4 choices (+-1.3 on 10): the sample size the issue asks CI to use.
CI_EPISODES = 2000


def _data(suite_id: str):
    if suite_id.split("-")[1] in ("Math", "Direct"):
        return None
    if not REAL_DATA_DIR or not Path(REAL_DATA_DIR, "gsm8k", "test.jsonl").is_file():
        pytest.skip("RSB_DATA_DIR is not set (CI sets RSB_DATA_DIR=../shared/data)")
    return REAL_DATA_DIR


@pytest.mark.parametrize("suite_id", [
    "RSB-Math-4", "RSB-Math-10", "RSB-Direct-4", "RSB-Direct-10",
    *(pytest.param(s, marks=pytest.mark.data) for s in ("RSB-HardMath-4", "RSB-HardMath-10", "RSB-General-4",
                                                         "RSB-General-10"))])
def test_every_suite_passes_the_audit(suite_id):
    a = audit_suite(suite_id, "test", CI_EPISODES, data_dir=_data(suite_id))
    probe = next(g for g in a.guessers if g.kind == "learned")
    assert probe.high < a.chance + 0.05  # the learned probe finds nothing either
    assert a.passed, [(g.name, round(g.accuracy, 3), round(g.low, 3)) for g in a.flagged]
    assert a.ambiguous == 0 and a.overlap.clean


@pytest.mark.parametrize("suite_id", ["RSB-General-4", "RSB-General-10"])
def test_commonsense_questions_alone_pass_the_audit(suite_id):
    """The commonsense table (where "the trash can" once answered "Where is trash kept?") on its
    own; built into the project, so the MMLU part comes from the test fixtures."""
    fixtures = Path(__file__).parents[1] / "fixtures" / "semantic_data"
    tr, te = (EpisodeSampler(suite_id, split, data_dir=fixtures) for split in ("train", "test"))
    idx = {s: [i for i, q in enumerate(x.pool.questions) if q.source == "commonsense"]
           for s, x in (("tr", tr), ("te", te))}
    train = [tr.sample(k, question_index=idx["tr"][k % len(idx["tr"])]) for k in range(CI_EPISODES)]
    test = [te.sample(10_000_000 + k, question_index=idx["te"][k % len(idx["te"])]) for k in range(CI_EPISODES)]
    a = audit_specs(suite_id, train, test)
    assert a.passed, [(g.name, round(g.accuracy, 3), round(g.low, 3)) for g in a.flagged]


def _with_answer(sp, pick):
    j = pick(sp)
    return dataclasses.replace(sp, answer_slot=j, correct_letter=sp.letters[j])


def _medoid(sp):
    ds = [digit_string(float(o)) for o in sp.options]
    cost = [sum(edit_distance(a, b) for b in ds) for a in ds]
    return int(np.argmin(cost))


def test_injected_medoid_shortcut_fails_the_audit():
    """A generator whose answer is always the digit-edit medoid (the old distractor scheme)."""
    tr, te = EpisodeSampler("RSB-Math-4", "train"), EpisodeSampler("RSB-Math-4", "test")
    train = [_with_answer(tr.episode(s), _medoid) for s in range(1000)]
    test = [_with_answer(te.episode(10_000_000 + s), _medoid) for s in range(1000)]
    a = audit_specs("RSB-Math-4", train, test)
    flagged = {g.name for g in a.flagged}
    assert not a.passed and {"digit-edit medoid", "learned probe"} <= flagged


def test_injected_longest_shortcut_fails_the_audit():
    tr, te = EpisodeSampler("RSB-Direct-10", "train"), EpisodeSampler("RSB-Direct-10", "test")

    def longest(sp):
        return max(range(sp.n_choices), key=lambda i: (len(sp.options[i]), sp.options[i]))
    # Direct options are block names: make them text of different lengths first
    def lengthen(sp):
        return dataclasses.replace(sp, options=tuple(o + " x" * ((i * 7 + sp.seed) % 10)
                                                     for i, o in enumerate(sp.options)))
    train = [_with_answer(lengthen(tr.episode(s)), longest) for s in range(1000)]
    test = [_with_answer(lengthen(te.episode(10_000_000 + s)), longest) for s in range(1000)]
    a = audit_specs("RSB-Direct-10", train, test)
    assert not a.passed and {"longest", "learned probe"} <= {g.name for g in a.flagged}


def test_learned_probe_finds_a_shortcut_no_named_guesser_has():
    """Answer = the option whose value is 3 mod 7: no named rule looks at that, the trees must."""
    s = EpisodeSampler("RSB-Math-10", "train")

    def pick(sp):
        hits = [i for i, o in enumerate(sp.options) if int(o) % 7 == 3]
        return hits[0] if hits else sp.answer_slot
    specs = [_with_answer(s.episode(x), pick) for x in range(3000)]
    a = audit_specs("RSB-Math-10", specs[:2000], specs[2000:])
    assert "learned probe" in {g.name for g in a.flagged}


def _marked(sp, answer_word: str, distractor_words: tuple[str, ...]):
    """Options rewritten as text whose words alone mark the answer: every option gets a word of
    the same length, the answer one word, each distractor one of others (no shape tells them apart)."""
    def word(i: int) -> str:
        return answer_word if i == sp.answer_slot else distractor_words[(i + sp.seed) % len(distractor_words)]
    opts = tuple(f"{o} {word(i)}" for i, o in enumerate(sp.options))
    return dataclasses.replace(sp, options=opts)


def test_lexical_probe_finds_words_that_mark_the_answer():
    """The answer's option holds "north", a distractor's "south" or "lakes": same length, same
    shape, so only a model of the words can see it; the audit names the words."""
    tr, te = EpisodeSampler("RSB-Math-4", "train"), EpisodeSampler("RSB-Math-4", "test")
    train = [_marked(tr.episode(s), "north", ("south", "lakes")) for s in range(1000)]
    test = [_marked(te.episode(10_000_000 + s), "north", ("south", "lakes")) for s in range(1000)]
    a = audit_specs("RSB-Math-4", train, test)
    lexical = next(g for g in a.guessers if g.name == "lexical probe")
    assert lexical.flagged and lexical.low > 0.9 and not a.passed
    assert "north" in " ".join(t for t, _, _ in a.answer_tokens)
    assert {"south", "lakes"} & set(" ".join(t for t, _, _ in a.distractor_tokens).replace("'", " ").split())


def test_lexical_probe_is_at_chance_on_words_that_mark_nothing():
    """The same words dealt at random: the lexical probe must not invent a signal."""
    tr, te = EpisodeSampler("RSB-Math-4", "train"), EpisodeSampler("RSB-Math-4", "test")
    rng = np.random.default_rng(0)

    def noise(sp):
        return dataclasses.replace(sp, options=tuple(f"{o} {rng.choice(['north', 'south', 'lakes'])}"
                                                     for o in sp.options))
    a = audit_specs("RSB-Math-4", [noise(tr.episode(s)) for s in range(1000)],
                    [noise(te.episode(10_000_000 + s)) for s in range(1000)])
    lexical = next(g for g in a.guessers if g.name == "lexical probe")
    assert not lexical.flagged and lexical.low < 0.25 < lexical.high + 0.02


def test_train_split_audit_has_no_lexical_probe():
    """On the train split an option's words are memorised answers, and a word model fit on half of
    the split's questions reads the other half's answers as distractors (below chance): the audit
    leaves the lexical probe out there and says so."""
    a = audit_suite("RSB-Math-4", "train", 600)
    assert "lexical probe" not in {g.name for g in a.guessers} and "learned probe" in {g.name for g in a.guessers}
    from rsb_maniskill.audit.report import summary_markdown
    assert "n/a (train split)" in summary_markdown([a])


def test_numeric_guessers_read_the_number_a_text_option_starts_with():
    # any 4-choice spec with these options (Math needs no question data; the guesser reads the options)
    sp = dataclasses.replace(EpisodeSampler("RSB-Math-4", "test").sample(seed=0),
                             options=("240 grams, 6.5 grams", "220 grams, 5.75 grams", "230 grams, 6 grams",
                                      "215 grams, 5.65 grams"))
    sp = dataclasses.replace(sp, answer_slot=2, correct_letter=sp.letters[2])
    median = next(g for g in named_guessers(4, sp.letters) if g.name == "median")
    assert credit(median.score(sp), sp.answer_slot) == 0.5  # 220 and 230 are the two middle values
    assert median.score(dataclasses.replace(sp, options=("a", "b", "c", "d"))) is None


def test_made_of_others_needs_two_other_options():
    """An option that is the sum, difference or product of two *other* options; never of itself."""
    from rsb_maniskill.audit.guessers import made_of_others

    assert made_of_others(np.array([2.0, 3.0, 6.0, 9.0])) == [0.0, 1.0, 1.0, 1.0]  # 6 = 2*3, 9 = 6+3, 3 = 9-6
    assert made_of_others(np.array([1.0, 2.0, 4.0])) == [0.0, 0.0, 0.0]  # 2 = 1*2 and 4 = 2*2 use the option itself
    assert made_of_others(np.array([5.0])) == [0.0] and made_of_others(np.array([])) == []


def test_credit_splits_ties():
    assert credit([1, 3, 3, 0], 1) == 0.5 and credit([1, 3, 3, 0], 0) == 0.0 and credit([2, 2, 2, 2], 3) == 0.25


def test_guessers_score_every_option():
    sp = EpisodeSampler("RSB-Math-4", "test").episode(10_000_000)
    for g in named_guessers(4, sp.letters):
        s = g.score(sp)
        assert s is None or len(s) == 4, g.name


def test_cli_writes_json_and_markdown(tmp_path, capsys):
    rc = main(["audit", "RSB-Direct-4", "RSB-Math-10", "-n", "400", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0 and "| RSB-Math-10 | 400 |" in out and "| RSB-Math-10 [counterfactual] | 1,600 |" in out
    data = json.loads((tmp_path / "audit.json").read_text())
    assert [d["suite_id"] for d in data] == ["RSB-Direct-4", "RSB-Direct-4 [counterfactual]", "RSB-Math-10",
                                             "RSB-Math-10 [counterfactual]"] and all(d["passed"] for d in data)
    assert "### RSB-Math-10" in (tmp_path / "audit.md").read_text()
    assert main(["audit", "RSB-Direct-4", "-n", "300", "--instruction", "normal", "--json"]) == 0
    assert [d["suite_id"] for d in json.loads(capsys.readouterr().out)] == ["RSB-Direct-4"]


@pytest.mark.parametrize("suite_id", [
    "RSB-Math-4", "RSB-Math-10", "RSB-Direct-10", "RSB-Math-4-Objects",
    *(pytest.param(s, marks=pytest.mark.data) for s in ("RSB-HardMath-10", "RSB-General-4", "RSB-General-10"))])
def test_the_counterfactual_variants_pass_the_audit(suite_id):
    """Position, colour / letter / object slot, wording, option-set shape: no shortcut in the variants
    either, also for a guesser that knows the variant index; one answer per set; no train question."""
    from rsb_maniskill.audit.counterfactual import audit_variants
    from rsb_maniskill.objects.family import split_env_id

    sid, targets = split_env_id(suite_id)
    a = audit_variants(sid, 500, data_dir=_data(sid), targets=targets)
    assert a.episodes == 500 * min(a.n_choices, 4) and a.suite_id.endswith(" [counterfactual]")
    by_index = [g for g in a.guessers if "(variant " in g.name]
    assert len(by_index) == 2 * a.n_choices * 3 and all(g.applies == 500 for g in by_index)
    assert any(g.name == "mentioned first" for g in a.guessers)  # the wording guessers read the variants
    assert a.passed, [(g.name, round(g.accuracy, 3), round(g.low, 3)) for g in a.flagged]
    assert a.ambiguous == 0 and a.overlap.clean
    # the variants of a scene share its question (remaps: its options too): intervals count scenes
    largest = next(g for g in a.guessers if g.name == "largest")  # Direct: no options, so it abstains
    lo, hi = wilson_interval(round(largest.accuracy * a.episodes), a.episodes)
    assert largest.high - largest.low > 1.2 * (hi - lo) or (largest.applies == 0 and "Direct" in sid)


def test_the_design_effect_counts_a_repeated_episode_once():
    """Each outcome three times in its group: the interval of the 400 distinct ones; groups of one
    keep the plain interval (but for the n / (n - 1) of the cluster-robust variance)."""
    from rsb_maniskill.audit.reference import rate
    from rsb_maniskill.evaluation.stats import design_effect

    base = (np.random.default_rng(0).random(400) < 0.3).astype(float)
    tripled, scenes = np.repeat(base, 3), np.repeat(np.arange(400), 3)
    assert design_effect(tripled, scenes) == pytest.approx(3 * 400 / 399)
    acc, lo, hi = rate(tripled, scenes)
    lo1, hi1 = wilson_interval(base.sum() * 399 / 400, 399)
    assert acc == pytest.approx(base.mean()) and (lo, hi) == pytest.approx((lo1, hi1))
    assert (lo, hi) == pytest.approx(rate(base)[1:], abs=0.002)  # 400 distinct episodes, not 1,200
    assert rate(base, np.arange(400))[1:] == pytest.approx(rate(base)[1:], abs=0.001)
    # no variance to estimate it from (issue 59): the groups' sizes, a question counted once
    assert design_effect(np.ones(30), np.repeat(np.arange(10), 3)) == 3.0


def test_audit_intervals_count_questions_not_episodes():
    """The same 300 episodes audited three times over: each interval is (about) that of the 300
    (a guesser's view of a question does not change when it is asked again); Direct suites ask no
    question, so their episodes are their own groups."""
    from rsb_maniskill.audit.run import question_clusters

    te = EpisodeSampler("RSB-Math-4", "test")
    once = [te.episode(10_000_000 + i) for i in range(300)]
    a1, a3 = audit_specs("once", [], once), audit_specs("thrice", [], once * 3)
    for name in ("largest", "median", "letter A"):
        g1, g3 = (next(g for g in a.guessers if g.name == name) for a in (a1, a3))
        assert g3.accuracy == pytest.approx(g1.accuracy)
        assert (g3.low, g3.high) == pytest.approx((g1.low, g1.high), abs=0.004), name
    assert len(set(question_clusters(once * 3))) == len({sp.question_id for sp in once})
    direct = [EpisodeSampler("RSB-Direct-4", "test").episode(10_000_000 + i) for i in range(50)]
    assert len(set(question_clusters(direct))) == 50  # not its 4 target "questions"


def test_an_index_shortcut_in_the_variants_fails_the_audit():
    """Variants whose variant-1 answer always sits on candidate 0 (what a biased target order would
    give): the guesser that knows the variant index is right every time it applies."""
    from rsb_maniskill.audit.counterfactual import index_guessers, variant_episodes
    from rsb_maniskill.semantic import counterfactual as cf

    te = EpisodeSampler("RSB-Math-4", "test")
    specs, index = variant_episodes(te, range(10_000_000, 10_000_400))
    fair = audit_specs("fair", [], specs, guessers=index_guessers(specs, index, 4, te.letters))
    assert fair.passed
    rigged = [sp if k != 1 else cf._onto(te, sp, 0) for sp, k in zip(specs, index)]
    a = audit_specs("rigged", [], rigged, guessers=index_guessers(rigged, index, 4, te.letters))
    g = next(g for g in a.guessers if g.name == "block 0 (variant 1)")
    assert g.flagged and g.applies == 400 and g.applies_accuracy == 1.0
    assert not any(f.name.endswith(("(variant 2)", "(variant 3)")) for f in a.flagged)


def test_cli_counterfactual_needs_the_test_split(capsys):
    assert main(["audit", "RSB-Direct-4", "--split", "train", "--instruction", "counterfactual"]) == 2
    assert "use --split test" in capsys.readouterr().err


def test_cli_exit_1_on_a_shortcut_in_user_specs(tmp_path, capsys):
    """Users audit their own option sets from spec files; a shortcut there gives exit status 1."""
    tr, te = EpisodeSampler("RSB-Math-4", "train"), EpisodeSampler("RSB-Math-4", "test")
    path = tmp_path / "specs.jsonl"
    with open(path, "w") as fh:
        for sp in [_with_answer(tr.episode(s), _medoid) for s in range(600)] + \
                  [_with_answer(te.episode(10_000_000 + s), _medoid) for s in range(600)]:
            fh.write(json.dumps(sp.to_dict()) + "\n")
    assert main(["audit", "--specs", str(path)]) == 1
    assert "**FAIL**" in capsys.readouterr().out


def test_cli_prints_the_words_that_fail_a_suite(tmp_path, capsys):
    tr, te = EpisodeSampler("RSB-Math-4", "train"), EpisodeSampler("RSB-Math-4", "test")
    path = tmp_path / "specs.jsonl"
    with open(path, "w") as fh:
        for sp in [_marked(tr.episode(s), "north", ("south",)) for s in range(600)] + \
                  [_marked(te.episode(10_000_000 + s), "north", ("south",)) for s in range(600)]:
            fh.write(json.dumps(sp.to_dict()) + "\n")
    assert main(["audit", "--specs", str(path), "--no-readers"]) == 1
    captured = capsys.readouterr()
    assert "| lexical probe |" in captured.out
    assert "RSB-Math-4: Lexical probe: n-grams marking the answer: " in captured.err and "north" in captured.err


@pytest.mark.parametrize("argv, message", [
    (["audit", "RSB-Nope-4"], "unknown suite 'RSB-Nope-4'"),
    (["audit"], "name at least one SUITE"),
    (["audit", "--specs", "/nonexistent/specs.jsonl"], "no such file /nonexistent/specs.jsonl"),
])
def test_cli_bad_input(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_cli_bad_spec_line(tmp_path, capsys):
    p = tmp_path / "bad.jsonl"
    p.write_text('{"suite_id": "x"}\n')
    assert main(["audit", "--specs", str(p)]) == 2
    assert f"{p}, line 1: not an episode spec" in capsys.readouterr().err
