"""The learned answer-blind probe: gradient-boosted trees that pick the answer from the options.

Each option becomes a row of features *relative to its set* (rank, distance to the centre, digits
shared with the others, length rank, similarity to the others, ...), plus how often that exact
option text was the answer in training (a memorised prior). A classifier is fit on episodes of
the train split and scored on the test split: it never sees the question. If it beats chance, the
options carry the answer.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from rsb_maniskill.audit.guessers import credit, made_of_others
from rsb_maniskill.audit.text import digit_string, edit_distance, trailing_zeros
from rsb_maniskill.objects.catalog import CATEGORY_KEYS
from rsb_maniskill.semantic.normalize import jaccard, leading_numbers, option_key, trigrams
from rsb_maniskill.semantic.spec import EpisodeSpec

NUMERIC_FEATURES = (
    "value", "log_value", "rank", "z", "abs_z", "median_dev", "abs_median_dev", "edit_mean", "edit_rank",
    "last_digit", "parity", "mod3", "mod5", "digit_sum_mod9", "trailing_zeros", "tz_minus_max", "n_digits",
    "share_last_digit", "share_parity", "share_tz", "cluster", "nearest_gap", "from_min", "made_of_others",
    "set_spread",
)
TEXT_FEATURES = (
    "chars", "words", "rel_chars", "len_rank", "sim_mean", "sim_max", "sim_rank", "capital", "has_digit",
    "punct", "full_stop", "commas", "slot", "block", "category", "answer_rate", "seen_count",
)
FEATURES = NUMERIC_FEATURES + TEXT_FEATURES


def _rank(x: np.ndarray) -> np.ndarray:
    """Average rank in [0, 1] (ties share their mean rank)."""
    n = len(x)
    if n < 2:
        return np.zeros(n)
    order = np.argsort(x, kind="stable")
    r = np.empty(n)
    r[order] = np.arange(n)
    for val in np.unique(x):
        m = x == val
        r[m] = r[m].mean()
    return r / (n - 1)


def _numeric_block(v: np.ndarray) -> np.ndarray:
    n = len(v)
    v = np.clip(v, -1e15, 1e15)
    sd = v.std() or 1.0
    med = np.median(v)
    ds = [digit_string(x) for x in v]
    edit = np.array([sum(edit_distance(a, b) for b in ds) / (n - 1) for a in ds])
    iv = np.where(v == np.round(v), np.abs(np.round(v)), np.nan)
    last = np.array([float(s[-1]) for s in ds])
    tz = np.array([trailing_zeros(x) for x in v], dtype=float)
    par = np.where(np.isnan(iv), np.nan, iv % 2)
    gaps = np.abs(v[:, None] - v[None, :]) + np.diag(np.full(n, np.inf))
    cols = [
        v, np.sign(v) * np.log10(1 + np.abs(v)), _rank(v), (v - v.mean()) / sd, np.abs(v - v.mean()) / sd,
        (v - med) / sd, np.abs(v - med) / sd, edit, _rank(edit), last, par, iv % 3, iv % 5,
        np.array([sum(int(c) for c in s if c.isdigit()) % 9 for s in ds], dtype=float), tz, tz - tz.max(),
        np.array([len(s) for s in ds], dtype=float),
        np.array([np.sum(last == x) - 1 for x in last], dtype=float),
        np.array([np.sum(par == x) - 1 for x in par], dtype=float),
        np.array([np.sum(tz == x) - 1 for x in tz], dtype=float),
        np.array([np.sum(np.abs(v - x) <= 0.1 * max(abs(x), 1e-9)) for x in v], dtype=float),
        gaps.min(axis=1) / sd, (v - v.min()) / ((v.max() - v.min()) or 1.0), np.array(made_of_others(v)),
        np.full(n, sd / (abs(v.mean()) or 1.0)),
    ]
    return np.stack(cols, axis=1)


@dataclass
class AnswerPrior:
    """How often each option text (normal form) was the answer, from a set of training episodes."""

    answer: Counter
    seen: Counter

    @classmethod
    def fit(cls, specs: Sequence[EpisodeSpec]) -> "AnswerPrior":
        ans, seen = Counter(), Counter()
        for sp in specs:
            keys = [option_key(o) for o in sp.options]
            seen.update(keys)
            ans[keys[sp.answer_slot]] += 1
        return cls(ans, seen)

    def rate(self, key: str, n_choices: int) -> tuple[float, float]:
        """Smoothed answer rate (chance 1/N with no data) and the number of sightings."""
        m = float(n_choices)
        s = self.seen.get(key, 0)
        return (self.answer.get(key, 0) + 1.0) / (s + m), float(s)


def _category_index(candidate: str) -> float:
    """Everyday-object category of a candidate as a number (NaN for blocks: "block" feature)."""
    cat = candidate.split(":", 1)[0]
    return float(CATEGORY_KEYS.index(cat)) if cat in CATEGORY_KEYS else np.nan


def option_features(sp: EpisodeSpec, prior: AnswerPrior | None = None) -> np.ndarray:
    """(N, len(FEATURES)) features of an episode's options; NaN where a feature does not apply."""
    opts = sp.options
    n = len(opts)
    vals = leading_numbers(opts)  # plain numbers, or the number each option starts with
    num = (_numeric_block(np.asarray(vals, dtype=float)) if vals is not None
           else np.full((n, len(NUMERIC_FEATURES)), np.nan))
    chars = np.array([len(o) for o in opts], dtype=float)
    g = [trigrams(o) for o in opts]
    sim = np.array([[jaccard(a, b) for b in g] for a in g])
    np.fill_diagonal(sim, np.nan)
    sim_mean = np.nanmean(sim, axis=1)
    keys = [option_key(o) for o in opts]
    prior_cols = np.array([prior.rate(k, n) if prior else (np.nan, np.nan) for k in keys], dtype=float)
    text = np.stack([
        chars, np.array([len(o.split()) for o in opts], dtype=float), chars / chars.mean(), _rank(chars),
        sim_mean, np.nanmax(sim, axis=1), _rank(sim_mean),
        np.array([o[:1].isupper() for o in opts], dtype=float),
        np.array([any(c.isdigit() for c in o) for o in opts], dtype=float),
        np.array([sum(not c.isalnum() and not c.isspace() for c in o) for o in opts], dtype=float),
        np.array([o.endswith(".") for o in opts], dtype=float),
        np.array([o.count(",") for o in opts], dtype=float),
        np.arange(n, dtype=float) / (n - 1), np.asarray(sp.block_of_option, dtype=float),
        np.array([_category_index(sp.candidates[b]) for b in sp.block_of_option], dtype=float),
        prior_cols[:, 0], prior_cols[:, 1],
    ], axis=1)
    out = np.concatenate([num, text], axis=1)
    out[~np.isfinite(out)] = np.nan  # huge values ("1e400") and 0/0 are missing, not features
    return out


