"""Every camera of K CPU-physics scenes in one render call: SAPIEN's ``RenderSystemGroup``.

ManiSkill batches rendering only for GPU physics (``mani_skill/envs/scene.py``,
``_sapien_setup_gpu_rendering`` and ``_sapien_gpu_setup_sensors``), where the render shapes read their
poses from PhysX's CUDA body buffer. Here the K scenes are separate CPU-physics scenes (one RSB env
each, ``rsb_maniskill.vector``), so the buffer is ours: a CUDA float32 tensor of rows of
:data:`POSE_COLUMNS` floats (pose p xyz in columns 0-2, q wxyz in 3-6, the rest unused by
rendering), filled from the bodies' CPU poses before each render. Each render shape of a rigid body
reads its body's row (``set_gpu_pose_batch_index``); static bodies get no row and keep their pose;
each camera reads the row of the entity it is mounted on (the Aloha's camera links have no render
body: their rows are added here). One camera group per camera name holds that camera of all K
scenes, in env order. Measured on an H100 (docs/gpu.md): 3.3 ms per batch at K = 4 against 27.4 ms
for the scenes' own renders, the same pixels.

This module is the home of SAPIEN's rendering internals beside ``compat.py`` (which keeps the
private ManiSkill attributes it reads: ``compat.render_cameras``, ``compat.hidden_objects``,
``compat.needed_textures``, and the observation of K envs from the pictures, ``compat.batched_obs``).
CUDA rendering only: lavapipe has no CUDA interop, so
:func:`group_rendering_unavailable` says why not, and the vector env renders scene by scene there.
The row mapping and the buffer filling are plain functions over SAPIEN-shaped objects, tested with
fakes on machines without CUDA.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from rsb_maniskill import compat

POSE_COLUMNS = 13  # SAPIEN's GPU rigid-body row: pose (p, q wxyz) in columns 0-6, velocities after (unused)


def group_rendering_unavailable() -> str | None:
    """Why this process cannot render a group of scenes in one call, or None when it can: it needs
    a CUDA device (the pose buffer and the pictures are CUDA memory) and a GPU Vulkan driver."""
    import torch

    from rsb_maniskill.sim.render import software_rendering

    if not torch.cuda.is_available():
        return "batched rendering (sapien.render.RenderSystemGroup) needs a CUDA device, and torch sees none"
    if software_rendering():
        return "batched rendering needs a GPU Vulkan driver; this process renders with Mesa lavapipe (CPU)"
    return None


@dataclass
class PoseRows:
    """Which entity's pose fills each row of the buffer, and which row each render shape and camera reads."""

    entities: list[Any] = field(default_factory=list)  # row r is filled from entities[r].pose
    shapes: list[tuple[Any, int]] = field(default_factory=list)  # (render shape, row)
    cameras: dict[str, list[tuple[Any, int]]] = field(default_factory=dict)  # camera name -> [(camera, row)], env order

    def apply(self) -> None:
        """Point every render shape and camera at its row (``set_gpu_pose_batch_index``)."""
        for shape, row in self.shapes:
            shape.set_gpu_pose_batch_index(row)
        for cams in self.cameras.values():
            for camera, row in cams:
                camera.set_gpu_pose_batch_index(row)


def assign_rows(render_systems: Sequence[Any], cameras: Sequence[Mapping[str, Sequence[Any]]],
                rigid_body_type: Any = None) -> PoseRows:
    """The rows of K scenes: one per rigid body that has render shapes (all its shapes read it), one
    per entity a camera is mounted on (shared with its body's row when it has one).

    ``render_systems[k]`` is scene k's ``sapien.render.RenderSystem``; ``cameras[k]`` maps each camera
    name to its SAPIEN camera components in scene k. ``rigid_body_type`` is
    ``sapien.physx.PhysxRigidBodyComponent`` (links and dynamic actors; a static actor's
    ``PhysxRigidStaticComponent`` is not one, so static bodies get no row)."""
    if rigid_body_type is None:
        import sapien

        rigid_body_type = sapien.physx.PhysxRigidBodyComponent
    rows = PoseRows()
    index: dict[tuple[int, int], int] = {}

    def row(k: int, entity: Any) -> int:
        key = (k, int(entity.per_scene_id))
        if key not in index:
            index[key] = len(rows.entities)
            rows.entities.append(entity)
        return index[key]

    for k, system in enumerate(render_systems):
        for body in system.render_bodies:
            if body.entity.find_component_by_type(rigid_body_type) is None:
                continue
            r = row(k, body.entity)
            rows.shapes.extend((shape, r) for shape in body.render_shapes)
    for k, named in enumerate(cameras):
        for name, comps in named.items():
            rows.cameras.setdefault(name, []).extend((c, row(k, c.entity)) for c in comps)
    counts = {name: len(cams) for name, cams in rows.cameras.items()}
    if len(set(counts.values())) > 1:
        raise ValueError(f"the scenes have different cameras ({counts}): a camera group needs one camera a scene")
    return rows


