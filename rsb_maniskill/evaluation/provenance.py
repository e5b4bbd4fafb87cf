"""Whether a run's records are of this benchmark version's episodes, from their episode digests.

Every record carries ``episode_digest`` (``records.DIGEST_FIELD``, ``semantic/digest.py``): the
digest of its question, options, option -> candidate binding, instruction and candidates. Here each
is compared with the digest of the episode this install's sampler makes for the same suite, seed,
perturbation and counterfactual variant on the evaluation split, without the simulator (``rsb
verify`` proves the install's episodes are the version's pinned ones). A run on other question data
(a GSM8K cut to 100 rows, another ``RSB_DATA_DIR``) asked other questions: its records differ and
every report says so. Records without a digest (written before it existed, or by another version)
are *unverified*.

The data a record is checked on must itself be the version's: a record that matches a GSM8K cut to
100 rows is that cut's episode, not the benchmark's. So a suite's evaluation question pool on the
data at hand is compared with its pinned digest (:data:`PINNED_POOLS`) first; the data tried are
the run's own (``--data-dir``, from run.json), then ``$RSB_DATA_DIR`` / the hub cache. A record is
*pinned* where pinned data makes its episode, *differs* where pinned data makes another or where
only unpinned data makes it, *unverified* where no data at hand can tell.

A verdict proven once does not decay: where no question data is at hand to check records that carry
this version's digests (``rsb report`` on a laptop, ``RSB_OFFLINE=1``), :meth:`Provenance.keep` keeps
the *pinned* an earlier check gave the same records (the results.json written when they ran,
``reporting/results.py``), and the line says "not re-checked: no data".
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
from collections import Counter
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Iterable, Mapping

from rsb_maniskill.evaluation.records import COUNTERFACTUAL, DIGEST_FIELD, VERSION_FIELD, perturb_label

PINNED, DIFFER, UNVERIFIED = "pinned", "differ", "unverified"  # a record's or a run's verdict
NO_DATA = "no data"  # why an unverified record with this version's digest is: no question data at hand to check it
# The evaluation split's question pools of the sources that read data, on the version's pinned
# GSM8K / MMLU-Pro (semantic/data.py's revisions): :func:`pool_digest`. A source without a pin here
# (a plugin's) is taken as its data makes it. tests/evaluation/test_episode_provenance.py checks
# them against the pinned episodes (audit/golden_episodes.json) on the real data.
PINNED_POOLS = {
    "HardMath": "15f0b4cad29dd736f51c60122201bcab351df54d21f13cfb461d5c5e4ea4c6c3",
    "General": "9b50b3536eec680d6487831c3ba9d7c029f2e0f7dd0422c7cc11fdb76bab87c2",
}
POOL_SPLIT = "test"  # the evaluation's split (protocol.EVAL_ENV_KWARGS)


def pool_digest(pool: Any) -> str:
    """The sha256 of a question pool: each question's fields but its origin (a file path), in order."""
    from rsb_maniskill.semantic.digest import canonical_line

    h = hashlib.sha256()
    for q in pool.questions:
        h.update(canonical_line({k: v for k, v in dataclasses.asdict(q).items() if k != "origin"}))
    return h.hexdigest()


@lru_cache(maxsize=64)
def data_pinned(suite_id: str, data_dir: str | None, env_data_dir: str | None = None) -> bool:
    """Whether the data at hand (``data_dir``, else $RSB_DATA_DIR or the hub: ``env_data_dir`` keys the
    cache) makes ``suite_id``'s pinned evaluation pool; raises the data's error when it is missing."""
    from rsb_maniskill.objects.family import split_env_id
    from rsb_maniskill.semantic.pools import get_pool
    from rsb_maniskill.semantic.suites import parse_suite_id, suite_source

    name = parse_suite_id(split_env_id(suite_id)[0])[0]
    source = suite_source(name)
    if not source.reads_data or name not in PINNED_POOLS:
        return True
    return pool_digest(get_pool(name, POOL_SPLIT, data_dir)) == PINNED_POOLS[name]


@lru_cache(maxsize=64)
def _sampler(suite_id: str, perturb: str, data_dir: str | None, color_map: str, env_data_dir: str | None):
    from rsb_maniskill.evaluation.protocol import EVAL_ENV_KWARGS
    from rsb_maniskill.objects.family import split_env_id
    from rsb_maniskill.semantic import EpisodeSampler

    suite, targets = split_env_id(suite_id)
    return EpisodeSampler(suite, **EVAL_ENV_KWARGS, color_map=color_map, targets=targets, data_dir=data_dir,
                          perturb=None if perturb == "none" else perturb)


