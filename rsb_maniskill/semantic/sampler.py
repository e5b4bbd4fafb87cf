"""EpisodeSampler: (suite, split, seed) -> EpisodeSpec, deterministic in any process."""
from __future__ import annotations

import os
from typing import Mapping, Sequence

import numpy as np

from rsb_maniskill.objects.family import DEFAULT_TARGETS, get_family
from rsb_maniskill.perturb import language, parse_perturb
from rsb_maniskill.semantic import mmlu_pro, wording
from rsb_maniskill.semantic.categories import episode_categories
from rsb_maniskill.semantic.distractors import numeric_options, weighted_options
from rsb_maniskill.semantic.pools import Pool, get_pool
from rsb_maniskill.semantic.records import Question, format_number
from rsb_maniskill.semantic.spec import EpisodeSpec
from rsb_maniskill.semantic.stable import axis_rng, episode_rng
from rsb_maniskill.semantic.suites import (
    COLOR_MAPS,
    INSTRUCTION_SETS,
    check_split,
    letters_for,
    parse_suite_id,
    suite_source,
)
from rsb_maniskill.semantic.templates import get_template, render_direct, render_instruction, template_ids


def _sentence(text: str) -> str:
    """Text closed by exactly one full stop (MMLU-Pro options often end with their own)."""
    return text if text[-1:] in ".!?" else text + "."


def candidate_phrase(name: str, lettered: bool) -> str:
    """"the red block" / "the mug", or "block F" for candidates named by their letter."""
    return name if lettered else f"the {name}"


