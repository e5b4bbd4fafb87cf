"""Which option a text states: the one parser of what a policy says and what a backbone answers.

A policy that talks (its chain of thought, ``docs/evaluation.md``) and a backbone asked the
question (``rsb backbone``) both answer in words. :func:`read_statement` finds the option such a
text names, against the episode's :class:`~rsb_maniskill.semantic.spec.EpisodeSpec`, in the forms
RSB's instructions use:

- *the option itself*: "option B", "choice B", "the answer is B", 'answer: "B"', "the answer is
  letter B";
- *other references*: the letter in every entry form of ``templates.py`` ("(B)", "B)", "B: ...",
  "[B]", "marked B", "10 is B") and the candidate bound to the option ("the green block", "block
  F", "the mug", and the ``lang_reference`` names of ``wording.py``: "the crimson cube");
- *values*: the option's text or number ("the answer is 10", "27 minus 17 equals 10").

The first kind the text holds decides: a chain of thought may mention other letters and objects
on its way ("exit A", "a stapler is used to ..."), but "option K" is what it concludes. Numbers
that are operands of a computation ("27 minus 17") are not taken for an answer; the text's copy of
the question is ignored, and so are letters and names inside an option's own text ("Vitamin A").
A text naming no option, or several different ones, states none.

:func:`read_instruction` is the inverse of the templates: the question and the options an
unperturbed multiple-choice instruction shows (what a question-only reader needs). Nothing here
imports the simulator.
"""
from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Sequence

from rsb_maniskill.objects.catalog import CATEGORY_KEYS, category_name
from rsb_maniskill.objects.family import get_family
from rsb_maniskill.semantic.normalize import numeric_values
from rsb_maniskill.semantic.records import normalize_text
from rsb_maniskill.semantic.suites import letters_for
from rsb_maniskill.semantic.templates import Template, render_template, template_family
from rsb_maniskill.semantic.wording import COLOUR_WORDS, OBJECT_NAMES, reference_names

_LETTERS = "ABCDEFGHIK"  # every option letter of the suites (J is never used)
_OPERATOR = r"(?:\b(?:plus|minus|times|multiplied by|divided by)\b|[-+*/×÷]|\bx\b)"
_OPERAND_AFTER = re.compile(rf"\s*{_OPERATOR}", re.IGNORECASE)  # the number is followed by an operator ...
_OPERAND_BEFORE = re.compile(rf"{_OPERATOR}\s*$", re.IGNORECASE)  # ... or follows one
_NUMBER = re.compile(r"(?<![\w.,])-?\$?\d[\d,]*(?:\.\d+)?(?![\w]|\.\d)")
_MASK = "\x00"


@dataclass(frozen=True)
class Statement:
    """What a text states: ``letter`` the one option it names (None: no option, or several);
    ``named`` the letters of the options named by the kind of mention that decided, in option
    order; ``by`` that kind: ``"option"``, ``"reference"``, ``"value"`` or ``"none"``."""

    letter: str | None
    named: tuple[str, ...]
    by: str


def read_statement(text: str | None, spec: Any) -> Statement:
    """The option ``text`` states in the episode ``spec`` (an EpisodeSpec, or anything with its
    ``question``, ``options``, ``letters``, ``block_of_option``, ``block_names`` and ``candidates``)."""
    t = _clean(text or "")
    if spec.question:
        t = re.sub(re.escape(_clean(spec.question)), " ", t, flags=re.IGNORECASE)
    letters = tuple(spec.letters)
    values, t = _value_mentions(t, spec)
    options = _letter_mentions(t, letters, _OPTION_PATTERNS)
    refs = _letter_mentions(t, letters, _REFERENCE_PATTERNS) | _candidate_mentions(t, spec)
    for by, slots in (("option", options), ("reference", refs), ("value", values)):
        if slots:
            named = tuple(letters[i] for i in sorted(slots))
            return Statement(named[0] if len(named) == 1 else None, named, by)
    return Statement(None, (), "none")


def stated_letter(text: str | None, spec: Any) -> str | None:
    """The letter of the one option ``text`` names, else None (see :func:`read_statement`)."""
    return read_statement(text, spec).letter


