"""Steps per second and reset time of the RSB tasks beside ManiSkill's PickCube-v1, in one run.

    python benchmarks/task_speed.py [--steps 300] [--rgb-steps 40]

Each env runs on the CPU backend (one env per process, as physx_cpu does) with random actions
around the robot's rest pose; the ratio column compares with PickCube-v1 measured in the same run.
The issue's target: RSB state-obs steps/s >= 0.6x PickCube-v1's.
"""
from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch

import mani_skill.envs  # noqa: F401
import rsb_maniskill  # noqa: F401

ENVS = ("PickCube-v1", "RSB-Math-4", "RSB-Math-10")


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
    args = p.parse_args()
    rows = {}
    for env_id in ENVS:
        s_sps, s_reset = measure(env_id, "state", args.steps)
        r_sps, _ = measure(env_id, "rgb", args.rgb_steps, resets=1)
        rows[env_id] = (s_sps, r_sps, s_reset)
    base_s, base_r, _ = rows["PickCube-v1"]
    print(f"torch threads: {torch.get_num_threads()}")
    print("| env | state steps/s | ratio to PickCube | rgb steps/s | ratio to PickCube | reset (ms) |")
    print("|---|---:|---:|---:|---:|---:|")
    for env_id, (s, r, reset) in rows.items():
        print(f"| {env_id} | {s:.0f} | {s / base_s:.2f} | {r:.1f} | {r / base_r:.2f} | {reset:.1f} |")
    print("PickCube-v1 rgb: one 128x128 camera; RSB rgb: head + two wrist cameras at 320x240.")


if __name__ == "__main__":
    main()
