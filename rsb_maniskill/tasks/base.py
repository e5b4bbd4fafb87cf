"""What every RSB env does before ManiSkill builds it: check the GPU physics library, hold the
process's render engine. Both exist because of how SAPIEN behaves on GPU machines (docs/gpu.md)."""
from __future__ import annotations

from mani_skill.envs.sapien_env import BaseEnv

from rsb_maniskill import _render
from rsb_maniskill.physx_gpu import check_for_sim_backend


class RSBEnv(BaseEnv):
    """Base of the RSB envs (``RSB-TableTop-v1`` and the answer-selection tasks)."""

    def __init__(self, *args, **kwargs):
        # SAPIEN would fetch the PhysX GPU library here with no timeout; fail clearly instead.
        check_for_sim_backend(kwargs.get("sim_backend", "auto"), kwargs.get("num_envs", 1))
        super().__init__(*args, **kwargs)

    def _setup_scene(self):
        _render.hold_render_engine(self._render_device)  # before the first render object of the scene
        super()._setup_scene()
