"""Every GPU figure of the batched path in one short run, on a machine with an NVIDIA GPU:

    python benchmarks/gpu_check.py [--procs 16] [--envs 4] [--episodes 128]

from the project root, in a venv with this package installed (``bash scripts/setup.sh``: on an NVIDIA
machine it also stages SAPIEN's PhysX GPU library). It prints, each as soon as it is measured, on
RSB-Math-4 (three 320x240 cameras, rendering every step), and records them in
``benchmarks/results/gpu_check.json`` (``benchmarks/recorded.py``; docs/gpu.md's table of GPU figures
shows that file once it exists):

1. the GPU tests: ``pytest -m gpu tests/vector tests/sim`` (the group's images against each scene's own);
2. the raw ceiling: PROCS spawned workers x ENVS envs, each stepping its vector env (physics, random
   actions) and rendering every camera in one group call, ``torch.cuda.synchronize()``, nothing else;
   aggregate env-steps/s, the workers started together at a barrier once all are built;
3. ``rsb eval random -o rgb`` with its defaults (``--num-envs auto``, ``--num-procs auto``) on
   EPISODES episodes: its own throughput line (start-up, steady env-steps/s) and the wall time;
4. the ratio eval steady / ceiling (the target: >= 0.85, and >= 2,000 env-steps/s on 16 cores);
5. training-set rendering (``export/render_demos.py``, K episodes a process set and observed in one
   call): recorded env states of random episodes, rendered by PROCS workers, frames/s in all
   (the target: >= 2,200).

Where CUDA rendering is absent it stops at once with one line saying so (exit status 2).
``--dry-run`` runs every stage on this machine instead, small (two workers, a stand-in group whose
pictures cost nothing, 32x24 cameras, a few steps, the GPU tests collected, not run): it checks the
script, not the GPU (its figures mean nothing). Nothing asserts a speed.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SUITE = "RSB-Math-4"
ROOT = Path(__file__).resolve().parent.parent
BARRIER_TIMEOUT_S = 600  # every worker's imports and envs, on a loaded 16-core box


def no_cuda_reason() -> str | None:
    """Why this machine cannot give the GPU figures, or None."""
    import torch

    if not torch.cuda.is_available():
        return "torch sees no CUDA device"
    from rsb_maniskill.sim.camera_group import group_rendering_unavailable

    return group_rendering_unavailable()


def _renderer(dry: bool):
    from rsb_maniskill.vector.env import GroupRenderer

    if not dry:
        return "group"
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from batched_render import FakeGroup

    return GroupRenderer(FakeGroup)


def _ceiling_worker(args: tuple) -> tuple[float, float]:
    """One worker of the raw ceiling: (t0, t1) of its timed steps, started at the barrier."""
    k, steps, size, dry, barrier = args
    import numpy as np
    import torch

    from rsb_maniskill.vector import RSBVectorEnv

    env = RSBVectorEnv(SUITE, k, obs_mode="rgb", camera_size=tuple(size), renderer=_renderer(dry))
    try:
        env.reset(seed=list(range(k)))
        rng = np.random.default_rng(0)
        low, high = env.single_action_space.low, env.single_action_space.high
        actions = [torch.as_tensor(rng.uniform(low, high, (k, low.shape[0])).astype(np.float32)) for _ in range(steps)]
        sync = torch.cuda.synchronize if torch.cuda.is_available() else (lambda: None)
        with env.skip_observations():
            env.step(actions[0])
        env.renderer.render(env.bases)  # the group built and warm
        sync()
        barrier.wait(BARRIER_TIMEOUT_S)
        t0 = time.time()
        with env.skip_observations():
            for a in actions:
                env.step(a)  # physics only
                env.renderer.render(env.bases)  # every camera of the K envs, one call
                sync()
        return t0, time.time()
    finally:
        env.close()


def _pool_run(fn, procs: int, args: tuple) -> tuple[list, float]:
    """``fn`` in ``procs`` spawned workers that start their timed part together (a barrier);
    returns their results and the aggregate wall time (first start to last end)."""
    ctx = mp.get_context("spawn")
    with ctx.Manager() as manager, ctx.Pool(procs) as pool:
        barrier = manager.Barrier(procs)
        res = pool.map(fn, [(*args, barrier)] * procs)
    return res, max(t1 for t0, t1, *_ in res) - min(t0 for t0, *_ in res)


def _barrier_probe(args: tuple) -> tuple[float, float, float]:
    """For the barrier's test: the worker that makes ``token`` first is slow to get ready; (start, end,
    ready) of each."""
    delay, token, barrier = args
    try:
        os.close(os.open(token, os.O_CREAT | os.O_EXCL))
        time.sleep(delay)
    except FileExistsError:
        pass
    ready = time.time()
    barrier.wait(BARRIER_TIMEOUT_S)
    return time.time(), time.time(), ready


def gpu_tests(dry: bool) -> str:
    cmd = [sys.executable, "-m", "pytest", "-m", "gpu", "-q", "-p", "no:cacheprovider", "tests/vector", "tests/sim"]
    if dry:
        cmd.append("--collect-only")
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    lines = [ln for ln in res.stdout.strip().splitlines() if ln.strip()]
    fails = [ln for ln in lines if ln.startswith(("FAILED", "ERROR"))]
    last = lines[-1] if lines else (res.stderr.strip().splitlines() or ["(no output)"])[-1]  # e.g. no pytest
    return "\n".join([*fails, f"{last} (exit {res.returncode})"])


def ceiling(procs: int, k: int, steps: int, size: list[int], dry: bool) -> float:
    _, wall = _pool_run(_ceiling_worker, procs, (k, steps, size, dry))
    return procs * k * steps / wall


def eval_defaults(episodes: int, max_steps: int | None, size: list[int] | None, dry: bool) -> tuple[float, str]:
    """``rsb eval random -o rgb`` with the defaults: (steady env-steps/s, its throughput line + wall)."""
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "rsb_maniskill.cli", "eval", "random", "-o", "rgb", "--suites", SUITE,
               "-n", str(episodes), "--out", out, "-q"]
        if max_steps:
            cmd += ["--max-steps", str(max_steps)]
        if size:
            cmd += ["-e", f"camera_size=[{size[0]},{size[1]}]"]
        if dry:
            cmd += ["--num-procs", "1"]
        t = time.perf_counter()
        res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        wall = time.perf_counter() - t
    line = next((ln for ln in res.stdout.splitlines() if ln.startswith("throughput:")), None)
    plan = [ln for ln in res.stderr.splitlines() if ln.startswith(("envs:", "workers:"))]
    if res.returncode != 0 or line is None:
        raise SystemExit(f"gpu_check: rsb eval failed (exit {res.returncode}):\n{res.stderr[-3000:]}")
    steady = float(re.search(r"then ([\d,.]+) env-steps/s", line).group(1).replace(",", ""))
    return steady, "\n".join([*plan, line, f"wall {wall:.1f} s (start-up included)"])


def record_demos(out: Path, episodes: int, steps: int, size: list[int] | None) -> Path:
    """Env states of random episodes, as ``rsb generate`` records them (no motion planner: mplib does not
    run on the GPU box): ManiSkill's RecordEpisode on the CPU backend."""
    import gymnasium as gym
    import numpy as np

    from mani_skill.utils.wrappers.record import RecordEpisode

    import rsb_maniskill  # noqa: F401
    from rsb_maniskill.env_ids import CPU_SIM_BACKEND

    kwargs = {"camera_size": tuple(size)} if size else {}
    env = gym.make(SUITE, obs_mode="state", sim_backend=CPU_SIM_BACKEND, max_episode_steps=steps, **kwargs)
    env = RecordEpisode(env, str(out), save_trajectory=True, trajectory_name="demos", save_video=False,
                        record_env_state=True)
    rng = np.random.default_rng(0)
    space = env.unwrapped.single_action_space
    for seed in range(episodes):
        env.reset(seed=seed)
        for _ in range(steps):
            env.step(rng.uniform(space.low, space.high).astype(np.float32)[None] * 0.3)
    env.close()
    return out / "demos.h5"


