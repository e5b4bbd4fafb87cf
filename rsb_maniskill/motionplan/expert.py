"""Scripted expert for the RSB answer-selection task: pick the target candidate, place it in the zone.

Reads the ground truth (``env.unwrapped.target_block``), takes the arm on the target's side
(y >= 0: left) and runs, each motion planned from the live state just before it is executed:

    approach  above the candidate's grasp frame, tool down, fingers across the grasp, gripper
              opened a centimetre wider than the grasp on each side
    descend   straight down to the grasp height
    close     gripper closed, arm held
    lift      straight up (checks the grasp)
    carry     straight across to above the zone centre, high enough to clear every candidate
    lower     down until the candidate hangs a few millimetres above the table (checks the hold)
    release   gripper half open, arm held
    retreat   straight up
    rest      joint-space move back to the rest pose

The other arm holds its current target throughout. Screw motions (straight TCP lines, fast) are
used everywhere; RRTConnect only when a screw motion fails (a joint limit or a collision).
Grasp frames come from the candidate family (``rsb_maniskill.objects``): a block offers two
closing directions, an everyday object those its catalog entry lists; heights are measured
from the grasp frame, so the same plan serves every shape.
"""
from __future__ import annotations

import itertools
import time
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from rsb_maniskill.batch import first_value as _first
from rsb_maniskill.compat import controller_target_qpos
from rsb_maniskill.motionplan.planner import (
    ArmPlanner,
    gripper_action,
    hold_actions,
    pose7,
)
from rsb_maniskill.robot import ARM_ACTION_SLICE, GRIPPER_ACTION_INDEX

# TCP frame pointing straight down (its x axis along -z) with the fingers closing along world y.
DOWN_Q = np.array([0.70710678, 0.0, 0.70710678, 0.0])
# Heights of the TCP above its grasp height (the grasp frame's TCP; fingertips reach 2.46 cm
# below the TCP). For a 4 cm block: TCP 11 cm up to approach, 12 cm to carry.
PREGRASP_DZ = 0.080  # fingertips clear the target and (for every height up to 5.5 cm) its neighbours
PREGRASP_CLEARANCE = 0.045  # TCP above the tallest candidate's top when that is higher
APPROACH_DZS = (0.0, -0.006, 0.010)  # a screw plan can fail at one height and not at the next
CARRY_CLEARANCE = 0.050  # carried candidate's bottom this far above the tallest candidate
MIN_CARRY_CLEARANCE = 0.015  # ... or down to this where the arm cannot reach that high
PLACE_DZ = 0.006  # release with the candidate 6 mm above the table
RETREAT_DZ = 0.090
# Gripper: a fully open gripper (9.5 cm gap plus 8 mm pads) may touch neighbours, so it opens
# 1 cm wider than the grasp on each side (a 6 cm gap on a 4 cm block).
GRASP_CLEARANCE = 0.010  # m per finger
MAX_OPENING = 0.045  # m per finger (joint travel is 4.76 cm)
CLOSED = -1.0
SETTLE_STEPS = 2  # hold the last target so the PD drives catch up before closing/opening
CLOSE_STEPS = 8
OPEN_STEPS = 5
IDLE_STEPS = 15  # after the plan: lets a released candidate come to rest
CARRY_YAWS = (0.0, np.pi / 2, -np.pi / 2)  # wrist turns tried on the way to the zone


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


