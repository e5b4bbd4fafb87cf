"""The RSB env ids and their fixed numbers: ids, groups, step limits, frequencies (a leaf: no simulator).

Every module that needs one of these facts imports it from here: the registry entries
(``registration.py``), the tasks, the expert, the evaluator, the audit, the dataset builder and the
LeRobot env. :func:`resolve_env_ids` is the one reader of suite names on command lines (``paper``,
``all``, ``paper-objects``, ids). Nothing here imports torch, SAPIEN or ManiSkill.
"""
from __future__ import annotations

from typing import Any

from rsb_maniskill.objects.family import DEFAULT_TARGETS, FAMILIES, OBJECTS_SUFFIX, split_env_id
from rsb_maniskill.semantic.suites import SUITE_IDS

MODULE = "rsb_maniskill"
SIM_FREQ, CONTROL_FREQ = 125, 25  # Hz: 5 physics steps per action, as ManiSkill's tabletop tasks
TASK_MAX_EPISODE_STEPS = 300  # 12 s at 25 Hz; the expert needs about 7 s (see docs/tasks.md)
TABLETOP_ID = "RSB-TableTop-v1"
TABLETOP_MAX_EPISODE_STEPS = 500
OBJECT_ENV_IDS: tuple[str, ...] = tuple(sid + OBJECTS_SUFFIX for sid in SUITE_IDS)
# The six suites of the paper's tables ("Avg" is over these; the Direct suites are controls), and
# the same six with everyday objects (the paper's Beyond Blocks tables).
PAPER_SUITES: tuple[str, ...] = (
    "RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4", "RSB-HardMath-10", "RSB-General-4", "RSB-General-10",
)
PAPER_OBJECT_SUITES: tuple[str, ...] = tuple(s + OBJECTS_SUFFIX for s in PAPER_SUITES)
SUITE_GROUPS: dict[str, tuple[str, ...]] = {
    "paper": PAPER_SUITES, "all": SUITE_IDS, "paper-objects": PAPER_OBJECT_SUITES, "all-objects": OBJECT_ENV_IDS,
}
# answer-selection id -> default kwargs of its task class: every suite with every candidate family
# (the default family's ids carry no suffix and no ``targets``)
TASK_ENVS: dict[str, dict[str, Any]] = {
    sid + fam.suffix: {"suite_id": sid, **({} if fam.name == DEFAULT_TARGETS else {"targets": fam.name})}
    for fam in FAMILIES.values() for sid in SUITE_IDS
}
# every id -> (max_episode_steps, default kwargs), as registered with ManiSkill and gymnasium
ENVS: dict[str, tuple[int, dict[str, Any]]] = {
    **{uid: (TASK_MAX_EPISODE_STEPS, kwargs) for uid, kwargs in TASK_ENVS.items()},
    TABLETOP_ID: (TABLETOP_MAX_EPISODE_STEPS, {}),
}


def qualified_id(env_id: str) -> str:
    """``"RSB-Math-4"`` -> ``"rsb_maniskill:RSB-Math-4"`` (unchanged if already qualified)."""
    return env_id if ":" in env_id else f"{MODULE}:{env_id}"


def resolve_env_ids(names: str | list[str] | tuple[str, ...]) -> list[str]:
    """Suite env ids named by ids and groups (a list, or one comma-separated string), in order,
    each once: ``"paper"`` -> the six paper suites. ValueError names what is valid."""
    if isinstance(names, str):
        names = [n for n in names.split(",")]
    out: list[str] = []
    for name in (n.strip() for n in names):
        for eid in SUITE_GROUPS.get(name, (name.split(":", 1)[-1],)):
            if split_env_id(eid)[0] not in SUITE_IDS:
                sfx = " or ".join(repr(f.suffix) for f in FAMILIES.values() if f.suffix)
                raise ValueError(f"unknown suite {name!r}; valid: a suite id ({', '.join(SUITE_IDS)}), the same with "
                                 f"{sfx}, or a group ({', '.join(SUITE_GROUPS)})")
            if eid not in out:
                out.append(eid)
    return out
