"""Instruction templates (paper section 3.4): question, options and their candidates, never the answer.

Three families. *Named* templates bind each option to a candidate by name in ``{MAPS}`` (one
"option -> candidate" entry each: the 4 coloured blocks, and everyday objects at any N).
*Lettered* templates list the options in ``{OPTIONS}`` only: the 10 lettered blocks carry the
option letters themselves. *Direct* templates name the target in ``{BLOCK}``. Each template has
its own entry format so that the option list is worded differently too. The templates say
"block"; other candidate families swap in their noun ("object"). "seen" templates are for
training, "unseen" ones, worded differently, for evaluation. Template ids: seen 0..S-1, unseen
S..S+U-1 within a family.

:func:`render_instruction` takes no answer argument at all: an instruction cannot depend on
which option is correct.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Sequence

from rsb_maniskill.semantic.records import normalize_text


@dataclass(frozen=True)
class Template:
    text: str
    entry: str  # format of one option mapping: {L} letter, {O} option text, {B} block name
    joiner: str = " "


_M4 = "{MAPS}"  # every option with its candidate

SEEN_NAMED: tuple[Template, ...] = (
    Template("{Q} Options: " + _M4 + " Place the block of the correct option in the gray answer zone.", "({L}) {O} - {B}."),
    Template("Question: {Q} Choices: " + _M4 + " Pick up the block that matches the right answer and put it in the gray answer zone.", "{L}: {O} ({B})."),
    Template("{Q} " + _M4 + " Move the block of the correct choice into the gray answer zone.", "Option {L} is {O}, on the {B}."),
    Template("Answer this: {Q} The options are " + _M4 + " Put the matching block in the gray answer zone.", "({L}) {O} [{B}]"),
    Template("Solve: {Q} " + _M4 + " Then place the block for your answer in the gray answer zone.", "{L} = {O} -> {B};"),
    Template("{Q} Choose from " + _M4 + " and put that block in the gray answer zone.", "({L}) {O} on the {B},"),
    Template("Here is a question: {Q} Possible answers: " + _M4 + " Grasp the block of the correct answer and drop it in the gray answer zone.", "{L}) {O}, the {B}."),
    Template("{Q} Candidates: " + _M4 + " Carry the block holding the right option to the gray answer zone.", "{L}: {O} / {B}."),
    Template("Work out the answer. {Q} " + _M4 + " Place the corresponding block in the gray answer zone.", "({L}) {O} is the {B}."),
    Template("{Q} The {BLOCKS} stand for these options: " + _M4 + " Put the block of the correct one in the gray answer zone.", "{L} {O} ({B})"),
    Template("Read the question and act. {Q} " + _M4 + " Move the block that answers it to the gray answer zone.", "({L}) {O}, {B}."),
    Template("{Q} Options with their blocks: " + _M4 + " Pick the block of the correct option and place it in the gray answer zone.", "{L}: {O} - {B};"),
    Template("Question: {Q} Answer choices: " + _M4 + " Deliver the block of the right choice to the gray answer zone.", "({L}) {O} => {B}"),
    Template("{Q} Option list: " + _M4 + " Place the block belonging to the correct answer in the gray answer zone.", "option {L}: {O} on the {B}."),
    Template("Figure out: {Q} " + _M4 + " Then pick up the matching block and set it down in the gray answer zone.", "{L} is {O} ({B})."),
    Template("{Q} Each block is an option: " + _M4 + " Put the block with the correct option in the gray answer zone.", "the {B} is ({L}) {O}."),
    Template("Quiz: {Q} " + _M4 + " Select the block of the right answer and move it to the gray answer zone.", "({L}) {O} {B},"),
    Template("{Q} Here are the options: " + _M4 + " Take the block of the correct answer to the gray answer zone.", "{L} - {O} - {B}."),
    Template("Please answer: {Q} " + _M4 + " Place the block that corresponds to your answer in the gray answer zone.", "({L}) {O}: {B}."),
    Template("{Q} Pick one of " + _M4 + " and place its block in the gray answer zone.", "({L}) {O} as the {B},"),
)
UNSEEN_NAMED: tuple[Template, ...] = (
    Template("Think about this problem: {Q} You can choose " + _M4 + " Lift whichever block shows the solution and lay it inside the gray target area.", "{O} marked {L} with the {B},"),
    Template("A question for the robot: {Q} Listed answers are " + _M4 + " Bring the solution's block over to the gray square.", "[{L}] {O} goes with the {B};"),
    Template("{Q} Among " + _M4 + " exactly one fits. Set its block down on the gray region.", "{O} (letter {L}, {B}),"),
    Template("Consider: {Q} Alternatives: " + _M4 + " Find the block standing for the solution and transport it onto the gray patch.", "letter {L} means {O} and uses the {B};"),
    Template("Your task is to answer {Q} by moving a block. Mapping: " + _M4 + " Drop the block for the answer on the gray area.", "{L} -> {O} -> {B},"),
    Template("{Q} Possible solutions and blocks: " + _M4 + " Relocate the one that solves it to the gray zone on the table.", "{O} is {L}, held by the {B}."),
    Template("Determine the solution to the following. {Q} Blocks: " + _M4 + " Transfer the right block onto the gray mat.", "the {B} carries {L}, {O};"),
    Template("Respond with a block. {Q} Choices map as " + _M4 + " Lay the block of the true answer in the gray area.", "{L} <- {O} ({B}),"),
)

SEEN_LETTERED: tuple[Template, ...] = (
    Template("{Q} Options: {OPTIONS}. Place the block of the correct option in the gray answer zone.", "({L}) {O}"),
    Template("Question: {Q} Choices: {OPTIONS}. Pick up the lettered block of the right answer and put it in the gray answer zone.", "{L}: {O}", "; "),
    Template("{Q} {OPTIONS}. Move the block of the correct choice into the gray answer zone.", "option {L} is {O}", ", "),
    Template("Answer this: {Q} The options are {OPTIONS}. Put the matching letter block in the gray answer zone.", "({L}) {O}", ", "),
    Template("Solve: {Q} {OPTIONS}. Then place the block for your answer in the gray answer zone.", "{L} = {O}", "; "),
    Template("{Q} Choose from {OPTIONS} and put that block in the gray answer zone.", "({L}) {O}", ", "),
    Template("Here is a question: {Q} Possible answers: {OPTIONS}. Grasp the block of the correct answer and drop it in the gray answer zone.", "{L}) {O}", " "),
    Template("{Q} Candidates: {OPTIONS}. Carry the block with the right letter to the gray answer zone.", "{L}: {O}", " / "),
    Template("Work out the answer. {Q} {OPTIONS}. Place the corresponding letter block in the gray answer zone.", "({L}) {O}", " "),
    Template("{Q} The blocks are lettered: {OPTIONS}. Put the block of the correct one in the gray answer zone.", "{B} is {O}", ", "),
    Template("Read the question and act. {Q} {OPTIONS}. Move the block that answers it to the gray answer zone.", "({L}) {O}", "; "),
    Template("{Q} Options by letter: {OPTIONS}. Pick the block of the correct option and place it in the gray answer zone.", "{L} - {O}", "; "),
    Template("Question: {Q} Answer choices: {OPTIONS}. Deliver the block of the right choice to the gray answer zone.", "({L}) {O}", " "),
    Template("{Q} Option list: {OPTIONS}. Place the block lettered with the correct answer in the gray answer zone.", "option {L}: {O}", "; "),
    Template("Figure out: {Q} {OPTIONS}. Then pick up the matching block and set it down in the gray answer zone.", "{L} is {O}", ", "),
    Template("{Q} Each block is an option: {OPTIONS}. Put the block with the correct option in the gray answer zone.", "{B}: {O}", "; "),
    Template("Quiz: {Q} {OPTIONS}. Select the block of the right answer and move it to the gray answer zone.", "({L}) {O}", ", "),
    Template("{Q} Here are the options: {OPTIONS}. Take the block of the correct answer to the gray answer zone.", "{L} - {O}", ", "),
    Template("Please answer: {Q} {OPTIONS}. Place the block that corresponds to your answer in the gray answer zone.", "({L}) {O}", "; "),
    Template("{Q} Pick one of {OPTIONS} and place its block in the gray answer zone.", "({L}) {O}", " "),
)
UNSEEN_LETTERED: tuple[Template, ...] = (
    Template("Think about this problem: {Q} You can choose {OPTIONS}. Lift whichever letter block shows the solution and lay it inside the gray target area.", "{O} marked {L}", ", "),
    Template("A question for the robot: {Q} Listed answers are {OPTIONS}. Bring the solution's block over to the gray square.", "[{L}] {O}", " "),
    Template("{Q} Among {OPTIONS} exactly one fits. Set its block down on the gray region.", "{O} (letter {L})", ", "),
    Template("Consider: {Q} Alternatives: {OPTIONS}. Find the block standing for the solution and transport it onto the gray patch.", "letter {L} means {O}", "; "),
    Template("Your task is to answer {Q} by moving a block. Mapping: {OPTIONS}. Drop the block for the answer on the gray area.", "{L} -> {O}", ", "),
    Template("{Q} Possible solutions by letter: {OPTIONS}. Relocate the one that solves it to the gray zone on the table.", "{O} is {L}", "; "),
    Template("Determine the solution to the following. {Q} Letters: {OPTIONS}. Transfer the right block onto the gray mat.", "{B} carries {O}", "; "),
    Template("Respond with a block. {Q} Choices map as {OPTIONS}. Lay the block of the true answer in the gray area.", "{L} <- {O}", ", "),
)

# Direct (diagnostic): the instruction names the target block itself; {BLOCK} = "blue block" / "block F".
SEEN_DIRECT: tuple[Template, ...] = tuple(Template(t, "") for t in (
    "Put the {BLOCK} in the gray answer zone.",
    "Pick up the {BLOCK} and place it in the gray answer zone.",
    "Move the {BLOCK} into the gray answer zone.",
    "Place the {BLOCK} in the gray answer zone.",
    "Grasp the {BLOCK} and drop it in the gray answer zone.",
    "Carry the {BLOCK} to the gray answer zone.",
    "Take the {BLOCK} to the gray answer zone.",
    "Deliver the {BLOCK} to the gray answer zone.",
    "Select the {BLOCK} and move it to the gray answer zone.",
    "Set the {BLOCK} down in the gray answer zone.",
    "Put the {BLOCK} into the gray answer zone, please.",
    "Pick the {BLOCK} and place it in the gray answer zone.",
    "Your target is the {BLOCK}: put it in the gray answer zone.",
    "Bring the {BLOCK} to the gray answer zone.",
    "Grab the {BLOCK} and put it in the gray answer zone.",
    "Lift the {BLOCK} and set it in the gray answer zone.",
    "Move only the {BLOCK} to the gray answer zone.",
    "The {BLOCK} goes in the gray answer zone.",
    "Place the {BLOCK} inside the gray answer zone.",
    "Get the {BLOCK} into the gray answer zone.",
))
UNSEEN_DIRECT: tuple[Template, ...] = tuple(Template(t, "") for t in (
    "Transport the {BLOCK} onto the gray patch.",
    "Lay the {BLOCK} inside the gray target area.",
    "Relocate the {BLOCK} to the gray square on the table.",
    "The gray region should end up holding the {BLOCK}.",
    "Transfer the {BLOCK} onto the gray mat.",
    "Use a gripper to shift the {BLOCK} over to the gray area.",
    "Drop the {BLOCK} on the gray zone of the table.",
    "Make sure the {BLOCK} ends up in the gray target.",
))


_NOUN = re.compile(r"\b(?:([Aa]) )?([Bb])lock(s?)\b")


def template_family(n_choices: int, direct: bool = False,
                    lettered: bool | None = None) -> tuple[tuple[Template, ...], tuple[Template, ...]]:
    """(seen, unseen) templates: direct, lettered (default for 10 choices: the lettered blocks) or named."""
    if n_choices not in (4, 10):
        raise ValueError(f"n_choices must be 4 or 10, got {n_choices!r}")
    if direct:
        return SEEN_DIRECT, UNSEEN_DIRECT
    if lettered is None:
        lettered = n_choices == 10
    if lettered:
        return SEEN_LETTERED, UNSEEN_LETTERED
    return SEEN_NAMED, UNSEEN_NAMED


def template_ids(n_choices: int, instructions: str, direct: bool = False, lettered: bool | None = None) -> range:
    """Template ids available for an instruction set ("seen" or "unseen")."""
    seen, unseen = template_family(n_choices, direct, lettered)
    if instructions == "seen":
        return range(len(seen))
    if instructions == "unseen":
        return range(len(seen), len(seen) + len(unseen))
    raise ValueError(f"unknown instruction set {instructions!r}; valid: seen, unseen")


def sibling_template_ids(n_choices: int, template_id: int, direct: bool = False,
                         lettered: bool | None = None) -> range:
    """Ids of the instruction set (seen or unseen) that ``template_id`` belongs to: rewording an
    episode with these never crosses from the training wording into the held-out one."""
    seen, _ = template_family(n_choices, direct, lettered)
    return template_ids(n_choices, "seen" if template_id < len(seen) else "unseen", direct, lettered)


def get_template(n_choices: int, template_id: int, direct: bool = False, lettered: bool | None = None) -> Template:
    seen, unseen = template_family(n_choices, direct, lettered)
    allt = seen + unseen
    if not 0 <= template_id < len(allt):
        raise ValueError(f"template id {template_id} out of range 0..{len(allt) - 1}")
    return allt[template_id]


def _with_noun(text: str, noun: str) -> str:
    """The template's "block(s)" as another family's noun ("object(s)")."""
    if noun == "block":
        return text

    def swap(m: re.Match) -> str:
        word = (noun.capitalize() if m[2] == "B" else noun) + m[3]
        if m[1] is None:
            return word
        article = m[1] + ("n" if noun[0] in "aeiou" else "")
        return f"{article} {word}"

    return _NOUN.sub(swap, text)


def render_instruction(n_choices: int, template_id: int, question: str, options: Sequence[str],
                       letters: Sequence[str], block_names: Sequence[str], block_of_option: Sequence[int],
                       lettered: bool | None = None, noun: str = "block") -> str:
    """Instruction for a multiple-choice episode. Deliberately has no answer parameter.

    ``block_names[c]`` names candidate ``c``; option ``i`` is bound to ``block_of_option[i]``."""
    return render_template(get_template(n_choices, template_id, lettered=lettered), question, options, letters,
                           block_names, block_of_option, noun)


def render_template(t: Template, question: str, options: Sequence[str], letters: Sequence[str],
                    block_names: Sequence[str], block_of_option: Sequence[int], noun: str = "block") -> str:
    """:func:`render_instruction` with the template given (the language robustness axes build
    their own); no answer parameter either."""
    n_choices = len(options)
    entries = [t.entry.format(L=letters[i], O=normalize_text(options[i]), B=block_names[block_of_option[i]])
               for i in range(n_choices)]
    fields = {"Q": normalize_text(question)}
    text = _with_noun(t.text, noun)
    if "{MAPS}" in t.text:
        # the last mapping closes the list: a full stop before a new sentence, nothing mid-sentence
        after = t.text.split("{MAPS}", 1)[1]
        last = entries[-1].rstrip(",;.")
        entries[-1] = last + "." if after[:1] == " " and after[1:2].isupper() else last
        fields["BLOCKS"] = ", ".join(block_names[:-1]) + " and " + block_names[-1]
        text = text.format(MAPS=" ".join(entries), **fields)
    else:
        if t.text.partition("{OPTIONS}")[2][:1] == "." and entries[-1].endswith("."):
            entries[-1] = entries[-1][:-1]  # an option ending its own sentence closes the list: one full stop
        text = text.format(OPTIONS=t.joiner.join(entries), **fields)
    return normalize_text(text)


def render_direct(n_choices: int, template_id: int, block_name: str) -> str:
    """Instruction of a Direct episode: names the target candidate (that is the point of Direct)."""
    return get_template(n_choices, template_id, direct=True).text.format(BLOCK=block_name)
