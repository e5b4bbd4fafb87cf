"""The statement parser (semantic/answers.py): every template's entry form, every candidate family
and suite, references, values, chains of thought in the paper's style, and no or several options."""
from __future__ import annotations

import dataclasses

import pytest

from rsb_maniskill.semantic import EpisodeSampler
from rsb_maniskill.semantic.answers import read_instruction, read_statement, stated_letter
from rsb_maniskill.semantic.records import normalize_text
from rsb_maniskill.semantic.templates import render_instruction, template_family, template_ids
from rsb_maniskill.semantic.wording import LAYOUTS, reference_names

SUITES = ("RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4", "RSB-HardMath-10", "RSB-General-4", "RSB-General-10",
          "RSB-Direct-4", "RSB-Direct-10")
TARGETS = ("blocks", "objects")


def statements(spec, sampler, slot: int) -> dict[str, str]:
    """Ways to state option ``slot`` of ``spec``: every entry form of the family's templates (seen,
    unseen and the lang_layout ones), letters, names and the option's value."""
    letter, option = spec.letters[slot], spec.options[slot]
    c = spec.block_of_option[slot]
    name, key = spec.block_names[c], spec.candidates[c]
    seen, unseen = template_family(spec.n_choices, lettered=sampler.lettered)
    entries = [t.entry for t in seen + unseen] + [layout[1 if sampler.lettered else 0] for layout in LAYOUTS.values()]
    out = {f"entry {e!r}": e.format(L=letter, O=option, B=name) for e in entries}
    out.update({"option": f"option {letter}", "Option (x)": f"Option ({letter})", "parens": f"({letter})",
                "answer is": f"The answer is {letter}.", "answer colon": f"Answer: {letter}", "bare": letter,
                "lower": f"I choose option {letter.lower()}.", "name": f"Put the {name} in the zone.",
                "quoted": f'The correct answer is "{letter}"', "answer letter": f"The answer is letter {letter}.",
                "llm": f"The correct answer is [{letter}] {option} goes with the {name}."})
    for level in (1, 2, 3):
        ref = reference_names([name], [key], level)[0]
        if key.startswith("block:") or " " in ref:  # one-word object synonyms ("ball") are not read
            out[f"reference {level}"] = f"Pick the {ref}."
    if spec.suite != "Direct":
        out["value"] = f"The answer is {option}."
    if any(normalize_text(o).lower() == name for o in spec.options):
        out.pop("name")  # "the stapler" is then also an option's text
    return out


@pytest.mark.parametrize("targets", TARGETS)
@pytest.mark.parametrize("suite", SUITES)
def test_every_statement_form_names_its_option(suite, targets, question_data):
    for split in ("test", "train"):
        sampler = EpisodeSampler(suite, split, targets=targets)
        for seed in range(3):
            spec = sampler.episode(seed)
            for slot in range(spec.n_choices):
                for form, text in statements(spec, sampler, slot).items():
                    st = read_statement(text, spec)
                    assert st.letter == spec.letters[slot], (form, text, st, spec.options)


@pytest.mark.parametrize("targets", TARGETS)
@pytest.mark.parametrize("suite", SUITES)
def test_the_rationale_states_the_correct_option(suite, targets, question_data):
    """Each episode's rationale (the CoT target of `rsb dataset build`) ends on the answer's option."""
    sampler = EpisodeSampler(suite, "test", targets=targets)
    for seed in range(40):
        spec = sampler.episode(seed)
        assert stated_letter(spec.rationale, spec) == spec.correct_letter, spec.rationale


def _math_spec(options=("4", "10", "11", "14")):
    """The paper's example (appendix D): "what is 27 minus 17? options: (A) 4 (B) 10 (C) 11 (D) 14"."""
    spec = EpisodeSampler("RSB-Math-4", "test").episode(0)
    q = "What is 27 minus 17?"
    return dataclasses.replace(spec, question=q, options=tuple(options), answer_slot=1, correct_letter="B",
                               instruction=render_instruction(4, spec.template_id, q, options, spec.letters,
                                                              spec.block_names, spec.block_of_option))


