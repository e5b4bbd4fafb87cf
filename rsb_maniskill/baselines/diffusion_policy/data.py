"""Demonstrations as the diffusion policy trains on them: ``rsb generate`` trajectory pairs
(``X.h5`` + ``X.json``) read as they are, cut into (obs history, action chunk) windows.

Actions are the recorded controller targets (``pd_joint_pos`` by default, or a file converted
with ManiSkill's replay tool), scaled to [-1, 1] per dimension; state observations are
standardised. The instruction of each episode comes from its JSON entry, together with its
paraphrases: the same episode worded by every template of its instruction set (the training set's
"seen" templates), which a language-conditioned policy trains on so that it reads the block named
rather than the wording (the evaluation's held-out wording is never among them).
"""
from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import h5py
import numpy as np
import torch

from rsb_maniskill.motionplan.dataset import DatasetError, check_pair
from rsb_maniskill.semantic.paraphrase import paraphrases as semantic_paraphrases
from rsb_maniskill.semantic.spec import EpisodeSpec

SPEC_FIELDS = tuple(f.name for f in dataclasses.fields(EpisodeSpec))

PROPRIO_GROUPS = ("agent", "extra")  # rgb variant: the vector beside the images


def proprio_vector(obs: Mapping[str, Any]) -> np.ndarray:
    """The robot's own state from a nested (rgb-mode) observation: ``agent`` and ``extra`` entries
    in sorted key order, flattened over the last axes (leading time axis kept if there is one)."""
    parts = []
    for group in PROPRIO_GROUPS:
        for key in sorted(obs.get(group, {})):
            parts.append(np.asarray(obs[group][key], dtype=np.float32))
    lead = parts[0].ndim - 1 if parts[0].ndim > 1 else 0
    return np.concatenate([p.reshape(*p.shape[:lead], -1) if lead else p.reshape(-1) for p in parts], axis=-1)


def camera_names(obs: Mapping[str, Any]) -> list[str]:
    return sorted(k for k, v in obs.get("sensor_data", {}).items() if "rgb" in v)


def camera_stack(obs: Mapping[str, Any], cameras: Sequence[str], size: int) -> torch.Tensor:
    """(..., 3 * cameras, size, size) uint8 from the cameras' (..., H, W, 3) rgb frames."""
    frames = []
    for cam in cameras:
        rgb = torch.as_tensor(np.asarray(obs["sensor_data"][cam]["rgb"]))
        lead = rgb.shape[:-3]
        x = rgb.reshape(-1, *rgb.shape[-3:]).permute(0, 3, 1, 2).float()
        x = torch.nn.functional.interpolate(x, size=(size, size), mode="area")
        frames.append(x.round().clamp(0, 255).to(torch.uint8).reshape(*lead, 3, size, size))
    return torch.cat(frames, dim=-3)


def _read_group(g: h5py.Group | h5py.Dataset) -> Any:
    if isinstance(g, h5py.Dataset):
        return g[()]
    return {k: _read_group(v) for k, v in g.items() if k != "sensor_param"}


@dataclass
class Episode:
    obs: np.ndarray  # (T+1, obs_dim) state or proprioception
    actions: np.ndarray  # (T, act_dim)
    instruction: str
    images: torch.Tensor | None = None  # (T+1, 3 * cameras, S, S) uint8, rgb variant
    paraphrases: tuple[str, ...] = ()  # the instruction in every template of its set (it among them)


def paraphrases(entry: Mapping[str, Any]) -> tuple[str, ...]:
    """The episode's wordings from its JSON entry (:func:`rsb_maniskill.semantic.paraphrase.paraphrases`):
    only the recorded one, with a warning, when the entry cannot be reworded (demos of another version)."""
    try:
        return semantic_paraphrases(EpisodeSpec.from_dict({k: entry[k] for k in SPEC_FIELDS if k in entry}))
    except (ValueError, KeyError, TypeError):
        warnings.warn("an episode's instruction cannot be reworded from its json entry (demos of another "
                      "rsb_maniskill version?): training on its recorded wording only", stacklevel=2)
        return (entry["instruction"],)


