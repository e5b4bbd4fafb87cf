"""Counterfactual scenes in physics: a variant is its scene (same layout, same candidates), and the
reference policies behave as the chance lines say: the oracle follows every variant, blind grasps
its own draw in each variant (a fresh one: not stuck), leftmost is stuck on one candidate."""
from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import rsb_maniskill  # noqa: F401  (registers the envs)
from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.protocol import EVAL_ENV_KWARGS, eval_seeds
from rsb_maniskill.evaluation.store import read_records
from rsb_maniskill.policies.reference import blind_target, leftmost_target
from rsb_maniskill.semantic import counterfactual as cf

SUITE = "RSB-Math-4"


@pytest.mark.parametrize("env_id", ["RSB-Math-4", "RSB-Math-10-Objects"])
def test_a_variant_is_played_on_its_scene(env_id, question_data):
    """reset(seed, options={"variant": k}) places what reset(seed) places; only the semantics move."""
    env = gym.make(env_id, obs_mode="state", render_backend="none", **EVAL_ENV_KWARGS)
    base = env.unwrapped
    try:
        for seed in eval_seeds(env_id, 2):
            env.reset(seed=seed)
            scene = base.episode_specs[0]
            slots, poses = base.block_slot[0].numpy().copy(), base.pool.raw_poses()[0].numpy().copy()
            assert base.episode_variants[0] is None
            targets = []
            for k in range(cf.default_variants(base.n_choices)):
                env.reset(seed=seed, options={"variant": [k] if k % 2 else k})  # one index, or one per env
                v = base.episode_variants[0]
                assert (v.index, v.spec) == (k, base.episode_specs[0]) == (k, base.episode_variant(seed, k).spec)
                assert base.episode_specs[0].candidates == scene.candidates
                assert base.get_language_instruction()[0] == v.spec.instruction
                assert int(base.target_block[0]) == v.target
                np.testing.assert_array_equal(base.block_slot[0].numpy(), slots)
                np.testing.assert_array_equal(base.pool.raw_poses()[0].numpy(), poses)
                targets.append(v.target)
            assert len(set(targets)) == len(targets) and targets[0] == scene.target_block
    finally:
        env.close()


def _eval(policy: str, out: Path, suites: list[str], n: int) -> dict:
    assert main(["eval", policy, "--suites", *suites, "-n", str(n), "--instruction", "counterfactual",
                 "--out", str(out), "-q"]) == 0
    return json.loads((out / "summary.json").read_text())["counterfactual"]["rows"][f"{policy} (counterfactual)"]


@pytest.mark.slow
def test_the_oracle_follows_every_variant(tmp_path, question_data):
    rows = _eval("oracle", tmp_path, [SUITE, "RSB-Math-10"], 1)
    for suite, k in ((SUITE, 4), ("RSB-Math-10", 4)):
        m = rows[suite]
        assert (m["scenes"], m["variants"], m["grasped"]) == (1, k, k)
        assert m["follow"]["value"] == m["follow_all"]["value"] == m["switch"]["value"] == 1.0
        assert m["stuck"]["value"] == 0.0
    assert rows["pooled"]["follow"]["value"] == 1.0
    records = read_records(tmp_path / "episodes.jsonl")
    assert sorted((r["suite_id"], r["variant"]) for r in records) == sorted(
        (s, k) for s in (SUITE, "RSB-Math-10") for k in range(4))
    assert all(r["success"] and r["first_grasped"] == r["target_block"] for r in records)
    assert {r["variant_kind"] for r in records} == {"protocol", "remap", "requestion"}


@pytest.mark.slow
def test_blind_grasps_a_fresh_draw_in_every_variant(tmp_path, question_data):
    """Blind is not stuck: it grasps blind_target(seed, N, k), drawn anew per variant (its chance-level
    follow and switch rates over many scenes: tests/evaluation/test_counterfactual_metrics.py)."""
    _eval("blind", tmp_path, [SUITE], 1)
    records = read_records(tmp_path / "episodes.jsonl")
    assert len(records) == 4
    draws = [blind_target(r["seed"], 4, r["variant"]) for r in records]
    assert [r["first_grasped"] for r in records] == draws
    assert draws[0] == blind_target(records[0]["seed"], 4)  # variant 0: the protocol episode's draw


@pytest.mark.slow
def test_leftmost_is_stuck(tmp_path, question_data):
    rows = _eval("leftmost", tmp_path, [SUITE], 2)
    m = rows[SUITE]
    assert m["stuck"]["value"] == 1.0 and m["full_scenes"] == 2
    records = read_records(tmp_path / "episodes.jsonl")
    # K = N: the answer lands on each candidate once a scene, so the stuck grasp follows one variant of
    # each scene; the headline follow counts the changed variants (k > 0) alone
    changed = [r for r in records if r.get("variant", 0) > 0]
    followed = sum(r["first_grasped"] == r["target_block"] for r in changed)
    assert sum(r["first_grasped"] == r["target_block"] for r in records) == 2  # one variant a scene
    assert m["switch"]["value"] == 0.0 and m["follow"]["value"] == followed / len(changed)
    env = gym.make(SUITE, obs_mode="state", render_backend="none", **EVAL_ENV_KWARGS)
    try:
        for r in records:
            env.reset(seed=r["seed"])
            assert r["first_grasped"] == leftmost_target(env)
    finally:
        env.close()
