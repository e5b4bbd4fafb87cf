"""Evaluation throughput of `rsb eval`: episodes per minute of a built-in policy with 1 and 2
worker processes, on the protocol's first seeds.

    python benchmarks/eval_throughput.py [--suite RSB-Math-4] [-n 40] [--procs 1 2] [--policy oracle]

State observations (what oracle / blind / random read), no video, into a temporary directory.
Wall time includes starting the workers and building their envs (what a user waits for); the
time per episode is measured inside the loop (reset, policy, steps). Also prints the TSR reached,
so that a fast but broken run cannot pass for a fast one.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from rsb_maniskill.evaluation import eval_seeds
from rsb_maniskill.evaluation.jobs import EvalJob, run_job


def run(suite: str, policy: str, num: int, procs: int) -> dict:
    job = EvalJob(suite_id=suite, seeds=tuple(eval_seeds(suite, num)), policy=policy, label=policy, obs_mode="state")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        records = run_job(job, Path(tmp) / "episodes.jsonl", num_procs=procs, progress=False)
        wall = time.perf_counter() - t0
    return dict(procs=procs, episodes=len(records), wall=wall, per_min=60 * len(records) / wall,
                ep_s=statistics.mean(r["wall_s"] for r in records),
                steps=statistics.mean(r["steps"] for r in records),
                tsr=sum(r["success"] for r in records) / len(records))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--suite", default="RSB-Math-4")
    p.add_argument("--policy", default="oracle", choices=["oracle", "blind", "random"])
    p.add_argument("-n", "--num", type=int, default=40, help="episodes per run")
    p.add_argument("--procs", type=int, nargs="+", default=[1, 2])
    args = p.parse_args()
    rows = [run(args.suite, args.policy, args.num, k) for k in args.procs]
    print(f"\n{args.policy} on {args.suite}, state obs, no video, {os.cpu_count()} CPUs visible")
    print(f"{'procs':>5} {'episodes':>8} {'wall s':>7} {'episodes/min':>12} {'s/episode':>9} {'steps/ep':>8} {'TSR':>6}")
    for r in rows:
        print(f"{r['procs']:>5} {r['episodes']:>8} {r['wall']:>7.1f} {r['per_min']:>12.1f} {r['ep_s']:>9.3f} "
              f"{r['steps']:>8.1f} {r['tsr']:>6.1%}")


if __name__ == "__main__":
    main()
