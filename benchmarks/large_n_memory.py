"""Peak memory of ``rsb eval`` and ``rsb audit`` against ``-n``: it must follow the work in flight.

    python benchmarks/large_n_memory.py [--seconds 25] [--n 100 1000000000000]

Runs ``rsb eval random --suites RSB-Math-4 -o state --max-steps 1 -n N`` for each N, samples the
resident memory (RSS) of the command and of its worker processes every 0.2 s, stops it with
SIGINT after ``--seconds`` (as a user would: it resumes), and prints the peak RSS of the process
tree, with the episodes it recorded. Then ``rsb audit RSB-Math-4 -n N`` the same way
(it refuses an ``-n`` it cannot hold in memory, in one line, at once). Nothing here asserts a
figure: compare the rows (before the fix ``-n 1000000000000`` grew past 8.7 GB in 32 s). The rows are
recorded in ``benchmarks/results/large_n_memory.json`` (``eval_peak_rss_gb`` by ``-n``: docs/evaluation.md).
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from recorded import write  # benchmarks/recorded.py: the figures to benchmarks/results/


def tree_rss_kb(pid: int) -> int:
    """RSS of ``pid`` and its descendants, in kB (Linux /proc)."""
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
            for task in Path(f"/proc/{p}/task").iterdir():
                children = (task / "children").read_text().split()
                todo.extend(int(c) for c in children)
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            pass
    return total


def measure(argv: list[str], seconds: float) -> tuple[int, int, float, str]:
    """(peak RSS in kB, exit code, wall s, last stderr line) of ``rsb ARGV`` stopped after ``seconds``."""
    proc = subprocess.Popen([sys.executable, "-m", "rsb_maniskill.cli", *argv], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    t0, peak = time.monotonic(), 0
    while proc.poll() is None and time.monotonic() - t0 < seconds:
        peak = max(peak, tree_rss_kb(proc.pid))
        time.sleep(0.2)
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    lines = [line for line in err.splitlines() if line.strip() and "WARNING" not in line]
    return peak, proc.returncode, time.monotonic() - t0, lines[-1] if lines else ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=25.0)
    ap.add_argument("--n", type=int, nargs="+", default=[100, 10**12])
    args = ap.parse_args()
    print(f"{'command':<7} {'-n':>15} {'peak RSS MB':>12} {'episodes':>9} {'exit':>5} {'wall s':>7}  last line")
    rows: dict[str, dict[str, dict]] = {"eval": {}, "audit": {}}
    for n in args.n:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "r"
            peak, rc, wall, last = measure(["eval", "random", "--suites", "RSB-Math-4", "-o", "state", "--max-steps",
                                            "1", "-q", "-n", str(n), "--out", str(out)], args.seconds)
            records = out / "episodes.jsonl"
            episodes = sum(1 for _ in records.open()) if records.exists() else 0
            print(f"{'eval':<7} {n:>15} {peak / 1024:>12.0f} {episodes:>9} {rc:>5} {wall:>7.1f}  {last[:90]}")
            rows["eval"][str(n)] = {"peak_rss_mb": round(peak / 1024), "episodes": episodes, "exit": rc,
                                    "wall_s": round(wall, 1)}
    for n in args.n:
        peak, rc, wall, last = measure(["audit", "RSB-Math-4", "-n", str(n)], args.seconds)
        print(f"{'audit':<7} {n:>15} {peak / 1024:>12.0f} {'-':>9} {rc:>5} {wall:>7.1f}  {last[:90]}")
        rows["audit"][str(n)] = {"peak_rss_mb": round(peak / 1024), "exit": rc, "wall_s": round(wall, 1)}
    sys.stdout.flush()
    gb = {n: round(r["peak_rss_mb"] / 1024, 2) for n, r in rows["eval"].items()}
    write("large_n_memory", {"eval_peak_rss_gb": gb, "seconds": args.seconds, **rows})


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    main()
