"""Reader rows (references beside the guessers) and lift over chance.

Lift = (accuracy - 1/N) / (1 - 1/N): 0 at chance, 1 when always right, so a 4- and a 10-choice
suite compare on one scale (the twin rule, twins.py, compares lifts).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from rsb_maniskill.audit.guessers import credit
from rsb_maniskill.audit.readers import BoundReader
from rsb_maniskill.evaluation.metrics import wilson_interval
from rsb_maniskill.evaluation.stats import design_effect
from rsb_maniskill.semantic.spec import EpisodeSpec


def rate(credits: np.ndarray, clusters: np.ndarray | None = None) -> tuple[float, float, float]:
    """Mean credit and its Wilson 95 % interval (credit is a 0/1 outcome or a tie share, whose
    variance is at most the binomial one, so the interval is conservative).

    ``clusters``: one id per episode where episodes come in dependent groups (the episodes that
    ask one question: a guesser reads it alike each time). The interval then counts ``n / deff``
    episodes, deff the groups' design effect (``evaluation/stats.py``): Kish's effective sample size."""
    n = len(credits)
    s = float(credits.sum())
    if clusters is None:
        lo, hi = wilson_interval(int(round(s)), n)
        return s / n, lo, hi
    n_eff = n / design_effect(credits, clusters)
    lo, hi = wilson_interval(s / n * n_eff, n_eff)
    return s / n, lo, hi


def lift(accuracy: float, n_choices: int) -> float:
    """(accuracy - 1/N) / (1 - 1/N); monotone, so it maps an accuracy interval to a lift interval."""
    c = 1.0 / n_choices
    return (accuracy - c) / (1.0 - c)


@dataclass
class ReaderResult:
    name: str
    description: str
    accuracy: float | None = None
    low: float | None = None
    high: float | None = None
    lift: float | None = None
    lift_low: float | None = None
    lift_high: float | None = None
    applies: int = 0  # episodes where the reader told options apart (others: uniform guess)
    unavailable: str = ""  # why the reader could not run (a missing optional package), else ""


def read(reader: BoundReader, specs: Sequence[EpisodeSpec], clusters: np.ndarray) -> ReaderResult:
    """Score one reader on ``specs`` (all with the same N); ``clusters`` as :func:`rate` takes them."""
    n = specs[0].n_choices
    try:
        scores = list(reader.batch([sp.question for sp in specs], [sp.options for sp in specs]))
    except ImportError as err:
        return ReaderResult(reader.name, reader.description, unavailable=str(err).splitlines()[0] or repr(err))
    if len(scores) != len(specs):
        raise ValueError(f"reader {reader.name}: {len(scores)} score lists for {len(specs)} episodes")
    cr, ap = np.full(len(specs), 1.0 / n), np.zeros(len(specs), dtype=bool)
    for i, (sp, s) in enumerate(zip(specs, scores)):
        if s is None:
            continue
        s = [float(x) for x in s]
        if len(s) != n:
            raise ValueError(f"reader {reader.name}: {len(s)} scores for {n} options")
        if len(set(s)) > 1:
            cr[i], ap[i] = credit(s, sp.answer_slot), True
    acc, lo, hi = rate(cr, clusters)
    return ReaderResult(reader.name, reader.description, acc, lo, hi, lift(acc, n), lift(lo, n), lift(hi, n),
                        int(ap.sum()))
