"""The test-split aliases (``RSB-Direct-4-Test``): registered like the suites, the same episodes as the
suite made with ``split="test"``, and never counted as suites."""
from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np
import pytest

import rsb_maniskill  # noqa: F401  (registers the envs)
from rsb_maniskill import env_ids as E
from rsb_maniskill.semantic import SUITE_IDS

from task_envs import make


def _episode(env_id: str, seed: int, **kw) -> dict:
    env = make(env_id, **kw)
    obs, _ = env.reset(seed=seed)
    u = env.unwrapped
    out = dict(split=u.split, templates=u.sampler.instructions, instruction=u.get_language_instruction()[0],
               question_id=int(u.question_id[0]), target=int(u.target_block[0]),
               candidates=list(u.episode_specs[0].candidates), obs=np.asarray(obs).copy())
    env.close()
    return out


def test_one_alias_per_answer_selection_id_with_split_test():
    assert E.TEST_ALIASES == {uid + E.TEST_SUFFIX: uid for uid in E.TASK_ENVS}
    assert "RSB-Direct-4-Test" in E.TEST_ALIASES and "RSB-Math-10-Objects-Test" in E.TEST_ALIASES
    assert "RSB-TableTop-v1-Test" not in E.ENVS_AND_ALIASES  # the table has no question pool
    assert not set(E.TEST_ALIASES) & set(E.ENVS)
    assert set(E.ENVS_AND_ALIASES) == set(E.ENVS) | set(E.TEST_ALIASES)
    for alias, uid in E.TEST_ALIASES.items():
        steps, kwargs = E.ENVS_AND_ALIASES[alias]
        assert steps == E.ENVS[uid][0] and kwargs == {**E.ENVS[uid][1], "split": "test"}
        assert E.ENVS_AND_ALIASES[uid] == E.ENVS[uid]  # the suite itself keeps the train default


def test_aliases_are_no_suites():
    """Whatever lists the suites (groups, `--suites all`, the golden pins, the card) lists them once."""
    every = E.resolve_env_ids(["all", "all-objects"])
    assert every == list(SUITE_IDS) + list(E.OBJECT_ENV_IDS) and not set(every) & set(E.TEST_ALIASES)
    assert not any(set(group) & set(E.TEST_ALIASES) for group in E.SUITE_GROUPS.values())
    for name in ("RSB-Direct-4-Test", "rsb_maniskill:RSB-Math-4-Objects-Test"):
        with pytest.raises(ValueError, match=r"test-split alias of RSB-\S+ for gym.make.*not a suite"):
            E.resolve_env_ids([name])


def test_a_command_refuses_an_alias_in_one_line(capsys):
    parser = argparse.ArgumentParser(prog="rsb generate")
    E.add_suites_argument(parser, positional=True)
    with pytest.raises(SystemExit) as exit_:
        parser.parse_args(["RSB-Direct-4-Test"])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and len(err.splitlines()) == 1
    assert err.startswith("rsb generate: error: RSB-Direct-4-Test is the test-split alias of RSB-Direct-4")


def test_gymnasium_knows_the_alias_before_the_simulator_loads():
    spec = gym.spec("RSB-Direct-4-Test")
    assert spec.kwargs == {"suite_id": "RSB-Direct-4", "split": "test"}
    assert spec.max_episode_steps == E.ENVS["RSB-Direct-4"][0]


def test_alias_episode_is_the_suites_test_episode():
    """gym.make of the alias, with no keywords, as ManiSkill's baselines call it: split "test", and for
    a seed the episode of the suite made with split="test" (not the train one)."""
    alias = _episode("rsb_maniskill:RSB-Direct-4-Test", seed=5)
    test = _episode("RSB-Direct-4", seed=5, split="test")
    train = _episode("RSB-Direct-4", seed=5)
    assert alias["split"] == test["split"] == "test" and train["split"] == "train"
    assert alias["templates"] == "unseen"  # the test split's default: the evaluation's kwargs
    assert {k: v for k, v in alias.items() if k != "obs"} == {k: v for k, v in test.items() if k != "obs"}
    assert np.array_equal(alias["obs"], test["obs"])
    assert alias["question_id"] != train["question_id"] or alias["instruction"] != train["instruction"]


def test_alias_keeps_keywords_and_records_its_own_id():
    env = make("RSB-Math-4-Objects-Test", split="train")  # a keyword still overrides the default
    assert env.unwrapped.split == "train" and env.unwrapped.family.name == "objects"
    env.close()
    env = make("RSB-Direct-4-Test")
    assert env.unwrapped.spec.id == "rsb_maniskill:RSB-Direct-4-Test"
    env.close()


def test_maniskill_registers_the_alias_with_its_suites_class():
    from mani_skill.utils.registration import REGISTERED_ENVS

    from rsb_maniskill.registration import load_simulator

    load_simulator()
    for alias, uid in E.TEST_ALIASES.items():
        assert REGISTERED_ENVS[alias].cls is REGISTERED_ENVS[uid].cls
        assert REGISTERED_ENVS[alias].default_kwargs == {**E.ENVS[uid][1], "split": "test"}
