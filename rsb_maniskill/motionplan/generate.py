"""Demonstration generation: run the scripted expert over seeds, keep the successful episodes.

Output is ManiSkill's RecordEpisode format (``.h5`` + ``.json``, pd_joint_pos actions), so
``replay_trajectory`` can convert it to other observation / control modes. Each kept episode's
json entry also carries the episode's semantics (``EpisodeSpec.to_dict()``: instruction,
question, options, correct letter, block map, rationale), so a dataset describes itself.

The run, in the order it happens, and where each part lives:

- the request (:mod:`.config`) is checked before any file is written;
- the shard's seeds or questions are dealt to workers by arithmetic (:mod:`.shards`);
- the workers (:mod:`.worker`) run in this process, in spawned ones, or as Ray tasks
  (:mod:`rsb_maniskill.parallel.pool`, the executors evaluation uses too), each into a part file under
  a hidden temp name, reporting every episode to the progress bar here;
- the parts are merged (sorted by seed, or by question) into the final file, renamed into place,
  with an ``rsb`` block saying how it was made (:mod:`.summary`).

SIGINT / SIGTERM stop the run between episodes and finalise a valid dataset of the episodes
completed so far.
"""
from __future__ import annotations

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


def generate(cfg: GenerateConfig, executor: Executor | None = None) -> GenerateSummary:
    """Runs the whole job: validate, run workers, merge their parts into the final file.

    ``executor`` runs the workers (e.g. a :class:`~rsb_maniskill.parallel.ray_pool.RayExecutor`, whose
    machines must see ``cfg.out``); default: this process for one worker, else a process pool."""
    t0 = time.perf_counter()
    pool_size = _validate(cfg)
    final = output_path(cfg)
    if dataset.existing_outputs(final) and not cfg.overwrite:
        raise GenerateError(f"{final} exists; pass --overwrite to replace it (or choose another --out / --traj-name)")
    plans = plan_work(cfg, pool_size)
    requested = sum(p.wanted for p in plans)
    if requested == 0:
        raise GenerateError("nothing to do: this shard owns no seeds / questions")
    try:
        created = dataset.check_writable_dir(final.parent)
    except dataset.DatasetError as err:
        raise GenerateError(str(err)) from err
    video_dir = None
    if cfg.save_video:
        video_dir = final.parent / "videos" / final.name.split(".")[0]
        video_dir.mkdir(parents=True, exist_ok=True)
    parts = {p.worker: dataset.temp_h5_path(final, f".part{p.worker}") for p in plans}
    path = None
    try:
        summaries = _run_workers(cfg, plans, parts, video_dir, requested, executor)
        header = rsb_header(cfg, pool_size, len(plans), requested, summaries)
        errors = [s["error"] for s in summaries if s["error"]]
        completed = sum(s["kept"] for s in summaries)
        if completed:
            errors += _merge_parts(cfg, parts, summaries, final, pool_size, header)
            path = final
    finally:
        for part in parts.values():
            dataset.remove_pair(part)
        if path is None:
            if video_dir is not None:
                dataset.remove_empty_dirs([video_dir, video_dir.parent])
            dataset.remove_empty_dirs(created)
    rsb = header["rsb"]
    return GenerateSummary(path, requested, completed, rsb["failures"], rsb["skipped_questions"],
                           rsb["interrupted"], errors, time.perf_counter() - t0,
                           sum(s["plan_time"] for s in summaries), sum(s["sim_time"] for s in summaries),
                           sum(s["kept_steps"] for s in summaries))


def run_plan(task: tuple[GenerateConfig, WorkPlan, str, str | None], emit: Any) -> dict:
    """Executor target: one worker's share (the simulator is imported here, not by this module)."""
    from rsb_maniskill.motionplan.worker import run_worker

    cfg, plan, part, video_dir = task
    return run_worker(cfg, plan, part, video_dir, emit)


def _run_workers(cfg: GenerateConfig, plans: list[WorkPlan], parts: dict[int, Path], video_dir: Path | None,
                 requested: int, executor: Executor | None = None) -> list[dict]:
    """Runs the workers (in this process when there is one) behind a progress bar; their summaries."""
    from rsb_maniskill.motionplan.worker import worker_summary

    progress = _Progress(requested, cfg.progress, cfg.verbose)
    tasks = [(cfg, p, str(parts[p.worker]), str(video_dir) if video_dir else None) for p in plans]
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
        else:
            summaries.append(worker_summary(k, parts[k], error=f"worker {k}: {task.error}"))
    if outcome.interrupted is not None:  # the signal the user sent this process names the interruption
        for s in summaries:
            s["interrupted"] = signal.Signals(outcome.interrupted).name
    return summaries


def _merge_parts(cfg: GenerateConfig, parts: dict[int, Path], summaries: list[dict], final: Path, pool_size: int,
                 header: dict) -> list[str]:
    """Merges the readable parts into ``final``; returns errors about parts that had demos but are unreadable."""
    from rsb_maniskill.parallel.pool import InterruptGuard

    errors = []
    with InterruptGuard() as guard:  # finishing up: a late signal must not cut the merge short
        guard.disarm()
        valid_parts = []
        for k in sorted(parts):
            try:
                dataset.check_pair(parts[k])
                valid_parts.append(parts[k])
            except (dataset.DatasetError, OSError) as err:
                if any(s["kept"] for s in summaries if s["worker"] == k):
                    errors.append(f"part {parts[k].name} unreadable: {err}")
        if cfg.questions is not None:
            key = lambda ep: (ep["episode_seed"] % pool_size, ep["episode_seed"])  # noqa: E731
        else:
            key = lambda ep: ep["episode_seed"]  # noqa: E731
        dataset.merge_pairs(valid_parts, final, overwrite=True, sort_key=key, header=header)
    return errors
