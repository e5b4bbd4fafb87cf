"""Writes a head-camera picture of every suite (and an outside view) to docs/gallery/.

    python examples/gallery.py [--out docs/gallery] [--seed 0] [--split test] [--targets blocks|objects]

Blocks: ``RSB-*.png`` and ``overview.png``. Objects: ``RSB-*-Objects.png``, ``overview_objects.png``
and ``objects.png`` (every category, cut out of the head camera). Suites that need GSM8K/MMLU
read them from $RSB_DATA_DIR (or the Hugging Face cache)."""
from __future__ import annotations

import argparse
import textwrap
from pathlib import Path

import cv2
import gymnasium as gym
import matplotlib
import numpy as np
import torch

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import rsb_maniskill  # noqa: F401,E402
from rsb_maniskill.objects.catalog import CATEGORY_KEYS, NUM_VARIANTS, category_name  # noqa: E402
from rsb_maniskill.objects.family import OBJECTS_SUFFIX  # noqa: E402
from rsb_maniskill.semantic import SUITE_IDS  # noqa: E402

TILE = 72  # head-camera pixels around each object in objects.png


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


def _pixel(obs, xyz: torch.Tensor) -> tuple[int, int]:
    """Head-camera pixel (u, v) of a world point."""
    param = obs["sensor_param"]["head_camera"]
    cam = param["extrinsic_cv"][0] @ torch.cat([xyz, torch.ones(1)])
    uvw = param["intrinsic_cv"][0] @ cam
    return int(uvw[0] / uvw[2]), int(uvw[1] / uvw[2])


def render_categories(out: Path) -> Path:
    """Every category, variants taking turns, ten at a time on the table, cut out of the head camera."""
    env = gym.make("RSB-Direct-10" + OBJECTS_SUFFIX, obs_mode="rgb", split="test")
    u = env.unwrapped
    tiles = []
    for start in range(0, len(CATEGORY_KEYS), 10):
        cats = list(CATEGORY_KEYS[start:start + 10])
        keys = [f"{c}:{(start + i) % NUM_VARIANTS}" for i, c in enumerate(cats)]
        filler = [f"{c}:0" for c in CATEGORY_KEYS if c not in cats][:10 - len(keys)]
        env.reset(seed=0)
        u.pool.assign(0, keys + filler)
        u._place_candidates(torch.tensor([0]))
        for _ in range(3):
            obs, *_ = env.step(u.agent.rest_action()[None])
        rgb = obs["sensor_data"]["head_camera"]["rgb"][0].numpy()
        pad = np.pad(rgb, ((TILE, TILE), (TILE, TILE), (0, 0)), mode="edge")
        poses = u.pool.raw_poses()[0]
        for i, key in enumerate(keys):
            x, y = _pixel(obs, poses[i, :3] + torch.tensor([0.0, 0.0, 0.02]))
            tiles.append((category_name(key), pad[y + TILE // 2:y + 3 * TILE // 2, x + TILE // 2:x + 3 * TILE // 2]))
    env.close()
    fig, axes = plt.subplots(4, 6, figsize=(12, 8.6))
    for ax, (name, tile) in zip(axes.flat, tiles):
        ax.imshow(tile)
        ax.set_title(name, fontsize=11)
        ax.set_xticks([]), ax.set_yticks([])
    fig.tight_layout()
    path = out / "objects.png"
    fig.savefig(path, dpi=80)
    return path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--out", default="docs/gallery")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--split", default="test")
    p.add_argument("--targets", default="blocks", choices=("blocks", "objects"))
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    objects = args.targets == "objects"
    if objects:
        print(f"wrote {render_categories(out)}")
    fig, axes = plt.subplots(2, 4, figsize=(20, 11))
    for ax, suite_id in zip(axes.T.flat, SUITE_IDS):
        env_id = suite_id + OBJECTS_SUFFIX if objects else suite_id
        path, instruction = render_suite(env_id, args.seed, args.split, out)
        ax.imshow(cv2.imread(str(path))[..., ::-1])
        ax.set_title(env_id, fontsize=13, fontweight="bold")
        ax.set_xticks([]), ax.set_yticks([])
        ax.set_xlabel("\n".join(textwrap.wrap(instruction, 62)[:7]), fontsize=7.5, loc="left")
        print(f"wrote {path}")
    fig.tight_layout()
    overview = out / ("overview_objects.png" if objects else "overview.png")
    fig.savefig(overview, dpi=80)
    print(f"wrote {overview}")


if __name__ == "__main__":
    main()