def expected_digest(record: Mapping[str, Any], data_dir: str | os.PathLike | None = None,
                    color_map: str = "fixed") -> str:
    """The digest of the episode this install makes (on ``data_dir``: default, RSB_DATA_DIR or the
    package's) for ``record``'s suite, seed, perturbation and variant."""
    counterfactual = record.get("instruction_mode") == COUNTERFACTUAL
    return _expected(str(record["suite_id"]), perturb_label(record), int(record["seed"]),
                     int(record.get("variant", 0)) if counterfactual else None,
                     None if data_dir is None else str(data_dir), color_map, os.environ.get("RSB_DATA_DIR"))


@lru_cache(maxsize=1 << 16)
def _expected(suite_id: str, perturb: str, seed: int, variant_index: int | None, data_dir: str | None,
              color_map: str, env_data_dir: str | None) -> str:
    """:func:`expected_digest`, kept: a run's summaries, results.json, page and last line each check it."""
    from rsb_maniskill.semantic.counterfactual import variant
    from rsb_maniskill.semantic.digest import episode_digest

    sampler = _sampler(suite_id, perturb, data_dir, color_map, env_data_dir)
    if variant_index is not None:
        return episode_digest(variant(sampler, seed, variant_index).spec)
    return episode_digest(sampler.episode(seed))


def check_question_pool(records: Iterable[Mapping[str, Any]], label: str, data_dir: str | os.PathLike | None,
                        color_map: str = "fixed") -> str | None:
    """None if ``label``'s recorded episodes are the ones the data at hand makes (a resume adds to
    the same question pool), else one line saying which differs: the first record of each suite,
    mode and perturbation is checked (a pool differs in every episode or in few; both show there)."""
    seen: set[tuple] = set()
    for r in records:
        key = (r.get("suite_id"), r.get("instruction_mode"), perturb_label(r))
        if r.get("policy") != label or DIGEST_FIELD not in r or key in seen:
            continue
        seen.add(key)
        try:
            same = expected_digest(r, data_dir, color_map) == r[DIGEST_FIELD]
        except (KeyError, ValueError, IndexError):
            same = False
        if not same:
            data = data_dir or os.environ.get("RSB_DATA_DIR") or "the package's data"
            return (f"the recorded episodes of {label!r} ({r['suite_id']}, seed {r['seed']}) asked other questions "
                    f"than the data at hand makes ({data}): a resume would pool two question pools; resume with "
                    "the data they were run on (RSB_DATA_DIR / --data-dir), or use another --out")
    return None


@lru_cache(maxsize=64)
def _pinned_at_hand(suite_id: str, data_dir: str | None, env_data_dir: str | None) -> bool | None:
    """:func:`data_pinned`, None where that data is not at hand (asked once, not once a record)."""
    from rsb_maniskill.semantic.errors import SemanticError

    try:
        return data_pinned(suite_id, data_dir, env_data_dir)
    except (SemanticError, OSError):
        return None


def record_verdict(record: Mapping[str, Any], data_dir: str | os.PathLike | None = None) -> str:
    """:data:`PINNED`, :data:`DIFFER` or :data:`UNVERIFIED` (no digest, another version's record, or
    no data at hand to check it on); ``data_dir``: the data the run was given (tried first)."""
    verdict = _verdict(record, data_dir)
    return UNVERIFIED if verdict == NO_DATA else verdict


def _verdict(record: Mapping[str, Any], data_dir: str | os.PathLike | None = None) -> str:
    """:func:`record_verdict`, with :data:`NO_DATA` where the record carries this version's digest and
    no question data at hand can check it (its unverified for a reason a report names)."""
    from rsb_maniskill.semantic.errors import SemanticError
    from rsb_maniskill.version import BENCHMARK_VERSION

    if DIGEST_FIELD not in record or record.get(VERSION_FIELD) != BENCHMARK_VERSION:
        return UNVERIFIED
    made_by_unpinned = False
    for data in ([str(data_dir)] if data_dir else []) + [None]:  # the run's data, then the default's
        try:
            pinned = _pinned_at_hand(str(record["suite_id"]), data, os.environ.get("RSB_DATA_DIR"))
            if pinned is None:  # this data is not at hand or not readable (a --data-dir gone, no hub cache)
                continue
            same = expected_digest(record, data) == record[DIGEST_FIELD]
        except (SemanticError, OSError):
            continue
        except (KeyError, ValueError, IndexError):  # a seed or suite this install cannot make: not this version's
            return DIFFER
        if pinned:
            return PINNED if same else DIFFER
        made_by_unpinned = made_by_unpinned or same
    return DIFFER if made_by_unpinned else NO_DATA


