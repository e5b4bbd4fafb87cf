"""RSB task envs as the task tests build them, and what they read back from one (an episode's fingerprint,
the head camera's image under a perturbation): also run in a fresh process, to compare across processes."""
from __future__ import annotations

import hashlib
import os

import gymnasium as gym
import numpy as np

import rsb_maniskill  # noqa: F401  (registers the envs)
from rsb_maniskill import perturb as P
from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE

HELPERS = os.path.dirname(os.path.abspath(__file__))  # what a fresh process puts on sys.path to import this
SMALL = (64, 48)  # camera size of the image checks: enough pixels to tell levels apart, fast to render
SEED = EVAL_SEED_BASE + 3


def make(suite_id="RSB-Math-4", **kw):
    kw.setdefault("obs_mode", "state")
    if kw["obs_mode"] in ("state", "state_dict", "none"):
        kw.setdefault("render_backend", "none")
    return gym.make(suite_id, **kw)


def _episode_fingerprint(suite_id: str, seed: int) -> dict:
    env = make(suite_id)
    env.reset(seed=seed)
    u = env.unwrapped
    out = dict(
        instruction=u.get_language_instruction()[0],
        target=int(u.target_block[0]),
        question_id=int(u.question_id[0]),
        xy=[round(float(v), 6) for v in u.pool.raw_poses()[0, :, :2].flatten()],
        candidates=list(u.episode_specs[0].candidates),
    )
    env.close()
    return out


def _head(perturb, obs_mode="rgbd", seed=SEED, steps=1):
    env = gym.make("RSB-Math-10", obs_mode=obs_mode, split="test", camera_size=SMALL, perturb=perturb)
    obs, _ = env.reset(seed=seed)
    for _ in range(steps):
        obs, *_ = env.step(env.unwrapped.agent.rest_action()[None])
    out = {}
    if obs_mode != "state":
        out = {k: v[0].cpu().numpy().copy() for k, v in obs["sensor_data"]["head_camera"].items()}
    out["instruction"] = env.unwrapped.get_language_instruction()[0]
    out["state"] = env.unwrapped.get_state_dict()
    env.close()
    return out


def _digest(img: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(img).tobytes()).hexdigest()


def _visual_digests() -> dict[str, str]:
    return {axis: _digest(_head({axis: 2}, obs_mode="rgb")["rgb"]) for axis in P.VISUAL_AXES}
