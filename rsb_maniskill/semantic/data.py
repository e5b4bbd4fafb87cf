"""Where GSM8K and MMLU-Pro come from: a data directory, else the pinned Hugging Face hub copy.

Order: ``data_dir`` argument, else ``$RSB_DATA_DIR`` -- a directory holding
``gsm8k/{train,test}.jsonl`` (GSM8K's original format) and ``mmlu_pro/data/test-*.parquet`` (the
hub's layout) -- else the hub files at pinned revisions (cached by huggingface_hub, so the second
run is offline), else :class:`DataNotFoundError` naming both ways. A machine without network gets
that error within seconds: the hub is asked once per process, with a deadline, before
huggingface_hub and its retries are (``rsb_maniskill.network``). Readers return raw row dicts
with their origin ("file, line N") so that every later error can point at the record.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from rsb_maniskill import network
from rsb_maniskill.semantic.errors import DataNotFoundError, EmptyDataError, SemanticDataError

ENV_VAR = "RSB_DATA_DIR"

# Pinned hub revisions (commit SHAs of the dataset repositories), so that every machine builds
# the same pools. Found in public code pinning these datasets (lighteval / lm-eval configs).
GSM8K_REPO = "openai/gsm8k"
GSM8K_REVISION = "cc7b047b6e5bb11b4f1af84efc572db110a51b3c"
GSM8K_FILES = {"train": "main/train-00000-of-00001.parquet", "test": "main/test-00000-of-00001.parquet"}
MMLU_PRO_REPO = "TIGER-Lab/MMLU-Pro"
MMLU_PRO_REVISION = "b189ec765aa7ed75c8acfea42df31fdae71f97be"
MMLU_PRO_FILE = "data/test-00000-of-00001.parquet"  # the test split: 12,032 questions (MIT)
GSM8K_SPLITS = ("train", "test")

Row = dict[str, Any]
MMLU_PRO_FILE_IN_DIR = f"mmlu_pro/{MMLU_PRO_FILE}"


def resolve_data_dir(data_dir: str | os.PathLike | None) -> Path | None:
    """The data directory to use (argument, else $RSB_DATA_DIR), or None for the hub."""
    if data_dir is not None and str(data_dir) != "":
        return Path(data_dir).expanduser()
    env = os.environ.get(ENV_VAR, "")
    return Path(env).expanduser() if env else None


def _how_to_provide(what: str) -> str:
    return (f"{what} not found. Provide it either way: (1) a data directory passed as data_dir / "
            f"--data-dir or in ${ENV_VAR}, holding gsm8k/{{train,test}}.jsonl and "
            f"{MMLU_PRO_FILE_IN_DIR} (the hub's layout); or (2) the Hugging Face hub "
            f"copy ({GSM8K_REPO}@{GSM8K_REVISION[:12]}, {MMLU_PRO_REPO}@{MMLU_PRO_REVISION[:12]}): run "
            f"`rsb data download` once on a machine with network (needs pip install 'rsb_maniskill[hub]'). "
            f"`rsb doctor` shows what this machine has.")


REFILL_HINT = (f"fetch a full copy with `rsb data download --out DIR` and pass --data-dir DIR (or set "
               f"{ENV_VAR}=DIR), or point --data-dir / {ENV_VAR} at another full copy (a broken file in the hub "
               f"cache: delete it, then `rsb data download`)")


def empty_data_error(path: str | os.PathLike, why: str, what: str = "") -> EmptyDataError:
    """The error for a data file that is there but holds no usable question (``why``: what is
    wrong with it): it names the file and how to replace it, on one line."""
    what = f"{what} " if what else ""
    return EmptyDataError(f"{path} holds no usable {what}questions ({why}), so the pools built from it would be "
                          f"empty: {REFILL_HINT}")


def _no_rows(path: Path) -> str:
    """Why a file gave no record: nothing in it at all, or blank lines only."""
    return "the file is empty" if path.stat().st_size == 0 else "no record in it, only blank lines"


# ---------------------------------------------------------------------------------------------
# data directory readers (original formats)


def read_gsm8k_jsonl(path: Path) -> list[Row]:
    """GSM8K rows ``{"question", "answer", "origin"}``; malformed lines raise with file and line."""
    rows: list[Row] = []
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, 1):
            if not line.strip():
                continue
            try:
                obj = json.loads(line)
            except json.JSONDecodeError as err:
                raise SemanticDataError(path, lineno, f"invalid JSON ({err.msg})") from None
            if not isinstance(obj, dict):
                raise SemanticDataError(path, lineno, "expected a JSON object with 'question' and 'answer'")
            for key in ("question", "answer"):
                if not isinstance(obj.get(key), str) or not obj[key].strip():
                    raise SemanticDataError(path, lineno, f"missing or empty field {key!r}")
            rows.append({"question": obj["question"], "answer": obj["answer"], "origin": f"{path}, line {lineno}"})
    if not rows:
        raise empty_data_error(path, _no_rows(path), "GSM8K")
    return rows


def read_mmlu_pro_rows(path: Path) -> list[Row]:
    """MMLU-Pro rows ``{"question", "choices", "answer", "subject", "src", "id", "origin"}`` from the hub's
    parquet file; a malformed row raises with file and row."""
    rows: list[Row] = []
    for i, rec in enumerate(read_parquet_rows(path, "MMLU-Pro"), 1):
        q, opts, ans = rec.get("question"), rec.get("options"), rec.get("answer_index")
        if not isinstance(q, str) or not q.strip():
            raise SemanticDataError(path, i, f"row {i}: missing or empty question")
        if not isinstance(opts, list) or not opts or not all(isinstance(o, str) for o in opts):
            raise SemanticDataError(path, i, f"row {i}: 'options' must be a list of texts, got {opts!r}")
        if not isinstance(ans, int) or not 0 <= ans < len(opts):
            raise SemanticDataError(path, i, f"row {i}: answer_index must be 0-{len(opts) - 1}, got {ans!r}")
        letter = rec.get("answer")
        if letter is not None and letter != "ABCDEFGHIJ"[ans]:
            raise SemanticDataError(path, i, f"row {i}: answer {letter!r} disagrees with answer_index {ans}")
        rows.append({"question": q, "choices": opts, "answer": ans, "subject": str(rec.get("category", "")),
                     "src": str(rec.get("src", "")), "id": rec.get("question_id"), "origin": f"{path}, row {i}"})
    if not rows:
        raise empty_data_error(path, "a parquet table without rows", "MMLU-Pro")
    return rows


def _gsm8k_dir_file(root: Path, split: str) -> Path:
    path = root / "gsm8k" / f"{split}.jsonl"
    if not path.is_file():
        raise DataNotFoundError(f"{path} does not exist (data directory {root}). " + _how_to_provide("GSM8K"))
    return path


def _mmlu_pro_dir_files(root: Path) -> list[Path]:
    files = sorted((root / "mmlu_pro" / "data").glob("test-*.parquet"))
    if not files:
        raise DataNotFoundError(f"no MMLU-Pro file {root / MMLU_PRO_FILE_IN_DIR} (data directory {root}). "
                                + _how_to_provide("MMLU-Pro"))
    return files


# ---------------------------------------------------------------------------------------------
# hub


def hub_file(repo: str, filename: str, revision: str, *, allow_network: bool = True) -> Path:
    """Path of a pinned hub file: the local cache first (a file lookup: huggingface_hub's own
    ``local_files_only`` download reaches for the network all the same), the network second."""
    try:
        import huggingface_hub
        from huggingface_hub import constants
    except ImportError as err:  # pragma: no cover - a core dependency
        raise DataNotFoundError(_how_to_provide(repo) + f" (huggingface_hub unavailable: {err})") from None
    cached = huggingface_hub.try_to_load_from_cache(repo, filename, revision=revision, repo_type="dataset")
    if isinstance(cached, str):
        return Path(cached)
    why = "network not allowed" if not allow_network else network.unreachable(constants.ENDPOINT)
    if why:
        raise DataNotFoundError(_how_to_provide(repo) + f" (not in the hub cache; {why})") from None
    try:
        return Path(huggingface_hub.hf_hub_download(repo, filename, repo_type="dataset", revision=revision))
    except Exception as err:  # noqa: BLE001 - offline, DNS, HTTP: all mean "not available"
        raise DataNotFoundError(_how_to_provide(repo) + f" (hub download of {repo}/{filename} failed: "
                                f"{type(err).__name__}: {err})") from None


def read_parquet_rows(path: Path, what: str = "") -> list[Row]:
    """Rows of a parquet file as dicts (needs the optional ``hub`` extra: pyarrow); an empty or
    unreadable file (a cut download) raises :class:`EmptyDataError`."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise DataNotFoundError(f"reading the hub file {path} needs pyarrow: pip install 'rsb_maniskill[hub]', "
                                f"or use a data directory via ${ENV_VAR}.") from None
    try:
        return pq.read_table(path).to_pylist()
    except (pa.ArrowException, OSError):
        why = _no_rows(path) if path.stat().st_size == 0 else "not a readable parquet file: a cut download?"
        raise empty_data_error(path, why, what) from None


