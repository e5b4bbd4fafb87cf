"""Candidate families without the simulator: what an episode's candidates are and are called.

A family draws the N candidates of an episode (asset keys and the names the instruction uses),
says which noun the templates use ("block", "object"), whether its candidates carry the option
letters themselves (the 10 lettered blocks), and gives the geometry that the task's layout and
the expert need. Importable without sapien or torch: the semantic sampler uses it.

Families live in a registry (:func:`register_family`): each declares its name (the ``targets``
string), its env-id suffix (``""`` for blocks, ``"-Objects"`` for everyday objects), which asset
keys it owns and its actor builder (``"module:function"``, imported only when a scene is built).
A new family is one class and one registration.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from rsb_maniskill.objects import catalog
from rsb_maniskill.objects.geometry import Grasp
from rsb_maniskill.resolve import resolve

BLOCK_HALF = 0.02  # 4 cm cubes
BLOCK_COLORS: dict[str, tuple[float, float, float]] = {  # RGB of the 4-choice blocks, in block-index order
    "red": (0.85, 0.12, 0.10),
    "green": (0.10, 0.65, 0.20),
    "blue": (0.12, 0.30, 0.85),
    "yellow": (0.95, 0.82, 0.10),
}
DEFAULT_TARGETS = "blocks"  # the family of env ids without a family suffix ("RSB-Math-4")


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

    name, suffix = "blocks", ""
    builder = "rsb_maniskill.objects.blocks:build_block"
    noun, nouns = "block", "blocks"
    described = "blocks"  # the candidates in prose (dataset cards, reports)
    # 7.4 cm or more between neighbouring centres; letters stay upright enough to read.
    layout = Layout(pitch=(0.10, 0.09), pos_jitter=0.008, yaw_jitter=0.2, yaw_choices=(0.0,))

    def lettered(self, n: int) -> bool:
        return n == 10

    def owns(self, key: str) -> bool:
        """True when ``key`` is an asset key of this family ("block:red", "block:F")."""
        return key.startswith("block:")

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

    name, suffix = "objects", "-Objects"
    builder = "rsb_maniskill.objects.everyday:build_object"
    noun, nouns = "object", "objects"
    described = "everyday objects"
    # Long sides roughly along x (either way round): the grasp across them keeps the wrist within
    # reach at the edges of the layout.
    layout = Layout(pitch=(0.12, 0.105), pos_jitter=0.010, yaw_jitter=0.5, yaw_choices=(0.0, np.pi))

    def lettered(self, n: int) -> bool:
        return False

    def owns(self, key: str) -> bool:
        """True when ``key`` is an everyday model's key ("mug:2")."""
        return key.split(":", 1)[0] in catalog.CATEGORY_KEYS

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


FAMILIES: dict[str, Any] = {}  # name -> family, in registration order (blocks first)


def register_family(family: Any) -> Any:
    """Adds ``family`` to the registry and returns it. A family has ``name`` (the ``targets``
    string), ``suffix`` (of its env ids; ``""`` only for the default family), ``builder``
    (``"module:function"`` building one actor: ``(scene, key, name, pose[, scene_idxs])``),
    ``noun``/``nouns``/``described``, ``layout`` and the methods of :class:`BlockFamily`. A name or a suffix
    already taken raises ValueError."""
    for other in FAMILIES.values():
        if other.name == family.name or other.suffix == family.suffix:
            raise ValueError(f"family {family.name!r} (suffix {family.suffix!r}) clashes with {other.name!r}")
    FAMILIES[family.name] = family
    return family


def unregister_family(name: str) -> None:
    """Removes a family added with :func:`register_family` (tests); the default family stays."""
    if name == DEFAULT_TARGETS:
        raise ValueError(f"the default family {name!r} cannot be removed")
    FAMILIES.pop(name, None)


def target_names() -> tuple[str, ...]:
    """The registered family names, in registration order: ``("blocks", "objects")``."""
    return tuple(FAMILIES)


def __getattr__(attr: str) -> Any:  # TARGETS follows the registry
    if attr == "TARGETS":
        return target_names()
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")


def get_family(targets: str) -> Any:
    """The family named ``targets`` ("blocks" or "objects"); ValueError lists the valid names."""
    if targets not in FAMILIES:
        raise ValueError(f"unknown targets {targets!r}; valid: {', '.join(FAMILIES)}")
    return FAMILIES[targets]


def split_env_id(env_id: str) -> tuple[str, str]:
    """``"RSB-Math-4-Objects"`` -> ``("RSB-Math-4", "objects")``: the id without its family's suffix,
    and the family's name; ids without a registered suffix -> ``(id, "blocks")``.

    Does not check the suite: ``semantic.parse_suite_id`` does."""
    eid = env_id.split(":", 1)[-1]
    for fam in sorted(FAMILIES.values(), key=lambda f: -len(f.suffix)):
        if fam.suffix and eid.endswith(fam.suffix):
            return eid[:-len(fam.suffix)], fam.name
    return eid, DEFAULT_TARGETS


def join_env_id(suite_id: str, targets: str) -> str:
    """``("RSB-Math-4", "objects")`` -> ``"RSB-Math-4-Objects"`` (inverse of :func:`split_env_id`)."""
    return suite_id + get_family(targets).suffix


def family_of_keys(keys: Sequence[str]) -> str:
    """The name of the family owning every asset key in ``keys`` (``["block:red", ...]`` -> "blocks");
    ValueError when none does."""
    for fam in FAMILIES.values():
        if all(fam.owns(k) for k in keys):
            return fam.name
    raise ValueError(f"no candidate family owns all of {list(keys)}; families: {', '.join(FAMILIES)}")


def actor_builder(family: Any) -> Callable[..., Any]:
    """The function building one actor of ``family`` (imports the simulator module on first use)."""
    return resolve(family.builder, "candidate builder")


register_family(BlockFamily())
register_family(ObjectFamily())
OBJECTS_SUFFIX = FAMILIES["objects"].suffix  # "RSB-Math-4-Objects"
