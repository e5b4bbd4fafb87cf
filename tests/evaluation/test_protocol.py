"""The fixed evaluation protocol: seeds, and the blank / shuffled instruction ablations."""
from __future__ import annotations

import pytest

from rsb_maniskill.evaluation.protocol import (
    EVAL_SEED_BASE,
    apply_instruction_mode,
    derangement,
    eval_seeds,
    shuffled_instruction,
)
from rsb_maniskill.semantic.suites import SUITE_IDS


def test_eval_seeds_fixed_distinct_and_prefix_stable():
    for suite in SUITE_IDS:
        seeds = eval_seeds(suite)
        assert seeds == eval_seeds(suite) and len(seeds) == 500 == len(set(seeds))
        assert seeds[0] == EVAL_SEED_BASE == 10_000_000 and seeds[-1] == 10_000_499
        assert eval_seeds(suite, 100) == seeds[:100]  # a smoke test meets the first episodes of the full run
    # far from the small seeds used for demonstrations
    assert min(eval_seeds("RSB-Math-4")) > 1_000_000


def test_eval_seeds_rejects_bad_input():
    with pytest.raises(ValueError, match="RSB-Math-4"):
        eval_seeds("RSB-Math-5")
    with pytest.raises(ValueError):
        eval_seeds("RSB-Math-4", 0)


@pytest.mark.parametrize("n", [2, 3, 10, 500])
def test_derangement_has_no_fixed_point(n):
    d = derangement(n, seed=7)
    assert sorted(d) == list(range(n))
    assert all(d[i] != i for i in range(n))
    assert d == derangement(n, seed=7)
    if n > 3:
        assert d != derangement(n, seed=8)


def test_derangement_needs_two():
    with pytest.raises(ValueError):
        derangement(1)


def test_shuffled_instruction_gives_another_episodes_text():
    texts = [f"instruction {i}" for i in range(50)]
    out = shuffled_instruction(texts, seed=3)
    assert out == shuffled_instruction(texts, seed=3)
    assert sorted(out) == sorted(texts)  # a permutation: every text is used once
    assert all(o != t for o, t in zip(out, texts))


def test_shuffled_instruction_avoids_equal_texts():
    # Two episodes with the same text: neither may be handed its own text back through the other.
    texts = ["same", "same", "a", "b", "c"]
    for seed in range(20):
        out = shuffled_instruction(texts, seed)
        assert all(o != t for o, t in zip(out, texts)), (seed, out)


def test_apply_instruction_mode():
    assert apply_instruction_mode("pick the answer", "normal") == "pick the answer"
    assert apply_instruction_mode("pick the answer", "blank") == ""
    assert apply_instruction_mode("pick the answer", "shuffled", "other") == "other"
    with pytest.raises(ValueError, match="donor"):
        apply_instruction_mode("x", "shuffled")
    with pytest.raises(ValueError, match="normal"):
        apply_instruction_mode("x", "reversed")


def test_counterfactual_mode_gives_the_variants_own_instruction():
    """The variant's instruction is the one given (the task renders it); no ablation fields."""
    from rsb_maniskill.evaluation.protocol import ablate, variant_reset

    assert apply_instruction_mode("put the red block", "counterfactual") == "put the red block"
    assert ablate("put the red block", "counterfactual", None) == ("put the red block", {})
    assert variant_reset(None, [None]) is None and variant_reset({"a": 1}, [None, None]) == {"a": 1}
    assert variant_reset(None, [2]) == {"variant": 2}
    assert variant_reset({"a": 1}, [0, 3]) == {"a": 1, "variant": [0, 3]}
