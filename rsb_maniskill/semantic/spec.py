"""EpisodeSpec: everything the simulator, expert, evaluator and exporters need to know
about the semantics of one episode, and nothing about physics."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from rsb_maniskill.objects.family import DEFAULT_TARGETS

_TUPLE_FIELDS = ("options", "letters", "block_of_option", "block_names", "candidates")


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode's question, options, option->candidate binding and instruction.

    The correct answer lives only here (``answer_slot`` / ``correct_letter``); it is evaluation
    metadata and never appears in ``instruction``. "Block" in field names means candidate (a
    block or an everyday object): candidate ``c`` is called ``block_names[c]`` and is the asset
    ``candidates[c]``; option ``i`` is bound to candidate ``block_of_option[i]``. ``targets`` names
    the candidates' family (``rsb_maniskill.objects.TARGETS``: "blocks", "objects").
    """

    suite_id: str
    suite: str
    n_choices: int
    split: str
    seed: int
    question_id: int
    question: str
    options: tuple[str, ...]
    letters: tuple[str, ...]
    answer_slot: int
    correct_letter: str
    block_of_option: tuple[int, ...]
    block_names: tuple[str, ...]
    candidates: tuple[str, ...]
    instruction: str
    template_id: int
    rationale: str
    targets: str = DEFAULT_TARGETS  # last, with a default: positional construction keeps working

    def __post_init__(self) -> None:
        n = self.n_choices
        if not (len(self.options) == len(self.letters) == len(self.block_of_option) == len(self.block_names)
                == len(self.candidates) == n):
            raise ValueError(f"EpisodeSpec: options, letters, block_of_option, block_names and candidates "
                             f"must all have {n} entries")
        if not 0 <= self.answer_slot < n:
            raise ValueError(f"EpisodeSpec: answer_slot {self.answer_slot} out of range 0..{n - 1}")
        if self.letters[self.answer_slot] != self.correct_letter:
            raise ValueError("EpisodeSpec: correct_letter does not match letters[answer_slot]")
        if sorted(self.block_of_option) != list(range(n)):
            raise ValueError("EpisodeSpec: block_of_option must be a permutation of the block indices")

    @property
    def target_block(self) -> int:
        """Candidate index the expert must place in the answer zone."""
        return self.block_of_option[self.answer_slot]

    @property
    def correct_option(self) -> str:
        """Text of the correct option."""
        return self.options[self.answer_slot]

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable dict (tuples become lists) for trajectory files and eval logs."""
        d = dataclasses.asdict(self)
        for k in _TUPLE_FIELDS:
            d[k] = list(d[k])
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "EpisodeSpec":
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ValueError. Dicts written before
        ``candidates`` (blocks) or ``targets`` (the family owning the candidates' keys) still load."""
        names = [f.name for f in dataclasses.fields(cls)]
        if "candidates" not in d and "block_names" in d:  # written before everyday objects: blocks
            d = {**d, "candidates": [_legacy_block_key(b) for b in d["block_names"]]}
        if "targets" not in d and "candidates" in d:  # written before ``targets``
            from rsb_maniskill.objects.family import family_of_keys

            d = {**d, "targets": family_of_keys(d["candidates"])}
        missing = [k for k in names if k not in d]
        extra = [k for k in d if k not in names]
        if missing or extra:
            raise ValueError(f"EpisodeSpec.from_dict: missing keys {missing}, unknown keys {extra}")
        kw = {k: d[k] for k in names}
        for k in _TUPLE_FIELDS:
            kw[k] = tuple(kw[k])
        for k in ("n_choices", "seed", "question_id", "answer_slot", "template_id"):
            kw[k] = int(kw[k])
        kw["block_of_option"] = tuple(int(b) for b in kw["block_of_option"])
        return cls(**kw)


def _legacy_block_key(name: str) -> str:
    """"red block" -> "block:red", "block F" -> "block:F" (records that predate ``candidates``)."""
    return "block:" + (name[:-len(" block")] if name.endswith(" block") else name.split()[-1])
