"""`rsb plan` on every odd input a reviewer tried: each answers or refuses, and how long it takes.

    python benchmarks/plan_inputs.py

Runs each command as a user would (a fresh `rsb plan` process: the time includes Python's start and the
imports) and records its wall time, exit status and line count in ``benchmarks/results/plan_inputs.json``.
The target is an answer or a one-line refusal within 5 s; on a loaded machine read the figures beside the
load the file records.
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from recorded import table, write  # noqa: E402

INPUTS = [
    "0.30 0.40", "10% 30% --icc 0.8", "0.5 0.51", "0.5 0.5000001", "0 1", "1 2", "1.5 0.5",
    "0.3 0.4 --alpha 1e-300", "0.3 0.4 --icc 1", "0.3 0.4 --icc 0", "0.2 0.6 --icc 0.9999999",
    "0.3 0.4 --variants 10", "0.3 0.35 --alpha 0.0001 --power 0.99",
]


def main() -> None:
    rsb = shutil.which("rsb") or str(Path(sys.executable).with_name("rsb"))
    rows, figures = [], {}
    for args in INPUTS:
        start = time.perf_counter()
        done = subprocess.run([rsb, "plan", *args.split()], capture_output=True, text=True)
        wall = time.perf_counter() - start
        lines = len((done.stdout + done.stderr).strip().splitlines())
        figures[args] = {"seconds": round(wall, 2), "exit": done.returncode, "lines": lines}
        rows.append([f"`rsb plan {args}`", f"{wall:.1f}", str(done.returncode),
                     "answer" if done.returncode == 0 else "one-line refusal" if lines == 1 else f"{lines} lines"])
        print(f"{wall:6.2f} s  exit {done.returncode}  {lines:2d} lines  rsb plan {args}", flush=True)
    figures["slowest_seconds"] = max(v["seconds"] for v in figures.values() if isinstance(v, dict))
    figures["table"] = table(["Command", "Seconds", "Exit", "Output"], rows, "lrrl")
    write("plan_inputs", figures)


if __name__ == "__main__":
    main()
