"""The evaluation driver: one suite x instruction mode of a policy, resumed, written and shown.

:func:`drive` is the one place that resumes (skips the seeds already in the records file), owns the
file (this process is its only writer) and the progress bar. What runs the episodes is up to its
caller:

- :func:`run_job` builds env and policy from an :class:`EvalJob` (a picklable description) in
  this process, in worker processes (one env each, records sent back over a queue), or on
  ``num_envs`` parallel envs: of the GPU backend (in one process), or a vector of CPU envs in
  each worker (``rsb_maniskill.vector``: every camera rendered in one call where CUDA rendering
  exists); one policy object if it has the batched form, else one per env;
- :func:`run_episodes` runs a policy object on an env you built.
"""
from __future__ import annotations

import os
import signal
import time
import traceback
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterator, Mapping, Sequence

from rsb_maniskill.env_ids import CPU_SIM_BACKEND
from rsb_maniskill.evaluation.protocol import EVAL_ENV_KWARGS, SHUFFLE_SEED, episode_of, record_episode
from rsb_maniskill.evaluation.records import perturb_label as record_perturb
from rsb_maniskill.evaluation.runner import DEFAULT_MAX_STEPS, EpisodeSettings, batched_loop, episode_loop
from rsb_maniskill.evaluation.store import RecordWriter, read_records
from rsb_maniskill.parallel.pool import Executor, InProcess, Interrupted, ProcessPool, deal, watched
from rsb_maniskill.perturb import label as perturb_label
from rsb_maniskill.policies.errors import (
    PolicyError,
    blame_policy,
    episode_where,
    one_line,
    policy_call_label,
    stuck_call_error,
)
from rsb_maniskill.policies.interface import is_batched, policy_name
from rsb_maniskill.policies.registry import load_policy, policy_spec

Write = Callable[[dict], None]
RUN_BATCH = 100_000  # episodes left are run this many at a time when they are not one plain range


class JobError(RuntimeError):
    """A job's episodes could not run: its env could not be built, or a worker failed or died.
    One line; ``detail`` is the traceback (``rsb --debug``). It pickles whole (a worker sends it
    back as it is); the episodes finished before it are kept."""

    def __init__(self, message: str, detail: str | None = None, then: str | None = None) -> None:
        super().__init__(message)
        self.detail = detail
        self.then = then  # what to do next, where it is not "fix it and rerun"

    def __reduce__(self) -> tuple:
        return type(self), (self.args[0], self.detail, self.then)


@dataclass(frozen=True, kw_only=True)
class EvalJob(EpisodeSettings):
    """Everything a worker needs to rebuild the env and the policy and run episodes."""

    policy: str  # built-in name or "package.module:factory"
    policy_kwargs: Mapping[str, Any] = field(default_factory=dict)
    obs_mode: str = "rgb"
    control_mode: str | None = None
    sim_backend: str = CPU_SIM_BACKEND
    num_envs: int = 1  # > 1: ManiSkill's parallel envs on GPU physics, or on the CPU backend a vector env
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)  # e.g. data_dir, camera_size
    renderer: str = "auto"  # CPU vector env: one render call for all envs (CUDA), or per scene

    @property
    def cpu_vector(self) -> bool:
        """Several envs on the CPU backend: a :class:`~rsb_maniskill.vector.RSBVectorEnv` per worker."""
        return self.num_envs > 1 and self.sim_backend == CPU_SIM_BACKEND


