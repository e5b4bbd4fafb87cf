"""Each worker's thread pools at its share of the cores, against a thread a core in every worker.

    python benchmarks/worker_threads.py [--procs 2] [--envs 1 4] [-n 16] [--max-steps 100] [--repeats 3]

`rsb eval` of the policy server benchmark's MLP (``policy_server.make_mlp``: 12.9 M parameters, torch's
default threads) with a copy a worker (``--policy-process worker``), P workers of K envs, RSB-Direct-4,
state observations, run two ways on the same seeds, interleaved, ``--repeats`` times (median kept):

- ``share``: no thread variable set; each worker gets ``cores // P`` (``rsb_maniskill.parallel.threads``).
- ``every core``: ``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` / ``OPENBLAS_NUM_THREADS`` = the usable
  CPUs, what each worker's torch, OpenMP and BLAS took before they were given a share.

Timed: the steady env-steps/s of the run's own throughput line, and its wall time. The records of the
two ways are compared (without their wall times and settings stamp): the thread count must not change
an episode. Recorded to ``benchmarks/results/worker_threads.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from policy_server import SUITE, THROUGHPUT  # the same model and suite as the policy server benchmark
from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.parallel.threads import THREAD_VARS, usable_cpus

HERE = Path(__file__).resolve().parent


def eval_run(args: argparse.Namespace, procs: int, envs: int, threads: int | None) -> tuple[dict[str, Any], list]:
    """One `rsb eval` of the MLP, each worker's pools at ``threads`` (None: its share): figures, records."""
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS}
    env["PYTHONPATH"] = os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])
    if threads is not None:
        env.update({name: str(threads) for name in THREAD_VARS})
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "rsb_maniskill.cli", "eval", "policy_server:make_mlp", "-a", "threads=0",
               "--suites", SUITE, "-o", "state", "-n", str(args.num_episodes), "--max-steps", str(args.max_steps),
               "--num-procs", str(procs), "--num-envs", str(envs), "--policy-process", "worker", "--out", tmp]
        t0 = time.perf_counter()
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=3600)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise SystemExit(f"rsb eval failed (P={procs}, K={envs}, threads={threads}):\n{done.stderr[-3000:]}")
        found = THROUGHPUT.search(done.stdout + done.stderr)
        records = sorted(({k: v for k, v in json.loads(line).items() if k not in ("wall_s", "settings_id")}
                          for line in (Path(tmp) / "episodes.jsonl").read_text().splitlines()),
                         key=lambda r: r["seed"])
    return {"wall_s": round(wall, 2),
            "env_steps_per_s": float(found.group(2).replace(",", "")) if found else None}, records


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--procs", type=int, nargs="+", default=[2], help="worker processes P")
    p.add_argument("--envs", type=int, nargs="+", default=[1, 4], help="envs a worker K")
    p.add_argument("-n", "--num-episodes", type=int, default=16)
    p.add_argument("--max-steps", type=int, default=100)
    p.add_argument("--repeats", type=int, default=3, help="runs of each way, interleaved; the median is kept")
    args = p.parse_args()
    cpus = usable_cpus()
    print(f"{SUITE}, state obs, {args.num_episodes} episodes of {args.max_steps} steps, a copy of the MLP a "
          f"worker; median of {args.repeats} runs each; {cpus} usable CPUs, 1-min load {os.getloadavg()[0]:.1f}")
    columns = ["P x K", "threads a worker", "wall s", "env-steps/s", "/ every core"]
    print("| " + " | ".join(columns) + " |")
    print("|---|---|" + "---:|" * (len(columns) - 2))
    ways = {"share": None, "every core": cpus}
    rows, runs, same = [], [], True
    for procs in args.procs:
        for envs in args.envs:
            tries: dict[str, list] = {name: [] for name in ways}
            records: dict[str, list] = {}
            for _ in range(args.repeats):  # interleaved: load from other work falls on both ways alike
                for name, threads in ways.items():
                    figures, recs = eval_run(args, procs, envs, threads)
                    tries[name].append(figures)
                    records.setdefault(name, recs)
                    same = same and recs == records["share"]
            got = {name: {k: float(np.median([t[k] for t in ts])) for k in ts[0]} for name, ts in tries.items()}
            runs.append({"procs": procs, "envs": envs, **got, "tries": tries})
            for name, threads in ways.items():
                fig = got[name]
                row = [f"{procs} x {envs}", f"{threads or max(1, cpus // procs)} ({name})", f"{fig['wall_s']:.1f}",
                       f"{fig['env_steps_per_s']:,.0f}",
                       f"{fig['env_steps_per_s'] / got['every core']['env_steps_per_s']:.2f}x"]
                rows.append(row)
                print("| " + " | ".join(row) + " |", flush=True)
    print(f"records of the two ways equal: {same}")
    write("worker_threads", {"suite": SUITE, "episodes": args.num_episodes, "max_steps": args.max_steps,
                             "repeats": args.repeats, "cpus": cpus, "runs": runs, "same_records": same,
                             "table": table(columns, rows, "llrrr")},
          notes="env-steps/s: the run's own throughput line (steady time); wall: the whole rsb eval command; "
                "each figure the median of the interleaved tries (kept in runs[].tries)")
    if not same:
        raise SystemExit("the thread count changed the records")


if __name__ == "__main__":
    main()
