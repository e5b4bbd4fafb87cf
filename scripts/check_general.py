"""Held-out answer-blind checks of RSB-General: models the filter and the audit never used.

scripts/filter_general.py keeps out the questions that logistic regressions on TF-IDF word and
character n-grams and on sentence embeddings (and gradient-boosted trees on shape) find from the
options alone, and ``rsb audit``'s lexical probe is a model of the first family. A filter tuned against one model can
fit that model and nothing else, so this script trains other families on other tokenisations and
other seeds, and scores the protocol's evaluation episodes:

- ``naive bayes``: complement naive Bayes on whitespace tokens (case and punctuation kept) and
  their pairs;
- ``char svm``: a linear SVM (hinge loss, SGD) on hashed character 1-4 grams across word
  boundaries;
- ``encoder + MLP``: a small neural network on all-MiniLM-L6-v2 sentence embeddings of each option
  and their difference from the set's mean (the weights ship with the ``baselines`` extra); and,
  as a check of the filter's own work rather than a held-out one, the logistic regression the
  filter fits on the same embeddings (marked "in the filter").

Each is fit on ``--train`` train-split episodes from seed ``--train-seed`` on (the audit's probes
use seeds 0, 1, ...) and scored on the first ``-n`` evaluation episodes. Prints one Markdown row
per suite and model, with Wilson 95 % intervals:

    python scripts/check_general.py [--suites RSB-General-4 RSB-General-10] [-n 3000] [--data-dir DIR]
"""
from __future__ import annotations

import argparse
import sys
from typing import Callable, Sequence

import numpy as np

from rsb_maniskill.audit.guessers import credit
from rsb_maniskill.audit.reference import rate
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
from rsb_maniskill.semantic.sampler import EpisodeSampler
from rsb_maniskill.semantic.spec import EpisodeSpec

TRAIN_SEED = 500_000  # far from the audit's seeds 0, 1, ...


def _texts(specs: Sequence[EpisodeSpec]) -> list[str]:
    return [o for sp in specs for o in sp.options]


def _labels(specs: Sequence[EpisodeSpec]) -> np.ndarray:
    return np.concatenate([np.arange(sp.n_choices) == sp.answer_slot for sp in specs]).astype(int)


def naive_bayes(train: Sequence[EpisodeSpec], test: Sequence[EpisodeSpec]) -> np.ndarray:
    from sklearn.feature_extraction.text import CountVectorizer
    from sklearn.naive_bayes import ComplementNB

    vec = CountVectorizer(token_pattern=r"\S+", lowercase=False, ngram_range=(1, 2), min_df=2)
    nb = ComplementNB(alpha=1.0).fit(vec.fit_transform(_texts(train)), _labels(train))
    return nb.predict_log_proba(vec.transform(_texts(test)))[:, 1]


def char_svm(train: Sequence[EpisodeSpec], test: Sequence[EpisodeSpec], seed: int = 7) -> np.ndarray:
    from sklearn.feature_extraction.text import HashingVectorizer
    from sklearn.linear_model import SGDClassifier

    vec = HashingVectorizer(analyzer="char", ngram_range=(1, 4), n_features=1 << 20, alternate_sign=False,
                            norm="l2")
    svm = SGDClassifier(loss="hinge", alpha=1e-5, max_iter=50, tol=None, class_weight="balanced", random_state=seed)
    svm.fit(vec.transform(_texts(train)), _labels(train))
    return svm.decision_function(vec.transform(_texts(test)))


_ENCODER: list = []


def _embeddings(specs: Sequence[EpisodeSpec]) -> np.ndarray:
    """all-MiniLM-L6-v2 embedding of each option beside its difference from its set's mean."""
    from rsb_maniskill.baselines.diffusion_policy.text import TextEncoder

    if not _ENCODER:
        _ENCODER.append(TextEncoder())  # one model, its cache shared by the encoder rows
    out = []
    for sp in specs:
        e = _ENCODER[0].encode(list(sp.options))
        out.append(np.concatenate([e, e - e.mean(axis=0)], axis=1))
    return np.concatenate(out)


def encoder_mlp(train: Sequence[EpisodeSpec], test: Sequence[EpisodeSpec], seed: int = 7) -> np.ndarray:
    from sklearn.neural_network import MLPClassifier

    mlp = MLPClassifier(hidden_layer_sizes=(128,), alpha=1e-3, early_stopping=True, max_iter=200, random_state=seed)
    return mlp.fit(_embeddings(train), _labels(train)).predict_proba(_embeddings(test))[:, 1]


def encoder_lr(train: Sequence[EpisodeSpec], test: Sequence[EpisodeSpec]) -> np.ndarray:
    from sklearn.linear_model import LogisticRegression

    lr = LogisticRegression(C=1.0, max_iter=3000).fit(_embeddings(train), _labels(train))
    return lr.decision_function(_embeddings(test))


# name -> (model, whether scripts/filter_general.py uses this family on this representation)
MODELS: dict[str, tuple[Callable[[Sequence[EpisodeSpec], Sequence[EpisodeSpec]], np.ndarray], bool]] = {
    "naive bayes (whitespace tokens, 1-2 grams)": (naive_bayes, False),
    "linear SVM (hashed character 1-4 grams)": (char_svm, False),
    "encoder (all-MiniLM-L6-v2) + MLP": (encoder_mlp, False),
    "encoder (all-MiniLM-L6-v2) + logistic regression": (encoder_lr, True),
}


def credits(scores: np.ndarray, test: Sequence[EpisodeSpec]) -> np.ndarray:
    bounds = np.cumsum([0] + [sp.n_choices for sp in test])
    return np.array([credit(np.round(scores[a:b], 9), sp.answer_slot) for sp, a, b in zip(test, bounds, bounds[1:])])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suites", nargs="+", default=["RSB-General-4", "RSB-General-10"])
    ap.add_argument("-n", type=int, default=3000, help="evaluation episodes scored per suite")
    ap.add_argument("--train", type=int, default=4000, help="train-split episodes each model is fit on")
    ap.add_argument("--train-seed", type=int, default=TRAIN_SEED)
    ap.add_argument("--data-dir", default=None)
    args = ap.parse_args(argv)

    print("| suite | model | in the filter | % | 95 % CI | vs chance (points) |\n|---|---|---|---:|---|---:|")
    for suite in args.suites:
        tr = EpisodeSampler(suite, "train", data_dir=args.data_dir)
        te = EpisodeSampler(suite, "test", data_dir=args.data_dir)
        train = [tr.episode(args.train_seed + i) for i in range(args.train)]
        test = [te.episode(EVAL_SEED_BASE + i) for i in range(args.n)]
        chance = 1.0 / test[0].n_choices
        for name, (model, in_filter) in MODELS.items():
            acc, lo, hi = rate(credits(model(train, test), test))
            print(f"| {suite} | {name} | {'yes' if in_filter else 'no'} | {100 * acc:.1f} | "
                  f"[{100 * lo:.1f}, {100 * hi:.1f}] | {100 * (acc - chance):+.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
