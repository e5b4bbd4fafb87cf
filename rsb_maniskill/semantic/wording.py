"""The language robustness axes: the same episode worded otherwise (``rsb_maniskill.perturb`` names them).

Each axis rewrites only how the instruction says things; the question, the options, their order,
the option -> candidate binding and so the correct option never change, and no rendering takes the
answer: :func:`render` has no answer parameter, as ``templates.render_instruction`` has none.

- ``lang_reference``: candidates named by a synonym (level 1: "the red cube"), a description (2:
  "the crimson block", "the little car"), or both (3: "the small crimson cube"); the templates'
  own noun ("block", "object") changes with them ("cube", "wooden block", "small wooden cube").
- ``lang_layout``: each option written "option A: 12" (1), "A <- 12" (2) or "12 is A" (3).
- ``lang_distractor``: irrelevant sentences: one at the end (1), at the start and the end (2),
  and after the question too (3).
- ``lang_order``: the options before the question: options, question, command (1); options,
  command, question (2); command, options, question (3). Fixed frames, the same for every template.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from rsb_maniskill.semantic.records import normalize_text
from rsb_maniskill.semantic.templates import Template, render_direct, render_template

# lang_reference, per level: 4-choice block colours, lettered blocks, and everyday categories.
COLOUR_WORDS = {"red": "crimson", "green": "emerald", "blue": "sapphire", "yellow": "golden"}
BLOCK_NOUN = {1: "cube", 2: "wooden block", 3: "small wooden cube"}  # the templates' noun ("block")
OBJECT_NOUN = {1: "item", 2: "thing", 3: "household item"}  # ... and the objects' ("object")
LETTERED_NAME = {1: "cube {X}", 2: "block marked {X}", 3: "cube showing the letter {X}"}
# category name -> (synonym, description, longer description): never a colour, never another category
OBJECT_NAMES: dict[str, tuple[str, str, str]] = {
    "toy car": ("toy vehicle", "little car", "small plastic vehicle"),
    "shoe": ("sneaker", "piece of footwear", "single trainer shoe"),
    "box of playing cards": ("deck of cards", "pack of playing cards", "small box holding a card deck"),
    "mug": ("coffee mug", "cup with a handle", "ceramic drinking mug"),
    "soda can": ("drink can", "can of pop", "aluminium soft-drink can"),
    "bottle": ("flask", "drinking bottle", "plastic water bottle"),
    "book": ("volume", "hardback", "bound hardback volume"),
    "banana": ("banana fruit", "curved fruit", "long curved fruit"),
    "apple": ("apple fruit", "round fruit with a stem", "small round orchard fruit"),
    "rubber duck": ("toy duck", "bath duck", "squeaky bath toy"),
    "remote control": ("remote", "TV remote", "television clicker"),
    "sponge": ("scrubber", "cleaning sponge", "kitchen scrubbing pad"),
    "tennis ball": ("ball", "fuzzy ball", "felt-covered ball"),
    "paper cup": ("disposable cup", "paper beaker", "single-use drinking cup"),
    "bowl": ("dish", "round bowl", "shallow serving dish"),
    "die": ("dice", "gaming die", "six-sided die"),
    "stapler": ("office stapler", "paper stapler", "desk stapling tool"),
    "glasses case": ("spectacles case", "eyeglass case", "case for eyeglasses"),
    "roll of tape": ("tape", "reel of tape", "roll of sticky tape"),
    "toothpaste tube": ("tube of toothpaste", "dental paste", "tube of dental paste"),
    "box of crayons": ("crayons", "pack of crayons", "carton of wax crayons"),
    "potted plant": ("plant", "houseplant", "small plant in a pot"),
    "spray bottle": ("sprayer", "spray flask", "trigger sprayer"),
    "wallet": ("purse", "billfold", "leather billfold"),
}
# lang_layout, per level: (entry of a named template, entry of a lettered one, lettered joiner)
LAYOUTS = {1: ("option {L}: {O}, the {B};", "option {L}: {O}", "; "),
           2: ("{L} <- {O}, the {B};", "{L} <- {O}", ", "),
           3: ("{O} is {L}, the {B};", "{O} is {L}", ", ")}
# lang_distractor: true of no episode, naming no number, letter, colour or candidate.
DISTRACTORS = (
    "The weather outside is calm today.", "This is one of many tasks in a long session.",
    "The room is quiet at the moment.", "Someone is reading a newspaper nearby.",
    "The window blinds are half open.", "It is a little past noon.",
    "Soft music is playing in the hallway.", "The floor was cleaned this morning.",
    "Somewhere down the corridor a door closes.", "Nobody else is working here right now.",
    "The air conditioner hums quietly.", "The lab lights were replaced last week.",
)
# lang_order frames (named: {MAPS}; lettered: {OPTIONS}); {CMD} is the command sentence.
ORDER_FRAMES = {1: "Options: {LIST} Question: {Q} {CMD}",
                2: "Options: {LIST} {CMD} The question is: {Q}",
                3: "{CMD} Options: {LIST} Which one answers this? {Q}"}
COMMAND = "Place the block of the correct option in the gray answer zone."


def reference_names(names: Sequence[str], keys: Sequence[str], level: int) -> tuple[str, ...]:
    """The candidates' names at a ``lang_reference`` level (all of them: none singled out)."""
    out = []
    for name, key in zip(names, keys):
        if key.startswith("block:"):
            label = key.split(":", 1)[1]
            if label in COLOUR_WORDS:
                colour = label if level == 1 else COLOUR_WORDS[label]
                out.append(f"{'small ' if level == 3 else ''}{colour} {'block' if level == 2 else 'cube'}")
            else:
                out.append(LETTERED_NAME[level].format(X=label))
        else:
            out.append(OBJECT_NAMES[name][level - 1])
    return tuple(out)


