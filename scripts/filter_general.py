"""Adversarial filter of RSB-General's MMLU-Pro questions (AFLite-style), on surface and words.

MMLU-Pro's written distractors leave marks on the answer: its shape (it is often the longest
option, or the one its variants were written around) and its words (distractors hold round
numbers inside sentences, "times 10", "because the ..."). A question whose answer a model finds
from the options alone -- never the question -- teaches and rewards shortcuts, so it is left out:

1. every eligible question (``mmlu_pro.eligible``) is seen as each suite shows it: its ten options
   (RSB-General-10) and the four of RSB-General-4 (``mmlu_pro.shown_subsets``; run
   scripts/mmlu_options.py first). Each option becomes word and character n-grams, features of its
   shape relative to its set (length, words, similarity to the others, punctuation, ...), and its
   sentence embedding (all-MiniLM-L6-v2, the ``baselines`` extra) beside its difference from the
   set's mean: what it says, which a text encoder reads (AFLite filters with one);
2. models are fit on three quarters of the questions and score the last quarter, the quarters
   drawn by the questions' split groups (``mmlu_pro._facts``: no near-duplicate or shared option
   on both sides), ``--rounds`` times: a logistic regression on n-grams and shape, one on the
   embeddings, and on the tens gradient-boosted trees on shape. A question's predictability in a
   suite is the lift over chance of the probability the held-out models gave its answer (their
   mean, each normalised over its options);
3. the ``--drop`` fraction most predictable on average over the suites still above chance is left
   out (a suite already at chance is not pushed below it: that would make its answers look like
   its distractors, the opposite give-away); within ``SLOW_DOWN`` of the target the fraction shrinks
   in proportion, so the last passes do not overshoot. 2-3 repeat until the held-out argmax
   accuracy of both suites is within ``--target`` of chance or ``--max-iters`` is reached.

The content keys of the questions left out (``mmlu_pro.content_key``) are written to
rsb_maniskill/semantic/mmlu_pro_filtered.txt, which the package ships: pools are built with that
list and no model at run time, so every machine builds the same pool (the defaults below wrote the
shipped list). ``rsb audit``'s surface and lexical probes (other features, fit on episodes) and
scripts/check_general.py (model families and tokenisations the filter never used, other seeds) are
the independent checks. Takes about 12 minutes on two idle cores (40 on busy ones). Run (needs the
MMLU-Pro data, see docs/semantic.md):

    python scripts/filter_general.py [--data-dir DIR] [--out rsb_maniskill/semantic/mmlu_pro_filtered.txt]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from rsb_maniskill.semantic import mmlu_pro
from rsb_maniskill.semantic.data import MMLU_PRO_REPO, MMLU_PRO_REVISION, mmlu_pro_rows
from rsb_maniskill.semantic.normalize import similarity_matrix
from rsb_maniskill.semantic.stable import stable_bucket

FOLDS = 4
SLOW_DOWN = 0.04  # within this much accuracy of the target, passes drop proportionally fewer questions
SUITES = (mmlu_pro.N_OPTIONS, 4)  # the option counts the two General suites show


def _z(x: np.ndarray) -> np.ndarray:
    sd = x.std()
    return (x - x.mean()) / sd if sd > 0 else np.zeros_like(x)


def set_features(options: list[str]) -> np.ndarray:
    """(N, F) features of each option's shape relative to its set."""
    n = len(options)
    sim = similarity_matrix(options)
    chars = np.array([len(o) for o in options], float)
    words = np.array([len(o.split()) for o in options], float)
    cols = [chars, words, np.nanmean(sim, axis=1), np.nanmax(sim, axis=1),
            np.array([o.count(",") for o in options], float),
            np.array([sum(not c.isalnum() and not c.isspace() for c in o) for o in options], float),
            np.array([sum(c.isdigit() for c in o) for o in options], float)]
    flags = [np.array([o[:1].isupper() for o in options], float), np.array([o.endswith(".") for o in options], float)]
    rel = [_z(c) for c in cols] + [chars / chars.mean(), words / words.mean()]
    ranks = [np.argsort(np.argsort(c, kind="stable"), kind="stable") / (n - 1) for c in cols[:4]]
    return np.stack(rel + ranks + [f - f.mean() for f in flags], axis=1)


