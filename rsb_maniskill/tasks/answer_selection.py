"""The RSB answer-selection task: put the candidate of the correct answer into the gray zone.

One class serves every suite (``RSB-Math-4`` ... ``RSB-Direct-10``, and their ``-Objects``
variants): the suite only changes the question source and the number of candidates, the
``targets`` family what the candidates are (blocks or everyday objects, ``rsb_maniskill.objects``).
The physical primitive never changes.

Determinism: everything about an episode is a function of its episode seed. The question is
``seed mod pool size`` of the split's pool (so seeds 0..P-1 visit every question once), the rest
of the semantic draw (options, colour map, template) comes from the semantic engine seeded with
the same seed, and the layout from ManiSkill's batched episode RNG (``objects/layout.py``), identical on CPU and
GPU and under ``replay_trajectory``. On the CPU backend so is the physics that follows: every reset
builds a fresh scene (``CPU_RECONFIGURATION_FREQ``), whatever ran before in the process.
"""
from __future__ import annotations

import numpy as np
import sapien
import torch

from mani_skill.utils.structs.types import GPUMemoryConfig, SimConfig

from rsb_maniskill import compat
from rsb_maniskill.agents.aloha import AlohaAgilex
from rsb_maniskill.env_ids import CONTROL_FREQ, SIM_FREQ, TASK_ENVS, serves
from rsb_maniskill.objects import layout
from rsb_maniskill.objects.family import DEFAULT_TARGETS, get_family
from rsb_maniskill.objects.pool import CandidatePool
from rsb_maniskill.perturb import language as perturb_language
from rsb_maniskill.perturb import parse_perturb
from rsb_maniskill.robot import ROBOT_UID
from rsb_maniskill.semantic import EpisodeSampler, EpisodeSpec, counterfactual, parse_suite_id
from rsb_maniskill.tasks.base import RSBEnv
from rsb_maniskill.tasks.contacts import PairContacts
from rsb_maniskill.tasks.perturb_scene import CLUTTER_ITEMS, SceneAxes, build_clutter
from rsb_maniskill.tasks.scene import TableSceneBuilder, human_camera_config

# Layout (metres, robot frame: arm bases at (0, +-0.30), table top z = 0); cells: objects/layout.py.
# Parked pool members: one layout cell apart (no two touch, so they stay asleep), in layers
# under the part of the table top that hides the floor from every camera (the human camera
# looks under the far and right edges), clear of the robot's base.
PARK_PITCH = (0.12, 0.105)
PARK_X, PARK_Y = (0.15, 0.39), (-0.45, 0.65)
PARK_LAYERS_Z = (-0.25, -0.42, -0.59)  # CPU: asleep and hidden in mid-air; GPU: they drop to the floor
ZONE_XY = (0.17, 0.0)  # on the midline: both arms reach it
ZONE_HALF = 0.05
ZONE_COLOR = (0.50, 0.50, 0.52, 1.0)

# Grasp and placement rule (paper appendix C).
CONTACT_FORCE = 0.5  # N: a finger "touches" a candidate
LIFT_HEIGHT = 0.01  # m above its resting height
HOLD_STEPS = 8  # consecutive control steps of closed-gripper contact
REST_SPEED = 0.05  # m/s: a placed candidate must be at rest

# CPU physics: a fresh PhysX scene at every reset (ManiSkill's reconfiguration_freq). A reset only
# teleports bodies, and PhysX keeps history no reset reaches (contact caches of pairs that survive
# a teleport, the order its scene visits new contacts in), so the same seed would otherwise play
# out differently after different episodes (docs/expert.md, "Reproducibility").
CPU_RECONFIGURATION_FREQ = 1


