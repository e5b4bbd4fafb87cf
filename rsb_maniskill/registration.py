"""The RSB env ids in gymnasium and ManiSkill: the only module that edits their registries.

``import rsb_maniskill`` registers each id (:mod:`env_ids`) with gymnasium as a lazy entry that
points at :func:`_make`: the robot and the tasks (torch, SAPIEN, ManiSkill) load at the first
``gym.make`` (or ``gym.make_vec``), so ``import rsb_maniskill``, its semantic engine and the ``rsb``
command line stay light. :func:`load_simulator` then registers the robot and the task classes with
ManiSkill, each under the ids it declares (``@env_ids.serves`` above the class), and ManiSkill's
``register_env`` replaces the lazy entries with its own.

The robot: ``import rsb_maniskill.agents`` registers ``aloha_agilex`` with ManiSkill; importing
``rsb_maniskill`` after ManiSkill does it too (ManiSkill is loaded already, so it costs nothing),
so ``gym.make("Empty-v1", robot_uids="aloha_agilex")`` works in either case.

The test-split aliases (``RSB-Math-4-Test``: ``split="test"`` by default, :data:`env_ids.TEST_ALIASES`)
are registered the same way, with the class of their suite.

Recorded trajectories name their env as ``"rsb_maniskill:RSB-Math-4"`` (see :mod:`tasks.base`):
gymnasium imports the module before looking the id up, so ManiSkill's ``replay_trajectory``
finds the env in a fresh process with nothing imported by hand.
"""
from __future__ import annotations

import sys
from functools import partial
from typing import Any, Sequence

import gymnasium as gym
from gymnasium.envs.registration import WrapperSpec

from rsb_maniskill.env_ids import ENVS, ENVS_AND_ALIASES, TEST_ALIASES

_LOADED = False


def load_simulator() -> None:
    """Registers the robot and every task class with ManiSkill (once per process)."""
    global _LOADED
    if _LOADED:
        return
    from mani_skill.utils.registration import register_env

    import rsb_maniskill.agents  # noqa: F401  (registers aloha_agilex)
    from rsb_maniskill.tasks import TASK_CLASSES

    classes = served_by(TASK_CLASSES)
    drop_lazy_entries()  # ManiSkill's register_env writes the gymnasium entries itself
    for uid, (steps, kwargs) in ENVS_AND_ALIASES.items():  # an alias with the class of its suite
        register_env(uid, max_episode_steps=steps, **kwargs)(classes[TEST_ALIASES.get(uid, uid)])
    _LOADED = True


def served_by(classes: Sequence[type]) -> dict[str, type]:
    """Each id of ``ENVS`` -> the one class of ``classes`` that declares it (``@env_ids.serves``);
    RuntimeError when an id has no class or two."""
    out: dict[str, type] = {}
    for cls in classes:
        for uid in cls.__dict__.get("ENV_IDS", ()):
            if uid in out:
                raise RuntimeError(f"{uid} is served by both {out[uid].__name__} and {cls.__name__}")
            out[uid] = cls
    missing = [uid for uid in ENVS if uid not in out]
    if missing:
        raise RuntimeError(f"no task class serves {', '.join(missing)}: add it to a class's @serves")
    return out


def register_agent_if_maniskill_loaded() -> None:
    """Registers ``aloha_agilex`` now when ManiSkill is already imported (it costs no import then)."""
    if "mani_skill.agents.registration" in sys.modules:
        import rsb_maniskill.agents  # noqa: F401


def drop_lazy_entries() -> None:
    """Removes the lazy gymnasium entries (ManiSkill's ``register_env`` is about to write its own)."""
    for uid in ENVS_AND_ALIASES:
        spec = gym.registry.get(uid)
        if spec is not None and isinstance(spec.entry_point, partial) and spec.entry_point.func is _make:
            del gym.registry[uid]


def _make(env_id: str, **kwargs: Any):
    load_simulator()
    from mani_skill.utils.registration import make

    return make(env_id, **kwargs)


def _make_vec(env_id: str, **kwargs: Any):
    load_simulator()
    from mani_skill.utils.registration import make_vec

    return make_vec(env_id, **kwargs)


def register_envs() -> None:
    """Registers every RSB id, the test-split aliases too, with gymnasium (ids already registered are
    left alone)."""
    for uid, (steps, defaults) in ENVS_AND_ALIASES.items():
        if uid in gym.registry:
            continue
        gym.register(uid, entry_point=partial(_make, env_id=uid), vector_entry_point=partial(_make_vec, env_id=uid),
                     max_episode_steps=steps, disable_env_checker=True, kwargs=dict(defaults),
                     additional_wrappers=[WrapperSpec("MSTimeLimit",
                                                      entry_point="mani_skill.utils.registration:TimeLimitWrapper",
                                                      kwargs=dict(max_episode_steps=steps))])
