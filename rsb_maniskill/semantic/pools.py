"""Question pools per (suite, split, data source), loaded once per process.

The 4- and 10-choice suites of a source share one pool. Each source's builder (the registry in
``suites.py``) makes its pools; a builder module may define ``clear_cache()`` for caches of its own.
"""
from __future__ import annotations

import os
import sys
from collections import Counter
from dataclasses import dataclass, field

from rsb_maniskill.resolve import resolve
from rsb_maniskill.semantic.data import REFILL_HINT, data_source_label, resolve_data_dir
from rsb_maniskill.semantic.distractors import Bins, value_bins
from rsb_maniskill.semantic.errors import EmptyDataError
from rsb_maniskill.semantic.records import Question
from rsb_maniskill.semantic.suites import SOURCES, check_split, suite_source


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


def data_key(data_dir: str | os.PathLike | None) -> str:
    """The question data a pool was built from: a resolved directory, or ``"hub"``."""
    root = resolve_data_dir(data_dir)
    return str(root.resolve()) if root is not None else "hub"


def get_pool(suite: str, split: str, data_dir: str | os.PathLike | None = None) -> Pool:
    """The cached pool of ``suite`` (a registered source with questions: "Math", "HardMath",
    "General") and ``split``; never empty (an episode's question is its seed modulo the pool's
    size): :class:`~.errors.EmptyDataError` instead."""
    check_split(split)
    try:
        source = suite_source(suite)
    except ValueError:
        source = None
    if source is None or source.direct:
        valid = ", ".join(s.name for s in SOURCES.values() if not s.direct)
        raise ValueError(f"unknown question source {suite!r}; valid: {valid}")
    key = (suite, split, data_key(data_dir) if source.reads_data else "")
    if key not in _POOLS:
        pool = resolve(source.pool, "question pool")(split, data_dir)
        if not len(pool):  # GSM8K's and MMLU-Pro's readers name the file at fault; this catches any source
            where = f"data: {data_source_label(data_dir)}" if source.reads_data else f"built by {source.pool}"
            raise EmptyDataError(f"the {suite} {split} question pool ({where}) holds no question: {REFILL_HINT}")
        _POOLS[key] = pool
    return _POOLS[key]


def clear_cache() -> None:
    """Forget loaded pools and the sources' own caches (tests; after changing $RSB_DATA_DIR)."""
    _POOLS.clear()
    for source in SOURCES.values():
        module = sys.modules.get((source.pool or "").partition(":")[0])
        if module is not None and hasattr(module, "clear_cache"):
            module.clear_cache()
