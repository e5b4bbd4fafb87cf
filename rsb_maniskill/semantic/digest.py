"""An episode's canonical form and digest: what a policy or a grader meets of it, as one JSON line.

One owner for the pinned digests of ``rsb verify`` (``audit/golden.py`` hashes these lines, with the
layout, per suite) and for the ``episode_digest`` every record carries (``evaluation/records.py``):
a result can then prove which question, options and option -> candidate binding its episode had,
without the simulator (``evaluation/provenance.py`` recomputes and compares).
"""
from __future__ import annotations

import hashlib
import json
from typing import Any

DIGEST_CHARS = 16  # hex characters of a record's episode digest (64 bits: no accidental collision)


def semantics(spec: Any) -> dict[str, Any]:
    """The ``EpisodeSpec`` fields a policy or a grader meets."""
    return {
        "seed": spec.seed, "question_id": spec.question_id, "question": spec.question,
        "options": list(spec.options), "letters": list(spec.letters), "block_of_option": list(spec.block_of_option),
        "answer_slot": spec.answer_slot, "correct_letter": spec.correct_letter, "template_id": spec.template_id,
        "instruction": spec.instruction, "candidates": list(spec.candidates),
    }


def canonical_line(obj: Any) -> bytes:
    """``obj`` as the one canonical JSON line the digests hash (sorted keys, no spaces, UTF-8)."""
    return json.dumps(obj, sort_keys=True, ensure_ascii=False, separators=(",", ":")).encode() + b"\n"


def episode_digest(spec: Any) -> str:
    """The short sha256 of an episode's :func:`semantics`: equal digests, the same episode."""
    return hashlib.sha256(canonical_line(semantics(spec))).hexdigest()[:DIGEST_CHARS]
