"""The trained diffusion policy behind ``rsb eval``'s policy interface.

    rsb eval rsb_maniskill.baselines.diffusion_policy:make_policy -a checkpoint=DIR -o state --suites RSB-Direct-4

Each inference denoises a ``pred_horizon`` chunk from the last ``obs_horizon`` observations and
executes ``act_horizon`` of its actions (ManiSkill's receding horizon). The harness shows the
policy an observation only when it asks for one, so a chunk is handed out as ``act_horizon - 1``
actions and then the last one alone: the observation seen in between is the one just before the
next inference's newest, which keeps the history of consecutive frames the network trained on.
"""
from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
import torch

from rsb_maniskill.baselines.diffusion_policy import checkpoint
from rsb_maniskill.baselines.diffusion_policy.data import Normalizer, camera_stack, proprio_vector
from rsb_maniskill.baselines.diffusion_policy.model import DiffusionPolicyNet, ModelConfig, make_scheduler

NOISE_SALT = 0xD1F5  # separates the sampling noise's seed from other users of the episode seed


class DiffusionPolicy:
    """A trained checkpoint as an ``rsb eval`` policy (``reset(instruction, obs)``, ``act(obs)``)."""

    def __init__(self, checkpoint_path: str, scheduler: str = "ddim", inference_steps: int = 10, seed: int = 0,
                 ema: bool = True, threads: int | None = None):
        if threads:
            torch.set_num_threads(int(threads))
        state = checkpoint.load(checkpoint_path)
        self.cfg = ModelConfig(**state["config"])
        self.norm = Normalizer.from_state_dict(state["norm"])
        self.cameras = state["meta"]["cameras"]
        self.control_mode = state["meta"]["control_mode"]
        self.step = state["step"]
        self.net = DiffusionPolicyNet(self.cfg)
        self.net.load_state_dict(state["ema_model" if ema else "model"])
        self.net.eval()
        self.sched = make_scheduler(self.cfg, scheduler)
        self.sched.set_timesteps(self.cfg.num_train_steps if scheduler == "ddpm" else int(inference_steps))
        self.seed = int(seed)
        self.gen = torch.Generator().manual_seed(self.seed)
        self.text = None
        if self.cfg.language:
            from rsb_maniskill.baselines.diffusion_policy.text import TextEncoder

            self.text = TextEncoder()
        self.name = f"diffusion-policy-{self.cfg.obs_mode}{'' if self.cfg.language else '-nolang'}"
        self.history: deque = deque(maxlen=self.cfg.obs_horizon)
        self.pending: np.ndarray | None = None
        self.text_emb: torch.Tensor | None = None

    def reset(self, instruction: str, obs: dict, seed: int | None = None) -> None:
        if seed is not None:  # the episode's noise is a function of its seed, under any --num-envs / order
            self.gen.manual_seed(int(np.random.SeedSequence([NOISE_SALT, self.seed, int(seed)]).generate_state(1)[0]))
        self.history.clear()
        self.pending = None
        if self.text is not None:
            self.text_emb = torch.as_tensor(self.text(instruction))[None]

    def _features(self, obs: Any) -> tuple[np.ndarray, torch.Tensor | None]:
        if self.cfg.obs_mode == "state":
            if isinstance(obs, dict):
                raise ValueError("this checkpoint is a state policy: run `rsb eval ... -o state`")
            vec = np.asarray(obs, dtype=np.float32).reshape(-1)
            if vec.shape[0] != self.cfg.obs_dim:
                raise ValueError(f"this checkpoint was trained on {self.cfg.obs_dim}-d state observations, the env "
                                 f"gives {vec.shape[0]}: evaluate on the suite it was trained on, or retrain on demos "
                                 "recorded with this version")
            return vec, None
        if not isinstance(obs, dict) or "sensor_data" not in obs:
            raise ValueError("this checkpoint is an rgb policy: run `rsb eval ... -o rgb`")
        return proprio_vector(obs), camera_stack(obs, self.cameras, self.cfg.image_size)

    @torch.no_grad()
    def predict(self) -> np.ndarray:
        """(pred_horizon, act_dim) actions in the env's units from the current history."""
        vecs, imgs = zip(*self.history)
        obs = torch.as_tensor(self.norm.norm_obs(np.stack(vecs)), dtype=torch.float32)[None]
        images = torch.stack(imgs)[None].float() / 255.0 if self.cfg.obs_mode == "rgb" else None
        cond = self.net.condition(obs, self.text_emb, images)
        x = torch.randn((1, self.cfg.pred_horizon, self.cfg.act_dim), generator=self.gen)
        for t in self.sched.timesteps:
            eps = self.net(x, t.reshape(1), cond)
            x = self.sched.step(eps, t, x).prev_sample
        return self.norm.unnorm_actions(x[0].numpy())

    def act(self, obs: Any) -> np.ndarray:
        feats = self._features(obs)
        self.history.append(feats)
        while len(self.history) < self.cfg.obs_horizon:  # episode start: repeat the first frame
            self.history.appendleft(feats)
        if self.pending is not None:
            out, self.pending = self.pending, None
            return out
        chunk = self.predict()
        start = self.cfg.obs_horizon - 1  # the action that follows the newest observation
        actions = chunk[start:start + self.cfg.act_horizon].astype(np.float32)
        if len(actions) > 1 and self.cfg.obs_horizon > 1:
            self.pending = actions[-1:]
            return actions[:-1]
        return actions


def make_policy(checkpoint: str, scheduler: str = "ddim", inference_steps: int = 10, seed: int = 0,
                ema: bool = True, threads: int | None = None) -> DiffusionPolicy:
    """``rsb eval rsb_maniskill.baselines.diffusion_policy:make_policy -a checkpoint=DIR [-a inference_steps=10]``."""
    return DiffusionPolicy(checkpoint, scheduler=scheduler, inference_steps=inference_steps, seed=seed, ema=ema,
                           threads=threads)
