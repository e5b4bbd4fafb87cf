"""Options: distinct, plausible, uniform correct letter, and no surface shortcut."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from rsb_maniskill.semantic import EpisodeSampler, clear_cache
from rsb_maniskill.semantic.commonsense import commonsense_pool
from rsb_maniskill.semantic.distractors import numeric_distractors, rank_range, rank_weights
from rsb_maniskill.semantic.knowledge import FACT_COUNT

FIXTURES = Path(__file__).parent / "fixtures" / "semantic_data"
EPISODES = 2000
TOLERANCE = 0.03


def _num(s: str):
    try:
        return float(s)
    except ValueError:
        return None


def shortcut_scores(specs) -> dict[str, float]:
    """Expected accuracy of answer-blind rules (ties broken uniformly), minus chance."""
    n = specs[0].n_choices
    acc: dict[str, float] = {k: 0.0 for k in ("largest", "smallest", "median", "longest", "most_digits")}
    acc.update({f"position_{L}": 0.0 for L in specs[0].letters})

    def credit(scores, a):
        m = max(scores)
        best = [i for i, s in enumerate(scores) if s == m]
        return 1.0 / len(best) if a in best else 0.0

    for sp in specs:
        o, a = sp.options, sp.answer_slot
        vals = [_num(x) for x in o]
        if all(v is not None for v in vals):
            med = float(np.median(vals))
            acc["largest"] += credit(vals, a)
            acc["smallest"] += credit([-v for v in vals], a)
            acc["median"] += credit([-abs(v - med) for v in vals], a)
        else:  # the value rules do not apply: they would guess
            for k in ("largest", "smallest", "median"):
                acc[k] += 1.0 / n
        acc["longest"] += credit([len(x) for x in o], a)
        acc["most_digits"] += credit([sum(c.isdigit() for c in x) for x in o], a)
        acc[f"position_{sp.correct_letter}"] += 1.0
    return {k: v / len(specs) - 1.0 / n for k, v in acc.items()}


def _assert_no_shortcut(suite_id, data_dir=None):
    s = EpisodeSampler(suite_id, "test", data_dir=data_dir)
    specs = [s.sample(seed) for seed in range(EPISODES)]
    scores = shortcut_scores(specs)
    worst = max(scores, key=scores.get)
    assert scores[worst] <= TOLERANCE, f"{suite_id}: rule {worst} beats chance by {100 * scores[worst]:.1f} points"
    return specs


def test_probe_detects_a_real_shortcut():
    """The probe itself must be able to fail: a sampler that always puts the answer first."""
    class Fake:
        def __init__(self, spec):
            self.__dict__.update(spec.__dict__)
    specs = [EpisodeSampler("RSB-Math-4", "test").sample(i) for i in range(200)]
    fake = [Fake(sp) for sp in specs]
    for f in fake:
        f.answer_slot, f.correct_letter = 0, "A"
        f.options = tuple(sorted(f.options, key=float, reverse=True))  # answer = largest? not necessarily
    scores = shortcut_scores(fake)
    assert scores["position_A"] > 0.5


@pytest.mark.parametrize("suite_id", ["RSB-Math-4", "RSB-Math-10", "RSB-Direct-4", "RSB-Direct-10"])
def test_no_shortcut_builtin_sources(suite_id):
    specs = _assert_no_shortcut(suite_id)
    # the correct letter is used about uniformly
    counts = np.bincount([sp.answer_slot for sp in specs], minlength=specs[0].n_choices)
    assert counts.min() > 0.6 * EPISODES / specs[0].n_choices


def _real_data_dir() -> Path:
    d = os.environ.get("RSB_DATA_DIR")
    if not d:
        pytest.skip("RSB_DATA_DIR is not set (CI sets RSB_DATA_DIR=../shared/data)")
    if not (Path(d) / "gsm8k" / "test.jsonl").is_file() or not (Path(d) / "mmlu" / "test").is_dir():
        pytest.skip(f"RSB_DATA_DIR={d} lacks gsm8k/ or mmlu/")
    return Path(d)


@pytest.mark.data
@pytest.mark.parametrize("suite_id", ["RSB-HardMath-4", "RSB-HardMath-10", "RSB-General-4", "RSB-General-10"])
def test_no_shortcut_real_data(suite_id):
    specs = _assert_no_shortcut(suite_id, _real_data_dir())
    for sp in specs[:300]:
        assert len({o.casefold() for o in sp.options}) == sp.n_choices


def test_math_distractors_are_plausible():
    s = EpisodeSampler("RSB-Math-10", "test")
    near = 0
    for seed in range(300):
        sp = s.sample(seed)
        ans = int(sp.options[sp.answer_slot])
        vals = [int(o) for o in sp.options]
        assert len(set(vals)) == 10 and all(v >= 0 for v in vals)
        assert all(abs(v - ans) <= max(10, ans // 2) for v in vals)  # same magnitude
        near += sum(abs(v - ans) in (1, 10) for v in vals)
    assert near > 300  # typical slips (off by one or ten) are common


def test_numeric_rank_is_what_was_asked():
    rng = np.random.default_rng(0)
    for v in (5, 37, 640, 12345, -7, -300):
        for n in (4, 10):
            lo, hi = rank_range(v, n)
            for r in range(lo, hi + 1):
                d = numeric_distractors(v, (v + 1, v * 2, v - 10), n, r, rng)
                assert len(d) == n - 1 == len(set(d)) and v not in d
                assert sum(x < v for x in d) == r
                assert all((x >= 0) == (v >= 0) for x in d)


def test_rank_weights_compensate_small_answers():
    values = [3] * 20 + [50] * 80
    w = rank_weights(values, 10)
    marginal = 0.2 * np.r_[np.full(4, 0.25), np.zeros(6)] + 0.8 * w
    assert np.allclose(marginal, 0.1)


def test_commonsense_table_and_split():
    assert FACT_COUNT >= 150
    train, test = commonsense_pool("train"), commonsense_pool("test")
    assert not {q.text for q, _ in train} & {q.text for q, _ in test}
    for q, cands in train + test:
        assert len(cands) >= 9 and q.answer not in cands


def test_commonsense_distractors_same_category():
    clear_cache()
    s = EpisodeSampler("RSB-General-10", "train", data_dir=FIXTURES)
    for qi, q in enumerate(s.pool.questions):
        if q.source != "commonsense":
            continue
        sp = s.sample(qi, question_index=qi)
        assert set(sp.options) - {q.answer} <= set(s.pool.candidates[qi])
        if qi > 60:
            break


def test_mmlu_10_adds_answers_of_same_subject():
    """Six extra options are answers of other questions of the subject (of the pool's MMLU
    answers only when a subject is too small, as in the remainders fixture)."""
    s = EpisodeSampler("RSB-General-10", "train", data_dir=FIXTURES)
    mmlu_answers = {x.answer for x in s.pool.questions if x.source == "mmlu"}
    same_subject = total = 0
    for qi, q in enumerate(s.pool.questions):
        if q.source != "mmlu":
            continue
        for seed in range(3):
            sp = s.sample(seed, question_index=qi)
            assert set(q.choices) <= set(sp.options)
            extra = set(sp.options) - set(q.choices)
            assert len(extra) == 6 and extra <= mmlu_answers
            if q.group == "toy_vocabulary":
                total += 1
                same_subject += extra <= {x.answer for x in s.pool.questions if x.group == q.group}
    assert same_subject >= 0.8 * total > 0
