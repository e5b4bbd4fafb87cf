"""Shared helpers for the robot tests: a table scene with one cube, IK, and joint-space moves."""
from __future__ import annotations

import numpy as np
import sapien
import torch

from mani_skill.utils.building import actors
from mani_skill.utils.registration import register_env

from rsb_maniskill.agents.aloha import PREFIX
from rsb_maniskill.tasks.tabletop import TableTopEnv

CUBE_HALF = 0.02
# TCP frame with the tool pointing straight down, fingers closing along world y.
DOWN_Q = np.array([0.70710678, 0.0, 0.70710678, 0.0])


@register_env("RSBTest-CubeOnTable-v1", max_episode_steps=2000)
class CubeOnTableEnv(TableTopEnv):
    """The robot at the table with one 4 cm cube; ``options['cube_xy']`` places it."""

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        self.cube = actors.build_cube(self.scene, CUBE_HALF, color=[0.8, 0.1, 0.1, 1], name="cube",
                                      initial_pose=sapien.Pose(p=[0.3, 0.3, CUBE_HALF]))

    def _initialize_episode(self, env_idx, options):
        super()._initialize_episode(env_idx, options)
        x, y = options.get("cube_xy", (0.3, 0.3))
        self.cube.set_pose(sapien.Pose(p=[x, y, CUBE_HALF]))


class ArmDriver:
    """Moves one arm through IK waypoints with pd_joint_pos actions, holding the other arm still."""

    def __init__(self, env, arm: str):
        self.env, self.arm = env, arm
        self.agent = env.unwrapped.agent
        self.model = self.agent.robot.create_pinocchio_model()
        links = [link.name for link in self.agent.robot.get_links()]
        self.tcp_index = links.index(f"{PREFIX[arm]}_tcp_link")
        self.mask = np.zeros(len(self.agent.active_joint_names), dtype=int)
        self.mask[self.agent.arm_qpos_index[arm]] = 1
        self.action = self.agent.rest_action().numpy().copy()
        self.slot = slice(0, 6) if arm == "left" else slice(6, 12)
        self.grip_slot = 12 if arm == "left" else 13

    def ik(self, xyz, quat=DOWN_Q) -> np.ndarray:
        q0 = self.agent.robot.get_qpos()[0].cpu().numpy()
        q, ok, err = self.model.compute_inverse_kinematics(
            self.tcp_index, sapien.Pose(p=xyz, q=quat), initial_qpos=q0, active_qmask=self.mask,
            max_iterations=500)
        assert ok, f"IK failed for {xyz}: {err}"
        return np.asarray(q)[self.agent.arm_qpos_index[self.arm]]

    def move_to(self, xyz, steps: int = 30):
        """Linear joint interpolation to the IK solution over ``steps`` control steps."""
        start = self.action[self.slot].copy()
        goal = self.ik(xyz)
        for t in np.linspace(0, 1, steps + 1)[1:]:
            self.action[self.slot] = start + t * (goal - start)
            self.step()

    def grip(self, value: float, steps: int = 15):
        self.action[self.grip_slot] = value
        for _ in range(steps):
            self.step()

    def step(self):
        out = self.env.step(torch.as_tensor(self.action[None], dtype=torch.float32))
        self.info = out[-1]
        return out