@serves(*TASK_ENVS)  # every suite with every candidate family: RSB-Math-4, RSB-Math-4-Objects, ...
class AnswerSelectionEnv(RSBEnv):
    """Aloha-AgileX at a table with N candidates (blocks or everyday objects) and a gray answer zone.

    Args:
        suite_id: one of ``rsb_maniskill.semantic.SUITE_IDS`` (set by the registered id).
        split: ``"train"`` or ``"test"`` (the evaluation pool, disjoint from train).
        instructions: ``"seen"`` or ``"unseen"`` templates; default seen for train, unseen for test.
        color_map: 4-choice only: ``"fixed"`` (A=red, B=green, C=blue, D=yellow) or ``"shuffle"``.
        data_dir: directory with GSM8K / MMLU-Pro files (else ``$RSB_DATA_DIR``, else the HF hub cache).
        camera_size: (width, height) of the head and wrist cameras; default ``robot.CAMERA_SIZE`` (320x240).
        targets: ``"blocks"`` or ``"objects"`` (everyday objects; the ``-Objects`` ids set it).
        perturb: robustness axes and their levels 0-3, e.g. ``{"camera": 2, "lang_layout": 1}``
            (``rsb_maniskill.perturb.AXES``; level 0 is today's episode). See docs/robustness.md.
        reconfiguration_freq: ManiSkill's; default here 1 on the CPU backend (a fresh scene every
            episode: ``CPU_RECONFIGURATION_FREQ``), ManiSkill's 0 on the GPU.
    """

    SUPPORTED_ROBOTS = [ROBOT_UID]
    SUPPORTED_REWARD_MODES = ["normalized_dense", "dense", "sparse", "none"]
    agent: AlohaAgilex
    pool: CandidatePool

    def __init__(self, *args, suite_id: str, split: str = "train", instructions: str | None = None,
                 color_map: str = "fixed", data_dir: str | None = None,
                 camera_size: tuple[int, int] | None = None, targets: str = DEFAULT_TARGETS,
                 perturb: dict[str, int] | str | None = None, robot_uids: str = ROBOT_UID, **kwargs):
        self.suite_id = suite_id
        self.perturb = parse_perturb(perturb)  # first: a bad axis or level fails before anything is built
        self.suite, self.n_choices = parse_suite_id(suite_id)
        self.family = get_family(targets)
        self.targets = targets
        # Built first so that a bad split, template set, colour map or missing data fails fast.
        self.sampler = EpisodeSampler(suite_id, split=split, instructions=instructions,
                                      color_map=color_map, data_dir=data_dir, targets=targets,
                                      perturb=perturb_language(self.perturb))
        self.split = split
        if camera_size is not None:
            w, h = camera_size
            kwargs["sensor_configs"] = {**kwargs.get("sensor_configs", {}), "width": int(w), "height": int(h)}
        self.episode_specs: list[EpisodeSpec | None] = []
        self.episode_variants: list[counterfactual.Variant | None] = []  # reset(options={"variant": k})
        super().__init__(*args, robot_uids=robot_uids, **kwargs)
        if kwargs.get("reconfiguration_freq") is None and not self.gpu_sim_enabled:
            self.reconfiguration_freq = CPU_RECONFIGURATION_FREQ

    # ------------------------------------------------------------------ configuration
    @property
    def _default_sim_config(self):
        return SimConfig(sim_freq=SIM_FREQ, control_freq=CONTROL_FREQ,
                         gpu_memory_config=GPUMemoryConfig(max_rigid_contact_count=2**21,
                                                           max_rigid_patch_count=2**19,
                                                           found_lost_pairs_capacity=2**25))

    @property
    def _default_sensor_configs(self):
        return []  # head and wrist cameras ride on the robot

    @property
    def _default_human_render_camera_configs(self):
        return human_camera_config()

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose())

    def _load_lighting(self, options: dict):
        if self.axes.level("lighting"):
            self.axes.load_lighting(self.enable_shadow)
        else:
            super()._load_lighting(options)

    def _load_scene(self, options: dict):
        self.axes = SceneAxes(self, self.perturb)
        self.table_scene = TableSceneBuilder(self)
        self.table_scene.build(per_env_materials=bool(self.axes.level("table")) and self.axes.per_env_materials)
        self.pool = CandidatePool(self.family, self.n_choices, self.sampler.letters, self.num_envs, self.device)
        n_clutter = len(CLUTTER_ITEMS) if self.axes.level("clutter") else 0
        park = _park_positions(len(self.pool.keys) + n_clutter)
        self.pool.build(self.scene, park[:len(self.pool.keys)],
                        per_env_materials=bool(self.axes.level("candidate")) and self.axes.per_env_materials)
        if n_clutter:
            self.axes.clutter = build_clutter(self.scene, park[len(self.pool.keys):])
            self.axes.set_clutter_park(park[len(self.pool.keys):])
        self.axes.after_load(self.table_scene.table, self.pool.actors)
        builder = self.scene.create_actor_builder()
        builder.add_box_visual(half_size=[ZONE_HALF, ZONE_HALF, 0.0005],
                               material=sapien.render.RenderMaterial(base_color=ZONE_COLOR, roughness=0.9))
        builder.initial_pose = sapien.Pose(p=[*ZONE_XY, 0.0006])
        self.zone = builder.build_kinematic(name="answer_zone")

    def _after_reconfigure(self, options: dict):
        fingers = [f for arm in self.agent.arms for f in self.agent.fingers[arm]]
        self.contacts = PairContacts(self.scene, fingers, self.pool.actors)
        self.zone_xy = torch.tensor(ZONE_XY, device=self.device)
        n, b = self.n_choices, self.num_envs
        long = dict(dtype=torch.long, device=self.device)
        self.target_block = torch.zeros(b, **long)
        self.answer_slot = torch.zeros(b, **long)
        self.question_id = torch.zeros(b, **long)
        self.template_id = torch.zeros(b, **long)
        self.block_of_option = torch.zeros(b, n, **long)
        self.block_slot = torch.zeros(b, n, **long)
        self.hold_steps = torch.zeros(b, len(self.agent.arms), n, **long)
        self.first_grasped = torch.full((b,), -1, **long)
        self.grasped_correct = torch.zeros(b, dtype=torch.bool, device=self.device)
        self.grasped_wrong = torch.zeros(b, dtype=torch.bool, device=self.device)
        self.episode_specs = [None] * b
        self.episode_variants = [None] * b
        self._grasp_update_pending = False
        self._block_pose_cache = self._tcp_cache = None

    # ------------------------------------------------------------------ episodes
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        self.table_scene.initialize(env_idx)
        idx = env_idx.cpu().numpy()
        for i in idx:
            seed, k = int(compat.episode_seeds(self)[i]), _variant_option(options, int(i))
            variant = None if k is None else self.episode_variant(seed, k)
            spec = self.episode_spec(seed) if variant is None else variant.spec
            self.episode_specs[i], self.episode_variants[i] = spec, variant
            self.target_block[i] = spec.target_block
            self.answer_slot[i] = spec.answer_slot
            self.question_id[i] = spec.question_id
            self.template_id[i] = spec.template_id
            self.block_of_option[i] = torch.as_tensor(spec.block_of_option, device=self.device)
            self.pool.assign(int(i), spec.candidates)
        self._place_candidates(env_idx)
        self.axes.initialize(env_idx)
        self.hold_steps[env_idx] = 0
        self.first_grasped[env_idx] = -1
        self.grasped_correct[env_idx] = False
        self.grasped_wrong[env_idx] = False
        self._grasp_update_pending = False

    def _place_candidates(self, env_idx: torch.Tensor):
        """Random distinct cells, position and yaw jitter within each candidate's footprint:
        identity and place are independent."""
        half = self.pool.half_extents()[env_idx].cpu().numpy()
        slots, xy, yaw = layout.place(compat.batched_episode_rng(self)[env_idx], self.family.layout, half)
        self.block_slot[env_idx] = torch.as_tensor(slots, device=self.device)
        xy = torch.as_tensor(xy, device=self.device)
        yaw = torch.as_tensor(yaw, device=self.device)
        z = self.rest_z[env_idx] + 5e-4
        zero = torch.zeros_like(yaw)
        q = torch.stack([torch.cos(yaw / 2), zero, zero, torch.sin(yaw / 2)], dim=-1)
        self.pool.place(env_idx, torch.cat([xy, z[..., None]], dim=-1), q)
        self._block_pose_cache = self._tcp_cache = None

    @property
    def rest_z(self) -> torch.Tensor:
        """(B, N) height of each candidate's origin above the table at rest."""
        return self.pool.rest_z()

    def candidate_actor(self, candidate: int, env: int = 0):
        """The actor of candidate ``candidate`` in env ``env`` (a pool member: index it by env)."""
        return self.pool.actor(candidate, env)

    def episode_spec(self, seed: int) -> EpisodeSpec:
        """The semantics of the episode ``seed`` (question ``seed mod pool size``), without a reset."""
        return self.sampler.episode(seed)

    def episode_categories(self, spec: EpisodeSpec) -> dict[str, str]:
        """What the per-category tables group the episode ``spec`` by (``semantic/categories.py``)."""
        return self.sampler.categories(spec)

    def episode_variant(self, seed: int, index: int) -> counterfactual.Variant:
        """Counterfactual variant ``index`` of the scene ``seed``: the same layout and candidates, the
        answer on another candidate (``semantic/counterfactual.py``); ``reset(seed=seed,
        options={"variant": index})`` runs it (a list gives each env its own)."""
        return counterfactual.variant(self.sampler, seed, index)

    def get_language_instruction(self) -> list[str]:
        """The instruction of each parallel env (strings can't live in observations)."""
        return [spec.instruction for spec in self.episode_specs]

    # ------------------------------------------------------------------ evaluation
    def _after_control_step(self):
        self._grasp_update_pending = True  # grasp state advances once per control step
        self.pool.after_step()
        self._block_pose_cache = self._tcp_cache = None

    def _block_poses(self) -> torch.Tensor:
        """(B, N, 7) candidate raw poses, read once per control step (evaluate, obs and reward share it)."""
        if self._block_pose_cache is None:
            self._block_pose_cache = self.pool.raw_poses()
        return self._block_pose_cache

    def _candidate_forces(self) -> torch.Tensor:
        """(B, 4 fingers, N) contact force magnitudes between the fingers and the candidates."""
        forces = self.contacts.forces()  # (B, 4, pool size)
        idx = self.pool.index[:, None, :].expand(-1, forces.shape[1], -1)
        return torch.gather(forces, 2, idx)

    def _tcp_raw_poses(self) -> list[torch.Tensor]:
        """Left and right TCP raw poses, read once per control step."""
        if self._tcp_cache is None:
            self._tcp_cache = [self.agent.tcp_pose(a).raw_pose for a in self.agent.arms]
        return self._tcp_cache

    def _block_positions(self) -> torch.Tensor:
        return self._block_poses()[..., :3]

    def _tcp_positions(self) -> torch.Tensor:
        """(B, arms, 3) TCP positions."""
        return torch.stack([pose[:, :3] for pose in self._tcp_raw_poses()], 1)

    def _update_grasps(self, forces: torch.Tensor, pos: torch.Tensor):
        touch = (forces >= CONTACT_FORCE).view(self.num_envs, len(self.agent.arms), 2, self.n_choices).any(2)
        closed = self.agent.grippers_closed()  # (B, 2)
        contact = touch & closed[..., None]  # (B, arms, N)
        self.hold_steps = torch.where(contact, self.hold_steps + 1, torch.zeros_like(self.hold_steps))
        lifted = (pos[..., 2] - self.rest_z) >= LIFT_HEIGHT  # (B, N)
        grasp_now = (contact & (lifted[:, None] | (self.hold_steps >= HOLD_STEPS))).any(1)  # (B, N)
        is_target = torch.arange(self.n_choices, device=self.device)[None] == self.target_block[:, None]
        self.grasped_correct |= (grasp_now & is_target).any(1)
        self.grasped_wrong |= (grasp_now & ~is_target).any(1)
        new = (self.first_grasped < 0) & grasp_now.any(1)
        self.first_grasped = torch.where(new, grasp_now.float().argmax(1), self.first_grasped)

    def evaluate(self) -> dict:
        forces = self._candidate_forces()  # (B, 4 fingers, N)
        pos = self._block_positions()
        if self._grasp_update_pending:
            self._update_grasps(forces, pos)
            self._grasp_update_pending = False
        speed = torch.linalg.norm(self.pool.linear_velocities(), dim=-1)
        in_zone = (pos[..., :2] - self.zone_xy).abs().le(ZONE_HALF).all(-1)
        untouched = (forces < CONTACT_FORCE).all(1)
        at_rest = (pos[..., 2] - self.rest_z < LIFT_HEIGHT) & (speed < REST_SPEED) & untouched
        placed = in_zone & at_rest  # (B, N)
        is_target = torch.arange(self.n_choices, device=self.device)[None] == self.target_block[:, None]
        placed_correct = (placed & is_target).any(1)
        placed_wrong = (placed & ~is_target).any(1)
        held = (forces >= CONTACT_FORCE).view(self.num_envs, len(self.agent.arms), 2, self.n_choices).all(2).any(1)
        return dict(
            success=placed_correct & ~placed_wrong,
            fail=placed_wrong,
            grasped_any=self.first_grasped >= 0,
            grasped_correct=self.grasped_correct.clone(),
            grasped_wrong=self.grasped_wrong.clone(),
            first_grasped=self.first_grasped.clone(),
            placed_correct=placed_correct,
            placed_wrong=placed_wrong,
            holding_target=(held & is_target).any(1),
            question_id=self.question_id.clone(),
            answer_slot=self.answer_slot.clone(),
            target_block=self.target_block.clone(),
        )

    # ------------------------------------------------------------------ observations / rewards
    def _get_obs_sensor_data(self, apply_texture_transforms: bool = True) -> dict:
        data = super()._get_obs_sensor_data(apply_texture_transforms)
        return self.axes.add_noise(data) if self.axes.level("noise") else data

    def _get_obs_extra(self, info: dict):
        obs = {f"{a}_tcp_pose": pose for a, pose in zip(self.agent.arms, self._tcp_raw_poses())}
        obs["zone_pos"] = self.zone.pose.p
        if "state" in self.obs_mode:
            poses = self._block_poses()
            obs["block_pose"] = poses.flatten(1)  # (B, 7N)
            obs["block_id"] = self.pool.index.clone()  # which block / object model each candidate is
            # Relative positions, as ManiSkill's PickCube gives tcp_to_obj_pos: what a reach or a
            # placement must close, without learning the arms' kinematics from world coordinates.
            tcp = self._tcp_positions()
            obs["tcp_to_block_pos"] = (poses[:, None, :, :3] - tcp[:, :, None]).flatten(1)  # (B, arms * 3N)
            obs["block_to_zone_pos"] = (self.zone.pose.p[:, None] - poses[..., :3]).flatten(1)  # (B, 3N)
        return obs

    def compute_dense_reward(self, obs, action, info: dict):
        target_pos = self._block_positions()[torch.arange(self.num_envs, device=self.device), self.target_block]
        tcp = self._tcp_positions()
        reach = torch.linalg.norm(tcp - target_pos[:, None], dim=-1).min(1)[0]
        to_zone = torch.linalg.norm(target_pos[:, :2] - self.zone_xy, dim=1)
        holding = info["holding_target"].float()
        reward = (1 - torch.tanh(5 * reach)) + 1.5 * holding + 2 * holding * (1 - torch.tanh(5 * to_zone))
        reward = reward - 1.0 * info["grasped_wrong"].float()
        reward[info["success"]] = 6.0
        return reward

    def compute_normalized_dense_reward(self, obs, action, info: dict):
        return self.compute_dense_reward(obs, action, info) / 6.0

    # ------------------------------------------------------------------ state (for replay)
    def _task_state_columns(self) -> dict[str, torch.Tensor]:
        """The task's own state, column block by column block (one source for get and set)."""
        return dict(question_id=self.question_id[:, None], answer_slot=self.answer_slot[:, None],
                    target_block=self.target_block[:, None], template_id=self.template_id[:, None],
                    first_grasped=self.first_grasped[:, None], grasped_correct=self.grasped_correct[:, None],
                    grasped_wrong=self.grasped_wrong[:, None], block_of_option=self.block_of_option,
                    block_slot=self.block_slot, pool_index=self.pool.index, hold_steps=self.hold_steps.flatten(1))

    def _task_state(self) -> torch.Tensor:
        return torch.cat([c.to(torch.float32) for c in self._task_state_columns().values()], dim=1)

    def get_state_dict(self):
        state = super().get_state_dict()
        state["task"] = self._task_state()
        return state

    def set_state_dict(self, state: dict, env_idx: torch.Tensor | None = None):
        task = state.get("task")
        state = {k: v for k, v in state.items() if k != "task"}
        super().set_state_dict(state, env_idx)
        self._block_pose_cache = self._tcp_cache = None
        if task is None:
            return
        task = torch.as_tensor(task, device=self.device).round().long()
        if task.ndim == 1:
            task = task[None]
        idx = slice(None) if env_idx is None else env_idx
        start = 0
        for name, col in self._task_state_columns().items():
            part = task[:, start:start + col.shape[1]]
            start += col.shape[1]
            if name == "hold_steps":
                self.hold_steps[idx] = part.view(-1, len(self.agent.arms), self.n_choices)
            elif name == "pool_index":
                self.pool.set_index(idx, part)
            elif col.shape[1] == 1:
                target = getattr(self, name)
                target[idx] = part[:, 0].to(target.dtype)
            else:
                getattr(self, name)[idx] = part


def _variant_option(options: dict | None, env: int) -> int | None:
    """The counterfactual variant a reset asks of env ``env``: ``options["variant"]``, one index for
    every env or a sequence with one per env (None: the protocol episode)."""
    k = (options or {}).get("variant")
    if k is not None and not isinstance(k, (int, np.integer)):
        k = list(k)[env]
    return None if k is None else int(k)


def _park_positions(count: int) -> np.ndarray:
    """(count, 3) spots under the table for pool members not in play: out of the arms' reach,
    and the table top hides them from the cameras."""
    xs = np.arange(PARK_X[0], PARK_X[1] + 1e-6, PARK_PITCH[0])
    ys = np.arange(PARK_Y[0], PARK_Y[1] + 1e-6, PARK_PITCH[1])
    spots = [(x, y, z) for z in PARK_LAYERS_Z for x in xs for y in ys]
    if count > len(spots):
        raise ValueError(f"{count} pool members but only {len(spots)} park spots: add a layer")
    spots = spots[:count]
    return np.asarray(spots, dtype=np.float32)
