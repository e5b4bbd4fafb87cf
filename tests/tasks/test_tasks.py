"""The RSB answer-selection tasks: registration, obs modes, determinism, grasp/place rules."""
from __future__ import annotations

import json
import subprocess
import sys

import gymnasium as gym
import pytest
import torch

import rsb_maniskill  # noqa: F401
from rsb_maniskill.env_ids import TASK_MAX_EPISODE_STEPS
from rsb_maniskill.semantic import SUITE_IDS
from rsb_maniskill.tasks.answer_selection import HOLD_STEPS, ZONE_XY

from robot_helpers import ArmDriver
from task_envs import HELPERS, _episode_fingerprint, make

OBS_MODES = ("state", "state_dict", "rgb", "rgbd", "none")


@pytest.mark.parametrize("suite_id", SUITE_IDS)
def test_every_suite_resets_and_steps(suite_id, question_data):
    env = make(suite_id)
    obs, info = env.reset(seed=1)
    n = int(suite_id.rsplit("-", 1)[1])
    assert obs.shape[0] == 1 and obs.shape[1] > 0
    assert env.unwrapped.n_choices == n and env.unwrapped.pool.raw_poses().shape == (1, n, 7)
    (instruction,) = env.unwrapped.get_language_instruction()
    assert isinstance(instruction, str) and len(instruction) > 10
    spec = env.unwrapped.episode_specs[0]
    assert info["target_block"].item() == spec.target_block
    assert info["question_id"].item() == spec.question_id
    assert not info["grasped_any"].item() and not info["success"].item()
    for _ in range(2):
        obs, reward, term, trunc, info = env.step(env.unwrapped.agent.rest_action()[None])
    assert torch.isfinite(reward).all()
    assert gym.spec(suite_id).max_episode_steps == TASK_MAX_EPISODE_STEPS
    env.close()


@pytest.mark.parametrize("obs_mode", OBS_MODES)
@pytest.mark.parametrize("suite_id", ["RSB-Math-4", "RSB-Direct-10"])
def test_obs_modes(suite_id, obs_mode):
    env = make(suite_id, obs_mode=obs_mode)
    obs, _ = env.reset(seed=0)
    n = env.unwrapped.n_choices
    if obs_mode == "state_dict":
        assert obs["extra"]["block_pose"].shape == (1, 7 * n)
        assert obs["extra"]["block_id"].tolist() == [list(range(n))]
        u = env.unwrapped
        blocks = u._block_positions()[0]
        left = u.agent.tcp_pose("left").raw_pose[0, :3]
        torch.testing.assert_close(obs["extra"]["tcp_to_block_pos"].view(2, n, 3)[0], blocks - left)
        torch.testing.assert_close(obs["extra"]["block_to_zone_pos"].view(n, 3), u.zone.pose.p[0] - blocks)
        assert "qpos" in obs["agent"]
    if obs_mode in ("rgb", "rgbd"):
        cams = obs["sensor_data"]
        assert set(cams) == {"head_camera", "left_wrist_camera", "right_wrist_camera"}
        assert cams["head_camera"]["rgb"].shape == (1, 240, 320, 3)
        assert "block_pose" not in obs["extra"], "pixel modes must not carry privileged block poses"
        if obs_mode == "rgbd":
            assert "depth" in cams["head_camera"]
    env.step(env.unwrapped.agent.rest_action()[None])
    env.close()


