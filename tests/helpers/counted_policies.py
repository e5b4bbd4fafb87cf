"""Policies for the shared policy server's tests (``rsb eval --policy-process``, ``rsb serve``): their
factories append one line to a file per build, so a test counts how often the model was loaded.
Importable by a server process with tests/helpers/ on PYTHONPATH."""
from __future__ import annotations

import os
import time

import numpy as np

ACTION_DIM = 14  # the RSB robot's joint-position actions
HORIZON = 2


def _action(obs) -> np.ndarray:
    """A deterministic chunk from one observation (a state vector or a nested dict): row-wise, so the
    batched form gives each row exactly what the single form gives it."""
    leaves = [obs] if not isinstance(obs, dict) else [v for v in obs.values() if not isinstance(v, dict)]
    total = float(sum(np.asarray(v, dtype=np.float64).sum() for v in leaves))
    return np.full((HORIZON, ACTION_DIM), 0.3 + 0.01 * np.tanh(total), dtype=np.float32)


class CountedPolicy:
    """Both forms, and the served form's ``reset_envs``; stateless between calls, so any grouping of
    rows gives the same actions. ``fail_on``: a row whose observation sums to it raises (a fault)."""

    name = "counted"

    def __init__(self, log: str, fail_on: float | None = None, delay_s: float = 0.0) -> None:
        with open(log, "a") as f:
            f.write(f"{os.getpid()}\n")
        self.fail_on, self.delay_s = fail_on, delay_s
        self.row_resets: list[list[int]] = []
        self.seeds: list[int] = []  # the episode seeds its resets were given

    def _check(self, obs) -> None:
        if self.fail_on is not None and float(np.asarray(obs).sum()) == self.fail_on:
            raise RuntimeError(f"row with sum {self.fail_on} is poison")

    def reset(self, instruction, obs) -> None:
        pass

    def act(self, obs):
        self._check(obs)
        return _action(obs)

    def reset_batch(self, instructions, obs) -> None:
        pass

    def reset_envs(self, instructions, obs, envs, seeds=None) -> None:
        self.row_resets.append([int(e) for e in envs])
        self.seeds += list(seeds or [])

    def act_batch(self, obs, envs):
        time.sleep(self.delay_s)
        rows = [obs[i] if not isinstance(obs, dict) else {k: v[i] for k, v in obs.items()} for i in range(len(envs))]
        for row in rows:
            self._check(row)
        return np.stack([_action(row) for row in rows])


def make_counted(log: str, fail_on: float | None = None, delay_s: float = 0.0) -> CountedPolicy:
    return CountedPolicy(log, fail_on, delay_s)


make_counted.heavy = True  # declares a model computed on a GPU: `--policy-process auto` shares it where CUDA is
make_counted.gpu = True


class CountedSingle:
    """The single form only (as the diffusion-policy baseline): a history per episode, whose length
    is in the actions, so rows that shared one history would act differently."""

    name = "counted-single"

    def __init__(self, log: str) -> None:
        with open(log, "a") as f:
            f.write(f"{os.getpid()}\n")
        self.history: list[float] = []
        self.seed: int | None = None

    def reset(self, instruction, obs, seed=None) -> None:
        self.history.clear()
        self.seed = seed

    def act(self, obs):
        self.history.append(float(np.asarray(obs).sum()))
        return _action(obs) + 0.001 * min(len(self.history), 50)


def make_counted_single(log: str) -> CountedSingle:
    return CountedSingle(log)


make_counted_single.heavy = True
