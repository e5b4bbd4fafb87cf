"""Demonstration generation: run the scripted expert over seeds, keep the successful episodes.

Output is ManiSkill's RecordEpisode format (``.h5`` + ``.json``, pd_joint_pos actions), so
``replay_trajectory`` can convert it to other observation / control modes. Each kept episode's
json entry also carries the episode's semantics (``EpisodeSpec.to_dict()``: instruction,
question, options, correct letter, block map, rationale), so a dataset describes itself.

The run, in the order it happens, and where each part lives:

- the request (:mod:`.config`) is checked before any file is written;
- the shard's seeds or questions are dealt to workers by arithmetic (:mod:`.shards`);
- the workers (:mod:`.worker`) run in this process, in spawned ones, or as Ray tasks
  (:mod:`rsb_maniskill.parallel.pool`, the executors evaluation uses too), each saving every kept
  demo as its own pair in a hidden resume folder (``.<name>.partial``) as it ends, and reporting
  every episode to the progress bar here;
- the demos are merged (sorted by seed, or by question) into the final file, renamed into place,
  with an ``rsb`` block saying how it was made (:mod:`.summary`); the resume folder goes.

SIGINT / SIGTERM stop the run between episodes (kill -9 anywhere): the finished demos stay in the
resume folder and the same command continues from them, skipping their seeds; a killed run's
half-written files are removed then. Every seed is a fresh scene, so the demos are those an
uninterrupted run keeps, byte for byte.
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from rsb_maniskill.motionplan import dataset
from rsb_maniskill.motionplan.config import GenerateConfig, GenerateError, output_path
from rsb_maniskill.motionplan.shards import WorkPlan, plan_work
from rsb_maniskill.motionplan.summary import GenerateSummary, describe, rsb_header
from rsb_maniskill.parallel.pool import Executor, InProcess, ProcessPool

# generate(GenerateConfig) -> GenerateSummary, and what goes with it
__all__ = ["GenerateConfig", "GenerateError", "GenerateSummary", "describe", "generate"]


def _validate(cfg: GenerateConfig) -> int:
    """Checks everything knowable before any file is written; returns the pool size."""
    from rsb_maniskill.objects.family import FAMILIES, split_env_id
    from rsb_maniskill.semantic import SUITE_IDS, EpisodeSampler, SemanticError

    suite_id, targets = split_env_id(cfg.env_id)
    if suite_id not in SUITE_IDS:
        sfx = " or ".join(repr(f.suffix) for f in FAMILIES.values() if f.suffix)
        raise GenerateError(f"unknown suite {cfg.env_id!r}; valid: {', '.join(SUITE_IDS)}, each also with {sfx}")
    if cfg.questions is None and (cfg.num is None or cfg.num < 1):
        raise GenerateError("give -n N (number of demos) or --questions all")
    if cfg.num is not None and cfg.num < 1:
        raise GenerateError(f"-n must be >= 1, got {cfg.num}")
    if cfg.num_procs < 1:
        raise GenerateError(f"--num-procs must be >= 1, got {cfg.num_procs}")
    if cfg.max_attempts < 1:
        raise GenerateError(f"--max-attempts must be >= 1, got {cfg.max_attempts}")
    if cfg.seed_start < 0:
        raise GenerateError(f"--seed-start must be >= 0, got {cfg.seed_start}")
    sampler_kwargs = {k: v for k, v in cfg.env_kwargs.items() if k in ("instructions", "color_map", "data_dir")}
    try:
        return EpisodeSampler(suite_id, split=cfg.split, targets=targets, **sampler_kwargs).num_questions
    except (ValueError, SemanticError) as err:
        raise GenerateError(str(err)) from err


class _Progress:
    """tqdm bar of kept demos, with failure counts; failures are logged with their reasons."""

    def __init__(self, total: int, enabled: bool, verbose: bool):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc="demos", unit="demo", disable=not enabled, dynamic_ncols=True,
                        file=sys.stderr)
        self.tried = self.failed = 0
        self.verbose = verbose

    def __call__(self, msg: dict) -> None:
        if msg.get("type") != "episode":
            return
        self.tried += 1
        if msg["kept"]:
            self.bar.update(1)
        else:
            self.failed += 1
            if self.verbose:
                self.bar.write(f"seed {msg['seed']} (question {msg['question_index']}) failed: {msg['reason']}")
        self.bar.set_postfix(tried=self.tried, failed=self.failed, refresh=False)

    def close(self) -> None:
        self.bar.close()


def _finished(cfg: GenerateConfig, final: Path, pool_size: int, workers: int, requested: int) -> dict | None:
    """The ``rsb`` block of ``final`` when it is the complete output of this very request (the same
    command run again: nothing to do), else None."""
    try:
        have = dataset.check_pair(final).get("rsb") or {}
    except (dataset.DatasetError, OSError):
        return None
    want = rsb_header(cfg, pool_size, workers, requested, [])["rsb"]
    same = ("env_id", "split", "pool_size", "obs_mode", "mode", "questions", "seed_start", "shard", "num_procs",
            "max_attempts", "requested", "expert", "env_kwargs_extra", "benchmark_version")
    if have.get("complete") and all(json.dumps(have.get(k)) == json.dumps(want.get(k)) for k in same):
        return have
    return None


def _resume_settings(cfg: GenerateConfig) -> dict:
    """What a resumed run must share with the run it continues (the demos it would keep)."""
    keep = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in ("progress", "verbose", "overwrite")}
    return json.loads(json.dumps(keep))


def _lock_resume(resume: Path, final: Path, overwrite: bool) -> Any:
    """Holds the resume folder for this run (an flock, released even by kill -9): a second
    ``rsb generate`` onto the same output is refused, instead of removing the first one's files.
    ``overwrite``: the folder is emptied first. Returns the open lock file (close it to release)."""
    import fcntl

    resume.mkdir(exist_ok=True)
    handle = open(resume / dataset.RESUME_LOCK, "a")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        raise GenerateError(f"another rsb generate is writing {final} (its demos are in {resume}); wait for it to "
                            "end, or choose another --out / --traj-name") from None
    if overwrite:
        for old in resume.iterdir():
            if old.name != dataset.RESUME_LOCK:
                shutil.rmtree(old) if old.is_dir() else old.unlink()
    return handle


def _remove_stale_temps(final: Path) -> None:
    """Temp files of ``final`` a killed run left next to it (a merge cut short, the part files of
    older versions): only this run, holding the resume folder's lock, writes there."""
    for stale in final.parent.glob(f".{final.stem}{dataset.TMP_TAG}*"):
        if stale.is_file():
            stale.unlink()


