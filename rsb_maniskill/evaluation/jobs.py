"""One evaluation job (a policy on one suite in one instruction mode), run the way the user asks:
one process, several CPU processes, or ``num_envs`` parallel envs on the GPU backend.

A job is a picklable description, so that spawned workers rebuild the env and the policy
themselves. Whatever runs the episodes, the records go to one file written by this process only:
workers send their records over a queue. Resuming skips the seeds already in that file.
"""
from __future__ import annotations

import os
import queue as queue_module
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .policy import RandomPolicy, as_chunk, load_policy
from .protocol import EVAL_ENV_KWARGS, SHUFFLE_SEED, apply_instruction_mode
from .records import RecordWriter, completed_seeds, read_records
from .runner import (
    DEFAULT_MAX_STEPS,
    _Donors,
    _first,
    build_record,
    default_instruction_lookup,
    episode_loop,
    progress_bar,
    run_episodes,
    write_video,
)

# Built-in policies that read the simulator's ground truth: built with the env, one env each.
PRIVILEGED_POLICIES = ("oracle", "blind")
# Policies that ignore observations: state obs and no renderer unless videos are asked for.
STATE_ONLY_POLICIES = ("oracle", "blind", "random")


@dataclass(frozen=True)
class EvalJob:
    """Everything a worker needs to rebuild the env and the policy and run episodes."""

    suite_id: str
    seeds: tuple[int, ...]
    policy: str  # built-in name or "package.module:factory"
    label: str  # the records' ``policy`` field and the table row
    policy_kwargs: Mapping[str, Any] = field(default_factory=dict)
    instruction_mode: str = "normal"
    obs_mode: str = "rgb"
    control_mode: str | None = None
    sim_backend: str = "physx_cpu"
    num_envs: int = 1
    max_steps: int = DEFAULT_MAX_STEPS
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)  # e.g. data_dir, camera_size
    video_dir: str | None = None
    num_videos: int = 0
    keep_spec: bool = True


def make_env(job: EvalJob) -> Any:
    """The evaluation env of ``job``: test split, unseen instructions (``EVAL_ENV_KWARGS``)."""
    import gymnasium as gym

    import rsb_maniskill  # noqa: F401  (registers the RSB-* envs, also in spawned workers)

    kwargs: dict[str, Any] = {**EVAL_ENV_KWARGS, **job.env_kwargs}
    kwargs.update(obs_mode=job.obs_mode, sim_backend=job.sim_backend, num_envs=job.num_envs)
    if job.control_mode:
        kwargs["control_mode"] = job.control_mode
    if job.num_videos and job.video_dir:
        kwargs["render_mode"] = "rgb_array"
    elif job.obs_mode in ("state", "state_dict", "none"):
        kwargs["render_backend"] = "none"  # nothing to render: skip the renderer entirely
    return gym.make(job.suite_id, **kwargs)


def make_policy(spec: str, env: Any, kwargs: Mapping[str, Any] | None = None) -> Any:
    """Built-ins get what they need from the env; user policies get only their ``kwargs``."""
    kwargs = dict(kwargs or {})
    if spec in PRIVILEGED_POLICIES:
        from . import baselines

        if env.unwrapped.num_envs != 1:
            raise ValueError(f"policy {spec!r} drives one env at a time; use num_procs instead of num_envs")
        return getattr(baselines, spec)(env, **kwargs)
    if spec == "random":
        space = getattr(env.unwrapped, "single_action_space", None) or env.action_space
        return RandomPolicy.from_action_space(space, **kwargs)
    return load_policy(spec, **kwargs)


def job_records(out_path: str | os.PathLike, job: EvalJob) -> list[dict]:
    return [r for r in read_records(out_path)
            if r.get("suite_id") == job.suite_id and r.get("instruction_mode") == job.instruction_mode
            and r.get("policy") == job.label]


def remaining_seeds(out_path: str | os.PathLike, job: EvalJob) -> list[int]:
    done = completed_seeds(out_path, job.suite_id, job.instruction_mode, job.label)
    return [s for s in job.seeds if s not in done]


