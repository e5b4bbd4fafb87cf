"""vla-eval's protocol against native `rsb eval`: seconds per 150-step episode, measured in one run.

    python benchmarks/vla_eval_speed.py [--suites RSB-Math-4] [-n 3] [--chunk 10] [--steps 150]

The same seeded random chunks of ``--chunk`` actions (RandomPolicy over the env's action space, seed
0) on the three 320x240 rgb cameras, the same protocol episodes, one process:

- ``rsb eval`` (native): the policy in-process; the runner renders the cameras when it asks for a chunk;
- ``rsb eval remote -a protocol=vla-eval``: the chunks served by a vla-eval PredictModelServer with
  ``chunk_size`` ``--chunk`` on 127.0.0.1; the client sends one rendered observation per chunk;
- ``vla-eval`` with RSBBenchmark (``vla_eval.evaluate``): ``render_every`` ``--chunk``, and 1 (every
  step rendered, as a benchmark without render on demand).

Prints the median seconds per episode (inside the episode loop: reset, policy or server, steps; the
vla-eval rows are its ``elapsed_sec``, the first episode of each left out as it builds the env), the
ratio to native (the target: <= 1.5x), the server's inferences per episode, and whether both
``rsb eval`` runs recorded the same episodes. ``--rounds`` repeats all rows and pools them, so that
load from other processes on a shared machine falls on every row.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/
from vla_eval.api import evaluate, serve_background
from vla_eval.model_servers.predict import PredictModelServer
from vla_eval.specs import RAW

from rsb_maniskill.evaluation import eval_seeds
from rsb_maniskill.evaluation.jobs import EvalJob, make_env, run_job
from rsb_maniskill.evaluation.store import RECORDS_FILE
from rsb_maniskill.policies.reference import RandomPolicy
from rsb_maniskill.policies.remote.vla_eval_layout import PRESETS


class RandomChunks(PredictModelServer):
    """The native run's random policy behind vla-eval's server: chunks in the Aloha-14 layout."""

    def __init__(self, policy: RandomPolicy, chunk: int) -> None:
        super().__init__(chunk_size=chunk)
        self.policy, self.calls = policy, 0

    def predict(self, obs: dict, ctx: Any) -> dict:
        self.calls += 1
        return {"actions": PRESETS["lerobot"].wire_actions(self.policy.act(obs))}

    def get_action_spec(self) -> dict:
        return {"actions": RAW}

    def get_observation_spec(self) -> dict:
        return {}


def random_policy(suite: str, chunk: int) -> RandomPolicy:
    env = make_env(EvalJob(suite_id=suite, seeds=(), label="", policy="random", obs_mode="state"))
    try:
        return RandomPolicy.for_env(env, chunk_size=chunk, seed=0)
    finally:
        env.close()


def rsb_eval(job: EvalJob) -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        return run_job(job, Path(tmp) / RECORDS_FILE, progress=False)


def run_rows(args: argparse.Namespace) -> list[tuple[str, list[float], list[int], float | None, list[dict]]]:
    """One round: each row once, on the same seeds: (name, seconds and steps per episode, server inferences
    per episode, records)."""
    seeds = tuple(eval_seeds(args.suite, args.num))
    base = dict(suite_id=args.suite, seeds=seeds, obs_mode="rgb", max_steps=args.steps)
    rows = []
    native = rsb_eval(EvalJob(**base, policy="random", label="random", policy_kwargs={"chunk_size": args.chunk}))
    rows.append(("rsb eval (native)", [r["wall_s"] for r in native], [r["steps"] for r in native], None, native))

    server = RandomChunks(random_policy(args.suite, args.chunk), args.chunk)
    with serve_background(server) as handle:
        kwargs = {"protocol": "vla-eval", "host": handle.url, "port": None, "chunk_size": args.chunk}
        remote = rsb_eval(EvalJob(**base, policy="remote", label="random", policy_kwargs=kwargs))
    rows.append(("rsb eval remote vla-eval", [r["wall_s"] for r in remote], [r["steps"] for r in remote],
                 server.calls / len(remote), remote))

    for every in (args.chunk, 1):
        server = RandomChunks(random_policy(args.suite, args.chunk), args.chunk)
        config = {"benchmarks": [{"benchmark": "rsb_maniskill.integrations.vla_eval:RSBBenchmark",
                                  "episodes_per_task": args.num + 1, "max_steps": args.steps,
                                  "params": {"suites": [args.suite], "episodes": args.num + 1,
                                             "render_every": every}}]}
        with tempfile.TemporaryDirectory() as tmp:
            (result,) = evaluate(server, config, output_dir=tmp, docker=False)
        episodes = result["tasks"][0]["episodes"][1:]  # the first one's elapsed_sec holds building the env
        rows.append((f"vla-eval, render_every {every}", [e["elapsed_sec"] for e in episodes],
                     [e["steps"] for e in episodes], server.calls / (args.num + 1), []))
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--suites", "--suite", dest="suite", default="RSB-Math-4", help="one suite")
    p.add_argument("-n", "--num-episodes", dest="num", type=int, default=3,
                   help="episodes per row and round (default 3)")
    p.add_argument("--chunk", type=int, default=10, help="actions per chunk, the server's chunk_size (default 10)")
    p.add_argument("--steps", type=int, default=150, help="steps per episode (default 150)")
    p.add_argument("--rounds", type=int, default=2, help="rounds of all rows, pooled (default 2): load that "
                                                          "comes and goes on a shared machine hits every row")
    args = p.parse_args()
    rounds = [run_rows(args) for _ in range(args.rounds)]
    names = [row[0] for row in rounds[0]]
    seconds = {n: [t for rows in rounds for row in rows if row[0] == n for t in row[1]] for n in names}
    ref = statistics.median(seconds[names[0]])
    print(f"\nrandom chunks of {args.chunk} on {args.suite}, rgb obs (3 cameras, 320x240), {args.steps} steps/episode, "
          f"{args.rounds} rounds of {args.num} episodes per row, 1 process, {os.cpu_count()} CPUs visible")
    print(f"{'run':>28} {'s/episode':>9} {'x native':>8} {'steps/ep':>8} {'inferences/ep':>13}")
    cells = []
    for name, _, steps, calls, _ in rounds[0]:
        med = statistics.median(seconds[name])
        per_ep = "" if calls is None else f"{calls:.0f}"
        print(f"{name:>28} {med:>9.2f} {med / ref:>8.2f} {np.mean(steps):>8.1f} {per_ep:>13}")
        cells.append([name, f"{med:.2f}", f"{med / ref:.2f}", per_ep])
    strip = lambda rs: [{k: v for k, v in r.items() if k not in ("wall_s", "policy")} for r in rs]  # noqa: E731
    same = all(strip(rows[0][4]) == strip(rows[1][4]) for rows in rounds)
    print(f"rsb eval and rsb eval remote recorded the same episodes: {same}")
    write("vla_eval_speed", {
        "suite": args.suite, "chunk": args.chunk, "steps": args.steps, "episodes_per_row": args.num * args.rounds,
        "median_s": {n: round(statistics.median(seconds[n]), 3) for n in names}, "same_records": same,
        "table": table(["run", "s / episode", "x native", "server inferences / episode"], cells, "lrrr")})


if __name__ == "__main__":
    main()
