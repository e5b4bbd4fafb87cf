"""The K envs' observation built once from the group's pictures (``compat.batched_obs``, issue 57):
equal, key for key (shape, dtype, value), to each env's own observation joined, with a stand-in
group that renders each scene on its own (no CUDA here); the textures the obs mode needs only; the
observation's images its own (not the group's buffers); per-env image noise; envs held."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from group_stand_ins import SMALL, SUITE, CamerasByScene, SceneByScene

import rsb_maniskill  # noqa: F401
from rsb_maniskill import compat
from rsb_maniskill.sim.camera_group import CameraGroup
from rsb_maniskill.vector import RSBVectorEnv
from rsb_maniskill.vector.env import GroupRenderer


class Recording(SceneByScene):
    """The scene-by-scene stand-in group, remembering the textures each camera group was asked for."""

    textures: list = []

    def create_camera_group(self, cameras, textures):
        Recording.textures.append(list(textures))
        return CamerasByScene(cameras)


def recording_group(bases):
    return CameraGroup(bases, device="cpu", group_factory=Recording, cuda_array=lambda t: t)


def assert_same(a, b, where="obs"):
    """Equal observations: the same keys in the same order, tensors of equal shape, dtype and values."""
    if isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            assert_same(a[k], b[k], f"{where}/{k}")
    else:
        assert a.shape == b.shape and a.dtype == b.dtype, (where, a.shape, b.shape, a.dtype, b.dtype)
        assert torch.equal(a.cpu(), b.cpu()), where


def pair(obs_mode: str, k: int = 2, **kwargs):
    return {"group": RSBVectorEnv(SUITE, k, obs_mode=obs_mode, renderer=GroupRenderer(recording_group), **SMALL,
                                  **kwargs),
            "own": RSBVectorEnv(SUITE, k, obs_mode=obs_mode, renderer="per_scene", **SMALL, **kwargs)}


def run_both(envs, steps: int = 2):
    """Reset, a few steps, a partial reset, an env held: every observation of both paths compared."""
    action = torch.as_tensor(np.stack([envs["own"].single_action_space.sample() * 0.3
                                       for _ in range(envs["own"].num_envs)]))
    assert_same(*(e.reset(seed=[5, 6])[0] for e in envs.values()), "reset")
    for t in range(steps):
        assert_same(*(e.step(action)[0] for e in envs.values()), f"step {t}")
    assert_same(*(e.reset(seed=[9], options={"env_idx": [0]})[0] for e in envs.values()), "partial reset")
    for e in envs.values():
        e.hold(1)
    assert_same(*(e.step(action)[0] for e in envs.values()), "held")
    assert_same(*(e.get_obs() for e in envs.values()), "get_obs()")


@pytest.mark.parametrize("obs_mode", ["rgb", "rgbd"])
def test_batched_observation_equals_each_envs_own(obs_mode):
    Recording.textures = []
    envs = pair(obs_mode)
    try:
        run_both(envs)
        rgb = envs["group"].get_obs()["sensor_data"]["head_camera"]["rgb"]
        assert rgb.dtype == torch.uint8 and rgb.shape == (2, 24, 32, 3) and rgb.any()
    finally:
        for e in envs.values():
            e.close()
    # the textures the obs mode reads, one camera group per camera, rebuilt at each reset
    want = ["Color"] if obs_mode == "rgb" else ["Color", "PositionSegmentation"]
    assert Recording.textures and all(t == want for t in Recording.textures)


def test_image_noise_is_each_envs_own():
    """The noise axis draws per env and step (the task's own sensor-data step): the batched path
    applies it to each env's rows, the same draws as each env's own observation."""
    envs = pair("rgb", perturb={"noise": 2})
    try:
        run_both(envs, steps=1)
    finally:
        for e in envs.values():
            e.close()


def test_observation_images_are_not_the_groups_buffers():
    """The next render overwrites the group's pictures; an observation already returned keeps its images."""
    vec = RSBVectorEnv(SUITE, 2, obs_mode="rgb", renderer=GroupRenderer(recording_group), **SMALL)
    try:
        first, _ = vec.reset(seed=[1, 2])
        kept = first["sensor_data"]["head_camera"]["rgb"].clone()
        CamerasByScene.blank = True
        blank = vec.get_obs()["sensor_data"]["head_camera"]["rgb"]
        assert not blank.any() and kept.any()
        assert torch.equal(first["sensor_data"]["head_camera"]["rgb"], kept)
    finally:
        CamerasByScene.blank = False
        vec.close()


def test_needed_textures_follow_the_obs_mode():
    import gymnasium as gym

    for mode, want in (("rgb", ["Color"]), ("depth", ["PositionSegmentation"]),
                       ("rgb+depth+segmentation", ["Color", "PositionSegmentation"]),
                       ("sensor_data", ["Color", "PositionSegmentation"])):
        env = gym.make(SUITE, obs_mode=mode, **SMALL)
        try:
            got = compat.needed_textures(env.unwrapped)
        finally:
            env.close()
        assert set(got) == {"head_camera", "left_wrist_camera", "right_wrist_camera"}
        assert all(t == want for t in got.values()), (mode, got)


def test_camera_envs_step_without_an_observation_of_their_own():
    """The sub-envs step under obs mode none (the K observations are built once afterwards); inside
    skip_observations a camera env's step and reset return none at all."""
    vec = RSBVectorEnv(SUITE, 2, obs_mode="rgb", renderer=GroupRenderer(recording_group), **SMALL)
    try:
        vec.reset(seed=[1, 2])
        seen = []
        for base in vec.bases:
            own = base.get_obs
            base.get_obs = lambda info=None, unflattened=False, own=own, base=base: seen.append(base.obs_mode) or own(
                info, unflattened)
        with vec.skip_observations():
            assert vec.step(torch.zeros(vec.action_space.shape))[0] == {}
            assert vec.reset(seed=[3], options={"env_idx": [1]})[0] == {}
        assert seen and set(seen) == {"none"}
        assert vec.get_obs()["sensor_data"]["head_camera"]["rgb"].shape == (2, 24, 32, 3)
    finally:
        vec.close()


def test_recorded_demos_render_through_the_batched_path(tmp_path, monkeypatch):
    """render_demos sets K recorded states and observes all K in one call: with the stand-in group the
    frames equal one env rendering the episodes in turn, and the K resets of a wave build the group once."""
    from rsb_maniskill.export import render_demos
    from rsb_maniskill.motionplan.generate import GenerateConfig, generate
    from rsb_maniskill.vector import env as vector_env

    summary = generate(GenerateConfig(env_id=SUITE, out=str(tmp_path), num=2, progress=False))
    assert summary.completed == 2
    cams = ("head", "right_wrist")
    try:
        one = list(render_demos.render_episodes(summary.path, cams, 40, num_envs=1))
        renderers = []
        monkeypatch.setattr(vector_env, "make_renderer",
                            lambda choice, obs_mode: renderers.append(GroupRenderer(recording_group)) or renderers[-1])
        two = list(render_demos.render_episodes(summary.path, cams, 40, num_envs=2))
    finally:
        render_demos.close_render_env()
    assert len(one) == len(two) == 2 and renderers[0].rebuilds == 1  # one wave: one group for its K resets
    for a, b in zip(one, two):
        assert a.meta == b.meta
        np.testing.assert_array_equal(a.state, b.state)
        for c in cams:
            assert a.frames[c].shape == b.frames[c].shape and a.frames[c].any()
            np.testing.assert_array_equal(a.frames[c], b.frames[c])
