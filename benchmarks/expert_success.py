"""Success rate, episode length and time per episode of the scripted expert, per suite.

    python benchmarks/expert_success.py [--suites RSB-Math-4 RSB-Math-10] [--seeds 200]
        [--seed-start 0] [--num-procs 2] [--failures outputs/expert_failures.jsonl]

Runs ``ScriptedExpert(env).run()`` on seeds ``seed-start .. seed-start+seeds-1`` of each suite
(default: the eight suites, 200 seeds each) with state observations on the CPU backend, in
worker processes (the pool of ``rsb generate`` and ``rsb eval``), one env per suite each. Success
is the env's own ``info["success"]``. Every failure is appended to the JSONL file with suite,
seed, reason, arm and steps. Suites built on GSM8K / MMLU read ``$RSB_DATA_DIR``.
The issue's target: >= 98 % success on every suite.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from recorded import write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.parallel.pool import InProcess, ProcessPool, deal

DEFAULT_FAILURES = "outputs/expert_failures.jsonl"

_ENVS: dict = {}  # per worker process: one env per suite


def _suite_ids() -> tuple[str, ...]:
    from rsb_maniskill.semantic import SUITE_IDS
    return tuple(SUITE_IDS)


def _env(suite: str):
    if suite not in _ENVS:
        import gymnasium as gym

        import rsb_maniskill  # noqa: F401  (registers the suites)
        _ENVS[suite] = gym.make(suite, obs_mode="state", render_backend="none")
    return _ENVS[suite]


def run_episode(job: tuple[str, int]) -> dict:
    """One expert episode; returns a JSON-able record."""
    import torch

    from rsb_maniskill.motionplan import ScriptedExpert

    torch.set_num_threads(1)
    suite, seed = job
    env = _env(suite)
    t0 = time.perf_counter()
    env.reset(seed=seed)
    reset_time = time.perf_counter() - t0
    try:
        res = ScriptedExpert(env).run()
        rec = dict(success=res.success, reason=res.reason, steps=res.steps, plan_time=res.plan_time,
                   sim_time=res.sim_time, arm=res.arm)
    except Exception as e:  # a crash is a failure with a reason, not the end of the sweep
        rec = dict(success=False, reason=f"error:{type(e).__name__}:{e}", steps=0, plan_time=0.0,
                   sim_time=0.0, arm="")
    rec.update(suite=suite, seed=seed, reset_time=reset_time, wall_time=time.perf_counter() - t0,
               target_block=int(env.unwrapped.target_block[0]))
    return rec


def run_episodes(jobs: list[tuple[str, int]], emit) -> None:
    """A worker's share: one record per (suite, seed), sent as each episode ends."""
    for job in jobs:
        emit(run_episode(job))


def summarise(records: list[dict]) -> dict[str, dict]:
    """Per-suite success rate, episode-length stats (successes) and mean times."""
    by_suite = defaultdict(list)
    for r in records:
        by_suite[r["suite"]].append(r)
    rows = {}
    for suite, rs in by_suite.items():
        ok = [r for r in rs if r["success"]]
        lengths = np.array([r["steps"] for r in ok]) if ok else np.zeros(1)
        rows[suite] = dict(
            n=len(rs), success=len(ok) / len(rs), len_mean=float(lengths.mean()),
            len_p95=float(np.percentile(lengths, 95)), len_max=int(lengths.max()),
            plan_time=float(np.mean([r["plan_time"] for r in rs])),
            sim_time=float(np.mean([r["sim_time"] for r in rs])),
            wall_time=float(np.mean([r["wall_time"] for r in rs])),
            reasons=dict(sorted(_count(r["reason"] for r in rs if not r["success"]).items())),
        )
    return rows


def _count(items) -> dict[str, int]:
    out: dict[str, int] = defaultdict(int)
    for i in items:
        out[i] += 1
    return out


