"""Suite identifiers and option letters shared by the whole task pack (candidates: objects/family.py)."""
from __future__ import annotations

LETTERS_4: tuple[str, ...] = ("A", "B", "C", "D")
# J is skipped: on a lettered block it is too easily confused with I (paper section 3.3).
LETTERS_10: tuple[str, ...] = ("A", "B", "C", "D", "E", "F", "G", "H", "I", "K")

SUITES: tuple[str, ...] = ("Math", "HardMath", "General", "Direct")
CHOICE_COUNTS: tuple[int, ...] = (4, 10)
SUITE_IDS: tuple[str, ...] = tuple(f"RSB-{s}-{n}" for s in SUITES for n in CHOICE_COUNTS)
SPLITS: tuple[str, ...] = ("train", "test")
INSTRUCTION_SETS: tuple[str, ...] = ("seen", "unseen")
COLOR_MAPS: tuple[str, ...] = ("fixed", "shuffle")

# Where each suite's questions come from (documentation and `rsb stats`).
SUITE_SOURCES: dict[str, str] = {
    "Math": "procedural arithmetic",
    "HardMath": "GSM8K",
    "General": "commonsense table + MMLU-Pro",
    "Direct": "target named in the instruction",
}


def parse_suite_id(suite_id: str) -> tuple[str, int]:
    """Split ``"RSB-HardMath-10"`` into ``("HardMath", 10)``; ValueError lists the valid ids."""
    if not isinstance(suite_id, str) or suite_id not in SUITE_IDS:
        raise ValueError(f"unknown suite id {suite_id!r}; valid ids: {', '.join(SUITE_IDS)}")
    _, suite, n = suite_id.split("-")
    return suite, int(n)


def check_split(split: str) -> str:
    """Return ``split`` or raise ValueError naming the valid splits."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(SPLITS)} (test = evaluation pool)")
    return split


def letters_for(n_choices: int) -> tuple[str, ...]:
    """Option letters of an N-choice suite."""
    if n_choices == 4:
        return LETTERS_4
    if n_choices == 10:
        return LETTERS_10
    raise ValueError(f"n_choices must be 4 or 10, got {n_choices!r}")
