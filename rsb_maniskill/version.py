"""Which benchmark and which code: the benchmark version, the package version, the code commit.

The **benchmark version** (``RSB-MS X.Y``) names the episodes: any change to what a suite's
episodes are (question, options, letters, option -> candidate map, instruction, candidates,
layout) bumps it, and nothing else does. Results of two benchmark versions are not comparable,
so every output carries it (records, summaries, results.json, report.html, demo files, datasets)
and ``rsb report`` refuses to pool them. docs/versions.md lists what each version changed;
``rsb_maniskill/audit/golden_episodes.json`` pins the episodes of this one (``rsb verify``).

The **package version** (``rsb_maniskill``) follows the code: a release that changes no episode
keeps the benchmark version. It and the dependency pins have one owner, ``pyproject.toml``: read
from the source checkout the package runs from, else from the installed package's metadata.
"""
from __future__ import annotations

import re
import subprocess
from functools import lru_cache
from importlib import metadata
from pathlib import Path

BENCHMARK = "RSB-MS"  # RoboSemanticBench on ManiSkill: not the RoboTwin release's episodes
BENCHMARK_VERSION = "1.1"
UNVERSIONED = "unversioned"  # what outputs written before benchmark versions existed are
DISTRIBUTION = "rsb_maniskill"
_ROOT = Path(__file__).resolve().parent.parent  # the source checkout, when the package runs from one


def benchmark_label(version: str = BENCHMARK_VERSION) -> str:
    """``"1.0"`` -> ``"RSB-MS 1.0"``; outputs written before versions existed -> ``"unversioned"``."""
    return version if version == UNVERSIONED else f"{BENCHMARK} {version}"


@lru_cache(maxsize=1)
def package_version() -> str:
    """The ``rsb_maniskill`` version: the source checkout's ``pyproject.toml`` when the package runs
    from one (an editable install's metadata keeps the version it was installed at), else the
    installed package's metadata; ``"unknown"`` when neither says."""
    pyproject = _ROOT / "pyproject.toml"
    if pyproject.is_file():
        found = re.search(r'^name = "rsb_maniskill"\nversion = "([^"]+)"', pyproject.read_text(), re.M)
        if found:
            return found[1]
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "unknown"


@lru_cache(maxsize=1)
def code_commit() -> str | None:
    """The git commit of the source tree this package runs from, ``-dirty`` when tracked files
    differ from it; None when it is not a git checkout (a wheel install) or git is missing."""
    root = _ROOT
    if not (root / ".git").exists():
        return None
    try:
        def git(*args: str) -> str:
            return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=5,
                                  check=True).stdout.strip()
        commit = git("rev-parse", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("-dirty" if dirty else "")


def requirements(extras: tuple[str, ...] = ()) -> dict[str, str]:
    """The package's dependency pins, ``{"mani-skill": "==3.0.1", ...}`` (core, plus ``extras``),
    from its metadata; empty when the package is not installed. A distribution pinned by the
    core and by an extra (numpy) gets both."""
    from packaging.requirements import Requirement
    from packaging.specifiers import SpecifierSet

    try:
        reqs = metadata.requires(DISTRIBUTION) or []
    except metadata.PackageNotFoundError:
        return {}
    out: dict[str, str] = {}
    for text in reqs:
        req = Requirement(text)
        if req.marker is not None and not any(req.marker.evaluate({"extra": e}) for e in extras):
            continue
        name = req.name.lower().replace("_", "-")
        if req.specifier:
            out[name] = str(SpecifierSet(out.get(name, "")) & req.specifier)
    return out


def version_fields() -> dict[str, str | None]:
    """What every results file and dataset says about its provenance."""
    return {"benchmark": BENCHMARK, "benchmark_version": BENCHMARK_VERSION, "rsb_maniskill_version": package_version(),
            "code_commit": code_commit()}


def code_label() -> str:
    """``"rsb_maniskill 0.2.0 (0123abcd4567-dirty)"``: the package and its short commit, when known."""
    commit = code_commit()
    short = f" ({commit[:12]}{'-dirty' if commit.endswith('-dirty') else ''})" if commit else ""
    return f"rsb_maniskill {package_version()}{short}"


def version_line() -> str:
    """``rsb --version``: the package and the benchmark."""
    return f"{code_label()}, benchmark {benchmark_label()}"