def run_job(job: EvalJob, out_path: str | os.PathLike, num_procs: int = 1, progress: bool = True) -> list[dict]:
    """Run the seeds of ``job`` not yet in ``out_path``; returns all of the job's records."""
    todo = remaining_seeds(out_path, job)
    if not todo:
        return job_records(out_path, job)
    if job.num_envs > 1:
        _run_batched_job(job, todo, out_path, progress)
    elif num_procs <= 1 or len(todo) == 1:
        env = make_env(job)
        try:
            run_episodes(env, make_policy(job.policy, env, job.policy_kwargs), job.suite_id, job.seeds, out_path,
                         job.instruction_mode, job.max_steps, progress, policy_label=job.label,
                         keep_spec=job.keep_spec, video_dir=job.video_dir, num_videos=job.num_videos)
        finally:
            env.close()
    else:
        _run_processes(job, todo, out_path, num_procs, progress)
    return job_records(out_path, job)


# ------------------------------------------------------------------ CPU worker processes
def _loop_kwargs(job: EvalJob) -> dict[str, Any]:
    return dict(instruction_mode=job.instruction_mode, max_steps=job.max_steps, label=job.label,
                keep_spec=job.keep_spec, video_dir=job.video_dir, num_videos=job.num_videos)


def _worker(job: EvalJob, todo: list[int], worker: int, q: Any) -> None:
    error = None
    try:
        env = make_env(job)
        try:
            policy = make_policy(job.policy, env, job.policy_kwargs)
            episode_loop(env, policy, job.suite_id, job.seeds, todo, lambda r: q.put(("record", r)),
                         **_loop_kwargs(job))
        finally:
            env.close()
    except KeyboardInterrupt:
        error = "interrupted"
    except BaseException as err:  # reported by the parent, with the traceback
        error = f"{err!r}\n{traceback.format_exc()}"
    q.put(("done", worker, error))


