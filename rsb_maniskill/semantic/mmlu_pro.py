"""MMLU-Pro questions for RSB-General: filtering, the train/evaluation split, answer-rank balance.

RSB-General-10 shows a question's own ten options, written for it by the MMLU-Pro authors, so
every option is about the question. RSB-General-4 shows, for a question MMLU-Pro took from MMLU,
MMLU's own four options (written by people; MMLU-Pro's six added options carry words that mark
them as distractors), and otherwise the answer and three of its other nine. Both suites draw on
one pool. Only questions with ten distinct options enter it.

The split is by *question*, up to wording: questions whose normal forms are equal or
near-duplicates (normalize.py, duplicates.py) form one group, and a group lands in one split.
"""
from __future__ import annotations

import re
from collections import Counter
from functools import lru_cache
from itertools import combinations
from pathlib import Path
from typing import Collection, Iterable, Sequence

import numpy as np

from rsb_maniskill.objects.family import BLOCK_COLORS
from rsb_maniskill.semantic.data import empty_data_error
from rsb_maniskill.semantic.duplicates import duplicate_groups
from rsb_maniskill.semantic.normalize import leading_numbers, option_key, question_key, similarity_matrix
from rsb_maniskill.semantic.records import Question, normalize_text
from rsb_maniskill.semantic.stable import stable_bucket, stable_key

N_OPTIONS = 10  # the pool holds questions with ten options of their own (RSB-General-10 shows all)
TRAIN_PERCENT = 80  # of question groups: the evaluation pool keeps over 1,000 questions
MAX_QUESTION_CHARS = 1000  # longer passages (e.g. professional law) make unusable robot instructions
MAX_OPTION_CHARS = 200
SHARED_OPTION_LIMIT = 5  # an option text in this many questions or more marks a formula option set
SPREAD_TOLERANCE = 0.05  # General-4 draws among the distractor triples this close to the least alike
RANK_SLACK = 0.01  # how far above 1/N the share of one answer rank may go (balanced_selection)
SHOWN = (N_OPTIONS, 4)  # options shown by RSB-General-10 and RSB-General-4
# Options that refer to other options ("All of the above", "A and B") break once options are
# reordered or cut to four, so their questions are left out.
_REFERENTIAL = re.compile(r"of the (?:above|following|these|options)\b", re.IGNORECASE)
_LETTER_REF = re.compile(r"(?:\b(?:[Bb]oth|[Nn]either|[Oo]nly|[Oo]ptions?|[Cc]hoices?)\s+\(?[A-J]\)?(?![\w'])"
                         r"|^\(?[A-J]\)?\s*(?:,|and|or|&)\s*\(?[A-J]\)?(?!\w)|\b[A-J],? (?:and|or) [A-J]\b)")
# A question that labels its own parts "(A)", "(B)" reads as if those were the options, whose
# letters name the blocks; such questions are left out.
_LETTER_LABEL = re.compile(r"\([A-J]\)")
# An option naming a block colour would be bound to a block of another colour ("A <- yellow
# (red block)") in the coloured-block suites, so such questions are left out of the pool.
_BLOCK_COLOR = re.compile(r"\b(?:" + "|".join(BLOCK_COLORS) + r")\b", re.IGNORECASE)


FILTERED = Path(__file__).with_name("mmlu_pro_filtered.txt")  # scripts/filter_general.py
MMLU_OPTIONS = Path(__file__).with_name("mmlu_pro_mmlu_options.txt")  # scripts/mmlu_options.py


def content_key(row: dict) -> str:
    """A question's identity by content (its normal form and its answer's), stable across releases
    and ids: the key the shipped lists use."""
    q = question_key(normalize_text(row["question"]))
    a = option_key(normalize_text(row["choices"][row["answer"]]))
    return stable_key("rsb-mmlu-pro-question", q, a).hex()[:16]


