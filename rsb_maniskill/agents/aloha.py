"""Aloha-AgileX dual-arm agent (``aloha_agilex``) for ManiSkill3.

Action layout, joint names, cameras and the Aloha-14 layout of VLA datasets: the robot contract
in ``rsb_maniskill/robot.py``, which this agent implements and every other module reads.

Both arms sit under one sub-controller ``"arm"`` and both grippers under ``"gripper"`` so that
ManiSkill's replay tool can convert between joint control modes. The gripper command is the same
normalised absolute opening in every mode (the replay tool copies it unchanged), so delta modes
are entirely in [-1, 1] as ManiSkill's diffusion-policy baseline expects.
VLA datasets use the Aloha order; :func:`to_aloha14` and :func:`from_aloha14` (re-exported from the
contract) convert.
"""
from __future__ import annotations

import copy

import numpy as np
import sapien
import torch

from mani_skill.agents.base_agent import BaseAgent, Keyframe
from mani_skill.agents.controllers import (
    PDJointPosControllerConfig,
    PDJointPosMimicControllerConfig,
    deepcopy_dict,
)
from mani_skill.agents.registration import register_agent
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import common
from mani_skill.utils.structs.actor import Actor
from mani_skill.utils.structs.pose import Pose

from rsb_maniskill.agents.aloha_urdf import ASSET_DIR, URDF_NAME
from rsb_maniskill.robot import (  # noqa: F401  (ALOHA14_NAMES, to/from_aloha14: re-exported)
    ALOHA14_NAMES,
    ARM_JOINT_NAMES,
    ARM_JOINTS,
    ARMS,
    CAMERA_SIZE,
    CAMERAS,
    FINGER_JOINT_NAMES,
    FINGER_TRAVEL,
    GRIPPER_JOINT_NAMES,
    PREFIX,
    ROBOT_UID,
    TCP_LINKS,
    from_aloha14,
    sensor_uid,
    to_aloha14,
)

GRIPPER_CLOSED = -0.005  # a target slightly past closed keeps squeezing a held block
GRIPPER_OPEN = FINGER_TRAVEL
ARM_STIFFNESS, ARM_DAMPING, ARM_FORCE_LIMIT = 2e3, 2e2, 100.0
GRIPPER_STIFFNESS, GRIPPER_DAMPING, GRIPPER_FORCE_LIMIT = 1e3, 1e2, 40.0
ARM_DELTA = 0.1  # rad per control step at |action| = 1 in the delta modes

# Per arm: folded above the table, turned inward so the head camera sees both grippers,
# tool pointing 57 degrees down, gripper open. The right arm mirrors the left (joint1 sign).
REST_ARM_QPOS = {"left": np.array([-0.6, 0.6, 0.8, -1.2, 0.0, 0.0]),
                 "right": np.array([0.6, 0.6, 0.8, -1.2, 0.0, 0.0])}
CAMERA_FOVY = np.deg2rad(42.0)  # a D435's colour camera
WRIST_CAMERA_FOVY = np.deg2rad(60.0)  # wide enough to see both fingertips and the block


def _rest_qpos() -> np.ndarray:
    """Rest pose in ManiSkill's active-joint order, computed from joint names at load time."""
    q = {}
    for arm in ARMS:
        q.update(zip(ARM_JOINTS[arm], REST_ARM_QPOS[arm]))
        q.update({n: GRIPPER_OPEN for n in FINGER_JOINT_NAMES[arm]})
    return q


