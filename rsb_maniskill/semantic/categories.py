"""What kind of episode an episode is: the categories the per-category tables group it by.

The semantic engine owns them: they are read from the episode spec and its pool question (never
parsed from the instruction text), so a report built from records needs no data files.
:func:`episode_categories` gives them (``EpisodeSampler.categories(spec)`` is the usual entry), the
runner writes them into each record (``categories``), and ``reporting/sections/categories.py`` tabulates.

Dimensions (a key, a string value; a suite has the ones that apply to it):

- ``operator`` (Math): ``plus``, ``minus``, ``times``;
- ``steps`` (HardMath): the reasoning steps of the GSM8K solution, i.e. its ``<<...>>`` calculator
  annotations, binned ``0-1``, ``2``, ``3``, ``4``, ``5+`` (18 of GSM8K's 1,319 test solutions
  carry no annotation and land in ``0-1``);
- ``answer_size`` (Math, HardMath): digits of the integer part of the answer, ``1 digit`` ...
  ``4+ digits`` (Math's answers have 2 or 3; GSM8K's mostly 1 to 3);
- ``source`` (General): ``commonsense`` (the written knowledge table) or ``mmlu_pro``;
- ``mmlu_category`` (General, MMLU-Pro questions only): MMLU-Pro's own category (14 values);
- ``template`` (every suite): the instruction template's id (``templates.py``);
- ``suite_kind`` (every suite): ``question`` or ``direct`` (the Direct controls name the target).
"""
from __future__ import annotations

import re
from typing import Any, Iterable

from rsb_maniskill.semantic.records import Question

OPERATOR, STEPS, ANSWER_SIZE = "operator", "steps", "answer_size"
SOURCE, MMLU_CATEGORY = "source", "mmlu_category"
TEMPLATE, SUITE_KIND = "template", "suite_kind"

# Each dimension's title, in the order the tables list them.
DIMENSIONS: dict[str, str] = {
    OPERATOR: "Operator",
    STEPS: "Reasoning steps (GSM8K calculator annotations)",
    ANSWER_SIZE: "Answer size (digits of the integer part)",
    SOURCE: "Question source",
    MMLU_CATEGORY: "MMLU-Pro category",
    TEMPLATE: "Instruction template",
    SUITE_KIND: "Direct vs question suites",
}
MAX_STEPS_BIN = 5  # 5 steps or more share a bin ("5+"): 225 of GSM8K's 1,319 test questions
MAX_DIGITS_BIN = 4  # answers of 4 digits or more share a bin ("4+ digits"): 131 GSM8K test answers
# How a value reads in a table (values not listed read as they are).
VALUE_LABELS: dict[str, dict[str, str]] = {
    SOURCE: {"commonsense": "commonsense facts (written)", "mmlu_pro": "MMLU-Pro"},
    SUITE_KIND: {"question": "question suites", "direct": "Direct (target named)"},
}


def steps_bin(steps: int) -> str:
    """``0-1``, ``2``, ``3``, ``4`` or ``5+`` reasoning steps."""
    if steps <= 1:
        return "0-1"
    return f"{MAX_STEPS_BIN}+" if steps >= MAX_STEPS_BIN else str(steps)


def answer_size_bin(value: int, decimals: int = 0) -> str:
    """Digits of the integer part of a numeric answer (``value`` in units of 10**-decimals)."""
    digits = len(str(abs(int(value)) // 10 ** int(decimals)))
    if digits >= MAX_DIGITS_BIN:
        return f"{MAX_DIGITS_BIN}+ digits"
    return "1 digit" if digits == 1 else f"{digits} digits"


def episode_categories(spec: Any, question: Question | None) -> dict[str, str]:
    """The categories of the episode ``spec`` (an ``EpisodeSpec``) whose pool question is
    ``question`` (None for the Direct controls)."""
    out = {SUITE_KIND: "direct" if question is None else "question", TEMPLATE: str(int(spec.template_id))}
    if question is None:
        return out
    if question.source == "math":
        out[OPERATOR] = question.group
    if question.source == "gsm8k" and question.steps is not None:
        out[STEPS] = steps_bin(question.steps)
    if question.numeric:
        out[ANSWER_SIZE] = answer_size_bin(question.value, question.decimals)
    if question.source in VALUE_LABELS[SOURCE]:
        out[SOURCE] = question.source
    if question.source == "mmlu_pro" and question.category:
        out[MMLU_CATEGORY] = question.category
    return out


def value_label(dimension: str, value: str) -> str:
    """How a category value reads in a table: ``"mmlu_pro"`` -> ``"MMLU-Pro"``, ``"20"`` ->
    ``"template 20"``."""
    if dimension == TEMPLATE:
        return f"template {value}"
    return VALUE_LABELS.get(dimension, {}).get(value, value)


def value_order(values: Iterable[str]) -> list[str]:
    """Values in reading order: by their leading number (bins, template ids), then by name."""
    def key(v: str) -> tuple[int, str]:
        m = re.match(r"\d+", v)
        return (int(m.group()) if m else 1 << 30, v)

    return sorted(values, key=key)
