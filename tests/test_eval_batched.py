"""The parallel-env loop (GPU backend): records equal the one-env loop's, episode for episode."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from test_eval_runner import HORIZON, SUITE, FakeRSBEnv, ScriptedPolicy

from rsb_maniskill.evaluation.runner import EpisodeSettings, batched_loop, episode_loop

SEEDS = [10_000_000 + i for i in range(8)]


class FakeBatchedEnv(gym.Env):
    """num_envs copies of the one-env fake, stepped together like a GPU ManiSkill env."""

    def __init__(self, num_envs):
        self.envs = [FakeRSBEnv() for _ in range(num_envs)]
        self.num_envs, self.device = num_envs, torch.device("cpu")
        self.single_action_space = self.envs[0].action_space
        self.action_space = gym.spaces.Box(-1.0, 1.0, (num_envs, 14), np.float32)
        self.actions = []

    @property
    def episode_specs(self):
        return [e.episode_specs[0] for e in self.envs]

    def episode_spec(self, seed):  # what shuffled mode reads for donors, without a reset
        env = FakeRSBEnv()
        env.reset(seed=seed)
        return type("Spec", (), {"instruction": env.get_language_instruction()[0]})

    def get_language_instruction(self):
        return [e.get_language_instruction()[0] for e in self.envs]

    @staticmethod
    def _cat(items):
        if isinstance(items[0], dict):
            return {k: FakeBatchedEnv._cat([d[k] for d in items]) for k in items[0]}
        return torch.cat(items)

    def reset(self, seed=None, options=None):
        assert isinstance(seed, list) and len(seed) == self.num_envs
        out = [e.reset(seed=s) for e, s in zip(self.envs, seed)]
        return self._cat([o for o, _ in out]), self._cat([i for _, i in out])

    def step(self, action):
        assert tuple(action.shape) == (self.num_envs, 14)
        self.actions.append(action.clone())
        out = [e.step(a.numpy()) for e, a in zip(self.envs, action)]
        obs, rew, term, trunc, info = (self._cat([o[k] for o in out]) for k in range(5))
        return obs, rew, term, trunc, info


def _strip(records):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in records]


@pytest.mark.parametrize("mode", ["normal", "blank", "shuffled"])
@pytest.mark.parametrize("num_envs", [1, 3, 8])
def test_batched_records_equal_one_env_records(num_envs, mode):
    settings = EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="p", instruction_mode=mode)
    single = []
    episode_loop(FakeRSBEnv(), ScriptedPolicy(), settings, SEEDS, single.append)
    env = FakeBatchedEnv(num_envs)
    batched = []
    batched_loop(env, [ScriptedPolicy() for _ in range(num_envs)], settings, SEEDS, batched.append)
    assert sorted(_strip(batched), key=lambda r: r["seed"]) == _strip(single)
    assert all(r["steps"] <= HORIZON for r in batched)


def test_finished_envs_hold_their_last_action():
    class Counting(ScriptedPolicy):
        def act(self, obs):
            self.acts += 1
            return np.full((1, 14), float(self.acts), dtype=np.float32)

    env = FakeBatchedEnv(2)
    records = []
    # seed % 4 == 0 succeeds at step 8; seed % 4 == 3 runs to the 20-step limit
    batched_loop(env, [Counting(), Counting()], EpisodeSettings(suite_id=SUITE, seeds=[8, 11], label="p"), [8, 11],
                 records.append)
    assert [r["steps"] for r in records] == [8, HORIZON]
    acts = torch.stack(env.actions)  # (steps, envs, 14)
    assert len(acts) == HORIZON
    assert torch.all(acts[8:, 0] == acts[7, 0])  # env 0 done after 8 steps: frozen
    assert acts[-1, 1, 0] == HORIZON


class BatchedScripted:
    """The batched form: one object for all envs, one act_batch call per step that needs chunks."""

    name = "scripted"

    def __init__(self, horizon=3):
        self.horizon, self.calls, self.instructions = horizon, [], []

    def reset_batch(self, instructions, obs):
        assert obs["agent"]["qpos"].shape == (len(instructions), 14)
        self.instructions.append(list(instructions))

    def act_batch(self, obs, envs):
        assert isinstance(obs["agent"]["qpos"], np.ndarray) and obs["agent"]["qpos"].shape == (len(envs), 14)
        self.calls.append(list(envs))
        return np.zeros((len(envs), self.horizon, 14), dtype=np.float32)


@pytest.mark.parametrize("mode", ["normal", "shuffled"])
def test_batched_policy_records_equal_one_env_records(mode):
    settings = EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="p", instruction_mode=mode)
    single = []
    episode_loop(FakeRSBEnv(), ScriptedPolicy(), settings, SEEDS, single.append)
    policy, batched = BatchedScripted(), []
    batched_loop(FakeBatchedEnv(3), policy, settings, SEEDS, batched.append)
    assert sorted(_strip(batched), key=lambda r: r["seed"]) == _strip(single)
    # one call per step for all envs needing a chunk; waves of 3, 3, 2 real envs
    assert [len(x) for x in policy.instructions] == [3, 3, 2]
    assert policy.calls[0] == [0, 1, 2] and policy.calls[-1] in ([0], [1], [0, 1])
    per_env = sum(-(-r["steps"] // 3) for r in batched)  # what one policy per env would be asked
    assert sum(len(c) for c in policy.calls) == per_env and len(policy.calls) < per_env


def test_batched_policy_output_is_checked():
    class Wrong(BatchedScripted):
        def act_batch(self, obs, envs):
            return np.zeros((len(envs), 3, 7), dtype=np.float32)

    settings = EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="p")
    with pytest.raises(ValueError, match="dim 7"):
        batched_loop(FakeBatchedEnv(2), Wrong(), settings, SEEDS, list().append)

    class Short(BatchedScripted):
        def act_batch(self, obs, envs):
            return np.zeros((1, 3, 14), dtype=np.float32)

    with pytest.raises(ValueError, match="1 chunks for 2 envs"):
        batched_loop(FakeBatchedEnv(2), Short(), settings, SEEDS, list().append)


def test_one_policy_per_env_is_required():
    with pytest.raises(ValueError, match="one policy per env"):
        batched_loop(FakeBatchedEnv(2), [ScriptedPolicy()], EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="p"),
                     SEEDS, list().append)


@pytest.mark.gpu
@pytest.mark.usefixtures("gpu_physics")
def test_rsb_eval_on_gpu_parallel_envs_matches_cpu_episodes(tmp_path):
    """`rsb eval -b physx_cuda --num-envs 4`: every episode is the CPU episode of the same seed."""
    import rsb_maniskill  # noqa: F401
    from rsb_maniskill.cli import main
    from rsb_maniskill.evaluation import EVAL_ENV_KWARGS, eval_seeds
    from rsb_maniskill.evaluation.store import read_records

    out = tmp_path / "gpu"
    assert main(["eval", "random", "--suites", "RSB-Math-4", "-n", "6", "-b", "physx_cuda", "--num-envs", "4",
                 "--max-steps", "20", "--out", str(out), "-q"]) == 0
    records = read_records(out / "episodes.jsonl")
    assert sorted(r["seed"] for r in records) == eval_seeds("RSB-Math-4", 6)
    cpu = gym.make("RSB-Math-4", obs_mode="state", render_backend="none", **EVAL_ENV_KWARGS)
    for r in records:
        assert r["steps"] == 20
        assert r["episode"] == cpu.unwrapped.episode_spec(r["seed"]).to_dict()
    cpu.close()


@pytest.mark.gpu
@pytest.mark.usefixtures("gpu_physics")
def test_batched_policy_on_gpu_envs_one_call_per_step(tmp_path):
    """A batched policy on 4 physx_cuda envs: one object, rows routed to their envs, CPU episodes."""
    import rsb_maniskill  # noqa: F401
    from rsb_maniskill.evaluation import EVAL_ENV_KWARGS, eval_seeds
    from rsb_maniskill.evaluation.jobs import EvalJob, make_env

    from policy_fixtures import EnvIdPolicy

    seeds = eval_seeds("RSB-Math-4", 6)
    job = EvalJob(suite_id="RSB-Math-4", seeds=tuple(seeds), policy="policy_fixtures:EnvIdPolicy", label="b",
                  obs_mode="state", num_envs=4, sim_backend="physx_cuda", max_steps=12)
    env, policy, records = make_env(job), EnvIdPolicy(), []
    try:
        batched_loop(env, policy, job, seeds, records.append)
    finally:
        env.close()
    assert sorted(r["seed"] for r in records) == seeds and all(r["steps"] == 12 for r in records)
    assert policy.resets == 2 and policy.calls == 2 * 4  # 2 waves x 12 steps / chunks of 3
    cpu = gym.make("RSB-Math-4", obs_mode="state", render_backend="none", **EVAL_ENV_KWARGS)
    for r in records:
        assert r["episode"] == cpu.unwrapped.episode_spec(r["seed"]).to_dict()
    cpu.close()


@pytest.mark.gpu
@pytest.mark.usefixtures("gpu_physics")
def test_render_on_demand_on_gpu_envs_same_records():
    import rsb_maniskill  # noqa: F401
    from rsb_maniskill.evaluation import eval_seeds
    from rsb_maniskill.evaluation.jobs import EvalJob, make_env

    from policy_fixtures import EnvIdPolicy

    seeds = eval_seeds("RSB-Math-4", 4)
    out = {}
    for every in (False, True):
        job = EvalJob(suite_id="RSB-Math-4", seeds=tuple(seeds), policy="policy_fixtures:EnvIdPolicy", label="b",
                      obs_mode="rgb", num_envs=2, sim_backend="physx_cuda", max_steps=9, render_every_step=every,
                      env_kwargs={"camera_size": [64, 48]})
        env, records = make_env(job), []
        try:
            batched_loop(env, EnvIdPolicy(), job, seeds, records.append)
        finally:
            env.close()
        out[every] = _strip(sorted(records, key=lambda r: r["seed"]))
    assert out[False] == out[True]


@pytest.mark.gpu
@pytest.mark.usefixtures("gpu_physics")
def test_rsb_eval_num_envs_on_ray_gpu_task(tmp_path):
    """`rsb eval -b physx_cuda --num-envs 2 --executor ray`: one GPU task running 2 envs; the CPU episodes."""
    from rsb_maniskill.cli import main
    from rsb_maniskill.evaluation import eval_seeds
    from rsb_maniskill.evaluation.store import read_records

    out = tmp_path / "ray-gpu"
    assert main(["eval", "random", "--suites", "RSB-Math-4", "-n", "4", "-b", "physx_cuda", "--num-envs", "2",
                 "--num-procs", "1", "--max-steps", "10", "--out", str(out), "-q", "--executor", "ray"]) == 0
    assert sorted(r["seed"] for r in read_records(out / "episodes.jsonl")) == eval_seeds("RSB-Math-4", 4)
