"""Third-party tools in virtual environments of their own (LeRobot 0.6 needs Python >= 3.12 and
numpy 2; openpi's client numpy < 2), built with uv: it installs in parallel, so LeRobot's venv
(CUDA torch, 6.5 GB) takes about 36 s to build where pip took 140 s on a fresh clone."""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from uv import find_uv_bin

UV = find_uv_bin()


def make_venv(venv: Path, python: str) -> Path:
    """A new, empty ``venv`` (anything there before is removed) on ``python``; its interpreter."""
    subprocess.run([UV, "venv", "-q", "--clear", "--python", python, str(venv)], check=True)
    return venv / "bin" / "python"


def install(py: Path, *args: str, timeout: float = 1500) -> None:
    """``uv pip install args`` into the venv of ``py``; a failure fails the test with uv's message."""
    # --compile-bytecode, as pip does: under PYTHONDONTWRITEBYTECODE (CI's) each process would
    # otherwise compile LeRobot's and torch's Python anew, 11 s more per `import lerobot`
    res = subprocess.run([UV, "pip", "install", "-q", "--compile-bytecode", "--python", str(py), *args],
                         capture_output=True, text=True, timeout=timeout)
    if res.returncode != 0:
        pytest.fail(f"uv pip install {' '.join(args)} failed:\n{res.stderr[-3000:]}")
