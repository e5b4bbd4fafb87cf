"""ManiSkill's batched values (a leading env dimension, torch or numpy) seen one env at a time.

Tensors are recognised by their ``detach`` method, so these helpers import no torch. The evaluator
and the generation worker read env 0 through them.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np


def first_value(x: Any) -> Any:
    """Python scalar of env 0 from a tensor / array / scalar."""
    if hasattr(x, "detach"):  # torch, without importing it
        x = x.detach().cpu().numpy()
    a = np.asarray(x)
    return a.reshape(-1)[0].item() if a.size else None


def env_row(x: Any, i: int) -> Any:
    """Row ``i`` of a batched (nested) obs or info value, as numpy."""
    if isinstance(x, Mapping):
        return {k: env_row(v, i) for k, v in x.items()}
    if hasattr(x, "detach"):
        return x[i].detach().cpu().numpy()
    return np.asarray(x)[i]


def single_env_obs(obs: Any) -> Any:
    """Nested obs of a one-env batch as numpy with the leading env dim removed."""
    if isinstance(obs, Mapping):
        return {k: single_env_obs(v) for k, v in obs.items()}
    if hasattr(obs, "detach"):
        obs = obs.detach().cpu().numpy()
    if isinstance(obs, np.ndarray) and obs.ndim >= 1:
        return obs[0]
    return obs
