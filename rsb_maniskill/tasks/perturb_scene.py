"""The visual robustness axes in the scene (``rsb_maniskill.perturb`` names them and draws the values).

Applied at every reset, per env from its own episode seed, so ``num_envs > 1`` gives every env its
own camera, light, table, candidate colours, clutter and start pose, the same as that seed alone
would on CPU. Nothing is built or touched for an axis at level 0: level 0 is today's scene.
Colours differ per env only where each env owns its materials: with ``num_envs > 1`` the table and
the candidates are then built env by env (``per_env_materials``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import sapien
import torch
from transforms3d.euler import euler2quat

from mani_skill.utils.structs.actor import Actor
from mani_skill.utils.structs.pose import Pose

from rsb_maniskill import perturb as P
from rsb_maniskill.compat import entities, episode_seeds, forget_camera_pose, physx_bodies, render_cameras
from rsb_maniskill.semantic.stable import axis_rng

HEAD_CAMERA = "head_camera"
# Lights of the default scene (ManiSkill's BaseEnv._load_lighting), perturbed around.
AMBIENT = np.array([0.3, 0.3, 0.3])
MAIN_LIGHT_DIR, FILL_LIGHT_DIR = np.array([1.0, 1.0, -1.0]), np.array([0.0, 0.0, -1.0])
CLUTTER_MARGIN = 0.006  # m between a clutter item's footprint and its cell's edge


@dataclass(frozen=True)
class ClutterItem:
    """A flat everyday object that is no candidate of any family (no catalog category, no block)."""

    name: str
    shape: str  # "box" or "disc"
    dims: tuple[float, ...]  # box: half sizes; disc: (radius, half height)
    rgb: tuple[float, float, float]

    @property
    def half_height(self) -> float:
        return self.dims[2] if self.shape == "box" else self.dims[1]

    @property
    def half_extents(self) -> tuple[float, float]:
        return (self.dims[0], self.dims[1]) if self.shape == "box" else (self.dims[0], self.dims[0])


# Flat (at most 1.6 cm high): fingertips pass above them, nothing to trip the expert's grasp.
CLUTTER_ITEMS: tuple[ClutterItem, ...] = (
    ClutterItem("coaster", "disc", (0.030, 0.004), (0.45, 0.30, 0.20)),
    ClutterItem("sticky notes", "box", (0.030, 0.030, 0.007), (0.98, 0.90, 0.35)),
    ClutterItem("eraser", "box", (0.025, 0.012, 0.008), (0.92, 0.55, 0.60)),
    ClutterItem("pencil", "box", (0.040, 0.005, 0.005), (0.95, 0.70, 0.15)),
)


def build_clutter(scene, park_xyz: np.ndarray) -> list[Actor]:
    """One actor per clutter item in every env, parked at ``park_xyz[i]`` (origin at rest there)."""
    actors = []
    for item, xyz in zip(CLUTTER_ITEMS, park_xyz):
        builder = scene.create_actor_builder()
        mat = sapien.render.RenderMaterial(base_color=[*item.rgb, 1.0], roughness=0.8)
        if item.shape == "box":
            builder.add_box_collision(half_size=list(item.dims), density=400.0)
            builder.add_box_visual(half_size=list(item.dims), material=mat)
        else:  # SAPIEN cylinders lie along x: stand the disc on its face
            up = sapien.Pose(q=euler2quat(0, np.pi / 2, 0))
            builder.add_cylinder_collision(up, radius=item.dims[0], half_length=item.dims[1], density=400.0)
            builder.add_cylinder_visual(up, radius=item.dims[0], half_length=item.dims[1], material=mat)
        builder.initial_pose = sapien.Pose(p=[float(xyz[0]), float(xyz[1]), float(xyz[2]) + item.half_height])
        actors.append(builder.build(name=f"clutter_{item.name.replace(' ', '_')}"))
    return actors


def clutter_layout(rng: np.random.Generator, level: int, cells: np.ndarray, pitch: Sequence[float],
                   used: Sequence[int]) -> list[tuple[int, np.ndarray]]:
    """(item index, (x, y)) of the clutter of one episode: distinct free cells, each item inside its cell."""
    count = P.CLUTTER_COUNT[level]
    free = np.array([c for c in range(len(cells)) if c not in set(int(u) for u in used)])
    items = rng.choice(len(CLUTTER_ITEMS), size=count, replace=False)
    chosen = rng.choice(free, size=min(count, len(free)), replace=False)
    out = []
    for k, cell in zip(items, chosen):
        hx, hy = CLUTTER_ITEMS[int(k)].half_extents
        slack = np.clip(np.array([pitch[0] / 2 - hx, pitch[1] / 2 - hy]) - CLUTTER_MARGIN, 0, None)
        out.append((int(k), cells[int(cell)] + rng.uniform(-1, 1, 2) * slack))
    return out


def shape_materials(actor: Actor) -> list[list[Any]]:
    """Per env, the render materials of ``actor``'s visual shapes, in build order (mesh parts flattened)."""
    out = []
    for obj in entities(actor):
        body = obj.find_component_by_type(sapien.render.RenderBodyComponent)
        mats = []
        if body is None:  # no renderer (render_backend="none"): nothing to colour
            out.append(mats)
            continue
        for shape in body.render_shapes:
            parts = shape.parts if isinstance(shape, sapien.render.RenderShapeTriangleMesh) else [shape]
            mats += [p.material for p in parts]
        out.append(mats)
    return out


