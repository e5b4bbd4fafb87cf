"""The reference policies' figures the README quotes: `rsb eval oracle` and `rsb eval blind` on the protocol's
first episodes of one suite, as a user runs them, with GSR / TSR / nSG and their 95 % intervals.

    python benchmarks/reference_baselines.py [--suites RSB-Math-4] [-n 100] [--num-procs 2]

Each policy is one `rsb eval POLICY --suites SUITE -n N -o state` into a temporary folder; the figures are
read from its `results.json` (the file a leaderboard reads). The oracle is the harness check (TSR 100 %);
blind is the random-selection line (TSR near 1/N, nSG near 0). The records are deterministic, so the
figures reproduce exactly on any machine; the wall times do not.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

POLICIES = ("oracle", "blind")


def _cell(rate: dict) -> str:
    """'23.0 [15.9, 32.1]' (percent), as the reports write a rate with its interval."""
    if rate["value"] is None:
        return "n/a"
    value = f"{100 * rate['value']:.1f}"
    if rate.get("low") is None:
        return value
    return f"{value} [{100 * rate['low']:.1f}, {100 * rate['high']:.1f}]"


def run(policy: str, suite: str, n: int, procs: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", "eval", policy, "--suites", suite, "-n", str(n),
                        "-o", "state", "--num-procs", procs, "--out", tmp, "-q"], check=True)
        wall = time.perf_counter() - t
        doc = json.loads((Path(tmp) / "results.json").read_text(encoding="utf-8"))
    (row,) = [r for r in doc["rows"] if r["policy"] == policy]
    return {"wall_s": round(wall, 1), "episodes_verdict": row["episodes"], **row["suites"][suite]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--suites", "--suite", dest="suite", default="RSB-Math-4", help="one suite")
    ap.add_argument("-n", "--num-episodes", dest="num", type=int, default=100)
    ap.add_argument("--num-procs", default="auto")
    args = ap.parse_args()
    figures = {p: run(p, args.suite, args.num, args.num_procs) for p in POLICIES}
    rows = [[p, args.suite, f["n"], _cell(f["gsr"]), _cell(f["tsr"]), _cell(f["nsg"])] for p, f in figures.items()]
    for row in rows:
        print("| " + " | ".join(map(str, row)) + " |")
    write("reference_baselines", {"suite": args.suite, **figures, "table": table(
        ["policy", "suite", "episodes", "GSR %", "TSR %", "nSG %"], rows, "llrlll")})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
