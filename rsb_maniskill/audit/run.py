"""Audit of one suite: named guessers, the learned probes (surface and lexical), ambiguous option
sets, split overlap, and question-aware readers as references (``reference.py``)."""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np

from rsb_maniskill.audit.guessers import Guesser, candidate_guessers, credit, named_guessers
from rsb_maniskill.audit.lexical import lexical_probe
from rsb_maniskill.audit.probe import learned_probe
from rsb_maniskill.audit.readers import BoundReader
from rsb_maniskill.audit.reference import ReaderResult, read
from rsb_maniskill.audit.reference import rate as _rate
from rsb_maniskill.audit.splits import SplitOverlap, split_overlap
from rsb_maniskill.audit.wording import instruction_guessers
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
from rsb_maniskill.objects.family import DEFAULT_TARGETS
from rsb_maniskill.semantic.normalize import option_key
from rsb_maniskill.semantic.sampler import EpisodeSampler
from rsb_maniskill.semantic.spec import EpisodeSpec
from rsb_maniskill.semantic.suites import SUITES, suite_source

MARGIN = 0.03  # a guesser fails the audit when its whole 95 % interval lies above chance + 3 points
MIN_SUBSET = 100  # smallest number of episodes a guesser must apply to for its own verdict
MIN_PROBE_TRAIN = 200  # train-split episodes the learned probes need to be fit at all
LEXICAL_PROBE = "lexical probe"
_EXAMPLES = 5


@dataclass
class GuesserResult:
    name: str
    description: str
    kind: str  # "named" | "learned"
    reads_question: bool
    accuracy: float
    low: float
    high: float
    applies: int  # episodes where the rule could tell options apart (others: uniform guess)
    applies_accuracy: float | None = None
    applies_low: float | None = None
    applies_high: float | None = None
    flagged: bool = False


@dataclass
class SuiteAudit:
    suite_id: str
    split: str
    n_choices: int
    episodes: int
    train_episodes: int
    margin: float
    guessers: list[GuesserResult]
    probe_features: list[tuple[str, float]]
    ambiguous: int
    ambiguous_examples: list[list[str]]
    overlap: SplitOverlap = field(default_factory=SplitOverlap)
    readers: list[ReaderResult] = field(default_factory=list)  # references: never fail the suite alone
    # the lexical probe's heaviest n-grams: (n-gram, weight, audited options holding it) per side
    answer_tokens: list[tuple[str, float, int]] = field(default_factory=list)
    distractor_tokens: list[tuple[str, float, int]] = field(default_factory=list)

    @property
    def chance(self) -> float:
        return 1.0 / self.n_choices

    @property
    def flagged(self) -> list[GuesserResult]:
        return [g for g in self.guessers if g.flagged]

    @property
    def passed(self) -> bool:
        return not self.flagged and self.ambiguous == 0 and self.overlap.clean

    @property
    def worst(self) -> GuesserResult:
        """The guesser furthest above chance (by interval low end)."""
        return max(self.guessers, key=lambda g: g.low)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.update(chance=self.chance, passed=self.passed,
                 overlap=dict(exact=len(self.overlap.exact), near=len(self.overlap.near), facts=len(self.overlap.facts),
                              examples=dict(exact=self.overlap.exact[:_EXAMPLES], near=self.overlap.near[:_EXAMPLES],
                                            facts=self.overlap.facts[:_EXAMPLES])))
        return d


def _result(name: str, desc: str, kind: str, reads_q: bool, credits: np.ndarray, applies: np.ndarray,
            chance: float, margin: float, clusters: np.ndarray) -> GuesserResult:
    acc, lo, hi = _rate(credits, clusters)
    r = GuesserResult(name, desc, kind, reads_q, acc, lo, hi, int(applies.sum()))
    flagged = lo > chance + margin
    if MIN_SUBSET <= r.applies < len(credits):
        r.applies_accuracy, r.applies_low, r.applies_high = _rate(credits[applies], clusters[applies])
        flagged = flagged or r.applies_low > chance + margin
    r.flagged = bool(flagged)
    return r


def question_clusters(specs: Sequence[EpisodeSpec]) -> list[tuple]:
    """The dependent groups of an audit: episodes that ask the same question.

    A pool holds fewer questions than an audit draws episodes (RSB-HardMath's 1,319 test questions
    for 3,000 scenes; a counterfactual scene asks its question in three of its four variants), and
    what a guesser reads of a question is the same each time it is asked: the evidence is the
    questions. A Direct suite asks none (its instruction names the target): each episode stands
    alone."""
    asks = {name: name in SUITES and suite_source(name).pool is not None for name in {sp.suite for sp in specs}}
    return [(sp.suite, sp.split, sp.question_id if asks[sp.suite] else f"seed {sp.seed}") for sp in specs]


def ambiguous_sets(specs: Sequence[EpisodeSpec]) -> list[list[str]]:
    """Option sets where another option has the answer's normal form (two correct members)."""
    out = []
    for sp in specs:
        keys = [option_key(o) for o in sp.options]
        if keys.count(keys[sp.answer_slot]) > 1:
            out.append(list(sp.options))
    return out


