"""Camera frames of recorded demos: RSB episodes rendered from a ManiSkill demo file's env states.

``rsb generate`` records states only; the exporter (``export/build.py``) asks this module for each
shard's episodes and hands them to the LeRobot writer (``export/lerobot.py``), which needs no
simulator. Everything here does: the env is built on the CPU backend with rgb observations, once
per process and env, and each recorded state is set and observed in turn.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from rsb_maniskill.env_ids import CPU_SIM_BACKEND
from rsb_maniskill.export.lerobot import Episode, ExportError
from rsb_maniskill.robot import sensor_uid

_RENDER_ENV: list = []  # (key, env): the last render env of this process, reused by the next shard


def _env_for(env_info: dict):
    """An rgb env for the demos' env (the same one for the next file of the same env: building one
    costs seconds, a shard of demos little more)."""
    import gymnasium as gym

    import rsb_maniskill  # noqa: F401  (registers the ids)

    kwargs = dict(env_info.get("env_kwargs") or {})
    for k in ("render_mode", "num_envs", "sim_backend", "render_backend"):
        kwargs.pop(k, None)
    kwargs.update(obs_mode="rgb", sim_backend=CPU_SIM_BACKEND)
    key = json.dumps([env_info["env_id"], kwargs], sort_keys=True, default=str)
    if _RENDER_ENV and _RENDER_ENV[0][0] == key:
        return _RENDER_ENV[0][1]
    close_render_env()
    env = gym.make(env_info["env_id"], **kwargs)
    _RENDER_ENV.append((key, env))
    return env


def close_render_env() -> None:
    while _RENDER_ENV:
        _RENDER_ENV.pop()[1].close()


def _read_group(group) -> dict | np.ndarray:
    """An h5 group as nested dicts of arrays, read at once (per-step h5 reads are slow)."""
    import h5py

    return {k: _read_group(v) if isinstance(v, h5py.Group) else v[()] for k, v in group.items()}


def render_episodes(h5_path: Path, cameras: Sequence[str], stride: int,
                    episode_ids: Sequence[int] | None = None, source: bool = True) -> Iterable[Episode]:
    """Episodes of one demo file (those of ``episode_ids``, default all), camera frames rendered
    from the recorded env states. With ``source`` each names the file and the episode in it it came
    from (``rsb export lerobot``: the user's demos); without (``rsb dataset build``: a shard's
    temporary file, gone after the build and numbered by the shard) the seed and question identify it."""
    import h5py

    from mani_skill.trajectory.utils import dict_to_list_of_dicts

    from rsb_maniskill.agents.aloha import to_aloha14
    from rsb_maniskill.motionplan.dataset import json_path_of, load_json

    data = load_json(json_path_of(h5_path))
    env = _env_for(data["env_info"])
    base = env.unwrapped
    try:
        with h5py.File(h5_path, "r") as f:
            wanted = None if episode_ids is None else set(episode_ids)
            for ep in data["episodes"]:
                if wanted is not None and ep["episode_id"] not in wanted:
                    continue
                group = f[f"traj_{ep['episode_id']}"]
                if "env_states" not in group:
                    raise ExportError(f"{h5_path}: episode {ep['episode_id']} has no env states; record demos with "
                                      "env states (rsb generate does) to export camera streams")
                states = dict_to_list_of_dicts(_read_group(group["env_states"]))
                actions = np.asarray(group["actions"][:], dtype=np.float32)
                options = (ep.get("reset_kwargs") or {}).get("options")
                env.reset(seed=ep["episode_seed"], options=options)
                spec = base.episode_specs[0]  # the episode's semantics, also for files without RSB fields
                state, frames = [], {c: [] for c in cameras}
                for t in range(0, len(actions), stride):
                    base.set_state_dict(states[t])
                    obs = base.get_obs()
                    state.append(base.agent.aloha14_state()[0].cpu().numpy())
                    for c in cameras:
                        frames[c].append(obs["sensor_data"][sensor_uid(c)]["rgb"][0].cpu().numpy())
                meta = {
                    "suite_id": spec.suite_id, "split": spec.split, "seed": int(ep["episode_seed"]),
                    "question_id": spec.question_id, "question": spec.question,
                    "options": [str(o) for o in spec.options], "correct_letter": spec.correct_letter,
                    "correct_option": str(spec.correct_option), "rationale": spec.rationale,  # a CoT target
                    "target_block": spec.target_block,
                    "template_id": spec.template_id,
                    **({"source_file": h5_path.name, "source_episode_id": int(ep["episode_id"])} if source else {}),
                }
                yield Episode(np.asarray(state, np.float32), to_aloha14(actions[::stride]).astype(np.float32),
                              {c: np.stack(v) for c, v in frames.items()}, ep.get("instruction", spec.instruction),
                              meta)
    except BaseException:
        close_render_env()  # an env left mid-episode by an error is not reused
        raise
