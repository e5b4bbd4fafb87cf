"""Normal forms of options and questions: when two texts mean the same thing on the surface.

Used for duplicate options (an option set must have exactly one correct member), for the
MMLU-Pro train/test split (near-duplicate questions fall on one side) and by ``rsb audit``.
"""
from __future__ import annotations

import re
import unicodedata
from functools import lru_cache
from typing import Sequence

import numpy as np

_TIMES = re.compile(r"(?<=[\d)\s])\s*(?:[x×*·]|\\times)\s*(?=[\d(\s])")
_POW10 = re.compile(r"(-?\d+(?:\.\d+)?)\s*x\s*10\s*\^\s*\{?\s*(-?\d+)\s*\}?")
_NUMBER = re.compile(r"(?<![\w.])-?\d[\d,]*(?:\.\d+)?(?![\w])")
_PUNCT = re.compile(r"[^\w\s.\-^/]")  # keep decimal points, minus, powers and fractions
_SPACES = re.compile(r"\s+")
_TRAILING = re.compile(r"[\s.,;:!?]+$")
_PLAIN_NUMBER = re.compile(r"^\$?\s*(-?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?)\s*$")
_UNIT_NUMBER = re.compile(r"^\s*\$?\s*(-?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?)\s*(.*?)\s*$")
_WORD = re.compile(r"[a-z0-9]+")
# Function words that do not make two texts "share a word".
STOPWORDS = frozenset("""
a an the of to in on at for by with from and or but not no is are was were be been being it its this that
these those there their they them he she his her we you your our i my me as if than then so do does did
which what who whom whose where when why how all any some each most more many much can could would should
will shall may might must has have had into out up down over under about after before between one two usually
""".split())


def _canonical_number(text: str) -> str:
    """"1,000.50" -> "1000.5", "-0.0" -> "0", "007" -> "7" (leading zeros are not meaning)."""
    t = text.replace(",", "")
    neg = t.startswith("-")
    t = t.lstrip("-")
    whole, _, frac = t.partition(".")
    whole = whole.lstrip("0") or "0"
    frac = frac.rstrip("0")
    s = whole + ("." + frac if frac else "")
    return ("-" + s) if neg and s != "0" else s


@lru_cache(maxsize=1 << 18)
def option_key(text: str) -> str:
    """Normal form of an option: case, accents, spacing, punctuation, x / * / × and the written
    form of numbers ("1.50" = "1.5", "1,000" = "1000", "1.5 x 10^8" = "1.5 * 10^8") are ignored."""
    t = unicodedata.normalize("NFKC", str(text)).casefold()
    t = t.replace("−", "-").replace("–", "-")
    t = _TIMES.sub(" x ", t)
    t = _POW10.sub(lambda m: f"{_canonical_number(m.group(1))}e{int(m.group(2))}", t)
    t = _NUMBER.sub(lambda m: _canonical_number(m.group(0)), t)
    t = _PUNCT.sub(" ", t)
    t = _TRAILING.sub("", _SPACES.sub(" ", t).strip())
    return t.strip(" .")


@lru_cache(maxsize=1 << 16)
def question_key(text: str) -> str:
    """Normal form of a question for split assignment and near-duplicate detection: like
    :func:`option_key`, and also blind to punctuation spacing ("0.6c ." = "0.6c.")."""
    t = option_key(text)
    t = re.sub(r"\s*([.\-^/])\s*", r"\1", t)
    return t.replace(".", " ").replace("  ", " ").strip()


def plain_number(text: str) -> float | None:
    """Value of an option that is just a number ("162", "-7", "3.75", "$1,200"), else None."""
    m = _PLAIN_NUMBER.match(str(text).strip())
    return float(m.group(1).replace(",", "")) if m else None


@lru_cache(maxsize=65536)
def content_words(text: str) -> frozenset[str]:
    """Lower-case words minus function words, with a plural 's' dropped ("cans" = "can")."""
    out = set()
    for w in _WORD.findall(text.casefold()):
        if w in STOPWORDS or len(w) < 2:
            continue
        out.add(w[:-1] if len(w) > 3 and w.endswith("s") and not w.endswith("ss") else w)
    return frozenset(out)


def numeric_values(options: Sequence[str]) -> list[float] | None:
    """Option values when every option is a number, alone or with one shared unit
    ("3 m/s", "5 m/s"); None for text options."""
    plain = [plain_number(o) for o in options]
    if all(v is not None for v in plain):
        return plain  # type: ignore[return-value]
    vals, units = [], set()
    for o in options:
        m = _UNIT_NUMBER.match(o)
        if not m or not m.group(2) or any(ch.isdigit() for ch in m.group(2)):
            return None
        vals.append(float(m.group(1).replace(",", "")))
        units.add(m.group(2).casefold())
    return vals if len(units) == 1 else None


def leading_numbers(options: Sequence[str]) -> list[float] | None:
    """The number each option starts with, when every option starts with one ("240 grams, 6.5
    grams" -> 240, "3.06% = 30.6 mills" -> 3.06, "162" -> 162); None when one does not. Written
    numeric distractors sit around the answer by these values as much as by plain numbers."""
    vals = []
    for o in options:
        m = _UNIT_NUMBER.match(o)
        if not m:
            return None
        vals.append(float(m.group(1).replace(",", "")))
    return vals


def _related(word: str, words: frozenset[str]) -> bool:
    """``word`` equals one of ``words``, shares its first four letters with one, or one of the two
    holds the other (4+ letters): "juice" / "juicer", "cork" / "corkscrew", "dish" / "dishwasher"."""
    if word in words:
        return True
    if len(word) < 4:
        return False
    return any(len(w) >= 4 and (w[:4] == word[:4] or w in word or word in w) for w in words)


def overlap(option: str, question: str) -> int:
    """How many content words of ``option`` are related to a content word of ``question``: the
    surface link a lexical guesser would follow."""
    q = content_words(question)
    return sum(_related(w, q) for w in content_words(option))


def related_words(a: str, b: str) -> bool:
    """Whether two texts share a content word or a word stem (see :func:`overlap`)."""
    return overlap(a, b) > 0


@lru_cache(maxsize=65536)
def trigrams(text: str) -> frozenset[str]:
    """Character trigrams of an option's normal form (padded, so never empty)."""
    t = f"  {option_key(text)} "
    return frozenset(t[i:i + 3] for i in range(len(t) - 2))


def jaccard(a: frozenset, b: frozenset) -> float:
    return len(a & b) / len(a | b) if a or b else 0.0


def similarity_matrix(options: Sequence[str]) -> np.ndarray:
    """(N, N) character-trigram Jaccard between options, NaN on the diagonal: how alike the
    members of an option set look (near twins, the set's medoid)."""
    grams = [trigrams(o) for o in options]
    sim = np.array([[jaccard(g, h) for h in grams] for g in grams])
    np.fill_diagonal(sim, np.nan)
    return sim