def make_env(job: EvalJob) -> Any:
    """The evaluation env of ``job``: test split, unseen instructions (``EVAL_ENV_KWARGS``)."""
    import gymnasium as gym

    import rsb_maniskill  # noqa: F401  (registers the RSB-* envs, also in spawned workers)

    kwargs: dict[str, Any] = {**EVAL_ENV_KWARGS, **job.env_kwargs}
    kwargs.update(obs_mode=job.obs_mode, sim_backend=job.sim_backend)
    if job.perturb:
        kwargs["perturb"] = dict(job.perturb)
    if job.control_mode:
        kwargs["control_mode"] = job.control_mode
    if job.num_videos and job.video_dir:
        kwargs["render_mode"] = "rgb_array"
    elif job.obs_mode in ("state", "state_dict", "none"):
        kwargs["render_backend"] = "none"  # nothing to render: skip the renderer entirely
    if job.cpu_vector:
        from rsb_maniskill.vector import RSBVectorEnv

        return RSBVectorEnv(job.suite_id, job.num_envs, renderer=job.renderer, **kwargs)
    return gym.make(job.suite_id, num_envs=job.num_envs, **kwargs)


class ProgressBar:
    """tqdm bar over a suite's episodes with the running GSR / TSR; a no-op when disabled."""

    def __init__(self, label: str, suite_id: str, mode: str, total: int, initial: int, enabled: bool) -> None:
        self.bar = None
        self.n = self.grasped = self.success = 0
        if enabled:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, initial=initial, desc=f"{label} {suite_id} [{mode}]", unit="ep")

    def add(self, record: Mapping[str, Any]) -> None:
        self.n += 1
        self.grasped += bool(record["grasped_any"] or record["success"])
        self.success += bool(record["success"])
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(GSR=f"{self.grasped / self.n:.0%}", TSR=f"{self.success / self.n:.0%}", refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class Throughput:
    """A run's pace, for the last line of ``rsb eval``, on this process's clock.

    The steady time is the time episodes ran: each job's window, from the moment its first worker
    began its episodes (it sends :data:`EPISODES_BEGIN` once its env and policy are built) to the
    job's last record; windows of several jobs add up. The start-up is the rest of the time up to the
    last record: the run's own (imports, the workers) and each job's env and policy. A job whose
    episodes run without that mark (:func:`run_episodes`, in this process) opens its window at its
    first episode's start: a record's arrival less its ``wall_s``."""

    def __init__(self) -> None:
        self.start()

    def start(self) -> None:
        self.t0 = time.monotonic()
        self.last = self.t0
        self.steps = self.episodes = 0
        self.windows: list[tuple[float, float]] = []  # (begin, last record) of each finished job
        self.opened: float | None = None  # the current job's window: since when episodes run
        self.marked = False  # opened by a worker's mark (else from records' wall_s)
        self.closes: float | None = None  # the current job's last record

    def begin(self) -> None:
        """A worker begins its episodes (the first one opens the job's window)."""
        if not self.marked:
            now = time.monotonic()
            self.opened = now if self.opened is None else min(self.opened, now)
            self.marked = True

    def add(self, record: Mapping[str, Any]) -> None:
        now = time.monotonic()
        if not self.marked:
            began = now - float(record.get("wall_s") or 0.0)
            self.opened = began if self.opened is None else min(self.opened, began)
        self.last = self.closes = now
        self.steps, self.episodes = self.steps + int(record.get("steps") or 0), self.episodes + 1

    def end_job(self) -> None:
        """The current job is over: its window closes at its last record (none: no window)."""
        if self.opened is not None and self.closes is not None:
            self.windows.append((self.opened, self.closes))
        self.opened, self.marked, self.closes = None, False, None

    def steady_s(self) -> float:
        """Seconds episodes ran (the windows, the current job's included)."""
        windows = self.windows + ([(self.opened, self.closes)] if self.opened is not None and self.closes else [])
        return sum(max(0.0, b - a) for a, b in windows)

    def line(self) -> str:
        if not self.episodes:
            return "throughput: no episode ran"
        run = max(self.steady_s(), 1e-9)
        start_up = max(0.0, self.last - self.t0 - run)
        return (f"throughput: start-up {start_up:.1f} s, then {self.steps / run:,.0f} "
                f"env-steps/s ({self.steps:,} env-steps, {self.episodes:,} episodes in {run:.1f} s)")


EPISODES_BEGIN = "episodes-begin"  # what a worker sends once its env and policy are built (not a record)
PACE = Throughput()  # every record drive() writes in this process; rsb eval starts it and prints its line


def job_records(out_path: str | os.PathLike, settings: EpisodeSettings) -> list[dict]:
    """The records of ``out_path`` that belong to this policy label, suite, instruction mode and perturbation."""
    want = perturb_label(settings.perturb or {})
    return [r for r in read_records(out_path)
            if r.get("suite_id") == settings.suite_id and r.get("instruction_mode") == settings.instruction_mode
            and r.get("policy") == settings.label and record_perturb(r) == want]


def drive(settings: EpisodeSettings, out_path: str | os.PathLike, run: Callable[[list[int], Write], None],
          progress: bool = True, stamp: Mapping[str, Any] | None = None) -> list[dict]:
    """Resume, write and show one evaluation: ``run(todo, write)`` runs the episodes not yet recorded
    (seeds; in counterfactual mode (seed, variant) pairs: resumed variant by variant).

    Reads ``out_path`` once; ``write`` appends a record (durably, with the ``stamp`` fields: the
    settings id ``rsb eval`` checks on resume) and advances the bar. Returns every
    record of this label / suite / mode in file order, old and new.
    """
    records = job_records(out_path, settings)
    done = {record_episode(r) for r in records}
    episodes = settings.episodes()
    members = episodes if isinstance(episodes, range) else set(episodes)
    n_done = sum(1 for e in done if e in members)
    if n_done >= len(episodes):
        return records
    mode = settings.instruction_mode + (f", {perturb_label(settings.perturb)}" if settings.perturb else "")
    bar = ProgressBar(settings.label, settings.suite_id, mode, len(episodes), n_done, progress)
    try:
        with RecordWriter(out_path) as writer:
            def write(record: dict) -> None:
                records.append(writer.write({**record, **stamp} if stamp else record))
                bar.add(record)
                PACE.add(record)

            for todo in _batches(episodes, done, RUN_BATCH):
                run(todo, write)
    finally:
        bar.close()
        PACE.end_job()
    return records


def _batches(episodes: Sequence[Any], done: set, size: int) -> Iterator[Sequence[Any]]:
    """The episodes not in ``done``, in order, ``size`` at a time: a range without done ones stays a
    range (one batch, nothing listed), else lists of at most ``size``: memory follows the work in
    flight, not ``-n``."""
    if isinstance(episodes, range) and not any(e in episodes for e in done):
        yield episodes
        return
    batch: list[Any] = []
    for e in episodes:
        if e not in done:
            batch.append(e)
            if len(batch) >= size:
                yield batch
                batch = []
    if batch:
        yield batch


def run_episodes(
    env_factory: Callable[[], Any] | Any,
    policy: Any,
    suite_id: str,
    seeds: Sequence[int],
    out_path: str | os.PathLike,
    instruction_mode: str = "normal",
    max_steps: int = DEFAULT_MAX_STEPS,
    progress: bool = True,
    *,
    policy_label: str | None = None,
    reset_options: dict | None = None,
    instruction_lookup: Callable[[int], str] | None = None,
    shuffle_seed: int = SHUFFLE_SEED,
    keep_spec: bool = True,
    video_dir: str | os.PathLike | None = None,
    num_videos: int = 0,
) -> list[dict]:
    """Evaluate ``policy`` on ``seeds`` of ``suite_id``, appending one record per episode to ``out_path``.

    Args:
        env_factory: zero-argument callable making a one-env RSB env of ``suite_id`` (evaluation
            split), or an env. It is only built when seeds remain, and closed if built here.
        policy: a :class:`~rsb_maniskill.policies.interface.Policy`.
        seeds: the full seed list of this evaluation (``protocol.eval_seeds``); seeds already
            recorded for this policy / suite / mode in ``out_path`` are skipped.
        instruction_mode, max_steps, video_dir, num_videos, ...: see
            :class:`~rsb_maniskill.evaluation.runner.EpisodeSettings` (make the env with
            ``render_mode="rgb_array"`` for videos).
    Returns:
        Every record of this (policy, suite, mode) in ``out_path``, old and new, in file order.
    """
    settings = EpisodeSettings(
        suite_id=suite_id, seeds=tuple(seeds), label=policy_label or policy_name(policy),
        instruction_mode=instruction_mode, max_steps=max_steps, reset_options=reset_options,
        instruction_lookup=instruction_lookup, shuffle_seed=shuffle_seed, keep_spec=keep_spec,
        video_dir=None if video_dir is None else str(video_dir), num_videos=num_videos)

    def run(todo: list[int], write: Write) -> None:
        own_env = not hasattr(env_factory, "step")
        env = env_factory() if own_env else env_factory
        try:
            episode_loop(env, policy, settings, todo, write)
        finally:
            if own_env:
                env.close()

    return drive(settings, out_path, run, progress)


def run_job(job: EvalJob, out_path: str | os.PathLike, num_procs: int = 1, progress: bool = True,
            executor: Executor | None = None, isolate: bool = False,
            stamp: Mapping[str, Any] | None = None) -> list[dict]:
    """Run the seeds of ``job`` not yet in ``out_path``; returns all of the job's records.

    The seeds left are dealt round-robin to ``num_procs`` spawned workers (or to ``num_procs`` tasks
    of ``executor``, e.g. a :class:`~rsb_maniskill.parallel.ray_pool.RayExecutor`); with one, or with
    parallel GPU envs (``job.num_envs > 1``) and no executor, they run in this process.
    A misbehaving policy raises its :class:`~rsb_maniskill.policies.errors.PolicyError`
    (from a worker process too), any other failure a :class:`JobError`; the finished episodes are
    kept either way. A signal stops the workers and raises
    :class:`~rsb_maniskill.parallel.pool.Interrupted`, a KeyboardInterrupt.

    ``isolate``: run even a single worker in a spawned process (what ``rsb eval`` does), so that a
    policy that exits the process, crashes in native code or outlasts ``job.policy_timeout`` in a
    blocking call ends in a PolicyError, not in a silent exit or a hang. In this process a policy
    call cannot be interrupted (a signal cannot stop a blocking C call; ``os._exit`` cannot be caught).
    """
    if job.num_envs > 1 and not job.cpu_vector and policy_spec(job.policy).single_env:
        raise ValueError(f"policy {job.policy!r} drives one env at a time; use num_procs instead of num_envs, "
                         "or the CPU backend's vector env")

    def run(todo: list[int], write: Write) -> None:
        # parallel GPU envs run in one process, or one shard per GPU task of an executor; CPU vector
        # envs, num_envs to each of num_procs workers
        gpu_envs = job.num_envs > 1 and not job.cpu_vector
        shards = deal(todo, 1 if gpu_envs and executor is None else num_procs)
        # never more envs than the episodes a worker runs: K envs for 2 episodes would build K - 2 for nothing
        sized = replace(job, num_envs=max(1, min(job.num_envs, max(map(len, shards)))))
        chosen = executor or (ProcessPool() if len(shards) > 1 or isolate else InProcess())
        recorded: set = set()

        def on_message(message: Any) -> None:
            if isinstance(message, str) and message == EPISODES_BEGIN:
                PACE.begin()
                return
            recorded.add(record_episode(message))
            write(message)

        outcome = chosen.run(run_shard, [(sized, shard) for shard in shards], on_message)
        if outcome.interrupted:
            raise Interrupted(outcome.interrupted)
        # SIGKILL: nothing the policy does ends its process so; the machine (out of memory) or a user did
        killed = [t for t in outcome.tasks if getattr(t, "exit_code", None) == -signal.SIGKILL]
        died = killed or [t for t in outcome.tasks if getattr(t, "exit_code", None) is not None and not t.stuck]
        if died:  # killed (out of memory?), or ended outside any policy call
            t = died[0]
            lost = sorted({episode_of(e)[0] for e in shards[t.index] if e not in recorded})
            raise JobError(f"evaluation worker {t.index} {'was ' if t.error.startswith('killed') else ''}{t.error}, "
                           f"running {episode_where(job.suite_id, lost, job.instruction_mode)}: those episodes were "
                           "not recorded", then="rerun the same command to resume: finished episodes are kept")
        stuck = [t for t in outcome.tasks if getattr(t, "stuck", None)]
        if stuck:  # a policy call that hung (killed at its limit) or ended its worker
            t = stuck[0]
            raise stuck_call_error(t.stuck, job.label, timeout_s=t.timed_out, exit_code=t.exit_code)
        failed = [t.result for t in outcome.tasks if isinstance(t.result, BaseException)]
        if failed:  # the first worker's error, whole (the others' are most likely the same)
            raise failed[0]
        errors = {**outcome.errors, **{t.index: "interrupted" for t in outcome.tasks if t.interrupted}}
        if errors:
            first = min(errors)
            raise JobError(f"{len(errors)} of {len(shards)} evaluation workers failed on {job.suite_id}; worker "
                           f"{first}: {errors[first].splitlines()[0]}", detail=errors[first])

    return drive(job, out_path, run, progress, stamp)


def _load_policies(job: EvalJob, env: Any) -> Any:
    """The policy of a job's worker: one object, or for parallel envs a batched one or one instance
    per env. On a CPU vector env each instance is built with its own env (``env.envs[i]``), so that
    a policy that reads the simulator of one env (the scripted expert's) drives each env."""
    sub_envs = getattr(env.unwrapped, "envs", None) if job.cpu_vector else None
    if sub_envs is not None and policy_spec(job.policy).single_env:
        return [load_policy(job.policy, env=sub, **job.policy_kwargs) for sub in sub_envs]
    policy = load_policy(job.policy, env=env, **job.policy_kwargs)
    if job.num_envs > 1 and not is_batched(policy):  # one instance per env
        policy = [policy] + [load_policy(job.policy, env=env, **job.policy_kwargs)
                             for _ in range(env.unwrapped.num_envs - 1)]
    return policy


def run_shard(task: tuple[EvalJob, list[int]], write: Write) -> BaseException | None:
    """A worker's share: build env and policy from the job, run its seeds, send each record.

    Returns the error that stopped it, None when every seed ran: a PolicyError, or a JobError
    carrying the traceback, so that it reaches the driver whole from any executor."""
    job, seeds = task
    try:
        env = make_env(job)
    except Exception as err:  # noqa: BLE001  (reported by the driver, in one line)
        settings = ", ".join(f"{k}={v!r}" for k, v in (("obs_mode", job.obs_mode), ("control_mode", job.control_mode),
                                                         *job.env_kwargs.items()) if v is not None)
        from rsb_maniskill.sim.render import renderer_hint

        hint = renderer_hint(str(err))
        return JobError(f"cannot build the env {job.suite_id} ({settings}): {type(err).__name__}: "
                        f"{one_line(str(err))}{f'; {hint}' if hint else ''}", detail=traceback.format_exc())
    try:
        with watched(policy_call_label("building it", job.suite_id), job.policy_timeout), \
                blame_policy("building it", policy=job.label, where=job.suite_id):
            policy = _load_policies(job, env)
        write(EPISODES_BEGIN)  # the throughput line's steady time starts here
        if job.num_envs > 1:
            batched_loop(env, policy, job, seeds, write)
        else:
            episode_loop(env, policy, job, seeds, write)
    except PolicyError as err:
        return err
    except Exception as err:  # noqa: BLE001  (reported by the driver, in one line)
        return JobError(f"{job.suite_id}: {type(err).__name__}: {one_line(str(err))}",
                        detail=traceback.format_exc())
    finally:
        env.close()
    return None

