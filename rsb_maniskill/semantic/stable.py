"""Process- and platform-independent hashing and seeding (never Python's ``hash()``)."""
from __future__ import annotations

import hashlib
import zlib

import numpy as np


def stable_key(*parts: object) -> bytes:
    """SHA-256 digest of the parts joined by '|': a sort key identical on every machine."""
    return hashlib.sha256("|".join(str(p) for p in parts).encode("utf-8")).digest()


def stable_bucket(*parts: object, modulo: int = 100) -> int:
    """Deterministic bucket in ``range(modulo)`` for split assignment."""
    return int.from_bytes(stable_key(*parts)[:8], "big") % modulo


def episode_rng(suite_id: str, split: str, seed: int, salt: str = "") -> np.random.Generator:
    """numpy Generator seeded from (suite, split, seed) via crc32 and explicit ints.

    ``salt`` separates independent streams (question choice vs. option order) so that forcing
    the question does not change the remaining draws' meaning.
    """
    entropy = [zlib.crc32(suite_id.encode()), zlib.crc32(split.encode()), int(seed) & 0xFFFFFFFF,
               (int(seed) >> 32) & 0xFFFFFFFF, zlib.crc32(salt.encode())]
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(entropy)))


def axis_rng(suite_id: str, split: str, seed: int, axis: str, level: int) -> np.random.Generator:
    """The draws of one robustness axis at one level for one episode (``rsb_maniskill.perturb``):
    independent of every other stream."""
    return episode_rng(suite_id, split, seed, f"perturb:{axis}:{level}")
