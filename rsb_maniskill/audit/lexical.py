"""The lexical answer-blind probe: a linear model over the words of each option.

The surface probe (probe.py) reads the *shape* of an option relative to its set (length,
similarity, digits); it does not read which words an option holds. Distractors written for a
question can carry words that mark them ("times 10", a round number inside a sentence, "because
the ..."), and then a bag of n-grams finds the answer without the question. This probe fits a
logistic regression on each option's word 1-2 grams and character 2-5 grams, and on the word
n-grams it shares with the rest of its set, on train-split episodes, and scores test-split
episodes. For a suite it flags, the n-grams with the largest weights show what gives the answer
away.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from rsb_maniskill.audit.guessers import credit
from rsb_maniskill.semantic.spec import EpisodeSpec

WORD_NGRAMS = (1, 2)
CHAR_NGRAMS = (2, 5)
MIN_DF = 2  # an n-gram seen in one training option only is a name, not a habit of the writers
TOP_TOKENS = 8  # n-grams listed for each side (answer-marking, distractor-marking)


@dataclass
class LexicalResult:
    credits: np.ndarray  # per audited episode, expected accuracy of the probe's pick
    train_episodes: int
    answer_tokens: list[tuple[str, float, int]]  # (n-gram, weight, options of the audited episodes holding it)
    distractor_tokens: list[tuple[str, float, int]]


class LexicalFeatures:
    """Word and character n-grams of each option, and the word n-grams it shares with its set."""

    def __init__(self) -> None:
        from sklearn.feature_extraction.text import CountVectorizer, TfidfVectorizer

        self.words = TfidfVectorizer(ngram_range=WORD_NGRAMS, min_df=MIN_DF, sublinear_tf=True)
        self.chars = TfidfVectorizer(analyzer="char_wb", ngram_range=CHAR_NGRAMS, min_df=MIN_DF, sublinear_tf=True)
        self.shared = CountVectorizer(ngram_range=WORD_NGRAMS, min_df=MIN_DF, binary=True)

    def fit(self, specs: Sequence[EpisodeSpec]) -> "LexicalFeatures":
        texts = _options(specs)
        for v in (self.words, self.chars, self.shared):
            v.fit(texts)
        return self

    def transform(self, specs: Sequence[EpisodeSpec]):
        from scipy.sparse import hstack
        from sklearn.preprocessing import normalize

        texts = _options(specs)
        return hstack([self.words.transform(texts), self.chars.transform(texts),
                       normalize(self._shared(specs, self.shared.transform(texts)))]).tocsr()

    @staticmethod
    def _shared(specs: Sequence[EpisodeSpec], counts):
        """Each option's n-grams that another option of its episode also holds."""
        from scipy.sparse import csr_matrix, vstack

        rows, start = [], 0
        for sp in specs:
            block = counts[start:start + sp.n_choices]
            total = np.asarray(block.sum(axis=0)).ravel()
            rows.append(block.multiply(csr_matrix((total >= 2).astype(float))))
            start += sp.n_choices
        return vstack(rows).tocsr()

    def names(self) -> list[str]:
        return ([f"word '{t}'" for t in self.words.get_feature_names_out()]
                + [f"chars '{t}'" for t in self.chars.get_feature_names_out()]
                + [f"shared '{t}'" for t in self.shared.get_feature_names_out()])


def _options(specs: Sequence[EpisodeSpec]) -> list[str]:
    return [o for sp in specs for o in sp.options]


def _labels(specs: Sequence[EpisodeSpec]) -> np.ndarray:
    return np.concatenate([np.arange(sp.n_choices) == sp.answer_slot for sp in specs]).astype(int)


def _fit_score(train: Sequence[EpisodeSpec], test: Sequence[EpisodeSpec], seed: int):
    from sklearn.linear_model import LogisticRegression

    feats = LexicalFeatures().fit(train)
    clf = LogisticRegression(C=1.0, max_iter=3000, random_state=seed)
    clf.fit(feats.transform(train), _labels(train))
    X = feats.transform(test)
    p = clf.predict_proba(X)[:, 1]
    bounds = np.cumsum([0] + [sp.n_choices for sp in test])
    credits = np.array([credit(np.round(p[a:b], 9), sp.answer_slot) for sp, a, b in zip(test, bounds, bounds[1:])])
    return credits, clf.coef_[0], feats.names(), X


def lexical_probe(train: Sequence[EpisodeSpec], test: Sequence[EpisodeSpec], seed: int = 0) -> LexicalResult:
    """Fit on ``train`` (episodes of the train split), score ``test`` (of the audited split).

    Not for auditing the train split itself: there an option's words are memorised answers, and
    fit on half of a split's questions the probe reads the other half's answers (the distractors
    of the first half) as distractors, below chance, which measures nothing.
    """
    credits, coef, names, X = _fit_score(train, test, seed)
    used = np.asarray((X > 0).sum(axis=0)).ravel()  # options of the audited episodes holding each n-gram
    return LexicalResult(credits, len(train), *_top_tokens(coef, names, used))


def _top_tokens(coef: np.ndarray, names: list[str], used: np.ndarray,
                top: int = TOP_TOKENS) -> tuple[list[tuple[str, float, int]], list[tuple[str, float, int]]]:
    """The n-grams that move the probe most on the audited episodes: weight times how many of their
    options hold it, largest towards "answer" and towards "distractor"."""
    pull = coef * np.log1p(used)
    order = np.argsort(pull)
    pos = [(names[i], float(coef[i]), int(used[i])) for i in order[::-1][:top] if pull[i] > 0]
    neg = [(names[i], float(coef[i]), int(used[i])) for i in order[:top] if pull[i] < 0]
    return pos, neg
