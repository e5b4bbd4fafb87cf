"""Everyday-object actors from the catalog's convex parts (SAPIEN primitives; hulls from cached files)."""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np
import sapien

from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs.actor import Actor

from rsb_maniskill.objects.catalog import model
from rsb_maniskill.objects.geometry import ObjectModel, Part

FRICTION = 1.0  # rubber-ish against the fingers' 2.0: held objects do not slip


def mesh_cache_dir() -> Path:
    """Where hull meshes are written: ``$RSB_CACHE_DIR/meshes``, else ``~/.cache/rsb_maniskill/meshes``."""
    root = os.environ.get("RSB_CACHE_DIR") or Path.home() / ".cache" / "rsb_maniskill"
    return Path(root) / "meshes"


def hull_file(points: np.ndarray) -> str:
    """An .obj of the convex hull of ``points``, written once and named by the points' hash.

    Written to a temporary name and renamed, so parallel workers never read a partial file."""
    import trimesh  # only needed the first time a hull is built in this cache

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    digest = hashlib.sha1(np.round(pts, 6).tobytes()).hexdigest()[:16]
    path = mesh_cache_dir() / f"hull_{digest}.obj"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(trimesh.convex.convex_hull(pts).export(file_type="obj"))
        os.replace(tmp, path)
    return str(path)


def _material(rgb) -> sapien.render.RenderMaterial:
    return sapien.render.RenderMaterial(base_color=[*rgb, 1.0], roughness=0.6, specular=0.25)


def _add_part(builder, p: Part, density: float, physx_mat) -> None:
    pose = sapien.Pose(p=list(p.pos), q=list(p.quat))
    mat = _material(p.rgb)
    if p.shape == "hull":
        f = hull_file(np.asarray(p.dims))
        if p.collide:
            builder.add_convex_collision_from_file(f, pose, material=physx_mat, density=density)
        if p.visible:
            builder.add_visual_from_file(f, pose, material=mat)
        return
    add_col = getattr(builder, f"add_{p.shape}_collision")
    add_vis = getattr(builder, f"add_{p.shape}_visual")
    if p.shape == "box":
        args = dict(half_size=list(p.dims))
    elif p.shape == "sphere":
        args = dict(radius=p.dims[0])
    else:  # cylinder, capsule: along the part's x axis
        args = dict(radius=p.dims[0], half_length=p.dims[1])
    if p.collide:
        add_col(pose, **args, material=physx_mat, density=density)
    if p.visible:
        add_vis(pose, **args, material=mat)


def build_object(scene: ManiSkillScene, key: str, name: str, initial_pose: sapien.Pose,
                 scene_idxs: list[int] | None = None) -> Actor:
    """The catalog model ``key`` ("mug:1"): one merged actor, the same object in every env (or in
    the envs ``scene_idxs``, with materials of their own)."""
    m: ObjectModel = model(key)
    physx_mat = sapien.physx.PhysxMaterial(FRICTION, FRICTION, 0.0)
    builder = scene.create_actor_builder()
    for p in m.parts:
        _add_part(builder, p, m.density, physx_mat)
    builder.initial_pose = initial_pose
    if scene_idxs is not None:
        builder.set_scene_idxs(scene_idxs)
    return builder.build(name=name)
