"""Options: exchangeable by construction, valid, unambiguous; pools: no shared question or fact."""
from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from rsb_maniskill.audit.splits import split_overlap
from rsb_maniskill.semantic import EpisodeSampler, clear_cache, mmlu_pro
from rsb_maniskill.semantic.commonsense import commonsense_pool, in_train
from rsb_maniskill.semantic.distractors import (
    Bins,
    inclusion_probabilities,
    lattice_options,
    numeric_options,
    systematic_sample,
    value_bins,
    weighted_options,
)
from rsb_maniskill.semantic.mmlu_pro import exclusion_reason
from rsb_maniskill.semantic.normalize import option_key, question_key, related_words

FIXTURES = Path(__file__).parents[1] / "fixtures" / "semantic_data"
REAL_DATA_DIR = os.environ.get("RSB_DATA_DIR")


def _real_data_dir() -> Path:
    d = REAL_DATA_DIR
    if not d:
        pytest.skip("RSB_DATA_DIR is not set (CI sets RSB_DATA_DIR=../shared/data)")
    if not (Path(d) / "gsm8k" / "test.jsonl").is_file() or not (Path(d) / "mmlu_pro" / "data").is_dir():
        pytest.skip(f"RSB_DATA_DIR={d} lacks gsm8k/ or mmlu_pro/")
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


TEN = ["Paris", "Lyon", "Nice", "Lille", "Nantes", "Rouen", "Brest", "Dijon", "Metz", "Reims"]


def test_mmlu_pro_exclusions():
    row = dict(question="What is the capital of France?", choices=TEN, answer=0)
    assert exclusion_reason(row) is None
    assert exclusion_reason({**row, "choices": TEN[:4]}) == "fewer than 10 options"
    assert exclusion_reason({**row, "choices": ["paris."] + TEN[1:]}) is None
    assert exclusion_reason({**row, "choices": TEN[:9] + ["paris."]}) == "duplicate options"
    numbers = [f"{2 * i} m/s" for i in range(1, 11)]
    assert exclusion_reason({**row, "choices": numbers}) == "numeric options centred on the answer"
    # written numeric distractors sit around the answer with words after the number too
    worded = [f"{20 * i} grams, {i / 2} grams" for i in range(1, 11)]
    assert exclusion_reason({**row, "choices": worded}) == "numeric options centred on the answer"
    assert exclusion_reason({**row, "choices": worded[:9] + ["none at all"]}) is None
    assert exclusion_reason({**row, "choices": TEN[:9] + ["All of the above"]}) == "option refers to other options"
    assert exclusion_reason({**row, "choices": TEN[:9] + ["G and H"]}) == "option refers to other options"
    labelled = dict(row, question="Express the tax rates (A) 3.06% (B) 6.85% in mills.")
    assert exclusion_reason(labelled) == "question labels its parts with option letters"
    # an option naming a block colour would be bound to a block of another colour
    assert exclusion_reason({**row, "choices": TEN[:9] + ["The Red Sea"]}) == "option names a block colour"


def _pro(i: int, text: str, choices: list[str], answer: int = 0) -> dict:
    return dict(question=text, choices=choices, answer=answer, id=i, src="stemez-toy", subject="toy", origin=f"row {i}")


def test_ten_own_options_and_four_without_a_twin_of_the_answer():
    """General-10 shows the question's own ten; General-4 the answer and three of its nine, drawn
    so that no shown option is a near twin of another (here "Increased heart rhythm" of the answer
    "Increased heart rate": a twin on show would point at the answer it was written around)."""
    ten = ["Increased heart rate", "Increased heart rhythm", "Lower body temperature", "Dry skin", "Blurred vision",
           "Loss of appetite", "Muscle cramps", "Hair loss", "Tooth decay", "Night sweats"]
    q = mmlu_pro.to_question(_pro(0, "What does adrenaline cause?", ten))
    rng = np.random.default_rng(0)
    seen = Counter()
    for _ in range(500):
        shown = mmlu_pro.options(q, 10, rng)
        assert shown[0] == ten[0] and sorted(shown) == sorted(ten)  # General-10: the question's own ten
        four = mmlu_pro.options(q, 4, rng)
        assert four[0] == ten[0] and len(set(four)) == 4 and set(four) <= set(ten)
        seen.update(four[1:])
    assert "Increased heart rhythm" not in seen
    assert len(seen) >= 5  # the three vary from episode to episode
    with pytest.raises(ValueError, match="fewer than 10"):
        mmlu_pro.options(mmlu_pro.to_question(_pro(1, "Q?", TEN[:4])), 10, rng)


