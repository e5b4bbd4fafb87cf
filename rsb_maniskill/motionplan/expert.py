"""Scripted expert for the RSB answer-selection task: pick the target block, place it in the zone.

Reads the ground truth (``env.unwrapped.target_block``), takes the arm on the target's side
(y >= 0: left) and runs, each motion planned from the live state just before it is executed:

    approach  above the block, tool down, fingers aligned with the block's yaw, gripper half open
    descend   straight down to the grasp height
    close     gripper closed, arm held
    lift      straight up (checks the grasp)
    carry     straight across to above the zone centre
    lower     down until the block hangs a few millimetres above the table (checks the hold)
    release   gripper half open, arm held
    retreat   straight up
    rest      joint-space move back to the rest pose

The other arm holds its current target throughout. Screw motions (straight TCP lines, fast) are
used everywhere; RRTConnect only when a screw motion fails (a joint limit or a collision).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Iterator

import numpy as np
import torch

from rsb_maniskill.agents.aloha import ARM_JOINT_NAMES, PREFIX, REST_ARM_QPOS
from rsb_maniskill.motionplan.planner import (
    ARM_ACTION_SLICE,
    GRIPPER_ACTION_INDEX,
    ArmPlanner,
    gripper_action,
    hold_actions,
    pose7,
)

# TCP frame pointing straight down (its x axis along -z) with the fingers closing along world y.
DOWN_Q = np.array([0.70710678, 0.0, 0.70710678, 0.0])
# Heights of the TCP relative to the block's resting centre height (the fingertips reach
# 2.46 cm past the TCP, so +1 cm keeps them ~5 mm above the table and the pads on the block).
GRASP_DZ = 0.010
PREGRASP_DZ = 0.090  # approach from here: fingertips clear the 4 cm neighbours
CARRY_DZ = 0.100  # carried block's bottom ~8 cm up: clears every other block
PLACE_DZ = GRASP_DZ + 0.006  # release with the block 6 mm above the table
RETREAT_DZ = 0.090
# Gripper: neighbours are >= 7.4 cm centre to centre, so a fully open gripper (9.5 cm gap plus
# 8 mm pads) may touch them; 3 cm per finger gives a 6 cm gap, 1 cm clearance on a 4 cm block.
GRASP_OPENING = 0.030  # m per finger
CLOSED = -1.0
SETTLE_STEPS = 2  # hold the last target so the PD drives catch up before closing/opening
CLOSE_STEPS = 8
OPEN_STEPS = 5
IDLE_STEPS = 15  # after the plan: lets a released block come to rest
YAW_CANDIDATES = (0.0, np.pi / 2, -np.pi / 2)  # grasp yaws tried, relative to the block face


@dataclass
class ExpertResult:
    """Outcome of one expert episode; ``reason`` is '' on success."""

    success: bool
    reason: str
    steps: int
    plan_time: float
    sim_time: float
    arm: str


def _yaw_of(quat_wxyz: np.ndarray) -> float:
    w, x, y, z = quat_wxyz
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def _wrap_quarter(angle: float) -> float:
    """The block is square: its yaw matters modulo pi/2; map to [-pi/4, pi/4)."""
    return float((angle + np.pi / 4) % (np.pi / 2) - np.pi / 4)


def down_quat(yaw: float) -> np.ndarray:
    """TCP quaternion (wxyz): tool down, fingers closing along the horizontal direction yaw + pi/2."""
    qz = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    w1, x1, y1, z1 = qz
    w2, x2, y2, z2 = DOWN_Q
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


class ScriptedExpert:
    """Motion-planning expert for one env (num_envs = 1).

    Args:
        env: the gym env, possibly wrapped (e.g. RecordEpisode).
        target_block: block index to pick instead of the ground truth (the 'blind' baseline).
    """

    def __init__(self, env, target_block: int | None = None):
        self.env = env
        self.base = env.unwrapped
        assert self.base.num_envs == 1, "ScriptedExpert drives one env at a time"
        self.agent = self.base.agent
        self.target = int(self.base.target_block[0]) if target_block is None else int(target_block)
        self.block = self.base.blocks[self.target]
        self.rest_z = float(self.base.rest_z[0, self.target])
        y = float(self.block.pose.p[0, 1])
        self.arm = "left" if y >= 0 else "right"
        self.planner = ArmPlanner(self.agent.robot, self.arm, self.base.control_timestep)
        self.action = self._current_action()
        self.open_action = gripper_action(GRASP_OPENING)
        self.reason = ""
        self.stage = ""

    # ------------------------------------------------------------------ public API
    def chunks(self) -> Iterator[np.ndarray]:
        """Yields (T, 14) pd_joint_pos chunks, each planned from the live state after the last.

        Stops early (``self.reason`` set) when a plan fails or the grasp is lost."""
        block_pose = self.block.pose.raw_pose[0].cpu().numpy()
        bxy = block_pose[:2]
        yaw0 = _wrap_quarter(_yaw_of(block_pose[3:]))
        zone = np.asarray(self.base.zone_xy.cpu().numpy(), np.float64)
        z0 = self.rest_z

        # approach: fingers square to the block, the least wrist turn first; screw, IK + joint
        # move, RRT in that order of preference over all yaws
        self.stage = "pregrasp"
        path, yaw = None, yaw0
        for straight, allow_rrt in ((True, False), (False, False), (False, True)):
            for dyaw in YAW_CANDIDATES:
                yaw = yaw0 + dyaw
                quat = down_quat(yaw)
                path = self.planner.move_to(pose7([*bxy, z0 + PREGRASP_DZ], quat),
                                            straight=straight, allow_rrt=allow_rrt)
                if path is not None:
                    break
            if path is not None:
                break
        if path is None:
            return self._fail("ik_failed:pregrasp")
        yield self._arm_chunk(path, self.open_action)

        chunk = self._line("grasp", pose7([*bxy, z0 + GRASP_DZ], quat), self.open_action, SETTLE_STEPS)
        if chunk is None:
            return
        yield chunk

        self.stage = "close"
        yield self._hold(CLOSE_STEPS, CLOSED)
        if not self._grasping():
            return self._fail("grasp_missed")

        chunk = self._line("lift", pose7([*bxy, z0 + CARRY_DZ], quat), CLOSED, 0)
        if chunk is None:
            return
        yield chunk
        if not self._grasping():
            return self._fail("grasp_missed")

        # carry: the block may turn by a quarter turn on the way if the wrist runs out of range
        self.stage = "carry"
        for dyaw in YAW_CANDIDATES:
            quat = down_quat(yaw + dyaw)
            path = self.planner.move_to(pose7([*zone, z0 + CARRY_DZ], quat), allow_rrt=False)
            if path is not None:
                break
        if path is None:
            quat = down_quat(yaw)
            path = self.planner.rrt(pose7([*zone, z0 + CARRY_DZ], quat))
        if path is None:
            return self._fail("ik_failed:carry")
        yield self._arm_chunk(path, CLOSED)
        if not self._grasping():
            return self._fail("dropped")

        chunk = self._line("lower", pose7([*zone, z0 + PLACE_DZ], quat), CLOSED, SETTLE_STEPS)
        if chunk is None:
            return
        yield chunk
        if not self._grasping():
            return self._fail("dropped")

        self.stage = "release"
        yield self._hold(OPEN_STEPS, self.open_action)

        chunk = self._line("retreat", pose7([*zone, z0 + PLACE_DZ + RETREAT_DZ], quat), self.open_action, 0)
        if chunk is None:
            return
        yield chunk

        self.stage = "rest"
        path = self.planner.joint_move(REST_ARM_QPOS[self.arm][self._rest_order()])
        if path is None:
            return self._fail("plan_failed:rest")
        yield self._arm_chunk(path, 1.0)

    def run(self) -> ExpertResult:
        """Steps the env through :meth:`chunks` until success, termination or truncation."""
        steps, sim_time, success, truncated = 0, 0.0, False, False
        info = {}
        for chunk in self.chunks():
            for a in chunk:
                t0 = time.perf_counter()
                _, _, terminated, truncated, info = self.env.step(a)
                sim_time += time.perf_counter() - t0
                steps += 1
                success = bool(_first(info["success"]))
                if success or bool(_first(terminated)) or bool(_first(truncated)):
                    break
            if success or bool(_first(truncated)) or (info and bool(_first(info.get("fail", False)))):
                break
        if not success and not self.reason and not bool(_first(truncated)):
            idle = self.action.copy()
            for _ in range(IDLE_STEPS):
                t0 = time.perf_counter()
                _, _, _, truncated, info = self.env.step(idle)
                sim_time += time.perf_counter() - t0
                steps += 1
                success = bool(_first(info["success"]))
                if success or bool(_first(truncated)):
                    break
        reason = ""
        if not success:
            reason = self.reason or ("wrong_block" if info and bool(_first(info.get("fail", False)))
                                     else "timeout" if bool(_first(truncated)) else "not_placed")
        return ExpertResult(success, reason, steps, self.planner.plan_time, sim_time, self.arm)

    @property
    def plan_time(self) -> float:
        return self.planner.plan_time

    # ------------------------------------------------------------------ helpers
    def _line(self, stage: str, pose: np.ndarray, grip: float, settle: int) -> np.ndarray | None:
        """A straight TCP move planned from the live qpos, plus ``settle`` held steps."""
        self.stage = stage
        path = self.planner.move_to(pose)
        if path is None:
            self._fail(f"ik_failed:{stage}")
            return None
        chunk = self._arm_chunk(path, grip)
        if settle:
            chunk = np.concatenate([chunk, hold_actions(self.action, settle)])
        return chunk

    def _arm_chunk(self, path: np.ndarray, grip: float) -> np.ndarray:
        chunk = self.planner.actions(path, self.action, grip)
        self.action = chunk[-1].copy()
        return chunk

    def _hold(self, steps: int, grip: float) -> np.ndarray:
        chunk = hold_actions(self.action, steps, self.arm, grip)
        self.action = chunk[-1].copy()
        return chunk

    def _grasping(self) -> bool:
        return bool(self.agent.is_grasping(self.block, self.arm)[0])

    def _fail(self, reason: str) -> None:
        self.reason = reason

    def _rest_order(self) -> np.ndarray:
        """Permutation taking REST_ARM_QPOS (joint1..6) to the plan's column order."""
        start = ARM_ACTION_SLICE[self.arm].start
        return self.planner.action_index - start

    def _current_action(self) -> np.ndarray:
        """The pd_joint_pos action that reproduces the controllers' current joint targets.

        Read from the controllers, not the drives: after a reset the drive targets stay zero
        until the first step, while the controllers already target the reset qpos."""
        targets = {}
        for ctrl in self.agent.controller.controllers.values():
            q = ctrl._target_qpos[0].cpu().numpy()
            targets.update({j.name: float(v) for j, v in zip(ctrl.joints, q)})
        action = np.zeros(14, dtype=np.float32)
        for k, name in enumerate(ARM_JOINT_NAMES):
            action[k] = targets[name]
        for arm, i in GRIPPER_ACTION_INDEX.items():
            action[i] = gripper_action(targets[f"{PREFIX[arm]}_joint7"])
        return action

def _first(x) -> object:
    if isinstance(x, torch.Tensor):
        return x.reshape(-1)[0].item()
    if isinstance(x, np.ndarray):
        return x.reshape(-1)[0]
    return x