def option_hash(text: str) -> str:
    """An option's identity by its normal form (the shipped MMLU-options list names options so)."""
    return stable_key("rsb-mmlu-pro-option", option_key(normalize_text(text))).hex()[:12]


def _shipped_lines(path: Path) -> list[list[str]]:
    lines = path.read_text(encoding="utf-8").splitlines()
    return [x.split() for x in lines if x.strip() and not x.startswith("#")]


@lru_cache(maxsize=1)
def filtered_out() -> frozenset[str]:
    """Content keys of the questions the adversarial filter leaves out (shipped data)."""
    return frozenset(x[0] for x in _shipped_lines(FILTERED))


@lru_cache(maxsize=1)
def mmlu_distractors() -> dict[str, frozenset[str]]:
    """Content key -> option hashes of MMLU's own three distractors, for the questions MMLU-Pro
    took from MMLU (shipped data: which of the ten options MMLU wrote)."""
    return {x[0]: frozenset(x[1:]) for x in _shipped_lines(MMLU_OPTIONS)}


def core_options(row: dict) -> tuple[str, ...] | None:
    """MMLU's own four options of a row (answer included, in MMLU-Pro's order), or None when the
    question is not MMLU's or its options are not all among the ten."""
    own = mmlu_distractors().get(content_key(row))
    if own is None:
        return None
    opts = [normalize_text(o) for o in row["choices"]]
    core = tuple(o for i, o in enumerate(opts) if i == row["answer"] or option_hash(o) in own)
    return core if len(core) == 4 else None


def exclusion_reason(row: dict) -> str | None:
    """Why an MMLU-Pro row is left out of the pool (None if kept)."""
    q = normalize_text(row["question"])
    opts = [normalize_text(o) for o in row["choices"]]
    if len(opts) != N_OPTIONS:
        return f"fewer than {N_OPTIONS} options"
    if len(q) > MAX_QUESTION_CHARS:
        return "question too long"
    if any(not o for o in opts):
        return "empty option"
    if max(len(o) for o in opts) > MAX_OPTION_CHARS:
        return "option too long"
    if len({option_key(o) for o in opts}) != N_OPTIONS:
        return "duplicate options"
    if any(_REFERENTIAL.search(o) or _LETTER_REF.search(o) for o in opts):
        return "option refers to other options"
    if _LETTER_LABEL.search(q):
        return "question labels its parts with option letters"
    if leading_numbers(opts) is not None:
        # numeric distractors are written around the answer, with or without words after the
        # number ("240 grams, 6.5 grams"): the answer is one of the two middle values ~45 % of the time
        return "numeric options centred on the answer"
    if any(_BLOCK_COLOR.search(o) for o in opts):
        return "option names a block colour"
    return None


def rank_profile(values: Sequence[float], answer: int) -> np.ndarray:
    """Where the answer ranks among its options by ``values``: a distribution over the N ranks
    (0 = smallest), a tie spread evenly over the ranks it covers (a rule picks among ties at random)."""
    v = np.asarray(values, dtype=float)
    below = int((v < v[answer]).sum())
    tied = int((v == v[answer]).sum())
    out = np.zeros(len(v))
    out[below:below + tied] = 1.0 / tied
    return out


def surface_ranks(q: Question) -> np.ndarray:
    """The answer's rank profiles among its options by surface readings that give MMLU-Pro's
    answers away: length in characters and in words, and similarity to the other options (mean
    and highest character-trigram Jaccard; distractors written as variants of the answer make it
    the set's medoid and give it a near twin)."""
    a = q.choices.index(q.answer)
    sim = similarity_matrix(q.choices)
    readings = ([len(o) for o in q.choices], [len(o.split()) for o in q.choices], np.nanmean(sim, axis=1),
                np.nanmax(sim, axis=1))
    return np.stack([rank_profile(r, a) for r in readings])