def _wrap(angle: float) -> float:
    """Angle in [-pi, pi)."""
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def _rotate_xy(v: tuple[float, float], yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def grasp_options(shape, pose7_world: np.ndarray) -> list[tuple[np.ndarray, float, float]]:
    """World (TCP xyz, TCP yaw, grasp width) of each grasp frame of a candidate resting on the
    table at ``pose7_world``, both finger orders; the least wrist turn (|yaw| smallest) first."""
    yaw_obj = _yaw_of(pose7_world[3:])
    out = []
    for g in shape.grasps:
        xy = pose7_world[:2] + _rotate_xy(g.pos[:2], yaw_obj)
        z = shape.rest_z + g.pos[2]  # the table top is z = 0
        for flip in (0.0, np.pi):
            # down_quat(yaw) closes the fingers along yaw + pi/2
            out.append((np.array([*xy, z]), _wrap(yaw_obj + g.yaw + flip - np.pi / 2), g.width))
    return sorted(out, key=lambda o: abs(o[1]))


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
        target_block: candidate index to pick instead of the ground truth (the 'blind' baseline).
    """

    def __init__(self, env, target_block: int | None = None):
        self.env = env
        self.base = env.unwrapped
        assert self.base.num_envs == 1, "ScriptedExpert drives one env at a time"
        self.agent = self.base.agent
        self.target = int(self.base.target_block[0]) if target_block is None else int(target_block)
        self.block = self.base.candidate_actor(self.target)
        self.shape = self.base.pool.shape(self.target)
        self.tallest = float(self.base.pool.heights()[0].max())
        y = float(self.block.pose.p[0, 1])
        self.arm = "left" if y >= 0 else "right"
        self.planner = ArmPlanner(self.agent.robot, self.arm, self.base.control_timestep)
        self.action = self._current_action()
        self.open_action = 1.0  # set per grasp in chunks()
        self.reason = ""
        self.stage = ""

    # ------------------------------------------------------------------ public API
    def chunks(self) -> Iterator[np.ndarray]:
        """Yields (T, 14) pd_joint_pos chunks, each planned from the live state after the last.

        Stops early (``self.reason`` set) when a plan fails or the grasp is lost."""
        options = grasp_options(self.shape, self.block.pose.raw_pose[0].cpu().numpy().astype(np.float64))
        zone = np.asarray(self.base.zone_xy.cpu().numpy(), np.float64)
        grasp_z = float(options[0][0][2])  # every grasp frame of a candidate shares its height
        above = grasp_z + max(PREGRASP_DZ, self.tallest + PREGRASP_CLEARANCE - grasp_z)
        carry_z = self.tallest + CARRY_CLEARANCE + grasp_z  # the bottom clears every candidate

        # approach: the grasp with the least wrist turn first whose descent and lift are also
        # reachable; screw, IK + joint move, RRT in that order of preference over all grasps
        self.stage = "pregrasp"
        plan = None
        for straight, allow_rrt in ((True, False), (False, False), (False, True)):
            for (tcp, yaw, width), dz in itertools.product(options, APPROACH_DZS):
                quat = down_quat(yaw)
                path = self.planner.move_to(pose7([*tcp[:2], above + dz], quat), straight=straight,
                                            allow_rrt=allow_rrt)
                if path is None:
                    continue
                lift = self._lift_height(path, pose7([*tcp[:2], grasp_z], quat), carry_z)
                if lift is not None:
                    plan = path, tcp[:2], quat, yaw, width, lift
                    break
            if plan is not None:
                break
        if plan is None:
            return self._fail("ik_failed:pregrasp")
        path, bxy, quat, yaw, width, carry_z = plan
        self.open_action = gripper_action(min(MAX_OPENING, width / 2 + GRASP_CLEARANCE))
        yield self._arm_chunk(path, self.open_action)

        chunk = self._line("grasp", pose7([*bxy, grasp_z], quat), self.open_action, SETTLE_STEPS)
        if chunk is None:
            return
        yield chunk

        self.stage = "close"
        yield self._hold(CLOSE_STEPS, CLOSED)
        if not self._grasping():
            return self._fail("grasp_missed")

        self.stage = "lift"
        path = None
        for z in self._carry_heights(carry_z, grasp_z):
            path = self.planner.move_to(pose7([*bxy, z], quat), allow_rrt=False)
            if path is not None:
                carry_z = float(z)
                break
        if path is None:
            return self._fail("ik_failed:lift")
        yield self._arm_chunk(path, CLOSED)
        if not self._grasping():
            return self._fail("grasp_missed")

        # carry: the candidate may turn by a quarter turn on the way if the wrist runs out of range
        self.stage = "carry"
        for dyaw in CARRY_YAWS:
            quat = down_quat(yaw + dyaw)
            path = self.planner.move_to(pose7([*zone, carry_z], quat), allow_rrt=False)
            if path is not None:
                break
        if path is None:
            quat = down_quat(yaw)
            path = self.planner.rrt(pose7([*zone, carry_z], quat))
        if path is None:
            return self._fail("ik_failed:carry")
        yield self._arm_chunk(path, CLOSED)
        if not self._grasping():
            return self._fail("dropped")

        chunk = self._line("lower", pose7([*zone, grasp_z + PLACE_DZ], quat), CLOSED, SETTLE_STEPS)
        if chunk is None:
            return
        yield chunk
        if not self._grasping():
            return self._fail("dropped")

        self.stage = "release"
        yield self._hold(OPEN_STEPS, self.open_action)

        chunk = self._line("retreat", pose7([*zone, grasp_z + PLACE_DZ + RETREAT_DZ], quat), self.open_action, 0)
        if chunk is None:
            return
        yield chunk

        self.stage = "rest"
        path = self.planner.joint_move(self.agent.rest_arm_qpos(self.arm)[self._rest_order()])
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

    def _carry_heights(self, carry_z: float, grasp_z: float) -> np.ndarray:
        """TCP heights to try for the carry, from ``carry_z`` down to the least clearance."""
        return np.linspace(carry_z, self.tallest + MIN_CARRY_CLEARANCE + grasp_z, 4)

    def _lift_height(self, approach: np.ndarray, grasp: np.ndarray, carry_z: float) -> float | None:
        """The highest carry height (``carry_z`` or lower, never below a 1.5 cm clearance) the
        arm can lift to straight up from ``grasp``, planned from the end of ``approach``;
        None if even the descent to ``grasp`` is out of reach."""
        q = self.planner.qpos()
        q[self.planner.index] = approach[-1]
        down = self.planner.screw(grasp, q)
        if down is None:
            return None
        q[self.planner.index] = down[-1]
        for z in self._carry_heights(carry_z, float(grasp[2])):
            if self.planner.screw(np.concatenate([grasp[:2], [z], grasp[3:]]), q) is not None:
                return float(z)
        return None

    def _grasping(self) -> bool:
        return bool(self.agent.is_grasping(self.block, self.arm)[0])

    def _fail(self, reason: str) -> None:
        self.reason = reason

    def _rest_order(self) -> np.ndarray:
        """Permutation taking the rest qpos (joint1..6) to the plan's column order."""
        start = ARM_ACTION_SLICE[self.arm].start
        return self.planner.action_index - start

    def _current_action(self) -> np.ndarray:
        """The pd_joint_pos action that reproduces the controllers' current joint targets.

        Read from the controllers, not the drives: after a reset the drive targets stay zero
        until the first step, while the controllers already target the reset qpos."""
        targets = {}
        for ctrl in self.agent.controller.controllers.values():
            q = controller_target_qpos(ctrl)[0].cpu().numpy()
            targets.update({j.name: float(v) for j, v in zip(ctrl.joints, q)})
        action = np.zeros(14, dtype=np.float32)
        for k, name in enumerate(self.agent.arm_joint_names):
            action[k] = targets[name]
        for arm, i in GRIPPER_ACTION_INDEX.items():
            action[i] = gripper_action(targets[self.agent.finger_joint_name(arm)])
        return action