def _open_resume(cfg: GenerateConfig, resume: Path) -> dict[int, Path]:
    """The demos an interrupted run of the same request kept in ``resume`` (the folder is made, or
    cleaned of half-written files); GenerateError when that run was asked for something else."""
    settings_path = resume / dataset.RESUME_SETTINGS
    wanted = _resume_settings(cfg)
    if settings_path.exists():
        try:
            had = json.loads(settings_path.read_text())
        except (OSError, ValueError):
            had = None
        if had != wanted:
            diff = sorted(k for k in set(wanted) | set(had or {}) if (had or {}).get(k) != wanted.get(k))
            shown = ", ".join(f"{k}: {(had or {}).get(k)!r} before, {wanted.get(k)!r} now" for k in diff[:3])
            raise GenerateError(f"{resume} holds the demos of an interrupted run with other settings ({shown}); "
                                "rerun that command to continue it, or pass --overwrite to start over")
        return dataset.resume_demos(resume)
    for stale in resume.iterdir():  # no settings: a run killed before it wrote them; nothing to keep
        if stale.name != dataset.RESUME_LOCK:
            stale.unlink()
    tmp = resume / f".{dataset.RESUME_SETTINGS}.tmp{os.getpid()}"
    tmp.write_text(json.dumps(wanted, indent=1))
    os.replace(tmp, settings_path)
    return {}


