"""The pinned episodes: per-suite digests that say whether an install gives this benchmark
version's episodes, and ``rsb verify``.

Three digests per suite (every suite, blocks and everyday objects):

- ``eval``: the evaluation protocol's episodes, ``EPISODES_PER_SUITE`` of them (test split,
  unseen templates, seeds ``EVAL_SEED_BASE + i``: what ``rsb eval`` and ``lerobot-eval`` run);
- ``train``: the first ``TRAIN_EPISODES`` training episodes (train split, seen templates, fixed
  colour map, seeds 0, 1, ...: what ``rsb generate`` makes first);
- ``counterfactual``: the counterfactual variants of the evaluation scenes, variants 0..K-1 with
  the default K = min(N, 4) of each of the ``eval`` seeds (``rsb eval --instruction
  counterfactual``, ``semantic/counterfactual.py``).

An episode is digested as one canonical JSON line: question, options, letters, the option ->
candidate map, the answer, question and template ids, the instruction, the candidates and the
seed-derived layout (cells, positions to 0.01 mm, yaws to 1e-5 rad, by ``objects.layout`` without
the simulator, as the task places them). A variant's line holds its index and kind and the same
semantics, not the layout: a variant's layout is its scene's, pinned by ``eval`` (tested in
physics, tests/evaluation/test_counterfactual_physics.py). ``golden_episodes.json`` beside this module holds the
digests of ``version.BENCHMARK_VERSION`` on the pinned GSM8K / MMLU-Pro; ``scripts/pin_episodes.py``
writes it (docs/versions.md says when and how).
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from rsb_maniskill.semantic.digest import canonical_line, semantics  # the canonical form's one owner

GOLDEN_FILE = Path(__file__).with_name("golden_episodes.json")
COUNTERFACTUAL = "counterfactual"  # the digest of the counterfactual variants of the evaluation scenes
TRAIN_EPISODES = 500
POSITION_DECIMALS = 5  # metres: 0.01 mm
YAW_DECIMALS = 5  # radians


def episode_sets() -> dict[str, dict[str, Any]]:
    """What each digest covers: sampler settings and seeds (the protocol owns the evaluation's)."""
    from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE, EVAL_ENV_KWARGS, EVAL_SEED_BASE
    from rsb_maniskill.semantic.counterfactual import MAX_VARIANTS

    return {
        "eval": {**EVAL_ENV_KWARGS, "color_map": "fixed", "first_seed": EVAL_SEED_BASE,
                 "episodes": EPISODES_PER_SUITE},
        "train": {"split": "train", "instructions": "seen", "color_map": "fixed", "first_seed": 0,
                  "episodes": TRAIN_EPISODES},
        COUNTERFACTUAL: {**EVAL_ENV_KWARGS, "color_map": "fixed", "first_seed": EVAL_SEED_BASE,
                         "episodes": EPISODES_PER_SUITE, "variants": f"min(N, {MAX_VARIANTS})"},
    }


def canonical_episode(spec: Any, cells: list[int], xy: list[list[float]], yaw: list[float]) -> dict[str, Any]:
    """What pins an episode: its semantics and its layout (``objects.layout.episode_layouts``, rounded)."""
    return {**semantics(spec), "cells": cells, "xy": xy, "yaw": yaw}


def iter_variants(env_id: str, data_dir: str | os.PathLike | None = None) -> Iterator[dict[str, Any]]:
    """The canonical counterfactual variants of the ``counterfactual`` digest of ``env_id``."""
    from rsb_maniskill.objects.family import split_env_id
    from rsb_maniskill.semantic import EpisodeSampler
    from rsb_maniskill.semantic.counterfactual import variants

    suite_id, targets = split_env_id(env_id)
    cfg = episode_sets()[COUNTERFACTUAL]
    sampler = EpisodeSampler(suite_id, split=cfg["split"], instructions=cfg["instructions"],
                             color_map=cfg["color_map"], data_dir=data_dir, targets=targets)
    for seed in range(cfg["first_seed"], cfg["first_seed"] + cfg["episodes"]):
        for v in variants(sampler, seed):
            yield {"variant": v.index, "kind": v.kind, **semantics(v.spec)}


def iter_episodes(env_id: str, which: str, data_dir: str | os.PathLike | None = None) -> Iterator[dict[str, Any]]:
    """The canonical episodes of one digest (``which``: ``"eval"``, ``"train"`` or ``"counterfactual"``)
    of ``env_id``."""
    if which == COUNTERFACTUAL:
        yield from iter_variants(env_id, data_dir)
        return
    from rsb_maniskill.objects.family import get_family, split_env_id
    from rsb_maniskill.objects.layout import episode_layouts
    from rsb_maniskill.semantic import EpisodeSampler

    suite_id, targets = split_env_id(env_id)
    cfg = episode_sets()[which]
    sampler = EpisodeSampler(suite_id, split=cfg["split"], instructions=cfg["instructions"],
                             color_map=cfg["color_map"], data_dir=data_dir, targets=targets)
    specs = [sampler.episode(s) for s in range(cfg["first_seed"], cfg["first_seed"] + cfg["episodes"])]
    cells, xy, yaw = episode_layouts(get_family(targets), [s.candidates for s in specs], [s.seed for s in specs])
    xy = np.round(xy.astype(np.float64), POSITION_DECIMALS).tolist()
    yaw = np.round(yaw.astype(np.float64), YAW_DECIMALS).tolist()
    for spec, c, p, y in zip(specs, cells.tolist(), xy, yaw):
        yield canonical_episode(spec, c, p, y)


def suite_digests(env_id: str, data_dir: str | os.PathLike | None = None) -> dict[str, str]:
    """``{"eval": sha256, "train": sha256, "counterfactual": sha256}`` of one suite on this install."""
    out = {}
    for which in episode_sets():
        h = hashlib.sha256()
        for ep in iter_episodes(env_id, which, data_dir):
            h.update(canonical_line(ep))
        out[which] = h.hexdigest()
    return out


def all_env_ids() -> list[str]:
    """Every suite, blocks then everyday objects."""
    from rsb_maniskill.env_ids import resolve_env_ids

    return resolve_env_ids(["all", "all-objects"])


def compute(env_ids: Sequence[str] | None = None, data_dir: str | os.PathLike | None = None) -> dict[str, dict]:
    """``{env_id: {"eval": digest, ...}}``; a suite whose question data is missing
    raises :class:`~rsb_maniskill.semantic.DataNotFoundError`."""
    return {eid: suite_digests(eid, data_dir) for eid in (env_ids or all_env_ids())}


def document(digests: Mapping[str, Mapping[str, str]]) -> dict[str, Any]:
    """The golden file's content for the current benchmark version."""
    from rsb_maniskill.version import BENCHMARK_VERSION, benchmark_label

    return {"benchmark": benchmark_label(), "benchmark_version": BENCHMARK_VERSION, "episodes": episode_sets(),
            "suites": {k: dict(v) for k, v in digests.items()}}


def load(path: str | os.PathLike | None = None) -> dict[str, Any]:
    """A golden file (default: this package's)."""
    return json.loads(Path(path or GOLDEN_FILE).read_text(encoding="utf-8"))


def write(path: str | os.PathLike, doc: Mapping[str, Any]) -> None:
    Path(path).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")


def differences(digests: Mapping[str, Mapping[str, str]], pinned: Mapping[str, Any],
                new: bool = True) -> dict[str, list[str]]:
    """``{env_id: ["eval", ...]}``: the digests that differ from the pinned ones (a suite the pinned
    file lacks differs in all). ``new=False`` leaves out the kinds of digest a pinned suite does
    not hold yet (:func:`additions`: pinning a new kind of episode changes nothing pinned)."""
    out = {}
    for eid, ds in digests.items():
        have = pinned["suites"].get(eid, {})
        parts = [w for w, d in ds.items() if have.get(w) != d and (new or not have or w in have)]
        if parts:
            out[eid] = parts
    return out


def additions(digests: Mapping[str, Mapping[str, str]], pinned: Mapping[str, Any]) -> dict[str, list[str]]:
    """``{env_id: ["counterfactual", ...]}``: the kinds of digest a pinned suite does not hold yet."""
    out = {}
    for eid, ds in digests.items():
        have = pinned["suites"].get(eid, {})
        parts = [w for w in ds if have and w not in have]
        if parts:
            out[eid] = parts
    return out
