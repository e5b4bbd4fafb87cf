"""The tabletop every RSB scene shares: a table whose top is z = 0 with the robot at its near
edge (x = 0), a floor below, and the cameras that look at it. No task logic lives here."""
from __future__ import annotations

import numpy as np
import sapien
import torch

from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.building.ground import build_ground
from mani_skill.utils.scene_builder.scene_builder import SceneBuilder
from mani_skill.utils.structs.actor import Actor

TABLE_X = (-0.10, 0.80)  # the robot's arm bases stand at x = 0
TABLE_Y = (-0.75, 0.75)
TABLE_THICKNESS = 0.04
FLOOR_Z = -0.75
TABLE_COLOR = (0.66, 0.55, 0.42, 1.0)
LEG_COLOR = (0.30, 0.26, 0.22, 1.0)
HUMAN_CAMERA_EYE, HUMAN_CAMERA_TARGET = (1.15, -0.95, 0.85), (0.15, 0.0, 0.05)


class TableSceneBuilder(SceneBuilder):
    """Builds the table and floor; ``initialize`` puts the robot in its rest pose."""

    def build(self, per_env_materials: bool = False):
        """``per_env_materials``: one table per env, merged, each with its own colours (the table
        robustness axis with parallel envs)."""
        if per_env_materials:
            parts = [self._build_table([e], f"table-{e}") for e in range(self.env.num_envs)]
            self.table = Actor.merge(parts, "table")
        else:
            self.table = self._build_table(None, "table")
        self.ground = build_ground(self.scene, altitude=FLOOR_Z)
        self.scene_objects = [self.table, self.ground]

    def _build_table(self, scene_idxs: list[int] | None, name: str) -> Actor:
        builder = self.scene.create_actor_builder()
        size = np.array([TABLE_X[1] - TABLE_X[0], TABLE_Y[1] - TABLE_Y[0], TABLE_THICKNESS])
        center = [sum(TABLE_X) / 2, sum(TABLE_Y) / 2, -TABLE_THICKNESS / 2]
        mat = sapien.render.RenderMaterial(base_color=TABLE_COLOR, roughness=0.7, specular=0.2)
        builder.add_box_collision(sapien.Pose(center), size / 2)
        builder.add_box_visual(sapien.Pose(center), size / 2, material=mat)
        leg_mat = sapien.render.RenderMaterial(base_color=LEG_COLOR, roughness=0.8)
        leg_h = -FLOOR_Z - TABLE_THICKNESS
        for x in (TABLE_X[0] + 0.05, TABLE_X[1] - 0.05):
            for y in (TABLE_Y[0] + 0.05, TABLE_Y[1] - 0.05):
                builder.add_box_visual(sapien.Pose([x, y, FLOOR_Z + leg_h / 2]), [0.025, 0.025, leg_h / 2],
                                       material=leg_mat)
        builder.initial_pose = sapien.Pose()
        if scene_idxs is not None:
            builder.set_scene_idxs(scene_idxs)
        return builder.build_static(name=name)

    def initialize(self, env_idx: torch.Tensor):
        agent = self.env.agent
        qpos = torch.as_tensor(agent.keyframes["rest"].qpos, dtype=torch.float32, device=self.env.device)
        agent.reset(qpos.expand(len(env_idx), -1))
        agent.robot.set_pose(sapien.Pose())


def human_camera_config(width: int = 512, height: int = 512) -> CameraConfig:
    pose = sapien_utils.look_at(HUMAN_CAMERA_EYE, HUMAN_CAMERA_TARGET)
    return CameraConfig("render_camera", pose, width, height, 0.9, 0.01, 10.0)
