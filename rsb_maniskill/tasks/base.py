"""What every RSB env does besides ManiSkill's BaseEnv: check the GPU physics library and hold
the process's render engine before building (both because of how SAPIEN behaves on GPU machines,
docs/gpu.md), keep scene rebuilds cheap, and name itself by a module-qualified id in its spec
(env_ids.py)."""
from __future__ import annotations

import dataclasses
import gc

from gymnasium.envs.registration import EnvSpec

from mani_skill.envs.sapien_env import BaseEnv

from rsb_maniskill import compat
from rsb_maniskill.env_ids import qualified_id
from rsb_maniskill.sim import render
from rsb_maniskill.sim.physx_gpu import check_for_sim_backend

_HEAP_FROZEN = False  # once a process


def freeze_import_heap() -> None:
    """Leave the objects alive before the first scene (the imports: torch, ManiSkill, SAPIEN, the
    question pools; ~300k) out of garbage collection, once a process.

    On the CPU backend every reset builds a fresh scene (tasks/answer_selection.py), and ManiSkill
    runs a full ``gc.collect()`` before each build; scanning those objects cost ~190 ms a reset
    (RSB-Math-4, state, 2 cores), frozen ~1 ms (``benchmarks/task_speed.py``). What is built later,
    the scenes included, is collected as usual."""
    global _HEAP_FROZEN
    if not _HEAP_FROZEN:
        gc.collect()  # nothing that is already garbage gets frozen
        gc.freeze()
        _HEAP_FROZEN = True


class RSBEnv(BaseEnv):
    """Base of the RSB envs (``RSB-TableTop-v1`` and the answer-selection tasks)."""

    @property
    def spec(self) -> EnvSpec | None:
        return self.__dict__.get("_rsb_spec")

    @spec.setter
    def spec(self, value: EnvSpec | None) -> None:
        # gymnasium sets the spec after make; RecordEpisode writes spec.id into every trajectory
        # file: "rsb_maniskill:RSB-Math-4" lets ManiSkill's replay tool find the env by itself.
        if value is not None:
            value = dataclasses.replace(value, id=qualified_id(value.id))
        self.__dict__["_rsb_spec"] = value

    def __init__(self, *args, **kwargs):
        # SAPIEN would fetch the PhysX GPU library here with no timeout; fail clearly instead.
        check_for_sim_backend(kwargs.get("sim_backend", "auto"), kwargs.get("num_envs", 1))
        super().__init__(*args, **kwargs)

    def _setup_scene(self):
        freeze_import_heap()  # before the first scene's objects exist: they are collected at the next rebuild
        render.hold_render_engine(compat.render_device(self))  # before the first render object of the scene
        super()._setup_scene()
