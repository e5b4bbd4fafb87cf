"""Split hygiene: questions (exact, normalised, near-duplicate) and facts shared by train and test."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

from rsb_maniskill.semantic.duplicates import near_duplicate_pairs
from rsb_maniskill.semantic.normalize import question_key


@dataclass
class SplitOverlap:
    exact: list[str] = field(default_factory=list)  # normalised question texts in both splits
    near: list[tuple[str, str, float]] = field(default_factory=list)  # (train, test, jaccard)
    facts: list[str] = field(default_factory=list)  # fact ids in both splits

    @property
    def clean(self) -> bool:
        return not (self.exact or self.near or self.facts)


def split_overlap(train_questions: Iterable[str], test_questions: Iterable[str],
                  train_facts: Iterable[str] = (), test_facts: Iterable[str] = ()) -> SplitOverlap:
    """Everything the two splits share: normalised questions, near-duplicates, facts."""
    train_q, test_q = [q for q in train_questions if q], [q for q in test_questions if q]
    exact = sorted({question_key(q) for q in train_q} & {question_key(q) for q in test_q})
    facts = sorted(set(f for f in train_facts if f) & set(f for f in test_facts if f))
    train_k, test_k = [question_key(q) for q in train_q], [question_key(q) for q in test_q]
    return SplitOverlap(exact, near_duplicate_pairs(train_k, test_k), facts)
