"""Where each candidate stands, left to right, as the robot's head camera sees the table.

The bias tables (``bias.py``) ask whether a policy favours a position ("always the leftmost
block"), so each record carries every candidate's rank from the left (``left_rank``). The ranks
come from the seed's layout (``objects.layout.episode_layouts``: numpy, no simulator; the layout is
a function of the seed, independent of the answer) seen through the head camera's fixed mount
(``agents.aloha_urdf``): the robot faces +x with its left arm at +y, and the head camera looks down
the +x axis without yaw or roll, so image left is +y. Candidates are ordered by the horizontal
image coordinate of their centre at rest (a perspective projection: of two candidates in one
column of the grid the nearer one looks further out), the order a policy watching the head camera
meets, and the one the ``leftmost`` reference policy reads from the live scene. The camera
robustness axis moves the rendered camera by a few centimetres; ranks stay those of the mount.
"""
from __future__ import annotations

from typing import Any

import numpy as np


def image_x(xyz: np.ndarray) -> np.ndarray:
    """Horizontal head-camera image coordinate (tangent of the angle right of the optical axis)
    of points ``xyz`` (..., 3) in the robot frame."""
    from rsb_maniskill.agents.aloha_urdf import HEAD_CAMERA_LOOK, HEAD_CAMERA_XYZ  # the package loads the robot

    forward = np.asarray(HEAD_CAMERA_LOOK, dtype=np.float64)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, (0.0, 0.0, 1.0))  # no roll: the image's right is level
    right /= np.linalg.norm(right)
    rel = np.asarray(xyz, dtype=np.float64) - np.asarray(HEAD_CAMERA_XYZ)
    return (rel @ right) / (rel @ forward)


def ranks_from_xyz(xyz: np.ndarray) -> list[int]:
    """Rank from the left (0 = leftmost in the head camera) of each of N candidates at ``xyz`` (N, 3)."""
    order = np.argsort(image_x(xyz), kind="stable")
    ranks = np.empty(len(order), dtype=int)
    ranks[order] = np.arange(len(order))
    return ranks.tolist()


def left_ranks(spec: Any) -> list[int]:
    """Rank from the left of each candidate of the episode ``spec`` (an ``EpisodeSpec``): its
    seed's layout, each candidate at its resting height, without the simulator."""
    from rsb_maniskill.objects.family import get_family
    from rsb_maniskill.objects.layout import episode_layouts

    family = get_family(spec.targets)
    _, xy, _ = episode_layouts(family, [spec.candidates], [spec.seed])
    z = np.array([family.shape(k).rest_z for k in spec.candidates])
    return ranks_from_xyz(np.column_stack([xy[0], z]))
