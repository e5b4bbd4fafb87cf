"""The Aloha-AgileX agent: assets, loading, cameras, control and grasping physics."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import rsb_maniskill  # noqa: F401
from rsb_maniskill.agents import from_aloha14, to_aloha14
from rsb_maniskill.agents.aloha import GRIPPER_OPEN
from rsb_maniskill.agents.aloha_urdf import ASSET_DIR, build_files, sapien_disabled_pairs
from rsb_maniskill.env_ids import CONTROL_FREQ

from robot_helpers import CUBE_HALF, ArmDriver  # noqa: F401  (registers the cube env)


def make(env_id="RSB-TableTop-v1", **kw):
    kw.setdefault("obs_mode", "state")
    kw.setdefault("render_backend", "none")
    return gym.make(env_id, **kw)


def test_committed_assets_match_generator():
    for name, text in build_files().items():
        assert (ASSET_DIR / name).read_text() == text, (
            f"{name} is stale: run `python -m rsb_maniskill.agents.aloha_urdf`")


def test_sapien_srdf_fits_collision_groups():
    assert len(sapien_disabled_pairs()) <= 31


def test_the_agent_implements_the_robot_contract():
    """Every module outside the agent reads the robot from rsb_maniskill.robot: the agent must say
    the same (joint order, action layout, cameras, grippers)."""
    from rsb_maniskill import robot

    env = make()
    env.reset(seed=0)
    agent = env.unwrapped.agent
    assert agent.uid == robot.ROBOT_UID
    assert tuple(agent.active_joint_names) == robot.QPOS_JOINT_NAMES
    arm, grip = agent.controller.controllers["arm"], agent.controller.controllers["gripper"]
    assert [j.name for j in arm.joints] == list(robot.ARM_JOINT_NAMES)
    assert arm.action_space.shape == (robot.ARM_ACTION_SLICE["right"].stop,)
    assert grip.action_space.shape == (robot.ACTION_DIM - robot.ARM_ACTION_SLICE["right"].stop,)
    assert [c.uid for c in agent._sensor_configs] == [robot.sensor_uid(c) for c in robot.CAMERAS]
    assert float(GRIPPER_OPEN) == robot.FINGER_TRAVEL
    # a pd_joint_pos action sent in the contract's slots lands on the contract's joints
    action = agent.rest_action().numpy().copy()
    action[robot.ARM_ACTION_SLICE["right"]][0] += 0.3
    action[robot.GRIPPER_ACTION_INDEX["left"]] = -1.0
    for _ in range(25):
        env.step(action)
    q = dict(zip(agent.active_joint_names, agent.robot.get_qpos()[0].tolist()))
    assert abs(q[robot.ARM_JOINTS["right"][0]] - action[6]) < 0.05
    assert q[robot.FINGER_JOINT_NAMES["left"][0]] < 0.1 * robot.FINGER_TRAVEL < q[robot.FINGER_JOINT_NAMES["right"][0]]
    env.close()


def test_action_space_and_aloha14_round_trip():
    env = make()
    env.reset(seed=0)
    assert env.action_space.shape == (14,)
    agent = env.unwrapped.agent
    assert list(agent.controller.controllers) == ["arm", "gripper"]
    rng = np.random.default_rng(0)
    a = rng.uniform(-1, 1, size=(5, 14)).astype(np.float32)
    assert np.allclose(from_aloha14(to_aloha14(a)), a, atol=1e-6)
    aloha = to_aloha14(a)
    assert np.allclose(aloha[:, 6], (a[:, 12] + 1) / 2) and np.allclose(aloha[:, 7:13], a[:, 6:12])
    assert torch.allclose(to_aloha14(torch.as_tensor(a)), torch.as_tensor(aloha))
    env.close()


@pytest.mark.parametrize("mode", ["pd_joint_pos", "pd_joint_delta_pos", "pd_joint_target_delta_pos"])
def test_control_modes_step(mode):
    env = make(control_mode=mode)
    env.reset(seed=0)
    low, high = env.action_space.low, env.action_space.high
    if mode != "pd_joint_pos":
        assert np.allclose(low, -1) and np.allclose(high, 1)
    for _ in range(3):
        env.step(env.action_space.sample() * 0.1)
    env.close()


def test_cameras_render_non_blank_images():
    env = make(obs_mode="rgb", render_backend="cpu", render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    cams = obs["sensor_data"]
    assert set(cams) == {"head_camera", "left_wrist_camera", "right_wrist_camera"}
    for name, data in cams.items():
        img = data["rgb"][0].numpy()
        assert img.shape == (240, 320, 3), name
        assert img.std() > 5, f"{name} is blank"
    assert env.render()[0].numpy().std() > 5
    env.close()


def test_camera_size_configurable():
    env = make(obs_mode="rgb", render_backend="cpu", sensor_configs=dict(width=160, height=120))
    obs, _ = env.reset(seed=0)
    assert obs["sensor_data"]["head_camera"]["rgb"].shape == (1, 120, 160, 3)
    env.close()


def test_joint_targets_are_tracked():
    """After 1 s, every arm joint is within 0.02 rad of its pd_joint_pos target."""
    env = make()
    env.reset(seed=0)
    agent = env.unwrapped.agent
    target = agent.rest_action().numpy().copy()
    target[:6] = [0.4, 1.2, 1.0, -0.8, 0.5, -0.6]
    target[6:12] = [-0.4, 1.4, 0.7, -0.4, -0.5, 0.6]
    for _ in range(CONTROL_FREQ):
        env.step(torch.as_tensor(target[None]))
    q = agent.robot.get_qpos()[0].numpy()
    idx = agent.arm_qpos_index["left"] + agent.arm_qpos_index["right"]
    err = np.abs(q[idx] - target[:12])
    assert err.max() < 0.02, err
    env.close()


def test_rest_pose_is_stable():
    """Holding the rest pose for 5 s: no joint drifts more than 0.01 rad, the TCPs stay put."""
    env = make()
    env.reset(seed=0)
    agent = env.unwrapped.agent
    hold = agent.rest_action()[None]
    env.step(hold)
    q0 = agent.robot.get_qpos()[0].clone()
    tcp0 = {a: agent.tcp_pose(a).p[0].clone() for a in ("left", "right")}
    for _ in range(5 * CONTROL_FREQ):
        env.step(hold)
    assert (agent.robot.get_qpos()[0] - q0).abs().max() < 0.01
    for a in ("left", "right"):
        assert torch.linalg.norm(agent.tcp_pose(a).p[0] - tcp0[a]) < 0.005
        assert agent.tcp_pose(a).p[0, 2] > 0.1, "rest pose must keep the gripper clear of the table"
        assert agent.gripper_opening(a)[0] > 0.9 * GRIPPER_OPEN
    assert bool(agent.is_static()[0])
    env.close()


@pytest.mark.parametrize("arm,cube_xy", [("left", (0.30, 0.25)), ("right", (0.28, -0.22))])
def test_gripper_lifts_and_holds_cube(arm, cube_xy):
    """IK-driven grasp from above: close on a 4 cm cube, lift it 10 cm, hold it 2 s."""
    env = make("RSBTest-CubeOnTable-v1")
    env.reset(seed=0, options=dict(cube_xy=cube_xy))
    drv = ArmDriver(env, arm)
    cube = env.unwrapped.cube
    agent = env.unwrapped.agent
    x, y = cube_xy
    drv.grip(1.0, steps=5)
    drv.move_to([x, y, 0.12], steps=40)
    drv.move_to([x, y, CUBE_HALF + 0.005], steps=25)
    assert not bool(agent.is_grasping(cube, arm)[0]), "an open gripper must not count as grasping"
    drv.grip(-1.0, steps=15)
    assert bool(agent.is_grasping(cube, arm)[0])
    drv.move_to([x, y, CUBE_HALF + 0.10 + 0.005], steps=30)
    z_lift = cube.pose.p[0, 2].item()
    assert z_lift > CUBE_HALF + 0.09, f"cube only reached z={z_lift:.3f}"
    for _ in range(2 * CONTROL_FREQ):
        drv.step()
    assert cube.pose.p[0, 2].item() > z_lift - 0.01, "cube slipped while held"
    assert bool(agent.is_grasping(cube, arm)[0])
    env.close()
