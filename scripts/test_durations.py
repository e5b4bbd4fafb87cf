"""Write ``tests/durations.json``: what each test and each test file cost in one whole-suite run.

``tests/conftest.py`` reads the file to start the costliest files first (``make test`` hands whole files
to its workers, ``--dist loadfile``), so that no long file starts last and runs alone at the end. Made
from the JUnit XML of a run (each test's setup, call and teardown) or from the text of a
``--durations 0`` run (its setup, call and teardown lines, summed per test):

    .venv/bin/python -m pytest -ra -n 3 --dist loadfile --no-loadscope-reorder --junitxml=/tmp/junit.xml \\
        --durations 0 | tee /tmp/test.log
    python scripts/test_durations.py /tmp/junit.xml --commit 955dfa3 --load "1-min load 2-4 (idle)"
    python scripts/test_durations.py /tmp/test.log ...    # the same from the --durations 0 text

A module fixture's cost falls on the first test of its file: the per-file totals are the figures the
order needs, a single test's figure is what it paid in that run. ``--top N`` prints the N costliest
tests and files (the file is written only with ``--write``, default ``tests/durations.json``; from a JUnit
XML it also records the suite's wall time and counts in ``benchmarks/results/test_suite.json``, which
README.md's Tests section quotes).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "tests" / "durations.json"
# `--durations 0`'s lines: "12.34s call     tests/x/test_y.py::test_z[a]"
DURATION_LINE = re.compile(r"^\s*(\d+(?:\.\d+)?)s (setup|call|teardown)\s+(\S.*?)\s*$")


def _nodeid_of(classname: str, name: str) -> str:
    """A JUnit testcase's pytest node id: ``classname`` is the dotted module path, then any classes."""
    parts = classname.split(".")
    for cut in range(len(parts), 0, -1):
        path = "/".join(parts[:cut]) + ".py"
        if (ROOT / path).is_file():
            return "::".join([path, *parts[cut:], name])
    return "/".join(parts) + ".py::" + name  # a file gone since the run: the usual layout


def from_junit(path: Path) -> dict[str, float]:
    """Test id -> seconds (JUnit's ``time``: setup, call and teardown, pytest's default report)."""
    seconds: dict[str, float] = defaultdict(float)
    for case in ET.parse(path).getroot().iter("testcase"):
        classname = case.get("classname") or ""
        if not classname.startswith("tests."):  # pytest's own entries (an internal error), not a test
            continue
        seconds[_nodeid_of(classname, case.get("name", ""))] += float(case.get("time") or 0)
    return dict(seconds)


def junit_counts(path: Path) -> dict[str, int]:
    """The run's counts as JUnit's testsuite records them: tests, skipped, failed (failures + errors)."""
    suite = next(ET.parse(path).getroot().iter("testsuite"), None)
    if suite is None:
        return {}
    count = {k: int(suite.get(k) or 0) for k in ("tests", "skipped", "failures", "errors")}
    return {"tests": count["tests"], "skipped": count["skipped"], "failed": count["failures"] + count["errors"]}


def junit_wall_seconds(path: Path) -> float | None:
    """The run's wall time, as JUnit's testsuite records it."""
    suite = next(ET.parse(path).getroot().iter("testsuite"), None)
    return None if suite is None or suite.get("time") is None else float(suite.get("time"))


def from_durations_text(path: Path) -> dict[str, float]:
    """Test id -> seconds, summed over the setup, call and teardown lines of a ``--durations 0`` run."""
    seconds: dict[str, float] = defaultdict(float)
    for line in path.read_text(errors="replace").splitlines():
        m = DURATION_LINE.match(line)
        if m:
            seconds[m.group(3)] += float(m.group(1))
    if not seconds:
        raise SystemExit(f"{path}: no '--durations' lines (run pytest with --durations 0, or give the --junitxml)")
    return dict(seconds)


def text_wall_seconds(path: Path) -> float | None:
    """The run's wall time from pytest's last summary line ("... in 2423.51s (0:40:23)")."""
    found = re.findall(r"(?:passed|failed|error).* in (\d+(?:\.\d+)?)s\b", path.read_text(errors="replace"))
    return float(found[-1]) if found else None


def per_file(tests: dict[str, float]) -> dict[str, float]:
    files: dict[str, float] = defaultdict(float)
    for nodeid, s in tests.items():
        files[nodeid.split("::", 1)[0]] += s
    return dict(files)


