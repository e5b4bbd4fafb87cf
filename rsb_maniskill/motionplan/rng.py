"""The random sources of mplib's sampling-based planning, reseeded before each such plan.

RRTConnect (OMPL) draws from OMPL's process-wide seed generator, seeded from the clock, and
mplib's IK restarts from pinocchio's random configurations, drawn with libc's ``rand()``. Neither
is exposed by mplib 0.1.1, so an RRT fallback would plan differently in every process and after
every earlier plan. Reseeding both with one constant before each sampling-based plan makes the
plan a function of its start and goal alone. OMPL's ``RNG::setSeed`` is called through the
library mplib's wheel bundles (``mplib.libs/libompl-*.so``, already loaded by mplib).
"""
from __future__ import annotations

import ctypes
import warnings
from functools import lru_cache
from pathlib import Path
from typing import Callable

import mplib

PLAN_SEED = 1  # OMPL ignores 0
_OMPL_SET_SEED = "_ZN4ompl3RNG7setSeedEm"  # ompl::RNG::setSeed(unsigned long)


@lru_cache(maxsize=1)
def _seeders() -> tuple[Callable[[int], None], ...]:
    """libc's ``srand`` and OMPL's ``RNG::setSeed``; OMPL's is left out (with a warning) when
    this mplib build has no bundled OMPL library to call it in."""
    libc = ctypes.CDLL(None)
    libc.srand.argtypes = [ctypes.c_uint]
    seeders: list[Callable[[int], None]] = [libc.srand]
    libs = sorted((Path(mplib.__file__).resolve().parent.parent / "mplib.libs").glob("libompl-*.so*"))
    try:
        set_seed = getattr(ctypes.CDLL(str(libs[0])), _OMPL_SET_SEED)
    except (IndexError, OSError, AttributeError):
        warnings.warn(f"OMPL's RNG::setSeed not found beside mplib {mplib.__version__}: RRT fallbacks of the "
                      "scripted expert will not repeat from process to process", RuntimeWarning, stacklevel=3)
    else:
        set_seed.argtypes = [ctypes.c_ulong]
        seeders.append(set_seed)
    return tuple(seeders)


def reseed_planners(seed: int = PLAN_SEED) -> None:
    """Reseeds OMPL and libc ``rand()``: the next RRT plan and IK restarts repeat exactly."""
    for seed_fn in _seeders():
        seed_fn(seed)
