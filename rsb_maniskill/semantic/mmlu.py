"""MMLU questions for RSB-General: filtering, the train/evaluation split, length balance.

The split is by *question*, up to wording: questions whose normal forms are equal or
near-duplicates (normalize.py, duplicates.py) form one group, and a group lands in one split.
"""
from __future__ import annotations

import re
from collections import Counter
from typing import Iterable

from .duplicates import duplicate_groups
from .normalize import numeric_values, option_key, overlap, question_key
from .records import Question, normalize_text
from .stable import stable_bucket, stable_key

TRAIN_PERCENT = 80
MAX_QUESTION_CHARS = 1000  # longer passages (e.g. professional law) make unusable robot instructions
MAX_OPTION_CHARS = 200
# Options that refer to other options ("All of the above", "A and B") break once options are
# reordered or extended to ten, so their questions are left out.
_REFERENTIAL = re.compile(r"of the (?:above|following|these|options)\b", re.IGNORECASE)
_LETTER_REF = re.compile(r"(?:\b(?:[Bb]oth|[Nn]either|[Oo]nly|[Oo]ptions?|[Cc]hoices?)\s+\(?[A-D]\)?(?![\w'])"
                         r"|^\(?[A-D]\)?\s*(?:,|and|or|&)\s*\(?[A-D]\)?(?!\w)|\b[A-D],? (?:and|or) [A-D]\b)")


def exclusion_reason(row: dict) -> str | None:
    """Why an MMLU row is left out of the pools (None if kept)."""
    q = normalize_text(row["question"])
    opts = [normalize_text(o) for o in row["choices"]]
    if len(q) > MAX_QUESTION_CHARS:
        return "question too long"
    if any(not o for o in opts):
        return "empty option"
    if max(len(o) for o in opts) > MAX_OPTION_CHARS:
        return "option too long"
    if len({option_key(o) for o in opts}) != 4:
        return "duplicate options"
    if any(_REFERENTIAL.search(o) or _LETTER_REF.search(o) for o in opts):
        return "option refers to other options"
    if numeric_values(opts) is not None:
        # MMLU writes numeric distractors around the answer: closest-to-the-mean picks it ~34 %
        return "numeric options centred on the answer"
    if any(overlap(o, q) for o in opts):
        # an option repeating a question word points at the question's own options among ten
        return "option shares a word with the question"
    return None


def longest_credit(options: tuple[str, ...], answer_index: int) -> float:
    """Expected score of "pick the longest option" (ties broken uniformly)."""
    lens = [len(o) for o in options]
    m = max(lens)
    return 1.0 / lens.count(m) if lens[answer_index] == m else 0.0


def to_question(row: dict, fact: str = "") -> Question:
    opts = tuple(normalize_text(o) for o in row["choices"])
    return Question(text=normalize_text(row["question"]), answer=opts[row["answer"]], source="mmlu",
                    group=row.get("subject", ""), choices=opts, origin=row.get("origin", ""), fact=fact)


def split_mmlu(rows: Iterable[dict]) -> tuple[dict[str, list[Question]], Counter]:
    """Kept questions per split ("train"/"test") in stable hash order, plus exclusion counts.

    A question's ``fact`` is the representative of its group of (near-)duplicates; the split
    hashes the fact, so a question and its near-duplicates always share a split.
    """
    kept: list[dict] = []
    excluded: Counter = Counter()
    for row in rows:
        why = exclusion_reason(row)
        if why:
            excluded[why] += 1
        else:
            kept.append(row)
    group = duplicate_groups(normalize_text(r["question"]) for r in kept)
    out: dict[str, list[tuple[bytes, Question]]] = {"train": [], "test": []}
    for row in kept:
        q = to_question(row)
        fact = group[question_key(q.text)]
        q = to_question(row, fact)
        split = "train" if stable_bucket("rsb-mmlu", fact) < TRAIN_PERCENT else "test"
        out[split].append((stable_key("rsb-mmlu-order", q.text, q.choices), q))
    return {s: [q for _, q in sorted(v, key=lambda kv: kv[0])] for s, v in out.items()}, excluded


def balanced_selection(questions: list[Question], limit: int | None, n_choices: int = 4) -> list[Question]:
    """Take questions in order while keeping "longest option is the answer" at <= 1/N (+0.5 slack).

    MMLU answers are the longest of their four options in about 28 % of questions; dropping
    some of those keeps the 4-choice longest-option rule at chance (25 %).
    """
    chosen: list[Question] = []
    credit = 0.0
    for q in questions:
        if limit is not None and len(chosen) >= limit:
            break
        c = longest_credit(q.choices, q.choices.index(q.answer))
        if credit + c <= (len(chosen) + 1) / n_choices + 0.5:
            chosen.append(q)
            credit += c
    return chosen


