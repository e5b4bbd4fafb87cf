"""Blocks as answer targets: four coloured cubes (4-choice) or ten lettered cubes (10-choice)."""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import sapien
import torch

from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs.actor import Actor

from rsb_maniskill.objects.textures import letter_texture

BLOCK_HALF = 0.02  # 4 cm cubes
BLOCK_DENSITY = 500.0  # wood: 32 g a block
BLOCK_COLORS = {  # RGB of the 4-choice blocks, in block-index order
    "red": (0.85, 0.12, 0.10),
    "green": (0.10, 0.65, 0.20),
    "blue": (0.12, 0.30, 0.85),
    "yellow": (0.95, 0.82, 0.10),
}
LETTER_BLOCK_RGB = (0.93, 0.86, 0.68)  # one light colour for all ten, so colour can't help
LETTER_PLATE_Q = [0.7071068, 0.0, -0.7071068, 0.0]
LETTERS_10 = ("A", "B", "C", "D", "E", "F", "G", "H", "I", "K")


@lru_cache(maxsize=None)
def _letter_render_texture(letter: str) -> sapien.render.RenderTexture2D:
    """One GPU texture per letter and process, shared by every env (the process holds its
    render engine, see _render.py, so the texture stays valid)."""
    # The plane's UVs show the texture transposed and turned half a turn when seen from the
    # robot; undo both so the letter reads upright in the head camera.
    tex = letter_texture(letter, LETTER_BLOCK_RGB)
    tex = np.ascontiguousarray(np.transpose(tex[::-1, ::-1], (1, 0, 2)))
    return sapien.render.RenderTexture2D(tex, "R8G8B8A8Unorm", mipmap_levels=4, srgb=True)


class Blocks:
    """N cubes with identical geometry; identity shows as colour (N = 4) or a letter (N = 10)."""

    def __init__(self, n: int, num_envs: int, device: torch.device | str = "cpu"):
        if n not in (4, 10):
            raise ValueError(f"blocks come in sets of 4 (coloured) or 10 (lettered), not {n}")
        self.n, self.num_envs, self.device = n, num_envs, device

    def names(self) -> tuple[str, ...]:
        if self.n == 4:
            return tuple(f"{c} block" for c in BLOCK_COLORS)
        return tuple(f"block {l}" for l in LETTERS_10)

    def _body_material(self, i: int) -> sapien.render.RenderMaterial:
        rgb = list(BLOCK_COLORS.values())[i] if self.n == 4 else LETTER_BLOCK_RGB
        return sapien.render.RenderMaterial(base_color=[*rgb, 1.0], roughness=0.6, specular=0.3)

    def _letter_material(self, i: int) -> sapien.render.RenderMaterial:
        mat = sapien.render.RenderMaterial(base_color=[1.0, 1.0, 1.0, 1.0], roughness=0.7, specular=0.2)
        mat.base_color_texture = _letter_render_texture(LETTERS_10[i])
        return mat

    def build(self, scene: ManiSkillScene) -> list[Actor]:
        actors = []
        half = [BLOCK_HALF] * 3
        for i in range(self.n):
            builder = scene.create_actor_builder()
            builder.add_box_collision(half_size=half, density=BLOCK_DENSITY)
            builder.add_box_visual(half_size=half, material=self._body_material(i))
            if self.n == 10:
                # The letter is a textured plane on the top face only (box UVs split the
                # texture across faces); the plane's normal is turned from +x to +z.
                builder.add_plane_visual(sapien.Pose(p=[0, 0, BLOCK_HALF + 2e-4], q=LETTER_PLATE_Q),
                                         scale=[1.0, BLOCK_HALF * 0.95, BLOCK_HALF * 0.95],
                                         material=self._letter_material(i))
            builder.initial_pose = sapien.Pose(p=[0.3, 0.1 * i - 0.45, BLOCK_HALF])
            actors.append(builder.build(name=f"block_{i}"))
        return actors

    def _full(self, value: float) -> torch.Tensor:
        return torch.full((self.num_envs, self.n), value, device=self.device)

    def rest_height(self) -> torch.Tensor:
        return self._full(BLOCK_HALF)

    def footprint_radius(self) -> torch.Tensor:
        return self._full(BLOCK_HALF * np.sqrt(2))

    def grasp_width(self) -> torch.Tensor:
        return self._full(2 * BLOCK_HALF)
