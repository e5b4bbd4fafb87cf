"""Where records live: the files of a results directory, written so that a killed run loses nothing.

A results directory (``rsb eval --out``, ``lerobot-eval``'s ``records_dir``) holds the episode
records in ``RECORDS_FILE``, ``rsb backbone``'s answers in ``BACKBONE_FILE``, and the settings
each row was run with in ``MANIFEST_FILE`` (``rsb eval``, ``rsb backbone``).

Each record is appended, flushed and fsync'ed as its episode ends. A run killed mid-write leaves
at most one partial last line; the reader skips it and the writer cuts it off before appending, so
resuming (skip ``completed_seeds``, run the rest) yields the same records as an uninterrupted run.
"""
from __future__ import annotations

import json
import os
import re
import warnings
from pathlib import Path
from typing import Any, Iterator, Mapping

from .records import VERSION_FIELD, dedupe, one_version, validate_record

RECORDS_FILE = "episodes.jsonl"
MANIFEST_FILE = "run.json"
BACKBONE_FILE = "backbone.jsonl"
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")  # what a file name of any system may not hold


class ManifestError(ValueError):
    """A results directory that does not fit this run: other settings, or another benchmark version."""


def safe_name(label: str) -> str:
    """A row or policy label as a file or directory name: each run of other characters than
    letters, digits, ``_ . -`` becomes one ``_`` (``"oracle (blank)"`` -> ``"oracle_blank"``,
    ``"pkg.mod:make"`` -> ``"pkg.mod_make"``); ``"policy"`` when nothing is left."""
    return _UNSAFE.sub("_", label).strip("_") or "policy"


# ---------------------------------------------------------------- writing
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

    One writer per file: parallel workers send their records to the process that owns it. Where
    writers in several processes share a file (LeRobot's vector envs), ``lock=True`` takes an
    exclusive file lock around each record (and repairs the tail under it).
    """

    def __init__(self, path: str | os.PathLike, validate: bool = True, lock: bool = False) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.validate, self.lock = validate, lock
        if not lock:
            repair_tail(self.path)
        self._f = open(self.path, "a", encoding="utf-8")

    def write(self, record: Mapping[str, Any]) -> dict:
        """Append ``record``; returns it as a reader will get it back (plain JSON values)."""
        if self.validate:
            validate_record(record)
        line = json.dumps(dict(record), default=_json_default, ensure_ascii=False)
        if not self.lock:
            self._append(line)
            return json.loads(line)
        import fcntl

        fcntl.flock(self._f, fcntl.LOCK_EX)
        try:
            repair_tail(self.path)
            self._append(line)
        finally:
            fcntl.flock(self._f, fcntl.LOCK_UN)
        return json.loads(line)

    def _append(self, line: str) -> None:
        self._f.write(line + "\n")
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()

    def __enter__(self) -> "RecordWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------- reading
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


def read_records(path: str | os.PathLike, unique: bool = True) -> list[dict]:
    """All records of ``path`` (first of each duplicate when ``unique``)."""
    records = list(iter_records(path))
    return dedupe(records) if unique else records


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


def backbone_record_key(record: Mapping[str, Any]) -> tuple:
    """A backbone record's identity: the same question of the same backbone row."""
    return record.get("backbone"), record.get("suite_id"), record.get("instruction_mode"), int(record["seed"])


def read_backbone_records(path: str | os.PathLike) -> list[dict]:
    """The records of ``path`` (a ``backbone.jsonl``), the first of each duplicate."""
    seen, out = set(), []
    for r in iter_records(path):
        if backbone_record_key(r) not in seen:
            seen.add(backbone_record_key(r))
            out.append(r)
    return out


# ---------------------------------------------------------------- the manifest
def read_manifest(results_dir: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """The settings of each policy row of a results directory (``MANIFEST_FILE``; ``rsb eval``
    writes it), or nothing when it has none (``lerobot-eval``)."""
    path = Path(results_dir) / MANIFEST_FILE
    return json.loads(path.read_text()).get("runs", {}) if path.exists() else {}


def check_manifest(out: Path, label: str, settings: Mapping[str, Any], *, keys: tuple[str, ...],
                   section: str = "runs") -> None:
    """Record this row's settings in ``MANIFEST_FILE`` (under ``section``: ``runs`` for policies,
    ``backbones`` for ``rsb backbone``), or check that ``keys`` match those it was started with; the
    directory's records must be of this benchmark version (a table holds one). ManifestError, one
    line, otherwise."""
    from rsb_maniskill.version import BENCHMARK_VERSION, code_commit, package_version

    try:
        one_version([*read_records(out / RECORDS_FILE), {VERSION_FIELD: BENCHMARK_VERSION}])
    except ValueError as err:
        raise ManifestError(f"{out / RECORDS_FILE}: {err}. Use another --out for this version's run.") from None
    path = out / MANIFEST_FILE
    manifest = json.loads(path.read_text()) if path.exists() else {"runs": {}}
    old = manifest.setdefault(section, {}).get(label)
    if old is not None:
        diff = [k for k in keys if old.get(k) != settings.get(k)]
        if diff:
            shown = ", ".join(f"{k}: {old.get(k)!r} before, {settings.get(k)!r} now" for k in diff)
            raise ManifestError(f"{out} already holds episodes of {label!r} run with other settings ({shown}). "
                                "Use the same settings to resume, or another --out / --name for a new run.")
        return
    manifest[section][label] = {**settings, "rsb_version": package_version(), "code_commit": code_commit()}
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(manifest, indent=2) + "\n")
    os.replace(tmp, path)
