"""``RSB-TableTop-v1``: the robot at the table and nothing else.

Used by the demo and the robot's physics tests; the RSB tasks build on the same scene."""
from __future__ import annotations

import sapien
import torch

from mani_skill.utils.structs.types import SimConfig

from rsb_maniskill.agents.aloha import AlohaAgilex
from rsb_maniskill.env_ids import CONTROL_FREQ, SIM_FREQ, TABLETOP_ID, serves
from rsb_maniskill.robot import ARMS, ROBOT_UID
from rsb_maniskill.tasks.base import RSBEnv
from rsb_maniskill.tasks.scene import TableSceneBuilder, human_camera_config


@serves(TABLETOP_ID)
class TableTopEnv(RSBEnv):
    """The Aloha-AgileX robot at the RSB table (no task: reward and success are empty)."""

    SUPPORTED_ROBOTS = [ROBOT_UID]
    SUPPORTED_REWARD_MODES = ["none"]
    agent: AlohaAgilex

    def __init__(self, *args, robot_uids=ROBOT_UID, **kwargs):
        super().__init__(*args, robot_uids=robot_uids, **kwargs)

    @property
    def _default_sim_config(self):
        return SimConfig(sim_freq=SIM_FREQ, control_freq=CONTROL_FREQ)

    @property
    def _default_sensor_configs(self):
        return []  # the robot carries the head and wrist cameras

    @property
    def _default_human_render_camera_configs(self):
        return human_camera_config()

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose())

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(self)
        self.table_scene.build()

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        self.table_scene.initialize(env_idx)

    def evaluate(self):
        return {}

    def _get_obs_extra(self, info: dict):
        return {f"{arm}_tcp_pose": self.agent.tcp_pose(arm).raw_pose for arm in ARMS}