class Shown:
    """One suite's option sets of every eligible question (in a fixed random order, as episodes
    show them: ties in the shape ranks must not sort the answer first), as model inputs: word and
    character n-grams (vocabulary and weights from all the texts: no labels), shape features, and
    sentence embeddings of each option and their difference from the set's mean."""

    def __init__(self, rows: list[dict], n: int, encoder: dict[str, np.ndarray]) -> None:
        from scipy.sparse import hstack
        from sklearn.feature_extraction.text import TfidfVectorizer

        self.n = n
        sets: list[list[str]] = []
        self.answer = np.zeros(len(rows), dtype=int)
        for i, r in enumerate(rows):
            q = mmlu_pro.to_question(r)
            rest = [c for c in q.choices if c != q.answer]
            shown = [q.answer, *(rest[k] for k in mmlu_pro.shown_subsets(q, n)[0])]
            order = np.random.default_rng(stable_bucket("filter-general-order", q.text, modulo=1 << 30)).permutation(n)
            sets.append([shown[k] for k in order])
            self.answer[i] = int(np.flatnonzero(order == 0)[0])
        texts = [o for s in sets for o in s]
        self.words = hstack([TfidfVectorizer(ngram_range=(1, 2), min_df=2, sublinear_tf=True).fit_transform(texts),
                             TfidfVectorizer(analyzer="char_wb", ngram_range=(2, 5), min_df=3,
                                             sublinear_tf=True).fit_transform(texts)]).tocsr()
        self.shape = np.stack([set_features(s) for s in sets])  # (Q, n, F)
        emb = np.stack([encoder[o] for o in texts]).reshape(len(sets), n, -1)
        self.meaning = np.concatenate([emb, emb - emb.mean(axis=1, keepdims=True)], axis=2)  # (Q, n, 2 x 384)

    def rows(self, idx: np.ndarray) -> np.ndarray:
        """Option rows of the questions ``idx``."""
        return (idx[:, None] * self.n + np.arange(self.n)[None, :]).ravel()

    def labels(self, idx: np.ndarray) -> np.ndarray:
        return (np.arange(self.n)[None, :] == self.answer[idx, None]).astype(int)


def encode(texts: set[str]) -> dict[str, np.ndarray]:
    """all-MiniLM-L6-v2 embeddings of the texts (the ``baselines`` extra ships the weights)."""
    from rsb_maniskill.baselines.diffusion_policy.text import TextEncoder

    order = sorted(texts)
    emb = TextEncoder().model.encode(order, batch_size=128, normalize_embeddings=True, convert_to_numpy=True,
                                     show_progress_bar=False)
    return dict(zip(order, emb))


def _held_out(shown: Shown, fit: np.ndarray, score: np.ndarray, seed: int) -> np.ndarray:
    """(len(score), n) held-out probability of each shown option being the answer."""
    from scipy.sparse import csr_matrix, hstack
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.linear_model import LogisticRegression
    from sklearn.preprocessing import StandardScaler

    n, nf = shown.n, shown.shape.shape[-1]
    y = shown.labels(fit).ravel()
    fit_s, score_s = shown.shape[fit].reshape(-1, nf), shown.shape[score].reshape(-1, nf)
    scale = StandardScaler().fit(fit_s)  # shape beside unit-norm n-grams: unscaled, the solver crawls
    fit_x = hstack([shown.words[shown.rows(fit)], csr_matrix(scale.transform(fit_s))]).tocsr()
    score_x = hstack([shown.words[shown.rows(score)], csr_matrix(scale.transform(score_s))]).tocsr()
    nm = shown.meaning.shape[-1]
    probs = [LogisticRegression(C=1.0, solver="liblinear").fit(fit_x, y).predict_proba(score_x)[:, 1],
             LogisticRegression(C=1.0, max_iter=2000).fit(shown.meaning[fit].reshape(-1, nm), y)
             .predict_proba(shown.meaning[score].reshape(-1, nm))[:, 1]]
    if n == mmlu_pro.N_OPTIONS:
        trees = HistGradientBoostingClassifier(max_iter=200, learning_rate=0.05, min_samples_leaf=20,
                                               l2_regularization=1.0, random_state=seed)
        probs.append(trees.fit(fit_s, y).predict_proba(score_s)[:, 1])
    return np.mean([(x / x.reshape(-1, n).sum(axis=1).repeat(n)) for x in probs], axis=0).reshape(-1, n)


