"""Where records live: the files of a results directory, written so that a killed run loses nothing.

A results directory (``rsb eval --out``, ``lerobot-eval``'s ``records_dir``) holds the episode
records in ``RECORDS_FILE``, ``rsb backbone``'s answers in ``BACKBONE_FILE``, and the settings
each row was run with in ``MANIFEST_FILE`` (``rsb eval``, ``rsb backbone``).

Each record is appended, flushed and fsync'ed as its episode ends. A run killed mid-write leaves
at most one partial last line; the reader skips it and the writer cuts it off before appending, so
resuming (skip ``completed_seeds``, run the rest) yields the same records as an uninterrupted run.

A file edited or damaged by hand fails in one line naming the file and the line (:class:`RecordsError`,
:class:`ManifestError`), never with a wrong summary.
"""
from __future__ import annotations

import json
import os
import re
import warnings
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

from rsb_maniskill.evaluation.records import VERSION_FIELD, VersionMixError, dedupe, one_version, validate_record
from rsb_maniskill.outdirs import naming

RECORDS_FILE = "episodes.jsonl"
MANIFEST_FILE = "run.json"
BACKBONE_FILE = "backbone.jsonl"
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")  # what a file name of any system may not hold
SHOWN_CHARS = 40  # how much of a bad line an error quotes
FIX_LINE = "fix or delete that line (the other records are kept) and rerun"


class ManifestError(ValueError):
    """A results directory that does not fit this run: other settings, another benchmark version,
    or a ``MANIFEST_FILE`` that is not one."""


class RecordsError(ValueError):
    """A records file with a line that is no record: the file was edited or damaged."""


def safe_name(label: str) -> str:
    """A row or policy label as a file or directory name: each run of other characters than
    letters, digits, ``_ . -`` becomes one ``_`` (``"oracle (blank)"`` -> ``"oracle_blank"``,
    ``"pkg.mod:make"`` -> ``"pkg.mod_make"``); ``"policy"`` when nothing is left."""
    return _UNSAFE.sub("_", label).strip("_") or "policy"


MAX_FOLDER_CHARS = 120  # a results folder's name: far below the 255 bytes of common file systems