def print_table(rows: dict[str, dict], elapsed: float, n_success: int) -> None:
    head = f"{'suite':<18}{'seeds':>6}{'success':>9}{'len mean':>9}{'p95':>6}{'max':>5}" \
           f"{'plan s':>8}{'sim s':>7}{'wall s':>8}  failures"
    print(head)
    print("-" * len(head))
    for suite, r in rows.items():
        fails = ", ".join(f"{k} x{v}" for k, v in r["reasons"].items()) or "-"
        print(f"{suite:<18}{r['n']:>6}{100 * r['success']:>8.1f}%{r['len_mean']:>9.1f}{r['len_p95']:>6.0f}"
              f"{r['len_max']:>5d}{r['plan_time']:>8.3f}{r['sim_time']:>7.2f}{r['wall_time']:>8.2f}  {fails}")
    print(f"\n{n_success} successful demos in {elapsed:.0f} s: {60 * n_success / max(elapsed, 1e-9):.1f} / min overall")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--suites", nargs="+", default=None, help="default: all eight suites")
    p.add_argument("--seeds", type=int, default=200, help="seeds per suite")
    p.add_argument("--seed-start", type=int, default=0)
    p.add_argument("--num-procs", type=int, default=2)
    p.add_argument("--failures", default=DEFAULT_FAILURES, help="JSONL log of every failure")
    p.add_argument("--records", default=None, help="optional JSONL of every episode")
    p.add_argument("--record-as", default="expert_success", metavar="NAME",
                   help="the figures go to benchmarks/results/NAME.json (default expert_success)")
    args = p.parse_args(argv)
    suites = args.suites or list(_suite_ids())
    jobs = [(s, seed) for s in suites for seed in range(args.seed_start, args.seed_start + args.seeds)]
    if "RSB_DATA_DIR" not in os.environ and any(("HardMath" in s or "General" in s) for s in suites):
        print("note: RSB_DATA_DIR is not set; GSM8K/MMLU suites fall back to the HF cache", file=sys.stderr)

    for path in (args.failures, args.records):
        if path:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            Path(path).write_text("")
    t0 = time.perf_counter()
    records: list[dict] = []
    shares = deal(jobs, args.num_procs)  # round-robin, so every worker sees every suite
    executor = ProcessPool() if len(shares) > 1 else InProcess()
    outcome = executor.run(run_episodes, shares, lambda rec: _collect(rec, records, args))
    if outcome.errors or outcome.interrupted:
        print(f"stopped early: {outcome.errors or 'interrupted'}", file=sys.stderr)
        return 1
    elapsed = time.perf_counter() - t0
    records.sort(key=lambda r: (suites.index(r["suite"]), r["seed"]))
    rows = summarise(records)
    print_table(rows, elapsed, sum(r["success"] for r in records))
    print(f"failures logged to {args.failures}")
    n_success = sum(r["success"] for r in records)
    lengths = np.array([r["steps"] for r in records if r["success"]] or [0])
    plans = np.array([r["plan_time"] for r in records])
    write(args.record_as, {
        "suites": {suite: {k: r[k] for k in ("n", "success", "len_mean", "len_p95", "len_max", "plan_time",
                                             "sim_time", "wall_time")} for suite, r in rows.items()},
        "seeds_per_suite": args.seeds, "episodes": len(records), "failures": len(records) - n_success,
        "lowest_success_pct": round(100 * min(r["success"] for r in rows.values()), 1),
        "demos_per_min": round(60 * n_success / elapsed, 1), "wall_s": round(elapsed, 1),
        "len_min": int(lengths.min()), "len_median": float(np.median(lengths)), "len_max": int(lengths.max()),
        "len_p99": float(np.percentile(lengths, 99)), "plan_s_mean": round(float(plans.mean()), 3),
        "plan_s_p99": round(float(np.percentile(plans, 99)), 3), "plan_s_max": round(float(plans.max()), 3),
        "arms": dict(sorted(_count(r["arm"] for r in records if r["arm"]).items()))})
    return 0 if all(r["success"] >= 0.98 for r in rows.values()) else 1


def _collect(rec: dict, records: list[dict], args) -> None:
    records.append(rec)
    if not rec["success"]:
        with open(args.failures, "a") as f:
            f.write(json.dumps(rec) + "\n")
        print(f"FAIL {rec['suite']} seed {rec['seed']}: {rec['reason']}", file=sys.stderr, flush=True)
    if args.records:
        with open(args.records, "a") as f:
            f.write(json.dumps(rec) + "\n")


if __name__ == "__main__":
    sys.exit(main())
