"""Demonstration throughput of `rsb generate`: successful demos per minute with 1 and 2 worker
processes, and where an episode's time goes (motion planning vs simulation, from ExpertResult).

    python benchmarks/demo_throughput.py [--env RSB-Math-4] [-n 20] [--procs 1 2]

State observations, no video, seeds from 0, into a temporary directory. Wall time includes
starting the workers and merging their parts (what a user waits for); "other" is per-episode
time spent neither planning nor stepping (resets, recording, writing), summed over workers.
"""
from __future__ import annotations

import argparse
import os
import tempfile

from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.motionplan.generate import GenerateConfig, generate


def run(env_id: str, num: int, procs: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        s = generate(GenerateConfig(env_id=env_id, out=tmp, num=num, num_procs=procs, progress=False))
    tried = s.completed + len(s.failures)
    worker_time = s.wall_time * procs  # upper bound on the workers' busy time
    return dict(procs=procs, demos=s.completed, tried=tried, wall=s.wall_time,
                per_min=60 * s.completed / s.wall_time, plan=s.plan_time / tried, sim=s.sim_time / tried,
                other=max(0.0, worker_time / tried - (s.plan_time + s.sim_time) / tried),
                steps=s.kept_steps / max(1, s.completed))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", default="RSB-Math-4")
    p.add_argument("-n", "--num-episodes", dest="num", type=int, default=20, help="successful demos per run")
    p.add_argument("--procs", type=int, nargs="+", default=[1, 2])
    args = p.parse_args()
    rows = [run(args.env, args.num, k) for k in args.procs]
    print(f"\n{args.env}, state obs, no video, {os.cpu_count()} CPUs visible")
    print(f"{'procs':>5} {'demos':>5} {'tried':>5} {'wall s':>7} {'demos/min':>9} "
          f"{'plan s/ep':>9} {'sim s/ep':>8} {'other s/ep':>10} {'steps/demo':>10}")
    for r in rows:
        print(f"{r['procs']:>5} {r['demos']:>5} {r['tried']:>5} {r['wall']:>7.1f} {r['per_min']:>9.1f} "
              f"{r['plan']:>9.3f} {r['sim']:>8.3f} {r['other']:>10.3f} {r['steps']:>10.0f}")
    write("demo_throughput", {
        "env": args.env, "runs": [{k: round(v, 4) if isinstance(v, float) else v for k, v in r.items()} for r in rows],
        "table": table(["procs", "successful demos/min", "planning s/episode", "simulation s/episode", "steps/demo"],
                       [[r["procs"], f"{r['per_min']:.0f}", f"{r['plan']:.3f}", f"{r['sim']:.2f}", f"{r['steps']:.0f}"]
                        for r in rows], "rrrrr")})


if __name__ == "__main__":
    main()
