"""The suites: a registry of question sources, and the ids, splits and option letters shared by the
whole task pack (candidates: ``objects/family.py``, the registry of candidate families).

A suite source declares its name (``"Math"``: suites ``RSB-Math-4``, ``RSB-Math-10``), its choice
counts, how it builds a split's question pool (``"module:function"``, imported at the first pool:
``(split, data_dir) -> pools.Pool``) or that it is a Direct control (the instruction names the
target: no questions), whether it reads GSM8K / MMLU-Pro, and what ``rsb stats`` and the dataset
card say about it. A new suite is one module with its pool builder and one :func:`register_suite`
call: a line below, or a plugin module (``plugins.py``: an installed distribution's entry point,
imported here before the suite ids are fixed; docs/tasks.md).
"""
from __future__ import annotations

from dataclasses import dataclass

from rsb_maniskill.plugins import load_plugins

LETTERS_4: tuple[str, ...] = ("A", "B", "C", "D")
# J is skipped: on a lettered block it is too easily confused with I (paper section 3.3).
LETTERS_10: tuple[str, ...] = ("A", "B", "C", "D", "E", "F", "G", "H", "I", "K")

CHOICE_COUNTS: tuple[int, ...] = (4, 10)
SPLITS: tuple[str, ...] = ("train", "test")
INSTRUCTION_SETS: tuple[str, ...] = ("seen", "unseen")
COLOR_MAPS: tuple[str, ...] = ("fixed", "shuffle")


@dataclass(frozen=True)
class SuiteSource:
    """Where the questions of the suites ``RSB-<name>-<n>`` (n in ``choices``) come from."""

    name: str
    summary: str  # the source in a few words (`rsb stats`)
    card: str  # the question source as the dataset card states it, with licences
    licence: str  # of the questions (the dataset card's header)
    pool: str | None = None  # "module:function": (split, data_dir) -> pools.Pool; None for a Direct control
    choices: tuple[int, ...] = CHOICE_COUNTS
    reads_data: bool = False  # needs the GSM8K / MMLU-Pro data (a data directory or the hub)

    @property
    def direct(self) -> bool:
        """A control without questions: the instruction names the target candidate."""
        return self.pool is None


SOURCES: dict[str, SuiteSource] = {}  # name -> source, in registration order


def register_suite(source: SuiteSource) -> SuiteSource:
    """Adds ``source`` to the registry (ValueError when its name is taken or its choices are not
    4 and/or 10, the counts the templates and letters exist for)."""
    if source.name in SOURCES:
        raise ValueError(f"a suite source named {source.name!r} is registered already")
    if not source.choices or any(n not in CHOICE_COUNTS for n in source.choices):
        raise ValueError(f"suite source {source.name!r}: choices must be among {CHOICE_COUNTS}, got {source.choices}")
    SOURCES[source.name] = source
    return source


def suite_source(name: str) -> SuiteSource:
    """The source named ``name`` ("Math"); ValueError lists the registered ones."""
    if name not in SOURCES:
        raise ValueError(f"unknown question source {name!r}; valid: {', '.join(SOURCES)}")
    return SOURCES[name]


register_suite(SuiteSource(
    "Math", "procedural arithmetic", "procedural two-operand arithmetic written by rsb_maniskill", "MIT",
    pool="rsb_maniskill.semantic.math_source:pool"))
register_suite(SuiteSource(
    "HardMath", "GSM8K", "GSM8K word problems (openai/gsm8k, MIT)", "MIT",
    pool="rsb_maniskill.semantic.gsm8k:pool", reads_data=True))
register_suite(SuiteSource(
    "General", "commonsense table + MMLU-Pro",
    "a commonsense knowledge table written by rsb_maniskill and MMLU-Pro (TIGER-Lab/MMLU-Pro, MIT); the pool is "
    "smaller than the paper's 10,000 training questions: only MMLU-Pro writes ten options for a question, and RSB "
    "keeps those whose answer no answer-blind model finds from the options alone (docs/semantic.md, Pool sizes)",
    "MIT",
    pool="rsb_maniskill.semantic.general:pool", reads_data=True))
register_suite(SuiteSource("Direct", "target named in the instruction", "none: the instruction names the target",
                           "MIT"))

load_plugins()  # a plugin's register_suite / register_family calls land before the ids below are fixed

SUITES: tuple[str, ...] = tuple(SOURCES)
SUITE_IDS: tuple[str, ...] = tuple(f"RSB-{s.name}-{n}" for s in SOURCES.values() for n in s.choices)
SUITE_SOURCES: dict[str, str] = {s.name: s.summary for s in SOURCES.values()}  # `rsb stats`, docs


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
