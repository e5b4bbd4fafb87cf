"""Instructions: template counts, seen/unseen wording, and no answer leak on every source."""
from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

from rsb_maniskill.semantic import EpisodeSampler, render_instruction
from rsb_maniskill.semantic import templates as T

FIXTURES = Path(__file__).parents[1] / "fixtures" / "semantic_data"
LEAK = re.compile(r"answer is|is (?:the )?(?:correct|right|true)\b|correct (?:answer|option|choice|block) is|"
                  r"\bsolution is|\bhint\b", re.IGNORECASE)


def _words(t: str) -> set[str]:
    return set(re.findall(r"[a-z']+", re.sub(r"\{[A-Z]+\}", " ", t.lower())))


@pytest.mark.parametrize("n, direct", [(4, False), (10, False), (4, True), (10, True)])
def test_template_counts_and_wording(n, direct):
    seen, unseen = T.template_family(n, direct)
    assert len(seen) >= 20 and len(unseen) >= 8
    assert len({t.text for t in seen + unseen}) == len(seen) + len(unseen)
    for u in unseen:  # worded differently: no unseen template is a near copy of a seen one
        for s in seen:
            a, b = _words(u.text), _words(s.text)
            assert len(a & b) / len(a | b) < 0.7, (u.text, s.text)
    for t in seen + unseen:
        if direct:
            assert "{BLOCK}" in t.text
        elif n == 4:
            assert "{MAPS}" in t.text and "{Q}" in t.text
            assert "{O}" in t.entry and "{L}" in t.entry and "{B}" in t.entry  # option and its block
        else:
            assert "{OPTIONS}" in t.text and "{Q}" in t.text and "{O}" in t.entry
        assert not LEAK.search(t.text)


def test_seen_for_train_unseen_for_test():
    seen_ids = set(T.template_ids(4, "seen"))
    tr = EpisodeSampler("RSB-Math-4", "train")
    te = EpisodeSampler("RSB-Math-4", "test")
    assert {tr.sample(s).template_id for s in range(200)} == seen_ids
    assert {te.sample(s).template_id for s in range(200)} == set(T.template_ids(4, "unseen"))
    seen_test = EpisodeSampler("RSB-Math-4", "test", instructions="seen")
    assert {seen_test.sample(s).template_id for s in range(50)} <= seen_ids


def test_renderer_cannot_see_the_answer():
    params = set(inspect.signature(render_instruction).parameters)
    assert not params & {"answer", "answer_slot", "correct", "correct_letter", "target"}


def _check_no_leak(spec):
    # 1) the instruction is a function of the visible fields only: rebuilding it without the
    #    answer gives the same text, so it is identical whichever option is correct
    again = render_instruction(spec.n_choices, spec.template_id, spec.question, spec.options, spec.letters,
                               spec.block_names, spec.block_of_option)
    assert again == spec.instruction
    # 2) no leaking phrase outside the question and option texts
    rest = spec.instruction.replace(spec.question, " ")
    for o in sorted(spec.options, key=len, reverse=True):
        rest = rest.replace(o, " ")
    assert not LEAK.search(rest), spec.instruction
    # 3) every letter appears the same number of times (the answer letter is not singled out)
    fixed = re.sub(r"\{[A-Z]+\}", " ", T.get_template(spec.n_choices, spec.template_id).text)  # e.g. "A question"

    def solo(L, text):
        return len(re.findall(rf"(?<![A-Za-z']){L}(?![A-Za-z'])", text))

    counts = {L: solo(L, rest) - solo(L, fixed) for L in spec.letters}
    assert len(set(counts.values())) == 1, (counts, spec.instruction)
    # 4) every block name appears once per option mapping (4-choice)
    if spec.n_choices == 4:
        assert {spec.instruction.count(b) for b in spec.block_names} == {1} or "{BLOCKS}" in \
            T.get_template(4, spec.template_id).text


@pytest.mark.parametrize("suite_id", ["RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4", "RSB-HardMath-10",
                                      "RSB-General-4", "RSB-General-10"])
