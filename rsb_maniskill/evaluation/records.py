"""What an episode record is: its fields, its identity, its table row, and how one is built.

A record is one JSON object per finished episode (``store.py`` writes and reads the files). The
runner builds it with :func:`build_record` from the episode spec and the env's last ``info``; the
LeRobot env and the vla-eval benchmark build theirs with the same function, naming themselves in
the ``runner`` field. Records carry the benchmark version of their episodes: records of two
versions never share a table (:func:`one_version`).
"""
from __future__ import annotations

from typing import Any, Iterable, Mapping, Sequence

from rsb_maniskill.batch import first_value
from rsb_maniskill.perturb import label as axes_label
from rsb_maniskill.semantic.counterfactual import MODE as COUNTERFACTUAL
from rsb_maniskill.semantic.digest import episode_digest
from rsb_maniskill.version import BENCHMARK_VERSION

# Fields every record carries (the runner fills them; extra fields are free).
RECORD_FIELDS: tuple[str, ...] = (
    "suite_id", "seed", "question_id", "instruction", "instruction_mode", "target_block", "correct_letter",
    "first_grasped", "grasped_any", "grasped_correct", "placed_correct", "placed_wrong", "success", "steps",
    "policy",
)
# The instruction ablations: one instruction an episode, the protocol's or made from it (the
# modes of rsb backbone, the LeRobot env and the vla-eval benchmark too).
INSTRUCTION_MODES: tuple[str, ...] = ("normal", "blank", "shuffled")
# Counterfactual scenes: K variants of each protocol scene, the answer on another candidate each
# (semantic/counterfactual.py); records carry VARIANT_FIELDS. rsb eval only.
EVAL_INSTRUCTION_MODES: tuple[str, ...] = INSTRUCTION_MODES + (COUNTERFACTUAL,)
VARIANT_FIELDS: tuple[str, ...] = ("variant", "variant_kind")  # the index (0 = the protocol episode), its kind
# A record's identity: the same episode of the same evaluation. Later duplicates are dropped.
RECORD_KEY: tuple[str, ...] = ("policy", "suite_id", "instruction_mode", "perturb", "seed", "variant")
# Values of key fields that a record may lack (records written before the field existed; an
# episode without a variant is its scene's protocol episode, variant 0).
KEY_DEFAULTS: dict[str, Any] = {"perturb": "none", "variant": 0}
# The benchmark version of the episodes (rsb_maniskill.version): the runner writes it into every
# record; records written before versions existed read as "unversioned".
VERSION_FIELD = "benchmark_version"
# info flags copied into every record, and extra ones kept when the env provides them.
RECORD_FLAGS = ("grasped_any", "grasped_correct", "placed_correct", "placed_wrong", "success")
EXTRA_FLAGS = ("grasped_wrong", "fail")
# What kind of episode it is ({dimension: value}, semantic/categories.py) and where its candidates
# stand (rank of each from the left in the head camera, positions.py): the per-category and bias
# tables read them; records written before they existed lack them (the tables say so).
CATEGORIES_FIELD = "categories"
# Which episode it was: the digest of its question, options, option -> candidate binding, instruction
# and candidates (semantic/digest.py); evaluation/provenance.py checks it against the episode the
# benchmark version makes. Records written before it existed lack it ("unverified").
DIGEST_FIELD = "episode_digest"
LEFT_RANK_FIELD = "left_rank"
# The ``runner`` field of records written by another harness than ``rsb eval`` (which writes none):
# LeRobot's ``lerobot-eval`` (integrations/lerobot_env.py) and vla-eval (integrations/vla_eval.py,
# whose RSBBenchmark and ``rsb eval remote -a protocol=vla-eval`` also take it as the policy name).
LEROBOT_RUNNER = "lerobot-eval"
VLA_EVAL_RUNNER = "vla-eval"


class VersionMixError(ValueError):
    """Records of two benchmark versions (their episodes differ) asked to share one table."""


def record_version(record: Mapping[str, Any]) -> str:
    """The benchmark version a record was measured on (``"unversioned"`` before versions existed)."""
    from rsb_maniskill.version import UNVERSIONED

    return str(record.get(VERSION_FIELD) or UNVERSIONED)


def one_version(records: Iterable[Mapping[str, Any]]) -> str | None:
    """The one benchmark version of ``records`` (None when there are none); VersionMixError, one
    line naming two of them, when they hold several."""
    from rsb_maniskill.version import UNVERSIONED, benchmark_label

    versions = sorted({record_version(r) for r in records})
    if len(versions) > 1:
        a, b = (benchmark_label(v) if v != UNVERSIONED else "unversioned records (written before benchmark "
                "versions existed; their episodes may differ)" for v in versions[:2])
        raise VersionMixError(f"cannot pool records of {a} and {b} into one table: they were measured on "
                              "different episodes; report each version's records apart")
    return versions[0] if versions else None