def _machine(load: str) -> dict:
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    try:
        memory = round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError, AttributeError):
        memory = None
    return {"cores": cores, "memory_gib": memory, "load": load}


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=ROOT, capture_output=True,
                              text=True, timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def build(tests: dict[str, float], *, commit: str, date: str, command: str, load: str, notes: str,
          wall_seconds: float | None = None, fill: dict[str, float] | None = None) -> dict:
    """The durations file's content. ``fill``: seconds of files the run did not reach (an earlier
    measurement), after the run's own files whatever their figures, and named in ``filled_files``."""
    files = per_file(tests)
    filled = {f: float(s) for f, s in (fill or {}).items() if f not in files}
    ranked = sorted(files.items(), key=lambda kv: (-kv[1], kv[0])) + \
        sorted(filled.items(), key=lambda kv: (-kv[1], kv[0]))
    body = {
        "commit": commit, "date": date, "command": command, "machine": _machine(load), "notes": notes,
        "wall_seconds": None if wall_seconds is None else round(wall_seconds, 1),
        "test_seconds": round(sum(tests.values()), 1), "tests_measured": len(tests),
        "files": {f: round(s, 2) for f, s in ranked},
        "tests": {t: round(s, 2) for t, s in sorted(tests.items())},
    }
    if filled:
        body["filled_files"] = sorted(filled)
    return body


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("source", type=Path, help="a run's --junitxml file, or the text output of a --durations 0 run")
    p.add_argument("--write", nargs="?", const=DEFAULT_OUT, type=Path, default=None, metavar="PATH",
                   help=f"write the durations file (default {DEFAULT_OUT.relative_to(ROOT)})")
    p.add_argument("--commit", default=None, help="the commit the run tested (default: this checkout's HEAD)")
    p.add_argument("--date", default=None, help="when the run ran (default: the source file's time)")
    p.add_argument("--command", default="make test", help="the command that made the run")
    p.add_argument("--load", default="not recorded", help="the machine's load during the run, in words")
    p.add_argument("--notes", default="")
    p.add_argument("--load-start", type=float, default=None, help="the 1-min load when the run began (its last line)")
    p.add_argument("--load-end", type=float, default=None, help="the 1-min load when it ended")
    p.add_argument("--record-to", type=Path, default=None, metavar="DIR",
                   help="where test_suite.json goes (default benchmarks/results)")
    p.add_argument("--fill", type=Path, default=None, metavar="JSON",
                   help="a {file: seconds} JSON file for the test files the run did not reach (a run that "
                        "stopped early): they follow the run's own files in the order")
    p.add_argument("--top", type=int, default=30, help="print the N costliest tests and files")
    args = p.parse_args(argv)
    if not args.source.is_file():
        p.error(f"no such file {args.source}")
    junit = args.source.suffix == ".xml"
    tests = from_junit(args.source) if junit else from_durations_text(args.source)
    date = args.date or _dt.datetime.fromtimestamp(args.source.stat().st_mtime, _dt.timezone.utc).isoformat(
        timespec="seconds")
    fill = json.loads(args.fill.read_text()) if args.fill else None
    wall = (junit_wall_seconds if junit else text_wall_seconds)(args.source)
    body = build(tests, commit=args.commit or _commit(), date=date, command=args.command, load=args.load,
                 notes=args.notes, wall_seconds=wall, fill=fill)
    print(f"{len(tests)} tests, {len(per_file(tests))} files, {body['test_seconds'] / 60:.1f} test-minutes"
          + (f", {body['wall_seconds'] / 60:.1f} min wall" if body["wall_seconds"] else ""))
    if args.top:
        print(f"\nThe {args.top} costliest files:")
        for f, s in sorted(per_file(tests).items(), key=lambda kv: -kv[1])[:args.top]:
            print(f"{s:8.1f}s  {f}")
        print(f"\nThe {args.top} costliest tests:")
        for t, s in sorted(body["tests"].items(), key=lambda kv: -kv[1])[:args.top]:
            print(f"{s:8.1f}s  {t}")
    if args.write:
        tmp = args.write.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(body, indent=1) + "\n", encoding="utf-8")
        tmp.replace(args.write)
        print(f"\nwritten: {args.write}")
        if junit and body["wall_seconds"]:
            path = record_suite(body, junit_counts(args.source), args.load_start, args.load_end, args.record_to)
            print(f"recorded: {path}")
    return 0


def record_suite(body: dict, counts: dict[str, int], load_start: float | None, load_end: float | None,
                 out_dir: Path | None = None) -> Path:
    """``benchmarks/results/test_suite.json``: the whole suite's wall time and counts, the figures README.md's
    Tests section quotes (rendered by scripts/render_figures.py like every benchmark's)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from recorded import machine, write_earlier

    here = machine()
    figures = {"wall_min": round(body["wall_seconds"] / 60, 1), "test_cpu_min": round(body["test_seconds"] / 60, 1),
               "files": len(body["files"]), **counts,
               "passed": counts.get("tests", 0) - counts.get("skipped", 0) - counts.get("failed", 0)}
    return write_earlier("test_suite", figures, command=body["command"], date=body["date"], commit=body["commit"],
                         machine={"cores": body["machine"]["cores"], "cpu": here["cpu"],
                                  "memory_gib": body["machine"]["memory_gib"], "load_1min_start": load_start,
                                  "load_1min_end": load_end},
                         recorded_from="the JUnit XML of that run (tests/durations.json; load: "
                                       f"{body['machine']['load']})", out_dir=out_dir)


if __name__ == "__main__":
    sys.exit(main())
