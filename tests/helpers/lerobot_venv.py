"""LeRobot in its own virtual environment (its pins clash with ours), and a dataset read back by
content: the export, dataset-build and LeRobot-env tests share them."""
from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import os
import shutil
import subprocess
from pathlib import Path
from typing import Iterator

import pyarrow.parquet as pq
import pytest
from venvs import install, make_venv

REPO = Path(__file__).resolve().parents[2]
LEROBOT = "lerobot[dataset]==0.6.1"  # the current release; needs Python >= 3.12 and numpy 2
VENV = Path(os.environ.get("RSB_LEROBOT_VENV", REPO / ".cache" / "lerobot-0.6.1-venv"))


def read_data(root: Path) -> dict:
    """Every frame of a dataset, from all its data files (a merged export has one per shard)."""
    import pyarrow as pa

    files = sorted((root / "data").glob("chunk-*/file-*.parquet"))
    return pa.concat_tables([pq.read_table(f) for f in files]).to_pydict()


def fingerprint(root: Path) -> dict[str, str]:
    """Every file of a dataset by content (parquet by table, so writer metadata cannot hide a difference)."""
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file():
            rel = str(p.relative_to(root))
            data = str(pq.read_table(p).to_pydict()) if p.suffix == ".parquet" else p.read_bytes()
            out[rel] = hashlib.sha256(data if isinstance(data, bytes) else data.encode()).hexdigest()
    return out


def _python312() -> str | None:
    """A working Python >= 3.12 (PATH, then pyenv's installs: its shims only run the active one)."""
    cands = [shutil.which(f"python3.{m}") for m in (12, 13, 14)]
    cands += sorted(str(p) for p in Path.home().glob(".pyenv/versions/3.1[2-9]*/bin/python3"))
    for c in filter(None, cands):
        ok = subprocess.run([c, "-c", "import sys, venv; assert sys.version_info >= (3, 12)"], capture_output=True)
        if ok.returncode == 0:
            return c
    return None


@contextlib.contextmanager
def venv_lock(venv: Path = VENV) -> Iterator[None]:
    """Held while a venv is checked and built or added to: `make test` runs test files in parallel
    (pytest-xdist), and two workers must not build, or install into, one venv at once."""
    venv.parent.mkdir(parents=True, exist_ok=True)
    with open(venv.parent / f".{venv.name}.lock", "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


@functools.lru_cache(maxsize=None)  # checked once a test process: the check imports LeRobot, ~7 s
def _lerobot_python() -> Path:
    """Python of a virtual environment with LeRobot (built once, reused from $RSB_LEROBOT_VENV)."""
    with venv_lock():
        return _build_lerobot_python()


def _build_lerobot_python() -> Path:
    py = VENV / "bin" / "python"
    if py.exists() and subprocess.run([str(py), "-c", "import lerobot.datasets"], capture_output=True).returncode == 0:
        return py
    base = _python312()
    if base is None:
        pytest.skip("LeRobot 0.6 needs Python >= 3.12 and none is installed here")
    install(make_venv(VENV, base), LEROBOT)
    return py