# ---------------------------------------------------------------- mentions
def _clean(text: str) -> str:
    """One line, NFKC (full-width letters, non-breaking spaces), typographic minus as '-'."""
    return normalize_text(unicodedata.normalize("NFKC", str(text)).replace("−", "-").replace("–", "-"))


def _mask(text: str, spans: Sequence[tuple[int, int]]) -> str:
    out = list(text)
    for a, b in spans:
        out[a:b] = _MASK * (b - a)
    return "".join(out)


def _value_mentions(t: str, spec: Any) -> tuple[set[int], str]:
    """Options named by their value, and ``t`` with their text masked (so that a letter or a
    name inside an option's text is not read as a reference)."""
    found: set[int] = set()
    values = numeric_values(list(spec.options))
    if values is not None:
        for m in _NUMBER.finditer(t):
            if _OPERAND_AFTER.match(t, m.end()) or _OPERAND_BEFORE.search(t[max(0, m.start() - 24):m.start()]):
                continue  # "27 minus 17": operands, not an answer
            v = float(m.group(0).replace("$", "").replace(",", ""))
            found |= {i for i, o in enumerate(values) if abs(o - v) <= 1e-9 * max(1.0, abs(v))}
        return found, t
    spans = []
    for i in sorted(range(len(spec.options)), key=lambda k: -len(spec.options[k])):
        words = _clean(spec.options[i]).rstrip(" .;,")
        if len(words) < 2:
            continue  # an option "k" cannot be told from the letter K
        for m in _phrase(words).finditer(_mask(t, spans)):
            found.add(i)
            spans.append(m.span())
    return found, _mask(t, spans)


@lru_cache(maxsize=4096)
def _phrase(words: str) -> re.Pattern:
    """A whole-phrase, case-blind, spacing-blind pattern of ``words``."""
    body = r"\s+".join(re.escape(w) for w in words.split())
    head = r"(?<!\w)" if words[:1].isalnum() else ""
    tail = r"(?!\w)" if words[-1:].isalnum() else ""
    return re.compile(head + body + tail, re.IGNORECASE)


# A single letter names an option after these words ("option B", "answer is B") ...
_OPTION_PATTERNS = (rf"\b(?:option|choice|answer)\s*(?:is\s+|:\s*|=\s*|#\s*)?(?:(?:option|choice|letter)\s+)?"
                    rf"[(\[\"'“‘]?(?P<L>[{_LETTERS}])(?![\w'])",)
# ... and in the entry forms of the templates and the names of the lettered blocks.
_REFERENCE_PATTERNS = (
    rf"\b(?:letter|block|cube|marked|carries|labell?ed)\s+(?P<L>[{_LETTERS}])(?![\w'])",
    rf"[(\[](?P<L>[{_LETTERS}])[)\]]",  # (B) [B]
    rf"(?<![\w'])(?P<L>[{_LETTERS}])\)",  # B)
    rf"(?<![\w'])(?P<L>[{_LETTERS}])\s*(?::|=|->|<-|=>|\s-\s)",  # B: / B = / B -> / B <- / B - 10
    rf"(?<![\w'])(?P<L>[{_LETTERS}]) is\b",  # B is 10
    rf"\bis (?P<L>[{_LETTERS}])(?![\w'])(?!\s+[a-z])",  # 10 is B
    rf"^\W*(?P<L>[{_LETTERS}])\W*$",  # just "B" or "B."
)


@lru_cache(maxsize=None)
def _compiled(pattern: str) -> re.Pattern:
    # Case-blind keywords ("Option b" too); the letter itself is checked by _letter_mentions.
    return re.compile(pattern, re.IGNORECASE)


def _letter_mentions(t: str, letters: Sequence[str], patterns: Sequence[str]) -> set[int]:
    index = {letter: i for i, letter in enumerate(letters)}
    found = set()
    for pattern in patterns:
        for m in _compiled(pattern).finditer(t):
            if m.group("L") in index or (m.group("L").upper() in index and _keyword_case_ok(m)):
                found.add(index[m.group("L").upper()])
    return found


def _keyword_case_ok(m: re.Match) -> bool:
    """A lower-case letter counts only right after "option" or "choice" ("option b"): elsewhere
    "a" and "i" are words."""
    return re.fullmatch(r"(?i)(?:option|choice)\s*[(\[\"'“‘]?[a-z]", m.group(0)) is not None


