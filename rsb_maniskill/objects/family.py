"""Candidate families without the simulator: what an episode's candidates are and are called.

A family draws the N candidates of an episode (asset keys and the names the instruction uses),
says which noun the templates use ("block", "object"), whether its candidates carry the option
letters themselves (the 10 lettered blocks), and gives the geometry that the task's layout and
the expert need. Importable without sapien or torch: the semantic sampler uses it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from rsb_maniskill.objects import catalog
from rsb_maniskill.objects.catalog import Grasp

BLOCK_HALF = 0.02  # 4 cm cubes
BLOCK_COLORS: dict[str, tuple[float, float, float]] = {  # RGB of the 4-choice blocks, in block-index order
    "red": (0.85, 0.12, 0.10),
    "green": (0.10, 0.65, 0.20),
    "blue": (0.12, 0.30, 0.85),
    "yellow": (0.95, 0.82, 0.10),
}
TARGETS: tuple[str, ...] = ("blocks", "objects")
OBJECTS_SUFFIX = "-Objects"  # env id of a suite with everyday objects: "RSB-Math-4-Objects"


def split_env_id(env_id: str) -> tuple[str, str]:
    """``"RSB-Math-4-Objects"`` -> ``("RSB-Math-4", "objects")``; other ids -> ``(id, "blocks")``.

    Does not check the suite: ``semantic.parse_suite_id`` does."""
    eid = env_id.split(":", 1)[-1]
    if eid.endswith(OBJECTS_SUFFIX):
        return eid[:-len(OBJECTS_SUFFIX)], "objects"
    return eid, "blocks"


@dataclass(frozen=True)
class Shape:
    """What the task and the expert know of a candidate: the height of its origin at rest, its
    footprint (half sizes along its x and y), its top above the table and its grasp frames."""

    rest_z: float
    half_extents: tuple[float, float]
    height: float
    grasps: tuple[Grasp, ...]


@dataclass(frozen=True)
class CandidateSet:
    """The candidates of one episode, in candidate-index order."""

    keys: tuple[str, ...]  # asset keys: "block:red", "block:F", "mug:2"
    names: tuple[str, ...]  # names in instructions: "red block", "block F", "mug"


@dataclass(frozen=True)
class Layout:
    """Cells of the placement grid and the jitter inside a cell (metres, radians)."""

    pitch: tuple[float, float]
    pos_jitter: float
    yaw_jitter: float
    yaw_choices: tuple[float, ...]  # base yaws tried before jitter (those whose footprint fits)


class BlockFamily:
    """Four coloured cubes (4-choice) or ten cubes carrying the option letters (10-choice)."""

    name = "blocks"
    noun, nouns = "block", "blocks"
    # 7.4 cm or more between neighbouring centres; letters stay upright enough to read.
    layout = Layout(pitch=(0.10, 0.09), pos_jitter=0.008, yaw_jitter=0.2, yaw_choices=(0.0,))

    def lettered(self, n: int) -> bool:
        return n == 10

    def draw(self, n: int, letters: Sequence[str], rng: np.random.Generator | None = None) -> CandidateSet:
        """Always the same blocks (block i = colour i or letter i); ``rng`` is not used."""
        return CandidateSet(self.pool_keys(n, letters), self.names(n, letters))

    def names(self, n: int, letters: Sequence[str]) -> tuple[str, ...]:
        if n == 4:
            return tuple(f"{c} block" for c in BLOCK_COLORS)
        return tuple(f"block {letter}" for letter in letters)

    def pool_keys(self, n: int, letters: Sequence[str]) -> tuple[str, ...]:
        if n == 4:
            return tuple(f"block:{c}" for c in BLOCK_COLORS)
        if n == 10:
            return tuple(f"block:{letter}" for letter in letters)
        raise ValueError(f"blocks come in sets of 4 (coloured) or 10 (lettered), not {n}")

    def shape(self, key: str) -> Shape:
        h = BLOCK_HALF
        grasps = tuple(Grasp((0.0, 0.0, 0.010), yaw, 2 * h) for yaw in (0.0, np.pi / 2))
        return Shape(rest_z=h, half_extents=(h, h), height=2 * h, grasps=grasps)


class ObjectFamily:
    """Everyday objects (Beyond Blocks): N distinct categories an episode, each in a random variant."""

    name = "objects"
    noun, nouns = "object", "objects"
    # Long sides roughly along x (either way round): the grasp across them keeps the wrist within
    # reach at the edges of the layout.
    layout = Layout(pitch=(0.12, 0.105), pos_jitter=0.010, yaw_jitter=0.5, yaw_choices=(0.0, np.pi))

    def lettered(self, n: int) -> bool:
        return False

    def draw(self, n: int, letters: Sequence[str], rng: np.random.Generator) -> CandidateSet:
        """N distinct categories in random order, each in a random variant: every category is
        equally likely at every candidate index, so the target's category is uniform too."""
        cats = rng.choice(len(catalog.CATEGORY_KEYS), size=n, replace=False)
        variants = rng.integers(catalog.NUM_VARIANTS, size=n)
        keys = tuple(f"{catalog.CATEGORY_KEYS[c]}:{v}" for c, v in zip(cats, variants))
        return CandidateSet(keys, tuple(catalog.category_name(k) for k in keys))

    def pool_keys(self, n: int, letters: Sequence[str]) -> tuple[str, ...]:
        return catalog.MODEL_KEYS

    def shape(self, key: str) -> Shape:
        m = catalog.model(key)
        return Shape(rest_z=0.0, half_extents=m.half_extents, height=m.height, grasps=m.grasps)


FAMILIES = {"blocks": BlockFamily(), "objects": ObjectFamily()}


def get_family(targets: str) -> BlockFamily | ObjectFamily:
    """The family named ``targets`` ("blocks" or "objects"); ValueError lists the valid names."""
    if targets not in FAMILIES:
        raise ValueError(f"unknown targets {targets!r}; valid: {', '.join(TARGETS)}")
    return FAMILIES[targets]
