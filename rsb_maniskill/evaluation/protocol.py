"""The fixed evaluation protocol: which episodes every policy meets, and the instruction ablations.

Paper section 4.3: 500 episodes per suite on the evaluation (test) split with unseen instruction
templates. An episode is a pure function of (suite, split, seed) in the RSB tasks, so fixing the
seeds fixes the 500 scenes (question, option->block binding, layout) for every model.

Seeds are ``EVAL_SEED_BASE + i`` for i = 0..n-1, the same numbers for every suite. Demonstration
collection uses small seeds (0, 1, ... and q + k*P) on the train split; the evaluation seeds start
at ten million so that the two can never meet even if someone evaluates on the train split.

The counterfactual mode runs K variants of each of these scenes (``semantic/counterfactual.py``):
its episodes are (seed, variant) pairs, and the task takes the variant at reset.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np

from rsb_maniskill.evaluation.metrics import PAPER_OBJECT_SUITES, PAPER_SUITES, num_choices
from rsb_maniskill.evaluation.records import COUNTERFACTUAL, EVAL_INSTRUCTION_MODES, INSTRUCTION_MODES
from rsb_maniskill.objects.family import split_env_id
from rsb_maniskill.semantic.suites import SUITE_IDS

EVAL_SEED_BASE = 10_000_000
EPISODES_PER_SUITE = 500
# gym.make kwargs of the evaluation split (disjoint questions, unseen instruction templates).
EVAL_ENV_KWARGS: dict[str, str] = {"split": "test", "instructions": "unseen"}
# Seed of the shuffled-instruction pairing; fixed so every policy gets the same mismatches.
SHUFFLE_SEED = 0
# lerobot-eval seeds episode i of a run with --seed + i (default 1000): the LeRobot env maps that
# seed back to protocol episode i (integrations/lerobot_env.py, the lerobot_env_rsb plugin).
LEROBOT_SEED_BASE = 1000
# What the loops run: a seed, or in counterfactual mode (seed, variant): variant k of the scene
# of that seed, reset with options={"variant": k} (semantic/counterfactual.py).
Episode = int | tuple[int, int]

__all__ = [
    "COUNTERFACTUAL", "EPISODES_PER_SUITE", "EVAL_ENV_KWARGS", "EVAL_INSTRUCTION_MODES", "EVAL_SEED_BASE",
    "INSTRUCTION_MODES", "LEROBOT_SEED_BASE", "PAPER_OBJECT_SUITES", "PAPER_SUITES", "SHUFFLE_SEED", "SUITE_IDS",
    "ShuffledDonors", "apply_instruction_mode", "derangement", "episode_of", "eval_seeds", "mode_episodes",
    "num_choices", "scene_variants", "shuffled_instruction",
]


def eval_seeds(suite_id: str, n: int = EPISODES_PER_SUITE) -> list[int]:
    """Episode seeds of the evaluation protocol for ``suite_id``: ``[10_000_000, ..., 10_000_000 + n - 1]``.

    The first n of a longer run are the same episodes, so a 100-episode smoke test is a prefix of
    the full 500-episode evaluation.
    """
    return list(eval_seed_range(suite_id, n))


def eval_seed_range(suite_id: str, n: int = EPISODES_PER_SUITE) -> range:
    """:func:`eval_seeds` as a ``range``: what ``rsb eval`` hands the runner, so that ``-n`` costs no
    memory (the seeds are made as they are run, never listed)."""
    if split_env_id(suite_id)[0] not in SUITE_IDS:
        raise ValueError(f"unknown suite id {suite_id!r}; valid ids: {', '.join(SUITE_IDS)} (and each with -Objects)")
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    return range(EVAL_SEED_BASE, EVAL_SEED_BASE + n)


def scene_variants(suite_id: str, variants: int | None = None) -> int:
    """K, the counterfactual variants run per scene: ``variants``, else ``min(N, 4)`` (every
    candidate of a 4-choice scene); ValueError unless 2 <= K <= N."""
    from rsb_maniskill.semantic.counterfactual import check_variants, default_variants

    n = num_choices(suite_id)
    return check_variants(default_variants(n) if variants is None else variants, n)


def mode_episodes(seeds: Sequence[int], mode: str, variants: int | None = None) -> Sequence[Episode]:
    """The episodes an instruction mode runs on ``seeds``: the seeds themselves, or in counterfactual
    mode variants 0..K-1 of each, ``(seed, k)``, the variants of a scene one after the other. A
    ``range`` of seeds stays a range (lazy)."""
    if mode != COUNTERFACTUAL:
        return seeds if isinstance(seeds, range) else [int(s) for s in seeds]
    if variants is None:
        raise ValueError("counterfactual mode needs K, the variants per scene (protocol.scene_variants)")
    return [(int(s), k) for s in seeds for k in range(int(variants))]


def episode_of(item: Episode) -> tuple[int, int | None]:
    """(seed, variant) of an episode the loops run; variant None for a protocol episode."""
    return (int(item[0]), int(item[1])) if isinstance(item, tuple) else (int(item), None)


def record_episode(record: Mapping[str, Any]) -> Episode:
    """The episode a record is of, as :func:`mode_episodes` names it (so a resumed run skips it)."""
    if record.get("instruction_mode") == COUNTERFACTUAL:
        return int(record["seed"]), int(record.get("variant", 0))
    return int(record["seed"])


def variant_reset(options: Mapping[str, Any] | None, variants: Sequence[int | None]) -> dict | None:
    """Reset options that ask the task for ``variants`` (one per env, None: the protocol episode)."""
    if all(v is None for v in variants):
        return None if options is None else dict(options)
    return {**(options or {}), "variant": variants[0] if len(variants) == 1 else list(variants)}


def variant_fields(env: Any, i: int = 0) -> dict[str, Any]:
    """The record fields of the variant env ``i`` runs (``variant``, ``variant_kind``); empty for
    a protocol episode. ValueError when the task knows no variants."""
    variants = getattr(env.unwrapped, "episode_variants", None)
    if variants is None:
        raise ValueError("counterfactual mode needs an RSB task env (env.unwrapped.episode_variants)")
    v = variants[i]
    return {} if v is None else {"variant": int(v.index), "variant_kind": str(v.kind)}


def derangement(n: int, seed: int = SHUFFLE_SEED) -> list[int]:
    """Deterministic permutation with no fixed point: element i maps to ``donor[i] != i``.

    Built as one random cycle through all indices, so it depends only on (n, seed).
    """
    if n < 2:
        raise ValueError(f"a derangement needs at least 2 elements, got {n}")
    order = np.random.default_rng(seed).permutation(n)
    donor = [0] * n
    for k in range(n):
        donor[int(order[k])] = int(order[(k + 1) % n])
    return donor


def shuffled_instruction(instructions: Sequence[str], seed: int = SHUFFLE_SEED) -> list[str]:
    """Give episode i the instruction of another episode (``donor[i] != i``).

    Where the donor's text happens to equal episode i's own (same question and mapping), the next
    donor along the cycle is used, so no episode keeps its own instruction unless all texts are equal.
    """
    n = len(instructions)
    donor = derangement(n, seed)
    out = []
    for i in range(n):
        j = donor[i]
        for _ in range(n - 1):
            if instructions[j] != instructions[i]:
                break
            j = donor[j]
        out.append(instructions[j])
    return out


class ShuffledDonors:
    """Shuffled mode: episode ``seeds[i]`` is told the instruction of ``seeds[donor[i]]``.

    Same rule as :func:`shuffled_instruction` on the whole seed list (so resumed and uninterrupted
    runs agree, and ``rsb eval`` and the LeRobot env pair alike), with the instructions looked up
    lazily, one donor at a time: ``donors(seed, own)`` -> (donor seed, its instruction).
    """

    def __init__(self, seeds: Sequence[int], lookup: Callable[[int], str], shuffle_seed: int) -> None:
        self.seeds = list(seeds)
        self.index = {s: i for i, s in enumerate(self.seeds)}
        self.donor = derangement(len(self.seeds), shuffle_seed)
        self.lookup = lookup
        self.cache: dict[int, str] = {}

    @classmethod
    def of_env(cls, env: Any, suite_id: str, n: int) -> ShuffledDonors:
        """Donors over the protocol's first ``n`` evaluation episodes of ``suite_id``, with the
        instructions ``env``'s task draws for them (``episode_spec``: no simulation)."""
        task = env.unwrapped
        return cls(eval_seeds(suite_id, n), lambda s: task.episode_spec(s).instruction, SHUFFLE_SEED)

    def text(self, seed: int) -> str:
        if seed not in self.cache:
            self.cache[seed] = self.lookup(seed)
        return self.cache[seed]

    def __call__(self, seed: int, own: str) -> tuple[int, str]:
        j = self.donor[self.index[seed]]
        for _ in range(len(self.seeds) - 1):
            if self.text(self.seeds[j]) != own:
                break
            j = self.donor[j]
        return self.seeds[j], self.text(self.seeds[j])


