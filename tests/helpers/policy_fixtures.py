"""Policies the tests serve from another process (``python -m rsb_maniskill.policies.remote.server
policy_fixtures:EnvIdPolicy`` with tests/helpers/ on PYTHONPATH)."""
from __future__ import annotations

import numpy as np


class EnvIdPolicy:
    """Both forms. Chunks of 3 actions equal to env_id / 10 (0 for the single form), so a test can
    see which env each row went to; counts its calls in the first action's last entry."""

    def __init__(self, horizon: int = 3):
        self.horizon, self.calls, self.resets = horizon, 0, 0

    def reset(self, instruction, obs):
        self.resets += 1

    def act(self, obs):
        self.calls += 1
        return np.zeros((self.horizon, 14), dtype=np.float32)

    def fork(self):  # served one env at a time: every env counts on this object (it keeps no episode state)
        return self

    def reset_batch(self, instructions, obs):
        assert obs["agent"]["qpos"].shape[0] == len(instructions)
        self.resets += 1

    def reset_envs(self, instructions, obs, envs):  # served (rsb serve): the envs that start, only
        self.resets += 1

    def act_batch(self, obs, envs):
        assert obs["agent"]["qpos"].shape == (len(envs), 14)
        self.calls += 1
        out = np.zeros((len(envs), self.horizon, 14), dtype=np.float32)
        out += (np.asarray(envs, dtype=np.float32) / 10)[:, None, None]
        return out
