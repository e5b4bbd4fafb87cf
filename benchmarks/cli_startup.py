"""Start-up cost of the light entry points: `rsb --help`, `import rsb_maniskill`, the semantic
engine, and the first env (which loads the simulator). Median of --repeat fresh processes.

    python benchmarks/cli_startup.py [--repeat 5]

Target (issue 12): `rsb --help` under 1 s.
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

CASES = {
    "rsb --help": [sys.executable, "-m", "rsb_maniskill.cli", "--help"],
    "import rsb_maniskill": [sys.executable, "-c", "import rsb_maniskill"],
    "import rsb_maniskill.semantic": [sys.executable, "-c", "import rsb_maniskill.semantic"],
    "python -c pass (interpreter alone)": [sys.executable, "-c", "pass"],
    "first env (gym.make + reset, state)": [sys.executable, "-c",
                                            "import gymnasium as gym, rsb_maniskill; "
                                            "gym.make('RSB-Math-4', obs_mode='state', render_backend='none')"
                                            ".reset(seed=0)"],
}
KEYS = {"rsb --help": "rsb_help", "import rsb_maniskill": "import_rsb_maniskill",
        "import rsb_maniskill.semantic": "import_semantic", "python -c pass (interpreter alone)": "interpreter",
        "first env (gym.make + reset, state)": "first_env"}  # the names the figures are recorded under


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print(f"{'entry point':<40}{'median s':>10}{'min s':>8}")
    figures = {}
    for name, cmd in CASES.items():
        times = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times.append(time.perf_counter() - t)
        figures[KEYS[name]] = {"median_s": round(statistics.median(times), 3), "min_s": round(min(times), 3)}
        print(f"{name:<40}{statistics.median(times):>10.2f}{min(times):>8.2f}")
    rows = [[f"`{name}`" if not name.startswith(("python", "first")) else name,
             f"{figures[KEYS[name]]['median_s']:.2f}", f"{figures[KEYS[name]]['min_s']:.2f}"] for name in CASES]
    write("cli_startup", {**figures, "repeat": args.repeat,
                          "table": table(["entry point", "median s", "min s"], rows)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
