"""Every camera of K CPU envs in one render call (rsb_maniskill.vector) against each scene's own render,
over a grid of processes x K, and `rsb eval` end to end.

    python benchmarks/batched_render.py [--procs 1 2] [--envs 1 4] [--steps 20] [--suite RSB-Math-4]
                                        [--camera-size 320 240] [--eval-episodes 0]
    python benchmarks/batched_render.py --fake-render [--envs 4] [--steps 30]

For each (P processes, K envs a process) it starts P spawned workers, each with a vector env of K envs
of SUITE (rgb, three cameras), and prints per batch of K: the physics (a step of every env without
rendering), the render of every camera per scene (ManiSkill's path, the one lavapipe has) and in one
group call (a SAPIEN RenderSystemGroup; only where CUDA rendering exists: "n/a" and why otherwise),
the group's rebuild after a reset (a CPU reset makes fresh scenes) and the aggregate rgb env-steps/s
of all P workers stepping and rendering every step with the renderer auto picks. With
``--eval-episodes N`` it then times ``rsb eval random -o rgb`` (chunks of one action: a render every
step) with each (P, K) on N episodes of 20 steps, start-up included. Nothing asserts a speed.

``--fake-render``: the pack's own cost around the render, on any machine: one process, a vector env
whose group is a stand-in returning preallocated pictures of the right shapes (zero-cost render),
and per batch of K: the physics (steps without observations), the observation (``get_obs(info)``
with the last step's info, as the eval loop asks: state parts, the pictures handed over, ManiSkill's
dict) and the loop (``step`` with its observation).
The workers of the grid start their timed run together at a barrier (every worker's imports and envs
done), not after a fixed wait.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import subprocess
import sys
import tempfile
import time

from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/


class FakeGroup:
    """A camera group whose render costs nothing: the pictures of every camera of K envs, preallocated
    once, of the shapes and dtype the scenes' own render gives (textures the obs mode reads only)."""

    def __init__(self, bases) -> None:
        import torch

        from rsb_maniskill import compat
        from rsb_maniskill.sim import camera_group

        needed = getattr(compat, "needed_textures", None)  # absent before issue 57: every texture
        cams, textures = camera_group.scene_cameras(bases[0])
        if needed is not None:
            textures = needed(bases[0])
        self.pictures = {}
        for name, comps in cams.items():
            h, w = comps[0].height, comps[0].width
            self.pictures[name] = {t: torch.zeros((len(bases), h, w, 4), dtype=torch.uint8) for t in textures[name]}

    def render(self, textures=None):
        return self.pictures


def fake_render(suite: str, k: int, steps: int, size: list[int]) -> list:
    import torch

    from rsb_maniskill.vector import RSBVectorEnv
    from rsb_maniskill.vector.env import GroupRenderer

    env = RSBVectorEnv(suite, k, obs_mode="rgb", camera_size=tuple(size), renderer=GroupRenderer(FakeGroup))
    try:
        env.reset(seed=list(range(k)))
        action = torch.zeros(env.action_space.shape)

        def timed(fn):
            fn()
            t = time.perf_counter()
            for _ in range(steps):
                fn()
            return 1000 * (time.perf_counter() - t) / steps

        with env.skip_observations():
            physics = timed(lambda: env.step(action))
        info = env.step(action)[4]
        obs = timed(lambda: env.get_obs(info))  # the last step's info, as the eval loop hands it
        loop = timed(lambda: env.step(action))
    finally:
        env.close()
    print(f"{suite}, rgb, K = {k}, 3 cameras {size[0]}x{size[1]}, zero-cost pictures, {steps} batches (ms per batch)")
    print("| K | step (physics) | observation (get_obs) | loop (step + observation) |")
    print("|---|---:|---:|---:|")
    print(f"| {k} | {physics:.1f} | {obs:.1f} | {loop:.1f} |", flush=True)
    return [k, f"{physics:.1f}", f"{obs:.1f}", f"{loop:.1f}"]


def _worker(args: tuple) -> dict:
    suite, k, steps, size, barrier = args
    import torch

    from rsb_maniskill.sim.camera_group import group_rendering_unavailable
    from rsb_maniskill.vector import RSBVectorEnv
    from rsb_maniskill.vector.env import GroupRenderer, PerSceneRenderer

    env = RSBVectorEnv(suite, k, obs_mode="rgb", camera_size=tuple(size), renderer="per_scene")
    out: dict = {"group_unavailable": group_rendering_unavailable()}
    try:
        env.reset(seed=list(range(k)))
        action = torch.zeros(env.action_space.shape)
        sync = torch.cuda.synchronize if torch.cuda.is_available() else (lambda: None)

        def timed(fn, n):
            fn()  # warm
            sync()
            t = time.perf_counter()
            for _ in range(n):
                fn()
            sync()
            return (time.perf_counter() - t) / n

        with env.skip_observations():
            out["physics_s"] = timed(lambda: env.step(action), steps)
        out["per_scene_s"] = timed(env.get_obs, steps)
        if out["group_unavailable"] is None:
            group = env.renderer = GroupRenderer()
            out["group_s"] = timed(env.get_obs, steps)
            t = time.perf_counter()
            env.reset(seed=list(range(k, 2 * k)))  # rebuilds the scenes, the group at its render
            sync()
            out["reset_and_group_s"] = time.perf_counter() - t
            out["group_rebuilds"] = group.rebuilds
        else:
            env.renderer = PerSceneRenderer()
        barrier.wait()  # all workers start the throughput run together, once all are ready
        t0 = time.time()
        for _ in range(steps):
            env.step(action)
        sync()
        out["t0"], out["t1"] = t0, time.time()
        out["renderer"] = env.renderer.name
    finally:
        env.close()
    return out


