"""What every RSB env does besides ManiSkill's BaseEnv: check the GPU physics library and hold
the process's render engine before building (both because of how SAPIEN behaves on GPU machines,
docs/gpu.md), and name itself by a module-qualified id in its spec (env_ids.py)."""
from __future__ import annotations

import dataclasses

from gymnasium.envs.registration import EnvSpec

from mani_skill.envs.sapien_env import BaseEnv

from rsb_maniskill import _render, compat
from rsb_maniskill.env_ids import qualified_id
from rsb_maniskill.physx_gpu import check_for_sim_backend


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
        _render.hold_render_engine(compat.render_device(self))  # before the first render object of the scene
        super()._setup_scene()
