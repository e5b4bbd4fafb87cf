"""The source-independent question record that pools hold."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Question:
    """One question of a pool.

    Numeric questions (Math, GSM8K) carry ``value``, the answer in units of 10**-decimals; their
    distractors are answers of other questions of the same ``group`` (Math: the operation).
    Text questions carry ``choices`` (MMLU-Pro's own ten, answer included) and/or ``group``
    (subject or knowledge category).
    """

    text: str
    answer: str
    source: str  # "math" | "gsm8k" | "mmlu_pro" | "commonsense"
    group: str = ""
    value: int | None = None
    decimals: int = 0
    choices: tuple[str, ...] | None = None
    # MMLU-Pro questions taken from MMLU: MMLU's own four options (answer included), written by
    # people before MMLU-Pro added six; RSB-General-4 shows these
    core: tuple[str, ...] | None = None
    solution: str = ""
    origin: str = ""  # "file, line N" or generator description, for error reports
    fact: str = ""  # what the question asks about; train and test never share one (rsb audit checks)
    # What the per-category tables group by (semantic/categories.py), kept when the pool is built:
    # MMLU-Pro's own category (14 values; ``group`` holds MMLU's subject for rows taken from MMLU),
    # and GSM8K's reasoning steps (calculator annotations of its worked solution, which
    # ``solution`` no longer shows).
    category: str = ""
    steps: int | None = None

    @property
    def numeric(self) -> bool:
        return self.value is not None


def format_number(units: int, decimals: int) -> str:
    """Render an integer number of 10**-decimals units as plain text (no thousands separators)."""
    if decimals == 0:
        return str(units)
    sign = "-" if units < 0 else ""
    q, r = divmod(abs(units), 10 ** decimals)
    return f"{sign}{q}.{r:0{decimals}d}"


def normalize_text(s: str) -> str:
    """Whitespace-collapsed text: instructions are one line."""
    return " ".join(str(s).split())
