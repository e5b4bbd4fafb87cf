"""Steps per second and reset time of the RSB tasks beside ManiSkill's PickCube-v1, in one run.

    python benchmarks/task_speed.py [--steps 300] [--rgb-steps 40] [--repeats 3]

Each env runs on the CPU backend (one env per process, as physx_cpu does) with random actions
around the robot's rest pose; the ratio column compares with PickCube-v1 measured in the same run,
and each ``-Objects`` suite with the block suite of the same id. Figures are the best of
``--repeats`` passes (the machine may be shared). Targets: RSB state-obs steps/s >= 0.6x
PickCube-v1's; objects >= 0.8x their block suite; reset < 50 ms.
"""
from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch
from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/

import mani_skill.envs  # noqa: F401

import rsb_maniskill  # noqa: F401

ENVS = ("PickCube-v1", "RSB-Math-4", "RSB-Math-10", "RSB-Math-4-Objects", "RSB-Math-10-Objects")


def _actions(env, n: int, rng: np.random.Generator) -> list[torch.Tensor]:
    u = env.unwrapped
    if hasattr(u.agent, "rest_action"):
        base = u.agent.rest_action().numpy()
        noise = rng.uniform(-0.05, 0.05, size=(n, base.shape[0])).astype(np.float32)
        return [torch.as_tensor(base + e)[None] for e in noise]
    return [torch.as_tensor(env.action_space.sample())[None] * 0.1 for _ in range(n)]


def measure(env_id: str, obs_mode: str, steps: int, resets: int = 5) -> tuple[float, float]:
    kw = dict(obs_mode=obs_mode)
    if obs_mode == "state":
        kw["render_backend"] = "none"
    env = gym.make(env_id, **kw)
    env.reset(seed=0)
    actions = _actions(env, steps, np.random.default_rng(0))
    for a in actions[:5]:  # warm-up
        env.step(a)
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    sps = steps / (time.perf_counter() - t)
    t = time.perf_counter()
    for i in range(resets):
        env.reset(seed=i + 1)
    reset_ms = (time.perf_counter() - t) / resets * 1e3
    env.close()
    return sps, reset_ms


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--rgb-steps", type=int, default=40)
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args()
    rows: dict[str, tuple[float, float, float]] = {}
    for _ in range(args.repeats):  # interleaved passes: a busy moment hurts every env alike
        for env_id in ENVS:
            s_sps, s_reset = measure(env_id, "state", args.steps)
            r_sps, _ = measure(env_id, "rgb", args.rgb_steps, resets=1)
            old = rows.get(env_id, (0.0, 0.0, float("inf")))
            rows[env_id] = (max(old[0], s_sps), max(old[1], r_sps), min(old[2], s_reset))
    base_s, base_r, _ = rows["PickCube-v1"]
    print(f"torch threads: {torch.get_num_threads()}")
    print("| env | state steps/s | ratio to PickCube | ratio to blocks | rgb steps/s | ratio to PickCube "
          "| reset (ms) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    cells = []
    for env_id, (s, r, reset) in rows.items():
        blocks = rows.get(env_id.removesuffix("-Objects"))
        vs_blocks = f"{s / blocks[0]:.2f}" if env_id.endswith("-Objects") and blocks else ""
        cells.append([env_id, f"{s:.0f}", f"{s / base_s:.2f}", vs_blocks, f"{r:.1f}", f"{r / base_r:.2f}",
                      f"{reset:.1f}"])
        print("| " + " | ".join(cells[-1]) + " |")
    print("PickCube-v1 rgb: one 128x128 camera; RSB rgb: head + two wrist cameras at 320x240.")
    write("task_speed", {
        "envs": {env_id: {"state_steps_s": round(s, 1), "rgb_steps_s": round(r, 2), "reset_ms": round(reset, 2)}
                 for env_id, (s, r, reset) in rows.items()},
        "torch_threads": torch.get_num_threads(),
        "table": table(["env", "state steps/s", "ratio to PickCube", "ratio to blocks", "rgb steps/s",
                        "ratio to PickCube", "reset (ms)"], cells)})


if __name__ == "__main__":
    main()
