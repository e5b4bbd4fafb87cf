"""Ten options for an MMLU question that has four: whole option groups of three questions.

Adding six loose answers of other questions makes the question's own four stand out (they are
alike, on-topic, and one of them is right), so a guesser picks among them: 25 % on a 10-choice
suite. Here every group shown is a whole MMLU option set, its own answer and distractors:

* the 10 options are groups of sizes 4, 4 and 2: the asked question and two *padding* questions
  of the same pool from other subject areas (a second right answer is less likely there); the
  group cut to two (its answer and one distractor) is the asked question's with probability
  2/10, so by group shape each option is the answer with probability 1/10;
* the pool only holds questions whose options share no word or stem with their question
  (mmlu.exclusion_reason), and padding options share none with the asked question either, so
  word overlap with the question cannot single out the asked group;
* no padding option has the normal form of an option of another group, or of an answer of any
  MMLU question with the asked question's normal form (their answers would be right here too).
"""
from __future__ import annotations

from collections import defaultdict
from typing import Mapping, Sequence

import numpy as np

from .errors import SemanticDataError
from .normalize import option_key, overlap, question_key
from .records import Question

GROUP = 4  # MMLU's own options per question
_TRIES = 200  # padding candidates examined before giving up on a question

# MMLU's subject categories (Hendrycks et al., categories.py); unknown subjects count as "other".
_AREA_SUBJECTS = {
    "stem": "abstract_algebra astronomy college_biology college_chemistry college_computer_science college_mathematics "
            "college_physics computer_security conceptual_physics electrical_engineering elementary_mathematics "
            "high_school_biology high_school_chemistry high_school_computer_science high_school_mathematics "
            "high_school_physics high_school_statistics machine_learning",
    "humanities": "formal_logic high_school_european_history high_school_us_history high_school_world_history "
                  "international_law jurisprudence logical_fallacies moral_disputes moral_scenarios philosophy "
                  "prehistory professional_law world_religions",
    "social sciences": "econometrics high_school_geography high_school_government_and_politics "
                       "high_school_macroeconomics high_school_microeconomics high_school_psychology human_sexuality "
                       "professional_psychology public_relations security_studies sociology us_foreign_policy",
}
AREAS: dict[str, str] = {s: a for a, subjects in _AREA_SUBJECTS.items() for s in subjects.split()}


def area(subject: str) -> str:
    """MMLU area of a subject: "stem", "humanities", "social sciences" or "other"."""
    return AREAS.get(subject, "other")


def group_sizes(n: int) -> list[int]:
    """Group sizes for N options: 10 -> [4, 4, 2]."""
    return [GROUP] * (n // GROUP) + ([n % GROUP] if n % GROUP else [])


class Padding:
    """Pads the MMLU questions of one pool to N options with option groups of other questions."""

    def __init__(self, questions: Sequence[Question], answers_by_question: Mapping[str, set[str]]) -> None:
        self.questions = list(questions)
        self.answers_by_question = answers_by_question  # question normal form -> answer normal forms
        self.keys = [frozenset(option_key(c) for c in q.choices) for q in self.questions]
        self.areas = [area(q.group) for q in self.questions]
        self.by_area: dict[str, list[int]] = defaultdict(list)
        for i, a in enumerate(self.areas):
            self.by_area[a].append(i)

    def options(self, i: int, n: int, rng: np.random.Generator) -> list[str]:
        """N options for question ``i``, its answer first."""
        q = self.questions[i]
        sizes = group_sizes(n)
        own_slot = int(rng.choice(len(sizes), p=np.array(sizes) / n))
        blocked = set(self.keys[i]) | self.answers_by_question.get(question_key(q.text), set())
        used = {i}
        out = [q.answer]
        for slot, size in enumerate(sizes):
            k = i if slot == own_slot else self._padding_question(i, blocked, used, rng)
            used.add(k)
            blocked |= self.keys[k]
            p = self.questions[k]
            rest = [c for c in p.choices if c != p.answer]
            picks = [rest[int(j)] for j in rng.choice(len(rest), size=size - 1, replace=False)]
            out += picks if k == i else [p.answer, *picks]
        return out

    def _padding_question(self, i: int, blocked: set[str], used: set[int], rng: np.random.Generator) -> int:
        """A random question of another area whose options are all new and share no stem with
        the asked question."""
        areas = [a for a in sorted(self.by_area) if a != self.areas[i]] or [self.areas[i]]
        for _ in range(_TRIES):
            members = self.by_area[areas[int(rng.integers(len(areas)))]]
            k = members[int(rng.integers(len(members)))]
            if k in used or blocked & self.keys[k]:
                continue
            if any(overlap(c, self.questions[i].text) for c in self.questions[k].choices):
                continue
            return k
        raise SemanticDataError(self.questions[i].origin, None, "no other MMLU question of the pool can pad this "
                                "one to 10 options (too few questions from other subject areas)")
