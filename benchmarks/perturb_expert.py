"""Success of the scripted expert at every level of every visual robustness axis.

    python benchmarks/perturb_expert.py [--suites RSB-Math-4 RSB-Math-10 RSB-Math-4-Objects] [--seeds 50]
        [--image-seeds 20] [--axes camera clutter ...] [--num-procs 1] [--out outputs/perturb_expert.json]

Runs ``ScriptedExpert(env).run()`` on the evaluation seeds (10,000,000 + i, test split) of each
suite, once unperturbed (level 0, the same episodes for every axis) and at levels 1-3 of each visual
axis, with state observations and the renderer on (so lights, materials and cameras are built and
set as in an rgb run; the expert reads no image). Success is the env's own ``info["success"]``.
Prints per suite, axis and level the success rate with its Wilson 95 % interval, then per axis and
level over all suites; exits 1 when a level falls below the target (97 %): a failure under a
perturbation must be the policy's.

The image-only axes (camera, lighting, table, noise, candidate) leave the physics alone (the state
after the same actions equals level 0, tests/tasks/test_perturb.py), so the expert's trajectory there is
level 0's: ``--image-seeds`` runs fewer seeds on them as a check; ``--seeds`` is for the axes that
change the physics (clutter, robot_init) and for level 0.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

from rsb_maniskill.parallel.pool import InProcess, ProcessPool

TARGET = 0.97
DEFAULT_SUITES = ("RSB-Math-4", "RSB-Math-10", "RSB-Math-4-Objects")

IMAGE_ONLY = ("camera", "lighting", "table", "noise", "candidate")

_ENVS: dict = {}


def _env(suite: str, axis: str, level: int):
    key = (suite, axis, level)
    if key not in _ENVS:
        import gymnasium as gym

        import rsb_maniskill  # noqa: F401

        for old in list(_ENVS):  # one env at a time per worker: memory stays flat
            _ENVS.pop(old).close()
        perturb = {axis: level} if level else None
        _ENVS[key] = gym.make(suite, obs_mode="state", split="test", perturb=perturb)
    return _ENVS[key]


def run_jobs(jobs: list[tuple[str, str, int, int]], emit) -> None:
    import torch

    from rsb_maniskill.motionplan import ScriptedExpert

    torch.set_num_threads(1)
    for suite, axis, level, seed in jobs:
        env = _env(suite, axis, level)
        t0 = time.perf_counter()
        env.reset(seed=seed)
        try:
            res = ScriptedExpert(env).run()
            ok, reason = bool(res.success), res.reason
        except Exception as e:  # a crash is a failure with a reason
            ok, reason = False, f"error:{type(e).__name__}:{e}"
        emit(dict(suite=suite, axis=axis, level=level, seed=seed, success=ok, reason=reason,
                  wall=time.perf_counter() - t0))


def main() -> int:
    from rsb_maniskill.evaluation.metrics import wilson_interval
    from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
    from rsb_maniskill.perturb import VISUAL_AXES

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--suites", nargs="+", default=list(DEFAULT_SUITES))
    p.add_argument("--axes", nargs="+", default=list(VISUAL_AXES), choices=list(VISUAL_AXES))
    p.add_argument("--seeds", type=int, default=50, help="episodes per suite and level of clutter and robot_init, "
                   "and at level 0")
    p.add_argument("--image-seeds", type=int, default=None,
                   help="episodes per suite and level of the image-only axes (default: --seeds)")
    p.add_argument("--num-procs", type=int, default=1)
    p.add_argument("--out", default="outputs/perturb_expert.json")
    args = p.parse_args()

    n_image = args.seeds if args.image_seeds is None else args.image_seeds
    seeds = [EVAL_SEED_BASE + i for i in range(args.seeds)]

    def axis_seeds(axis: str) -> list[int]:
        return seeds[:n_image] if axis in IMAGE_ONLY else seeds

    jobs = [(s, "none", 0, seed) for s in args.suites for seed in seeds]
    jobs += [(s, a, lv, seed) for s in args.suites for a in args.axes for lv in (1, 2, 3) for seed in axis_seeds(a)]
    size = -(-len(jobs) // args.num_procs)  # contiguous shares: each worker builds few envs
    shards = [jobs[i:i + size] for i in range(0, len(jobs), size)]
    records: list[dict] = []
    t0 = time.perf_counter()
    executor = InProcess() if args.num_procs == 1 else ProcessPool()
    outcome = executor.run(run_jobs, shards, records.append)
    if outcome.errors:
        print(f"worker errors: {outcome.errors}", file=sys.stderr)
    wall = time.perf_counter() - t0

    by = defaultdict(list)
    for r in records:
        by[(r["suite"], r["axis"], r["level"])].append(r)
    rows, worst = [], 1.0
    print(f"{'suite':<22} {'axis':<11} {'level':>5} {'episodes':>8} {'success %':>10} {'95% interval':>16}")
    for suite in args.suites:
        for axis in ["none", *args.axes]:
            for level in ((0,) if axis == "none" else (1, 2, 3)):
                rs = by.get((suite, axis, level), [])
                k, n = sum(r["success"] for r in rs), len(rs)
                lo, hi = wilson_interval(k, n) if n else (float("nan"), float("nan"))
                rate = k / n if n else float("nan")
                worst = min(worst, rate) if n else worst
                fails = sorted({r["reason"] for r in rs if not r["success"]})
                rows.append(dict(suite=suite, axis=axis, level=level, episodes=n, success=rate, low=lo, high=hi,
                                 failures=[(r["seed"], r["reason"]) for r in rs if not r["success"]]))
                print(f"{suite:<22} {axis:<11} {level:>5} {n:>8} {100 * rate:>10.1f} "
                      f"[{100 * lo:5.1f}, {100 * hi:5.1f}]" + (f"  failures: {fails}" if fails else ""))
    pooled = []
    print(f"\nall suites pooled\n{'axis':<11} {'level':>5} {'episodes':>8} {'success %':>10} {'95% interval':>16}")
    for axis in ["none", *args.axes]:
        for level in ((0,) if axis == "none" else (1, 2, 3)):
            rs = [r for (s, a, lv), v in by.items() if a == axis and lv == level for r in v]
            k, n = sum(r["success"] for r in rs), len(rs)
            if not n:
                continue
            lo, hi = wilson_interval(k, n)
            pooled.append(dict(axis=axis, level=level, episodes=n, success=k / n, low=lo, high=hi))
            print(f"{axis:<11} {level:>5} {n:>8} {100 * k / n:>10.1f} [{100 * lo:5.1f}, {100 * hi:5.1f}]")
    print(f"{len(records)} episodes in {wall:.0f} s; worst level {100 * worst:.1f} % (target {100 * TARGET:.0f} %)")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(dict(rows=rows, pooled=pooled, wall_s=wall, seeds=args.seeds, image_seeds=n_image),
                              indent=1) + "\n")
    cell = lambda r: f"{100 * r['success']:.1f} [{100 * r['low']:.1f}, {100 * r['high']:.1f}]"  # noqa: E731
    write("perturb_expert", {
        "suites": args.suites, "episodes": len(records), "failures": sum(not r["success"] for r in records),
        "wall_s": round(wall, 1), "worst_pct": round(100 * worst, 1), "pooled": pooled,
        "table": table(["axis", "level", "episodes", "success % [95 % interval]"],
                       [[f"`{r['axis']}`" if r["axis"] != "none" else "none (level 0)", r["level"], r["episodes"],
                         cell(r)] for r in pooled], "lrrl")})
    return 0 if worst >= TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
