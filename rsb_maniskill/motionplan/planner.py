"""mplib planners for one Aloha-AgileX arm, returning ``pd_joint_pos`` action chunks.

One ``mplib.Planner`` per arm over the project's URDF and the full mplib SRDF (SAPIEN takes at most
31 collision-disable groups, so it reads a shorter one), ``move_group`` = that arm's TCP link. A
plan covers only the move-group joints; we map them back by joint name into the 14-d action and
hold every other entry (the other arm's target, both grippers) at the value the caller gives.
Planners are cached per process: building one costs little, but the expert builds one per
episode otherwise.
"""
from __future__ import annotations

import time

import numpy as np

if int(np.__version__.split(".")[0]) >= 2:  # mplib 0.1.1 segfaults in Planner() under numpy 2
    raise ImportError(f"the scripted expert needs numpy < 2 (mplib 0.1.1), found numpy {np.__version__}: "
                      "pip install 'rsb_maniskill[expert]'")

import mplib  # noqa: E402

from rsb_maniskill.agents.aloha import GRIPPER_CLOSED, GRIPPER_OPEN
from rsb_maniskill.agents.aloha_urdf import ASSET_DIR, MPLIB_SRDF_NAME, URDF_NAME
from rsb_maniskill.motionplan.rng import reseed_planners
from rsb_maniskill.robot import ARM_ACTION_SLICE, ARM_JOINT_NAMES, GRIPPER_ACTION_INDEX, TCP_LINKS

# Trajectory limits for the move group (rad/s, rad/s^2). mplib's default is 1 and 1; the PD
# drives (stiffness 2e3, damping 2e2) track 1.6 rad/s without a visible lag at 25 Hz.
JOINT_VEL_LIMIT = 1.6
JOINT_ACC_LIMIT = 3.0
RRT_PLANNING_TIME = 1.0  # s; only used when a screw motion fails
# Joint-space moves (e.g. back to rest) use a smooth-step profile at this mean speed.
JOINT_MOVE_SPEED = 1.2  # rad/s
MIN_SEGMENT_STEPS = 2

_PLANNERS: dict[tuple, mplib.Planner] = {}


def gripper_action(opening: float) -> float:
    """Normalised gripper action for a finger joint target ``opening`` (m per finger)."""
    return float(np.clip(2 * (opening - GRIPPER_CLOSED) / (GRIPPER_OPEN - GRIPPER_CLOSED) - 1, -1, 1))


def gripper_opening(action: float) -> float:
    """Finger joint target (m) of a normalised gripper action (inverse of gripper_action)."""
    return GRIPPER_CLOSED + (float(action) + 1) / 2 * (GRIPPER_OPEN - GRIPPER_CLOSED)


def get_planner(arm: str, link_names: list[str], joint_names: list[str],
                urdf: str | None = None, srdf: str | None = None) -> mplib.Planner:
    """The cached mplib planner of ``arm`` (``"left"``/``"right"``) for this joint order."""
    urdf = str(urdf or ASSET_DIR / URDF_NAME)
    srdf = str(srdf or ASSET_DIR / MPLIB_SRDF_NAME)
    key = (urdf, srdf, arm, tuple(link_names), tuple(joint_names))
    if key not in _PLANNERS:
        dof = 6
        _PLANNERS[key] = mplib.Planner(
            urdf=urdf, srdf=srdf, user_link_names=list(link_names), user_joint_names=list(joint_names),
            move_group=TCP_LINKS[arm],
            joint_vel_limits=np.full(dof, JOINT_VEL_LIMIT), joint_acc_limits=np.full(dof, JOINT_ACC_LIMIT))
    return _PLANNERS[key]


