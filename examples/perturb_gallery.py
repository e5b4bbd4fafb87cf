"""Writes ``docs/gallery/perturb_<axis>.png``: levels 0-3 of each visual robustness axis side by side
from the head camera (the same episode at every level).

    python examples/perturb_gallery.py [--out docs/gallery] [--seed 10000003] [--axes camera lighting ...]

Blocks of RSB-Math-10 (lettered: letters must stay readable) above, everyday objects of
RSB-Math-4-Objects below."""
from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import rsb_maniskill  # noqa: F401,E402
from rsb_maniskill.perturb import LEVELS, VISUAL_AXES  # noqa: E402

ROWS = ("RSB-Math-10", "RSB-Math-4-Objects")


def head_image(env_id: str, axis: str, level: int, seed: int) -> np.ndarray:
    env = gym.make(env_id, obs_mode="rgb", split="test", perturb={axis: level})
    env.reset(seed=seed)
    obs, *_ = env.step(env.unwrapped.agent.rest_action()[None])  # one step: everything at rest
    img = obs["sensor_data"]["head_camera"]["rgb"][0].cpu().numpy()
    env.close()
    return img


def axis_figure(axis: str, seed: int, out: Path) -> Path:
    fig, axes = plt.subplots(len(ROWS), len(LEVELS), figsize=(4 * len(LEVELS), 3.1 * len(ROWS)))
    for r, env_id in enumerate(ROWS):
        for c, level in enumerate(LEVELS):
            ax = axes[r, c]
            ax.imshow(head_image(env_id, axis, level, seed))
            ax.set_xticks([]), ax.set_yticks([])
            if r == 0:
                ax.set_title(f"{axis} = {level}", fontsize=13, fontweight="bold")
            if c == 0:
                ax.set_ylabel(env_id, fontsize=10)
    fig.suptitle(VISUAL_AXES[axis], fontsize=11)
    fig.tight_layout()
    path = out / f"perturb_{axis}.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--out", default="docs/gallery")
    p.add_argument("--seed", type=int, default=10_000_003)
    p.add_argument("--axes", nargs="+", default=list(VISUAL_AXES), choices=list(VISUAL_AXES))
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for axis in args.axes:
        print(f"wrote {axis_figure(axis, args.seed, out)}")


if __name__ == "__main__":
    main()