@dataclass
class DemoSet:
    episodes: list[Episode]
    control_mode: str
    env_id: str
    cameras: list[str]


def load_demos(paths: Sequence[str | Path], obs: str = "state", image_size: int = 64,
               max_episodes: int | None = None) -> DemoSet:
    """Reads trajectory pairs; every file must share one control mode and record ``obs``."""
    if obs not in ("state", "rgb"):
        raise ValueError(f"--obs must be 'state' or 'rgb', got {obs!r}")
    episodes: list[Episode] = []
    control_modes, env_ids, cameras = set(), set(), None
    for path in paths:
        meta = check_pair(path)
        kwargs = meta["env_info"].get("env_kwargs", {})
        control_modes.add(kwargs.get("control_mode") or meta["episodes"][0].get("control_mode"))
        env_ids.add(meta["env_info"]["env_id"])
        recorded = kwargs.get("obs_mode", "state")
        wanted = "state" if obs == "state" else "rgb"
        if (obs == "state") != (recorded in ("state", "state_dict")) or (obs == "rgb" and "rgb" not in recorded):
            raise DatasetError(f"{path}: recorded with obs_mode {recorded!r}, but --obs {obs} needs '{wanted}' "
                               f"(record with `rsb generate -o {wanted}` or convert with `rsb replay -o {wanted}`)")
        with h5py.File(path, "r") as f:
            for ep in meta["episodes"]:
                if max_episodes is not None and len(episodes) >= max_episodes:
                    break
                if "instruction" not in ep:
                    raise DatasetError(f"{path}: episode {ep['episode_id']} has no 'instruction' in the json; files "
                                       "written by ManiSkill's replay tool lose it: convert with `rsb replay`, or "
                                       "call rsb_maniskill.motionplan.replay.carry_metadata(source, replayed)")
                g = f[f"traj_{ep['episode_id']}"]
                actions = np.asarray(g["actions"], dtype=np.float32)
                if obs == "state":
                    o = g["obs"]
                    if not isinstance(o, h5py.Dataset):
                        raise DatasetError(f"{path}: 'obs' is not a flat state vector (recorded as {recorded!r})")
                    episodes.append(Episode(np.asarray(o, dtype=np.float32), actions, ep["instruction"],
                                            paraphrases=paraphrases(ep)))
                else:
                    tree = _read_group(g["obs"])
                    cams = camera_names(tree)
                    if cameras is None:
                        cameras = cams
                    elif cams != cameras:
                        raise DatasetError(f"{path}: cameras {cams} differ from {cameras}")
                    episodes.append(Episode(proprio_vector(tree), actions, ep["instruction"],
                                            camera_stack(tree, cameras, image_size), paraphrases(ep)))
    if not episodes:
        raise DatasetError("no episodes in " + ", ".join(map(str, paths)))
    if len(control_modes) != 1:
        raise DatasetError(f"demo files mix control modes {sorted(map(str, control_modes))}: train on one")
    return DemoSet(episodes, control_modes.pop(), sorted(env_ids)[0], cameras or [])