@dataclass
class ProbeResult:
    credits: np.ndarray  # per test episode, expected accuracy of the probe's pick
    train_episodes: int
    top_features: list[tuple[str, float]]


def learned_probe(train: Sequence[EpisodeSpec], test: Sequence[EpisodeSpec], seed: int = 0,
                  use_prior: bool = True) -> ProbeResult:
    """Fit on ``train`` (the answer-rate prior on one half, the trees on the other), score ``test``.

    ``use_prior=False`` drops the memorised answer rates: needed when ``test`` asks the same
    questions as ``train`` (auditing the train split), where remembering answers is no shortcut.
    """
    from sklearn.ensemble import HistGradientBoostingClassifier  # heavy: loaded on use

    half = len(train) // 2 if use_prior else 0
    prior = AnswerPrior.fit(train[:half]) if use_prior else None
    fit_specs = train[half:]
    X = np.concatenate([option_features(sp, prior) for sp in fit_specs])
    y = np.concatenate([np.arange(sp.n_choices) == sp.answer_slot for sp in fit_specs]).astype(int)
    used = np.isfinite(X).any(axis=0)  # features that never apply (value features on text) are dropped
    X = X[:, used]
    clf = HistGradientBoostingClassifier(max_iter=300, learning_rate=0.05, max_leaf_nodes=31, min_samples_leaf=20,
                                         l2_regularization=1.0, early_stopping=True, validation_fraction=0.2,
                                         n_iter_no_change=20, random_state=seed)
    clf.fit(X, y)
    p = clf.predict_proba(np.concatenate([option_features(sp, prior) for sp in test])[:, used])[:, 1]
    bounds = np.cumsum([0] + [sp.n_choices for sp in test])
    credits = np.array([credit(np.round(p[a:b], 9), sp.answer_slot) for sp, a, b in zip(test, bounds, bounds[1:])])
    names = [f for f, u in zip(FEATURES, used) if u]
    return ProbeResult(credits, len(fit_specs), _importance(clf, X, y, names, seed))


def _importance(clf, X: np.ndarray, y: np.ndarray, names: list[str], seed: int,
                top: int = 5) -> list[tuple[str, float]]:
    """The features the probe leans on most (permutation importance on a sample of its rows)."""
    from sklearn.inspection import permutation_importance

    rng = np.random.default_rng(seed)
    idx = rng.choice(len(X), size=min(len(X), 4000), replace=False)
    imp = permutation_importance(clf, X[idx], y[idx], scoring="neg_log_loss", n_repeats=2, random_state=seed)
    order = np.argsort(-imp.importances_mean)[:top]
    return [(names[i], float(imp.importances_mean[i])) for i in order]