def fill_poses(entities: Sequence[Any], host: np.ndarray) -> np.ndarray:
    """``host[r, :7]`` = the pose (p, q wxyz) of ``entities[r]``, read now from the CPU scenes."""
    for r, entity in enumerate(entities):
        pose = entity.pose
        host[r, :3] = pose.p
        host[r, 3:7] = pose.q
    return host


def scene_cameras(base: Any) -> tuple[dict[str, list[Any]], dict[str, list[str]]]:
    """An env's cameras (name -> its SAPIEN camera components) and the textures each one's shader
    writes (``Color``, ``PositionSegmentation``, ...), from ManiSkill's sensors."""
    from mani_skill.sensors.camera import Camera

    cams, textures = {}, {}
    for name, sensor in base.scene.sensors.items():
        if isinstance(sensor, Camera):
            cams[name] = list(compat.render_cameras(sensor.camera))
            textures[name] = list(sensor.config.shader_config.texture_names.keys())
    return cams, textures


class CameraGroup:
    """One ``RenderSystemGroup`` over the scenes of K one-env ManiSkill envs (``bases``, each
    ``env.unwrapped``), and one camera group per camera name. Build it again after any of the scenes
    is rebuilt (a CPU reset makes a fresh scene: its render system is new).

    ``group_factory`` and ``cuda_array`` are SAPIEN's ``RenderSystemGroup`` and
    ``pysapien.CudaArray``; ``device`` where the pose buffer lives (tests pass fakes and "cpu")."""

    def __init__(self, bases: Sequence[Any], *, device: Any = "cuda", group_factory: Callable | None = None,
                 cuda_array: Callable | None = None) -> None:
        import torch

        if group_factory is None or cuda_array is None:
            import sapien

            group_factory = group_factory or sapien.render.RenderSystemGroup
            cuda_array = cuda_array or sapien.pysapien.CudaArray
        t0 = time.perf_counter()
        self.bases = list(bases)
        systems = [b.scene.sub_scenes[0].render_system for b in self.bases]
        per_env = [scene_cameras(b) for b in self.bases]
        self.textures = compat.needed_textures(self.bases[0])  # rgb: Color only, not PositionSegmentation
        self.rows = assign_rows(systems, [cams for cams, _ in per_env])
        self.rows.apply()
        self.host = np.zeros((len(self.rows.entities), 7), np.float32)
        self.buffer = torch.zeros((len(self.rows.entities), POSE_COLUMNS), dtype=torch.float32, device=device)
        self.group = group_factory(systems)
        self.group.set_cuda_poses(cuda_array(self.buffer))
        self.camera_groups = {name: self.group.create_camera_group([c for c, _ in cams], self.textures[name])
                              for name, cams in self.rows.cameras.items()}
        self.build_s = time.perf_counter() - t0

    def render(self) -> dict[str, dict[str, Any]]:
        """Every camera of every scene, now: camera name -> texture name -> (K, H, W, C) tensor on
        the render device (env order), what ``RenderCamera.get_picture`` gives one env; the textures
        the obs mode reads only (``compat.needed_textures``)."""
        import torch

        for base in self.bases:  # as ManiSkill's per-scene render does first
            for obj in compat.hidden_objects(base):
                obj.hide_visual()
        fill_poses(self.rows.entities, self.host)
        self.buffer[:, :7].copy_(torch.from_numpy(self.host))
        self.group.update_render()
        out = {}
        for name, group in self.camera_groups.items():
            group.take_picture()
            out[name] = {tex: group.get_picture_cuda(tex).torch() for tex in self.textures[name]}
        return out
