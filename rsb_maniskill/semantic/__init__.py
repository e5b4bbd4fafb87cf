"""Semantic engine of RSB: (suite, split, seed) -> EpisodeSpec.

Knows nothing of the simulator (no mani_skill, sapien or torch imports), so it is fast to test
and shared by the tasks, the scripted expert, the evaluator and the exporters. See docs/semantic.md.
"""
from __future__ import annotations

from rsb_maniskill.semantic.errors import DataNotFoundError, SemanticDataError, SemanticError
from rsb_maniskill.semantic.paraphrase import paraphrases
from rsb_maniskill.semantic.pools import clear_cache, get_pool
from rsb_maniskill.semantic.sampler import EpisodeSampler
from rsb_maniskill.semantic.spec import EpisodeSpec
from rsb_maniskill.semantic.suites import (
    COLOR_MAPS,
    INSTRUCTION_SETS,
    LETTERS_4,
    LETTERS_10,
    SPLITS,
    SUITE_IDS,
    SUITE_SOURCES,
    SUITES,
    SuiteSource,
    letters_for,
    parse_suite_id,
    register_suite,
    suite_source,
)
from rsb_maniskill.semantic.templates import render_instruction

__all__ = [
    "COLOR_MAPS", "DataNotFoundError", "EpisodeSampler", "EpisodeSpec", "INSTRUCTION_SETS",
    "LETTERS_4", "LETTERS_10", "SPLITS", "SUITE_IDS", "SUITE_SOURCES", "SUITES", "SemanticDataError",
    "SemanticError", "SuiteSource", "clear_cache", "get_pool", "letters_for", "paraphrases", "parse_suite_id",
    "register_suite", "render_instruction", "suite_source",
]
