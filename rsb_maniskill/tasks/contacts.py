"""Contact forces between a few robot links and many candidate objects, in one query a step.

Asking ManiSkill pair by pair costs one pass over all contacts (CPU) or one GPU query per pair;
the grasp rule needs fingers x candidates pairs every step, so we batch them."""
from __future__ import annotations

import numpy as np
import torch

from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs.actor import Actor
from mani_skill.utils.structs.link import Link

from rsb_maniskill.compat import physx_bodies


class PairContacts:
    """Force magnitudes (N) between each of F links and each of M actors: ``forces() -> (B, F, M)``."""

    def __init__(self, scene: ManiSkillScene, links: list[Link], actors: list[Actor]):
        self.scene, self.links, self.actors = scene, links, actors
        self.shape = (len(links), len(actors))
        self._query = None
        if not scene.gpu_sim_enabled:
            self._link_index = {physx_bodies(link)[0].entity: f for f, link in enumerate(links)}
            self._actor_index = {physx_bodies(a)[0].entity: m for m, a in enumerate(actors)}

    def forces(self) -> torch.Tensor:
        if self.scene.gpu_sim_enabled:
            return self._gpu_forces()
        return self._cpu_forces()

    def _cpu_forces(self) -> torch.Tensor:
        impulse = np.zeros((*self.shape, 3))
        for contact in self.scene.px.get_contacts():
            e0, e1 = contact.bodies[0].entity, contact.bodies[1].entity
            f, m, sign = self._link_index.get(e0), self._actor_index.get(e1), 1.0
            if f is None or m is None:
                f, m, sign = self._link_index.get(e1), self._actor_index.get(e0), -1.0
                if f is None or m is None:
                    continue
            impulse[f, m] += sign * np.sum([p.impulse for p in contact.points], axis=0)
        force = np.linalg.norm(impulse, axis=-1) / self.scene.timestep
        return torch.as_tensor(force, dtype=torch.float32, device=self.scene.device)[None]

    def _gpu_forces(self) -> torch.Tensor:
        if self._query is None:
            pairs = [(physx_bodies(link)[e], physx_bodies(a)[e]) for link in self.links for a in self.actors
                     for e in range(self.scene.num_envs)]
            self._query = self.scene.px.gpu_create_contact_pair_impulse_query(pairs)
        self.scene.px.gpu_query_contact_pair_impulses(self._query)
        imp = self._query.cuda_impulses.torch().clone().reshape(*self.shape, self.scene.num_envs, 3)
        return (torch.linalg.norm(imp, dim=-1) / self.scene.timestep).permute(2, 0, 1)
