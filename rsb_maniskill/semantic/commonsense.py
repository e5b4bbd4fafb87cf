"""Commonsense questions generated from the knowledge table (knowledge.py).

Each fact yields questions in both directions (tool -> purpose, purpose -> tool, ...) and in
several phrasings. Facts, not questions, are split between the pools (80 % train by stable
hash), so the evaluation pool asks about things never asked about in training. Distractors for
a question are the other answers of its category, minus rows that could also be right
(conflict groups / place areas).
"""
from __future__ import annotations

from functools import lru_cache

from . import knowledge as kb
from .records import Question
from .stable import stable_bucket

TRAIN_PERCENT = 80


def _conflict_map(groups: tuple[tuple[str, ...], ...]) -> dict[str, set[str]]:
    m: dict[str, set[str]] = {}
    for g in groups:
        for a in g:
            m.setdefault(a, set()).update(g)
    return m


def _fact_questions() -> list[tuple[str, Question, tuple[str, ...]]]:
    """(fact key, question, candidate distractor texts) for every fact and phrasing."""
    out: list[tuple[str, Question, tuple[str, ...]]] = []
    tconf = _conflict_map(kb.TOOL_CONFLICTS)
    for tool, purpose in kb.TOOLS:
        bad = tconf.get(tool, set()) | {tool}
        others = [(t, p) for t, p in kb.TOOLS if t not in bad]
        purposes = tuple(f"to {p}" for _, p in others)
        tools = tuple(t for t, _ in others)
        key = f"tool:{tool}"
        for text in (f"What is a {tool} used for?", f"What do people usually use a {tool} for?",
                     f"Why would someone pick up a {tool}?"):
            out.append((key, Question(text, f"to {purpose}", "commonsense", "tool purpose",
                                      solution=f"A {tool} is used to {purpose}."), purposes))
        for text in (f"Which tool would you use to {purpose}?", f"What do you need if you want to {purpose}?",
                     f"Which of these is made to {purpose}?"):
            out.append((key, Question(text, tool, "commonsense", "tool",
                                      solution=f"A {tool} is used to {purpose}."), tools))
    for item, place in kb.LOCATIONS:
        area = kb.PLACE_AREAS[place]
        places = tuple(sorted({p for _, p in kb.LOCATIONS if kb.PLACE_AREAS[p] != area}))
        items = tuple(i for i, p in kb.LOCATIONS if kb.PLACE_AREAS[p] != area)
        key = f"location:{item}"
        for text in (f"Where are {item} usually kept?", f"In a typical home, where would you find {item}?",
                     f"Where should you put {item} away?"):
            out.append((key, Question(text, place, "commonsense", "place",
                                      solution=f"{item.capitalize()} are usually kept in {place}."), places))
        for text in (f"Which of these is usually kept in {place}?",):
            out.append((f"place:{place}", Question(text, item, "commonsense", "household item",
                                                   solution=f"{item.capitalize()} are usually kept in {place}."), items))
    aconf = _conflict_map(kb.APPLIANCE_CONFLICTS)
    for appliance, function in kb.APPLIANCES:
        bad = aconf.get(appliance, set()) | {appliance}
        others = [(a, f) for a, f in kb.APPLIANCES if a not in bad]
        functions = tuple(f for _, f in others)
        names = tuple(a for a, _ in others)
        key = f"appliance:{appliance}"
        for text in (f"What does a {appliance} do?", f"What is the job of a {appliance} in a home?",
                     f"Why do people have a {appliance}?"):
            out.append((key, Question(text, function, "commonsense", "appliance function",
                                      solution=f"A {appliance} {function}."), functions))
        for text in (f"Which appliance {function}?", f"Which household machine {function}?",
                     f"What do you call the appliance that {function}?"):
            out.append((key, Question(text, appliance, "commonsense", "appliance",
                                      solution=f"A {appliance} {function}."), names))
    return out


@lru_cache(maxsize=None)
def commonsense_pool(split: str) -> tuple[tuple[Question, tuple[str, ...]], ...]:
    """(question, distractor candidates) of ``split``; facts split 80/20 by stable hash.

    A reverse location question ("which of these is kept in the freezer?") is keyed by its place,
    so that its text, shared by every item of that place, lands in one split only.
    """
    chosen = []
    seen_text: set[str] = set()
    for key, q, cands in _fact_questions():
        in_train = stable_bucket("rsb-commonsense", key) < TRAIN_PERCENT
        if in_train != (split == "train") or q.text in seen_text:
            continue
        seen_text.add(q.text)
        chosen.append((q, tuple(c for c in dict.fromkeys(cands) if c.casefold() != q.answer.casefold())))
    return tuple(chosen)
