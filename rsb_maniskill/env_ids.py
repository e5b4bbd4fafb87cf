"""The RSB env ids and their fixed numbers: ids, step limits, frequencies (a leaf: no simulator).

Every module that needs one of these facts imports it from here: the registry entries
(``registration.py``), the tasks, the expert, the evaluator and the exporters. Nothing here imports
torch, SAPIEN or ManiSkill.
"""
from __future__ import annotations

from typing import Any

from rsb_maniskill.objects.family import OBJECTS_SUFFIX
from rsb_maniskill.semantic.suites import SUITE_IDS

MODULE = "rsb_maniskill"
SIM_FREQ, CONTROL_FREQ = 125, 25  # Hz: 5 physics steps per action, as ManiSkill's tabletop tasks
TASK_MAX_EPISODE_STEPS = 300  # 12 s at 25 Hz; the expert needs about 7 s (see docs/tasks.md)
TABLETOP_ID = "RSB-TableTop-v1"
TABLETOP_MAX_EPISODE_STEPS = 500
OBJECT_ENV_IDS: tuple[str, ...] = tuple(sid + OBJECTS_SUFFIX for sid in SUITE_IDS)
# answer-selection id -> default kwargs of its task class
TASK_ENVS: dict[str, dict[str, Any]] = {
    **{sid: {"suite_id": sid} for sid in SUITE_IDS},
    **{eid: {"suite_id": eid[: -len(OBJECTS_SUFFIX)], "targets": "objects"} for eid in OBJECT_ENV_IDS},
}
# every id -> (max_episode_steps, default kwargs), as registered with ManiSkill and gymnasium
ENVS: dict[str, tuple[int, dict[str, Any]]] = {
    **{uid: (TASK_MAX_EPISODE_STEPS, kwargs) for uid, kwargs in TASK_ENVS.items()},
    TABLETOP_ID: (TABLETOP_MAX_EPISODE_STEPS, {}),
}


def qualified_id(env_id: str) -> str:
    """``"RSB-Math-4"`` -> ``"rsb_maniskill:RSB-Math-4"`` (unchanged if already qualified)."""
    return env_id if ":" in env_id else f"{MODULE}:{env_id}"