@pytest.mark.parametrize("split", ["train", "test"])
def test_no_leak_every_source(suite_id, split):
    s = EpisodeSampler(suite_id, split, color_map="shuffle", data_dir=FIXTURES)
    sources = set()
    for seed in range(150):
        spec = s.sample(seed)
        if s.pool is not None:
            sources.add(s.pool.questions[spec.question_id].source)
        _check_no_leak(spec)
    if suite_id.startswith("RSB-General") and split == "train":
        assert sources == {"commonsense", "mmlu_pro"}


def test_same_options_any_answer_same_instruction():
    """Swapping which option is correct (same options) leaves the instruction unchanged."""
    s = EpisodeSampler("RSB-General-4", data_dir=FIXTURES)
    spec = s.sample(11)
    for slot in range(4):
        other = spec.__class__(**{**spec.__dict__, "answer_slot": slot, "correct_letter": spec.letters[slot]})
        assert render_instruction(4, other.template_id, other.question, other.options, other.letters,
                                  other.block_names, other.block_of_option) == spec.instruction


def test_instruction_lists_each_option_with_its_block():
    s = EpisodeSampler("RSB-Math-4", color_map="shuffle")
    for seed in range(50):
        spec = s.sample(seed)
        for i, opt in enumerate(spec.options):
            block = spec.block_names[spec.block_of_option[i]]
            entry = T.get_template(4, spec.template_id).entry.format(L=spec.letters[i], O=opt, B=block)
            assert entry.rstrip(",;.") in spec.instruction


@pytest.mark.parametrize("suite_id, targets", [("RSB-Direct-4", "blocks"), ("RSB-Direct-10", "blocks"),
                                               ("RSB-Math-4", "blocks"), ("RSB-General-10", "blocks"),
                                               ("RSB-Math-4", "objects"), ("RSB-Direct-4", "objects")])
@pytest.mark.parametrize("split", ["train", "test"])
def test_paraphrases_reword_within_the_episodes_template_set(suite_id, targets, split):
    """Every template of the episode's own set, the recorded wording first, the same question, options,
    bindings (and target, Direct) in each; never a wording of the other set."""
    from rsb_maniskill.semantic.paraphrase import paraphrases

    s = EpisodeSampler(suite_id, split, color_map="shuffle", data_dir=FIXTURES, targets=targets)
    other = EpisodeSampler(suite_id, "test" if split == "train" else "train", data_dir=FIXTURES, targets=targets)
    other_wordings = {other.sample(seed).instruction for seed in range(300)}
    for seed in range(12):
        spec = s.sample(seed)
        texts = paraphrases(spec)
        assert texts[0] == spec.instruction
        assert len(texts) == len(set(texts)) == len(s._templates)
        for t in texts:
            if spec.suite == "Direct":
                assert spec.block_names[spec.target_block] in t
            else:
                assert spec.question in t and all(o in t for o in spec.options)
                assert all(b in t for b in spec.block_names) or spec.n_choices == 10  # lettered: letters only
        assert not set(texts) & other_wordings
    # a spec whose template no longer renders its recorded instruction is refused, not reworded
    bad = spec.__class__(**{**spec.__dict__, "instruction": spec.instruction + " Now."})
    with pytest.raises(ValueError, match="not the recorded"):
        paraphrases(bad)


@pytest.mark.parametrize("tid", range(len(T.SEEN_LETTERED) + len(T.UNSEEN_LETTERED)))
def test_an_option_ending_its_sentence_closes_the_list_with_one_full_stop(tid):
    """General-10's MMLU-Pro options often end with their own full stop: never ".. Place the block"."""
    opts = [f"option {i} holds." for i in range(9)] + ["at least 200 songs."]
    letters = "ABCDEFGHIK"
    text = render_instruction(10, tid, "How many songs?", opts, letters, [f"block {c}" for c in letters],
                              list(range(10)))
    assert ".." not in text and "at least 200 songs." in text  # the option's own full stop is kept
