"""run_episodes (the driver and the one-env loop) against a tiny fake env exposing the RSB task
contract (no simulator)."""
from __future__ import annotations

import numpy as np
import pytest

from rsb_maniskill.evaluation.jobs import run_episodes
from rsb_maniskill.evaluation.protocol import shuffled_instruction
from rsb_maniskill.evaluation.store import read_records
from rsb_maniskill.reporting.summary import results_from_records, summary_dict

from fake_envs import HORIZON, OUTCOMES, SUITE, FakeRSBEnv, ScriptedPolicy

SEEDS = [10_000_000 + i for i in range(12)]


def run(tmp_path, seeds=SEEDS, mode="normal", policy=None, env=None, name="e.jsonl", **kw):
    env = env or FakeRSBEnv()
    policy = policy or ScriptedPolicy()
    records = run_episodes(lambda: env, policy, SUITE, seeds, tmp_path / name, mode, max_steps=kw.pop("max_steps", 300),
                           progress=False, **kw)
    return records, env, policy


def test_records_follow_the_scripted_outcomes(tmp_path):
    records, env, policy = run(tmp_path)
    assert [r["seed"] for r in records] == SEEDS and env.closed
    for r in records:
        kind = OUTCOMES[r["seed"] % 4]
        assert r["policy"] == "scripted" and r["suite_id"] == SUITE and r["instruction_mode"] == "normal"
        assert r["question_id"] == r["seed"] % 7 and r["target_block"] == r["seed"] % 4
        assert r["correct_letter"] == "ABCD"[(r["seed"] // 4) % 4]
        assert r["instruction"] == f"which block answers question {r['seed']}?"
        assert r["success"] == (kind == "success") and r["placed_wrong"] == (kind == "wrong_target")
        assert r["grasped_any"] == (kind != "no_grasp")
        assert r["grasped_correct"] == (kind in ("success", "not_placed"))
        assert r["first_grasped"] == {"success": r["seed"] % 4, "wrong_target": (r["seed"] + 1) % 4,
                                      "not_placed": r["seed"] % 4, "no_grasp": -1}[kind]
        assert r["steps"] == {"success": 8, "wrong_target": 6, "not_placed": HORIZON, "no_grasp": HORIZON}[kind]
        assert r["episode"]["seed"] == r["seed"] and r["fail"] == (kind == "wrong_target")
    # the policy got the instruction and numpy obs without the env dim, at t = 0
    assert policy.instructions == [r["instruction"] for r in records]
    assert policy.obs[0]["sensor_data"]["head"]["rgb"].shape == (6, 8, 3) and policy.obs[0]["agent"]["qpos"][0] == 0
    m = results_from_records(records)["scripted"][SUITE]
    assert (m.n_episodes, m.n_grasped, m.n_success) == (12, 9, 3)
    assert (m.errors.not_placed, m.errors.wrong_target, m.errors.no_grasp) == (3, 3, 3)


def test_chunks_are_executed_in_order_and_cut_at_the_end(tmp_path):
    policy = ScriptedPolicy(horizon=3)
    records, env, _ = run(tmp_path, seeds=[SEEDS[0]], policy=policy)  # success at step 8
    assert records[0]["steps"] == 8 and env.n_steps == 8 and policy.acts == 3  # 3 + 3 + 2


def test_max_steps_caps_the_episode(tmp_path):
    records, env, _ = run(tmp_path, seeds=[SEEDS[3]], max_steps=5)  # would run to the time limit
    assert records[0]["steps"] == 5 and env.n_steps == 5 and not records[0]["grasped_any"]


def test_resume_after_interruption_gives_the_same_summary(tmp_path):
    full, _, _ = run(tmp_path, name="full.jsonl")

    class Interrupting(ScriptedPolicy):
        def reset(self, instruction, obs):
            if len(self.instructions) == 7:
                raise KeyboardInterrupt  # killed during the 8th episode
            super().reset(instruction, obs)

    with pytest.raises(KeyboardInterrupt):
        run(tmp_path, policy=Interrupting(), name="part.jsonl")
    path = tmp_path / "part.jsonl"
    assert len(read_records(path)) == 7
    # and the process died while writing the 7th record: a torn last line
    text = path.read_text()
    path.write_text(text[: len(text) - 30])

    env = FakeRSBEnv()
    with pytest.warns(UserWarning, match="truncated"):
        resumed, env, _ = run(tmp_path, env=env, name="part.jsonl")
    assert env.reset_seeds == SEEDS[6:]  # only the missing episodes ran
    assert [r["seed"] for r in resumed] == SEEDS
    assert summary_dict(results_from_records(resumed)) == summary_dict(results_from_records(full))


def test_nothing_left_builds_no_env(tmp_path):
    run(tmp_path)
    built = []
    records = run_episodes(lambda: built.append(1), ScriptedPolicy(), SUITE, SEEDS, tmp_path / "e.jsonl",
                           progress=False)
    assert built == [] and len(records) == len(SEEDS)


def test_blank_instruction(tmp_path):
    records, _, policy = run(tmp_path, mode="blank")
    assert policy.instructions == [""] * len(SEEDS)
    assert all(r["instruction"] == "" and r["original_instruction"].endswith(f"{r['seed']}?") for r in records)


def test_shuffled_instruction_is_another_episodes(tmp_path):
    records, env, policy = run(tmp_path, mode="shuffled")
    own = [f"which block answers question {s}?" for s in SEEDS]
    assert policy.instructions == shuffled_instruction(own)  # same pairing as the documented helper
    assert all(r["instruction"] != r["original_instruction"] for r in records)
    assert all(r["instruction"] == own[SEEDS.index(r["donor_seed"])] for r in records)
    # the donor lookup resets the env on other seeds, but each episode is run from its own reset
    assert [r["steps"] for r in records] == [{0: 8, 1: 6}.get(s % 4, HORIZON) for s in SEEDS]

    # with a lookup: no extra resets, same pairing
    records2, env2, _ = run(tmp_path, mode="shuffled", name="lookup.jsonl",
                            instruction_lookup=lambda s: f"which block answers question {s}?")
    assert env2.reset_seeds == SEEDS
    assert [r["instruction"] for r in records2] == [r["instruction"] for r in records]


def test_modes_and_policies_are_recorded_side_by_side(tmp_path):
    run(tmp_path, mode="normal")
    records, env, _ = run(tmp_path, mode="blank")
    assert env.reset_seeds == SEEDS  # the blank run does not count the normal run's seeds as done
    rows = results_from_records(read_records(tmp_path / "e.jsonl"))
    assert set(rows) == {"scripted", "scripted (blank)"}


def test_wrong_action_dim_is_reported(tmp_path):
    class Wrong(ScriptedPolicy):
        def act(self, obs):
            return np.zeros((2, 16))

    with pytest.raises(ValueError, match="dim 16"):
        run(tmp_path, policy=Wrong())


def test_throughput_line_splits_start_up_from_the_steady_rate(monkeypatch):
    """rsb eval's last line: start-up to the first episode's start (arrival less its wall_s), then
    every episode's steps over the first start to the last record."""
    from rsb_maniskill.evaluation import jobs

    now = [100.0]
    monkeypatch.setattr(jobs.time, "monotonic", lambda: now[0])
    pace = jobs.Throughput()
    assert pace.line() == "throughput: no episode ran"
    for t, steps, wall in ((112.0, 300, 2.0), (113.0, 300, 3.0), (114.0, 100, 1.0)):
        now[0] = t
        pace.add({"steps": steps, "wall_s": wall})
    # first start 110 (112 - 2): start-up 10 s; 700 steps from 110 to 114
    assert pace.line() == "throughput: start-up 10.0 s, then 175 env-steps/s (700 env-steps, 3 episodes in 4.0 s)"
