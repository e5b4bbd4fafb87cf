"""Re-record every figure README.md and docs/ quote that this machine can measure, then re-render the pages.

    python benchmarks/record_docs_figures.py            # every benchmark below, then scripts/render_figures.py
    python benchmarks/record_docs_figures.py --list     # what it would run
    python benchmarks/record_docs_figures.py --only task_speed cli_startup
    python benchmarks/record_docs_figures.py --quick    # smaller runs, for a busy machine (their commands say so)

Run it on an otherwise idle machine with the question data (`RSB_DATA_DIR`): each benchmark writes
`benchmarks/results/NAME.json` (`recorded.py`: command, date, commit, machine and its load), and the pages'
marked regions are rendered from those files. Then commit the files and the pages together
(`tests/acceptance/test_docs_figures.py` fails while a page differs from its file). About half an hour on two
idle cores (an estimate from the single runs' times), most of it the expert's 3,200 episodes, the
fresh clone's set-up and the 200-episode throughput runs.

Figures from lent GPU boxes and long trainings (`recorded_from` in their files) are not re-measured here:
`python benchmarks/gpu_check.py` on a GPU box records `gpu_check.json`, which docs/gpu.md's table then shows.
A benchmark whose figures a page quotes adds its line to JOBS.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

OBJECTS = [f"RSB-{s}-{n}-Objects" for s in ("Math", "HardMath", "General", "Direct") for n in (4, 10)]
# recorded file -> (the command the pages quote, a smaller one for --quick)
JOBS: dict[str, tuple[list[str], list[str]]] = {
    "cli_startup": (["cli_startup.py", "--repeat", "5"], ["cli_startup.py", "--repeat", "3"]),
    "reference_baselines": (["reference_baselines.py", "-n", "100"], ["reference_baselines.py", "-n", "100"]),
    "eval_throughput_random": (["eval_throughput.py", "--policy", "random", "-n", "4", "--procs", "1"],
                               ["eval_throughput.py", "--policy", "random", "-n", "4", "--procs", "1"]),
    "eval_throughput_rgb": (["eval_throughput.py", "--rgb", "-n", "3", "--max-steps", "300"],
                            ["eval_throughput.py", "--rgb", "-n", "2", "--max-steps", "300"]),
    "eval_throughput_oracle": (["eval_throughput.py", "-n", "200"], ["eval_throughput.py", "-n", "40"]),
    "demo_throughput": (["demo_throughput.py", "-n", "200"], ["demo_throughput.py", "-n", "20"]),
    "task_speed": (["task_speed.py", "--repeats", "2"], ["task_speed.py", "--repeats", "1"]),
    "expert_success": (["expert_success.py"], ["expert_success.py", "--seeds", "10"]),
    "expert_success_objects": (["expert_success.py", "--record-as", "expert_success_objects", "--suites", *OBJECTS],
                               ["expert_success.py", "--record-as", "expert_success_objects", "--seeds", "10",
                                "--suites", *OBJECTS]),
    "first_hour": (["first_hour.py"], ["first_hour.py"]),
    "eval_run": (["eval_run.py"], ["eval_run.py", "--repeats", "1"]),
    "policy_server": (["policy_server.py", "-n", "16", "--max-steps", "100"],
                      ["policy_server.py", "-n", "8", "--max-steps", "100"]),
    "worker_threads": (["worker_threads.py"], ["worker_threads.py"]),
    "stats_checks": (["stats_checks.py"], ["stats_checks.py"]),
    "plan_inputs": (["plan_inputs.py"], ["plan_inputs.py"]),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", choices=sorted(JOBS), metavar="NAME", help="these recorded files only")
    ap.add_argument("--quick", action="store_true", help="smaller runs (a busy machine); the files say which")
    ap.add_argument("--list", action="store_true", help="print the commands and stop")
    args = ap.parse_args(argv)
    names = args.only or list(JOBS)
    if not os.environ.get("RSB_DATA_DIR"):
        print("record_docs_figures: RSB_DATA_DIR is not set: rsb verify reads the question data from the hub "
              "cache (or fails offline)", file=sys.stderr)
    failed = []
    for name in names:
        script, *rest = JOBS[name][1 if args.quick else 0]
        cmd = [sys.executable, str(HERE / script), *rest]
        print(f"== {name}: python {' '.join(cmd[1:])}", flush=True)
        if args.list:
            continue
        t = time.perf_counter()
        done = subprocess.run(cmd, cwd=ROOT)
        print(f"== {name}: exit {done.returncode} after {time.perf_counter() - t:.0f} s", flush=True)
        if done.returncode != 0:
            failed.append(name)
    if args.list:
        return 0
    subprocess.run([sys.executable, str(ROOT / "scripts" / "render_figures.py")], cwd=ROOT, check=True)
    if failed:
        print(f"record_docs_figures: failed, their files kept as they were: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
