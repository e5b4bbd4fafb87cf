"""Options: exchangeable by construction, valid, unambiguous; pools: no shared question or fact."""
from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from rsb_maniskill.audit.splits import split_overlap
from rsb_maniskill.semantic import EpisodeSampler, clear_cache
from rsb_maniskill.semantic.commonsense import commonsense_pool, in_train
from rsb_maniskill.semantic.distractors import (
    Bins, inclusion_probabilities, lattice_options, numeric_options, systematic_sample, value_bins, weighted_options)
from rsb_maniskill.semantic.mmlu import exclusion_reason
from rsb_maniskill.semantic.mmlu_padding import Padding, area
from rsb_maniskill.semantic.normalize import option_key, question_key, related_words
from rsb_maniskill.semantic.records import Question

FIXTURES = Path(__file__).parent / "fixtures" / "semantic_data"
REAL_DATA_DIR = os.environ.get("RSB_DATA_DIR")


def _real_data_dir() -> Path:
    d = REAL_DATA_DIR
    if not d:
        pytest.skip("RSB_DATA_DIR is not set (CI sets RSB_DATA_DIR=../shared/data)")
    if not (Path(d) / "gsm8k" / "test.jsonl").is_file() or not (Path(d) / "mmlu" / "test").is_dir():
        pytest.skip(f"RSB_DATA_DIR={d} lacks gsm8k/ or mmlu/")
    return Path(d)


# ------------------------------------------------------------------ the sampling mechanism


def test_inclusion_probabilities_sum_and_cap():
    pi = inclusion_probabilities(np.array([10.0, 1, 1, 1, 1, 1, 1, 1]), 4)
    assert pi.sum() == pytest.approx(4) and pi.max() <= 1 + 1e-12
    assert pi[0] == 1.0 and np.allclose(pi[1:], 3 / 7)  # the heavy member is capped, the rest share
    with pytest.raises(ValueError):
        inclusion_probabilities(np.ones(3), 4)


def test_systematic_sample_size_membership_and_inclusion():
    rng = np.random.default_rng(0)
    w = np.array([1.0, 2, 3, 4, 2, 1, 3, 2, 2])
    pi = inclusion_probabilities(w, 4)
    hits = np.zeros(len(w))
    for _ in range(4000):
        idx = systematic_sample(pi, 2, rng)
        assert len(idx) == len(set(idx.tolist())) == 4 and 2 in idx
        hits[idx] += 1
    # conditioned on member 2 the others are included at P(i | 2), all well inside (0, 1)
    assert hits[2] == 4000 and (hits > 0).all()


def test_bins_make_the_answer_exchangeable():
    """The property itself: draw an answer from a skewed distribution (atoms included), draw its
    option set, and check every value is the answer in 1/N of the sets it appears in."""
    rng = np.random.default_rng(1)
    values = np.r_[np.repeat([2, 3, 4, 5, 10], [40, 25, 35, 38, 33]), rng.integers(6, 200, size=400)]
    n = 4
    bins = value_bins(values.tolist(), n)
    seen, answer = Counter(), Counter()
    rank = Counter()
    for _ in range(30000):
        a = int(values[rng.integers(len(values))])
        opts = numeric_options(a, bins, n, rng)
        assert opts[0] == a and len(set(opts)) == n
        seen.update(opts)
        answer[a] += 1
        rank[sorted(opts).index(a)] += 1
    for v in (2, 3, 4, 5, 10):  # the atoms are answers no more often than any other member
        assert answer[v] / seen[v] == pytest.approx(1 / n, abs=0.03)
    assert all(abs(rank[r] / 30000 - 1 / n) < 0.02 for r in range(n))  # "smallest", "largest", ... at chance


def test_bins_cut_gives_room_for_every_member():
    counts = [(v, c) for v, c in zip(range(30), [50] + [1] * 29)]
    b = Bins.cut(counts, 4)
    for lo, hi in zip(b.edges, b.edges[1:]):
        assert hi - lo >= 8
        assert b.weights[lo:hi].max() <= b.weights[lo:hi].sum() / 4 + 1e-9 or hi == len(counts)