def predictability(suites: list[Shown], idx: np.ndarray, facts: list[str], rounds: int,
                   seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Per suite and question of ``idx``: the held-out lift of its answer, averaged over rounds;
    and each suite's held-out argmax accuracy."""
    lift = np.zeros((len(suites), len(idx)))
    hits = np.zeros(len(suites))
    for r in range(rounds):
        fold = np.array([stable_bucket(f"filter-general-{seed}-{r}", facts[i]) % FOLDS for i in idx])
        for s, shown in enumerate(suites):
            chance = 1.0 / shown.n
            for f in range(FOLDS):
                held = idx[fold == f]
                p = _held_out(shown, idx[fold != f], held, seed * 100 + r)
                p_answer = p[np.arange(len(held)), shown.answer[held]]
                lift[s, fold == f] += (p_answer - chance) / (1 - chance) / rounds
                hits[s] += float((p.argmax(axis=1) == shown.answer[held]).sum())
    return lift, hits / (rounds * len(idx))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", default=None)
    ap.add_argument("--out", default=str(mmlu_pro.FILTERED))
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--drop", type=float, default=0.06, help="fraction of the remaining questions dropped per pass")
    ap.add_argument("--target", type=float, default=0.005, help="stop when held-out accuracy <= 1/N + this")
    ap.add_argument("--max-iters", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    rows, _ = mmlu_pro.eligible(mmlu_pro_rows(args.data_dir))
    rows.sort(key=mmlu_pro.content_key)
    facts = mmlu_pro._facts(rows)
    suites = [Shown(rows, n, encode({o for r in rows for o in mmlu_pro.to_question(r).choices})) for n in SUITES]
    alive = np.ones(len(rows), dtype=bool)
    for it in range(args.max_iters):
        idx = np.flatnonzero(alive)
        lift, acc = predictability(suites, idx, facts, args.rounds, args.seed + it)
        print(f"pass {it}: {len(idx):,} questions, held-out accuracy "
              + ", ".join(f"{100 * a:.1f} % of {s.n} (chance {100 / s.n:.0f} %)" for a, s in zip(acc, suites)),
              file=sys.stderr, flush=True)
        off = np.array([a - 1 / s.n for a, s in zip(acc, suites)])  # accuracy minus chance, per suite
        above = off > args.target
        if not above.any():
            break
        # rank by the suites still above chance only: pushing the other below chance would plant
        # the opposite give-away (its answers would look like its distractors)
        excess = float(off[above].max()) - args.target
        k = int(np.ceil(len(idx) * args.drop * float(np.clip(excess / SLOW_DOWN, 1 / 6, 1))))
        alive[idx[np.argsort(-lift[above].mean(axis=0), kind="stable")[:k]]] = False
    dropped = sorted(mmlu_pro.content_key(rows[i]) for i in np.flatnonzero(~alive))
    out = Path(args.out)
    header = (f"# RSB-General: MMLU-Pro ({MMLU_PRO_REPO}@{MMLU_PRO_REVISION[:12]}) questions left out by "
              f"scripts/filter_general.py (content keys)\n# {len(dropped):,} of {len(rows):,} eligible questions; "
              "final held-out accuracy " + ", ".join(f"{100 * a:.1f} % of {s.n}" for a, s in zip(acc, suites)) + "\n")
    out.write_text(header + "\n".join(dropped) + "\n", encoding="utf-8")
    print(f"wrote {out}: {len(dropped):,} of {len(rows):,} eligible questions left out", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
