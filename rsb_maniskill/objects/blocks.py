"""Block actors: a coloured cube (4-choice) or a light cube carrying its letter on top (10-choice)."""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import sapien

from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs.actor import Actor

from rsb_maniskill.objects.family import BLOCK_COLORS, BLOCK_HALF
from rsb_maniskill.objects.textures import STROKE, letter_texture

BLOCK_DENSITY = 500.0  # wood: 32 g a block
LETTER_BLOCK_RGB = (0.93, 0.86, 0.68)  # one light colour for all ten, so colour can't help
LETTER_PLATE_Q = [0.7071068, 0.0, -0.7071068, 0.0]


@lru_cache(maxsize=None)
def letter_render_texture(letter: str, stroke: int = STROKE) -> sapien.render.RenderTexture2D:
    """One GPU texture per letter (and stroke width) and process, shared by every env (the process
    holds its render engine, see sim/render.py, so the texture stays valid)."""
    # The plane's UVs show the texture transposed and turned half a turn when seen from the
    # robot; undo both so the letter reads upright in the head camera.
    tex = letter_texture(letter, LETTER_BLOCK_RGB, stroke=stroke)
    tex = np.ascontiguousarray(np.transpose(tex[::-1, ::-1], (1, 0, 2)))
    return sapien.render.RenderTexture2D(tex, "R8G8B8A8Unorm", mipmap_levels=4, srgb=True)


def build_block(scene: ManiSkillScene, key: str, name: str, initial_pose: sapien.Pose,
                scene_idxs: list[int] | None = None) -> Actor:
    """``block:<colour>`` or ``block:<letter>``: one merged actor, the same block in every env
    (or in the envs ``scene_idxs``, with materials of their own)."""
    label = key.split(":", 1)[1]
    half = [BLOCK_HALF] * 3
    rgb = BLOCK_COLORS.get(label, LETTER_BLOCK_RGB)
    builder = scene.create_actor_builder()
    builder.add_box_collision(half_size=half, density=BLOCK_DENSITY)
    builder.add_box_visual(half_size=half, material=sapien.render.RenderMaterial(
        base_color=[*rgb, 1.0], roughness=0.6, specular=0.3))
    if label not in BLOCK_COLORS:
        # The letter is a textured plane on the top face only (box UVs split the texture across
        # faces); the plane's normal is turned from +x to +z.
        mat = sapien.render.RenderMaterial(base_color=[1.0, 1.0, 1.0, 1.0], roughness=0.7, specular=0.2)
        mat.base_color_texture = letter_render_texture(label)
        builder.add_plane_visual(sapien.Pose(p=[0, 0, BLOCK_HALF + 2e-4], q=LETTER_PLATE_Q),
                                 scale=[1.0, BLOCK_HALF * 0.95, BLOCK_HALF * 0.95], material=mat)
    builder.initial_pose = initial_pose
    if scene_idxs is not None:
        builder.set_scene_idxs(scene_idxs)
    return builder.build(name=name)