def test_four_of_a_question_from_mmlu_are_mmlus_own(monkeypatch):
    """A question MMLU-Pro took from MMLU shows MMLU's own four in General-4 (the six MMLU-Pro
    added carry words that mark them); General-10 still shows all ten."""
    row = {**_pro(0, "What is the capital of France?", TEN), "src": "ori_mmlu-geography"}
    own = [TEN[3], TEN[6], TEN[8]]  # MMLU's three distractors, found by scripts/mmlu_options.py
    monkeypatch.setattr(mmlu_pro, "mmlu_distractors",
                        lambda: {mmlu_pro.content_key(row): frozenset(mmlu_pro.option_hash(o) for o in own)})
    q = mmlu_pro.to_question(row)
    assert q.core == (TEN[0], TEN[3], TEN[6], TEN[8])
    rng = np.random.default_rng(0)
    for _ in range(50):
        four = mmlu_pro.options(q, 4, rng)
        assert four[0] == TEN[0] and sorted(four) == sorted(q.core)
        assert sorted(mmlu_pro.options(q, 10, rng)) == sorted(TEN)
    # MMLU's four must hold the answer (MMLU-Pro corrected some answers): else no core
    monkeypatch.setattr(mmlu_pro, "mmlu_distractors",
                        lambda: {mmlu_pro.content_key(row): frozenset(mmlu_pro.option_hash(o) for o in own[:2])})
    assert mmlu_pro.to_question(row).core is None


@pytest.mark.data
def test_general_4_shows_mmlus_own_options_for_mmlu_questions():
    """With the real data, most of General's MMLU-Pro questions that came from MMLU carry MMLU's
    four, and General-4 episodes of them show exactly those."""
    d = _real_data_dir()
    clear_cache()
    s = EpisodeSampler("RSB-General-4", "test", data_dir=d)
    pro = [i for i, q in enumerate(s.pool.questions) if q.source == "mmlu_pro"]
    cored = [i for i in pro if s.pool.questions[i].core]
    assert len(cored) > 0.4 * len(pro)
    for i in cored[:200]:
        sp = s.sample(10_000_000 + i, question_index=i)
        assert sorted(sp.options) == sorted(s.pool.questions[i].core)


def test_questions_sharing_an_option_land_in_one_split():
    rows = [_pro(i, f"Which of these words is listed in toy question number {i}?",
                 [f"word{i}x{k}" for k in range(10)]) for i in range(60)]
    for i in range(0, 60, 2):  # pairs of questions that share an option text
        rows[i + 1]["choices"][3] = rows[i]["choices"][5]
    by_split, _ = mmlu_pro.split_questions(rows, filtered=())
    side = {q.text: s for s, qs in by_split.items() for q in qs}
    assert len(side) == 60 and {len(by_split["train"]), len(by_split["test"])} != {0}
    for i in range(0, 60, 2):
        assert side[rows[i]["question"]] == side[rows[i + 1]["question"]]
    # the shipped adversarial filter leaves questions out by content, whatever their ids
    drop = {mmlu_pro.content_key(rows[0])}
    kept, excluded = mmlu_pro.split_questions(rows, filtered=drop)
    assert rows[0]["question"] not in {q.text for qs in kept.values() for q in qs}
    assert excluded["answer found from the options alone (adversarial filter)"] == 1


def test_balance_keeps_the_answers_rank_near_uniform():
    """Answers that are always the longest option get thinned out until the longest is the
    answer in about 1/10 of the kept questions."""
    rng = np.random.default_rng(1)
    qs = []
    for i in range(3000):
        words = [f"w{i}{k}" + "x" * int(rng.integers(0, 12)) for k in range(10)]
        a = int(np.argmax([len(w) for w in words])) if i % 3 == 0 else int(rng.integers(10))
        qs.append(mmlu_pro.to_question(_pro(i, f"Toy question {i}?", words, a)))
    kept, dropped = mmlu_pro.balanced_selection(qs)

    def longest(q):  # "pick the longest", ties split
        lens = [len(c) for c in q.choices]
        return (lens[q.choices.index(q.answer)] == max(lens)) / lens.count(max(lens))

    before, longest = np.mean([longest(q) for q in qs]), np.mean([longest(q) for q in kept])
    assert before > 0.3 and abs(longest - 0.1) < 0.02 and dropped > 500


def test_every_general_option_is_free_of_block_colours(question_data):
    """No General option names a block colour (an option "yellow" bound to the red block)."""
    clear_cache()
    pattern = mmlu_pro._BLOCK_COLOR
    for split in ("train", "test"):
        pool = EpisodeSampler("RSB-General-10", split, data_dir=question_data).pool
        for i, q in enumerate(pool.questions):
            texts = q.choices if q.choices else [q.answer] + [c for c, _ in pool.candidates[i][0]]
            assert not any(pattern.search(t) for t in texts), (q.text, texts)


@pytest.mark.parametrize("suite_id", ["RSB-HardMath-4", "RSB-HardMath-10"])
def test_fixture_pools_still_give_valid_options(suite_id):
    clear_cache()
    s = EpisodeSampler(suite_id, "train", data_dir=FIXTURES)
    for seed in range(40):
        sp = s.episode(seed)
        assert len({option_key(o) for o in sp.options}) == sp.n_choices


# ------------------------------------------------------------------ real data, many episodes


@pytest.mark.slow
@pytest.mark.parametrize("suite_id", [
    "RSB-Math-4", "RSB-Math-10", "RSB-Direct-4", "RSB-Direct-10",
    *(pytest.param(s, marks=pytest.mark.data) for s in ("RSB-HardMath-4", "RSB-HardMath-10", "RSB-General-4",
                                                         "RSB-General-10"))])
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
