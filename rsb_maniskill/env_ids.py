"""The RSB env ids and their fixed numbers: ids, groups, step limits, frequencies (no simulator).

Every module that needs one of these facts imports it from here: the registry entries
(``registration.py``), the tasks, the expert, the evaluator, the audit, the dataset builder and the
LeRobot env. :func:`resolve_env_ids` is the one reader of suite names (ids, groups such as
``paper``, the paper release's task names), and :func:`add_suites_argument` the one way a command
takes a list of them. Nothing here imports torch, SAPIEN or ManiSkill. Not a leaf: the ids are the
suites of ``semantic/suites.py`` times the candidate families of ``objects/family.py``, so this module
sits on the floor just above those two, and every floor from the simulator's plumbing (``sim/``) up
may import it.
"""
from __future__ import annotations

import argparse
from typing import Any, Callable, Sequence

from rsb_maniskill.objects.family import DEFAULT_TARGETS, FAMILIES, OBJECTS_SUFFIX, split_env_id
from rsb_maniskill.semantic.suites import SUITE_IDS

MODULE = "rsb_maniskill"
SIM_FREQ, CONTROL_FREQ = 125, 25  # Hz: 5 physics steps per action, as ManiSkill's tabletop tasks
# ManiSkill's sim_backend names of the two ways RSB runs: one env a process on the CPU (the expert's
# demos, the golden digests, rendering demos) or parallel envs on the GPU. Here, beside the
# frequencies, which every floor from sim/ up reads; sim/physx_gpu.py only reads a backend's name.
CPU_SIM_BACKEND, GPU_SIM_BACKEND = "physx_cpu", "physx_cuda"
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
# The task names of the paper's own release (a RoboTwin 2.0 fork) name the same suites here; the
# episodes are this pack's (questions, seeds, layout), not the release's.
RELEASE_TASK_NAMES: dict[str, str] = {
    "rsb_math": "RSB-Math-4", "rsb_math_10blocks": "RSB-Math-10",
    "rsb_hardmath": "RSB-HardMath-4", "rsb_hardmath_10blocks": "RSB-HardMath-10",
    "rsb_general": "RSB-General-4", "rsb_general_10blocks": "RSB-General-10",
}
# answer-selection id -> default kwargs of its task class: every suite with every candidate family
# (the default family's ids carry no suffix and no ``targets``)
TASK_ENVS: dict[str, dict[str, Any]] = {
    sid + fam.suffix: {"suite_id": sid, **({} if fam.name == DEFAULT_TARGETS else {"targets": fam.name})}
    for fam in FAMILIES.values() for sid in SUITE_IDS
}
# every env of the pack (the suites, the table) -> (max_episode_steps, default kwargs), as registered
# with ManiSkill and gymnasium
ENVS: dict[str, tuple[int, dict[str, Any]]] = {
    **{uid: (TASK_MAX_EPISODE_STEPS, kwargs) for uid, kwargs in TASK_ENVS.items()},
    TABLETOP_ID: (TABLETOP_MAX_EPISODE_STEPS, {}),
}
# The test-split aliases: "RSB-Direct-4-Test" is RSB-Direct-4 with ``split="test"`` as its default, for
# scripts that name an env id but pass gym.make no keywords (ManiSkill's baselines: ``--env-id``).
# gym.make("RSB-Direct-4-Test") and gym.make("RSB-Direct-4", split="test") give the same episode for
# a seed. Aliases, not suites: they are registered (ENVS_AND_ALIASES) but are not in ENVS, the groups
# or what resolve_env_ids accepts, so nothing that lists the suites lists them twice.
TEST_SUFFIX = "-Test"
TEST_ALIASES: dict[str, str] = {uid + TEST_SUFFIX: uid for uid in TASK_ENVS}  # alias -> suite env id
# every id gymnasium and ManiSkill know from the pack -> (max_episode_steps, default kwargs)
ENVS_AND_ALIASES: dict[str, tuple[int, dict[str, Any]]] = {
    **ENVS,
    **{alias: (ENVS[uid][0], {**ENVS[uid][1], "split": "test"}) for alias, uid in TEST_ALIASES.items()},
}


