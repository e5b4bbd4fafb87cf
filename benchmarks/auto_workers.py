"""`--num-procs auto` against every explicit worker count, on this machine, in one run.

    python benchmarks/auto_workers.py [--job generate eval] [-n 16] [--repeats 2] [--suites RSB-Math-4]
                                      [-o state|rgb]

Runs the same small job as a user types it, each time in a fresh process (start-up and worker
spawning included: what a user waits for): ``rsb generate SUITE -n N`` (the scripted expert) and
``rsb eval oracle --suites SUITE -n N``, with ``--num-procs auto`` and with every count from 1
to the usable CPUs. Prints each run's wall time and episodes/s (median of the repeats, with the
spread), the CPU seconds of the main process alone (its imports and its share of the work: what
a CPU kept for it would serve), the line auto printed, and auto's ratio to the best explicit count
(1.00: as fast; below 1: slower). Settings are run in a rotated order on each repeat, so that a machine getting busier
does not always hit the same one. Nothing here asserts a speed: on a shared machine read the
spread. Where a command does not take ``auto`` yet, its auto run passes the count
``plan_workers`` picks for this machine (said in the output).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.parallel.plan import nvidia_gpus, obs_mode_renders, plan_workers
from rsb_maniskill.parallel.threads import usable_cpus

AUTO = "auto"


# `rsb ARGS`, then the main process's own CPU seconds (not its workers'): does it need a CPU of its own?
RSB = ("import resource, sys; from rsb_maniskill.cli import main; rc = main(sys.argv[1:]); "
       "r = resource.getrusage(resource.RUSAGE_SELF); print(f'MAIN-CPU {r.ru_utime + r.ru_stime:.2f}', "
       "file=sys.stderr); sys.exit(rc)")


def command(job: str, suite: str, n: int, obs_mode: str, procs: str, out: str) -> list[str]:
    if job == "generate":
        args = ["generate", suite, "-n", str(n), "-o", obs_mode, "--out", out, "-q"]
    else:
        args = ["eval", "oracle", "--suites", suite, "-n", str(n), "-o", obs_mode, "--out", out, "-q"]
    return [sys.executable, "-c", RSB, *args, "--num-procs", procs]


def takes_auto(job: str) -> bool:
    """Whether this command's --num-procs accepts auto yet (its help says auto|N)."""
    out = subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", job, "--help"], capture_output=True, text=True)
    return "auto|N" in out.stdout


def run_once(cmd: list[str]) -> tuple[float, float, str]:
    """Wall seconds of one run, its main process's CPU seconds, and the ``workers:`` line it printed."""
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"failed ({res.returncode}): {' '.join(cmd)}\n{res.stderr[-2000:]}")
    line = next((ln for ln in res.stderr.splitlines() if ln.startswith("workers: ")), "")
    main_cpu = next(float(ln.split()[1]) for ln in res.stderr.splitlines() if ln.startswith("MAIN-CPU "))
    return wall, main_cpu, line


def bench(job: str, args: argparse.Namespace, cpus: int) -> dict:
    auto_arg = AUTO
    if not takes_auto(job):
        plan = plan_workers(cpus, len(nvidia_gpus()), obs_mode_renders(args.obs_mode), episodes=args.num)
        auto_arg = str(plan.num_procs)
        print(f"# rsb {job} does not take --num-procs auto yet: its auto run passes {auto_arg} ({plan.line()})")
    settings = [AUTO] + [str(k) for k in range(1, cpus + 1)]
    walls: dict[str, list[float]] = {s: [] for s in settings}
    main_cpu: dict[str, list[float]] = {s: [] for s in settings}
    lines: dict[str, str] = {}
    for r in range(args.repeats):
        for s in settings[r % len(settings):] + settings[:r % len(settings)]:
            with tempfile.TemporaryDirectory() as tmp:
                wall, cpu, line = run_once(command(job, args.suite, args.num, args.obs_mode,
                                                   auto_arg if s == AUTO else s, tmp))
            walls[s].append(wall)
            main_cpu[s].append(cpu)
            lines.setdefault(s, line)
    print(f"\nrsb {job} {args.suite} -n {args.num} -o {args.obs_mode}, {args.repeats} run(s) each, "
          f"{cpus} usable CPUs, load average before: {os.getloadavg()[0]:.2f}")
    print(f"{'--num-procs':>11} {'wall s (median)':>15} {'min-max':>13} {'episodes/s':>10} {'main CPU s':>10}  "
          "workers line")
    rate = {s: args.num / statistics.median(w) for s, w in walls.items()}
    for s in settings:
        w = walls[s]
        print(f"{s:>11} {statistics.median(w):>15.1f} {min(w):>6.1f}-{max(w):<6.1f} {rate[s]:>10.3f} "
              f"{statistics.median(main_cpu[s]):>10.1f}  {lines[s]}")
    best = max(settings[1:], key=rate.get)
    print(f"auto / best explicit ({best}): {rate[AUTO] / rate[best]:.2f} in episodes/s "
          f"(each run's own spread: {min(walls[AUTO]):.1f}-{max(walls[AUTO]):.1f} s for auto)")
    chose = auto_arg if auto_arg != AUTO else (lines[AUTO].split()[1:2] or ["?"])[0]
    return {"auto_chose": chose, "auto_over_best": round(rate[AUTO] / rate[best], 2),
            "wall_s": {s: round(statistics.median(w), 1) for s, w in walls.items()},
            "auto_spread_s": [round(min(walls[AUTO]), 1), round(max(walls[AUTO]), 1)],
            "main_cpu_s": {s: round(statistics.median(c), 1) for s, c in main_cpu.items()}}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--job", nargs="+", choices=("generate", "eval"), default=["generate", "eval"])
    p.add_argument("--suites", "--suite", dest="suite", default="RSB-Math-4", help="one suite")
    p.add_argument("-n", "--num-episodes", dest="num", type=int, default=16,
                   help="demos (generate) or episodes (eval) a run")
    p.add_argument("-o", "--obs-mode", default="state", help="state (default) or rgb: rendering workers")
    p.add_argument("--repeats", type=int, default=2)
    args = p.parse_args()
    cpus = usable_cpus()
    jobs = {job: bench(job, args, cpus) for job in args.job}
    counts = [str(k) for k in range(1, cpus + 1)]
    rows = [[f"`rsb {job} -n {args.num}`" if job == "generate" else f"`rsb eval oracle -n {args.num}`", r["auto_chose"],
             " / ".join(f"{r['wall_s'][s]:.1f}" for s in [AUTO, *counts]),
             f"{r['auto_over_best']:.2f} (auto's own spread {r['auto_spread_s'][0]}-{r['auto_spread_s'][1]} s)"]
            for job, r in jobs.items()]
    heads = " / ".join(["auto", *(f"{k} process" + ("es" if k != "1" else "") for k in counts)])
    write("auto_workers", {"table": table(["job", "auto chose", f"wall s: {heads}", "auto / best (episodes/s)"], rows,
                                          align="lrlr"),
                           "suite": args.suite, "episodes": args.num, "repeats": args.repeats, "jobs": jobs})


if __name__ == "__main__":
    main()
