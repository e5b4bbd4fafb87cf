"""Stand-ins for SAPIEN's RenderSystemGroup on a machine without CUDA interop (lavapipe): a group
that renders each scene on its own, so the vector env's group path (pose buffer, camera groups, the
batched observation) runs with pictures a CPU machine can make. Shared by tests/vector/."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

SUITE = "RSB-Math-4"
SMALL = {"camera_size": (32, 24)}  # rgb where images are the point, at a size lavapipe renders fast


class SceneByScene:
    """A RenderSystemGroup that renders each scene on its own (lavapipe has no CUDA interop): the
    group path, buffer and camera groups included, with pictures a CPU machine can make."""

    made: list = []

    def __init__(self, systems):
        self.systems, self.poses = systems, None
        SceneByScene.made.append(self)

    def set_cuda_poses(self, buffer):
        self.poses = buffer

    def update_render(self):
        for system in self.systems:
            system.step()

    def create_camera_group(self, cameras, textures):
        return CamerasByScene(cameras)


class CamerasByScene:
    blank = False  # True: black pictures, to see that the observation's images are the group's

    def __init__(self, cameras):
        self.cameras = cameras

    def take_picture(self):
        for c in self.cameras:
            c.take_picture()

    def get_picture_cuda(self, name):
        pics = torch.stack([torch.from_numpy(np.asarray(c.get_picture(name))) for c in self.cameras])
        pics = torch.zeros_like(pics) if self.blank else pics
        return SimpleNamespace(torch=lambda: pics)