def serves(*env_ids: str) -> Callable[[type], type]:
    """Class decorator: the ids of :data:`ENVS` a task class serves, read above the class as
    ManiSkill's ``@register_env``. It only records them (``cls.ENV_IDS``); ``registration.py``
    registers each id with the class that declares it. ValueError for an id not in ``ENVS``."""
    unknown = [e for e in env_ids if e not in ENVS]
    if unknown or not env_ids:
        raise ValueError(f"@serves takes ids of env_ids.ENVS, got {', '.join(unknown) or 'none'}")

    def declare(cls: type) -> type:
        cls.ENV_IDS = tuple(env_ids)
        return cls

    return declare


def qualified_id(env_id: str) -> str:
    """``"RSB-Math-4"`` -> ``"rsb_maniskill:RSB-Math-4"`` (unchanged if already qualified)."""
    return env_id if ":" in env_id else f"{MODULE}:{env_id}"


def resolve_env_ids(names: str | Sequence[str]) -> list[str]:
    """Suite env ids named by ids, groups and the paper release's task names, in order, each once:
    ``"paper"`` -> the six paper suites, ``"rsb_math_10blocks"`` -> ``"RSB-Math-10"``. ``names`` is
    a list whose items may hold several names separated by commas (``["RSB-Math-4,RSB-Math-10"]``),
    or one such string. ValueError names what is valid."""
    out: list[str] = []
    for name in (n.strip() for item in ([names] if isinstance(names, str) else names) for n in item.split(",")):
        if not name:
            continue
        name = RELEASE_TASK_NAMES.get(name, name)
        alias_of = TEST_ALIASES.get(name.split(":", 1)[-1])
        if alias_of:
            raise ValueError(f"{name} is the test-split alias of {alias_of} for gym.make (scripts that pass no "
                             f"keywords), not a suite; name the suite, {alias_of} (rsb eval always runs the test "
                             "split; rsb generate and rsb audit take --split test)")
        for eid in SUITE_GROUPS.get(name, (name.split(":", 1)[-1],)):
            if split_env_id(eid)[0] not in SUITE_IDS:
                sfx = " or ".join(repr(f.suffix) for f in FAMILIES.values() if f.suffix)
                raise ValueError(f"unknown suite {name!r}; valid: a suite id ({', '.join(SUITE_IDS)}), the same with "
                                 f"{sfx}, a group ({', '.join(SUITE_GROUPS)}) or a task name of the paper's release "
                                 f"({', '.join(RELEASE_TASK_NAMES)})")
            if eid not in out:
                out.append(eid)
    return out


SUITES_HELP = ("suite ids (RSB-Math-4, RSB-Math-4-Objects, ...), groups (paper: the six of the paper; all: with the "
               "Direct controls; paper-objects, all-objects: the same with everyday objects) or the paper release's "
               "task names (rsb_math, rsb_math_10blocks, ...); separated by spaces or commas")


class _SuitesAction(argparse.Action):
    """Resolves the names as they are parsed: a bad one is one line naming the valid ones (exit 2)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        if option_string is None and values is self.default:  # an empty positional: keep what --suites set
            return
        try:
            suites = resolve_env_ids(values)
        except ValueError as err:
            parser.exit(2, f"{parser.prog}: error: {err}\n")
        if values and not suites:  # e.g. --suites "": something was given, and it names nothing
            given = " ".join(repr(v) for v in values)
            parser.exit(2, f"{parser.prog}: error: {option_string or 'SUITE'} {given} names no suite; give a suite id "
                           f"(e.g. RSB-Math-4) or a group ({', '.join(SUITE_GROUPS)})\n")
        setattr(namespace, self.dest, suites)


def add_suites_argument(parser: argparse.ArgumentParser, default: Sequence[str] = ("paper",),
                        positional: bool = False, help: str | None = None) -> None:
    """The one way a command takes suites: ``--suites``, and where ``positional`` a ``SUITE ...`` list
    too (either spelling), names separated by spaces or commas; ``args.suites`` holds the resolved env
    ids (``default``, resolved, when none is given). The help names the default and how many suites it
    is: it decides the size of a run."""
    suites = resolve_env_ids(default)
    said = f" (default: {' '.join(default)}: {len(suites)} suite{'s' if len(suites) != 1 else ''})" if suites else ""
    kwargs: dict[str, Any] = dict(nargs="*" if positional else "+", action=_SuitesAction, metavar="SUITE",
                                  default=suites, help=(help or SUITES_HELP) + said)
    if positional:
        parser.add_argument("suites", **kwargs)
        kwargs.update(nargs="+", help="the same as SUITE ...", default=argparse.SUPPRESS)
    parser.add_argument("--suites", **kwargs)