def _names(spec: Any) -> list[tuple[str, int]]:
    """(name, candidate index) of every way the instructions call a candidate, longest first."""
    out = []
    for c, (name, key) in enumerate(zip(spec.block_names, spec.candidates)):
        out.append((name, c))
        if key.startswith("block:"):
            out += [(reference_names([name], [key], level)[0], c) for level in (1, 2, 3)]
            label = key.split(":", 1)[1]
            if label in COLOUR_WORDS:  # "the green one", "the emerald one"
                out += [(f"{colour} one", c) for colour in (label, COLOUR_WORDS[label])]
        else:  # one-word synonyms ("ball", "volume") are too common to mean the object
            out += [(alias, c) for alias in OBJECT_NAMES.get(name, ()) if " " in alias]
    return sorted(set(out), key=lambda p: -len(p[0]))


def _candidate_mentions(t: str, spec: Any) -> set[int]:
    slot_of = {c: i for i, c in enumerate(spec.block_of_option)}
    found, spans = set(), []
    for name, c in _names(spec):
        for m in _phrase(name).finditer(_mask(t, spans)):
            found.add(slot_of[c])
            spans.append(m.span())
    return found


# ---------------------------------------------------------------- instructions
@dataclass(frozen=True)
class Reading:
    """The question and options an instruction shows, with the options' letters."""

    question: str
    options: tuple[str, ...]
    letters: tuple[str, ...]


def read_instruction(instruction: str) -> Reading | None:
    """The question and options of an unperturbed multiple-choice instruction (any template, N,
    candidate family), or None (a Direct or blank instruction, or one in another wording)."""
    text = normalize_text(instruction)
    for pattern, letters in _instruction_patterns():
        if all(piece in text for piece in pattern.pieces):
            m = pattern.regex.fullmatch(text)
            if m:
                return Reading(m.group("q"), tuple(m.group(f"o{i}") for i in range(len(letters))), letters)
    return None


@dataclass(frozen=True)
class _Pattern:
    regex: re.Pattern
    pieces: tuple[str, ...]  # literal text the instruction must hold: a cheap test before the regex


@lru_cache(maxsize=1)
def _instruction_patterns() -> tuple[tuple[_Pattern, tuple[str, ...]], ...]:
    """One pattern per (template, N, noun): the template rendered on placeholders, escaped, and
    the placeholders turned into groups, so the templates' own rendering is what is inverted."""
    out = []
    # ten options first: a four-option pattern would take the rest of a ten-option list for its last entry
    for n, lettered, noun in ((10, True, "block"), (10, False, "object"), (4, False, "block"), (4, False, "object")):
        letters = letters_for(n)
        seen, unseen = template_family(n, lettered=lettered)
        for template in seen + unseen:
            out.append((_pattern(template, letters, noun), letters))
    return tuple(out)


@lru_cache(maxsize=1)
def _candidate_names() -> str:
    """Any name an unperturbed instruction calls a candidate by: the coloured and the lettered
    blocks and every everyday category (a name, not any text: options may hold "(...)" too)."""
    blocks = get_family("blocks")
    names = {*blocks.names(4, letters_for(4)), *blocks.names(10, letters_for(10))}
    names |= {category_name(key) for key in CATEGORY_KEYS}
    return "(?:" + "|".join(re.escape(n) for n in sorted(names, key=len, reverse=True)) + ")"


def _pattern(template: Template, letters: Sequence[str], noun: str) -> _Pattern:
    n = len(letters)
    text = render_template(template, "\x01q\x01", [f"\x02{i}\x02" for i in range(n)], letters,
                           [f"\x03{i}\x03" for i in range(n)], list(range(n)), noun)
    parts = re.split(r"(\x01q\x01|\x02\d+\x02|\x03\d+\x03)", text)
    regex, pieces = [], []
    for part in parts:
        if part.startswith("\x01"):
            regex.append(r"(?P<q>.+)")  # greedy: a question may hold an entry's form ("A is 60 degrees")
        elif part.startswith("\x02"):
            regex.append(rf"(?P<o{part[1:-1]}>.+?)")
        elif part.startswith("\x03"):
            regex.append(_candidate_names())
        elif part:
            regex.append(re.escape(part))
            pieces.append(part)
    return _Pattern(re.compile("".join(regex), re.DOTALL), tuple(pieces))
