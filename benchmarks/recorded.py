"""Recorded figures: every benchmark writes what it measured to ``benchmarks/results/NAME.json``.

A figure a page quotes as measured comes from one of these files (committed beside the benchmark), so
that a reader can see the command, the date, the commit and the machine behind it, and a test can
check the page against it. A benchmark calls :func:`write` once at the end:

    from recorded import write  # benchmarks/ is on sys.path when a script in it runs
    write("eval_throughput", {"state_env_steps_per_s": 412.0, ...})

``--record-to DIR`` style overrides are left to the caller (``out_dir=``); the default folder is
``benchmarks/results`` of this checkout. :func:`read` loads a recorded file (tests, docs).

How a page quotes a recorded figure (``python scripts/render_figures.py`` renders every marked region of
README.md and docs/*.md from these files; ``tests/acceptance/test_docs_figures.py`` fails when a region
differs from its file, so re-record, re-render, commit both):

- a table: put ``table(columns, rows)`` in the figures (``{"table": ...}``, or several under ``"tables"``),
  its cells the strings the page shows, and mark the page
  ``<!-- figures: NAME -->`` / ``<!-- figures: NAME TABLE -->`` ... ``<!-- /figures -->``: the region becomes
  the table and a line naming the file, command, date, commit, machine and load;
- one value: ``<!-- fig: NAME KEY FORMAT -->0.52<!-- /fig -->`` (KEY a dotted path into the figures,
  FORMAT a Python format spec such as ``.2f`` or ``,.0f``; ``<!-- fig: NAME @date -->`` the date,
  ``@source`` the short provenance).

A figure measured in an earlier run whose output was not kept is written once with
:func:`write_earlier`, with the date, commit and machine the page gave (``recorded_from`` says so);
``python benchmarks/record_docs_figures.py`` re-records every figure the pages quote that this machine
can measure.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any, Mapping

RESULTS_DIR = Path(__file__).resolve().parent / "results"
ROOT = RESULTS_DIR.parent.parent


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _gpu() -> str:
    """The first NVIDIA GPU's name, or "none"."""
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "none"
    names = [line.strip() for line in out.stdout.splitlines() if line.strip()]
    return names[0] if out.returncode == 0 and names else "none"


LOAD_AT_START = os.getloadavg()[0] if hasattr(os, "getloadavg") else None  # this module imported: the run began


def machine() -> dict[str, Any]:
    """Where the figures were measured: cores, CPU, memory, GPU, and the 1-minute load at start and end
    (a figure measured beside other work reads differently from one on an idle machine)."""
    try:
        memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        memory = None
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {"cores": cores, "cpu": _cpu_model(), "memory_gib": None if memory is None else round(memory, 1),
            "gpu": _gpu(), "load_1min_start": LOAD_AT_START,
            "load_1min_end": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
            "python": platform.python_version(), "platform": platform.platform()}


def write(name: str, figures: Mapping[str, Any], *, command: str | None = None, notes: str = "",
          out_dir: str | os.PathLike | None = None) -> Path:
    """Write ``figures`` (JSON-able) as ``NAME.json`` with the command, date, commit and machine; returns
    the path (printed too, so a reader of the benchmark's output knows where its figures went)."""
    if not name or "/" in name or name.startswith("."):
        raise ValueError(f"a recorded benchmark's name is a plain file stem, got {name!r}")
    folder = Path(out_dir) if out_dir is not None else RESULTS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    body = {
        "name": name,
        "command": command or " ".join(shlex.quote(a) for a in ["python", *_script_argv()]),
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "commit": _git("rev-parse", "--short=12", "HEAD") or "unknown",
        # the code measured differs from the commit (not the recorded files: a run of several benchmarks
        # rewrites them as it goes)
        "dirty": bool(_git("status", "--porcelain", "--untracked-files=no", "--", "rsb_maniskill", "benchmarks",
                           ":(exclude)benchmarks/results")),
        "machine": machine(),
        "figures": dict(figures),
    }
    if notes:
        body["notes"] = notes
    path = folder / f"{name}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(body, indent=2, sort_keys=False) + "\n", encoding="utf-8")
    tmp.replace(path)  # never a half-written file in place of a good one
    print(f"recorded: {path}", flush=True)
    return path


def table(columns: list[str], rows: list[list[Any]], align: str | None = None) -> dict[str, Any]:
    """A table a page renders as Markdown: ``align`` one letter a column (``l`` left, ``r`` right, ``c``
    centred; default: the first left, the rest right); cells are shown as ``str(cell)``, so format them here."""
    align = align or "l" + "r" * (len(columns) - 1)
    if len(align) != len(columns) or any(len(row) != len(columns) for row in rows):
        raise ValueError(f"a table of {len(columns)} columns needs that many alignments and cells a row")
    return {"columns": list(columns), "align": align, "rows": [[str(c) for c in row] for row in rows]}


def write_earlier(name: str, figures: Mapping[str, Any], *, command: str, date: str, commit: str,
                  machine: Mapping[str, Any], recorded_from: str, notes: str = "",
                  out_dir: str | os.PathLike | None = None) -> Path:
    """Record figures measured in an earlier run whose own output was not kept (a lent GPU box, a long
    training): the date, commit and machine are the ones the page gave, and ``recorded_from`` says where
    the figures were taken from. Such a file is not re-recorded by this checkout's benchmarks."""
    folder = Path(out_dir) if out_dir is not None else RESULTS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    body = {"name": name, "command": command, "date": date, "commit": commit, "dirty": False,
            "machine": {"cores": None, "cpu": None, "memory_gib": None, "gpu": "none", "load_1min_start": None,
                        "load_1min_end": None, **machine},
            "recorded_from": recorded_from, "figures": dict(figures)}
    if notes:
        body["notes"] = notes
    path = folder / f"{name}.json"
    path.write_text(json.dumps(body, indent=2) + "\n", encoding="utf-8")
    return path


def _script_argv() -> list[str]:
    argv = list(sys.argv)
    if argv and argv[0]:
        try:
            argv[0] = str(Path(argv[0]).resolve().relative_to(ROOT))
        except ValueError:
            pass
    return argv


def read(name: str, folder: str | os.PathLike | None = None) -> dict[str, Any]:
    """A recorded file's content (``figures`` and where they came from)."""
    path = Path(folder) if folder is not None else RESULTS_DIR
    return json.loads((path / f"{name}.json").read_text(encoding="utf-8"))
