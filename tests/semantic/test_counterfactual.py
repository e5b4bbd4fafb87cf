"""Counterfactual variants in the semantic engine: same scene, the answer on another candidate.

No simulator: the variants are built from the sampler alone (the layout is the seed's, checked in
physics in tests/evaluation/test_counterfactual_physics.py)."""
from __future__ import annotations

import numpy as np
import pytest

from rsb_maniskill.env_ids import resolve_env_ids
from rsb_maniskill.evaluation.protocol import EVAL_ENV_KWARGS, EVAL_SEED_BASE, eval_seeds
from rsb_maniskill.objects.family import split_env_id
from rsb_maniskill.semantic import EpisodeSampler
from rsb_maniskill.semantic import counterfactual as cf
from rsb_maniskill.semantic.normalize import option_key, question_key

SEEDS = [EVAL_SEED_BASE + i for i in range(12)]


def _sampler(env_id: str, split: str = "test") -> EpisodeSampler:
    suite_id, targets = split_env_id(env_id)
    kwargs = EVAL_ENV_KWARGS if split == "test" else {"split": split}
    return EpisodeSampler(suite_id, **kwargs, targets=targets)


@pytest.mark.parametrize("env_id", resolve_env_ids(["all", "all-objects"]))
def test_variants_keep_the_scene_and_move_the_answer(env_id, question_data):
    s = _sampler(env_id)
    train_questions = {question_key(q.text) for q in _sampler(env_id, "train").pool.questions} if s.pool else set()
    for seed in SEEDS[:6]:
        scene = s.episode(seed)
        vs = cf.variants(s, seed)
        assert len(vs) == cf.default_variants(s.n_choices) == min(s.n_choices, 4)
        assert vs[0].spec == scene and vs[0].kind == cf.PROTOCOL
        assert len({v.target for v in vs}) == len(vs)  # K distinct targets
        assert [v.target for v in vs] == list(cf.variant_targets(s, scene)[:len(vs)])
        for v in vs:
            sp = v.spec
            assert v.kind == cf.variant_kind(v.index, s.direct)
            assert (sp.seed, sp.candidates, sp.block_names, sp.template_id) == (
                seed, scene.candidates, scene.block_names, scene.template_id)
            assert sp.split == "test"
            assert [option_key(o) for o in sp.options].count(option_key(sp.correct_option)) == 1
            assert sp.instruction and sp.correct_letter == sp.letters[sp.answer_slot]
            if s.lettered:  # a block is its letter: the binding never changes
                assert sp.block_of_option == scene.block_of_option
            if v.kind == cf.REMAP:
                assert sp.question_id == scene.question_id and sp.correct_option == scene.correct_option
                assert sorted(sp.options) == sorted(scene.options) and sp.instruction != scene.instruction
                if not s.lettered:  # the binding rotated, the options where they were
                    assert sp.options == scene.options and sp.answer_slot == scene.answer_slot
                    n = s.n_choices
                    shift = (scene.block_of_option.index(sp.block_of_option[0])) % n
                    assert sp.block_of_option == tuple(scene.block_of_option[(i + shift) % n] for i in range(n))
                else:  # the option texts rotated over the letters
                    i = scene.options.index(sp.options[0])
                    assert sp.options == scene.options[i:] + scene.options[:i]
            if v.kind == cf.REQUESTION and not s.direct:
                assert sp.block_of_option == scene.block_of_option
                assert question_key(sp.question) not in train_questions
        requestioned = [v.spec.question_id for v in vs if v.kind != cf.REMAP]
        assert len(set(requestioned)) == len(requestioned)  # every requestion asks a new question


def test_a_variant_is_a_pure_function_of_suite_seed_and_index(question_data):
    a, b = _sampler("RSB-General-10-Objects"), _sampler("RSB-General-10-Objects")
    for seed in SEEDS[:3]:
        every = cf.variants(a, seed, 10)
        assert [cf.variant(b, seed, k) for k in range(10)] == every  # not of K, nor of what ran before
        assert cf.variants(b, seed, 4) == every[:4]
        assert [v.kind for v in every] == ["protocol"] + ["remap", "requestion"] * 4 + ["remap"]
    direct = cf.variants(_sampler("RSB-Direct-10"), SEEDS[0], 10)
    assert [v.kind for v in direct] == ["protocol"] + ["requestion"] * 9
    assert sorted(v.target for v in direct) == list(range(10))
    assert all(v.spec.instruction.count(v.spec.block_names[v.target]) == 1 for v in direct)


@pytest.mark.parametrize("env_id", ["RSB-Math-4", "RSB-Math-10", "RSB-Direct-4-Objects"])
def test_the_target_of_every_variant_is_uniform_over_candidates(env_id, question_data):
    """Across scenes no candidate (colour, letter, object slot) is the target of variant k more often
    than chance: the audit's position and colour guessers check the same on the full suites."""
    s = _sampler(env_id)
    seeds = eval_seeds(env_id, 400)
    k = cf.default_variants(s.n_choices)
    targets = np.array([[v.target for v in cf.variants(s, seed)] for seed in seeds])
    slots = np.array([[v.spec.answer_slot for v in cf.variants(s, seed)] for seed in seeds])
    expected = len(seeds) / s.n_choices
    for col in range(k):
        for counts in (np.bincount(targets[:, col], minlength=s.n_choices),
                       np.bincount(slots[:, col], minlength=s.n_choices)):
            chi2 = float(((counts - expected) ** 2 / expected).sum())
            assert chi2 < 30.0, (col, counts)  # df = N - 1 <= 9: p < 0.001 at 27.9


def test_bad_variants_are_refused(question_data):
    s = _sampler("RSB-Math-4")
    with pytest.raises(ValueError, match="0..3"):
        cf.variant(s, SEEDS[0], 4)
    with pytest.raises(ValueError, match="2..4"):
        cf.variants(s, SEEDS[0], 5)
    with pytest.raises(ValueError, match="2..10"):
        cf.check_variants(1, 10)
    with pytest.raises(ValueError, match="test split"):
        cf.variant(_sampler("RSB-Math-4", "train"), 3, 1)


def test_rebind_renders_as_sample_does(question_data):
    """The sampler's one rendering path: rebinding an episode to its own binding gives it back."""
    for env_id in ("RSB-Math-4", "RSB-General-10", "RSB-Math-10-Objects"):
        s = _sampler(env_id)
        for seed in SEEDS[:4]:
            sp = s.episode(seed)
            assert s.rebind(sp, sp.options, sp.answer_slot, sp.block_of_option) == sp
    with pytest.raises(ValueError, match="Direct"):
        d = _sampler("RSB-Direct-4")
        d.rebind(d.episode(SEEDS[0]), (), 0, ())
