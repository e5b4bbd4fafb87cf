"""Question pools per (suite, split, data source), loaded once per process.

The 4- and 10-choice suites of a subset share one pool (paper section 4.1).
"""
from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from . import commonsense, mmlu
from .data import mmlu_rows, resolve_data_dir
from .distractors import SortedAnswers, rank_weights
from .gsm8k import gsm8k_pool
from .math_source import math_pool
from .records import Question
from .suites import SUITES, check_split

GENERAL_TRAIN_SIZE = 10_000


@dataclass
class Pool:
    """Questions of one suite and split, with what distractor generation needs precomputed."""

    suite: str
    split: str
    questions: tuple[Question, ...]
    candidates: tuple[tuple[str, ...] | None, ...] = ()  # commonsense: distractor texts per question
    source_counts: dict[str, int] = field(default_factory=dict)
    excluded: Counter = field(default_factory=Counter)
    _subject_answers: dict[str, SortedAnswers] = field(default_factory=dict, repr=False)
    _all_answers: SortedAnswers | None = field(default=None, repr=False)
    _rank_w: dict[int, np.ndarray] = field(default_factory=dict, repr=False)
    _p_longest: float | None = field(default=None, repr=False)
    fallback_answers: tuple[str, ...] = ()  # MMLU answers of both splits, for tiny subjects/pools
    _fallback: SortedAnswers | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.questions)

    def rank_weights(self, n: int) -> np.ndarray:
        if n not in self._rank_w:
            self._rank_w[n] = rank_weights([q.value for q in self.questions if q.numeric], n)
        return self._rank_w[n]

    def subject_answers(self, subject: str) -> SortedAnswers:
        """Answers of this pool's MMLU questions of ``subject`` (10-choice distractors)."""
        if not self._subject_answers:
            by: dict[str, list[str]] = {}
            for q in self.questions:
                if q.source == "mmlu":
                    by.setdefault(q.group, []).append(q.answer)
            self._subject_answers = {s: SortedAnswers(v) for s, v in by.items()}
        return self._subject_answers[subject]

    def all_answers(self) -> SortedAnswers:
        if self._all_answers is None:
            self._all_answers = SortedAnswers([q.answer for q in self.questions if q.source == "mmlu"])
        return self._all_answers

    def fallback(self) -> SortedAnswers:
        if self._fallback is None:
            self._fallback = SortedAnswers(self.fallback_answers)
        return self._fallback

    def p_longest(self) -> float:
        """Share of MMLU questions whose answer is the longest of its own four options."""
        if self._p_longest is None:
            m = [mmlu.answer_is_longest(q) for q in self.questions if q.source == "mmlu"]
            self._p_longest = float(np.mean(m)) if m else 0.25
        return self._p_longest


_POOLS: dict[tuple[str, str, str], Pool] = {}
_MMLU: dict[str, tuple[dict[str, list[Question]], Counter]] = {}


def _dir_key(data_dir: str | os.PathLike | None) -> str:
    root = resolve_data_dir(data_dir)
    return str(root.resolve()) if root is not None else "hub"


def _mmlu_split(data_dir: str | os.PathLike | None) -> tuple[dict[str, list[Question]], Counter]:
    key = _dir_key(data_dir)
    if key not in _MMLU:
        _MMLU[key] = mmlu.split_mmlu(mmlu_rows(data_dir))
    return _MMLU[key]


def _general(split: str, data_dir: str | os.PathLike | None) -> Pool:
    cs = commonsense.commonsense_pool(split)
    by_split, excluded = _mmlu_split(data_dir)
    limit = GENERAL_TRAIN_SIZE - len(cs) if split == "train" else None
    mq = mmlu.balanced_selection(by_split[split], limit)
    questions = tuple(q for q, _ in cs) + tuple(mq)
    cands = tuple(c for _, c in cs) + (None,) * len(mq)
    everything = tuple(q.answer for qs in by_split.values() for q in qs)
    return Pool("General", split, questions, cands, {"commonsense": len(cs), "mmlu": len(mq)}, excluded,
                fallback_answers=everything)


def get_pool(suite: str, split: str, data_dir: str | os.PathLike | None = None) -> Pool:
    """The cached pool of ``suite`` ("Math", "HardMath", "General") and ``split``."""
    check_split(split)
    if suite not in SUITES or suite == "Direct":
        raise ValueError(f"unknown question source {suite!r}; valid: Math, HardMath, General")
    key = (suite, split, "" if suite == "Math" else _dir_key(data_dir))
    if key not in _POOLS:
        if suite == "Math":
            qs = math_pool(split)
            pool = Pool(suite, split, qs, (None,) * len(qs), {"math": len(qs)})
        elif suite == "HardMath":
            qs = gsm8k_pool(split, data_dir)
            pool = Pool(suite, split, qs, (None,) * len(qs), {"gsm8k": len(qs)})
        else:
            pool = _general(split, data_dir)
        _POOLS[key] = pool
    return _POOLS[key]


def clear_cache() -> None:
    """Forget loaded pools (tests; after changing $RSB_DATA_DIR)."""
    _POOLS.clear()
    _MMLU.clear()
    math_pool.cache_clear()
    commonsense.commonsense_pool.cache_clear()