class ArmPlanner:
    """Plans one arm of a live robot; returns joint paths (T, 6) sampled at the control rate.

    Args:
        robot: the agent's articulation (``env.unwrapped.agent.robot``), num_envs = 1.
        arm: ``"left"`` or ``"right"``.
        time_step: the control period (``env.unwrapped.control_timestep``).
    """

    def __init__(self, robot, arm: str, time_step: float):
        self.robot, self.arm, self.time_step = robot, arm, float(time_step)
        link_names = [link.name for link in robot.get_links()]
        self.joint_names = [j.name for j in robot.get_active_joints()]
        self.planner = get_planner(arm, link_names, self.joint_names)
        self.index = np.asarray(self.planner.move_group_joint_indices)
        names = [self.joint_names[i] for i in self.index]
        # Column k of a plan drives action entry action_index[k].
        self.action_index = np.array([ARM_JOINT_NAMES.index(n) for n in names])
        slot = ARM_ACTION_SLICE[arm]
        assert set(self.action_index) == set(range(slot.start, slot.stop)), names
        self.tcp_link = self.planner.link_name_2_idx[TCP_LINKS[arm]]
        self.plan_time = 0.0  # accumulated wall time spent planning
        self.rrt_calls = 0  # screw or joint moves that needed the RRTConnect fallback

    # ------------------------------------------------------------------ state
    def qpos(self) -> np.ndarray:
        """Full active-joint qpos of env 0."""
        return self.robot.get_qpos()[0].cpu().numpy().astype(np.float64)

    def arm_qpos(self, qpos: np.ndarray | None = None) -> np.ndarray:
        """Move-group joints, in plan column order."""
        return (self.qpos() if qpos is None else qpos)[self.index]

    def fk(self, qpos: np.ndarray) -> np.ndarray:
        """TCP pose [x, y, z, qw, qx, qy, qz] of a full qpos (robot base = world)."""
        model = self.planner.pinocchio_model
        model.compute_forward_kinematics(qpos)
        return np.asarray(model.get_link_pose(self.tcp_link))

    # ------------------------------------------------------------------ planning
    def screw(self, pose: np.ndarray, qpos: np.ndarray | None = None) -> np.ndarray | None:
        """Screw motion of the TCP to ``pose`` (a straight line when the orientation is kept);
        None if it hits a joint limit, a self-collision or a singularity."""
        qpos = self.qpos() if qpos is None else qpos
        t0 = time.perf_counter()
        try:
            res = self.planner.plan_screw(np.asarray(pose, np.float64), qpos.copy(), time_step=self.time_step)
        except RuntimeError:  # TOPP-RA fails on degenerate (near-zero length) paths
            res = {"status": "topp failed"}
        self.plan_time += time.perf_counter() - t0
        return self._path(res, qpos)

    def rrt(self, pose: np.ndarray, qpos: np.ndarray | None = None) -> np.ndarray | None:
        """Collision-free RRTConnect motion to ``pose`` (slower: IK with random restarts)."""
        qpos = self.qpos() if qpos is None else qpos
        self.rrt_calls += 1
        t0 = time.perf_counter()
        reseed_planners()
        try:
            res = self.planner.plan_qpos_to_pose(
                np.asarray(pose, np.float64), qpos.copy(), time_step=self.time_step,
                planning_time=RRT_PLANNING_TIME, wrt_world=True)
        except RuntimeError:
            res = {"status": "topp failed"}
        self.plan_time += time.perf_counter() - t0
        return self._path(res, qpos)

    def ik(self, pose: np.ndarray, qpos: np.ndarray | None = None) -> np.ndarray | None:
        """Move-group joints reaching ``pose``, seeded from ``qpos``: within limits and
        collision-free, else None. One damped CLIK solve (~1 ms), unlike mplib's 20-restart IK."""
        qpos = self.qpos() if qpos is None else qpos
        mask = [True] * len(qpos)
        for i in self.index:
            mask[i] = False
        t0 = time.perf_counter()
        q, ok, _ = self.planner.pinocchio_model.compute_IK_CLIK(
            self.tcp_link, np.asarray(pose, np.float64), qpos.copy(), mask, eps=1e-5, max_iter=500, damp=1e-6)
        q = np.asarray(q, np.float64)
        ok = bool(ok) and self.planner.wrap_joint_limit(q) and not self.collides(q[self.index][None], qpos)
        self.plan_time += time.perf_counter() - t0
        return q[self.index] if ok else None

    def move_to(self, pose: np.ndarray, qpos: np.ndarray | None = None, straight: bool = True,
                allow_rrt: bool = True) -> np.ndarray | None:
        """Screw motion; if it fails and not ``straight``, IK plus a joint-space move (free
        space only: the TCP leaves the straight line); then RRTConnect if ``allow_rrt``."""
        qpos = self.qpos() if qpos is None else qpos
        path = self.screw(pose, qpos)
        if path is None and not straight:
            goal = self.ik(pose, qpos)
            path = None if goal is None else self.joint_move(goal, qpos, allow_rrt=False)
        if path is None and allow_rrt:
            path = self.rrt(pose, qpos)
        return path

    def joint_move(self, goal: np.ndarray, qpos: np.ndarray | None = None,
                   allow_rrt: bool = True) -> np.ndarray | None:
        """Smooth-step joint interpolation to ``goal`` (move-group order), RRTConnect if it collides."""
        qpos = self.qpos() if qpos is None else qpos
        start, goal = qpos[self.index], np.asarray(goal, np.float64)
        dist = float(np.abs(goal - start).max())
        steps = max(MIN_SEGMENT_STEPS, int(np.ceil(dist / JOINT_MOVE_SPEED / self.time_step)))
        s = np.linspace(0, 1, steps + 1)[1:, None]
        path = start + (s * s * (3 - 2 * s)) * (goal - start)
        if not self.collides(path, qpos):
            return path
        if not allow_rrt:
            return None
        full = qpos.copy()  # mplib takes whole configurations as goals and reads the move group's joints
        full[self.index] = goal
        t0 = time.perf_counter()
        reseed_planners()
        try:
            res = self.planner.plan_qpos_to_qpos([full], qpos.copy(), time_step=self.time_step,
                                                 planning_time=RRT_PLANNING_TIME)
        except RuntimeError:
            res = {"status": "topp failed"}
        self.plan_time += time.perf_counter() - t0
        self.rrt_calls += 1
        return self._path(res, qpos)

    def collides(self, path: np.ndarray, qpos: np.ndarray) -> bool:
        """Any waypoint in self-collision (the other arm at its configuration in ``qpos``)."""
        world = self.planner.planning_world
        self.planner.robot.set_qpos(self.planner.pad_qpos(qpos.copy()), True)
        for q in path:
            world.set_qpos_all(q)
            if world.collide():
                return True
        return False

    def _path(self, res: dict, qpos: np.ndarray) -> np.ndarray | None:
        if res.get("status") != "Success":
            return None
        path = np.asarray(res["position"], dtype=np.float64)
        if len(path) == 0:  # the goal is where we are
            path = qpos[self.index][None]
        return path

    # ------------------------------------------------------------------ actions
    def actions(self, path: np.ndarray, base_action: np.ndarray, gripper: float | None = None) -> np.ndarray:
        """(T, 14) pd_joint_pos actions: ``path`` on this arm, the rest of ``base_action`` held."""
        out = np.repeat(np.asarray(base_action, np.float32)[None], len(path), axis=0)
        out[:, self.action_index] = path
        if gripper is not None:
            out[:, GRIPPER_ACTION_INDEX[self.arm]] = gripper
        return out


def hold_actions(base_action: np.ndarray, steps: int, arm: str | None = None,
                 gripper: float | None = None) -> np.ndarray:
    """(steps, 14) copies of ``base_action``, optionally with ``arm``'s gripper set."""
    out = np.repeat(np.asarray(base_action, np.float32)[None], steps, axis=0)
    if arm is not None and gripper is not None:
        out[:, GRIPPER_ACTION_INDEX[arm]] = gripper
    return out


def pose7(p, q) -> np.ndarray:
    """[x, y, z, qw, qx, qy, qz] from a position and a wxyz quaternion."""
    return np.concatenate([np.asarray(p, np.float64), np.asarray(q, np.float64)])