def area(row: dict) -> str:
    """Subject of a row: MMLU's subject for questions taken from MMLU, else MMLU-Pro's category."""
    src = str(row.get("src", ""))
    return src[len("ori_mmlu-"):] if src.startswith("ori_mmlu-") else str(row.get("subject", ""))


def to_question(row: dict, fact: str = "") -> Question:
    """A pool question of an MMLU-Pro row: ``group`` its :func:`area`, ``category`` MMLU-Pro's own
    category (the reader's ``subject``)."""
    opts = tuple(normalize_text(o) for o in row["choices"])
    return Question(text=normalize_text(row["question"]), answer=opts[row["answer"]], source="mmlu_pro",
                    group=area(row), choices=opts, core=core_options(row), origin=row.get("origin", ""), fact=fact,
                    category=str(row.get("subject", "")))


def _facts(rows: list[dict]) -> list[str]:
    """One fact per row, shared by rows that must land in one split: (near-)duplicate questions,
    and questions that share an option text (seen as a distractor in training, an option is
    struck off at evaluation; seen as an answer, it is picked)."""
    group = duplicate_groups(normalize_text(r["question"]) for r in rows)
    parent = {g: g for g in group.values()}

    def find(k: str) -> str:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    holder: dict[str, str] = {}
    reps = [group[question_key(normalize_text(r["question"]))] for r in rows]
    for rep, row in zip(reps, rows):
        for key in {option_key(normalize_text(o)) for o in row["choices"]}:
            a, b = find(rep), find(holder.setdefault(key, rep))
            if a != b:
                parent[max(a, b)] = min(a, b)
    return [find(rep) for rep in reps]


def eligible(rows: Iterable[dict]) -> tuple[list[dict], Counter]:
    """Rows that can enter the pool, and why the others cannot (counts)."""
    kept: list[dict] = []
    excluded: Counter = Counter()
    for row in rows:
        why = exclusion_reason(row)
        if why:
            excluded[why] += 1
        else:
            kept.append(row)
    # Formula options shared by many questions ("True, True", "I and III only", "0") would chain
    # hundreds of questions into one group (_facts); their sets are left out.
    shared = Counter(k for r in kept for k in {option_key(normalize_text(o)) for o in r["choices"]})
    formula = [any(shared[option_key(normalize_text(o))] >= SHARED_OPTION_LIMIT for o in r["choices"]) for r in kept]
    if any(formula):
        excluded["option shared by many questions"] += sum(formula)
    return [r for r, f in zip(kept, formula) if not f], excluded


def split_questions(rows: Iterable[dict], filtered: Collection[str] | None = None,
                    ) -> tuple[dict[str, list[Question]], Counter]:
    """Kept questions per split ("train"/"test") in stable hash order, plus exclusion counts.

    ``filtered``: content keys of eligible questions to leave out (default: the shipped
    :func:`filtered_out`). A question's ``fact`` names its group (``_facts``); the split
    hashes the fact, so the two splits share no question, near-duplicate or option text.
    """
    rows = list(rows)
    kept, excluded = eligible(rows)
    drop = filtered_out() if filtered is None else filtered
    n = len(kept)
    kept = [r for r in kept if content_key(r) not in drop]
    if n > len(kept):
        excluded["answer found from the options alone (adversarial filter)"] += n - len(kept)
    if rows and not kept:
        files = sorted({str(r.get("origin", "")).rpartition(", row ")[0] for r in rows} - {""})
        why = ", ".join(f"{count} {reason}" for reason, count in excluded.most_common(3))
        raise empty_data_error(", ".join(files) or "the MMLU-Pro rows", f"all {len(rows)} rows left out: {why}",
                               "MMLU-Pro")
    out: dict[str, list[tuple[bytes, Question]]] = {"train": [], "test": []}
    for row, fact in zip(kept, _facts(kept)):
        q = to_question(row, fact)
        split = "train" if stable_bucket("rsb-mmlu-pro", fact) < TRAIN_PERCENT else "test"
        out[split].append((stable_key("rsb-mmlu-pro-order", q.text, q.choices), q))
    return {s: [q for _, q in sorted(v, key=lambda kv: kv[0])] for s, v in out.items()}, excluded


