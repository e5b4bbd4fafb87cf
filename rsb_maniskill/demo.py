"""`rsb demo`: the README's first command. Builds the robot at the table and writes what its
cameras see, so that a fresh install can be checked by eye."""
from __future__ import annotations

import argparse
from pathlib import Path

DEFAULT_OUT = "outputs/demo"


def register(subparsers) -> None:
    p = subparsers.add_parser("demo", help="render the robot at the table from every camera")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"output directory (default: {DEFAULT_OUT})")
    p.add_argument("--env", default="RSB-TableTop-v1", help="environment id to render")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def save_camera_pictures(env, obs: dict, out: Path, prefix: str = "") -> list[Path]:
    """Writes each camera's RGB frame of env 0, and the outside view, as PNGs."""
    import cv2

    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, data in obs["sensor_data"].items():
        path = out / f"{prefix}{name}.png"
        cv2.imwrite(str(path), data["rgb"][0].cpu().numpy()[..., ::-1])
        paths.append(path)
    path = out / f"{prefix}outside_view.png"
    cv2.imwrite(str(path), env.render()[0].cpu().numpy()[..., ::-1])
    paths.append(path)
    return paths


def run(args: argparse.Namespace) -> int:
    import gymnasium as gym

    import rsb_maniskill  # noqa: F401  (registers the envs)
    from rsb_maniskill._render import ensure_renderer

    ensure_renderer()
    env = gym.make(args.env, obs_mode="rgb", render_mode="rgb_array")
    obs, _ = env.reset(seed=args.seed)
    hold = env.unwrapped.agent.rest_action()[None]
    for _ in range(5):  # let the rest pose settle before taking pictures
        obs, *_ = env.step(hold)
    for path in save_camera_pictures(env.unwrapped, obs, Path(args.out)):
        print(f"wrote {path}")
    env.close()
    return 0
