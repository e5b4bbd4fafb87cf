"""LeRobot's ``--eval.batch_size B`` through RSB's vector env against gymnasium's SyncVectorEnv of
one-env RSB envs (the old path): seconds per batched step and rgb env-steps/s, as LeRobot's rollout
steps them (numpy Aloha-14 actions in, numpy pixels + agent_pos out, SAME_STEP autoreset).

    python benchmarks/lerobot_vector_env.py [--envs 1 4] [--steps 20] [--suite RSB-Math-4]
                                            [--camera-size 320 240] [--renderer auto]

Where CUDA renders, the vector env renders every camera of the B envs in one call (``auto``: the
group); under lavapipe both render per scene, so the figures there measure the wrapper's overhead.
Nothing asserts a speed.
"""
from __future__ import annotations

import argparse
import time

from recorded import table, write  # benchmarks/recorded.py: the figures to benchmarks/results/


def _time(vector: bool, suite: str, n: int, steps: int, size: tuple[int, int], renderer: str) -> tuple[float, float]:
    from rsb_maniskill.integrations.lerobot_env import create_rsb_envs

    env = create_rsb_envs(suite, n, vector=vector, renderer=renderer, camera_size=size, episodes=max(n, 1),
                          records_dir=None, episode_length=10_000)[suite][0]
    t0 = time.perf_counter()
    obs, _ = env.reset(seed=1000)
    reset_s = time.perf_counter() - t0
    hold = obs["agent_pos"].copy()
    env.step(hold)  # warm-up
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(hold)
    step_s = (time.perf_counter() - t0) / steps
    env.close()
    return reset_s, step_s


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--envs", type=int, nargs="+", default=[1, 4])
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--suite", default="RSB-Math-4")
    p.add_argument("--camera-size", type=int, nargs=2, default=[320, 240])
    p.add_argument("--renderer", default="auto", choices=["auto", "group", "per_scene"])
    a = p.parse_args()
    size = (a.camera_size[0], a.camera_size[1])
    print(f"{a.suite}, rgb {size[0]}x{size[1]} x 3 cameras, {a.steps} steps, renderer {a.renderer}")
    print("| B | path | reset s | s per batched step | rgb env-steps/s |\n|---:|---|---:|---:|---:|")
    rows = []
    for n in a.envs:
        for vector in (False, True):
            reset_s, step_s = _time(vector, a.suite, n, a.steps, size, a.renderer)
            name = "RSBLeRobotVectorEnv" if vector else "SyncVectorEnv of one-env envs"
            rows.append([n, name, f"{reset_s:.2f}", f"{step_s:.3f}", f"{n / step_s:.1f}"])
            print("| " + " | ".join(map(str, rows[-1])) + " |", flush=True)
    write("lerobot_vector_env", {"suite": a.suite, "steps": a.steps, "renderer": a.renderer, "table": table(
        ["B", "path", "reset s", "s per batched step", "rgb env-steps/s"], rows, "rlrrr")})


if __name__ == "__main__":
    main()
