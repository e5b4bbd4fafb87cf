"""Commonsense questions generated from the knowledge table (knowledge.py).

Each fact yields questions in both directions (tool -> purpose, purpose -> tool, ...) and in
several phrasings. Facts, not questions, are split between the pools (half each, by stable hash
of the fact's split key), so no fact is asked in both pools in either direction: location facts
are keyed by their place's *area* (areas are dealt out evenly instead of hashed), because the
reverse question "Which of these is kept in the pantry?" asks about every item of the pantry at
once, and "kept in the bathroom" is nearly "kept in the bathroom cabinet".

Distractors (see distractors.py) are other answers of the same kind of question *in the same
split*, each weighted by how often it is an answer there, minus rows that could also be right
(conflict groups, place areas) and texts sharing a word or stem with the question. So neither
identity, wording nor "was it ever an answer in training" marks the answer. The even split
leaves each split enough answers of every kind for ten options.
"""
from __future__ import annotations

from collections import Counter
from functools import lru_cache
from typing import NamedTuple

from rsb_maniskill.semantic import knowledge as kb
from rsb_maniskill.semantic.normalize import option_key, related_words
from rsb_maniskill.semantic.records import Question
from rsb_maniskill.semantic.stable import stable_bucket

TRAIN_PERCENT = 50


class CommonsenseItem(NamedTuple):
    question: Question
    candidates: tuple[tuple[str, float], ...]  # (distractor text, weight = times it is an answer)
    answer_weight: float


_PLURAL_NOUNS = frozenset({"scissors", "pliers", "tongs", "binoculars", "tweezers"})


def _a(noun: str) -> str:
    """"a hammer", "an axe", "scissors"."""
    if noun in _PLURAL_NOUNS:
        return noun
    return ("an " if noun[0] in "aeiou" else "a ") + noun


def _cap(text: str) -> str:
    return text[0].upper() + text[1:]


def _conflict_map(groups: tuple[tuple[str, ...], ...]) -> dict[str, set[str]]:
    m: dict[str, set[str]] = {}
    for g in groups:
        for a in g:
            m.setdefault(a, set()).update(g)
    return m


@lru_cache(maxsize=None)
def _area_splits() -> dict[str, bool]:
    """Area -> in train. Areas differ a lot in size, so instead of a hash they are dealt out,
    largest first, to the split with fewer places so far: both splits get enough places."""
    places: dict[str, set[str]] = {}
    for _, place in kb.LOCATIONS:
        places.setdefault(kb.PLACE_AREAS[place], set()).add(place)
    count = {True: 0, False: 0}
    out: dict[str, bool] = {}
    for a in sorted(places, key=lambda a: (-len(places[a]), a)):
        side = count[True] <= count[False]
        out[a] = side
        count[side] += len(places[a])
    return out


def in_train(fact: str) -> bool:
    """Split of a fact key: areas as dealt by :func:`_area_splits`, other facts by stable hash."""
    if fact.startswith("area:"):
        return _area_splits()[fact[5:]]
    return stable_bucket("rsb-commonsense", fact) < TRAIN_PERCENT


def _fact_questions() -> list[tuple[Question, tuple[str, ...]]]:
    """(question, candidate distractor texts) for every fact and phrasing; ``fact`` is the split key."""
    out: list[tuple[Question, tuple[str, ...]]] = []
    tconf = _conflict_map(kb.TOOL_CONFLICTS)
    for tool, purpose in kb.TOOLS:
        bad = tconf.get(tool, set()) | {tool}
        others = [(t, p) for t, p in kb.TOOLS if t not in bad]
        purposes = tuple(f"to {p}" for _, p in others)
        tools = tuple(t for t, _ in others)
        key = f"tool:{tool}"
        be = "are" if tool in _PLURAL_NOUNS else "is"
        solution = f"{_cap(_a(tool))} {be} used to {purpose}."
        for text in (f"What {be} {_a(tool)} used for?", f"What do people usually use {_a(tool)} for?",
                     f"Why would someone pick up {_a(tool)}?"):
            out.append((Question(text, f"to {purpose}", "commonsense", "tool purpose", solution=solution, fact=key),
                        purposes))
        for text in (f"Which tool would you use to {purpose}?", f"What do you reach for if you want to {purpose}?",
                     f"Which of these is made to {purpose}?"):
            out.append((Question(text, tool, "commonsense", "tool", solution=solution, fact=key), tools))
    for item, place in kb.LOCATIONS:
        area = kb.PLACE_AREAS[place]
        places = tuple(sorted({p for _, p in kb.LOCATIONS if kb.PLACE_AREAS[p] != area}))
        items = tuple(i for i, p in kb.LOCATIONS if kb.PLACE_AREAS[p] != area)
        key = f"area:{area}"
        be = "are" if item.endswith("s") else "is"
        solution = f"{_cap(item)} {be} usually kept in {place}."
        for text in (f"Where {be} {item} usually kept?", f"In a typical home, where would you find {item}?",
                     f"Where should you put {item} away?"):
            out.append((Question(text, place, "commonsense", "place", solution=solution, fact=key), places))
        where = place if place.startswith("beside ") else f"in {place}"
        out.append((Question(f"Which of these is usually kept {where}?", item, "commonsense", "household item",
                             solution=solution, fact=key), items))
    aconf = _conflict_map(kb.APPLIANCE_CONFLICTS)
    for appliance, function in kb.APPLIANCES:
        bad = aconf.get(appliance, set()) | {appliance}
        others = [(a, f) for a, f in kb.APPLIANCES if a not in bad]
        functions = tuple(f for _, f in others)
        names = tuple(a for a, _ in others)
        key = f"appliance:{appliance}"
        solution = f"{_cap(_a(appliance))} {function}."
        for text in (f"What does {_a(appliance)} do?", f"What is the job of {_a(appliance)} in a home?",
                     f"Why do people have {_a(appliance)}?"):
            out.append((Question(text, function, "commonsense", "appliance function", solution=solution, fact=key),
                        functions))
        for text in (f"Which appliance {function}?", f"Which household device {function}?",
                     f"What do you call the appliance that {function}?"):
            out.append((Question(text, appliance, "commonsense", "appliance", solution=solution, fact=key), names))
    return out


@lru_cache(maxsize=None)
def commonsense_pool(split: str) -> tuple[CommonsenseItem, ...]:
    """Questions of ``split`` with their weighted distractor candidates.

    A question text is asked once (the reverse place question exists once per place, its answer
    the place's first item). Weights count answers within the split, so that a text's share
    among distractors matches its share among the split's answers.
    """
    questions: list[tuple[Question, tuple[str, ...]]] = []
    seen_text: set[str] = set()
    for q, cands in _fact_questions():
        if q.text not in seen_text and in_train(q.fact) == (split == "train"):
            seen_text.add(q.text)
            questions.append((q, cands))
    weight = Counter((q.group, q.answer) for q, _ in questions)
    chosen = []
    for q, cands in questions:
        akey = option_key(q.answer)
        kept = tuple((c, float(weight[(q.group, c)])) for c in dict.fromkeys(cands)
                     if weight[(q.group, c)] and option_key(c) != akey and not related_words(c, q.text))
        chosen.append(CommonsenseItem(q, kept, float(weight[(q.group, q.answer)])))
    return tuple(chosen)
