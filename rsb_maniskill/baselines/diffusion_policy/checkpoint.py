"""Checkpoints: ``<out>/checkpoints/step_<N>.pt`` and ``last.pt``, written atomically.

One file holds everything a resumed run or the evaluator needs: model config, normaliser,
weights, EMA weights, optimizer and LR-schedule state, step, every RNG state and the run's
arguments.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

LAST = "last.pt"


def checkpoint_dir(out: str | os.PathLike) -> Path:
    return Path(out) / "checkpoints"


def save(out: str | os.PathLike, state: dict[str, Any], step: int, keep_step_file: bool = True) -> Path:
    """Writes ``last.pt`` (and ``step_<step>.pt``) through a temp name: a crash mid-write keeps the old one."""
    d = checkpoint_dir(out)
    d.mkdir(parents=True, exist_ok=True)
    tmp = d / f".{LAST}.tmp{os.getpid()}"
    torch.save(state, tmp)
    if keep_step_file:
        step_file = d / f"step_{step}.pt"
        torch.save(state, step_file.with_name(f".{step_file.name}.tmp"))
        os.replace(step_file.with_name(f".{step_file.name}.tmp"), step_file)
    os.replace(tmp, d / LAST)
    return d / LAST


def resolve(path: str | os.PathLike) -> Path:
    """A checkpoint file from a file, a run directory or its ``checkpoints`` directory."""
    p = Path(path)
    for cand in (p, p / LAST, checkpoint_dir(p) / LAST):
        if cand.is_file():
            return cand
    raise FileNotFoundError(f"no checkpoint at {p}: give a .pt file, or a training --out directory holding "
                            f"checkpoints/{LAST}")


def load(path: str | os.PathLike) -> dict[str, Any]:
    return torch.load(resolve(path), map_location="cpu", weights_only=False)
