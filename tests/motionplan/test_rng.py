"""The planners' random sources (motionplan/rng.py): reseeding makes libc's ``rand()`` (mplib's IK
restarts) repeat whatever was drawn before; another seed draws other numbers."""
from __future__ import annotations

import ctypes

from rsb_maniskill.motionplan.rng import PLAN_SEED, reseed_planners


def test_reseeding_repeats_the_draws():
    libc = ctypes.CDLL(None)
    reseed_planners()
    first = [libc.rand() for _ in range(8)]
    [libc.rand() for _ in range(100)]  # an earlier plan's draws
    reseed_planners()
    assert [libc.rand() for _ in range(8)] == first
    reseed_planners(PLAN_SEED + 1)
    assert [libc.rand() for _ in range(8)] != first
