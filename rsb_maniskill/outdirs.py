"""Output directories, made and proven writable before a long job writes into them: a typo or a
read-only --out fails in one line at the start, not after minutes of work."""
from __future__ import annotations

import os
from pathlib import Path


def probe_writable(directory: str | os.PathLike) -> None:
    """OSError unless a file can be created in ``directory`` (which exists)."""
    probe = Path(directory) / f".write-probe{os.getpid()}"
    probe.touch()
    probe.unlink()


def writable_dir(path: str | os.PathLike) -> Path:
    """``path`` made (parents included) and proven writable; OSError otherwise."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    probe_writable(path)
    return path