def test_numeric_options_sign_and_fallback():
    rng = np.random.default_rng(2)
    bins = value_bins(list(range(0, 60)), 10)
    for a in (0, 7, 59, -7, -30):
        opts = numeric_options(a, bins, 10, rng)
        assert opts[0] == a and len(set(opts)) == 10
        assert all(v < 0 for v in opts) if a < 0 else all(v >= 0 for v in opts)
    for a in (3, 1234, -2):  # no bins: the lattice, same rules
        opts = lattice_options(a, 10, rng)
        assert opts[0] == a and len(set(opts)) == 10
        assert all(v < 0 for v in opts) if a < 0 else all(v >= 0 for v in opts)


def test_weighted_options_are_distinct_and_keep_the_answer():
    rng = np.random.default_rng(3)
    cands = [(f"t{i}", float(1 + i % 3)) for i in range(12)]
    for _ in range(200):
        out = weighted_options("answer", cands, 2.0, 4, rng)
        assert out[0] == "answer" and len(set(out)) == 4


# ------------------------------------------------------------------ suites


def test_math_options_are_answers_of_the_same_operation():
    """Math distractors are answers of other questions of the same form in the same split."""
    s = EpisodeSampler("RSB-Math-10", "test")
    by_op: dict[str, set[str]] = {}
    for q in s.pool.questions:
        by_op.setdefault(q.group, set()).add(q.answer)
    for seed in range(300):
        sp = s.episode(seed)
        q = s.question(sp.question_id)
        assert sp.correct_option == q.answer
        assert set(sp.options) <= by_op[q.group]
        assert len(set(sp.options)) == 10 and all(int(o) >= 10 for o in sp.options)


def test_correct_letter_and_block_uniform():
    s = EpisodeSampler("RSB-Math-4", "test", color_map="shuffle")
    specs = [s.episode(10_000_000 + i) for i in range(4000)]
    for counts in (Counter(sp.answer_slot for sp in specs), Counter(sp.target_block for sp in specs)):
        assert all(abs(c / 4000 - 0.25) < 0.03 for c in counts.values())


def test_commonsense_options_share_no_word_with_the_question():
    for split in ("train", "test"):
        for item in commonsense_pool(split):
            q = item.question
            assert not related_words(q.answer, q.text), q.text
            assert all(not related_words(c, q.text) for c, _ in item.candidates), q.text
            assert len(item.candidates) >= 9  # ten distinct options from the split alone


def test_commonsense_facts_never_cross_splits():
    train, test = commonsense_pool("train"), commonsense_pool("test")
    assert not {i.question.fact for i in train} & {i.question.fact for i in test}
    assert all(in_train(i.question.fact) for i in train) and not any(in_train(i.question.fact) for i in test)
    # distractors come from the same split's answers: a test option was never a training answer
    train_answers = {i.question.answer for i in train}
    test_texts = {c for i in test for c, _ in i.candidates} | {i.question.answer for i in test}
    assert not train_answers & test_texts
    overlap = split_overlap([i.question.text for i in train], [i.question.text for i in test],
                            [i.question.fact for i in train], [i.question.fact for i in test])
    assert overlap.clean, (overlap.exact[:3], overlap.near[:3])


def test_option_key_normal_forms():
    assert option_key("De-excitation.") == option_key("de-excitation")
    assert option_key("1.5 x 10^8 m/s") == option_key("1.5 * 10^8 m/s") == option_key("1.5 × 10^8 m/s")
    assert option_key("1,000") == option_key("1000") and option_key("3.50") == option_key("3.5")
    assert option_key("the  Red block") == option_key("the red block.")
    assert option_key("12") != option_key("21")
    assert question_key("about 0.6c. How much work") == question_key("about 0.6c . How much work")
    assert question_key("in parallel in a circuit, the current") == question_key("in parallel in a circuit the current")


