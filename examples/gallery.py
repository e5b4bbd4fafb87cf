"""Writes a head-camera picture of every suite (and an outside view) to docs/gallery/.

    python examples/gallery.py [--out docs/gallery] [--seed 0] [--split test]

Suites that need GSM8K/MMLU read them from $RSB_DATA_DIR (or the Hugging Face cache)."""
from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

import cv2
import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import rsb_maniskill  # noqa: F401,E402
from rsb_maniskill.semantic import SUITE_IDS  # noqa: E402


def render_suite(suite_id: str, seed: int, split: str, out: Path) -> tuple[Path, str]:
    env = gym.make(suite_id, obs_mode="rgb", render_mode="rgb_array", split=split)
    obs, _ = env.reset(seed=seed)
    obs, *_ = env.step(env.unwrapped.agent.rest_action()[None])
    head = obs["sensor_data"]["head_camera"]["rgb"][0].numpy()
    path = out / f"{suite_id}.png"
    cv2.imwrite(str(path), head[..., ::-1])
    if suite_id == "RSB-Math-10":
        cv2.imwrite(str(out / "outside_view.png"), env.render()[0].numpy()[..., ::-1])
    instruction = env.unwrapped.get_language_instruction()[0]
    env.close()
    return path, instruction


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--out", default="docs/gallery")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--split", default="test")
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, 4, figsize=(20, 11))
    for ax, suite_id in zip(axes.T.flat, SUITE_IDS):
        path, instruction = render_suite(suite_id, args.seed, args.split, out)
        ax.imshow(cv2.imread(str(path))[..., ::-1])
        ax.set_title(suite_id, fontsize=13, fontweight="bold")
        ax.set_xticks([]), ax.set_yticks([])
        ax.set_xlabel("\n".join(textwrap.wrap(instruction, 62)[:7]), fontsize=7.5, loc="left")
        print(f"wrote {path}")
    fig.tight_layout()
    fig.savefig(out / "overview.png", dpi=80)
    print(f"wrote {out / 'overview.png'}")


if __name__ == "__main__":
    main()