def _gsm8k_hub_rows(split: str) -> list[Row]:
    path = hub_file(GSM8K_REPO, GSM8K_FILES[split], GSM8K_REVISION)
    rows = []
    for i, rec in enumerate(read_parquet_rows(path, "GSM8K"), 1):
        for key in ("question", "answer"):
            if not isinstance(rec.get(key), str) or not rec[key].strip():
                raise SemanticDataError(path, i, f"row {i}: missing or empty field {key!r}")
        rows.append({"question": rec["question"], "answer": rec["answer"], "origin": f"{path}, row {i}"})
    if not rows:
        raise empty_data_error(path, "a parquet table without rows", "GSM8K")
    return rows


# ---------------------------------------------------------------------------------------------
# public entry points


def gsm8k_rows(split: str, data_dir: str | os.PathLike | None = None) -> list[Row]:
    """Raw GSM8K rows of ``split`` ("train" or "test") from the first source that has them."""
    if split not in GSM8K_SPLITS:
        raise ValueError(f"unknown GSM8K split {split!r}; valid: {', '.join(GSM8K_SPLITS)}")
    root = resolve_data_dir(data_dir)
    if root is not None:
        return read_gsm8k_jsonl(_gsm8k_dir_file(root, split))
    return _gsm8k_hub_rows(split)


