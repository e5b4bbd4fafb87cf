"""The RSB env ids in gymnasium, registered at ``import rsb_maniskill`` without the simulator.

Each id points at :func:`_make`, which imports the robot and the tasks (torch, SAPIEN, ManiSkill)
at the first ``gym.make`` and hands over to ManiSkill's own ``make``. So ``import rsb_maniskill``,
its semantic engine and the ``rsb`` command line stay light, and ``gym.make("RSB-Math-4")`` works
as before. The lazy entries mirror what ManiSkill's ``register_env`` writes (time limit,
wrapper, default kwargs); importing :mod:`rsb_maniskill.tasks` replaces them with ManiSkill's own.

Recorded trajectories name their env as ``"rsb_maniskill:RSB-Math-4"`` (see :mod:`tasks.base`):
gymnasium imports the module before looking the id up, so ManiSkill's ``replay_trajectory``
finds the env in a fresh process with nothing imported by hand.
"""
from __future__ import annotations

from functools import partial
from typing import Any

import gymnasium as gym
from gymnasium.envs.registration import WrapperSpec

from rsb_maniskill.objects.family import OBJECTS_SUFFIX
from rsb_maniskill.semantic.suites import SUITE_IDS

MODULE = "rsb_maniskill"
TASK_MAX_EPISODE_STEPS = 300  # 12 s at 25 Hz; the expert needs about 7 s (see docs/tasks.md)
TABLETOP_ID = "RSB-TableTop-v1"
TABLETOP_MAX_EPISODE_STEPS = 500
OBJECT_ENV_IDS: tuple[str, ...] = tuple(sid + OBJECTS_SUFFIX for sid in SUITE_IDS)
# id -> (max_episode_steps, default kwargs), as the tasks register themselves with ManiSkill
ENVS: dict[str, tuple[int, dict[str, Any]]] = {
    **{sid: (TASK_MAX_EPISODE_STEPS, {"suite_id": sid}) for sid in SUITE_IDS},
    **{eid: (TASK_MAX_EPISODE_STEPS, {"suite_id": eid[:-len(OBJECTS_SUFFIX)], "targets": "objects"})
       for eid in OBJECT_ENV_IDS},
    TABLETOP_ID: (TABLETOP_MAX_EPISODE_STEPS, {}),
}


def qualified_id(env_id: str) -> str:
    """``"RSB-Math-4"`` -> ``"rsb_maniskill:RSB-Math-4"`` (unchanged if already qualified)."""
    return env_id if ":" in env_id else f"{MODULE}:{env_id}"


def load_simulator() -> None:
    """Imports the robot and the tasks: ManiSkill's registration replaces the lazy entries."""
    import rsb_maniskill.agents  # noqa: F401
    import rsb_maniskill.tasks  # noqa: F401


def drop_lazy_entries() -> None:
    """Removes the lazy gymnasium entries (ManiSkill's ``register_env`` is about to write its own)."""
    for uid in ENVS:
        spec = gym.registry.get(uid)
        if spec is not None and isinstance(spec.entry_point, partial) and spec.entry_point.func is _make:
            del gym.registry[uid]


def _make(env_id: str, **kwargs: Any):
    load_simulator()
    from mani_skill.utils.registration import make

    return make(env_id, **kwargs)


def register_envs() -> None:
    """Registers every RSB id with gymnasium (ids already registered are left alone)."""
    for uid, (steps, defaults) in ENVS.items():
        if uid in gym.registry:
            continue
        gym.register(uid, entry_point=partial(_make, env_id=uid), max_episode_steps=steps,
                     disable_env_checker=True, kwargs=dict(defaults),
                     additional_wrappers=[WrapperSpec("MSTimeLimit",
                                                      entry_point="mani_skill.utils.registration:TimeLimitWrapper",
                                                      kwargs=dict(max_episode_steps=steps))])