def validate_record(record: Mapping[str, Any]) -> None:
    """Raise ValueError naming the missing fields or a bad instruction mode."""
    missing = [k for k in RECORD_FIELDS if k not in record]
    if len(missing) == len(RECORD_FIELDS):
        raise ValueError(f"not an episode record: it has none of their fields ({', '.join(missing[:3])}, ...)")
    if missing:
        raise ValueError(f"episode record lacks fields: {', '.join(missing)}")
    if record["instruction_mode"] not in EVAL_INSTRUCTION_MODES:
        raise ValueError(f"instruction_mode must be one of {EVAL_INSTRUCTION_MODES}, "
                         f"got {record['instruction_mode']!r}")
    if record["instruction_mode"] == COUNTERFACTUAL and any(k not in record for k in VARIANT_FIELDS):
        raise ValueError(f"a counterfactual record lacks {' or '.join(VARIANT_FIELDS)}")


# ---------------------------------------------------------------- identity and rows
def _key(record: Mapping[str, Any]) -> tuple:
    return tuple(record.get(k, KEY_DEFAULTS.get(k)) for k in RECORD_KEY)


def perturb_label(record: Mapping[str, Any]) -> str:
    """The record's robustness perturbation (``"camera=2"``), ``"none"`` for an unperturbed episode."""
    return str(record.get("perturb", "none"))


def row_label(policy: str, instruction_mode: str = "normal", perturb: str = "none") -> str:
    """Table row of a policy; ablation modes and perturbations get their own rows, e.g.
    ``"pi0 (blank)"``, ``"pi0 [camera=2]"``."""
    label = policy if instruction_mode == "normal" else f"{policy} ({instruction_mode})"
    return label if perturb == "none" else f"{label} [{perturb}]"


def record_row(record: Mapping[str, Any]) -> str:
    """The table row a record belongs to (:func:`row_label` of its policy, mode and perturbation)."""
    return row_label(str(record.get("policy", "?")), record.get("instruction_mode", "normal"), perturb_label(record))


def dedupe(records: Iterable[Mapping[str, Any]]) -> list[dict]:
    """Keep the first record of each (policy, suite, instruction mode, perturbation, seed, variant)."""
    seen: set[tuple] = set()
    out = []
    for r in records:
        k = _key(r)
        if k not in seen:
            seen.add(k)
            out.append(dict(r))
    return out


# ---------------------------------------------------------------- building one
def perturb_fields(perturb: Mapping[str, int]) -> dict[str, Any]:
    """A perturbed episode's record fields: ``perturb`` ("camera=2"), and with one axis its
    ``perturb_axis`` and ``perturb_level``."""
    out: dict[str, Any] = {"perturb": axes_label(perturb)}
    if len(perturb) == 1:
        (axis, level), = perturb.items()
        out.update(perturb_axis=axis, perturb_level=int(level))
    return out


def info_flag(info: Mapping[str, Any], key: str, default: Any = False) -> Any:
    return first_value(info[key]) if key in info else default


def build_record(
    *,
    suite_id: str,
    seed: int,
    spec: Any,
    instruction: str,
    instruction_mode: str,
    info: Mapping[str, Any],
    steps: int,
    policy: str,
    extra: Mapping[str, Any] | None = None,
    categories: Mapping[str, str] | None = None,
    left_rank: Sequence[int] | None = None,
) -> dict[str, Any]:
    """The episode record (:data:`RECORD_FIELDS`, and the benchmark version) from the episode
    spec and the last ``info``; with ``categories`` (what the task says the episode is:
    ``semantic/categories.py``) and ``left_rank`` (each candidate's rank from the left in the head
    camera: ``positions.py``) the per-category and bias tables can read the record."""
    record: dict[str, Any] = {
        "suite_id": suite_id,
        "seed": int(seed),
        "question_id": int(spec.question_id),
        "instruction": instruction,
        "instruction_mode": instruction_mode,
        "target_block": int(spec.target_block),
        "correct_letter": str(spec.correct_letter),
        "first_grasped": int(info_flag(info, "first_grasped", -1)),
        **{k: bool(info_flag(info, k)) for k in RECORD_FLAGS},
        "steps": int(steps),
        "policy": policy,
        VERSION_FIELD: BENCHMARK_VERSION,
    }
    if hasattr(spec, "block_of_option"):  # an EpisodeSpec (tests may pass a bare stand-in)
        record[DIGEST_FIELD] = episode_digest(spec)
    record.update({k: bool(info_flag(info, k)) for k in EXTRA_FLAGS if k in info})
    if categories:
        record[CATEGORIES_FIELD] = {str(k): str(v) for k, v in categories.items()}
    if left_rank is not None:
        record[LEFT_RANK_FIELD] = [int(r) for r in left_rank]
    if extra:
        record.update(extra)
    return record