def _colour(mat: Any) -> np.ndarray:
    return np.asarray(mat.base_color, dtype=np.float64)


class SceneAxes:
    """The visual axes of one env: built at load, applied at each reset (``env_idx`` of the reset)."""

    def __init__(self, env: Any, perturb: dict[str, int]):
        self.env = env
        self.levels = P.visual(perturb)
        self.clutter: list[Actor] = []
        self.lights: list[tuple[Any, Any, Any]] = []  # per sub-scene: (render system, main light, fill light)
        self._table_rgb: list[list[np.ndarray]] = []
        self._table_mats: list[list[Any]] = [[]]
        self._member_rgb: list[list[list[np.ndarray]]] = []

    def level(self, axis: str) -> int:
        return self.levels.get(axis, 0)

    @property
    def per_env_materials(self) -> bool:
        """Build the table / the candidates env by env (each env its own colours)."""
        return self.env.num_envs > 1

    def rng(self, env: int, axis: str) -> np.random.Generator:
        e = self.env
        return axis_rng(e.suite_id, e.split, int(episode_seeds(e)[env]), axis, self.level(axis))

    # ------------------------------------------------------------------ load
    def load_lighting(self, shadow: bool) -> None:
        """The default lights, one set per sub-scene, kept so each episode can change them."""
        for sub in self.env.scene.sub_scenes:
            lights = []
            for direction, cast in ((MAIN_LIGHT_DIR, shadow), (FILL_LIGHT_DIR, False)):
                entity = sapien.Entity()
                light = sapien.render.RenderDirectionalLightComponent()
                entity.add_component(light)
                light.color = [1.0, 1.0, 1.0]
                light.shadow = cast
                if cast:
                    light.shadow_near, light.shadow_far, light.shadow_half_size = -10.0, 10.0, 5.0
                    light.shadow_map_size = 2048
                light.pose = sapien.Pose([0, 0, 0], sapien.math.shortest_rotation([1, 0, 0], direction))
                sub.add_entity(entity)
                lights.append(light)
            sub.render_system.ambient_light = AMBIENT.tolist()
            self.lights.append((sub.render_system, *lights))

    def after_load(self, table: Actor, members: list[Actor]) -> None:
        if self.level("table"):
            self._table_rgb = [[_colour(m) for m in mats] for mats in shape_materials(table)]
            self._table_mats = shape_materials(table)
        if self.level("candidate"):
            self._member_mats = [shape_materials(a) for a in members]
            self._member_rgb = [[[_colour(m) for m in mats] for mats in per_env] for per_env in self._member_mats]

    # ------------------------------------------------------------------ episodes
    def initialize(self, env_idx: torch.Tensor) -> None:
        idx = [int(i) for i in env_idx.cpu().numpy()]
        if self.level("robot_init"):
            self._robot(env_idx, idx)
        if self.level("camera"):
            self._camera(idx)
        if self.level("lighting"):
            self._lighting(idx)
        if self.level("table"):
            self._table(idx)
        if self.level("candidate"):
            self._candidates(idx)
        if self.level("clutter"):
            self._clutter(env_idx, idx)

    def _robot(self, env_idx: torch.Tensor, idx: list[int]) -> None:
        agent = self.env.agent
        qpos = agent.robot.get_qpos()[env_idx].clone()
        cols = [c for arm in agent.arms for c in agent.arm_qpos_index[arm]]
        for row, i in enumerate(idx):
            off = P.joint_offsets(self.rng(i, "robot_init"), self.level("robot_init"), len(cols))
            qpos[row, cols] += torch.as_tensor(off, dtype=qpos.dtype, device=qpos.device)
        agent.reset(qpos)

    def _camera(self, idx: list[int]) -> None:
        if HEAD_CAMERA not in self.env.scene.sensors:  # no renderer, no camera
            return
        camera = self.env.scene.sensors[HEAD_CAMERA].camera
        comps = render_cameras(camera)
        for i in idx:
            shift, (roll, pitch, yaw) = P.camera_offset(self.rng(i, "camera"), self.level("camera"))
            comps[i].set_local_pose(sapien.Pose(p=shift.tolist(), q=euler2quat(roll, pitch, yaw)))
        forget_camera_pose(camera)

    def _lighting(self, idx: list[int]) -> None:
        for i in idx if self.lights else ():
            d = P.lighting(self.rng(i, "lighting"), self.level("lighting"))
            system, main, fill = self.lights[i]
            colour = (d["gain"] * d["tint"]).tolist()
            main.color, fill.color = colour, colour
            system.ambient_light = (AMBIENT * d["gain"] * d["tint"]).tolist()
            rx, ry = d["tilt"]
            rot = sapien.Pose(q=euler2quat(rx, ry, 0.0))
            direction = rot.to_transformation_matrix()[:3, :3] @ MAIN_LIGHT_DIR
            main.pose = sapien.Pose([0, 0, 0], sapien.math.shortest_rotation([1, 0, 0], direction))

    def _table(self, idx: list[int]) -> None:
        for i in idx if self._table_mats[0] else ():
            mat = self._table_mats[min(i, len(self._table_mats) - 1)][0]  # the top (legs are under it, out of view)
            rgb = P.table_colour(self.rng(i, "table"), self.level("table"), self._table_rgb[i][0])
            mat.base_color = [*rgb, 1.0]

    def _candidates(self, idx: list[int]) -> None:
        from rsb_maniskill.objects.blocks import letter_render_texture

        pool, level = self.env.pool, self.level("candidate")
        for i in idx:
            rng = self.rng(i, "candidate")
            env_mats = min(i, len(self._member_mats[0]) - 1)  # one material set when envs share them
            for c in range(pool.n):
                k = int(pool.index[i, c])
                mats, rgbs = self._member_mats[k][env_mats], self._member_rgb[k][env_mats]
                key = pool.keys[k]
                if not mats:
                    continue
                if key.startswith("block:"):
                    f = P.shade_factor(rng, level)
                    mats[0].base_color = [*np.clip(rgbs[0][:3] * f, 0.0, 1.0), 1.0]
                    if len(mats) > 1:  # the letter plate: its texture times the same shade
                        mats[1].base_color = [f, f, f, 1.0]
                        mats[1].base_color_texture = letter_render_texture(key.split(":", 1)[1],
                                                                           P.letter_stroke(rng, level))
                else:
                    for m, rgb in zip(mats, rgbs):
                        m.base_color = [*P.recolour(rng, level, rgb[:3]), 1.0]

    def _clutter(self, env_idx: torch.Tensor, idx: list[int]) -> None:
        from rsb_maniskill.objects import layout

        e = self.env
        cells = layout.grid(e.family.layout)
        b = len(idx)
        p = torch.as_tensor(self._park, device=e.device)[None].repeat(b, 1, 1)
        for row, i in enumerate(idx):
            placed = clutter_layout(self.rng(i, "clutter"), self.level("clutter"), cells, e.family.layout.pitch,
                                    e.block_slot[i].tolist())
            for k, xy in placed:
                p[row, k, :2] = torch.as_tensor(xy, device=e.device)
                p[row, k, 2] = CLUTTER_ITEMS[k].half_height + 2e-4
        q = torch.tensor([1.0, 0.0, 0.0, 0.0], device=e.device).expand(b, 4)
        zeros = torch.zeros((b, 3), device=e.device)
        for k, actor in enumerate(self.clutter):
            actor.set_pose(Pose.create_from_pq(p[:, k], q))
            actor.set_linear_velocity(zeros)
            actor.set_angular_velocity(zeros)
            if not e.scene.gpu_sim_enabled and float(p[0, k, 2]) < 0:
                physx_bodies(actor)[0].put_to_sleep()

    def set_clutter_park(self, park_xyz: np.ndarray) -> None:
        self._park = np.asarray(park_xyz, dtype=np.float32).copy()
        for k, item in enumerate(CLUTTER_ITEMS):
            self._park[k, 2] += item.half_height

    # ------------------------------------------------------------------ observations
    def add_noise(self, sensor_obs: dict) -> dict:
        """Gaussian noise on every camera's rgb (0-255) and depth (mm), drawn per env and step."""
        e, level = self.env, self.level("noise")
        steps = e.elapsed_steps
        for name, data in sensor_obs.items():
            for key, sigma in (("rgb", P.NOISE_RGB[level]), ("depth", P.NOISE_DEPTH[level])):
                img = data.get(key)
                if img is None:
                    continue
                noise = np.stack([
                    axis_rng(e.suite_id, e.split, int(episode_seeds(e)[i]), f"noise:{name}:{key}:{int(steps[i])}",
                               level).normal(0.0, sigma, tuple(img.shape[1:]))
                    for i in range(img.shape[0])])
                noisy = img.to(torch.float32) + torch.as_tensor(noise, dtype=torch.float32, device=img.device)
                if key == "depth":
                    noisy = torch.where(img > 0, noisy.clamp(min=1), noisy.new_zeros(()))
                hi = 255 if img.dtype == torch.uint8 else torch.iinfo(img.dtype).max
                data[key] = noisy.round().clamp(0, hi).to(img.dtype)
        return sensor_obs
