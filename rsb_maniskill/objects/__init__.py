"""What the candidates are: blocks or everyday objects (Beyond Blocks).

Two halves. Without the simulator (numpy only, used by the semantic sampler): ``family`` (the
families, their per-episode draw, names, noun and geometry) and ``catalog`` (everyday objects as
convex parts with grasp frames). With the simulator: ``pool`` builds a family's actors in a scene
and places, parks and reads the candidates of each parallel env (``blocks`` and ``everyday``
build the actors). See docs/objects.md.
"""
from rsb_maniskill.objects.family import TARGETS, get_family

__all__ = ["TARGETS", "get_family"]