def test_mmlu_exclusions():
    row = dict(question="What is the capital of France?", choices=["Paris", "Lyon", "Nice", "Lille"], answer=0)
    assert exclusion_reason(row) is None
    assert exclusion_reason({**row, "choices": ["Paris", "paris.", "Nice", "Lille"]}) == "duplicate options"
    assert exclusion_reason({**row, "choices": ["2 m/s", "4 m/s", "6 m/s", "8 m/s"]}) == "numeric options centred on the answer"
    assert exclusion_reason({**row, "choices": ["Paris, capital", "Lyon", "Nice", "Lille"]}) == \
        "option shares a word with the question"


def _mmlu(i: int, subject: str, text: str, answer: str, others: tuple[str, ...]) -> Question:
    return Question(text, answer, "mmlu", subject, choices=(answer, *others), origin=f"row {i}")


def test_padding_groups_shapes_and_blocked_answers():
    qs = [_mmlu(i, subj, f"Question number {i} about topic {subj}?", f"ans{i}", (f"x{i}a", f"x{i}b", f"x{i}c"))
          for i, subj in enumerate(["philosophy", "anatomy", "astronomy", "sociology"] * 6)]
    # another row with question 0's text: its answer would be right for question 0 too
    blocked = {question_key(qs[0].text): {option_key("ans5")}}
    pad = Padding(qs, blocked)
    owner = {c: i for i, q in enumerate(qs) for c in q.choices}
    rng = np.random.default_rng(0)
    shapes = Counter()
    for _ in range(400):
        opts = pad.options(0, 10, rng)
        assert opts[0] == "ans0" and len({option_key(o) for o in opts}) == 10
        assert "ans5" not in opts
        groups = Counter(owner[o] for o in opts)
        shapes[groups[0]] += 1
        assert sorted(groups.values()) == [2, 4, 4]
        for k in groups:  # every group shows its own answer; padding comes from other subject areas
            assert qs[k].answer in opts
            assert k == 0 or area(qs[k].group) != area("philosophy")
    assert shapes[2] / 400 == pytest.approx(0.2, abs=0.06)  # the asked group is the short one 2/10 of the time


@pytest.mark.parametrize("suite_id", ["RSB-HardMath-4", "RSB-HardMath-10"])
def test_fixture_pools_still_give_valid_options(suite_id):
    clear_cache()
    s = EpisodeSampler(suite_id, "train", data_dir=FIXTURES)
    for seed in range(40):
        sp = s.episode(seed)
        assert len({option_key(o) for o in sp.options}) == sp.n_choices


# ------------------------------------------------------------------ real data, many episodes


@pytest.mark.parametrize("suite_id", ["RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4", "RSB-HardMath-10",
                                      "RSB-General-4", "RSB-General-10", "RSB-Direct-4", "RSB-Direct-10"])
def test_no_second_answer_in_50000_episodes(suite_id):
    d = None if suite_id.split("-")[1] in ("Math", "Direct") else _real_data_dir()
    s = EpisodeSampler(suite_id, "test", data_dir=d)
    for seed in range(10_000_000, 10_050_000):
        sp = s.episode(seed)
        keys = [option_key(o) for o in sp.options]
        assert keys.count(keys[sp.answer_slot]) == 1, (seed, sp.options)


@pytest.mark.data
@pytest.mark.parametrize("suite", ["HardMath", "General"])
def test_no_shared_or_near_duplicate_question_across_splits(suite):
    d = _real_data_dir()
    train = EpisodeSampler(f"RSB-{suite}-4", "train", data_dir=d).pool.questions
    test = EpisodeSampler(f"RSB-{suite}-4", "test", data_dir=d).pool.questions
    overlap = split_overlap([q.text for q in train], [q.text for q in test], [q.fact for q in train],
                            [q.fact for q in test])
    assert overlap.clean, (overlap.exact[:3], overlap.near[:3], overlap.facts[:3])


def test_math_pools_share_no_question_or_operand_pair():
    train = EpisodeSampler("RSB-Math-4", "train").pool.questions
    test = EpisodeSampler("RSB-Math-4", "test").pool.questions
    assert split_overlap([q.text for q in train], [q.text for q in test], [q.fact for q in train],
                         [q.fact for q in test]).clean
