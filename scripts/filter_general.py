"""Adversarial surface filter of RSB-General's MMLU-Pro questions (AFLite-style).

MMLU-Pro's written distractors leave surface marks on the answer (it is often the longest option,
or the one its variants were written around). A question whose answer a model finds from the
options alone -- never the question -- teaches and rewards shortcuts, so it is left out:

1. every eligible question (``mmlu_pro.eligible``) becomes ten rows of features *relative to its
   option set* (length, words, similarity to the other options, punctuation, ...);
2. two models, a logistic regression and gradient-boosted trees, are fit on a random half of the
   questions and score the other half, ``--rounds`` times; a question's predictability is the mean
   probability the held-out models gave its answer (their mean, normalised over its ten options);
3. the most predictable ``--drop`` fraction is left out, and 2-3 repeat until the held-out model's
   accuracy is within ``--target`` of chance or ``--max-iters`` is reached.

The content keys of the questions left out (``mmlu_pro.content_key``) are written to
rsb_maniskill/semantic/mmlu_pro_surface_filtered.txt, which the package ships: pools are built with
that list and no model at run time, so every machine builds the same pool. The audit's learned
probe (gradient-boosted trees on other features) is the independent check that the filter
generalises. Run (needs the MMLU-Pro data, see docs/semantic.md):

    python scripts/filter_general.py [--data-dir DIR] [--out rsb_maniskill/semantic/mmlu_pro_surface_filtered.txt]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from rsb_maniskill.semantic import mmlu_pro
from rsb_maniskill.semantic.data import MMLU_PRO_REPO, MMLU_PRO_REVISION, mmlu_pro_rows
from rsb_maniskill.semantic.normalize import similarity_matrix
from rsb_maniskill.semantic.records import normalize_text

N = mmlu_pro.N_OPTIONS


def _z(x: np.ndarray) -> np.ndarray:
    sd = x.std()
    return (x - x.mean()) / sd if sd > 0 else np.zeros_like(x)


def set_features(options: list[str]) -> np.ndarray:
    """(N, F) features of each option relative to its set."""
    sim = similarity_matrix(options)
    chars = np.array([len(o) for o in options], float)
    words = np.array([len(o.split()) for o in options], float)
    cols = [chars, words, np.nanmean(sim, axis=1), np.nanmax(sim, axis=1),
            np.array([o.count(",") for o in options], float),
            np.array([sum(not c.isalnum() and not c.isspace() for c in o) for o in options], float),
            np.array([sum(c.isdigit() for c in o) for o in options], float)]
    flags = [np.array([o[:1].isupper() for o in options], float), np.array([o.endswith(".") for o in options], float)]
    rel = [_z(c) for c in cols] + [chars / chars.mean(), words / words.mean()]
    ranks = [np.argsort(np.argsort(c, kind="stable"), kind="stable") / (N - 1) for c in cols[:4]]
    return np.stack(rel + ranks + [f - f.mean() for f in flags], axis=1)


def _held_out_probs(X: np.ndarray, y: np.ndarray, held: np.ndarray, seed: int) -> np.ndarray:
    """(held questions, N) probability of each option being the answer, by the two models fit on
    the other questions (mean of their per-option probabilities, normalised per set)."""
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.linear_model import LogisticRegression

    fit_x, fit_y = X[~held].reshape(-1, X.shape[-1]), y[~held].reshape(-1)
    test_x = X[held].reshape(-1, X.shape[-1])
    models = (LogisticRegression(C=1.0, max_iter=2000),
              HistGradientBoostingClassifier(max_iter=200, learning_rate=0.05, max_leaf_nodes=31, min_samples_leaf=20,
                                             l2_regularization=1.0, random_state=seed))
    p = np.mean([m.fit(fit_x, fit_y).predict_proba(test_x)[:, 1] for m in models], axis=0).reshape(-1, N)
    return p / p.sum(axis=1, keepdims=True)


def predictability(X: np.ndarray, y: np.ndarray, rounds: int, seed: int) -> tuple[np.ndarray, float]:
    """Mean held-out probability of each question's answer, and the held-out argmax accuracy."""
    q = len(X)
    rng = np.random.default_rng(seed)
    p_sum, p_n, hits, seen = np.zeros(q), np.zeros(q), 0.0, 0
    for r in range(rounds):
        held = rng.permutation(q) < q // 2
        p = _held_out_probs(X, y, held, seed * 1000 + r)
        ans = y[held].argmax(axis=1)
        p_sum[held] += p[np.arange(len(p)), ans]
        p_n[held] += 1
        hits += float((p.argmax(axis=1) == ans).sum())
        seen += int(held.sum())
    return p_sum / np.maximum(p_n, 1), hits / seen


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", default=None)
    ap.add_argument("--out", default=str(mmlu_pro.SURFACE_FILTERED))
    ap.add_argument("--rounds", type=int, default=8)
    ap.add_argument("--drop", type=float, default=0.05, help="fraction of the remaining questions dropped per pass")
    ap.add_argument("--target", type=float, default=0.005, help="stop when held-out accuracy <= 1/10 + this")
    ap.add_argument("--max-iters", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    rows, excluded = mmlu_pro.eligible(mmlu_pro_rows(args.data_dir))
    rows.sort(key=mmlu_pro.content_key)
    X = np.stack([set_features([normalize_text(o) for o in r["choices"]]) for r in rows])
    y = np.stack([np.arange(N) == r["answer"] for r in rows]).astype(int)
    alive = np.ones(len(rows), dtype=bool)
    for it in range(args.max_iters):
        idx = np.flatnonzero(alive)
        pred, acc = predictability(X[idx], y[idx], args.rounds, args.seed + it)
        print(f"pass {it}: {len(idx):,} questions, held-out accuracy {100 * acc:.1f} % (chance {100 / N:.0f} %)",
              file=sys.stderr)
        if acc <= 1 / N + args.target:
            break
        k = int(np.ceil(args.drop * len(idx)))
        alive[idx[np.argsort(-pred, kind="stable")[:k]]] = False
    dropped = sorted(mmlu_pro.content_key(rows[i]) for i in np.flatnonzero(~alive))
    out = Path(args.out)
    header = (f"# RSB-General: MMLU-Pro ({MMLU_PRO_REPO}@{MMLU_PRO_REVISION[:12]}) questions left out by "
              f"scripts/filter_general.py (content keys)\n# {len(dropped):,} of {len(rows):,} eligible questions; "
              f"final held-out accuracy {100 * acc:.1f} % (chance {100 / N:.0f} %)\n")
    out.write_text(header + "\n".join(dropped) + "\n", encoding="utf-8")
    print(f"wrote {out}: {len(dropped):,} of {len(rows):,} eligible questions left out", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
