"""A tiny fake of the RSB task contract (no simulator) and a scripted policy: the evaluation
tests drive the runner with them (one env, and the parallel-env form a GPU ManiSkill env has)."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

SUITE = "RSB-Math-4"
HORIZON = 20
# seed % 4 -> outcome: success at step 8 / wrong block placed (fail) at step 6 /
# correct block grasped, never placed (time limit) / nothing grasped (time limit)
OUTCOMES = ("success", "wrong_target", "not_placed", "no_grasp")


class FakeSpec:
    def __init__(self, seed):
        self.seed, self.question_id, self.target_block = seed, seed % 7, seed % 4
        self.correct_letter = "ABCD"[(seed // 4) % 4]

    def to_dict(self):
        return {"seed": self.seed, "question_id": self.question_id, "correct_letter": self.correct_letter}


class FakeRSBEnv(gym.Env):
    """One-env batch like ManiSkill: torch obs / info with a leading env dim, latched flags."""

    def __init__(self):
        self.action_space = gym.spaces.Box(-1.0, 1.0, (14,), np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (14,), np.float32)
        self.episode_specs = []
        self.reset_seeds, self.n_steps, self.closed = [], 0, False

    def get_language_instruction(self):
        return [f"which block answers question {self.seed}?"]

    def _obs(self):
        return {"agent": {"qpos": torch.full((1, 14), float(self.t))},
                "sensor_data": {"head": {"rgb": torch.zeros((1, 6, 8, 3), dtype=torch.uint8)}}}

    def _info(self):
        kind = OUTCOMES[self.seed % 4]
        target, wrong = self.seed % 4, (self.seed + 1) % 4
        grasp_t = {"success": 3, "wrong_target": 3, "not_placed": 4, "no_grasp": None}[kind]
        grasped = grasp_t is not None and self.t >= grasp_t
        placed_c = kind == "success" and self.t >= 8
        placed_w = kind == "wrong_target" and self.t >= 6
        b = lambda v: torch.tensor([bool(v)])  # noqa: E731
        return {
            "grasped_any": b(grasped), "grasped_correct": b(grasped and kind in ("success", "not_placed")),
            "grasped_wrong": b(grasped and kind == "wrong_target"), "placed_correct": b(placed_c),
            "placed_wrong": b(placed_w), "success": b(placed_c and not placed_w), "fail": b(placed_w),
            "first_grasped": torch.tensor([(wrong if kind == "wrong_target" else target) if grasped else -1]),
        }

    def reset(self, seed=None, options=None):
        self.seed, self.t = seed, 0
        self.reset_seeds.append(seed)
        self.episode_specs = [FakeSpec(seed)]
        return self._obs(), self._info()

    def step(self, action):
        assert np.asarray(action).shape == (14,)
        self.t += 1
        self.n_steps += 1
        info = self._info()
        terminated = info["success"] | info["fail"]
        truncated = torch.tensor([self.t >= HORIZON])
        return self._obs(), torch.zeros(1), terminated, truncated, info

    def close(self):
        self.closed = True


class ScriptedPolicy:
    """Returns chunks of ``horizon`` actions; records what it was given."""

    name = "scripted"

    def __init__(self, horizon=3):
        self.horizon, self.instructions, self.obs, self.acts = horizon, [], [], 0

    def reset(self, instruction, obs):
        self.instructions.append(instruction)
        self.obs.append(obs)

    def act(self, obs):
        self.acts += 1
        assert isinstance(obs["agent"]["qpos"], np.ndarray) and obs["agent"]["qpos"].shape == (14,)
        return np.zeros((self.horizon, 14), dtype=np.float32)


# the parallel-env tests' seeds (and those of the tests that borrow their env)
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

