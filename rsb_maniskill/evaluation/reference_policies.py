"""Privileged reference policies built on the scripted expert: ``oracle`` and ``blind``.

They read the simulator (``env.unwrapped``), so unlike user policies they are built with the env:

- ``oracle``: the expert placing the correct block. A check of the harness: TSR near 100 %.
- ``blind``: the same expert placing a uniformly random candidate, drawn from the episode seed
  (so every run picks the same blocks). The random-selection line: GSR near 100 %, nSG near 0.

Both speak the :class:`~rsb_maniskill.evaluation.policy.Policy` interface: each ``act`` returns the
next motion-planned chunk, planned from the live state after the previous chunk was executed;
once the expert's plan is over (or it gave up) they hold the last target.
"""
from __future__ import annotations

from typing import Any

import numpy as np

HOLD_STEPS = 10  # chunk length once the expert's plan is over
BLIND_SALT = 0xB11D  # separates the blind draw from the task's own use of the episode seed


def blind_target(episode_seed: int, n_choices: int) -> int:
    """The block the blind baseline picks in the episode of ``episode_seed``: uniform over N."""
    return int(np.random.default_rng([BLIND_SALT, int(episode_seed)]).integers(n_choices))


class ExpertPolicy:
    """The scripted expert as a policy; ``blind=True`` picks a random candidate instead of the target.

    Args:
        env: the one-env RSB env the runner steps (possibly wrapped).
        blind: pick ``blind_target(seed, N)`` rather than the correct block.
    """

    def __init__(self, env: Any, blind: bool = False) -> None:
        self.env = env
        self.blind = bool(blind)
        self.name = "blind" if blind else "oracle"
        self.expert = None
        self._chunks = None

    def reset(self, instruction: str, obs: dict) -> None:
        from rsb_maniskill.motionplan import ScriptedExpert

        base = self.env.unwrapped
        target = None
        if self.blind:
            target = blind_target(int(base.episode_specs[0].seed), base.n_choices)
        self.expert = ScriptedExpert(self.env, target_block=target)
        self._chunks = self.expert.chunks()

    def act(self, obs: dict) -> np.ndarray:
        if self.expert is None:
            raise RuntimeError(f"{self.name}: act() before reset()")
        chunk = next(self._chunks, None)
        if chunk is None:  # plan over (success, or the expert gave up): hold still
            return np.repeat(self.expert.action[None], HOLD_STEPS, axis=0)
        return chunk


def oracle(env: Any) -> ExpertPolicy:
    return ExpertPolicy(env, blind=False)


def blind(env: Any) -> ExpertPolicy:
    return ExpertPolicy(env, blind=True)
