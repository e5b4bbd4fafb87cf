"""The reference policies: ``random`` (uniform actions), and, built on the scripted expert, the
privileged ``oracle``, ``blind`` and ``leftmost``.

They read the simulator (``env.unwrapped``), so unlike user policies they are built with the env:

- ``oracle``: the expert placing the correct block. A check of the harness: TSR near 100 %.
- ``blind``: the same expert placing a uniformly random candidate, drawn from the episode seed
  (so every run picks the same blocks) and, in a counterfactual variant, from the variant too
  (variant 0 is the protocol episode's draw). The random-selection line: GSR near 100 %, nSG
  near 0; under ``--instruction counterfactual`` it follows and switches at chance.
- ``leftmost``: the expert placing the leftmost candidate as the head camera sees it, whatever
  the instruction. A fixed-position line: TSR near 1/N, and in counterfactual scenes stuck on
  one candidate in every variant of a scene (the layout is the seed's alone).

All speak the :class:`~rsb_maniskill.policies.interface.Policy` interface: each ``act`` returns the
next motion-planned chunk, planned from the live state after the previous chunk was executed;
once the expert's plan is over (or it gave up) they hold the last target.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from rsb_maniskill.policies.interface import env_action_space

HOLD_STEPS = 10  # chunk length once the expert's plan is over
BLIND_SALT = 0xB11D  # separates the blind draw from the task's own use of the episode seed
RANDOM_SALT = 0x7A2D  # separates the random policy's draws from the task's own use of the episode seed
HEAD_CAMERA_LINK = "head_camera_link"  # the head camera's mount (ManiSkill camera frame: x forward, y left)
PICKS = ("oracle", "blind", "leftmost")  # how an ExpertPolicy chooses the candidate it places


def episode_key(salt: int, policy_seed: int, episode_seed: int) -> list[int]:
    """The seed of a policy's draws in one episode: its own seed and the episode's, apart from
    other users of the episode seed (``salt``); numpy and torch generators take it as it is."""
    return [int(salt), int(policy_seed), int(episode_seed)]


def blind_target(episode_seed: int, n_choices: int, variant: int = 0) -> int:
    """The block the blind baseline picks in the episode of ``episode_seed``: uniform over N.

    Variant 0 (the protocol episode) keeps the draw of the seed alone; counterfactual variant
    ``k > 0`` of the same scene draws afresh, so blind is not stuck on one block per scene."""
    key = [BLIND_SALT, int(episode_seed)] + ([int(variant)] if variant else [])
    return int(np.random.default_rng(key).integers(n_choices))


def leftmost_target(env: Any) -> int:
    """The candidate leftmost in the head camera's image (env 0): the largest bearing y/x in the
    frame of the camera's mount, which is the image's left-to-right order (u grows with -y/x).
    The mount is the robot's link, so the choice ignores a ``camera`` perturbation of the render."""
    base = env.unwrapped
    mount = base.agent.robot.links_map[HEAD_CAMERA_LINK].pose.to_transformation_matrix()[0]
    world_to_cam = np.linalg.inv(mount.detach().cpu().numpy().astype(np.float64))
    points = np.stack([base.candidate_actor(c).pose.p[0].detach().cpu().numpy()
                       for c in range(base.n_choices)]).astype(np.float64)
    local = points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
    return int(np.argmax(local[:, 1] / local[:, 0]))


class ExpertPolicy:
    """The scripted expert as a policy, placing the candidate its ``pick`` rule chooses.

    Args:
        env: the one-env RSB env the runner steps (possibly wrapped).
        blind: shorthand for ``pick="blind"``.
        pick: ``"oracle"`` (the correct block), ``"blind"`` (:func:`blind_target`) or
            ``"leftmost"`` (:func:`leftmost_target`).
    """

    def __init__(self, env: Any, blind: bool = False, pick: str | None = None) -> None:
        pick = pick or ("blind" if blind else "oracle")
        if pick not in PICKS:
            raise ValueError(f"unknown pick {pick!r}; valid: {', '.join(PICKS)}")
        self.env = env
        self.pick = pick
        self.blind = pick == "blind"
        self.name = pick
        self.expert = None
        self._chunks = None

    def target(self) -> int | None:
        """The candidate this episode's plan places; None: the ground truth (oracle)."""
        base = self.env.unwrapped
        if self.pick == "blind":
            variants = getattr(base, "episode_variants", None) or [None]
            variant = variants[0].index if variants[0] is not None else 0
            return blind_target(int(base.episode_specs[0].seed), base.n_choices, variant)
        if self.pick == "leftmost":
            return leftmost_target(self.env)
        return None

    def reset(self, instruction: str, obs: dict) -> None:
        from rsb_maniskill.motionplan import ScriptedExpert

        self.expert = ScriptedExpert(self.env, target_block=self.target())
        self._chunks = self.expert.chunks()

    def act(self, obs: dict) -> np.ndarray:
        if self.expert is None:
            raise RuntimeError(f"{self.name}: act() before reset()")
        chunk = next(self._chunks, None)
        if chunk is None:  # plan over (success, or the expert gave up): hold still
            return np.repeat(self.expert.action[None], HOLD_STEPS, axis=0)
        return chunk


def oracle(env: Any) -> ExpertPolicy:
    return ExpertPolicy(env, pick="oracle")


def blind(env: Any) -> ExpertPolicy:
    return ExpertPolicy(env, pick="blind")


def leftmost(env: Any) -> ExpertPolicy:
    return ExpertPolicy(env, pick="leftmost")


class RandomPolicy:
    """Uniform random actions in [low, high]: the floor of the benchmark (no grasp expected).

    The draws of an episode are a function of ``seed`` and the episode's seed (reseeded at each
    ``reset``): the same actions under any ``--num-envs``, ``--num-procs`` or resume. Without an
    episode seed (a caller that gives none) it keeps drawing from the generator it has."""

    name = "random"

    def __init__(self, low: Any, high: Any, chunk_size: int = 1, seed: int = 0) -> None:
        self.low = np.asarray(low, dtype=np.float32)
        self.high = np.asarray(high, dtype=np.float32)
        if self.low.shape != self.high.shape or self.low.ndim != 1:
            raise ValueError(f"low and high must be 1-D of equal shape, got {self.low.shape} and {self.high.shape}")
        self.chunk_size = int(chunk_size)
        self.seed = int(seed)
        self.rng = np.random.default_rng(seed)

    @classmethod
    def from_action_space(cls, space: Any, **kwargs: Any) -> "RandomPolicy":
        """From a gymnasium Box (batched spaces: the last axis is the action)."""
        low, high = np.asarray(space.low), np.asarray(space.high)
        return cls(low.reshape(-1, low.shape[-1])[0], high.reshape(-1, high.shape[-1])[0], **kwargs)

    @classmethod
    def for_env(cls, env: Any, chunk_size: int = 1, seed: int = 0) -> "RandomPolicy":
        """Over the action space of one env of ``env`` (the ``random`` policy's factory)."""
        return cls.from_action_space(env_action_space(env), chunk_size=chunk_size, seed=seed)

    def reset(self, instruction: str, obs: dict, seed: int | None = None) -> None:
        if seed is not None:
            self.rng = np.random.default_rng(episode_key(RANDOM_SALT, self.seed, seed))

    def act(self, obs: dict) -> np.ndarray:
        return self.rng.uniform(self.low, self.high, size=(self.chunk_size, self.low.shape[0])).astype(np.float32)
