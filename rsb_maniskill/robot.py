"""The robot contract: what every module outside the agent knows of the robot (numpy only).

The agent (``agents/aloha.py``), the URDF generator, the expert's planners, the exporters and the
policy adapters read the joint names, the action layout, the cameras and the Aloha-14 layout of
VLA datasets from here, so none of them writes a robot fact again and a second robot is one
contract plus its agent and planner config. Light on purpose: importing it loads no simulator.

ManiSkill action (every control mode), 14 numbers::

    [ 0: 6] left arm joints 1-6   (fl_joint1..6)
    [ 6:12] right arm joints 1-6  (fr_joint1..6)
    [12]    left gripper           -1 closed ... +1 open
    [13]    right gripper          -1 closed ... +1 open

Aloha-14 (VLA datasets, ``observation.state`` and ``action``): [left arm 6, left gripper, right
arm 6, right gripper], gripper opening in [0, 1] (0 closed).
"""
from __future__ import annotations

from typing import Any

import numpy as np

ROBOT_UID = "aloha_agilex"
ARMS = ("left", "right")
PREFIX = {"left": "fl", "right": "fr"}  # front-left = left arm (+y), front-right = right arm (-y)
ARM_JOINTS = {a: tuple(f"{PREFIX[a]}_joint{i}" for i in range(1, 7)) for a in ARMS}  # joints 1-6 per arm
ARM_JOINT_NAMES = tuple(n for a in ARMS for n in ARM_JOINTS[a])
FINGER_JOINT_NAMES = {a: (f"{PREFIX[a]}_joint7", f"{PREFIX[a]}_joint8") for a in ARMS}  # driven, mimic
GRIPPER_JOINT_NAMES = tuple(n for a in ARMS for n in FINGER_JOINT_NAMES[a])
TCP_LINKS = {a: f"{PREFIX[a]}_tcp_link" for a in ARMS}
FINGER_TRAVEL = 0.0476  # m, each finger's prismatic range: gripper fully open
# obs["agent"]["qpos"]: SAPIEN's active joints, breadth-first over the URDF tree (both arms
# interleaved; fingers 7 and 8 of each gripper). tests/policies/test_openpi_preset.py checks it on the agent.
QPOS_JOINT_NAMES = (*(f"{PREFIX[a]}_joint{i}" for i in range(1, 7) for a in ARMS), *GRIPPER_JOINT_NAMES)

ACTION_DIM = 14
# The controller every RSB env, demo and policy uses unless told otherwise: absolute joint targets
# (the agent lists it first, so it is ManiSkill's default); the delta modes are for replay conversion.
CONTROL_MODE = "pd_joint_pos"
ARM_ACTION_SLICE = {"left": slice(0, 6), "right": slice(6, 12)}
GRIPPER_ACTION_INDEX = {"left": 12, "right": 13}

# Cameras by short name; the sensor (``obs["sensor_data"]``) is ``<name>_camera``.
CAMERAS = ("head", "left_wrist", "right_wrist")
CAMERA_SIZE = (320, 240)  # width, height of every camera by default (RoboTwin's D435 model)

ALOHA14_NAMES = tuple(f"{a}_{j}" for a in ARMS for j in ("waist", "shoulder", "elbow", "forearm_roll", "wrist_angle",
                                                      "wrist_rotate", "gripper"))
ALOHA14_ARM_SLICE = {"left": slice(0, 6), "right": slice(7, 13)}
ALOHA14_GRIPPER_INDEX = {"left": 6, "right": 13}
# the joint behind each Aloha-14 slot (a gripper slot reads its driven finger)
ALOHA14_JOINT_NAMES = tuple(n for a in ARMS for n in (*ARM_JOINTS[a], FINGER_JOINT_NAMES[a][0]))


def sensor_uid(camera: str) -> str:
    """``"head"`` -> ``"head_camera"``, the key of ``obs["sensor_data"]``."""
    if camera not in CAMERAS:
        raise ValueError(f"unknown camera {camera!r}; valid: {', '.join(CAMERAS)}")
    return f"{camera}_camera"


def _cat(parts: list[Any], like: Any) -> Any:
    if type(like).__module__.startswith("torch"):
        import torch

        return torch.cat(parts, -1)
    return np.concatenate(parts, -1)


def to_aloha14(action: Any) -> Any:
    """ManiSkill action [..., 14] -> Aloha [left arm 6, left grip, right arm 6, right grip], grip in
    [0, 1] (numpy or torch, as given)."""
    a, g = action, GRIPPER_ACTION_INDEX
    parts = []
    for arm in ARMS:
        parts += [a[..., ARM_ACTION_SLICE[arm]], (a[..., g[arm]:g[arm] + 1] + 1) / 2]
    return _cat(parts, a)


def from_aloha14(action: Any) -> Any:
    """Aloha [left arm 6, left grip, right arm 6, right grip] (grip in [0, 1]) -> ManiSkill action
    [..., 14] (numpy or torch, as given)."""
    a, g = action, ALOHA14_GRIPPER_INDEX
    parts = [a[..., ALOHA14_ARM_SLICE[arm]] for arm in ARMS]
    parts += [2 * a[..., g[arm]:g[arm] + 1] - 1 for arm in ARMS]
    return _cat(parts, a)