def _render_worker(args: tuple) -> tuple[float, float, int]:
    h5, k, barrier = args
    from rsb_maniskill.export.render_demos import close_render_env, render_episodes

    list(render_episodes(Path(h5), ("head", "left_wrist", "right_wrist"), 1, num_envs=k))  # the envs built, warm
    barrier.wait(BARRIER_TIMEOUT_S)
    t0 = time.time()
    frames = sum(len(ep.state) for ep in render_episodes(Path(h5), ("head", "left_wrist", "right_wrist"), 1,
                                                         num_envs=k))
    t1 = time.time()
    close_render_env()
    return t0, t1, frames


def training_frames(procs: int, k: int, episodes: int, steps: int, size: list[int] | None) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        h5 = record_demos(Path(tmp), episodes, steps, size)
        res, wall = _pool_run(_render_worker, procs, (str(h5), k))
    return sum(frames for *_, frames in res) / wall


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--procs", type=int, default=None, help="workers (default: the usable CPUs; 2 with --dry-run)")
    ap.add_argument("--envs", type=int, default=None, help="envs a worker (default: --num-envs auto's, 4; 2 dry)")
    ap.add_argument("--steps", type=int, default=None, help="ceiling steps a worker (default 200; 3 dry)")
    ap.add_argument("--episodes", type=int, default=None, help="rsb eval episodes (default 128; 2 dry)")
    ap.add_argument("--demo-episodes", type=int, default=None, help="recorded episodes (default 8; 2 dry)")
    ap.add_argument("--dry-run", action="store_true", help="every stage here, small, with a stand-in group")
    args = ap.parse_args(argv)
    dry = args.dry_run
    if not dry:
        why = no_cuda_reason()
        if why:
            print(f"gpu_check: error: no GPU figures here: {why}. Run it on a machine with an NVIDIA GPU, from "
                  "the project root in a venv with this package installed (python benchmarks/gpu_check.py), or "
                  "--dry-run to check the script", file=sys.stderr)
            return 2
    from rsb_maniskill.parallel.plan import RENDER_ENVS_PER_PROC
    from rsb_maniskill.parallel.threads import usable_cpus

    procs = args.procs or (2 if dry else usable_cpus())
    k = args.envs or (2 if dry else RENDER_ENVS_PER_PROC)
    steps = args.steps or (3 if dry else 200)
    episodes = args.episodes or (2 if dry else 128)
    demo_eps = args.demo_episodes or (2 if dry else 8)
    size = [32, 24] if dry else None
    t_all = time.perf_counter()
    print(json.dumps({"dry_run": dry, "procs": procs, "envs": k, "cpus": usable_cpus(), "suite": SUITE}), flush=True)
    print(f"1. GPU tests{' (collected only: --dry-run)' if dry else ''}:\n{gpu_tests(dry)}", flush=True)
    raw = ceiling(procs, k, steps, size or [320, 240], dry)
    print(f"2. raw ceiling ({procs} procs x K = {k}, physics + group render, {steps} steps): "
          f"{raw:,.0f} env-steps/s", flush=True)
    steady, said = eval_defaults(episodes, 3 if dry else None, size, dry)
    print(f"3. rsb eval random -o rgb, defaults, {episodes} episodes:\n{said}", flush=True)
    print(f"4. eval / ceiling: {steady / raw:.2f} (steady {steady:,.0f} vs {raw:,.0f} env-steps/s)", flush=True)
    fps = training_frames(procs, k, demo_eps, 3 if dry else 100, size)
    print(f"5. training-set rendering ({procs} procs x K = {k}, render_demos): {fps:,.0f} frames/s", flush=True)
    print(f"gpu_check: {time.perf_counter() - t_all:.0f} s in all", flush=True)
    if not dry:  # a dry run's figures mean nothing
        from recorded import write

        write("gpu_check", {"procs": procs, "envs": k, "suite": SUITE, "raw_ceiling_env_steps_s": round(raw, 1),
                            "eval_steady_env_steps_s": steady, "eval_over_ceiling": round(steady / raw, 3),
                            "eval_said": said, "training_frames_s": round(fps, 1)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