def check_ablation_mode(mode: str, harness: str) -> None:
    """For a harness that gives one instruction per episode (the LeRobot env, the vla-eval
    benchmark): ValueError, one line, unless ``mode`` is an instruction ablation."""
    if mode == COUNTERFACTUAL:
        raise ValueError(f"instruction_mode 'counterfactual' runs K variants of each scene, under rsb eval only "
                         f"(rsb eval POLICY --instruction counterfactual); {harness} takes "
                         f"{', '.join(INSTRUCTION_MODES)}")
    if mode not in INSTRUCTION_MODES:
        raise ValueError(f"instruction_mode must be one of {', '.join(INSTRUCTION_MODES)}, got {mode!r}")


def apply_instruction_mode(instruction: str, mode: str, donor_instruction: str | None = None) -> str:
    """Instruction the policy sees: ``normal`` as is, ``blank`` empty, ``shuffled`` another episode's;
    ``counterfactual`` the variant's own, as is."""
    if mode in ("normal", COUNTERFACTUAL):
        return instruction
    if mode == "blank":
        return ""
    if mode == "shuffled":
        if donor_instruction is None:
            raise ValueError("instruction mode 'shuffled' needs the donor episode's instruction")
        return donor_instruction
    raise ValueError(f"instruction mode must be one of {EVAL_INSTRUCTION_MODES}, got {mode!r}")


def ablate(own: str, mode: str, donor: tuple[int, str] | None) -> tuple[str, dict[str, Any]]:
    """The instruction given in ``mode`` (``donor``: the shuffled mode's (seed, instruction), from
    :class:`ShuffledDonors`), and the record fields saying what was done (``donor_seed``,
    ``original_instruction``)."""
    extra: dict[str, Any] = {}
    if donor is not None:
        extra["donor_seed"] = donor[0]
    if mode not in ("normal", COUNTERFACTUAL):
        extra["original_instruction"] = own
    return apply_instruction_mode(own, mode, donor[1] if donor else None), extra
