"""The interface between a task and its answer targets (blocks today, everyday objects later).

A task asks for N candidates, places them, and needs a few numbers to judge grasps and
placements; it never looks at how a candidate is built. Each candidate index is one merged
``Actor`` across parallel envs, so different envs may hold different shapes (Beyond Blocks)
as long as the per-env geometry tensors describe them.
"""
from __future__ import annotations

from typing import Protocol

import torch

from mani_skill.envs.scene import ManiSkillScene
from mani_skill.utils.structs.actor import Actor


class AnswerTargets(Protocol):
    """N candidate objects, candidate ``i`` standing for block/option identity ``i``."""

    n: int

    def build(self, scene: ManiSkillScene) -> list[Actor]:
        """Creates the N candidates (one merged actor each) in every parallel env."""

    def names(self) -> tuple[str, ...]:
        """Human names of the candidates, e.g. ``("red block", ...)`` or ``("block A", ...)``."""

    def rest_height(self) -> torch.Tensor:
        """(num_envs, N) height of each candidate's centre above the table when it lies at rest."""

    def footprint_radius(self) -> torch.Tensor:
        """(num_envs, N) radius of a circle around each candidate that must stay clear of neighbours."""

    def grasp_width(self) -> torch.Tensor:
        """(num_envs, N) width between the fingers when a candidate is held."""