@dataclass
class Normalizer:
    """Actions to [-1, 1] from their range; observations standardised."""

    act_min: np.ndarray
    act_max: np.ndarray
    obs_mean: np.ndarray
    obs_std: np.ndarray

    @classmethod
    def fit(cls, episodes: Sequence[Episode]) -> "Normalizer":
        acts = np.concatenate([e.actions for e in episodes])
        obs = np.concatenate([e.obs for e in episodes])
        lo, hi = acts.min(0), acts.max(0)
        flat = hi - lo < 1e-4  # a joint the demos never move: keep it where it is
        hi = np.where(flat, lo + 1e-4, hi)
        return cls(lo, hi, obs.mean(0), np.maximum(obs.std(0), 1e-2))

    def norm_actions(self, a: np.ndarray) -> np.ndarray:
        return 2 * (a - self.act_min) / (self.act_max - self.act_min) - 1

    def unnorm_actions(self, a: np.ndarray) -> np.ndarray:
        return (np.clip(a, -1, 1) + 1) / 2 * (self.act_max - self.act_min) + self.act_min

    def norm_obs(self, o: np.ndarray) -> np.ndarray:
        return (o - self.obs_mean) / self.obs_std

    def state_dict(self) -> dict:
        return {k: torch.as_tensor(getattr(self, k)) for k in ("act_min", "act_max", "obs_mean", "obs_std")}

    @classmethod
    def from_state_dict(cls, d: Mapping[str, Any]) -> "Normalizer":
        return cls(**{k: np.asarray(v, dtype=np.float32) for k, v in d.items()})


class WindowSampler:
    """All (obs history, action chunk) windows of the demos, as index arrays into flat tensors.

    ManiSkill's padding: the window may start ``obs_horizon - 1`` steps before the episode (the
    first obs repeated) and run ``pred_horizon - obs_horizon`` steps past its end, padded with the
    last action (for absolute joint targets that means: stay).
    """

    def __init__(self, demos: DemoSet, norm: Normalizer, text_emb: Sequence[np.ndarray] | None,
                 obs_horizon: int, pred_horizon: int):
        """``text_emb[e]``: (K_e, text_dim) embeddings of episode ``e``'s wordings; a batch draws one."""
        obs_idx, act_idx, ep_idx = [], [], []
        o_off = a_off = 0
        for i, e in enumerate(demos.episodes):
            t = len(e.actions)
            if len(e.obs) != t + 1:
                raise DatasetError(f"episode {i}: {len(e.obs)} observations for {t} actions (expected T+1)")
            for start in range(-(obs_horizon - 1), t - obs_horizon + 1):
                obs_idx.append(o_off + np.clip(np.arange(start, start + obs_horizon), 0, t))
                act_idx.append(a_off + np.clip(np.arange(start, start + pred_horizon), 0, t - 1))
                ep_idx.append(i)
            o_off += t + 1
            a_off += t
        self.obs = torch.as_tensor(norm.norm_obs(np.concatenate([e.obs for e in demos.episodes])), dtype=torch.float32)
        self.actions = torch.as_tensor(norm.norm_actions(np.concatenate([e.actions for e in demos.episodes])),
                                       dtype=torch.float32)
        self.images = (torch.cat([e.images for e in demos.episodes]) if demos.episodes[0].images is not None
                       else None)
        self.obs_idx = torch.as_tensor(np.stack(obs_idx))
        self.act_idx = torch.as_tensor(np.stack(act_idx))
        self.ep_idx = torch.as_tensor(ep_idx)
        self.text = self.text_start = self.text_count = None
        if text_emb is not None:
            counts = [len(t) for t in text_emb]
            self.text = torch.as_tensor(np.concatenate(text_emb), dtype=torch.float32)
            self.text_count = torch.as_tensor(counts)
            self.text_start = torch.cumsum(self.text_count, 0) - self.text_count

    def __len__(self) -> int:
        return len(self.obs_idx)

    def batch(self, idx: torch.Tensor, gen: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """Windows ``idx``; each takes one of its episode's wordings at random from ``gen`` (the
        first, without one)."""
        out = {"obs": self.obs[self.obs_idx[idx]], "actions": self.actions[self.act_idx[idx]]}
        if self.text is not None:
            ep = self.ep_idx[idx]
            pick = torch.zeros_like(ep) if gen is None else (
                torch.rand(len(ep), generator=gen) * self.text_count[ep]).long()
            out["text"] = self.text[self.text_start[ep] + pick]
        if self.images is not None:
            out["images"] = self.images[self.obs_idx[idx]].float() / 255.0
        return out
