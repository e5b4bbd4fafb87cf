"""RSB-HardMath: GSM8K word problems (train pool = GSM8K train, evaluation pool = GSM8K test)."""
from __future__ import annotations

import os
import re

from rsb_maniskill.semantic.data import gsm8k_rows
from rsb_maniskill.semantic.errors import SemanticDataError
from rsb_maniskill.semantic.normalize import question_key
from rsb_maniskill.semantic.pools import Pool
from rsb_maniskill.semantic.records import Question, format_number, normalize_text

_ANNOTATION = re.compile(r"<<[^>]*>>")
_FINAL = re.compile(r"^(-?)(\d{1,3}(?:,\d{3})+|\d+)(?:\.(\d+))?$")


def parse_final_answer(answer_field: str) -> tuple[int, int]:
    """Value after the last ``####`` as (units, decimals): thousands separators stripped,
    negatives kept. ValueError when absent or not a number (the caller adds file and line)."""
    if "####" not in answer_field:
        raise ValueError("no '####' final-answer marker in 'answer'")
    raw = answer_field.rsplit("####", 1)[1].strip()
    m = _FINAL.match(raw.replace("$", "").strip())
    if not m:
        raise ValueError(f"cannot parse final answer {raw!r} as a number")
    sign, whole, frac = m.group(1), m.group(2).replace(",", ""), m.group(3) or ""
    frac = frac.rstrip("0")
    units = int(whole + frac) if frac else int(whole)
    return (-units if sign else units), len(frac)


def clean_solution(answer_field: str) -> str:
    """GSM8K's worked solution as one line, without calculator annotations or the #### line."""
    body = _ANNOTATION.sub("", answer_field.rsplit("####", 1)[0])
    lines = [normalize_text(line) for line in body.splitlines() if line.strip()]
    return " ".join(line if line[-1] in ".!?" else line + "." for line in lines)


def reasoning_steps(answer_field: str) -> int:
    """Steps of GSM8K's worked solution: its ``<<...>>`` calculator annotations, one per computation
    (counted before :func:`clean_solution` strips them). A few solutions carry none (0)."""
    return len(_ANNOTATION.findall(answer_field.rsplit("####", 1)[0]))


def question_from_row(row: dict) -> Question:
    """Build a HardMath question; unparseable records raise SemanticDataError (never skipped)."""
    origin = row.get("origin", "")
    path, _, line = origin.rpartition(", line ")
    lineno = int(line) if line.isdigit() else None
    if lineno is None:
        path = origin
    try:
        units, decimals = parse_final_answer(row["answer"])
    except ValueError as err:
        raise SemanticDataError(path, lineno, str(err)) from None
    text = normalize_text(row["question"])
    return Question(
        text=text,
        answer=format_number(units, decimals),
        source="gsm8k",
        value=units,
        decimals=decimals,
        solution=clean_solution(row["answer"]),
        origin=origin,
        fact=question_key(text),
        steps=reasoning_steps(row["answer"]),
    )


def gsm8k_pool(split: str, data_dir: str | os.PathLike | None = None) -> tuple[Question, ...]:
    """All GSM8K questions of ``split`` in file order (question_id = row index)."""
    return tuple(question_from_row(r) for r in gsm8k_rows(split, data_dir))


def pool(split: str, data_dir: str | os.PathLike | None = None) -> Pool:
    """The HardMath pool of ``split``: GSM8K's split of the same name."""
    qs = gsm8k_pool(split, data_dir)
    return Pool("HardMath", split, qs, (None,) * len(qs), {"gsm8k": len(qs)})
