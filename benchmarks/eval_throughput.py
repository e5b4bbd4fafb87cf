"""Evaluation throughput of `rsb eval`: episodes per minute, on the protocol's first seeds.

    python benchmarks/eval_throughput.py [--suites RSB-Math-4] [-n 40] [--procs 1 2] [--policy oracle]
    python benchmarks/eval_throughput.py --rgb [-n 3] [--chunk 10] [--max-steps 100]
    python benchmarks/eval_throughput.py --loop-cost [--envs 1 4] [-n 8] [--max-steps 300]

Default: a built-in policy with state observations (what oracle / blind / random read) with 1 and
2 worker processes. ``--rgb``: render on demand, in one run: the random policy with chunks of
``--chunk`` actions on the three 320x240 rgb cameras, with the cameras rendered only when it asks
for a chunk, then at every step (the same episodes; the issue's target: >= 4x episodes/min).
No video, into a temporary directory. Wall time includes building the env (what a user waits
for; with --rgb the first build also compiles shaders, so there episodes/min are taken from the
time inside the loop); the time per episode is measured inside the loop (reset, policy, steps).
Also prints the TSR reached, so that a fast but broken run cannot pass for a fast one.

``--loop-cost``: the eval loop's own cost, in this process: the random policy, state observations,
the loop of one env (K = 1, ``episode_loop``) and of a vector of K (``batched_loop``), with the
env's ``reset`` / ``step`` and the policy's calls timed inside the same run. Prints per env-step the
loop's wall time, the env's own (simulation), the policy's, and the rest (the loop's bookkeeping),
and loop / env: the ratio issue 57 asks to bring within 1.15 (the env's own step, same actions).
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.evaluation import eval_seeds
from rsb_maniskill.evaluation.jobs import EvalJob, run_job
from rsb_maniskill.evaluation.store import RECORDS_FILE


def run(job: EvalJob, procs: int = 1, executor=None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        records = run_job(job, Path(tmp) / RECORDS_FILE, num_procs=procs, progress=False, executor=executor)
        wall = time.perf_counter() - t0
    return dict(procs=procs, episodes=len(records), wall=wall, per_min=60 * len(records) / wall,
                loop_per_min=60 * len(records) / sum(r["wall_s"] for r in records),
                ep_s=statistics.mean(r["wall_s"] for r in records),
                steps=statistics.mean(r["steps"] for r in records),
                tsr=sum(r["success"] for r in records) / len(records), records=records)


def loop_cost(suite: str, envs: list[int], episodes: int, max_steps: int) -> None:
    from rsb_maniskill.evaluation.jobs import _load_policies, make_env
    from rsb_maniskill.evaluation.runner import batched_loop, episode_loop

    seeds = tuple(eval_seeds(suite, episodes))
    print(f"random on {suite}, state obs, {episodes} episodes of at most {max_steps} steps, 1 process, "
          f"{os.cpu_count()} CPUs visible; ms per env-step")
    print("| K | loop | env (reset + step) | policy | rest | loop / env |")
    print("|---|---:|---:|---:|---:|---:|")
    rows = []
    for k in envs:
        job = EvalJob(suite_id=suite, seeds=seeds, policy="random", label="random", obs_mode="state", num_envs=k,
                      max_steps=max_steps)
        env = make_env(job)
        policy = _load_policies(job, env)
        spent = {"env": 0.0, "policy": 0.0}

        def timed(obj, name, kind):
            fn = getattr(obj, name)

            def call(*args, **kwargs):
                t = time.perf_counter()
                try:
                    return fn(*args, **kwargs)
                finally:
                    spent[kind] += time.perf_counter() - t
            setattr(obj, name, call)

        timed(env, "reset", "env")
        timed(env, "step", "env")
        for p in policy if isinstance(policy, list) else [policy]:
            for name in ("reset", "act", "reset_batch", "act_batch"):
                if callable(getattr(p, name, None)):
                    timed(p, name, "policy")
        records: list = []
        loop = batched_loop if k > 1 else episode_loop
        try:
            loop(env, policy, job, list(seeds[:k]), records.append)  # warm: first reset, imports
            spent.update(env=0.0, policy=0.0)
            records = []
            t = time.perf_counter()
            loop(env, policy, job, list(seeds), records.append)
            wall = time.perf_counter() - t
        finally:
            env.close()
        steps = sum(r["steps"] for r in records)
        ms = {key: 1000 * v / steps for key, v in (("loop", wall), *spent.items())}
        rest = ms["loop"] - ms["env"] - ms["policy"]
        rows.append([k, f"{ms['loop']:.2f}", f"{ms['env']:.2f}", f"{ms['policy']:.2f}", f"{rest:.2f}",
                     f"{ms['loop'] / ms['env']:.2f}"])
        print("| " + " | ".join(map(str, rows[-1])) + " |", flush=True)
    write("eval_loop_cost", {"suite": suite, "episodes": episodes, "max_steps": max_steps, "table": table(
        ["K", "loop", "env (reset + step)", "policy", "rest", "loop / env"], rows, "rrrrrr")})


def show(rows: list[tuple[str, dict]]) -> None:
    print(f"{'run':>22} {'episodes':>8} {'wall s':>7} {'episodes/min':>12} {'s/episode':>9} {'steps/ep':>8} {'TSR':>6}")
    for name, r in rows:
        print(f"{name:>22} {r['episodes']:>8} {r['wall']:>7.1f} {r['per_min']:>12.1f} {r['ep_s']:>9.3f} "
              f"{r['steps']:>8.1f} {r['tsr']:>6.1%}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--suites", "--suite", dest="suite", default="RSB-Math-4", help="one suite")
    p.add_argument("--policy", default="oracle", choices=["oracle", "blind", "random"])
    p.add_argument("-n", "--num-episodes", dest="num", type=int, default=None,
                   help="episodes per run (default 40; 3 with --rgb)")
    p.add_argument("--procs", type=int, nargs="+", default=[1, 2])
    p.add_argument("--rgb", action="store_true", help="render on demand vs every step, rgb cameras")
    p.add_argument("--chunk", type=int, default=10, help="--rgb: actions per chunk (default 10)")
    p.add_argument("--max-steps", type=int, default=None, help="--rgb: steps per episode (default 100; "
                   "--loop-cost: the task's limit)")
    p.add_argument("--loop-cost", action="store_true", help="the eval loop's own cost against the env's step")
    p.add_argument("--envs", type=int, nargs="+", default=[1, 4], help="--loop-cost: K envs a loop")
    args = p.parse_args()
    if args.loop_cost:
        from rsb_maniskill.evaluation.runner import DEFAULT_MAX_STEPS

        loop_cost(args.suite, args.envs, args.num or 8, args.max_steps or DEFAULT_MAX_STEPS)
        return
    args.max_steps = args.max_steps or 100
    seeds = tuple(eval_seeds(args.suite, args.num or (3 if args.rgb else 40)))
    if args.rgb:
        base = dict(suite_id=args.suite, seeds=seeds, policy="random", label="random", obs_mode="rgb",
                    policy_kwargs={"chunk_size": args.chunk}, max_steps=args.max_steps)
        lazy = run(EvalJob(**base))
        eager = run(EvalJob(**base, render_every_step=True))
        strip = lambda rs: [{k: v for k, v in r.items() if k != "wall_s"} for r in rs]  # noqa: E731
        print(f"\nrandom policy on {args.suite}, rgb obs (3 cameras, 320x240), chunks of {args.chunk}, "
              f"{args.max_steps} steps/episode, 1 process, {os.cpu_count()} CPUs visible")
        show([("render on demand", lazy), ("render every step", eager)])
        same = strip(lazy['records']) == strip(eager['records'])
        print(f"episodes/min inside the loop: {lazy['loop_per_min']:.1f} on demand, {eager['loop_per_min']:.1f} "
              f"every step: {lazy['loop_per_min'] / eager['loop_per_min']:.1f}x; same records: {same}")
        write("eval_throughput_rgb", {"suite": args.suite, "chunk": args.chunk, "max_steps": args.max_steps,
                                      "on_demand": _figures(lazy), "every_step": _figures(eager),
                                      "speedup": round(lazy["loop_per_min"] / eager["loop_per_min"], 2),
                                      "same_records": same})
        return
    rows = []
    for k in args.procs:
        job = EvalJob(suite_id=args.suite, seeds=seeds, policy=args.policy, label=args.policy, obs_mode="state")
        rows.append((f"{k} procs", run(job, k)))
    print(f"\n{args.policy} on {args.suite}, state obs, no video, {os.cpu_count()} CPUs visible")
    show(rows)
    write(f"eval_throughput_{args.policy}", {
        "suite": args.suite, "policy": args.policy, "runs": [_figures(r) for _, r in rows],
        "table": table(["procs", "episodes/min", "s/episode", f"{args.policy} TSR"],
                       [[r["procs"], f"{r['per_min']:.0f}", f"{r['ep_s']:.2f}", f"{r['tsr']:.0%}".replace("%", " %")]
                        for _, r in rows], "rrrr")})


def _figures(r: dict) -> dict:
    """A run's figures as recorded (``ms_per_step``: the time inside the loop over the steps)."""
    return {"procs": r["procs"], "episodes": r["episodes"], "wall_s": round(r["wall"], 2),
            "episodes_per_min": round(r["per_min"], 1), "loop_episodes_per_min": round(r["loop_per_min"], 1),
            "s_per_episode": round(r["ep_s"], 3), "steps_per_episode": round(r["steps"], 1),
            "ms_per_step": round(1000 * r["ep_s"] / r["steps"], 2), "tsr": r["tsr"]}


if __name__ == "__main__":
    main()