def grid(suite: str, procs: list[int], envs: list[int], steps: int, size: list[int]) -> list[list[str]]:
    ctx = mp.get_context("spawn")
    print(f"{suite}, rgb, 3 cameras {size[0]}x{size[1]}, {steps} steps; times per batch of K envs (ms)")
    print("| procs x K | physics | render per scene | render group | reset + group rebuild | "
          "aggregate rgb env-steps/s (renderer) |")
    print("|---|---:|---:|---:|---:|---:|")
    why, rows = None, []
    for p in procs:
        for k in envs:
            with ctx.Manager() as manager, ctx.Pool(p) as pool:
                barrier = manager.Barrier(p)  # every worker's imports and envs done: the timed runs start
                res = pool.map(_worker, [(suite, k, steps, size, barrier)] * p)
            wall = max(r["t1"] for r in res) - min(r["t0"] for r in res)
            rate = p * k * steps / wall

            def ms(key):
                vals = [r[key] for r in res if key in r]
                return f"{1000 * sum(vals) / len(vals):.1f}" if vals else "n/a"

            why = res[0]["group_unavailable"]
            rows.append([f"{p} x {k}", ms("physics_s"), ms("per_scene_s"), ms("group_s"), ms("reset_and_group_s"),
                         f"{rate:.1f} ({res[0]['renderer']})"])
            print("| " + " | ".join(rows[-1]) + " |", flush=True)
    if why:
        print(f"group: n/a: {why}")
    return rows


def eval_end_to_end(suite: str, procs: list[int], envs: list[int], episodes: int) -> list[list[str]]:
    print(f"\nrsb eval random -o rgb, {suite}, {episodes} episodes x 20 steps (start-up included)")
    print("| procs x K | wall s | env-steps/s |")
    print("|---|---:|---:|")
    rows = []
    for p in procs:
        for k in envs:
            with tempfile.TemporaryDirectory() as out:
                cmd = [sys.executable, "-m", "rsb_maniskill.cli", "eval", "random", "-o", "rgb", "--suites", suite,
                       "-n", str(episodes), "--max-steps", "20", "--num-envs", str(k), "--num-procs", str(p),
                       "--out", out, "-q"]
                t = time.perf_counter()
                rc = subprocess.run(cmd, capture_output=True, text=True).returncode
                wall = time.perf_counter() - t
            said = f"{episodes * 20 / wall:.1f}" + ("" if rc == 0 else f" (exit {rc})")
            rows.append([f"{p} x {k}", f"{wall:.1f}", said])
            print("| " + " | ".join(rows[-1]) + " |", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--suite", default="RSB-Math-4")
    ap.add_argument("--procs", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--envs", type=int, nargs="+", default=[1, 4])
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--camera-size", type=int, nargs=2, default=[320, 240])
    ap.add_argument("--eval-episodes", type=int, default=0)
    ap.add_argument("--fake-render", action="store_true",
                    help="one process, zero-cost pictures: the step, observation and loop costs per batch")
    args = ap.parse_args()
    print(json.dumps({"cpus": len(os.sched_getaffinity(0))}))
    if args.fake_render:
        rows = [fake_render(args.suite, k, args.steps, args.camera_size) for k in args.envs]
        write("batched_render_fake", {"suite": args.suite, "steps": args.steps, "table": table(
            ["K", "step (physics)", "observation (get_obs)", "loop (step + observation)"], rows, "rrrr")})
        return
    tables = {"grid": table(["procs x K", "physics", "render per scene", "render group", "reset + group rebuild",
                             "aggregate rgb env-steps/s (renderer)"],
                            grid(args.suite, args.procs, args.envs, args.steps, args.camera_size), "lrrrrr")}
    if args.eval_episodes:
        tables["eval"] = table(["procs x K", "wall s", "env-steps/s"],
                               eval_end_to_end(args.suite, args.procs, args.envs, args.eval_episodes), "lrr")
    write("batched_render", {"suite": args.suite, "steps": args.steps, "tables": tables})


if __name__ == "__main__":
    main()
