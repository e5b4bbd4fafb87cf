"""Local process pool vs Ray executor: the same evaluation, in one run, on this machine.

    python benchmarks/executor_overhead.py [--suites RSB-Math-4] [-n 16] [--workers 2] [--policy blind]

Runs ``run_job`` on the protocol's first ``n`` seeds with ``--workers`` spawned processes, then
with as many Ray tasks on a local Ray cluster (started once, before the timing: on a real cluster
it is already running), state observations, and prints episodes/min of each and the overhead of
Ray (the issue's target: <= 15 %). The records must be equal (printed). Wall times include
building each worker's env, as a user waits for it. On a shared machine, run it twice.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from recorded import write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.evaluation import eval_seeds
from rsb_maniskill.evaluation.jobs import EvalJob, run_job
from rsb_maniskill.evaluation.store import RECORDS_FILE
from rsb_maniskill.parallel.ray_pool import RayExecutor


def timed(job: EvalJob, workers: int, executor=None) -> tuple[float, list[dict]]:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        records = run_job(job, Path(tmp) / RECORDS_FILE, num_procs=workers, progress=False, executor=executor)
        return time.perf_counter() - t0, records


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--suites", "--suite", dest="suite", default="RSB-Math-4", help="one suite")
    p.add_argument("--policy", default="blind", choices=["oracle", "blind", "random"])
    p.add_argument("-n", "--num-episodes", dest="num", type=int, default=16)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--ray-first", action="store_true", help="time Ray before the local pool (order effects)")
    args = p.parse_args()
    job = EvalJob(suite_id=args.suite, seeds=tuple(eval_seeds(args.suite, args.num)), policy=args.policy,
                  label=args.policy, obs_mode="state")
    if not args.ray_first:
        local_s, local = timed(job, args.workers)
    t0 = time.perf_counter()
    with RayExecutor(num_cpus=args.workers) as ray_ex:
        start_s = time.perf_counter() - t0
        ray_s, on_ray = timed(job, args.workers, ray_ex)
    if args.ray_first:
        local_s, local = timed(job, args.workers)
    strip = lambda rs: sorted(({k: v for k, v in r.items() if k != "wall_s"} for r in rs),  # noqa: E731
                              key=lambda r: r["seed"])
    n = len(local)
    print(f"\n{args.policy} on {args.suite}, state obs, {n} episodes, {args.workers} workers, "
          f"{os.cpu_count()} CPUs visible")
    print(f"{'executor':>10} {'wall s':>7} {'episodes/min':>12} {'s/episode (in loop)':>20}")
    for name, wall, recs in (("local", local_s, local), ("ray", ray_s, on_ray)):
        print(f"{name:>10} {wall:>7.1f} {60 * n / wall:>12.1f} {sum(r['wall_s'] for r in recs) / n:>20.3f}")
    same = strip(local) == strip(on_ray)
    print(f"Ray overhead: {100 * (ray_s - local_s) / local_s:+.1f} % wall time "
          f"(local cluster start, not counted: {start_s:.1f} s); same records: {same}")
    write("executor_overhead", {
        "suite": args.suite, "policy": args.policy, "episodes": n, "workers": args.workers, "ray_first": args.ray_first,
        "local_wall_s": round(local_s, 2), "ray_wall_s": round(ray_s, 2), "ray_start_s": round(start_s, 2),
        "local_s_per_episode": round(sum(r["wall_s"] for r in local) / n, 3),
        "ray_s_per_episode": round(sum(r["wall_s"] for r in on_ray) / n, 3),
        "ray_overhead_pct": round(100 * (ray_s - local_s) / local_s, 1), "same_records": same})


if __name__ == "__main__":
    main()