class EpisodeSampler:
    """Builds episode specifications of one suite and split.

    ``split="test"`` is the evaluation pool. ``instructions`` defaults to the seen templates for
    training and the unseen ones for evaluation. ``color_map="shuffle"`` draws the 4-choice
    option->candidate map per episode (10-choice blocks carry their letter, so it has no effect
    there). ``targets`` names the candidate family (``rsb_maniskill.objects.TARGETS``): it says
    what the candidates are called; questions and options do not depend on it. ``perturb``: the
    language robustness axes and their levels (``{"lang_layout": 2}``, see ``wording``); only the
    instruction's wording changes, never the question, the options or the answer.
    """

    def __init__(self, suite_id: str, split: str = "train", instructions: str | None = None,
                 color_map: str = "fixed", data_dir: str | os.PathLike | None = None,
                 targets: str = DEFAULT_TARGETS, perturb: Mapping[str, int] | str | None = None) -> None:
        self.suite_id = suite_id
        # the language robustness axes (rsb_maniskill.perturb); visual ones are the simulator's
        self.perturb = language(parse_perturb(perturb))
        self.suite, self.n_choices = parse_suite_id(suite_id)
        self.split = check_split(split)
        if instructions is None:
            instructions = "seen" if split == "train" else "unseen"
        if instructions not in INSTRUCTION_SETS:
            raise ValueError(f"unknown instruction set {instructions!r}; valid: {', '.join(INSTRUCTION_SETS)}")
        if color_map not in COLOR_MAPS:
            raise ValueError(f"unknown color_map {color_map!r}; valid: {', '.join(COLOR_MAPS)}")
        self.instructions = instructions
        self.color_map = color_map
        self.family = get_family(targets)
        self.targets = targets
        self.letters = letters_for(self.n_choices)
        self.lettered = self.family.lettered(self.n_choices)
        self.direct = suite_source(self.suite).direct
        self._templates = template_ids(self.n_choices, instructions, self.direct, self.lettered)
        self.pool: Pool | None = None if self.direct else get_pool(self.suite, split, data_dir)

    @property
    def num_questions(self) -> int:
        """Pool size of this split (Direct: one "question" per block)."""
        return self.n_choices if self.pool is None else len(self.pool)

    def question(self, index: int) -> Question:
        """The pool's question record (not for Direct)."""
        if self.pool is None:
            raise ValueError("Direct suites have no question records")
        return self.pool.questions[index]

    def categories(self, spec: EpisodeSpec) -> dict[str, str]:
        """What the per-category tables group the episode ``spec`` of this sampler by (operator,
        reasoning steps, answer size, source, template, ...: ``categories.py``)."""
        return episode_categories(spec, None if self.direct else self.question(spec.question_id))

    def episode(self, seed: int) -> EpisodeSpec:
        """The episode of the RSB tasks for ``seed``: question ``seed mod pool size`` (seeds
        0..P-1 visit every question once), everything else drawn from ``seed``."""
        return self.sample(seed, question_index=int(seed) % self.num_questions)

    def sample(self, seed: int, question_index: int | None = None) -> EpisodeSpec:
        """Episode of ``seed``; ``question_index`` forces the question (one demo per question),
        the option order, colour map and template still come from ``seed``."""
        seed = int(seed)
        if seed < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        n_q = self.num_questions
        if question_index is None:
            qi = int(episode_rng(self.suite_id, self.split, seed, "question").integers(n_q))
        else:
            qi = int(question_index)
            if not 0 <= qi < n_q:
                raise IndexError(f"question_index {qi} out of range 0..{n_q - 1} for {self.suite_id} {self.split}")
        rng = episode_rng(self.suite_id, self.split, seed, "episode")
        n = self.n_choices
        template_id = int(self._templates[int(rng.integers(len(self._templates)))])
        if n == 4 and self.color_map == "shuffle":
            block_of_option = tuple(int(b) for b in rng.permutation(4))
        else:
            block_of_option = tuple(range(n))
        cands = self.family.draw(n, self.letters, episode_rng(self.suite_id, self.split, seed, "candidates"))
        if self.direct:
            return self._direct(seed, qi, template_id, block_of_option, cands.names, cands.keys)

        q = self.pool.questions[qi]
        options = self._options(qi, q, rng)  # options[0] is the answer
        perm = rng.permutation(n)
        ordered = tuple(options[int(i)] for i in perm)
        slot = int(np.flatnonzero(perm == 0)[0])
        return self._compose(seed, qi, q, ordered, slot, block_of_option, template_id, cands.names, cands.keys)

    def rebind(self, spec: EpisodeSpec, options: Sequence[str], answer_slot: int,
               block_of_option: Sequence[int]) -> EpisodeSpec:
        """``spec`` (not Direct) with its options in another order or bound to other candidates:
        the same seed, question, candidates and template; instruction and rationale rendered anew
        as :meth:`sample` renders them. The counterfactual variants are built with it."""
        if self.pool is None:
            raise ValueError("Direct suites have no options to rebind: sample another target instead")
        return self._compose(spec.seed, spec.question_id, self.pool.questions[spec.question_id], tuple(options),
                             int(answer_slot), tuple(int(b) for b in block_of_option), spec.template_id,
                             spec.block_names, spec.candidates)

    def _compose(self, seed: int, qi: int, q: Question, ordered: tuple[str, ...], slot: int,
                 block_of_option: tuple[int, ...], template_id: int, names: tuple[str, ...],
                 keys: tuple[str, ...]) -> EpisodeSpec:
        """The spec of a drawn question episode: its instruction and rationale rendered."""
        n = self.n_choices
        letter = self.letters[slot]
        if self.perturb:
            instruction = wording.render(get_template(n, template_id, lettered=self.lettered), q.text, ordered,
                                         self.letters, names, keys, block_of_option, self.family.noun,
                                         self.perturb, self._axis_rngs(seed))
        else:
            instruction = render_instruction(n, template_id, q.text, ordered, self.letters, names, block_of_option,
                                             self.lettered, self.family.noun)
        binding = (f"Option {letter} is {_sentence(ordered[slot])} "
                   f"Option {letter} is {candidate_phrase(names[block_of_option[slot]], self.lettered)}.")
        if q.source == "math":
            rationale = f"{q.solution} {binding}"
        elif q.source == "gsm8k":
            rationale = f"{q.solution} The answer is {_sentence(q.answer)} {binding}"
        else:  # MMLU-Pro, commonsense (the latter states its fact first)
            rationale = f"{q.solution} The answer is {_sentence(q.answer)} {binding}".lstrip()
        return EpisodeSpec(self.suite_id, self.suite, n, self.split, seed, qi, q.text, ordered, self.letters, slot,
                           letter, block_of_option, names, keys, instruction, template_id, rationale,
                           self.family.name)

    # -----------------------------------------------------------------------------------------

    def _direct(self, seed: int, target: int, template_id: int, block_of_option: tuple[int, ...],
                names: tuple[str, ...], keys: tuple[str, ...]) -> EpisodeSpec:
        options = tuple(names[b] for b in block_of_option)
        slot = block_of_option.index(target)
        letter = self.letters[slot]
        name = names[target]
        rationale = f"The instruction names {candidate_phrase(name, self.lettered)}."
        if self.perturb:
            instruction = wording.render_direct_perturbed(self.n_choices, template_id, name, keys[target], self.perturb,
                                                          self._axis_rngs(seed))
        else:
            instruction = render_direct(self.n_choices, template_id, name)
        return EpisodeSpec(self.suite_id, self.suite, self.n_choices, self.split, seed, target, "", options,
                           self.letters, slot, letter, block_of_option, names, keys,
                           instruction, template_id, rationale, self.family.name)

    def _axis_rngs(self, seed: int) -> dict[str, np.random.Generator]:
        return {a: axis_rng(self.suite_id, self.split, seed, a, lv) for a, lv in self.perturb.items()}

    def _options(self, qi: int, q: Question, rng: np.random.Generator) -> list[str]:
        n = self.n_choices
        if q.numeric:
            values = numeric_options(q.value, self.pool.value_bins(n, q.group, q.decimals), n, rng)
            return [format_number(v, q.decimals) for v in values]
        if q.source == "mmlu_pro":
            return mmlu_pro.options(q, n, rng)
        cands, weight = self.pool.candidates[qi]
        return weighted_options(q.answer, cands, weight, n, rng)