def folder_name(label: str, strict: bool = True) -> str:
    """The folder of a row label, one way: :func:`safe_name`, and for a label with characters
    beyond ASCII (dropped there) a digest of the whole label after it, so two such names never share
    a folder (``"🤖"`` -> ``"policy-…"``; ASCII names keep their folders). The label is taken in NFC
    (one spelling of "é"). ValueError, one line, when the name is too long to be a folder (not
    ``strict``: cut, the digest after it)."""
    import hashlib
    import unicodedata

    label = unicodedata.normalize("NFC", label)
    name = safe_name(label)
    digest = hashlib.sha256(label.encode()).hexdigest()[:8]
    if not label.isascii() or not name.strip("."):  # ("." and ".." are folders already: results/.. is ./)
        name = f"{name.strip('.') or 'policy'}-{digest}"
    if len(name) > MAX_FOLDER_CHARS and not strict:
        return f"{name[:MAX_FOLDER_CHARS - 9]}-{digest}"
    if len(name) > MAX_FOLDER_CHARS:
        raise ValueError(f"the name {label[:30]!r}... is {len(label)} characters: too long for a results folder "
                         f"(at most {MAX_FOLDER_CHARS}); give a shorter --name, or --out")
    return name


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
        with naming(self.path):  # a full disk names the file (a torn line is cut off on the next open)
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
def iter_records(path: str | os.PathLike, check: Callable[[Mapping[str, Any]], None] | None = None
                 ) -> Iterator[dict]:
    """Records of ``path`` in file order; a torn last line is skipped with a warning.

    A malformed line anywhere else means the file was edited or corrupted: RecordsError naming the
    file and the line (``path:lineno: ...``), rather than a silently wrong summary; so does a
    record that ``check`` (e.g. ``records.validate_record``) refuses with a ValueError.
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
                warnings.warn(f"{path}: skipping its truncated last line (a run stopped mid-write; the next run "
                              "into this folder cuts it off)", stacklevel=2)
                return
            shown = raw[:SHOWN_CHARS].decode("utf-8", errors="replace") + ("..." if len(raw) > SHOWN_CHARS else "")
            raise RecordsError(f"{path}:{lineno}: not a JSON object record ({shown!r}): the file was edited or "
                               f"damaged; {FIX_LINE}")
        if check is not None:
            try:
                check(record)
            except ValueError as err:
                raise RecordsError(f"{path}:{lineno}: {err}; {FIX_LINE}") from None
        yield record


def read_records(path: str | os.PathLike, unique: bool = True) -> list[dict]:
    """All records of ``path`` (first of each duplicate when ``unique``); RecordsError naming the
    line of one that is no episode record (``records.validate_record``)."""
    records = list(iter_records(path, validate_record))
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
def _load_manifest(path: Path) -> dict[str, Any]:
    """``MANIFEST_FILE``'s content (empty sections when there is none); ManifestError naming the
    file when it is not JSON, or not a manifest."""
    if not path.exists():
        return {"runs": {}}
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise ManifestError(f"{path}: not valid JSON (line {err.lineno}, column {err.colno}: {err.msg}); restore it, "
                            "or delete it and the next run writes it anew") from None
    except UnicodeDecodeError:
        raise ManifestError(f"{path}: not a text file; restore it, or delete it and the next run writes it "
                            "anew") from None
    if not isinstance(manifest, dict) or not all(isinstance(v, dict) for v in manifest.values()):
        raise ManifestError(f"{path}: not the settings file of rsb eval (an object of sections, each "
                            "label -> settings); restore it, or delete it and the next run writes it anew")
    return manifest


def read_manifest(results_dir: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """The settings of each policy row of a results directory (``MANIFEST_FILE``; ``rsb eval``
    writes it), or nothing when it has none (``lerobot-eval``); ManifestError naming the file
    when it is damaged."""
    return _load_manifest(Path(results_dir) / MANIFEST_FILE).get("runs", {})


def folder_labels(results_dir: str | os.PathLike) -> list[str]:
    """The row labels ``MANIFEST_FILE`` of ``results_dir`` names, of every section (policies, backbones)."""
    path = Path(results_dir) / MANIFEST_FILE
    if not path.is_file():
        return []
    return [label for section in _load_manifest(path).values() for label in section]


def _has_records(out: Path, section: str, label: str, records: list[dict]) -> bool:
    """Whether ``out`` holds records of the row ``label`` of ``section``."""
    if section == "runs":
        return any(r.get("policy") == label for r in records)
    return any(r.get("backbone") == label for r in read_backbone_records(out / BACKBONE_FILE))


SETTINGS_FIELD = "settings_id"  # in each record of rsb eval: the digest of the settings it ran with


def settings_id(settings: Mapping[str, Any], keys: tuple[str, ...]) -> str:
    """A short digest of a row's ``keys`` settings: each record carries it (``SETTINGS_FIELD``), so
    a resume checks the records it extends even when ``MANIFEST_FILE`` is gone."""
    import hashlib

    text = json.dumps({k: settings.get(k) for k in keys}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _check_record_settings(out: Path, label: str, settings: Mapping[str, Any], keys: tuple[str, ...], section: str,
                           records: list[dict], also: tuple[str, ...] = ()) -> None:
    """The settings id the records of ``label`` carry against these settings' (what a resume checks
    when ``MANIFEST_FILE`` has no row for them, or one that was edited): ManifestError, one line.
    ``also``: other ids of the same settings (those an older version digested, its row's)."""
    if section == "runs":
        wanted = settings_id(settings, keys)
        other = [r for r in records if r.get("policy") == label and r.get(SETTINGS_FIELD) not in (None, wanted, *also)]
        if other:
            raise ManifestError(f"{out / RECORDS_FILE} holds {len(other)} episodes of {label!r} run with other "
                                f"settings than these ({', '.join(keys)}: settings id {other[0][SETTINGS_FIELD]} "
                                f"there, {wanted} now). Use the same settings to resume, or another --out / --name "
                                "for a new run.")


CODE_FIELD = "policy_factory"  # in a row of MANIFEST_FILE: where the policy's code lives ("module:attr")


def _check_code(out: Path, label: str, old: Mapping[str, Any], settings: Mapping[str, Any], section: str,
                records: list[dict]) -> None:
    """A resume extends records made by the same code: a name whose factory changed (a plugin's
    policy where a built-in was) is refused, one line. Rows of older versions name no factory."""
    had, now = old.get(CODE_FIELD), settings.get(CODE_FIELD)
    if had and now and had != now and _has_records(out, section, label, records):
        raise ManifestError(f"{out} holds episodes of {label!r} made by {had}, and {label!r} is now {now}: a resume "
                            "would pool two policies' episodes. Use another --out / --name for the new code.")


def check_manifest(out: Path, label: str, settings: Mapping[str, Any], *, keys: tuple[str, ...],
                   section: str = "runs", read_row: Callable[[Mapping[str, Any]], Mapping[str, Any]] = dict
                   ) -> str | None:
    """Record this row's settings in ``MANIFEST_FILE`` (under ``section``: ``runs`` for policies,
    ``backbones`` for ``rsb backbone``), or check that ``keys`` match those it was started with; the
    directory's records must be of this benchmark version (a table holds one). ManifestError, one
    line, otherwise; RecordsError for a damaged records file. ``read_row`` reads a row as ``settings``
    are given (a row an older version wrote with more in it); a row that matches so is kept as it is,
    and the records it made (their settings id, of the row as written) extend.

    A row started with other settings that recorded nothing (a run that failed before its first
    episode) locks nothing: its settings are replaced, and the returned note (one line) says so."""
    from rsb_maniskill.version import BENCHMARK_VERSION, code_commit, package_version

    records = read_records(out / RECORDS_FILE)
    try:
        one_version([*records, {VERSION_FIELD: BENCHMARK_VERSION}])
    except VersionMixError as err:
        raise ManifestError(f"{out / RECORDS_FILE}: {err}. Use another --out for this version's run.") from None
    path = out / MANIFEST_FILE
    manifest = _load_manifest(path)
    written = manifest.setdefault(section, {}).get(label)
    old = read_row(written) if written is not None else None
    note = None
    if old is not None:
        _check_code(out, label, old, settings, section, records)
        diff = [k for k in keys if old.get(k) != settings.get(k)]
        if not diff:
            _check_record_settings(out, label, settings, keys, section, records, also=(settings_id(written, keys),))
            return None
        shown = ", ".join(f"{k}: {old.get(k)!r} before, {settings.get(k)!r} now" for k in diff)
        if _has_records(out, section, label, records):
            raise ManifestError(f"{out} already holds episodes of {label!r} run with other settings ({shown}). "
                                "Use the same settings to resume, or another --out / --name for a new run.")
        note = f"{path}: {label!r} was started with other settings and recorded nothing; replaced ({shown})"
    _check_record_settings(out, label, settings, keys, section, records)
    manifest[section][label] = {**settings, "rsb_version": package_version(), "code_commit": code_commit()}
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(manifest, indent=2) + "\n")
    os.replace(tmp, path)
    return note


class RunStart:
    """What a run is about to add to ``out`` before its first episode (its ``MANIFEST_FILE`` row, an
    empty ``RECORDS_FILE``), so that :meth:`undo` can take it back when the run fails without
    recording one: a typo's failed run leaves the directory as it found it."""

    def __init__(self, out: Path) -> None:
        self.manifest, self.records = out / MANIFEST_FILE, out / RECORDS_FILE
        self.manifest_before = self.manifest.read_bytes() if self.manifest.exists() else None
        self.records_existed = self.records.exists()

    def undo(self, label: str) -> bool:
        """Restore ``MANIFEST_FILE`` (and drop an empty records file this run made) unless the
        directory now holds records of ``label``; True when it did."""
        if any(r.get("policy") == label for r in iter_records(self.records)):
            return False
        if self.manifest_before is None:
            self.manifest.unlink(missing_ok=True)
        elif self.manifest.read_bytes() != self.manifest_before:
            tmp = self.manifest.with_suffix(".json.tmp")
            tmp.write_bytes(self.manifest_before)
            os.replace(tmp, self.manifest)
        if not self.records_existed and self.records.exists() and self.records.stat().st_size == 0:
            self.records.unlink()
        return True