def test_camera_size_and_render():
    env = make(obs_mode="rgb", camera_size=(160, 120), render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    assert obs["sensor_data"]["head_camera"]["rgb"].shape == (1, 120, 160, 3)
    assert env.render().shape[-1] == 3
    env.close()


FINGERPRINT_SCRIPT = """
import json, sys
sys.path.insert(0, {tests!r})
from task_envs import _episode_fingerprint
print(json.dumps(_episode_fingerprint({suite!r}, {seed})))
"""


# one suite in test-fast; the 10-candidate layouts in the slow run (a fresh process each, ~5 s)
@pytest.mark.parametrize("suite_id", ["RSB-Math-4", pytest.param("RSB-Math-10", marks=pytest.mark.slow),
                                      pytest.param("RSB-Math-10-Objects", marks=pytest.mark.slow)])
def test_same_seed_same_episode_in_fresh_process(suite_id):
    here = _episode_fingerprint(suite_id, seed=7)
    code = FINGERPRINT_SCRIPT.format(tests=HELPERS, suite=suite_id, seed=7)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    there = json.loads(out.stdout.strip().splitlines()[-1])
    assert here == there
    other = _episode_fingerprint(suite_id, seed=8)
    assert other["xy"] != here["xy"] and other["instruction"] != here["instruction"]


@pytest.mark.parametrize("suite_id", ["RSB-Math-10", "RSB-Math-4-Objects"])
def test_reset_twice_with_seed_is_identical(suite_id):
    env = make(suite_id)
    env.reset(seed=3)
    a = env.unwrapped.get_state_dict()
    inst = env.unwrapped.get_language_instruction()
    env.reset(seed=4)
    env.reset(seed=3)
    b = env.unwrapped.get_state_dict()
    assert inst == env.unwrapped.get_language_instruction()
    assert torch.allclose(a["task"], b["task"])
    on_table = {f"candidate_{k.replace(':', '_')}" for k in env.unwrapped.episode_specs[0].candidates}
    assert on_table <= set(a["actors"])
    for name in on_table | {"answer_zone"}:
        assert torch.allclose(a["actors"][name], b["actors"][name]), name
    env.close()


@pytest.mark.parametrize("suite_id", ["RSB-Math-10", "RSB-Math-10-Objects"])
def test_state_dict_restores_task_ids(suite_id):
    env = make(suite_id)
    env.reset(seed=11)
    state = env.unwrapped.get_state_dict()
    target = int(env.unwrapped.target_block[0])
    poses = env.unwrapped.pool.raw_poses().clone()
    env.reset(seed=12)
    env.unwrapped.set_state_dict(state)
    assert int(env.unwrapped.target_block[0]) == target
    assert torch.allclose(env.unwrapped.pool.raw_poses(), poses, atol=1e-6), "the same candidates, in place"
    info = env.unwrapped.get_info()
    assert int(info["target_block"][0]) == target
    env.close()


def test_layout_min_spacing_and_reach():
    env = make("RSB-Math-10")
    for seed in range(20):
        env.reset(seed=seed)
        xy = env.unwrapped.pool.raw_poses()[0, :, :2]
        d = torch.cdist(xy, xy) + torch.eye(len(xy)) * 10
        assert d.min() > 0.07, f"seed {seed}: blocks {d.min():.3f} m apart"
        assert (xy[:, 0] > 0.25).all() and (xy[:, 0] < 0.45).all()
        zone_gap = torch.linalg.norm(xy - torch.tensor(ZONE_XY), dim=1).min()
        assert zone_gap > 0.1
    env.close()


def _footprint_boxes(u) -> torch.Tensor:
    """(N, 4) world bounding boxes [xmin, ymin, xmax, ymax] of the candidates' turned footprints."""
    pose = u.pool.raw_poses()[0]
    yaw = 2 * torch.atan2(pose[:, 6], pose[:, 3])
    hx, hy = u.pool.half_extents()[0].unbind(-1)
    ex = hx * yaw.cos().abs() + hy * yaw.sin().abs()
    ey = hx * yaw.sin().abs() + hy * yaw.cos().abs()
    return torch.stack([pose[:, 0] - ex, pose[:, 1] - ey, pose[:, 0] + ex, pose[:, 1] + ey], 1)


@pytest.mark.parametrize("suite_id", ["RSB-Math-10-Objects", "RSB-Math-4-Objects"])
def test_objects_do_not_overlap_and_stay_in_reach(suite_id):
    env = make(suite_id)
    for seed in range(40):
        env.reset(seed=seed)
        u = env.unwrapped
        box = _footprint_boxes(u)
        n = len(box)
        for i in range(n):
            for j in range(i + 1, n):
                apart = ((box[i, 2] < box[j, 0]) | (box[j, 2] < box[i, 0])
                         | (box[i, 3] < box[j, 1]) | (box[j, 3] < box[i, 1]))
                assert apart, f"seed {seed}: candidates {i} and {j} overlap"
        assert (box[:, 0] > 0.22).all() and (box[:, 2] < 0.48).all() and (box[:, [1, 3]].abs() < 0.32).all()
        assert len(set(u.episode_specs[0].candidates)) == n
        assert len({k.split(":")[0] for k in u.episode_specs[0].candidates}) == n, "distinct categories"
    env.close()


def test_target_block_is_not_tied_to_slot_or_identity():
    """Over many seeds the correct block takes every identity and every layout slot."""
    env = make("RSB-Math-4")
    targets, slots = set(), set()
    for seed in range(60):
        env.reset(seed=seed)
        t = int(env.unwrapped.target_block[0])
        targets.add(t)
        slots.add(int(env.unwrapped.block_slot[0, t]))
    assert targets == set(range(4))
    assert len(slots) >= 10
    env.close()


# ---------------------------------------------------------------- grasp and placement rules
def _setup(seed=5, suite="RSB-Math-4"):
    env = make(suite)
    env.reset(seed=seed)
    return env, env.unwrapped


def _arm_for(xy) -> str:
    return "left" if float(xy[1]) >= 0 else "right"


def test_touch_without_closing_is_no_grasp():
    env, u = _setup()
    x, y = u.candidate_actor(0).pose.p[0, :2].tolist()
    arm = _arm_for((x, y))
    drv = ArmDriver(env, arm)
    drv.grip(1.0, steps=5)
    # Offset so one open finger lands on the block's top face and presses it.
    off = 0.05
    drv.move_to([x, y + off, 0.12], steps=30)
    drv.move_to([x, y + off, 0.04 + 0.0246 - 0.006], steps=20)
    for _ in range(5):  # let the arm settle onto the block
        drv.step()
    forces = u.contacts.forces()[0]
    assert forces[:, 0].max() > 0.5, "the finger should be touching the block"
    for _ in range(HOLD_STEPS + 4):
        drv.step()
    assert not drv.info["grasped_any"].item()
    env.close()


def test_closed_empty_gripper_is_no_grasp():
    env, u = _setup()
    drv = ArmDriver(env, "left")
    drv.move_to([0.25, 0.15, 0.08], steps=20)
    drv.grip(-1.0, steps=HOLD_STEPS + 4)
    assert not drv.info["grasped_any"].item()
    assert u.agent.is_gripper_closed("left").item()
    env.close()


def _pick(env, u, index) -> ArmDriver:
    x, y = u.candidate_actor(index).pose.p[0, :2].tolist()
    drv = ArmDriver(env, _arm_for((x, y)))
    drv.grip(0.5, steps=5)
    drv.move_to([x, y, 0.12], steps=30)
    drv.move_to([x, y, 0.03], steps=20)
    drv.grip(-1.0, steps=12)
    drv.move_to([x, y, 0.12], steps=20)
    return drv


@pytest.mark.parametrize("correct", [True, False])
def test_lifted_block_is_a_grasp_and_placement_rules(correct):
    env, u = _setup(seed=5)
    target = int(u.target_block[0])
    index = target if correct else (target + 1) % u.n_choices
    drv = _pick(env, u, index)
    info = drv.info
    assert info["grasped_any"].item() and info["first_grasped"].item() == index
    assert info["grasped_correct"].item() == correct and info["grasped_wrong"].item() == (not correct)
    # Into the zone, still held: not placed.
    zx, zy = ZONE_XY
    drv.move_to([zx, zy, 0.12], steps=30)
    drv.move_to([zx, zy, 0.032], steps=20)
    for _ in range(5):
        drv.step()
    assert not drv.info["placed_correct"].item() and not drv.info["placed_wrong"].item()
    # Released and at rest: placed, and the episode ends with success or fail.
    drv.grip(0.5, steps=8)
    drv.move_to([zx, zy, 0.12], steps=15)
    info = drv.info
    assert info["placed_correct"].item() == correct and info["placed_wrong"].item() == (not correct)
    assert info["success"].item() == correct and info["fail"].item() == (not correct)
    assert info["grasped_any"].item(), "grasp flags are latched over the episode"
    env.close()


# ---------------------------------------------------------------- ids
def test_task_classes_declare_the_ids_of_env_ids():
    """Each class names its ids above itself (@serves); together they are env_ids.ENVS, each once,
    and ManiSkill holds each id with the class that declares it."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    from rsb_maniskill.env_ids import ENVS, TABLETOP_ID, TASK_ENVS
    from rsb_maniskill.registration import load_simulator, served_by
    from rsb_maniskill.tasks import TASK_CLASSES, AnswerSelectionEnv, TableTopEnv

    assert AnswerSelectionEnv.ENV_IDS == tuple(TASK_ENVS) and TableTopEnv.ENV_IDS == (TABLETOP_ID,)
    classes = served_by(TASK_CLASSES)
    assert set(classes) == set(ENVS)
    load_simulator()
    assert all(REGISTERED_ENVS[uid].cls is cls for uid, cls in classes.items())


def test_serves_takes_known_ids_and_every_id_needs_one_class():
    from rsb_maniskill.env_ids import ENVS, TABLETOP_ID, serves
    from rsb_maniskill.registration import served_by

    with pytest.raises(ValueError, match="RSB-Math-7"):
        serves("RSB-Math-7")
    table = serves(TABLETOP_ID)(type("Table", (), {}))
    with pytest.raises(RuntimeError, match="no task class serves RSB-"):
        served_by([table])
    every = serves(*ENVS)(type("Every", (), {}))
    with pytest.raises(RuntimeError, match=f"{TABLETOP_ID} is served by both"):
        served_by([every, table])
    assert set(served_by([every])) == set(ENVS)


# ---------------------------------------------------------------- errors
def test_unknown_id_fails_clearly():
    with pytest.raises(gym.error.Error, match="RSB-Math-7"):
        gym.make("RSB-Math-7")


def test_bad_split_and_color_map_fail_clearly():
    with pytest.raises(ValueError, match="split"):
        make("RSB-Math-4", split="validation")
    with pytest.raises(ValueError, match="color"):
        make("RSB-Math-4", color_map="rainbow")


# ---------------------------------------------------------------- GPU
@pytest.mark.gpu
@pytest.mark.usefixtures("gpu_physics")  # skips without CUDA, or without the PhysX GPU library and network
def test_gpu_parallel_envs_are_independent():
    env = gym.make("RSB-Math-10", num_envs=16, obs_mode="state", sim_backend="physx_cuda",
                   render_backend="none")
    env.reset(seed=list(range(16)))
    u = env.unwrapped
    assert len(set(u.get_language_instruction())) > 1
    assert len(set(u.target_block.tolist())) > 1
    # Same seeds give the same episodes as on the CPU backend.
    cpu = make("RSB-Math-10")
    for i in (0, 5):
        cpu.reset(seed=i)
        assert cpu.unwrapped.get_language_instruction()[0] == u.get_language_instruction()[i]
        assert torch.allclose(cpu.unwrapped.pool.raw_poses()[0, :, :3], u.pool.raw_poses()[i, :, :3].cpu(), atol=1e-4)
    # Moving env 0's arm leaves the others alone.
    before = u.agent.robot.get_qpos().clone()
    action = u.agent.rest_action().to(u.device).repeat(16, 1)
    action[0, 0] += 0.5
    for _ in range(10):
        env.step(action)
    after = u.agent.robot.get_qpos()
    assert (after[0] - before[0]).abs().max() > 0.1
    assert (after[1:] - before[1:]).abs().max() < 0.02
    env.close()


@pytest.mark.gpu
@pytest.mark.usefixtures("gpu_physics")
def test_gpu_objects_differ_per_env_and_match_cpu():
    env = gym.make("RSB-Math-10-Objects", num_envs=16, obs_mode="state", sim_backend="physx_cuda",
                   render_backend="none")
    env.reset(seed=list(range(16)))
    u = env.unwrapped
    assert len({tuple(s.candidates) for s in u.episode_specs}) == 16, "each env draws its own objects"
    cpu = make("RSB-Math-10-Objects")
    for i in (0, 7):
        cpu.reset(seed=i)
        assert cpu.unwrapped.episode_specs[0].candidates == u.episode_specs[i].candidates
        assert torch.equal(cpu.unwrapped.pool.index[0], u.pool.index[i].cpu())
        assert torch.allclose(cpu.unwrapped.pool.raw_poses()[0, :, :3], u.pool.raw_poses()[i, :, :3].cpu(), atol=1e-4)
    for _ in range(20):
        env.step(u.agent.rest_action().to(u.device).repeat(16, 1))
    z = u.pool.raw_poses()[..., 2]
    assert (z - u.rest_z).abs().max() < 0.01, "candidates rest on the table in every env"
    env.close()