def shown_profile(q: Question, n: int) -> np.ndarray:
    """The answer's rank profiles (:func:`surface_ranks`) among the options RSB-General-N shows,
    averaged over the option sets it may show."""
    rest = [c for c in q.choices if c != q.answer]
    sets = [[q.answer, *(rest[k] for k in sub)] for sub in shown_subsets(q, n)]
    return np.mean([surface_ranks(Question(q.text, q.answer, q.source, choices=tuple(o))) for o in sets], axis=0)


def balanced_selection(questions: list[Question], limit: int | None = None) -> tuple[list[Question], int]:
    """Take questions in order while the answer's rank among the options each suite shows, by
    length and by similarity to the other options, stays near uniform (each rank within 1 point
    + 2 questions of 1/N, for the ten of RSB-General-10 and the four of RSB-General-4).

    Returns the kept questions and how many were left out.
    """
    chosen: list[Question] = []
    counts = {n: np.zeros((4, n)) for n in SHOWN}
    dropped = 0
    for q in questions:
        if limit is not None and len(chosen) >= limit:
            break
        prof = {n: shown_profile(q, n) for n in SHOWN}
        if all(np.all(counts[n] + prof[n] <= (len(chosen) + 1) * (1 / n + RANK_SLACK) + 2) for n in SHOWN):
            chosen.append(q)
            for n in SHOWN:
                counts[n] += prof[n]
        else:
            dropped += 1
    return chosen, dropped


@lru_cache(maxsize=1 << 14)
def _spread_subsets(choices: tuple[str, ...], answer: str, n: int) -> tuple[tuple[int, ...], ...]:
    """The (n - 1)-subsets of the answer's distractors whose most alike pair of shown options
    (answer included; character-trigram Jaccard) is least alike, within SPREAD_TOLERANCE."""
    rest = [c for c in choices if c != answer]
    sim = similarity_matrix([answer, *rest])
    subsets = list(combinations(range(1, len(sim)), n - 1))
    worst = np.array([max(sim[i, j] for i, j in combinations((0, *c), 2)) for c in subsets])
    return tuple(tuple(k - 1 for k in c) for c, w in zip(subsets, worst) if w <= worst.min() + SPREAD_TOLERANCE)


def shown_subsets(q: Question, n: int) -> tuple[tuple[int, ...], ...]:
    """The sets of N - 1 distractors (indices into the answer's other options, in order) that
    RSB-General-N may show with the answer.

    N = 10: all nine. N = 4: MMLU's own three for a question taken from MMLU. Otherwise the
    subsets that make the shown options most unlike each other: a four drawn at random would show
    the answer's near twin (MMLU-Pro writes distractors as variants of the answer) far more often
    than two twin distractors, and "the option with a twin" would point at the answer.
    """
    if q.choices is None or len(q.choices) < n:
        raise ValueError(f"question {q.origin or q.text[:40]!r} has {0 if q.choices is None else len(q.choices)} "
                         f"options, fewer than {n}")
    rest = [c for c in q.choices if c != q.answer]
    if n == len(q.choices):
        return (tuple(range(n - 1)),)
    if q.core is not None and len(q.core) == n:
        return (tuple(k for k, c in enumerate(rest) if c in q.core),)
    return _spread_subsets(q.choices, q.answer, n)


def options(q: Question, n: int, rng: np.random.Generator) -> list[str]:
    """N options of a pool question, its answer first: one of its :func:`shown_subsets`, drawn."""
    rest = [c for c in q.choices if c != q.answer] if q.choices else []
    subsets = shown_subsets(q, n)
    return [q.answer, *(rest[k] for k in subsets[int(rng.integers(len(subsets)))])]
