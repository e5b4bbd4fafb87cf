"""Episode records: one JSON line per finished episode, written so that a killed run loses nothing.

A results directory (``rsb eval --out``, ``lerobot-eval``'s ``records_dir``) holds them in
``RECORDS_FILE``, and ``rsb eval`` the settings of each policy row in ``MANIFEST_FILE``.

Each record is appended, flushed and fsync'ed as its episode ends. A run killed mid-write leaves
at most one partial last line; the reader skips it and the writer cuts it off before appending, so
resuming (skip ``completed_seeds``, run the rest) yields the same records as an uninterrupted run.
"""
from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

RECORDS_FILE = "episodes.jsonl"
MANIFEST_FILE = "run.json"
# Fields every record carries (the runner fills them; extra fields are free).
RECORD_FIELDS: tuple[str, ...] = (
    "suite_id", "seed", "question_id", "instruction", "instruction_mode", "target_block", "correct_letter",
    "first_grasped", "grasped_any", "grasped_correct", "placed_correct", "placed_wrong", "success", "steps",
    "policy",
)
INSTRUCTION_MODES: tuple[str, ...] = ("normal", "blank", "shuffled")
# A record's identity: the same episode of the same evaluation. Later duplicates are dropped.
RECORD_KEY: tuple[str, ...] = ("policy", "suite_id", "instruction_mode", "perturb", "seed")
# Values of key fields that a record may lack (records written before the field existed).
KEY_DEFAULTS: dict[str, Any] = {"perturb": "none"}
# The benchmark version of the episodes (rsb_maniskill.version): the runner writes it into every
# record; records written before versions existed read as "unversioned".
VERSION_FIELD = "benchmark_version"


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
    if missing:
        raise ValueError(f"episode record lacks fields: {', '.join(missing)}")
    if record["instruction_mode"] not in INSTRUCTION_MODES:
        raise ValueError(f"instruction_mode must be one of {INSTRUCTION_MODES}, got {record['instruction_mode']!r}")


def _json_default(obj: Any) -> Any:
    # numpy / torch scalars and arrays coming straight from the env's info.
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if hasattr(obj, "item"):
        return obj.item()
    if isinstance(obj, (set, tuple)):
        return list(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _parse_tail(tail: bytes) -> dict | None:
    try:
        value = json.loads(tail.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    return value if isinstance(value, dict) else None


def repair_tail(path: str | os.PathLike) -> bool:
    """Make ``path`` end at a line boundary; True if it was changed.

    A last line without its newline is either complete JSON cut before the newline (kept: a newline
    is added, the reader already counts it) or a torn write (cut off: the reader skips it).
    """
    path = Path(path)
    if not path.exists() or path.stat().st_size == 0:
        return False
    with open(path, "rb+") as f:
        f.seek(0, os.SEEK_END)
        size = f.tell()
        # Find the last newline, reading backwards in blocks (records are a few hundred bytes).
        pos, block, last_nl = size, 1 << 14, -1
        while pos > 0 and last_nl < 0:
            start = max(0, pos - block)
            f.seek(start)
            chunk = f.read(pos - start)
            i = chunk.rfind(b"\n")
            if i >= 0:
                last_nl = start + i
            pos = start
        if last_nl == size - 1:
            return False
        f.seek(last_nl + 1)
        tail = f.read()
        if _parse_tail(tail) is not None:
            f.seek(0, os.SEEK_END)
            f.write(b"\n")
        else:
            f.truncate(last_nl + 1)
        f.flush()
        os.fsync(f.fileno())
    return True


class RecordWriter:
    """Appends records to a JSON-lines file, durable per record (flush + fsync).

    One writer per file: parallel workers send their records to the process that owns it.
    """

    def __init__(self, path: str | os.PathLike, validate: bool = True) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        repair_tail(self.path)
        self.validate = validate
        self._f = open(self.path, "a", encoding="utf-8")

    def write(self, record: Mapping[str, Any]) -> dict:
        """Append ``record``; returns it as a reader will get it back (plain JSON values)."""
        if self.validate:
            validate_record(record)
        line = json.dumps(dict(record), default=_json_default, ensure_ascii=False)
        self._f.write(line + "\n")
        self._f.flush()
        os.fsync(self._f.fileno())
        return json.loads(line)

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def __enter__(self) -> "RecordWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def iter_records(path: str | os.PathLike) -> Iterator[dict]:
    """Records of ``path`` in file order; a torn last line is skipped with a warning.

    A malformed line anywhere else means the file was edited or corrupted: ValueError with its
    line number, rather than a silently wrong summary.
    """
    path = Path(path)
    if not path.exists():
        return
    with open(path, "rb") as f:
        lines = f.read().split(b"\n")
    # After the last "\n" comes b"" (clean end) or an unterminated last line.
    for lineno, raw in enumerate(lines, start=1):
        if not raw.strip():
            continue
        record = _parse_tail(raw)
        if record is None:
            if lineno == len(lines):
                warnings.warn(f"{path}: skipping a truncated last line (interrupted run)", stacklevel=2)
                return
            raise ValueError(f"{path}:{lineno}: not a JSON object record")
        yield record


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
    """Keep the first record of each (policy, suite, instruction mode, perturbation, seed)."""
    seen: set[tuple] = set()
    out = []
    for r in records:
        k = _key(r)
        if k not in seen:
            seen.add(k)
            out.append(dict(r))
    return out


def read_records(path: str | os.PathLike, unique: bool = True) -> list[dict]:
    """All records of ``path`` (first of each duplicate when ``unique``)."""
    records = list(iter_records(path))
    return dedupe(records) if unique else records


def read_manifest(results_dir: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """The settings of each policy row of a results directory (``MANIFEST_FILE``; ``rsb eval``
    writes it), or nothing when it has none (``lerobot-eval``)."""
    path = Path(results_dir) / MANIFEST_FILE
    return json.loads(path.read_text()).get("runs", {}) if path.exists() else {}


def completed_seeds(
    path: str | os.PathLike,
    suite_id: str | None = None,
    instruction_mode: str | None = None,
    policy: str | None = None,
) -> set[int]:
    """Seeds already recorded in ``path`` (optionally for one suite / mode / policy): skip them on resume."""
    out = set()
    for r in iter_records(path):
        if suite_id is not None and r.get("suite_id") != suite_id:
            continue
        if instruction_mode is not None and r.get("instruction_mode") != instruction_mode:
            continue
        if policy is not None and r.get("policy") != policy:
            continue
        out.add(int(r["seed"]))
    return out