def audit_specs(suite_id: str, train: Sequence[EpisodeSpec], test: Sequence[EpisodeSpec], *,
                split: str = "test", margin: float = MARGIN, overlap: SplitOverlap | None = None,
                seed: int = 0, read_instruction: bool = False,
                readers: Sequence[BoundReader] = (), guessers: Sequence[Guesser] = ()) -> SuiteAudit:
    """Audit ``test`` episodes; the learned probe is fit on ``train`` episodes (never the same seeds).
    ``read_instruction``: also the guessers of the instruction's wording (``wording.py``).
    ``readers``: question-aware readers scored as reference rows (``readers.py``).
    ``guessers``: more named guessers (the counterfactual variants' index guessers).
    Every interval counts the episodes that ask one question (:func:`question_clusters`) by their
    effective size (``reference.rate``)."""
    if not test:
        raise ValueError(f"{suite_id}: no episodes to audit")
    n = test[0].n_choices
    if any(sp.n_choices != n for sp in list(train) + list(test)):
        raise ValueError(f"{suite_id}: episodes with different numbers of choices cannot be audited together")
    chance = 1.0 / n
    ids: dict[tuple, int] = {}  # a group's key -> 0, 1, ...
    groups = np.array([ids.setdefault(key, len(ids)) for key in question_clusters(test)], dtype=np.int64)
    results = []
    extra = instruction_guessers(test) if read_instruction else []
    for g in named_guessers(n, test[0].letters) + candidate_guessers(test) + extra + list(guessers):
        cr, ap = np.empty(len(test)), np.zeros(len(test), dtype=bool)
        for i, sp in enumerate(test):
            s = g.score(sp)
            if s is None or len(set(s)) == 1:
                cr[i] = chance
            else:
                cr[i], ap[i] = credit(s, sp.answer_slot), True
        results.append(_result(g.name, g.description, "named", g.reads_question, cr, ap, chance, margin, groups))
    features: list[tuple[str, float]] = []
    tokens: tuple[list, list] = ([], [])
    if len(train) >= MIN_PROBE_TRAIN:
        probe = learned_probe(train, test, seed=seed, use_prior=split != "train")
        features = probe.top_features
        results.append(_result("learned probe", "gradient-boosted trees on per-option features relative to the set, "
                               f"fit on {probe.train_episodes:,} train-split episodes; never sees the question",
                               "learned", False, probe.credits, np.ones(len(test), dtype=bool), chance, margin,
                               groups))
    if len(train) >= MIN_PROBE_TRAIN and split != "train":  # memorised answers are no shortcut on the train split
        lex = lexical_probe(train, test, seed=seed)
        tokens = (lex.answer_tokens, lex.distractor_tokens)
        results.append(_result(LEXICAL_PROBE, "logistic regression on each option's word 1-2 grams, character 2-5 "
                               f"grams and the words it shares with its set, fit on {lex.train_episodes:,} "
                               "train-split episodes; never sees the question", "learned", False, lex.credits,
                               np.ones(len(test), dtype=bool), chance, margin, groups))
    amb = ambiguous_sets(test)
    return SuiteAudit(suite_id, split, n, len(test), len(train), margin, results, features, len(amb),
                      amb[:_EXAMPLES], overlap or SplitOverlap(), [read(r, test, groups) for r in readers], *tokens)


def suite_overlap(train: EpisodeSampler, test: EpisodeSampler) -> SplitOverlap:
    """Questions and facts the two pools of a suite share (Direct suites have no questions)."""
    if train.pool is None or test.pool is None:
        return SplitOverlap()
    tr, te = train.pool.questions, test.pool.questions
    return split_overlap([q.text for q in tr], [q.text for q in te], [q.fact for q in tr], [q.fact for q in te])


def suite_name(suite_id: str, targets: str = DEFAULT_TARGETS, perturb: dict[str, int] | None = None) -> str:
    """The audit row of a suite: its env id, with the language perturbation in brackets."""
    name = suite_id if targets == DEFAULT_TARGETS else f"{suite_id}-{targets.capitalize()}"
    if perturb:
        from rsb_maniskill.perturb import label

        name += f" [{label(perturb)}]"
    return name


def audit_suite(suite_id: str, split: str = "test", n: int = 3000, *, n_train: int | None = None,
                data_dir: str | os.PathLike | None = None, margin: float = MARGIN,
                targets: str = DEFAULT_TARGETS, perturb: dict[str, int] | None = None,
                readers: Sequence[BoundReader] = ()) -> SuiteAudit:
    """Audit ``n`` episodes of ``split`` (the evaluation protocol's seeds) of a suite.

    The probe trains on ``n_train`` (default ``n``) train-split episodes of seeds 0, 1, ...; the
    audited episodes use seeds from ``EVAL_SEED_BASE`` on, so the two never share a seed.
    ``perturb``: language robustness axes (``{"lang_layout": 2}``) worded into both splits.
    ``readers``: question-aware readers scored as reference rows.
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    train_s = EpisodeSampler(suite_id, "train", data_dir=data_dir, targets=targets, perturb=perturb)
    test_s = train_s if split == "train" else EpisodeSampler(suite_id, split, data_dir=data_dir, targets=targets,
                                                             perturb=perturb)
    train = [train_s.episode(s) for s in range(n if n_train is None else n_train)]
    test = [test_s.episode(EVAL_SEED_BASE + i) for i in range(n)]
    overlap = suite_overlap(train_s, test_s if split == "test" else EpisodeSampler(suite_id, "test", data_dir=data_dir))
    return audit_specs(suite_name(suite_id, targets, perturb), train, test, split=split, margin=margin,
                       overlap=overlap, read_instruction=bool(perturb), readers=readers)
