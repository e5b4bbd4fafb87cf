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
from typing import Any, Mapping

from .policy import RandomPolicy, load_policy
from .protocol import EVAL_ENV_KWARGS
from .records import RecordWriter, completed_seeds, read_records
from .runner import DEFAULT_MAX_STEPS, batched_loop, episode_loop, ProgressBar, run_episodes

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
    bar = ProgressBar(job.label, job.suite_id, job.instruction_mode, len(job.seeds), len(job.seeds) - len(todo),
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
    bar = ProgressBar(job.label, job.suite_id, job.instruction_mode, len(job.seeds), len(job.seeds) - len(todo),
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
