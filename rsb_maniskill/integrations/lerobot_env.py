"""RSB suites as LeRobot evaluation envs: one RSB env per sub-env, or n_envs in one RSB vector env.

LeRobot's rollout (``lerobot-eval``) wants a plain ``gym.Env`` per sub-env with numpy observations
(``pixels/<camera>`` HWC uint8 and ``agent_pos``), the attributes ``task_description``, ``task``
and ``_max_episode_steps`` (read through ``VectorEnv.call``), and ``info["is_success"]``.
ManiSkill's ``ManiSkillVectorEnv`` returns torch tensors and reports ``success``, so each RSB
env is wrapped here, as LeRobot wraps RoboTwin 2.0 (the same robot). Nothing here imports LeRobot:
``lerobot_env_rsb`` (the ``--env.type=rsb`` plugin) and the EnvHub file build on this module.

- Observations and actions are those of ``rsb export lerobot``: the three cameras under the keys of
  a naming (``export/naming.py``: ``cam_high``, ... or RoboTwin's ``head_camera``, ...), the Aloha
  14-number state (``agent_pos``) and Aloha 14-number absolute joint targets as actions, so a
  policy trained on an export evaluates with no feature mapping.
- Episodes are the evaluation protocol's: LeRobot seeds episode i of a run with ``--seed`` + i;
  ``seed_base`` (LeRobot's default ``--seed``, ``protocol.LEROBOT_SEED_BASE``) maps it back to i
  and episode i is protocol episode i (seed 10,000,000 + i, test split, unseen templates), the one
  ``rsb eval`` runs.
- ``instruction_mode`` ``blank`` / ``shuffled`` are ``rsb eval``'s ablations (the same donors,
  ``protocol.ShuffledDonors``).
- Each finished episode appends an ``rsb eval`` record (with the benchmark version) to
  ``records_dir/episodes.jsonl`` (under a file lock: sub-envs may live in several processes), so
  ``rsb report records_dir`` gives the paper's GSR / TSR / nSG tables, report.html and results.json
  of a ``lerobot-eval`` run.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from rsb_maniskill.env_ids import CONTROL_FREQ, CPU_SIM_BACKEND, TASK_MAX_EPISODE_STEPS
from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE, LEROBOT_SEED_BASE, check_ablation_mode
from rsb_maniskill.evaluation.records import LEROBOT_RUNNER, build_record
from rsb_maniskill.evaluation.store import RECORDS_FILE, RecordWriter
from rsb_maniskill.export.naming import DEFAULT_NAMING, camera_key, check_naming
from rsb_maniskill.robot import ACTION_DIM, CAMERA_SIZE, CAMERAS, CONTROL_MODE, from_aloha14, sensor_uid

OBS_TYPES = ("pixels_agent_pos", "pixels")


def append_record(path: Path, record: dict[str, Any]) -> None:
    """Appends one (validated) record line under an exclusive file lock, durable (flush + fsync):
    the sub-envs of an async vector env share the file."""
    with RecordWriter(path, lock=True) as writer:
        writer.write(record)


class RSBLeRobotEnv(gym.Env):
    """One RSB suite's evaluation episodes for LeRobot (see the module doc).

    Args:
        env_id: an RSB id (``RSB-Math-4``, ``RSB-Math-4-Objects``, ...).
        instruction_mode: ``normal``, ``blank`` or ``shuffled``.
        naming: camera keys, ``rsb`` or ``robotwin``.
        obs_type: ``pixels_agent_pos`` (cameras and state) or ``pixels``.
        camera_size: (width, height) of every camera.
        episode_length: step cap (LeRobot reads it as ``_max_episode_steps``).
        seed_base: lerobot-eval's ``--seed``; seed ``seed_base + i`` is protocol episode i.
        episodes: how many protocol episodes the shuffled ablation pairs over (``rsb eval -n``).
        records_dir: where ``episodes.jsonl`` goes (None: no records).
        policy_name: the ``policy`` field of the records (a row of the report's tables).
        data_dir: question data (default ``$RSB_DATA_DIR`` or the hub cache).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": CONTROL_FREQ}

    def __init__(self, env_id: str, *, instruction_mode: str = "normal", naming: str = DEFAULT_NAMING,
                 obs_type: str = "pixels_agent_pos", camera_size: tuple[int, int] = CAMERA_SIZE,
                 episode_length: int = TASK_MAX_EPISODE_STEPS, seed_base: int = LEROBOT_SEED_BASE,
                 episodes: int = EPISODES_PER_SUITE, records_dir: str | None = None, policy_name: str = "lerobot",
                 data_dir: str | None = None) -> None:
        from rsb_maniskill.env_ids import resolve_env_ids

        (self.env_id,) = resolve_env_ids([env_id])
        check_ablation_mode(instruction_mode, "the LeRobot env")
        if obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type must be one of {', '.join(OBS_TYPES)}, got {obs_type!r}")
        self.naming = check_naming(naming)
        self.instruction_mode, self.obs_type = instruction_mode, obs_type
        self.camera_size = (int(camera_size[0]), int(camera_size[1]))
        self.seed_base, self.episodes = int(seed_base), int(episodes)
        self.records = Path(records_dir) / RECORDS_FILE if records_dir else None
        self.policy_name, self.data_dir = policy_name, data_dir
        # what LeRobot reads through VectorEnv.call
        self.task = self.env_id
        self.task_description = ""
        self._max_episode_steps = int(episode_length)
        w, h = self.camera_size
        pixels = spaces.Dict({camera_key(c, naming): spaces.Box(0, 255, (h, w, 3), np.uint8) for c in CAMERAS})
        obs = {"pixels": pixels}
        if obs_type == "pixels_agent_pos":
            obs["agent_pos"] = spaces.Box(-np.inf, np.inf, (ACTION_DIM,), np.float32)
        self.observation_space = spaces.Dict(obs)
        self.action_space = spaces.Box(-np.inf, np.inf, (ACTION_DIM,), np.float32)
        self._env: Any = None  # built at the first reset, in the process that steps it
        self._donors: Any = None
        self._donor_seed: int | None = None
        self._episode = -1
        self._seed = 0
        self._steps = 0
        self._instruction = ""
        self._last: tuple | None = None  # the finished episode's last transition, replayed until a seeded reset

    # ------------------------------------------------------------------ the RSB env
    def make_kwargs(self) -> dict[str, Any]:
        """``gym.make`` keyword arguments of the RSB env (one, or each of a vector env's)."""
        from rsb_maniskill.evaluation.protocol import EVAL_ENV_KWARGS

        kwargs = dict(EVAL_ENV_KWARGS, obs_mode="rgb", control_mode=CONTROL_MODE, camera_size=self.camera_size,
                      sim_backend=CPU_SIM_BACKEND)
        if self.data_dir:
            kwargs["data_dir"] = self.data_dir
        return kwargs

    def _ensure_env(self) -> None:
        if self._env is not None:
            return
        import rsb_maniskill  # noqa: F401  (registers the ids)

        self._env = gym.make(self.env_id, **self.make_kwargs())

    def _obs(self, raw: dict) -> dict[str, Any]:
        base = self._env.unwrapped
        out: dict[str, Any] = {"pixels": {camera_key(c, self.naming): raw["sensor_data"][sensor_uid(c)]["rgb"][0]
                                          .cpu().numpy().astype(np.uint8) for c in CAMERAS}}
        if self.obs_type == "pixels_agent_pos":
            out["agent_pos"] = base.agent.aloha14_state()[0].cpu().numpy().astype(np.float32)
        return out

    def _shown_instruction(self, seed: int, own: str) -> str:
        """The instruction the policy gets (``rsb eval``'s ablations); shuffled: the donor's seed is
        kept for the record."""
        from rsb_maniskill.evaluation.protocol import ShuffledDonors, apply_instruction_mode

        self._donor_seed = None
        donor = None
        if self.instruction_mode == "shuffled":
            if self._donors is None:
                self._donors = ShuffledDonors.of_env(self._env, self.env_id, self.episodes)
            self._donor_seed, donor = self._donors(seed, own)
        return apply_instruction_mode(own, self.instruction_mode, donor)

    # ------------------------------------------------------------------ gym.Env
    def holds_on_reset(self, seed: int | None) -> bool:
        """Whether ``reset(seed=seed)`` only replays the finished episode's last transition."""
        return seed is None and self._last is not None

    def next_episode(self, seed: int | None) -> int:
        """The protocol episode ``reset(seed=seed)`` runs (seed ``seed_base`` + i: episode i; None: the next)."""
        if seed is None:
            return self._episode + 1
        episode = int(seed) - self.seed_base
        if not 0 <= episode < self.episodes:
            raise ValueError(f"seed {seed} is not episode 0..{self.episodes - 1} of the protocol: lerobot-eval "
                             f"--seed must equal --env.seed_base ({self.seed_base}) and --eval.n_episodes "
                             f"<= --env.episodes ({self.episodes})")
        return episode

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE

        super().reset(seed=seed)
        self._ensure_env()
        if self.holds_on_reset(seed):
            # the vector env's autoreset of a finished sub-env: LeRobot's rollout ignores it until the
            # next batch resets with seeds, so no episode is run (nor recorded) in between
            return self._last[0], self._last[4]
        self._episode = self.next_episode(seed)
        self._last = None
        self._seed = EVAL_SEED_BASE + self._episode
        raw, _ = self._env.reset(seed=self._seed)
        base = self._env.unwrapped
        self._instruction = base.get_language_instruction()[0]
        self.task_description = self._shown_instruction(self._seed, self._instruction)
        self._steps = 0
        return self._obs(raw), {"is_success": False, "task": self.env_id}

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        if self._last is not None:
            return self._last
        action = np.asarray(action, dtype=np.float32)
        if action.shape != (ACTION_DIM,):
            raise ValueError(f"{self.env_id}: expected an Aloha 14-number action of shape ({ACTION_DIM},), "
                             f"got {action.shape}")
        raw, _, terminated, truncated, info = self._env.step(from_aloha14(action))
        self._steps += 1
        success = bool(info["success"][0])
        terminated = bool(terminated[0]) if hasattr(terminated, "__len__") else bool(terminated)
        truncated = bool(truncated[0]) if hasattr(truncated, "__len__") else bool(truncated)
        truncated = truncated or self._steps >= self._max_episode_steps
        out = {"is_success": success, "task": self.env_id}
        transition = (self._obs(raw), float(success), terminated, truncated, out)
        if terminated or truncated:
            out["final_info"] = {"is_success": success, "task": self.env_id}
            self._write_record(info)
            self._last = (transition[0], 0.0, terminated, truncated, dict(out))
        return transition

    def _write_record(self, info: dict) -> None:
        if self.records is None:
            return
        record = build_record(suite_id=self.env_id, seed=self._seed, spec=self._env.unwrapped.episode_specs[0],
                              instruction=self.task_description, instruction_mode=self.instruction_mode, info=info,
                              steps=self._steps, policy=self.policy_name,
                              extra={"original_instruction": self._instruction, "runner": LEROBOT_RUNNER,
                                     **({"donor_seed": self._donor_seed} if self._donor_seed is not None else {})})
        append_record(self.records, record)

    def render(self) -> np.ndarray:
        """The head camera (LeRobot's eval videos)."""
        self._ensure_env()
        raw = self._env.unwrapped.get_obs()
        return self._obs(raw)["pixels"][camera_key("head", self.naming)]

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
            self._env = None


class _VectorRow:
    """Env ``i`` of an :class:`RSBVectorEnv` as the one-env env :class:`RSBLeRobotEnv` steps: its
    ``reset`` / ``step`` hand back row i of the batched call :class:`RSBLeRobotVectorEnv` made first."""

    def __init__(self, vector: Any, i: int) -> None:
        self.vector, self.i = vector, i
        self.pending: Any = None

    @property
    def unwrapped(self) -> Any:
        return self.vector.envs[self.i].unwrapped

    def take(self) -> Any:
        out, self.pending = self.pending, None
        if out is None:
            raise RuntimeError("RSBLeRobotVectorEnv: a sub-env was stepped outside the vector env's step / reset")
        return out

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple:
        got_seed, out = self.take()
        assert got_seed == seed, (got_seed, seed)
        return out

    def step(self, action: Any) -> tuple:
        return self.take()

    def close(self) -> None:
        pass  # the vector env closes the K envs


class RSBLeRobotVectorEnv(gym.vector.SyncVectorEnv):
    """LeRobot's ``n_envs`` as one process holding one :class:`~rsb_maniskill.vector.RSBVectorEnv`:
    every camera of the K envs renders in one call where CUDA rendering exists.

    It is gymnasium's ``SyncVectorEnv`` of K :class:`RSBLeRobotEnv` (the same autoreset, info
    layout, ``call``, seeds ``seed`` + i, episodes, records), whose sub-envs do not simulate: each
    ``reset`` / ``step`` first runs the physics of all K (one batched reset of the envs that start an
    episode, one batched step of those still running; a finished one is held), then lets
    ``SyncVectorEnv`` step the sub-envs, which take their row of that batch.
    """

    def __init__(self, env_fns: list, renderer: str = "auto", **kwargs: Any) -> None:
        super().__init__(env_fns, **kwargs)
        self.renderer = renderer
        self.vector: Any = None

    def _ensure_vector(self) -> None:
        if self.vector is not None:
            return
        from rsb_maniskill.vector import RSBVectorEnv

        first = self.envs[0]
        self.vector = RSBVectorEnv(first.env_id, self.num_envs, renderer=self.renderer, **first.make_kwargs())
        for i, env in enumerate(self.envs):
            env._env = _VectorRow(self.vector, i)

    def reset(self, *, seed: int | list | None = None, options: dict | None = None) -> tuple:
        from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
        from rsb_maniskill.vector.env import _row

        self._ensure_vector()
        if seed is None:
            seeds: list = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
        mask = (options or {}).get("reset_mask")  # gymnasium >= 1.1: reset only these
        idx = [i for i, env in enumerate(self.envs)
               if (mask is None or mask[i]) and not env.holds_on_reset(seeds[i])]
        physics = [EVAL_SEED_BASE + self.envs[i].next_episode(seeds[i]) for i in idx]
        if idx:
            obs, info = self.vector.reset(seed=physics, options={"env_idx": idx})
            for i, s in zip(idx, physics):
                self.envs[i]._env.pending = (s, (_row(obs, i), _row(info, i)))
        return super().reset(seed=seed, options=options)

    def step(self, actions: Any) -> tuple:
        from rsb_maniskill.vector.env import _row

        self._ensure_vector()
        a = np.asarray(actions, dtype=np.float32)
        if a.shape != (self.num_envs, ACTION_DIM):
            raise ValueError(f"{self.envs[0].env_id}: expected Aloha 14-number actions of shape "
                             f"({self.num_envs}, {ACTION_DIM}), got {a.shape}")
        obs, rew, term, trunc, info = self.vector.step(from_aloha14(a))
        for i, env in enumerate(self.envs):
            if env._last is None:
                env._env.pending = tuple(_row(x, i) for x in (obs, rew, term, trunc, info))
        out = super().step(actions)
        for i, env in enumerate(self.envs):
            env._env.pending = None
            if env._last is not None:
                self.vector.hold(i)
        return out

    def close_extras(self, **kwargs: Any) -> None:
        super().close_extras(**kwargs)
        if self.vector is not None:
            self.vector.close()
            self.vector = None


def make_env_fns(env_id: str, n_envs: int, **kwargs: Any) -> list:
    """``n_envs`` factories of :class:`RSBLeRobotEnv` for LeRobot's Sync / Async vector envs."""
    from functools import partial

    return [partial(RSBLeRobotEnv, env_id, **kwargs) for _ in range(n_envs)]


def use_vector_env(vector: bool | str = "auto", renderer: str = "auto") -> bool:
    """Whether ``n_envs`` run as one :class:`RSBLeRobotVectorEnv`: ``vector="auto"`` where it pays,
    i.e. where every camera of the envs renders in one call (CUDA rendering, ``renderer`` not
    ``per_scene``). Under lavapipe each scene renders its own either way and the batched
    observations cost more than they save (``benchmarks/lerobot_vector_env.py``)."""
    if vector != "auto":
        return bool(vector)
    if renderer == "per_scene":
        return False
    if renderer == "group":
        return True
    from rsb_maniskill.sim.camera_group import group_rendering_unavailable

    return group_rendering_unavailable() is None


def create_rsb_envs(task: str, n_envs: int, use_async_envs: bool = False, vector: bool | str = "auto",
                    renderer: str = "auto", **kwargs: Any) -> dict[str, dict[int, Any]]:
    """``{suite: {0: VectorEnv}}`` for the suites ``task`` names (ids, comma list, ``paper``, ...),
    as LeRobot's ``EnvConfig.create_envs`` returns them. Where CUDA renders (:func:`use_vector_env`)
    the ``n_envs`` run in this process as one :class:`RSBLeRobotVectorEnv` (one render call for all
    cameras); otherwise, with ``use_async_envs`` (one process per env) or ``vector=False``,
    gymnasium's Sync / Async vector env of one-env :class:`RSBLeRobotEnv` (each renders its own). The
    episodes, instructions, success and records are the same either way."""
    from functools import partial

    from rsb_maniskill.env_ids import resolve_env_ids

    if use_async_envs and n_envs > 1:
        env_cls: Any = gym.vector.AsyncVectorEnv
    elif use_vector_env(vector, renderer):
        env_cls = partial(RSBLeRobotVectorEnv, renderer=renderer)
    else:
        env_cls = gym.vector.SyncVectorEnv
    extra = {"context": "forkserver"} if env_cls is gym.vector.AsyncVectorEnv else {}
    out: dict[str, dict[int, Any]] = {}
    for env_id in resolve_env_ids(task):
        fns = make_env_fns(env_id, n_envs, **kwargs)
        try:
            from gymnasium.vector import AutoresetMode

            out[env_id] = {0: env_cls(fns, autoreset_mode=AutoresetMode.SAME_STEP, **extra)}
        except ImportError:  # gymnasium < 1.1
            out[env_id] = {0: env_cls(fns, **extra)}
    return out


def expected_features(naming: str = DEFAULT_NAMING, obs_type: str = "pixels_agent_pos",
                      camera_size: tuple[int, int] = CAMERA_SIZE) -> dict[str, tuple[int, ...]]:
    """The policy input features a policy must take (LeRobot keys -> shapes), for error messages."""
    w, h = camera_size
    out: dict[str, tuple[int, ...]] = {f"observation.images.{camera_key(c, naming)}": (3, h, w) for c in CAMERAS}
    if obs_type == "pixels_agent_pos":
        out["observation.state"] = (ACTION_DIM,)
    return out


def check_policy_features(policy_features: dict[str, tuple[int, ...]], naming: str = DEFAULT_NAMING,
                          obs_type: str = "pixels_agent_pos", camera_size: tuple[int, int] = CAMERA_SIZE) -> None:
    """Raises one ValueError naming the expected keys and shapes when a policy's observation inputs
    (LeRobot key -> shape; ``observation.*`` only) are not all given, in those shapes, by the env."""
    given = expected_features(naming, obs_type, camera_size)
    wanted = {k: tuple(v) for k, v in policy_features.items() if k.startswith("observation.")}
    bad = {k: v for k, v in wanted.items() if given.get(k) != v}
    if bad:
        show = lambda d: ", ".join(f"{k} {tuple(v)}" for k, v in d.items())  # noqa: E731
        raise ValueError(f"the policy takes {show(bad)}, which RSB (naming={naming}, obs_type={obs_type}, camera "
                         f"{camera_size[0]}x{camera_size[1]}) does not give; it gives {show(given)}: set "
                         "--env.naming / --env.obs_type / --env.camera_width / --env.camera_height as in the "
                         "policy's training data")