@dataclass(frozen=True)
class Provenance:
    """Counts of records per verdict, and the suites holding a record that differs; ``no_data``: how
    many of the unverified carry this version's digest and found no question data to be checked on;
    ``kept``: PINNED kept from an earlier check of the same records (:meth:`keep`)."""

    counts: Mapping[str, int] = field(default_factory=dict)
    differ_suites: tuple[str, ...] = ()
    no_data: int = 0
    kept: bool = False

    @property
    def verdict(self) -> str:
        """:data:`DIFFER` if any record differs, else :data:`UNVERIFIED` if any is (unless an earlier
        check's PINNED is kept), else :data:`PINNED`."""
        if self.kept:
            return PINNED
        for v in (DIFFER, UNVERIFIED):
            if self.counts.get(v):
                return v
        return PINNED

    @property
    def unchecked(self) -> bool:
        """Unverified only for want of question data: every unverified record carries this version's digest."""
        return not self.counts.get(DIFFER) and 0 < self.counts.get(UNVERIFIED, 0) == self.no_data

    def keep(self, earlier: str | None) -> "Provenance":
        """This verdict, or :data:`PINNED` where an earlier check of the same records proved them the
        version's (``earlier``: the verdict a results file gave them when they ran) and this one could
        not check them for want of question data: a verdict proven once does not decay to unverified
        because a report ran where the data is not."""
        return dataclasses.replace(self, kept=True) if earlier == PINNED and self.unchecked else self

    def text(self, version: str | None = None) -> str:
        """One line: ``"episodes differ from RSB-MS 1.1 (RSB-HardMath-4: 3 of 3 episodes)"``."""
        from rsb_maniskill.version import benchmark_label

        label = benchmark_label(version) if version else benchmark_label()
        n = sum(self.counts.values())
        if self.kept:
            return (f"episodes: {n} of {label}, pinned when they were checked before (results.json); not "
                    f"re-checked: no data (no question data at hand; set RSB_DATA_DIR to re-check them)")
        if self.verdict == DIFFER:
            return (f"episodes differ from {label} ({', '.join(self.differ_suites)}: {self.counts[DIFFER]} of {n} "
                    "episodes are not the version's: other question data? check RSB_DATA_DIR and `rsb verify`)")
        if self.unchecked:
            return (f"episodes unverified: not checked, no data ({self.no_data} of {n} records carry digests of "
                    f"{label}, and no question data is at hand to check them on; set RSB_DATA_DIR to the data "
                    "they ran on)")
        if self.verdict == UNVERIFIED:
            return (f"episodes unverified ({self.counts[UNVERIFIED]} of {n} records: no episode digest of {label}, or "
                    "no question data at hand to check them on; set RSB_DATA_DIR to the data they ran on)")
        return f"episodes: {n} of {label}, each checked against its digest"


def run_data_dir(runs: Mapping[str, Mapping[str, Any]] | None, policy: Any) -> str | None:
    """The ``--data-dir`` the run of ``policy`` was given: ``runs`` is run.json's settings per policy."""
    env_kwargs = ((runs or {}).get(str(policy)) or {}).get("env_kwargs") or {}
    return env_kwargs.get("data_dir") if isinstance(env_kwargs, Mapping) else None


def check_records(records: Iterable[Mapping[str, Any]], data_dir: str | os.PathLike | None = None,
                  runs: Mapping[str, Mapping[str, Any]] | None = None) -> Provenance:
    """The :class:`Provenance` of ``records``, each checked on the data its run was given first
    (``runs``: run.json's settings per policy, or one ``data_dir`` for all), then on the default's."""
    counts: Counter[str] = Counter()
    differ: set[str] = set()
    for r in records:
        v = _verdict(r, run_data_dir(runs, r.get("policy")) if runs else data_dir)
        counts[v] += 1
        if v == DIFFER:
            differ.add(str(r.get("suite_id")))
    from rsb_maniskill.evaluation.metrics import suite_order

    no_data = counts.pop(NO_DATA, 0)
    if no_data:
        counts[UNVERIFIED] += no_data
    return Provenance(dict(counts), tuple(suite_order(differ)), no_data)
