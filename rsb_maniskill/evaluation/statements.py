"""What a talking policy said in an episode, and whether its arm followed (the paper's Table 5).

A policy may return text with its chunks (``policy.py``). :class:`EpisodeText` gathers an
episode's texts and turns them into record fields: ``text`` (the texts in order, a repeat of the
previous one dropped, joined by newlines, cut to :data:`MAX_TEXT_CHARS`), ``text_chars`` (its
length before the cut) and ``stated_letter`` (the option it states, parsed from the whole text by
``semantic.answers``; None when it names none or several). Records of a policy that never
returned text have none of these fields.

:func:`reasoning_following` counts, over one suite's records, the paper's Table 5: the
grasped-but-failed episodes split into *stated wrong, wrong target*, *stated right, wrong target*
(the reasoning-following failure), *no statement, wrong target* and *grasped right, not placed*;
and over all grasped episodes the statement (right, wrong, none) against the grasp (the correct
block, or only wrong ones). Every share comes with its Wilson 95 % interval.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Mapping

from rsb_maniskill.evaluation.metrics import Rate, outcome
from rsb_maniskill.semantic.answers import read_statement

# A chain of thought of the paper's kind is 200-300 characters; 2,000 keep a long one whole while a
# policy that returns text with every chunk cannot grow a run's files without bound: episodes.jsonl
# and report.html (which shows every episode's text) hold at most 2 kB of it per episode.
MAX_TEXT_CHARS = 2000
TEXT_FIELDS = ("text", "text_chars", "stated_letter")
STATEMENTS = ("right", "wrong", "none")  # what an episode's text states, against the correct option
# The grasped-but-failed episodes, split as the paper's Table 5, in its row order.
FAILURES = ("not_placed", "stated_wrong", "stated_right", "no_statement")
FAILURE_LABELS = {
    "not_placed": "Grasped right, not placed",
    "stated_wrong": "Stated wrong, wrong target",
    "stated_right": "Stated right, wrong target",
    "no_statement": "No statement, wrong target",
}


class EpisodeText:
    """The texts a policy returned in one episode, in order."""

    def __init__(self) -> None:
        self.texts: list[str] = []
        self.talked = False  # returned a mapping with text at least once (maybe empty)

    def add(self, text: str | None) -> None:
        if text is None:
            return
        self.talked = True
        text = text.strip()
        if text and (not self.texts or self.texts[-1] != text):
            self.texts.append(text)

    def fields(self, spec: Any) -> dict[str, Any]:
        """The record fields (none when the policy never talked)."""
        if not self.talked:
            return {}
        full = "\n".join(self.texts)
        return {"text": full[:MAX_TEXT_CHARS], "text_chars": len(full),
                "stated_letter": read_statement(full, spec).letter}


def talks(records: Iterable[Mapping[str, Any]]) -> bool:
    """Whether any record carries a policy's text."""
    return any("stated_letter" in r for r in records)


def statement(record: Mapping[str, Any]) -> str:
    """``right`` / ``wrong``: the option the episode's text states against the correct one;
    ``none`` when it states none (or the policy said nothing in this episode)."""
    letter = record.get("stated_letter")
    if letter is None:
        return "none"
    return "right" if letter == record.get("correct_letter") else "wrong"


def failure_kind(record: Mapping[str, Any]) -> str | None:
    """The Table 5 row of a grasped-but-failed episode; None for a success or no grasp."""
    kind = outcome(record)
    if kind == "not_placed":
        return "not_placed"
    if kind != "wrong_target":
        return None
    return {"right": "stated_right", "wrong": "stated_wrong", "none": "no_statement"}[statement(record)]


@dataclass(frozen=True)
class ReasoningFollowing:
    """Table 5 of one policy on one suite: counts, and shares with Wilson 95 % intervals."""

    suite_id: str
    n_episodes: int
    n_grasped: int
    n_grasped_failed: int
    failures: dict[str, int]  # FAILURES -> episodes (of the grasped-but-failed)
    # "<statement>/<grasp>" -> grasped episodes; statement in STATEMENTS, grasp "right" (the correct
    # block was grasped) or "wrong" (only wrong ones)
    crossing: dict[str, int]
    n_stated_right: int  # of all episodes

    def failure_rates(self) -> dict[str, Rate]:
        return {k: Rate.of(v, self.n_grasped_failed) for k, v in self.failures.items()}

    def crossing_rates(self) -> dict[str, Rate]:
        return {k: Rate.of(v, self.n_grasped) for k, v in self.crossing.items()}

    def stated_right_rate(self) -> Rate:
        return Rate.of(self.n_stated_right, self.n_episodes)

    def to_dict(self) -> dict[str, Any]:
        return {"suite_id": self.suite_id, "n_episodes": self.n_episodes, "n_grasped": self.n_grasped,
                "n_grasped_failed": self.n_grasped_failed, "failures": dict(self.failures),
                "failure_rates": {k: vars(r) for k, r in self.failure_rates().items()},
                "crossing": dict(self.crossing),
                "crossing_rates": {k: vars(r) for k, r in self.crossing_rates().items()},
                "stated_right": vars(self.stated_right_rate())}


def reasoning_following(records: Iterable[Mapping[str, Any]], suite_id: str) -> ReasoningFollowing:
    """Table 5 of the records of one suite (of one policy row)."""
    failures = dict.fromkeys(FAILURES, 0)
    crossing = {f"{s}/{g}": 0 for s in STATEMENTS for g in ("right", "wrong")}
    n = grasped = stated_right = 0
    for r in records:
        if r.get("suite_id", suite_id) != suite_id:
            raise ValueError(f"record of suite {r.get('suite_id')!r} passed to reasoning_following({suite_id!r})")
        n += 1
        said, kind = statement(r), outcome(r)
        stated_right += said == "right"
        if kind == "no_grasp":
            continue
        grasped += 1
        crossing[f"{said}/{'wrong' if kind == 'wrong_target' else 'right'}"] += 1
        failed = failure_kind(r)
        if failed is not None:
            failures[failed] += 1
    return ReasoningFollowing(suite_id, n, grasped, sum(failures.values()), failures, crossing, stated_right)
