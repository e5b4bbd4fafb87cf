"""Output directories, made and proven writable before a long job writes into them: a typo or a
read-only --out fails in one line at the start, not after minutes of work."""
from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path
from typing import Iterator


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


# What to do when writing output fails for a reason of the file system, not of the program.
_WRITE_FIXES = {
    errno.ENOSPC: "no space left on the device: free some space or choose another --out",
    errno.EDQUOT: "disk quota exceeded: free some space or choose another --out",
    errno.EROFS: "the file system is read-only: choose a writable --out",
    errno.EACCES: "permission denied: fix the folder's permissions or choose another --out",
    errno.EPERM: "operation not permitted: fix the folder's permissions or choose another --out",
    errno.ENAMETOOLONG: "a name is too long for the file system: choose a shorter --out / --name",
}


def write_error_line(err: BaseException) -> str | None:
    """One line for an OSError met writing output (full disk, read-only folder, name too long, no
    permission), naming the path and the fix; None for any other error."""
    if not isinstance(err, OSError) or err.errno not in _WRITE_FIXES:
        return None
    where = f"{err.filename}: " if err.filename else ""
    return f"cannot write {where}{_WRITE_FIXES[err.errno]}"


@contextlib.contextmanager
def naming(path: str | os.PathLike) -> Iterator[None]:
    """An OSError of the block that names no file (a write to an open file) names ``path``."""
    try:
        yield
    except OSError as err:
        if err.filename is None and err.errno is not None:
            raise OSError(err.errno, err.strerror or os.strerror(err.errno), str(path)) from err
        raise