def reference_noun(noun: str, level: int) -> str:
    """The templates' noun at a ``lang_reference`` level ("block" -> "cube", "object" -> "item")."""
    return (BLOCK_NOUN if noun == "block" else OBJECT_NOUN)[level]


def render(template: Template, question: str, options: Sequence[str], letters: Sequence[str],
           names: Sequence[str], keys: Sequence[str], block_of_option: Sequence[int], noun: str,
           perturb: Mapping[str, int], rng: Mapping[str, np.random.Generator]) -> str:
    """The instruction of a multiple-choice episode under the language axes ``perturb`` (level > 0
    each; ``rng[axis]`` their draws). Deliberately has no answer parameter."""
    if "lang_reference" in perturb:
        level = perturb["lang_reference"]
        names, noun = reference_names(names, keys, level), reference_noun(noun, level)
    lettered = "{OPTIONS}" in template.text
    if "lang_layout" in perturb:
        named_entry, lettered_entry, joiner = LAYOUTS[perturb["lang_layout"]]
        template = Template(template.text, lettered_entry if lettered else named_entry,
                            joiner if lettered else " ")
    if "lang_order" in perturb:
        listing = "{OPTIONS}." if lettered else "{MAPS}"
        frame = ORDER_FRAMES[perturb["lang_order"]].replace("{LIST}", listing).replace("{CMD}", COMMAND)
        template = Template(frame, template.entry, template.joiner)
    text = render_template(template, question, options, letters, names, block_of_option, noun)
    if "lang_distractor" in perturb:
        text = add_distractors(text, normalize_text(question), perturb["lang_distractor"], rng["lang_distractor"])
    return text


def render_direct_perturbed(n_choices: int, template_id: int, name: str, key: str, perturb: Mapping[str, int],
                            rng: Mapping[str, np.random.Generator]) -> str:
    """A Direct instruction (it names its target) under the language axes: the reference and
    distractor axes apply; a Direct instruction has no options and no question to move."""
    if "lang_reference" in perturb:
        name = reference_names([name], [key], perturb["lang_reference"])[0]
    text = render_direct(n_choices, template_id, name)
    if "lang_distractor" in perturb:
        text = add_distractors(text, "", perturb["lang_distractor"], rng["lang_distractor"])
    return text


def add_distractors(text: str, question: str, level: int, rng: np.random.Generator) -> str:
    """``text`` with ``level`` irrelevant sentences: end (1), start and end (2), and after the question (3)."""
    picks = [DISTRACTORS[int(i)] for i in rng.choice(len(DISTRACTORS), size=3, replace=False)]
    text = f"{text} {picks[0]}"
    if level >= 2:
        text = f"{picks[1]} {text}"
    if level >= 3 and question and question in text:
        text = text.replace(question, f"{question} {picks[2]}", 1)
    elif level >= 3:
        text = f"{picks[2]} {text}"
    return normalize_text(text)
