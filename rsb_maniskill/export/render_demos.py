"""Camera frames of recorded demos: RSB episodes rendered from a ManiSkill demo file's env states.

``rsb generate`` records states only; the exporter (``export/build.py``) asks this module for each
shard's episodes and hands them to the LeRobot writer (``export/lerobot.py``), which needs no
simulator. Everything here does: the env is built on the CPU backend with rgb observations, once
per process and env, and each recorded state is set and observed in turn.

Where an NVIDIA GPU renders, K episodes are rendered together on a vector of K CPU envs
(``rsb_maniskill.vector``): step t of K episodes is set, then every camera of the K renders in one
call and the K observations are built once, the eval's path (:func:`render_envs`: ``--num-envs
auto``'s rule, the default of ``rsb dataset build`` and ``rsb export lerobot``). The same frames either way.
"""
from __future__ import annotations

import json
from contextlib import nullcontext
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


def render_envs() -> int:
    """Episodes rendered together in this process: ``--num-envs auto``'s K for rendering (4 where an
    NVIDIA GPU renders, else 1; ``parallel.plan.plan_num_envs``), asked once a process."""
    if not _RENDER_ENVS:
        from rsb_maniskill.parallel.plan import nvidia_gpus, plan_num_envs

        _RENDER_ENVS.append(plan_num_envs(len(nvidia_gpus()), True)[0])
    return _RENDER_ENVS[0]


_RENDER_ENVS: list[int] = []


def _vector_env_for(env_info: dict, num_envs: int):
    """A vector of ``num_envs`` rgb CPU envs for the demos' env, kept for the next file like :func:`_env_for`."""
    from rsb_maniskill.vector import RSBVectorEnv

    kwargs = dict(env_info.get("env_kwargs") or {})
    for k in ("render_mode", "num_envs", "sim_backend", "render_backend"):
        kwargs.pop(k, None)
    kwargs.update(obs_mode="rgb")
    key = json.dumps([env_info["env_id"], num_envs, kwargs], sort_keys=True, default=str)
    if _RENDER_ENV and _RENDER_ENV[0][0] == key:
        return _RENDER_ENV[0][1]
    close_render_env()
    env = RSBVectorEnv(env_info["env_id"], num_envs, **kwargs)
    _RENDER_ENV.append((key, env))
    return env


def render_episodes(h5_path: Path, cameras: Sequence[str], stride: int,
                    episode_ids: Sequence[int] | None = None, source: bool = True,
                    num_envs: int | None = None) -> Iterable[Episode]:
    """Episodes of one demo file (those of ``episode_ids``, default all), camera frames rendered
    from the recorded env states. With ``source`` each names the file and the episode in it it came
    from (``rsb export lerobot``: the user's demos); without (``rsb dataset build``: a shard's
    temporary file, gone after the build and numbered by the shard) the seed and question identify it.
    ``num_envs`` episodes are rendered together (default :func:`render_envs`): the same frames."""
    import h5py

    from mani_skill.trajectory.utils import dict_to_list_of_dicts

    from rsb_maniskill.motionplan.dataset import json_path_of, load_json

    data = load_json(json_path_of(h5_path))
    k = render_envs() if num_envs is None else int(num_envs)
    env = _env_for(data["env_info"]) if k == 1 else _vector_env_for(data["env_info"], k)
    try:
        with h5py.File(h5_path, "r") as f:
            wanted = None if episode_ids is None else set(episode_ids)
            todo = [ep for ep in data["episodes"] if wanted is None or ep["episode_id"] in wanted]
            for start in range(0, len(todo), k):
                wave = []
                for ep in todo[start:start + k]:
                    group = f[f"traj_{ep['episode_id']}"]
                    if "env_states" not in group:
                        raise ExportError(f"{h5_path}: episode {ep['episode_id']} has no env states; record demos "
                                          "with env states (rsb generate does) to export camera streams")
                    wave.append((ep, dict_to_list_of_dicts(_read_group(group["env_states"])),
                                 np.asarray(group["actions"][:], dtype=np.float32)))
                yield from _render_wave(env, wave, cameras, stride, h5_path, source)
    except BaseException:
        close_render_env()  # an env left mid-episode by an error is not reused
        raise


def _render_wave(env, wave: list, cameras: Sequence[str], stride: int, h5_path: Path,
                 source: bool) -> Iterable[Episode]:
    """The episodes of ``wave`` ((episode entry, states, actions) each), episode i on env i of ``env``
    (a one-env env, or a vector env): step t of every episode set, then all observed in one call."""
    from rsb_maniskill.agents.aloha import to_aloha14

    vector = hasattr(env.unwrapped, "bases")
    bases = env.unwrapped.bases if vector else [env.unwrapped]
    # each episode's own reset (its seed and options), rendering nothing: the group is built and
    # every camera of the K rendered once, at the first observation below
    with env.unwrapped.skip_observations() if vector else nullcontext():
        for i, (ep, _, _) in enumerate(wave):
            options = (ep.get("reset_kwargs") or {}).get("options")
            if vector:
                env.reset(seed=[ep["episode_seed"]], options={**(options or {}), "env_idx": [i]})
            else:
                env.reset(seed=ep["episode_seed"], options=options)
    specs = [base.episode_specs[0] for base in bases]  # the episodes' semantics, also for files without RSB fields
    state: list[list] = [[] for _ in wave]
    frames: list[dict] = [{c: [] for c in cameras} for _ in wave]
    for t in range(0, max(len(actions) for _, _, actions in wave), stride):
        live = [i for i, (_, _, actions) in enumerate(wave) if t < len(actions)]
        for i in live:
            bases[i].set_state_dict(wave[i][1][t])
        obs = env.unwrapped.get_obs()  # every camera of the K envs in one call, the observation built once
        rgb = {c: obs["sensor_data"][sensor_uid(c)]["rgb"].cpu().numpy() for c in cameras}  # one copy a camera
        for i in live:
            state[i].append(bases[i].agent.aloha14_state()[0].cpu().numpy())
            for c in cameras:
                frames[i][c].append(rgb[c][i])
    for i, (ep, _, actions) in enumerate(wave):
        spec = specs[i]
        meta = {
            "suite_id": spec.suite_id, "split": spec.split, "seed": int(ep["episode_seed"]),
            "question_id": spec.question_id, "question": spec.question,
            "options": [str(o) for o in spec.options], "correct_letter": spec.correct_letter,
            "correct_option": str(spec.correct_option), "rationale": spec.rationale,  # a CoT target
            "target_block": spec.target_block,
            "template_id": spec.template_id,
            **({"source_file": h5_path.name, "source_episode_id": int(ep["episode_id"])} if source else {}),
        }
        yield Episode(np.asarray(state[i], np.float32), to_aloha14(actions[::stride]).astype(np.float32),
                      {c: np.stack(v) for c, v in frames[i].items()}, ep.get("instruction", spec.instruction), meta)
