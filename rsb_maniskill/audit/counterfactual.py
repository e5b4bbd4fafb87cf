"""The shortcut audit of the counterfactual variants (``rsb eval --instruction counterfactual``).

The variants of an evaluation scene move the answer to other candidates (``semantic/
counterfactual.py``): a remap rebinds the same options, a requestion asks another test question.
Neither may open a shortcut, so the variants of the audited scenes get the protocol episodes'
audit (every named guesser, the instruction-wording guessers, both learned probes fit on the
train split, ambiguous option sets), and two checks of their own:

- guessers that know the variant index: "always option L in variant k", "always candidate b in
  variant k" (its colour, letter or object slot). Within a scene the K targets are distinct by
  construction; across scenes the target of every variant must stay uniform, else a policy that
  guessed which variant it meets would beat chance;
- the questions the variants ask, against the train pool: a requestion draws only from the test
  pool, so none may be a train question (exact, near-duplicate) or share its fact.
"""
from __future__ import annotations

import os
from typing import Sequence

from rsb_maniskill.audit.guessers import Guesser
from rsb_maniskill.audit.readers import BoundReader
from rsb_maniskill.audit.run import MARGIN, SuiteAudit, audit_specs, suite_name
from rsb_maniskill.audit.splits import SplitOverlap, split_overlap
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
from rsb_maniskill.objects.family import DEFAULT_TARGETS
from rsb_maniskill.semantic.counterfactual import variants
from rsb_maniskill.semantic.sampler import EpisodeSampler
from rsb_maniskill.semantic.spec import EpisodeSpec

TAG = "counterfactual"  # the audit row of a suite's variants: "RSB-Math-4 [counterfactual]"


def variant_episodes(sampler: EpisodeSampler, seeds: Sequence[int]) -> tuple[list[EpisodeSpec], list[int]]:
    """The default K variants of each scene ``seeds``, and each one's variant index."""
    specs, index = [], []
    for seed in seeds:
        for v in variants(sampler, seed):
            specs.append(v.spec)
            index.append(v.index)
    return specs, index


def index_guessers(specs: Sequence[EpisodeSpec], index: Sequence[int], n_choices: int,
                   letters: Sequence[str]) -> list[Guesser]:
    """Per variant index k >= 1 (variant 0 is the protocol episode, audited as such): always option
    L, always candidate b, on variant k's episodes (elsewhere they abstain: a uniform guess)."""
    of = dict(zip(specs, index))
    out = []
    for k in sorted(set(index) - {0}):
        out += [Guesser(f"letter {L} (variant {k})", f"always option {L} in variant {k}",
                        lambda sp, i=i, k=k: [float(j == i) for j in range(n_choices)] if of[sp] == k else None)
                for i, L in enumerate(letters)]
        out += [Guesser(f"block {b} (variant {k})", f"always physical candidate {b} in variant {k}",
                        lambda sp, b=b, k=k: [float(x == b) for x in sp.block_of_option] if of[sp] == k else None)
                for b in range(n_choices)]
    return out


def variant_overlap(train: EpisodeSampler, test: EpisodeSampler, specs: Sequence[EpisodeSpec]) -> SplitOverlap:
    """The variants' questions and facts that the train pool holds too (Direct: none)."""
    if train.pool is None or test.pool is None:
        return SplitOverlap()
    asked = [test.pool.questions[i] for i in sorted({sp.question_id for sp in specs})]
    tr = train.pool.questions
    return split_overlap([q.text for q in tr], [q.text for q in asked], [q.fact for q in tr], [q.fact for q in asked])


def audit_variants(suite_id: str, n: int = 3000, *, n_train: int | None = None,
                   data_dir: str | os.PathLike | None = None, margin: float = MARGIN,
                   targets: str = DEFAULT_TARGETS, perturb: dict[str, int] | None = None,
                   readers: Sequence[BoundReader] = ()) -> SuiteAudit:
    """Audit the variants of ``n`` evaluation scenes (``n`` x K episodes) of a suite; the probes fit
    on ``n_train`` (default ``n``) train-split episodes, as :func:`~.run.audit_suite` does."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    train_s = EpisodeSampler(suite_id, "train", data_dir=data_dir, targets=targets, perturb=perturb)
    test_s = EpisodeSampler(suite_id, "test", data_dir=data_dir, targets=targets, perturb=perturb)
    train = [train_s.episode(s) for s in range(n if n_train is None else n_train)]
    specs, index = variant_episodes(test_s, [EVAL_SEED_BASE + i for i in range(n)])
    return audit_specs(f"{suite_name(suite_id, targets, perturb)} [{TAG}]", train, specs, margin=margin,
                       overlap=variant_overlap(train_s, test_s, specs), read_instruction=True, readers=readers,
                       guessers=index_guessers(specs, index, test_s.n_choices, test_s.letters))