def generate(cfg: GenerateConfig, executor: Executor | None = None) -> GenerateSummary:
    """Runs the whole job: validate, run workers, merge their demos into the final file.

    Each kept demo is saved as it ends in a hidden resume folder next to the output
    (:func:`~rsb_maniskill.motionplan.dataset.resume_dir_of`); an interrupted or killed run leaves it
    there and the same request continues from it (the demos are those an uninterrupted run keeps,
    byte for byte). ``executor`` runs the workers (e.g. a
    :class:`~rsb_maniskill.parallel.ray_pool.RayExecutor`, whose machines must see ``cfg.out``);
    default: this process for one worker, else a process pool."""
    t0 = time.perf_counter()
    pool_size = _validate(cfg)
    final = output_path(cfg)
    plans = plan_work(cfg, pool_size)
    requested = sum(p.wanted for p in plans)
    if dataset.existing_outputs(final) and not cfg.overwrite:
        done = _finished(cfg, final, pool_size, len(plans), requested)
        if done is None:
            raise GenerateError(f"{final} exists; pass --overwrite to replace it (or choose another --out / "
                                "--traj-name)")
        resume = dataset.resume_dir_of(final)
        if resume.exists():  # killed between the final rename and the clean-up: its demos are in the file
            _lock_resume(resume, final, overwrite=False).close()
            shutil.rmtree(resume, ignore_errors=True)
        _remove_stale_temps(final)
        return GenerateSummary(final, requested, done["completed"], done["failures"], done["skipped_questions"],
                               None, [], time.perf_counter() - t0, 0.0, 0.0, 0, already=True)
    if requested == 0:
        raise GenerateError("nothing to do: this shard owns no seeds / questions")
    try:
        created = dataset.check_writable_dir(final.parent)
    except dataset.DatasetError as err:
        raise GenerateError(str(err)) from err
    resume = dataset.resume_dir_of(final)
    lock = _lock_resume(resume, final, cfg.overwrite)
    _remove_stale_temps(final)
    try:
        kept_before = _open_resume(cfg, resume)
    except GenerateError:
        lock.close()
        dataset.remove_empty_dirs(created)
        raise
    video_dir = None
    if cfg.save_video:
        video_dir = final.parent / "videos" / final.name.split(".")[0]
        video_dir.mkdir(parents=True, exist_ok=True)
    parts = {p.worker: resume / f".work{p.worker}{dataset.TMP_TAG}{os.getpid()}.h5" for p in plans}
    path, summaries, interrupted, lost, keep = None, [], False, False, False
    try:
        summaries = _run_workers(cfg, plans, parts, video_dir, requested, executor, resume, sorted(kept_before))
        header = rsb_header(cfg, pool_size, len(plans), requested, summaries)
        errors = [s["error"] for s in summaries if s["error"]]
        interrupted = header["rsb"]["interrupted"] is not None
        demos = dataset.resume_demos(resume)
        completed = len(demos)
        # a worker process that died (kill -9, the OOM killer) or met a full disk left its share unfinished:
        # the demos kept so far stay in the resume folder, for the same command to continue, as after Ctrl-C
        stops = [s["error"] for s in summaries if s.get("resumable")]
        if completed and not interrupted and not stops:
            try:
                errors += _merge_demos(cfg, demos, final, pool_size, header)
                completed = header["rsb"]["completed"]
                path = final
            except (OSError, RuntimeError) as err:
                if not dataset.is_no_space(err):
                    raise
                stops = [str(err) if isinstance(err, dataset.NoSpaceError) else str(dataset.no_space(final.parent))]
        lost = completed > 0 and bool(stops)
        if lost:  # one line: what stopped it, what is kept where, what to do
            errors = [e for e in errors if e not in stops]
            where = "there" if str(resume) in stops[-1] else f"in {resume}"
            errors.append(f"{'; '.join(stops)}; the {completed} finished demos of {requested} requested are kept "
                          f"{where}: rerun the same command to continue")
    finally:
        for part in parts.values():
            dataset.remove_pair(part)
        keep = interrupted or lost
        if not keep:  # done (or failed): the demos are in the final file, or there were none
            shutil.rmtree(resume, ignore_errors=True)
        lock.close()
        if path is None and not keep:
            if video_dir is not None:
                dataset.remove_empty_dirs([video_dir, video_dir.parent])
            dataset.remove_empty_dirs(created)
    rsb = header["rsb"]
    return GenerateSummary(path, requested, completed, rsb["failures"], rsb["skipped_questions"],
                           rsb["interrupted"], errors, time.perf_counter() - t0,
                           sum(s["plan_time"] for s in summaries), sum(s["sim_time"] for s in summaries),
                           sum(s["kept_steps"] for s in summaries),
                           resume_dir=resume if keep and completed else None)