def _run_processes(job: EvalJob, todo: list[int], out_path: str | os.PathLike, num_procs: int,
                   progress: bool) -> None:
    """Round-robin split of ``todo`` over spawned workers; this process writes every record."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")  # SAPIEN / torch state must not be forked
    q = ctx.Queue()
    k = min(num_procs, len(todo))
    procs = [ctx.Process(target=_worker, args=(job, todo[i::k], i, q), daemon=True) for i in range(k)]
    bar = progress_bar(job.label, job.suite_id, job.instruction_mode, len(job.seeds), len(job.seeds) - len(todo),
                       progress)
    errors: dict[int, str] = {}
    finished: set[int] = set()
    try:
        with RecordWriter(out_path) as writer:
            for p in procs:
                p.start()
            while len(finished) < k:
                try:
                    msg = q.get(timeout=1.0)
                except queue_module.Empty:
                    for i, p in enumerate(procs):  # died without saying so (killed, segfault)
                        if i not in finished and p.exitcode is not None and q.empty():
                            finished.add(i)
                            errors[i] = f"worker {i} exited with code {p.exitcode}"
                    continue
                if msg[0] == "record":
                    writer.write(msg[1])
                    bar.add(msg[1])
                else:
                    finished.add(msg[1])
                    if msg[2]:
                        errors[msg[1]] = msg[2]
    finally:
        bar.close()
        for p in procs:
            if p.is_alive():
                p.terminate()
            p.join(timeout=10)
    if errors:
        first = min(errors)
        raise RuntimeError(f"{len(errors)} of {k} evaluation workers failed on {job.suite_id} "
                           f"(finished episodes are saved; rerun to resume). Worker {first}: {errors[first]}")


# ------------------------------------------------------------------ GPU: num_envs parallel envs
def _run_batched_job(job: EvalJob, todo: list[int], out_path: str | os.PathLike, progress: bool) -> None:
    if job.policy in PRIVILEGED_POLICIES:
        raise ValueError(f"policy {job.policy!r} drives one env at a time; use num_procs instead of num_envs")
    env = make_env(job)
    bar = progress_bar(job.label, job.suite_id, job.instruction_mode, len(job.seeds), len(job.seeds) - len(todo),
                       progress)
    try:
        policies = [make_policy(job.policy, env, job.policy_kwargs) for _ in range(env.unwrapped.num_envs)]
        with RecordWriter(out_path) as writer:
            def write(record: dict) -> None:
                writer.write(record)
                bar.add(record)

            batched_loop(env, policies, job.suite_id, job.seeds, todo, write, **_loop_kwargs(job))
    finally:
        bar.close()
        env.close()


def _env_row(x: Any, i: int) -> Any:
    """Row ``i`` of a batched (nested) obs, as numpy."""
    if isinstance(x, Mapping):
        return {k: _env_row(v, i) for k, v in x.items()}
    if hasattr(x, "detach"):
        x = x[i].detach().cpu().numpy()
        return x
    return np.asarray(x)[i]


def _row_info(info: Mapping[str, Any], i: int) -> dict[str, Any]:
    return {k: _env_row(v, i) for k, v in info.items() if hasattr(v, "__len__") or hasattr(v, "detach")}


def batched_loop(
    env: Any,
    policies: Sequence[Any],
    suite_id: str,
    seeds: Sequence[int],
    todo: Sequence[int],
    write: Callable[[dict], None],
    *,
    instruction_mode: str = "normal",
    max_steps: int = DEFAULT_MAX_STEPS,
    label: str,
    shuffle_seed: int = SHUFFLE_SEED,
    keep_spec: bool = True,
    video_dir: str | os.PathLike | None = None,
    num_videos: int = 0,
) -> None:
    """Episodes in waves of ``num_envs``: env i of a wave runs one seed with ``policies[i]``.

    All envs of a wave are reset together with their seeds (a list); each env's record is taken at
    the step it terminates or truncates, and it then holds its last action until the wave ends. The
    last wave is padded with repeats of its last seed whose outcome is discarded. Records equal
    those of :func:`~rsb_maniskill.evaluation.runner.episode_loop`, episode for episode.
    """
    import torch

    base = env.unwrapped
    b = base.num_envs
    if len(policies) != b:
        raise ValueError(f"need one policy per env: {b} envs, {len(policies)} policies")
    space = getattr(base, "single_action_space", None) or env.action_space
    action_dim = int(space.shape[-1])
    donors = None
    if instruction_mode == "shuffled":
        if not callable(getattr(base, "episode_spec", None)):
            raise ValueError("shuffled mode on parallel envs needs the task's episode_spec(seed)")
        donors = _Donors(seeds, default_instruction_lookup(env), shuffle_seed)
    filmed = set(seeds[:num_videos]) if video_dir is not None else set()

    for start in range(0, len(todo), b):
        wave = list(todo[start:start + b])
        n = len(wave)
        obs, info = env.reset(seed=wave + [wave[-1]] * (b - n))
        specs = list(base.episode_specs)
        instructions = base.get_language_instruction()
        given, extras = [], []
        for i, seed in enumerate(wave):
            extra: dict[str, Any] = {}
            donor_text = None
            if donors is not None:
                extra["donor_seed"], donor_text = donors(seed, instructions[i])
            if instruction_mode != "normal":
                extra["original_instruction"] = instructions[i]
            given.append(apply_instruction_mode(instructions[i], instruction_mode, donor_text))
            extras.append(extra)
            policies[i].reset(given[i], _env_row(obs, i))
        frames = {i: [] for i, s in enumerate(wave) if s in filmed}
        _collect_frames(env, frames)
        pending: list[list[np.ndarray]] = [[] for _ in range(b)]
        last = np.zeros((b, action_dim), dtype=np.float32)
        steps = [0] * b
        active = [i < n for i in range(b)]
        while any(active):
            for i in range(b):
                if active[i] and not pending[i]:
                    pending[i] = list(as_chunk(policies[i].act(_env_row(obs, i)), action_dim))
                if active[i]:
                    last[i] = pending[i].pop(0)
            action = torch.as_tensor(last, device=base.device)
            obs, _, terminated, truncated, info = env.step(action)
            _collect_frames(env, frames, active)
            for i in range(n):
                if not active[i]:
                    continue
                steps[i] += 1
                done = bool(_first(terminated[i:i + 1])) or bool(_first(truncated[i:i + 1])) or steps[i] >= max_steps
                if done:
                    active[i] = False
                    extra = extras[i]
                    if i in frames:
                        name = f"{suite_id}_{instruction_mode}_seed{wave[i]}"
                        extra["video"] = write_video(frames.pop(i), video_dir, name).name
                    if keep_spec and hasattr(specs[i], "to_dict"):
                        extra["episode"] = specs[i].to_dict()
                    row = {k: v[None] if isinstance(v, np.ndarray) else v for k, v in _row_info(info, i).items()}
                    write(build_record(suite_id=suite_id, seed=wave[i], spec=specs[i], instruction=given[i],
                                       instruction_mode=instruction_mode, info=row, steps=steps[i], policy=label,
                                       extra=extra))


def _collect_frames(env: Any, frames: dict[int, list], active: Sequence[bool] | None = None) -> None:
    if not frames:
        return
    img = env.render()
    img = img.detach().cpu().numpy() if hasattr(img, "detach") else np.asarray(img)
    for i, f in frames.items():
        if active is None or active[i]:
            f.append(img[i])