def mmlu_pro_rows(data_dir: str | os.PathLike | None = None) -> list[Row]:
    """All raw MMLU-Pro test rows from the first source that has them."""
    root = resolve_data_dir(data_dir)
    paths = _mmlu_pro_dir_files(root) if root is not None else [
        hub_file(MMLU_PRO_REPO, MMLU_PRO_FILE, MMLU_PRO_REVISION)]
    return [row for path in paths for row in read_mmlu_pro_rows(path)]


def data_source_label(data_dir: str | os.PathLike | None = None) -> str:
    """Human-readable description of where data would be read from (for `rsb stats`)."""
    root = resolve_data_dir(data_dir)
    return f"directory {root}" if root is not None else f"hub cache ({GSM8K_REPO}, {MMLU_PRO_REPO}, pinned)"


def download_hub_data(export_dir: str | os.PathLike | None = None) -> dict[str, Path]:
    """Fetch (or find cached) every pinned hub file; optionally write them out in the original
    formats under ``export_dir`` so that it can serve as ``$RSB_DATA_DIR`` offline."""
    paths: dict[str, Path] = {}
    for split, fn in GSM8K_FILES.items():
        paths[f"gsm8k/{split}"] = hub_file(GSM8K_REPO, fn, GSM8K_REVISION)
    paths["mmlu_pro"] = hub_file(MMLU_PRO_REPO, MMLU_PRO_FILE, MMLU_PRO_REVISION)
    if export_dir is not None:
        root = Path(export_dir)
        for split in GSM8K_SPLITS:
            out = root / "gsm8k" / f"{split}.jsonl"
            out.parent.mkdir(parents=True, exist_ok=True)
            with open(out, "w", encoding="utf-8") as fh:
                for rec in read_parquet_rows(paths[f"gsm8k/{split}"]):
                    fh.write(json.dumps({"question": rec["question"], "answer": rec["answer"]}) + "\n")
        out = root / MMLU_PRO_FILE_IN_DIR
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(paths["mmlu_pro"], out)  # the hub's file as it is: the directory layout is the hub's
    return paths