def run_plan(task: tuple[GenerateConfig, WorkPlan, str, str | None, str, list[int]], emit: Any) -> dict:
    """Executor target: one worker's share (the simulator is imported here, not by this module)."""
    from rsb_maniskill.motionplan.worker import run_worker

    cfg, plan, part, video_dir, resume, done = task
    return run_worker(cfg, plan, part, video_dir, emit, resume_dir=resume, done=set(done))


def _run_workers(cfg: GenerateConfig, plans: list[WorkPlan], parts: dict[int, Path], video_dir: Path | None,
                 requested: int, executor: Executor | None, resume: Path, done: list[int]) -> list[dict]:
    """Runs the workers (in this process when there is one) behind a progress bar; their summaries."""
    from rsb_maniskill.motionplan.worker import worker_summary

    progress = _Progress(requested, cfg.progress, cfg.verbose)
    tasks = [(cfg, p, str(parts[p.worker]), str(video_dir) if video_dir else None, str(resume), done)
             for p in plans]
    try:
        try:
            chosen = executor or (InProcess() if len(plans) == 1 else ProcessPool())
            outcome = chosen.run(run_plan, tasks, progress)
        except Exception as err:  # in this process: a worker that could not start
            k = plans[0].worker
            return [worker_summary(k, parts[k], error=f"{err!r}\n{traceback.format_exc()}")]
    finally:
        progress.close()
    summaries = []
    for plan, task in zip(plans, outcome.tasks):
        k = plan.worker
        if task.result is not None:
            summaries.append(task.result)
        elif task.interrupted is not None:
            summaries.append(worker_summary(k, parts[k], interrupted=signal.Signals(task.interrupted).name))
        elif task.exit_code is not None:  # the process ended without a word: killed, or it crashed
            summaries.append(worker_summary(k, parts[k], error=f"worker {k} died before finishing its share "
                                            f"({_death(task.exit_code)})", resumable=True))
        else:
            summaries.append(worker_summary(k, parts[k], error=f"worker {k}: {task.error}"))
    if outcome.interrupted is not None:  # the signal the user sent this process names the interruption
        for s in summaries:
            s["interrupted"] = signal.Signals(outcome.interrupted).name
    return summaries


def _death(exit_code: int) -> str:
    """How a worker process ended: ``killed by SIGKILL`` or ``exit code 3``."""
    if exit_code < 0:
        try:
            return f"killed by {signal.Signals(-exit_code).name}"
        except ValueError:
            pass
    return f"exit code {exit_code}"


def _merge_demos(cfg: GenerateConfig, demos: dict[int, Path], final: Path, pool_size: int,
                 header: dict) -> list[str]:
    """Merges the kept demos into ``final``; returns errors about demos that are unreadable."""
    from rsb_maniskill.parallel.pool import InterruptGuard

    errors = []
    with InterruptGuard() as guard:  # finishing up: a late signal must not cut the merge short
        guard.disarm()
        valid = []
        for seed in sorted(demos):
            try:
                dataset.check_pair(demos[seed])
                valid.append(demos[seed])
            except (dataset.DatasetError, OSError) as err:
                errors.append(f"demo {demos[seed].name} unreadable: {err}")
        if cfg.questions is not None:
            key = lambda ep: (ep["episode_seed"] % pool_size, ep["episode_seed"])  # noqa: E731
        else:
            key = lambda ep: ep["episode_seed"]  # noqa: E731
        rsb = header["rsb"]  # the counts the file states are those of the demos it holds
        rsb["completed"] = len(valid)
        rsb["complete"] = rsb["complete"] and len(valid) == rsb["requested"]
        if valid:
            dataset.merge_pairs(valid, final, overwrite=True, sort_key=key, header=header)
    return errors