@register_agent()
class AlohaAgilex(BaseAgent):
    """Two ARX5-style 6-DoF arms with parallel grippers on a fixed base, plus a head camera."""

    uid = ROBOT_UID
    arms: tuple[str, ...] = ARMS  # the robot contract the task and expert use: arms, fingers[arm],
    # tcp_pose(arm), grippers_closed(), is_grasping(actor, arm), rest_arm_qpos(arm), the joint names
    urdf_path = str(ASSET_DIR / URDF_NAME)
    urdf_config = dict(
        _materials=dict(finger=dict(static_friction=2.0, dynamic_friction=2.0, restitution=0.0)),
        link={
            f"{p}_link{i}": dict(material="finger", patch_radius=0.1, min_patch_radius=0.1)
            for p in ("fl", "fr") for i in (7, 8)
        },
    )
    fix_root_link = True
    # qpos is filled in active-joint order in _after_init (SAPIEN orders joints by tree walk).
    keyframes = dict(rest=Keyframe(pose=sapien.Pose(), qpos=np.zeros(16)))

    arm_joint_names = list(ARM_JOINT_NAMES)
    gripper_joint_names = list(GRIPPER_JOINT_NAMES)
    camera_size = CAMERA_SIZE

    @property
    def _sensor_configs(self):
        w, h = self.camera_size
        links = self.robot.links_map
        mounts = {"head": links["head_camera_link"],
                  **{f"{a}_wrist": links[f"{PREFIX[a]}_camera_link"] for a in ARMS}}
        fovy = {"head": CAMERA_FOVY, "left_wrist": WRIST_CAMERA_FOVY, "right_wrist": WRIST_CAMERA_FOVY}
        return [CameraConfig(sensor_uid(c), sapien.Pose(), w, h, fovy[c], 0.01, 10.0, mount=mounts[c])
                for c in CAMERAS]

    @property
    def _controller_configs(self):
        arm_pd_joint_pos = PDJointPosControllerConfig(
            self.arm_joint_names, lower=None, upper=None, stiffness=ARM_STIFFNESS,
            damping=ARM_DAMPING, force_limit=ARM_FORCE_LIMIT, normalize_action=False,
        )
        arm_pd_joint_delta_pos = PDJointPosControllerConfig(
            self.arm_joint_names, lower=-ARM_DELTA, upper=ARM_DELTA, stiffness=ARM_STIFFNESS,
            damping=ARM_DAMPING, force_limit=ARM_FORCE_LIMIT, use_delta=True,
        )
        arm_pd_joint_target_delta_pos = copy.deepcopy(arm_pd_joint_delta_pos)
        arm_pd_joint_target_delta_pos.use_target = True
        gripper = PDJointPosMimicControllerConfig(
            self.gripper_joint_names, lower=GRIPPER_CLOSED, upper=GRIPPER_OPEN,
            stiffness=GRIPPER_STIFFNESS, damping=GRIPPER_DAMPING, force_limit=GRIPPER_FORCE_LIMIT,
            normalize_action=True,
            mimic={FINGER_JOINT_NAMES[a][1]: {"joint": FINGER_JOINT_NAMES[a][0]} for a in ARMS},
        )
        return deepcopy_dict(dict(
            pd_joint_pos=dict(arm=arm_pd_joint_pos, gripper=gripper),
            pd_joint_delta_pos=dict(arm=arm_pd_joint_delta_pos, gripper=gripper),
            pd_joint_target_delta_pos=dict(arm=arm_pd_joint_target_delta_pos, gripper=gripper),
        ))

    def _after_init(self):
        links = self.robot.links_map
        self.tcp = {a: links[TCP_LINKS[a]] for a in ARMS}
        self.fingers = {a: (links[f"{PREFIX[a]}_link7"], links[f"{PREFIX[a]}_link8"]) for a in ARMS}
        names = [j.name for j in self.robot.get_active_joints()]
        rest = _rest_qpos()
        self.keyframes = dict(rest=Keyframe(pose=sapien.Pose(), qpos=np.array([rest[n] for n in names])))
        self.active_joint_names = names
        self.arm_qpos_index = {a: [names.index(n) for n in ARM_JOINTS[a]] for a in ARMS}
        self.finger_qpos_index = {a: names.index(FINGER_JOINT_NAMES[a][0]) for a in ARMS}

    # ------------------------------------------------------------------ state helpers
    def tcp_pose(self, arm: str) -> Pose:
        """Pose of the tool centre point (12 cm along link6's x axis) of ``arm``."""
        return self.tcp[arm].pose

    def gripper_opening(self, arm: str) -> torch.Tensor:
        """Finger joint position (0 = closed, FINGER_TRAVEL = open), per env."""
        return self.robot.get_qpos()[:, self.finger_qpos_index[arm]]

    def is_gripper_closed(self, arm: str) -> torch.Tensor:
        """The gripper is commanded closed (its drive target is below half travel)."""
        target = self.robot.get_drive_targets()[:, self.finger_qpos_index[arm]]
        return target < 0.5 * GRIPPER_OPEN

    def grippers_closed(self) -> torch.Tensor:
        """(B, 2) :meth:`is_gripper_closed` of the left and right arm, in one read."""
        idx = [self.finger_qpos_index[a] for a in ARMS]
        return self.robot.get_drive_targets()[:, idx] < 0.5 * GRIPPER_OPEN

    def is_grasping(self, actor: Actor, arm: str | None = None, min_force: float = 0.5,
                    max_angle: float = 85.0) -> torch.Tensor:
        """Both fingers of ``arm`` (either arm if None) push ``actor`` from opposite sides."""
        if arm is None:
            return self.is_grasping(actor, "left", min_force, max_angle) | self.is_grasping(
                actor, "right", min_force, max_angle)
        f1, f2 = self.fingers[arm]
        c1 = self.scene.get_pairwise_contact_forces(f1, actor)
        c2 = self.scene.get_pairwise_contact_forces(f2, actor)
        # The finger opening direction is +y of link7 and -y of link8.
        d1 = f1.pose.to_transformation_matrix()[..., :3, 1]
        d2 = -f2.pose.to_transformation_matrix()[..., :3, 1]
        ok1 = (torch.linalg.norm(c1, dim=1) >= min_force) & (
            torch.rad2deg(common.compute_angle_between(d1, c1)) <= max_angle)
        ok2 = (torch.linalg.norm(c2, dim=1) >= min_force) & (
            torch.rad2deg(common.compute_angle_between(d2, c2)) <= max_angle)
        return ok1 & ok2

    def is_static(self, threshold: float = 0.2) -> torch.Tensor:
        """All arm joints move slower than ``threshold`` rad/s."""
        idx = self.arm_qpos_index["left"] + self.arm_qpos_index["right"]
        return torch.max(torch.abs(self.robot.get_qvel()[:, idx]), dim=1)[0] <= threshold

    def aloha14_state(self) -> torch.Tensor:
        """(B, 14) joint state in the Aloha layout VLA datasets use: [left arm 6, left gripper,
        right arm 6, right gripper], gripper opening in [0, 1] (0 closed, 1 open)."""
        q = self.robot.get_qpos()
        parts = []
        for a in ARMS:
            opening = (q[:, self.finger_qpos_index[a]] / GRIPPER_OPEN).clamp(0, 1)
            parts += [q[:, self.arm_qpos_index[a]], opening[:, None]]
        return torch.cat(parts, dim=1)

    def tcp_link_name(self, arm: str) -> str:
        return TCP_LINKS[arm]

    def finger_joint_name(self, arm: str) -> str:
        """The driven finger joint of ``arm`` (the other finger mimics it)."""
        return FINGER_JOINT_NAMES[arm][0]

    def rest_arm_qpos(self, arm: str) -> np.ndarray:
        """Joints 1-6 of ``arm`` in the rest pose."""
        return REST_ARM_QPOS[arm].copy()

    def rest_action(self) -> torch.Tensor:
        """pd_joint_pos action that holds the rest pose with both grippers open."""
        q = [torch.as_tensor(REST_ARM_QPOS[a], dtype=torch.float32) for a in ARMS]
        return torch.cat([*q, torch.ones(2)])
