"""Counterfactual variants of an evaluation scene: the same seed, layout and candidates, the
answer on another candidate.

TSR and nSG say whether a policy grounds the question; the variants say why not. Variant ``k`` of
the scene of seed ``s`` keeps everything physical (the layout is the seed's alone,
``objects/layout.py``; the candidates are the seed's draw) and changes only what the instruction
makes correct, so that the K variants of a scene have K different target candidates:

- variant 0, ``protocol``: the protocol episode itself (``sampler.episode(seed)``);
- odd k, ``remap``: the same question and option set with the answer bound to another candidate.
  Where candidates are named in the instruction (4-choice blocks, every everyday-object suite) the
  option -> candidate map is rotated; where a block carries its letter (10-choice blocks) the
  option texts are rotated over the letters instead. Either way one rotation of the scene's
  binding: same question, same options, the answer on candidate ``targets[k]``;
- even k > 0, ``requestion``: another question of the same (test) pool, drawn from the seed, its
  options rotated so that its answer lands on ``targets[k]``, the scene's option -> candidate map
  kept;
- Direct suites have no question or options: every k > 0 is a ``requestion`` that names
  ``targets[k]``.

``targets`` is the scene's target first, then the other candidates in an order drawn from the
seed, so within a scene the targets are distinct, and across scenes the target of every variant
is uniform over the candidates (the scene's target is). Everything is a pure function of the
sampler's settings, the seed and the variant index (never of K, never of the process), and only
the evaluation (test) pool is ever read: a variant shares no question with the train split.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rsb_maniskill.semantic.sampler import EpisodeSampler
from rsb_maniskill.semantic.spec import EpisodeSpec
from rsb_maniskill.semantic.stable import episode_rng

MODE = "counterfactual"  # the instruction mode that runs the variants (rsb eval, rsb audit)
MAX_VARIANTS = 4  # default K: min(N, MAX_VARIANTS) variants a scene
PROTOCOL, REMAP, REQUESTION = "protocol", "remap", "requestion"
KINDS = (PROTOCOL, REMAP, REQUESTION)
SALT = "counterfactual"  # the streams below are independent of every draw of the protocol episode


@dataclass(frozen=True)
class Variant:
    """Variant ``index`` of a scene: its kind and its episode (``spec.target_block`` its target)."""

    index: int
    kind: str
    spec: EpisodeSpec

    @property
    def target(self) -> int:
        return self.spec.target_block


def default_variants(n_choices: int) -> int:
    """K when none is asked for: every candidate of a 4-choice scene, four of a 10-choice one."""
    return min(int(n_choices), MAX_VARIANTS)


def check_variants(k: int, n_choices: int) -> int:
    """``k`` if a scene of ``n_choices`` candidates has that many variants (2..N), else ValueError."""
    if not 2 <= int(k) <= n_choices:
        raise ValueError(f"counterfactual variants: K must be 2..{n_choices} (one target per candidate), got {k}")
    return int(k)


def variant_kind(index: int, direct: bool = False) -> str:
    """What variant ``index`` varies: 0 the protocol episode, then remap (odd) and requestion (even);
    Direct suites, which have no options to remap, requestion (name another candidate) throughout."""
    if index == 0:
        return PROTOCOL
    return REQUESTION if direct or index % 2 == 0 else REMAP


def variant_targets(sampler: EpisodeSampler, scene: EpisodeSpec) -> tuple[int, ...]:
    """Every candidate, in the order the variants take them: the scene's target, then the rest in
    an order drawn from the seed (variant k targets ``[k]``)."""
    t0 = scene.target_block
    others = [c for c in range(sampler.n_choices) if c != t0]
    order = _rng(sampler, scene.seed, "targets").permutation(len(others))
    return (t0, *(others[int(i)] for i in order))


def variant(sampler: EpisodeSampler, seed: int, index: int) -> Variant:
    """Variant ``index`` (0..N-1) of the scene of ``seed``."""
    _check(sampler, index)
    scene = sampler.episode(seed)
    return _build(sampler, scene, variant_targets(sampler, scene), int(index))


def variants(sampler: EpisodeSampler, seed: int, k: int | None = None) -> list[Variant]:
    """Variants 0..K-1 of the scene of ``seed`` (K default :func:`default_variants`)."""
    k = check_variants(default_variants(sampler.n_choices) if k is None else k, sampler.n_choices)
    _check(sampler, k - 1)
    scene = sampler.episode(seed)
    targets = variant_targets(sampler, scene)
    return [_build(sampler, scene, targets, i) for i in range(k)]


# ---------------------------------------------------------------------------------- building
def _rng(sampler: EpisodeSampler, seed: int, stream: str) -> np.random.Generator:
    return episode_rng(sampler.suite_id, sampler.split, seed, f"{SALT}:{stream}")


def _check(sampler: EpisodeSampler, index: int) -> None:
    if sampler.split != "test":
        raise ValueError(f"counterfactual variants are evaluation scenes: the sampler must be of the test split, "
                         f"not {sampler.split!r}")
    if not 0 <= int(index) < sampler.n_choices:
        raise ValueError(f"variant index must be 0..{sampler.n_choices - 1} (one target per candidate), got {index}")


def _build(sampler: EpisodeSampler, scene: EpisodeSpec, targets: tuple[int, ...], index: int) -> Variant:
    kind = variant_kind(index, sampler.direct)
    target = targets[index]
    if kind == PROTOCOL:
        spec = scene
    elif sampler.direct:  # the Direct episode of this seed that names `target`
        spec = sampler.sample(scene.seed, question_index=target)
    elif kind == REMAP:
        spec = _remap(sampler, scene, target)
    else:
        spec = _onto(sampler, sampler.sample(scene.seed, question_index=_question(sampler, scene, index)), target)
    if spec.target_block != target or spec.candidates != scene.candidates:
        raise AssertionError(f"variant {index} of seed {scene.seed}: target {spec.target_block} != {target}")
    return Variant(index, kind, spec)


def _rotate(seq: tuple, shift: int) -> tuple:
    """``seq`` rotated right by ``shift``: item i moves to i + shift."""
    n = len(seq)
    return tuple(seq[(i - shift) % n] for i in range(n))


def _remap(sampler: EpisodeSampler, scene: EpisodeSpec, target: int) -> EpisodeSpec:
    """The scene's question and options with the answer bound to ``target`` by one rotation."""
    bo = scene.block_of_option
    if sampler.lettered:  # a block is its letter: the option texts move over the letters
        return _onto(sampler, scene, target)
    shift = (bo.index(target) - scene.answer_slot) % len(bo)  # bo'[slot] = bo[slot + shift] = target
    return sampler.rebind(scene, scene.options, scene.answer_slot, _rotate(bo, -shift))


def _onto(sampler: EpisodeSampler, spec: EpisodeSpec, target: int) -> EpisodeSpec:
    """``spec`` with its option texts rotated so that the answer sits on the option bound to ``target``."""
    slot = spec.block_of_option.index(target)
    shift = (slot - spec.answer_slot) % spec.n_choices
    return sampler.rebind(spec, _rotate(spec.options, shift), slot, spec.block_of_option)


def _question(sampler: EpisodeSampler, scene: EpisodeSpec, index: int) -> int:
    """The pool question of requestion variant ``index``: the j-th distinct draw of the seed's stream
    that is not the scene's question (j counts the requestion variants up to ``index``)."""
    j = sum(variant_kind(i, sampler.direct) == REQUESTION for i in range(1, index + 1))
    pool = sampler.num_questions
    if pool <= j:
        raise ValueError(f"{sampler.suite_id}: a pool of {pool} questions has too few for {j} requestion variants")
    rng, taken = _rng(sampler, scene.seed, "questions"), [scene.question_id]
    while len(taken) <= j:
        q = int(rng.integers(pool))
        if q not in taken:
            taken.append(q)
    return taken[j]
