"""What the candidates are: blocks or everyday objects (Beyond Blocks).

Two halves. Without the simulator (numpy only, used by the semantic sampler): ``family`` (the
families, their per-episode draw, names, noun and geometry), ``catalog`` (everyday objects as
convex parts with grasp frames) and ``geometry`` (what a part, a grasp and a model are). With the
simulator: ``pool`` builds a family's actors in a scene and places, parks and reads the candidates
of each parallel env (``blocks`` and ``everyday`` build the actors). See docs/objects.md.
"""
from rsb_maniskill.objects import family as _family
from rsb_maniskill.objects.family import get_family, register_family

__all__ = ["TARGETS", "get_family", "register_family"]


def __getattr__(attr: str):  # TARGETS follows the family registry
    if attr == "TARGETS":
        return _family.target_names()
    raise AttributeError(f"module {__name__!r} has no attribute {attr!r}")
