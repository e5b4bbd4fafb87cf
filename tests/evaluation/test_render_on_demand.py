"""Render on demand: cameras rendered only when a chunked policy asks for a chunk, same records."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from rsb_maniskill.evaluation.runner import EpisodeSettings, Observations, episode_loop

from fake_envs import SUITE, FakeRSBEnv

SEEDS = [10_000_000 + i for i in range(8)]


class FakeVisualEnv(FakeRSBEnv):
    """The fake with ManiSkill's observation switch: sensor data only outside the state modes."""

    def __init__(self):
        super().__init__()
        self._obs_mode = "rgb"
        self.renders = 0

    @property
    def obs_mode(self):
        return self._obs_mode

    def get_obs(self, info=None):
        obs = {"agent": {"qpos": torch.full((1, 14), float(self.t))}}
        if self._obs_mode not in ("state", "state_dict"):
            self.renders += 1
            img = torch.full((1, 6, 8, 3), self.t * 7 % 256, dtype=torch.uint8)
            obs["sensor_data"] = {"head": {"rgb": img}}
        return obs

    def _obs(self):
        return self.get_obs()


class ChunkedPolicy:
    """Chunks of ``size`` actions computed from the image and qpos it is shown; keeps what it saw."""

    def __init__(self, size=5):
        self.size, self.seen = size, []

    def reset(self, instruction, obs):
        self.seen.append(("reset", instruction, obs["agent"]["qpos"].copy()))

    def act(self, obs):
        img = obs["sensor_data"][next(iter(obs["sensor_data"]))]["rgb"]
        self.seen.append((img.copy(), obs["agent"]["qpos"].copy()))
        level = (float(img.mean()) / 255.0 + float(np.abs(obs["agent"]["qpos"]).mean())) % 1.0
        return np.full((self.size, 14), 0.1 * level - 0.05, dtype=np.float32)


def _strip(records):
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in records]


def _run(env, every_step, size=5, seeds=SEEDS, **kw):
    policy, records = ChunkedPolicy(size), []
    settings = EpisodeSettings(suite_id=SUITE, seeds=seeds, label="p", render_every_step=every_step, **kw)
    episode_loop(env, policy, settings, seeds, records.append)
    return records, policy.seen


def _same_seen(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        for u, v in zip(x, y):
            assert np.array_equal(u, v) if isinstance(u, np.ndarray) else u == v


def test_cameras_rendered_once_per_chunk_with_the_same_records():
    eager_env, lazy_env = FakeVisualEnv(), FakeVisualEnv()
    eager, seen_eager = _run(eager_env, True)
    lazy, seen_lazy = _run(lazy_env, False)
    assert _strip(lazy) == _strip(eager)
    _same_seen(seen_lazy, seen_eager)  # the policy is shown the very same observations
    acts = sum(1 for s in seen_lazy if not isinstance(s[0], str))
    steps = sum(r["steps"] for r in lazy)
    # every step and reset renders eagerly; lazily: resets, plus one per chunk after the first
    assert eager_env.renders == steps + len(SEEDS)
    assert lazy_env.renders == acts  # len(SEEDS) resets + (acts - len(SEEDS)) chunks asked after a step
    assert lazy_env.renders < eager_env.renders / 3


def test_state_envs_are_stepped_as_they_are():
    env = FakeVisualEnv()
    env._obs_mode = "state"
    assert not Observations(env).lazy
    assert Observations(FakeVisualEnv()).lazy
    assert not Observations(FakeVisualEnv(), every_step=True).lazy
    assert not Observations(FakeRSBEnv()).lazy  # no ManiSkill get_obs: nothing to switch


def test_obs_mode_restored_after_a_failing_step():
    class Broken(FakeVisualEnv):
        def step(self, action):
            raise RuntimeError("boom")

    env = Broken()
    obs = Observations(env)
    obs.reset(seed=1)
    with pytest.raises(RuntimeError, match="boom"):
        obs.step(np.zeros(14, np.float32))
    assert env._obs_mode == "rgb"


@pytest.mark.slow
def test_real_rgb_env_same_records_and_observations():
    """RSB-Math-4 with rgb cameras: on demand and every step give the same episodes, pixel for pixel."""
    import gymnasium as gym

    import rsb_maniskill  # noqa: F401
    from rsb_maniskill.evaluation import EVAL_ENV_KWARGS

    env = gym.make(SUITE, obs_mode="rgb", camera_size=(64, 48), **EVAL_ENV_KWARGS)
    try:
        seeds = [10_000_000, 10_000_001]
        eager, seen_eager = _run(env, True, size=4, seeds=seeds, max_steps=24)
        lazy, seen_lazy = _run(env, False, size=4, seeds=seeds, max_steps=24)
    finally:
        env.close()
    assert [r["steps"] for r in lazy] == [24, 24]
    assert _strip(lazy) == _strip(eager)
    _same_seen(seen_lazy, seen_eager)
    assert any(float(s[0].std()) > 0 for s in seen_lazy if not isinstance(s[0], str))  # real images, not blanks
