"""RSB-General's pools: the commonsense knowledge table (``commonsense.py``) and MMLU-Pro
(``mmlu_pro.py``), one pool per split shared by General-4 and General-10."""
from __future__ import annotations

import os
from collections import Counter

from rsb_maniskill.semantic import commonsense, mmlu_pro
from rsb_maniskill.semantic.data import mmlu_pro_rows
from rsb_maniskill.semantic.pools import Pool, data_key
from rsb_maniskill.semantic.records import Question

_MMLU_PRO: dict[str, tuple[dict[str, list[Question]], Counter]] = {}


def _mmlu_pro_split(data_dir: str | os.PathLike | None) -> tuple[dict[str, list[Question]], Counter]:
    key = data_key(data_dir)
    if key not in _MMLU_PRO:
        _MMLU_PRO[key] = mmlu_pro.split_questions(mmlu_pro_rows(data_dir))
    return _MMLU_PRO[key]


def pool(split: str, data_dir: str | os.PathLike | None) -> Pool:
    """The General pool of ``split``: the table's questions first, then MMLU-Pro's."""
    cs = commonsense.commonsense_pool(split)
    by_split, excluded = _mmlu_pro_split(data_dir)
    mq, dropped = mmlu_pro.balanced_selection(by_split[split])
    excluded = excluded + Counter({"answer rank balance (this split)": dropped}) if dropped else excluded
    questions = tuple(item.question for item in cs) + tuple(mq)
    cands = tuple((item.candidates, item.answer_weight) for item in cs) + (None,) * len(mq)
    return Pool("General", split, questions, cands, {"commonsense": len(cs), "mmlu_pro": len(mq)}, excluded)


def clear_cache() -> None:
    _MMLU_PRO.clear()
    commonsense.commonsense_pool.cache_clear()
