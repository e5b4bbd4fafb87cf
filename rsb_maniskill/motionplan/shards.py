"""Which seeds or questions each shard and each of its workers owns: split by arithmetic, never by timing.

* seed mode (``num``): shard ``i/n`` owns the seeds ``s`` with ``(s - seed_start) % n == i``,
  and its worker ``k`` of ``K`` the seeds ``seed_start + i + n*k + n*K*j`` (j = 0, 1, ...);
  shard i makes ``num // n`` demos (+1 for the first ``num % n`` shards), split the same way
  over its workers. Shards never share a seed whatever their ``--num-procs``.
* question mode (``questions``): one demo per question q of the split's pool of size P,
  trying the seeds q, q+P, q+2P, ... (the env's question is ``seed % P``) until one succeeds;
  shard i owns the questions with ``q % n == i``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Generator

from rsb_maniskill.motionplan.config import GenerateConfig, GenerateError


@dataclass
class WorkPlan:
    """One worker's share: a seed progression with a quota, or a list of questions."""

    worker: int
    pool_size: int
    first_seed: int = 0
    stride: int = 1
    quota: int = 0
    questions: list[int] | None = None

    @property
    def wanted(self) -> int:
        """Demos this worker should keep."""
        return self.quota if self.questions is None else len(self.questions)


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/n"`` -> (i, n) with 0 <= i < n."""
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise GenerateError(f"bad --shard {text!r}: expected INDEX/COUNT, e.g. 0/4") from None
    if n < 1 or not 0 <= i < n:
        raise GenerateError(f"bad --shard {text!r}: need 0 <= INDEX < COUNT")
    return i, n


def split_count(total: int, parts: int) -> list[int]:
    """``total`` items over ``parts``: the first ``total % parts`` get one more."""
    return [total // parts + (k < total % parts) for k in range(parts)]


def question_list(questions: str, pool_size: int, num: int | None) -> list[int]:
    """``"all"`` or ``"START:STOP"`` -> question indices, cut to the first ``num``."""
    if questions == "all":
        qs = list(range(pool_size))
    else:
        try:
            start, stop = (int(x) for x in questions.split(":"))
        except ValueError:
            raise GenerateError(f"bad --questions {questions!r}: expected 'all' or START:STOP") from None
        if not 0 <= start < stop <= pool_size:
            raise GenerateError(f"bad --questions {questions!r}: the pool has questions 0..{pool_size - 1}")
        qs = list(range(start, stop))
    return qs if num is None else qs[:num]


def plan_work(cfg: GenerateConfig, pool_size: int) -> list[WorkPlan]:
    """Deterministic, disjoint shares of this shard for ``cfg.num_procs`` workers."""
    i, n = cfg.shard
    if cfg.questions is not None:
        mine = question_list(cfg.questions, pool_size, cfg.num)[i::n]
        k_procs = max(1, min(cfg.num_procs, len(mine)))
        return [WorkPlan(k, pool_size, questions=mine[k::k_procs]) for k in range(k_procs)
                if mine[k::k_procs]]
    quota = split_count(cfg.num, n)[i]
    k_procs = max(1, min(cfg.num_procs, quota))
    return [WorkPlan(k, pool_size, first_seed=cfg.seed_start + i + n * k, stride=n * k_procs, quota=q)
            for k, q in enumerate(split_count(quota, k_procs)) if q > 0]


def seed_schedule(plan: WorkPlan, max_attempts: int) -> Generator[tuple[int, int | None], bool | None, None]:
    """Yields (seed, question or None) to try next; ``send(True)`` after a kept episode."""
    if plan.questions is None:
        seed = plan.first_seed
        while True:
            yield seed, None
            seed += plan.stride
    for q in plan.questions:
        for attempt in range(max_attempts):
            kept = yield q + attempt * plan.pool_size, q
            if kept:
                break
