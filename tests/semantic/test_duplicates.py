"""Near-duplicate questions (semantic/duplicates.py): word trigrams, the prefix-filtered pair search
against every pair compared, and the groups the MMLU-Pro split keeps on one side."""
from __future__ import annotations

import itertools
import random

from rsb_maniskill.semantic.duplicates import (
    NEAR_DUPLICATE_JACCARD,
    duplicate_groups,
    near_duplicate_pairs,
    shingles,
)
from rsb_maniskill.semantic.normalize import question_key

LONG = ("a train leaves the station at noon and travels east at sixty miles per hour while a second train "
        "leaves two hours later on the same track going faster")


def test_shingles_are_word_trigrams_or_the_whole_short_text():
    assert shingles("one two") == frozenset({"one two"})
    assert shingles("a b c d") == frozenset({"a b c", "b c d"})


def _jaccard(a: str, b: str) -> float:
    x, y = shingles(a), shingles(b)
    return len(x & y) / len(x | y)


def test_prefix_filtering_finds_exactly_the_pairs_a_full_comparison_finds():
    rng = random.Random(0)
    words = LONG.split()
    keys = {LONG}
    for _ in range(60):  # variants of one text: a word changed, dropped or two swapped
        w = list(words)
        i = rng.randrange(len(w))
        op = rng.choice(("change", "drop", "swap"))
        if op == "change":
            w[i] = rng.choice(("north", "west", "seventy", "slower", "bus"))
        elif op == "drop":
            del w[i]
        else:
            j = rng.randrange(len(w))
            w[i], w[j] = w[j], w[i]
        keys.add(" ".join(w))
    keys |= {"what is the capital of france", "name the largest planet of the solar system"}
    keys = sorted(keys)
    full = sorted((a, b, round(_jaccard(a, b), 3)) for a, b in itertools.combinations(keys, 2)
                  if _jaccard(a, b) >= NEAR_DUPLICATE_JACCARD)
    assert full, "the variants must include near-duplicates for the check to mean anything"
    assert near_duplicate_pairs(keys) == full


def test_pairs_across_two_lists_only_pair_one_with_the_other():
    one_word = LONG.replace("faster", "slower")
    pairs = near_duplicate_pairs([LONG], [one_word, "what is the capital of france"])
    assert pairs == [(LONG, one_word, round(_jaccard(LONG, one_word), 3))]


def test_groups_join_wording_slips_and_keep_other_questions_apart():
    texts = [LONG, LONG.upper() + " ?", LONG.replace("noon", "midday"), "What is the capital of France?"]
    groups = duplicate_groups(texts)
    assert set(groups) == {question_key(t) for t in texts}
    train = {groups[question_key(t)] for t in texts[:3]}
    assert len(train) == 1  # case, punctuation and one changed word: one question
    assert groups[question_key(texts[3])] == question_key(texts[3]) not in train
