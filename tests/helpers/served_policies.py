"""Policies that write every action chunk they hand out to a log (one JSON line: the episode's seed, the
call's number in the episode, the chunk), so a test compares ``rsb eval --policy-process worker /
shared / auto`` and ``--num-envs 1 / 4`` action for action, whichever process computed them.
Importable by a served policy's process with tests/helpers/ on PYTHONPATH."""
from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

ACTION_DIM = 14
HORIZON = 2


def _write(log: str, seed: int | None, step: int, chunk: np.ndarray) -> None:
    line = json.dumps({"seed": seed, "step": step, "chunk": np.asarray(chunk, dtype=np.float64).tolist()}) + "\n"
    fd = os.open(log, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line.encode())  # one write a line: lines of several processes never interleave
    finally:
        os.close(fd)


def read_chunks(log: str | os.PathLike) -> dict[tuple[int, int], list]:
    """``(seed, call) -> chunk`` of a log; a (seed, call) written twice (a call re-run) is an error."""
    chunks: dict[tuple[int, int], list] = {}
    with open(log) as f:
        for line in f:
            row = json.loads(line)
            key = (row["seed"], row["step"])
            assert key not in chunks, f"chunk {key} handed out twice"
            chunks[key] = row["chunk"]
    return chunks


class _EnvState:
    def __init__(self, seed: int | None) -> None:
        self.seed, self.step = seed, 0
        self.rng = np.random.default_rng(seed)


class StatefulBatched:
    """Both forms and the served form's ``reset_envs``, with episode state per env: its seed, a call
    count and a generator seeded by the seed. A chunk reads the observation, the count and a draw of
    the env's generator: resetting the wrong env, sharing a generator or calling twice shows."""

    name = "stateful-batched"

    def __init__(self, log: str) -> None:
        self.log = log
        self.envs: dict[int, _EnvState] = {}

    def _chunk(self, env: int, obs: Any) -> np.ndarray:
        state = self.envs[env]
        state.step += 1
        base = 0.3 + 0.01 * np.tanh(float(np.asarray(obs, dtype=np.float64).sum()))
        chunk = base + 0.001 * state.step + 0.01 * state.rng.standard_normal((HORIZON, ACTION_DIM))
        _write(self.log, state.seed, state.step, chunk)
        return chunk.astype(np.float32)

    def reset(self, instruction: str, obs: Any, seed: int | None = None) -> None:
        self.envs[-1] = _EnvState(seed)

    def act(self, obs: Any) -> np.ndarray:
        return self._chunk(-1, obs)

    def reset_batch(self, instructions: Any, obs: Any, seeds: Any = None) -> None:
        self.envs = {i: _EnvState(None if seeds is None else seeds[i]) for i in range(len(instructions))}

    def reset_envs(self, instructions: Any, obs: Any, envs: Any, seeds: Any = None) -> None:
        for i, env in enumerate(envs):
            self.envs[int(env)] = _EnvState(None if seeds is None else seeds[i])

    def act_batch(self, obs: Any, envs: Any) -> np.ndarray:
        return np.stack([self._chunk(int(env), obs[k]) for k, env in enumerate(envs)])


def make_stateful(log: str) -> StatefulBatched:
    return StatefulBatched(log)


make_stateful.heavy = True  # a model computed on a GPU: `--policy-process auto` shares it where CUDA is
make_stateful.gpu = True


class RecordingDiffusion:
    """The diffusion-policy baseline, wrapped: every chunk it returns is written to the log with its
    episode's seed (a wrapper holding an inner policy, as users write them)."""

    def __init__(self, log: str, **kwargs: Any) -> None:
        from rsb_maniskill.baselines.diffusion_policy.policy import DiffusionPolicy

        self.log = log
        self.inner = DiffusionPolicy(**kwargs)
        self.name = self.inner.name
        self.seed: int | None = None
        self.step = 0

    def reset(self, instruction: str, obs: Any, seed: int | None = None) -> None:
        self.seed, self.step = seed, 0
        self.inner.reset(instruction, obs, seed=seed)

    def act(self, obs: Any) -> np.ndarray:
        chunk = self.inner.act(obs)
        self.step += 1
        _write(self.log, self.seed, self.step, chunk)
        return chunk


def make_recording_diffusion(log: str, checkpoint: str, inference_steps: int = 2) -> RecordingDiffusion:
    return RecordingDiffusion(log, checkpoint_path=checkpoint, inference_steps=inference_steps)


make_recording_diffusion.heavy = True  # as the baseline's make_policy: a checkpoint, computed on the CPU


class Faulty:
    """Both forms and ``reset_envs``; its first act raises ``KeyboardInterrupt`` (``fault="interrupt"``),
    ``SystemExit`` ("exit") or never returns ("hang"), after writing the time it did so to ``stamp``."""

    name = "faulty"

    def __init__(self, fault: str, stamp: str) -> None:
        self.fault, self.stamp = fault, stamp

    def reset(self, instruction: str, obs: Any, seed: int | None = None) -> None:
        pass

    def act(self, obs: Any) -> np.ndarray:
        return self.act_batch(np.asarray(obs)[None], [0])[0]

    def reset_batch(self, instructions: Any, obs: Any) -> None:
        pass

    def reset_envs(self, instructions: Any, obs: Any, envs: Any) -> None:
        pass

    def act_batch(self, obs: Any, envs: Any) -> np.ndarray:
        import time

        with open(self.stamp, "a") as f:
            f.write(f"{time.time()}\n")
        if self.fault == "interrupt":
            raise KeyboardInterrupt
        if self.fault == "exit":
            raise SystemExit(3)
        if self.fault == "hang":
            time.sleep(3600)
        return np.zeros((len(envs), HORIZON, ACTION_DIM), np.float32)

    def fork(self) -> "Faulty":  # no episode state: every env may use this object
        return self


def make_faulty(fault: str, stamp: str) -> Faulty:
    return Faulty(fault, stamp)
