"""Question pools per (suite, split, data source), loaded once per process.

The 4- and 10-choice suites of a subset share one pool.
"""
from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field

from . import commonsense, mmlu_pro
from .data import mmlu_pro_rows, resolve_data_dir
from .distractors import Bins, value_bins
from .gsm8k import gsm8k_pool
from .math_source import math_pool
from .records import Question
from .suites import SUITES, check_split


@dataclass
class Pool:
    """Questions of one suite and split, with what option generation needs precomputed."""

    suite: str
    split: str
    questions: tuple[Question, ...]
    # commonsense: (weighted distractor candidates, answer weight) per question; None elsewhere
    candidates: tuple[tuple[tuple[tuple[str, float], ...], float] | None, ...] = ()
    source_counts: dict[str, int] = field(default_factory=dict)
    excluded: Counter = field(default_factory=Counter)
    _bins: dict[tuple[int, str, int], Bins | None] = field(default_factory=dict, repr=False)

    def __len__(self) -> int:
        return len(self.questions)

    def value_bins(self, n: int, group: str, decimals: int) -> Bins | None:
        """Bins of this pool's numeric answers of one group (Math: operation) and format; None
        when there are fewer than N distinct magnitudes (the sampler then uses a lattice)."""
        key = (n, group, decimals)
        if key not in self._bins:
            vals = [q.value for q in self.questions if q.numeric and q.group == group and q.decimals == decimals]
            try:
                self._bins[key] = value_bins(vals, n)
            except ValueError:
                self._bins[key] = None
        return self._bins[key]


_POOLS: dict[tuple[str, str, str], Pool] = {}
_MMLU_PRO: dict[str, tuple[dict[str, list[Question]], Counter]] = {}


def _dir_key(data_dir: str | os.PathLike | None) -> str:
    root = resolve_data_dir(data_dir)
    return str(root.resolve()) if root is not None else "hub"


def _mmlu_pro_split(data_dir: str | os.PathLike | None) -> tuple[dict[str, list[Question]], Counter]:
    key = _dir_key(data_dir)
    if key not in _MMLU_PRO:
        _MMLU_PRO[key] = mmlu_pro.split_questions(mmlu_pro_rows(data_dir))
    return _MMLU_PRO[key]


def _general(split: str, data_dir: str | os.PathLike | None) -> Pool:
    cs = commonsense.commonsense_pool(split)
    by_split, excluded = _mmlu_pro_split(data_dir)
    mq, dropped = mmlu_pro.balanced_selection(by_split[split])
    excluded = excluded + Counter({"answer rank balance (this split)": dropped}) if dropped else excluded
    questions = tuple(item.question for item in cs) + tuple(mq)
    cands = tuple((item.candidates, item.answer_weight) for item in cs) + (None,) * len(mq)
    return Pool("General", split, questions, cands, {"commonsense": len(cs), "mmlu_pro": len(mq)}, excluded)


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
    _MMLU_PRO.clear()
    math_pool.cache_clear()
    commonsense.commonsense_pool.cache_clear()
