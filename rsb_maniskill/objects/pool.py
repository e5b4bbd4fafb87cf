"""A family's actors in a scene, and which of them are the N candidates of each parallel env.

Every env holds the family's whole pool (4 or 10 blocks; every everyday model), one merged
actor per pool member, so building happens once and a reset only moves actors: the episode's
candidates go onto the table, the rest stay parked out of reach and out of view (under the
table). Different envs may hold different candidates (``index`` is per env), on CPU and GPU.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import sapien
import torch

from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs.actor import Actor
from mani_skill.utils.structs.pose import Pose

from rsb_maniskill.compat import entities, physx_bodies
from rsb_maniskill.objects.family import Shape, actor_builder


class CandidatePool:
    """Pool members ``keys`` (K), the per-env candidate -> member map ``index`` (B, N) and the
    geometry the task and expert read, gathered per candidate."""

    def __init__(self, family: Any, n: int, letters: Sequence[str], num_envs: int,
                 device: torch.device | str):
        self.family, self.n, self.num_envs, self.device = family, n, num_envs, device
        self.keys = family.pool_keys(n, letters)
        self.member = {k: i for i, k in enumerate(self.keys)}
        self.shapes: list[Shape] = [family.shape(k) for k in self.keys]
        f32 = dict(dtype=torch.float32, device=device)
        self._rest_z = torch.tensor([s.rest_z for s in self.shapes], **f32)
        self._half = torch.tensor([s.half_extents for s in self.shapes], **f32)
        self._height = torch.tensor([s.height for s in self.shapes], **f32)
        self.index = torch.arange(n, device=device).repeat(num_envs, 1) % len(self.keys)
        self.actors: list[Actor] = []
        self._park: torch.Tensor | None = None
        self._on_table = torch.zeros(num_envs, len(self.keys), dtype=torch.bool, device=device)
        self._cpu = True
        self._rest_again: list[int] = []

    @property
    def parks(self) -> bool:
        """True when the pool holds more members than candidates (some are parked each episode)."""
        return len(self.keys) > self.n

    def build(self, scene: ManiSkillScene, park_xyz: np.ndarray, per_env_materials: bool = False) -> list[Actor]:
        """Builds every member at its park position ``park_xyz[k]`` (origin at rest there);
        ``per_env_materials``: env by env, merged, so each env can colour its members its own way."""
        build = actor_builder(self.family)
        park = np.asarray(park_xyz, dtype=np.float32).copy()
        park[:, 2] += self._rest_z.cpu().numpy()
        self._park = torch.as_tensor(park, device=self.device)
        self.actors = []
        for i, k in enumerate(self.keys):
            name, pose = f"candidate_{k.replace(':', '_')}", sapien.Pose(p=park[i].tolist())
            if per_env_materials:
                parts = [build(scene, k, f"{name}-{e}", pose, [e]) for e in range(self.num_envs)]
                self.actors.append(Actor.merge(parts, name))
            else:
                self.actors.append(build(scene, k, name, pose))
        self._cpu = not scene.gpu_sim_enabled
        for k in range(len(self.keys)):
            self._set_visible(k, False)
        return self.actors

    def _set_visible(self, k: int, visible: bool) -> None:
        if self._cpu and self.parks:
            for obj in entities(self.actors[k]):
                body = obj.find_component_by_type(sapien.render.RenderBodyComponent)
                if body is not None:
                    body.visibility = float(visible)

    # ------------------------------------------------------------------ per-episode assignment
    def assign(self, env: int, keys: Sequence[str]) -> None:
        """Candidate ``c`` of env ``env`` becomes the member named ``keys[c]``."""
        try:
            self.index[env] = torch.as_tensor([self.member[k] for k in keys], device=self.device)
        except KeyError as e:
            raise KeyError(f"candidate {e.args[0]!r} is not in the {self.family.name} pool "
                           f"(members: {', '.join(self.keys[:6])}, ...)") from None

    def set_index(self, env_idx: torch.Tensor | slice, index: torch.Tensor) -> None:
        """Sets the candidate -> member map from a saved state (replay); members on the table follow."""
        self.index[env_idx] = index.to(self.index.dtype)
        on_table = torch.zeros_like(self._on_table[env_idx])
        self._on_table[env_idx] = on_table.scatter_(1, self.index[env_idx], True)
        for k in range(len(self.keys)):
            self._set_visible(k, bool(self._on_table[0, k]))
        self.sleep_parked()

    def place(self, env_idx: torch.Tensor, xyz: torch.Tensor, quat: torch.Tensor) -> None:
        """Puts the candidates of ``env_idx`` at ``xyz`` / ``quat`` (b, N, 3|4) and parks every
        other member that was on the table; members parked before and after are not touched."""
        b = len(env_idx)
        idx = self.index[env_idx]  # (b, N)
        on_table = torch.zeros(b, len(self.keys), dtype=torch.bool, device=self.device)
        on_table.scatter_(1, idx, True)
        was = self._on_table[env_idx]
        for k, actor in enumerate(self.actors):
            if not (on_table[:, k] | was[:, k]).any():
                continue
            p = self._park[k].expand(b, 3).clone()
            q = torch.tensor([1.0, 0.0, 0.0, 0.0], device=self.device).expand(b, 4).clone()
            rows, cols = torch.nonzero(idx == k, as_tuple=True)
            p[rows], q[rows] = xyz[rows, cols], quat[rows, cols]
            _set_still(actor, p, q)
            self._set_visible(k, bool(on_table[0, k]))
        if self._cpu:  # their lost table contacts wake them in the first step: park them again then
            self._rest_again = torch.nonzero(was[0] & ~on_table[0]).flatten().tolist()
        self._on_table[env_idx] = on_table
        self.sleep_parked()

    def sleep_parked(self) -> None:
        """CPU: puts every parked member to sleep where it is (it stays there until touched)."""
        if self._cpu:
            for k in torch.nonzero(~self._on_table[0]).flatten().tolist():
                physx_bodies(self.actors[k])[0].put_to_sleep()

    def after_step(self) -> None:
        """CPU, once after a reset: members just taken off the table were woken by the contacts
        they lost; put them back on their park spot, asleep."""
        if not self._rest_again:
            return
        upright = torch.tensor([[1.0, 0.0, 0.0, 0.0]], device=self.device)
        for k in self._rest_again:
            _set_still(self.actors[k], self._park[k][None], upright)
            physx_bodies(self.actors[k])[0].put_to_sleep()
        self._rest_again = []

    # ------------------------------------------------------------------ per-candidate views
    def rest_z(self) -> torch.Tensor:
        """(B, N) height of each candidate's origin above the table at rest."""
        return self._rest_z[self.index]

    def half_extents(self) -> torch.Tensor:
        """(B, N, 2) footprint half sizes along each candidate's own x and y."""
        return self._half[self.index]

    def heights(self) -> torch.Tensor:
        """(B, N) top of each candidate above the table at rest."""
        return self._height[self.index]

    def member_values(self, per_member: torch.Tensor) -> torch.Tensor:
        """(B, K, ...) values of every member -> (B, N, ...) values of the candidates."""
        idx = self.index.view(*self.index.shape, *([1] * (per_member.ndim - 2)))
        return torch.gather(per_member, 1, idx.expand(-1, -1, *per_member.shape[2:]))

    def _read(self, attr) -> torch.Tensor:
        """(B, N, ...) of a per-actor reading: with one env only the N candidates are read (each
        read is a Python call on CPU); on GPU every member's row is a view of one buffer."""
        if self.num_envs == 1:
            return torch.stack([attr(self.actors[k]) for k in self.index[0].tolist()], dim=1)
        return self.member_values(torch.stack([attr(a) for a in self.actors], dim=1))

    def raw_poses(self) -> torch.Tensor:
        """(B, N, 7) candidate poses."""
        return self._read(lambda a: a.pose.raw_pose)

    def linear_velocities(self) -> torch.Tensor:
        """(B, N, 3) candidate velocities."""
        return self._read(lambda a: a.linear_velocity)

    def actor(self, candidate: int, env: int = 0) -> Actor:
        """The merged actor holding candidate ``candidate`` of env ``env`` (index it by env)."""
        return self.actors[int(self.index[env, candidate])]

    def shape(self, candidate: int, env: int = 0) -> Shape:
        return self.shapes[int(self.index[env, candidate])]


def _set_still(actor, p: torch.Tensor, q: torch.Tensor) -> None:
    """Puts ``actor`` at (b, 3) positions ``p`` / (b, 4) quaternions ``q``, at rest."""
    actor.set_pose(Pose.create_from_pq(p, q))
    zeros = torch.zeros((len(p), 3), device=p.device)
    actor.set_linear_velocity(zeros)
    actor.set_angular_velocity(zeros)