def test_chain_of_thought_in_the_papers_style():
    spec = _math_spec(("17", "10", "11", "27"))  # the operands are options too
    assert spec.correct_option == "10" and spec.block_names[spec.target_block] == "green block"
    letter, name = spec.correct_letter, spec.block_names[spec.target_block]
    cot = (f"<think> 27 minus 17 equals 10. Among the options, option {letter} is 10. According to the fixed "
           f"color mapping, option {letter} corresponds to the {name}, so the robot should grasp the {name}. </think>")
    assert read_statement(cot, spec).letter == letter and read_statement(cot, spec).by == "option"
    # without a letter or a block: the result, not the operands (17 may be an option too)
    assert stated_letter("27 minus 17 equals 10.", spec) == letter
    assert stated_letter(f"{spec.question} The answer is 10.", spec) == letter  # the echoed question is ignored
    other = next(i for i in range(4) if spec.letters[i] != letter)
    wrong = f"27 minus 17 equals 10, so option {spec.letters[other]}."
    assert stated_letter(wrong, spec) == spec.letters[other]  # what it says, right or wrong


def test_no_option_or_several_state_none():
    spec = _math_spec()
    a, b = spec.letters[0], spec.letters[1]
    for text in ("", "I am not sure.", "Pick up a block.", "A block goes in the gray zone.", "I think so."):
        assert read_statement(text, spec).letter is None and read_statement(text, spec).by == "none", text
    st = read_statement(f"Option {a} or option {b}.", spec)
    assert st.letter is None and st.named == (a, b)
    assert stated_letter(spec.instruction, spec) is None  # the instruction names every option
    # a letter outranks a name, a name a value: "option B ... the red block" states B
    red = spec.block_names[spec.block_of_option[0]]
    assert stated_letter(f"Option {b}, the {red}.", spec) == b


def test_letters_inside_option_texts_and_words_are_not_references(question_data):
    """"Vitamin A" is the text of option C, not a mention of option A."""
    spec = EpisodeSampler("RSB-General-10", "test").episode(0)
    i = 2
    spec = dataclasses.replace(spec, options=tuple("Vitamin A" if k == i else o for k, o in enumerate(spec.options)))
    assert stated_letter(f"The answer is {spec.options[i]}.", spec) == spec.letters[i]


@pytest.mark.parametrize("targets", TARGETS)
@pytest.mark.parametrize("n", (4, 10))
def test_read_instruction_inverts_every_template(n, targets, question_data):
    suite = f"RSB-General-{n}"
    sampler = EpisodeSampler(suite, "test", targets=targets)
    spec = sampler.episode(0)
    for template_id in list(template_ids(n, "seen", lettered=sampler.lettered)) + list(
            template_ids(n, "unseen", lettered=sampler.lettered)):
        text = render_instruction(n, template_id, spec.question, spec.options, spec.letters, spec.block_names,
                                  spec.block_of_option, sampler.lettered, sampler.family.noun)
        reading = read_instruction(text)
        assert reading is not None, text
        assert reading.question == normalize_text(spec.question) and reading.letters == spec.letters
        # an option's closing full stop may serve as the list's own: compare without it
        assert [o.rstrip(".") for o in reading.options] == [normalize_text(o).rstrip(".") for o in spec.options]


@pytest.mark.parametrize("suite", ("RSB-Math-10", "RSB-HardMath-4", "RSB-General-4", "RSB-General-10"))
def test_read_instruction_on_sampled_episodes(suite, question_data):
    for targets in TARGETS:
        sampler = EpisodeSampler(suite, "test", targets=targets)
        for seed in range(60):
            spec = sampler.episode(seed)
            reading = read_instruction(spec.instruction)
            assert reading is not None and reading.question == normalize_text(spec.question), spec.instruction
            assert len(reading.options) == spec.n_choices
    assert read_instruction("") is None
    assert read_instruction(EpisodeSampler("RSB-Direct-4", "test").episode(0).instruction) is None
    assert read_instruction(EpisodeSampler("RSB-Math-4", "test", perturb="lang_order=2").episode(0).instruction) is None
