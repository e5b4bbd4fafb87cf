"""Demonstration generation: run the scripted expert over seeds, keep the successful episodes.

Output is ManiSkill's RecordEpisode format (``.h5`` + ``.json``, pd_joint_pos actions), so
``replay_trajectory`` can convert it to other observation / control modes. Each kept episode's
json entry also carries the episode's semantics (``EpisodeSpec.to_dict()``: instruction,
question, options, correct letter, block map, rationale), so a dataset describes itself.

Work is split deterministically, never by timing:

* seed mode (``num``): shard ``i/n`` owns the seeds ``s`` with ``(s - seed_start) % n == i``,
  and its worker ``k`` of ``K`` the seeds ``seed_start + i + n*k + n*K*j`` (j = 0, 1, ...);
  shard i makes ``num // n`` demos (+1 for the first ``num % n`` shards), split the same way
  over its workers. Shards never share a seed whatever their ``--num-procs``.
* question mode (``questions``): one demo per question q of the split's pool of size P,
  trying the seeds q, q+P, q+2P, ... (the env's question is ``seed % P``) until one succeeds;
  shard i owns the questions with ``q % n == i``.

Workers write part files under hidden temp names; the parent merges them (sorted by seed, or
by question) into the final file and renames it into place. SIGINT / SIGTERM stop the run
between episodes and finalise a valid dataset of the episodes completed so far.
"""
from __future__ import annotations

import importlib
import os
import queue as queue_module
import signal
import sys
import time
import traceback
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from rsb_maniskill.motionplan import dataset

CONTROL_MODE = "pd_joint_pos"
SIM_BACKEND = "physx_cpu"
DEFAULT_EXPERT = "rsb_maniskill.motionplan:ScriptedExpert"
SOURCE_DESC = ("RSB scripted motion-planning expert (mplib): grasps the correct block with the arm "
               "on its side and places it in the answer zone; only successful episodes are kept")


class GenerateError(RuntimeError):
    """A bad request (suite, split, output path, shard) detected before anything is written."""


class Interrupted(KeyboardInterrupt):
    """SIGINT / SIGTERM received; carries the signal number."""

    def __init__(self, signum: int):
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


class InterruptGuard:
    """Turns SIGINT / SIGTERM into :class:`Interrupted`, but never inside a ``critical()`` block
    (writing an episode to the .h5/.json), so a stopped run never leaves half an episode."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: int | None = None
        self.armed = True
        self._depth = 0
        self._old: dict = {}

    def __enter__(self) -> "InterruptGuard":
        for s in self.SIGNALS:
            self._old[s] = signal.signal(s, self._handler)
        return self

    def __exit__(self, *exc) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)

    def disarm(self) -> None:
        """Stop raising: later signals are only recorded (we are already shutting down)."""
        self.armed = False

    def _handler(self, signum, frame) -> None:
        if self.received is not None:
            return
        self.received = signum
        if self.armed and self._depth == 0:
            raise Interrupted(signum)

    @contextmanager
    def critical(self):
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
        if self.armed and self._depth == 0 and self.received is not None:
            raise Interrupted(self.received)


@dataclass
class GenerateConfig:
    """What ``rsb generate`` was asked for (see ``rsb generate --help``)."""

    env_id: str
    out: str = "demos"
    split: str = "train"
    num: int | None = None
    questions: str | None = None  # None: seed mode; "all" or "START:STOP"
    seed_start: int = 0
    obs_mode: str = "state"
    save_video: bool = False
    num_procs: int = 1
    shard: tuple[int, int] = (0, 1)
    overwrite: bool = False
    max_attempts: int = 20
    traj_name: str | None = None
    expert: str = DEFAULT_EXPERT
    env_kwargs: dict = field(default_factory=dict)  # extra env kwargs: instructions, color_map, data_dir
    progress: bool = True
    verbose: bool = False


@dataclass
class WorkPlan:
    """One worker's share: a seed progression with a quota, or a list of questions."""

    worker: int
    pool_size: int
    first_seed: int = 0
    stride: int = 1
    quota: int = 0
    questions: list[int] | None = None


@dataclass
class GenerateSummary:
    path: Path | None
    requested: int
    completed: int
    failures: list[dict]
    skipped_questions: list[int]
    interrupted: str | None
    errors: list[str]
    wall_time: float
    plan_time: float
    sim_time: float
    kept_steps: int

    @property
    def exit_code(self) -> int:
        if self.interrupted:
            return 128 + int(signal.Signals[self.interrupted])
        return 1 if self.errors else 0  # questions without a demo are listed, not an error


# ---------------------------------------------------------------------------- planning
def parse_shard(text: str) -> tuple[int, int]:
    """``"i/n"`` -> (i, n) with 0 <= i < n."""
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise GenerateError(f"bad --shard {text!r}: expected INDEX/COUNT, e.g. 0/4") from None
    if n < 1 or not 0 <= i < n:
        raise GenerateError(f"bad --shard {text!r}: need 0 <= INDEX < COUNT")
    return i, n


def split_count(total: int, parts: int) -> list[int]:
    """``total`` items over ``parts``: the first ``total % parts`` get one more."""
    return [total // parts + (k < total % parts) for k in range(parts)]


def question_list(questions: str, pool_size: int, num: int | None) -> list[int]:
    """``"all"`` or ``"START:STOP"`` -> question indices, cut to the first ``num``."""
    if questions == "all":
        qs = list(range(pool_size))
    else:
        try:
            start, stop = (int(x) for x in questions.split(":"))
        except ValueError:
            raise GenerateError(f"bad --questions {questions!r}: expected 'all' or START:STOP") from None
        if not 0 <= start < stop <= pool_size:
            raise GenerateError(f"bad --questions {questions!r}: the pool has questions 0..{pool_size - 1}")
        qs = list(range(start, stop))
    return qs if num is None else qs[:num]


def plan_work(cfg: GenerateConfig, pool_size: int) -> list[WorkPlan]:
    """Deterministic, disjoint shares of this shard for ``cfg.num_procs`` workers."""
    i, n = cfg.shard
    if cfg.questions is not None:
        mine = question_list(cfg.questions, pool_size, cfg.num)[i::n]
        k_procs = max(1, min(cfg.num_procs, len(mine)))
        return [WorkPlan(k, pool_size, questions=mine[k::k_procs]) for k in range(k_procs)
                if mine[k::k_procs]]
    quota = split_count(cfg.num, n)[i]
    k_procs = max(1, min(cfg.num_procs, quota))
    return [WorkPlan(k, pool_size, first_seed=cfg.seed_start + i + n * k, stride=n * k_procs, quota=q)
            for k, q in enumerate(split_count(quota, k_procs)) if q > 0]


def output_path(cfg: GenerateConfig) -> Path:
    """``<out>/<ENV_ID>/motionplanning/<name>.<obs_mode>.pd_joint_pos.physx_cpu.h5``.

    ``name`` is ``--traj-name`` or the split, plus ``-shard<i>of<n>`` for a shard. ManiSkill's
    replay keeps the part before the first dot and appends the new modes, so a replayed file
    lands next to it as ``<name>.<obs>.<control>.physx_cpu.h5``."""
    name = cfg.traj_name or cfg.split
    if "." in name or "/" in name:
        raise GenerateError(f"bad --traj-name {name!r}: no dots or slashes (replay splits names on '.')")
    i, n = cfg.shard
    if n > 1:
        name += f"-shard{i}of{n}"
    return Path(cfg.out) / cfg.env_id / "motionplanning" / f"{name}.{cfg.obs_mode}.{CONTROL_MODE}.{SIM_BACKEND}.h5"


def make_env_kwargs(cfg: GenerateConfig) -> dict:
    """Kwargs for ``gym.make``; RecordEpisode stores them in the json so replay rebuilds the env."""
    kwargs = dict(obs_mode=cfg.obs_mode, control_mode=CONTROL_MODE, sim_backend=SIM_BACKEND, split=cfg.split)
    kwargs.update(cfg.env_kwargs)
    if cfg.save_video:
        kwargs["render_mode"] = "rgb_array"  # videos come from the human render camera
    return kwargs


def load_expert(path: str) -> Callable:
    """``"module:attr"`` -> the expert class (``attr(env).run() -> ExpertResult``)."""
    module, _, attr = path.partition(":")
    try:
        return getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as err:
        raise GenerateError(f"cannot load expert {path!r}: {err}") from err


# ---------------------------------------------------------------------------- one worker
def _seed_schedule(plan: WorkPlan, max_attempts: int):
    """Yields (seed, question or None); ``send(True)`` after a kept episode."""
    if plan.questions is None:
        seed = plan.first_seed
        while True:
            yield seed, None
            seed += plan.stride
    for q in plan.questions:
        for attempt in range(max_attempts):
            kept = yield q + attempt * plan.pool_size, q
            if kept:
                break


def run_worker(cfg: GenerateConfig, plan: WorkPlan, part_h5: str | Path, video_dir: str | Path | None,
               report: Callable[[dict], None]) -> dict:
    """Generates this worker's share into ``part_h5`` (a valid pair even when interrupted)."""
    import gymnasium as gym
    import numpy as np

    import rsb_maniskill  # noqa: F401  (registers the RSB envs)
    from mani_skill.utils.visualization.misc import images_to_video
    from mani_skill.utils.wrappers.record import RecordEpisode

    from rsb_maniskill.tasks.tabletop import CONTROL_FREQ

    part_h5 = Path(part_h5)
    expert_cls = load_expert(cfg.expert)
    summary = dict(worker=plan.worker, part=str(part_h5), kept=0, failures=[], skipped_questions=[],
                   interrupted=None, error=None, plan_time=0.0, sim_time=0.0, kept_steps=0)
    with InterruptGuard() as guard:
        env = gym.make(cfg.env_id, **make_env_kwargs(cfg))
        env = RecordEpisode(env, output_dir=str(part_h5.parent), trajectory_name=part_h5.stem,
                            save_video=cfg.save_video, save_on_reset=False, record_reward=True,
                            video_fps=CONTROL_FREQ, source_type="motionplanning", source_desc=SOURCE_DESC)
        base = env.unwrapped
        quota = plan.quota if plan.questions is None else len(plan.questions)
        schedule = _seed_schedule(plan, cfg.max_attempts)
        consecutive_failures, pending_question, kept = 0, None, None
        try:
            while summary["kept"] < quota:
                try:
                    seed, q = schedule.send(kept) if kept is not None else next(schedule)
                except StopIteration:
                    break
                if pending_question is not None and q != pending_question:
                    summary["skipped_questions"].append(pending_question)  # attempts exhausted
                pending_question = q
                env.reset(seed=seed)
                spec = base.episode_specs[0]
                try:
                    result = expert_cls(env).run()
                    buf = env._trajectory_buffer
                    env_success = buf.success is not None and bool(np.asarray(buf.success)[-1].reshape(-1)[0])
                    reason = result.reason or ("" if env_success else "env_not_successful")
                    kept = bool(result.success and env_success)
                except Exception as err:  # a planner crash costs one seed, not the run
                    result, kept = None, False
                    reason = f"error:{type(err).__name__}: {err}"
                msg = dict(type="episode", worker=plan.worker, seed=seed, question_index=seed % plan.pool_size,
                           kept=kept, reason="" if kept else reason,
                           steps=getattr(result, "steps", 0), plan_time=getattr(result, "plan_time", 0.0),
                           sim_time=getattr(result, "sim_time", 0.0), arm=getattr(result, "arm", ""))
                with guard.critical():
                    if kept:
                        env.flush_trajectory()
                        entry = env._json_data["episodes"][-1]
                        entry.update(spec.to_dict())
                        entry["question_index"] = seed % plan.pool_size
                        entry["expert"] = dict(arm=msg["arm"], steps=msg["steps"], plan_time=round(msg["plan_time"], 4),
                                               sim_time=round(msg["sim_time"], 4))
                        if cfg.save_video:
                            name = f"seed{seed:06d}"
                            images_to_video(env.render_images, str(video_dir), video_name=name,
                                            fps=CONTROL_FREQ, verbose=False)
                            entry["video"] = os.path.relpath(Path(video_dir) / f"{name}.mp4", Path(cfg.out))
                            env.flush_video(save=False)
                        summary["kept"] += 1
                        summary["kept_steps"] += msg["steps"]
                        pending_question = None
                        consecutive_failures = 0
                    else:
                        env.flush_trajectory(save=False)
                        if cfg.save_video:
                            env.flush_video(save=False)
                        summary["failures"].append(dict(seed=seed, question_index=msg["question_index"],
                                                        reason=reason, steps=msg["steps"]))
                        consecutive_failures += 1
                    summary["plan_time"] += msg["plan_time"]
                    summary["sim_time"] += msg["sim_time"]
                report(msg)
                if plan.questions is None and consecutive_failures >= cfg.max_attempts:
                    raise RuntimeError(f"the expert failed on {consecutive_failures} seeds in a row "
                                       f"(last: seed {seed}, {reason}); stopping this worker")
            if pending_question is not None and summary["kept"] < quota:
                summary["skipped_questions"].append(pending_question)
        except Interrupted as err:
            guard.disarm()
            summary["interrupted"] = signal.Signals(err.signum).name
        except Exception as err:
            guard.disarm()
            summary["error"] = f"worker {plan.worker}: {err}"
            if not isinstance(err, RuntimeError):
                summary["error"] += "\n" + traceback.format_exc()
        finally:
            guard.disarm()
            env.close()  # writes the json of the kept episodes, closes the h5
    return summary


def _worker_entry(cfg: GenerateConfig, plan: WorkPlan, part_h5: str, video_dir: str | None, q) -> None:
    """Process target: runs one worker and posts its summary (always, even on errors)."""
    try:
        summary = run_worker(cfg, plan, part_h5, video_dir, q.put)
    except BaseException as err:  # noqa: BLE001  (reported to the parent)
        summary = _error_summary(plan.worker, part_h5, f"worker {plan.worker}: {err!r}\n{traceback.format_exc()}")
    q.put(dict(type="done", **summary))


# ---------------------------------------------------------------------------- the run
def _validate(cfg: GenerateConfig) -> int:
    """Checks everything knowable before any file is written; returns the pool size."""
    from rsb_maniskill.semantic import SUITE_IDS, EpisodeSampler, SemanticError

    if cfg.env_id not in SUITE_IDS:
        raise GenerateError(f"unknown suite {cfg.env_id!r}; valid: {', '.join(SUITE_IDS)}")
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
        return EpisodeSampler(cfg.env_id, split=cfg.split, **sampler_kwargs).num_questions
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


def _run_processes(cfg, plans, parts, video_dir, progress) -> list[dict]:
    """Runs the workers in spawned processes; on SIGINT/SIGTERM tells them to finish up."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")  # SAPIEN / torch state must not be forked
    q = ctx.Queue()
    procs = {p.worker: ctx.Process(target=_worker_entry, args=(cfg, p, str(parts[p.worker]), video_dir, q))
             for p in plans}
    done: dict[int, dict] = {}
    dead_seen: Counter = Counter()
    with InterruptGuard() as guard:
        for proc in procs.values():
            proc.start()
        deadline = None
        while len(done) < len(procs):
            try:
                try:
                    msg = q.get(timeout=0.5)
                except queue_module.Empty:
                    for k, proc in procs.items():
                        if k not in done and proc.exitcode is not None:
                            dead_seen[k] += 1
                            if dead_seen[k] > 4:  # its summary never came: it died hard
                                done[k] = _error_summary(k, parts[k], f"worker {k} exited with code {proc.exitcode}")
                    if deadline is not None and time.monotonic() > deadline:
                        for k, proc in procs.items():
                            if k not in done and proc.is_alive():
                                proc.kill()
                        deadline = None
                    continue
                if msg["type"] == "done":
                    done[msg["worker"]] = msg
                else:
                    progress(msg)
            except Interrupted:
                guard.disarm()
                for proc in procs.values():
                    if proc.is_alive():
                        os.kill(proc.pid, signal.SIGTERM)
                deadline = time.monotonic() + 120
        for proc in procs.values():
            proc.join(timeout=30)
        received = guard.received
    summaries = [done[k] for k in sorted(done)]
    if received is not None:  # the signal the user sent the parent names the interruption
        for s in summaries:
            s["interrupted"] = signal.Signals(received).name
    return summaries


def generate(cfg: GenerateConfig) -> GenerateSummary:
    """Runs the whole job: validate, run workers, merge their parts into the final file."""
    t0 = time.perf_counter()
    pool_size = _validate(cfg)
    final = output_path(cfg)
    if dataset.existing_outputs(final) and not cfg.overwrite:
        raise GenerateError(f"{final} exists; pass --overwrite to replace it (or choose another --out / --traj-name)")
    plans = plan_work(cfg, pool_size)
    requested = sum(p.quota if p.questions is None else len(p.questions) for p in plans)
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
        summaries = _run(cfg, plans, parts, video_dir, requested)
        completed = sum(s["kept"] for s in summaries)
        errors = [s["error"] for s in summaries if s["error"]]
        header = _header(cfg, pool_size, len(plans), requested, summaries)
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
            if completed:
                if cfg.questions is not None:
                    key = lambda ep: (ep["episode_seed"] % pool_size, ep["episode_seed"])  # noqa: E731
                else:
                    key = lambda ep: ep["episode_seed"]  # noqa: E731
                dataset.merge_pairs(valid_parts, final, overwrite=True, sort_key=key, header=header)
                path = final
    finally:
        for part in parts.values():
            dataset.remove_pair(part)
        if path is None:
            if video_dir is not None:
                dataset.remove_empty_dirs([video_dir, video_dir.parent])
            dataset.remove_empty_dirs(created)
    rsb = header["rsb"]
    plan_time = sum(s["plan_time"] for s in summaries)
    sim_time = sum(s["sim_time"] for s in summaries)
    return GenerateSummary(path, requested, completed, rsb["failures"], rsb["skipped_questions"],
                           rsb["interrupted"], errors,
                           time.perf_counter() - t0, plan_time, sim_time,
                           sum(s["kept_steps"] for s in summaries))


def _run(cfg, plans, parts, video_dir, requested) -> list[dict]:
    """Runs the workers (in this process when there is one) behind a progress bar."""
    progress = _Progress(requested, cfg.progress, cfg.verbose)
    try:
        if len(plans) == 1:
            try:
                return [run_worker(cfg, plans[0], parts[plans[0].worker], video_dir, progress)]
            except Exception as err:
                return [_error_summary(plans[0].worker, parts[plans[0].worker], f"{err!r}\n{traceback.format_exc()}")]
        return _run_processes(cfg, plans, parts, str(video_dir) if video_dir else None, progress)
    finally:
        progress.close()


def _error_summary(worker: int, part, error: str) -> dict:
    return dict(worker=worker, part=str(part), kept=0, failures=[], skipped_questions=[], interrupted=None,
                error=error, plan_time=0.0, sim_time=0.0, kept_steps=0)


def _header(cfg: GenerateConfig, pool_size: int, num_procs: int, requested: int, summaries: list[dict]) -> dict:
    """Top-level ``rsb`` block of the dataset json: how it was made, what failed and why."""
    completed = sum(s["kept"] for s in summaries)
    errors = [s["error"] for s in summaries if s["error"]]
    return dict(rsb=dict(
        env_id=cfg.env_id, split=cfg.split, pool_size=pool_size, obs_mode=cfg.obs_mode,
        mode="questions" if cfg.questions is not None else "seeds", questions=cfg.questions,
        seed_start=cfg.seed_start, shard=f"{cfg.shard[0]}/{cfg.shard[1]}", num_procs=num_procs,
        max_attempts=cfg.max_attempts, requested=requested, completed=completed,
        complete=completed == requested and not errors,
        interrupted=next((s["interrupted"] for s in summaries if s["interrupted"]), None),
        expert=cfg.expert, env_kwargs_extra=cfg.env_kwargs, rsb_version=_version(),
        failures=sorted((f for s in summaries for f in s["failures"]), key=lambda f: f["seed"]),
        skipped_questions=sorted(q for s in summaries for q in s["skipped_questions"]),
    ))


def _version() -> str:
    try:
        from rsb_maniskill import __version__
        return __version__
    except ImportError:
        return "unknown"


def describe(summary: GenerateSummary) -> str:
    """Human summary printed at the end of ``rsb generate``."""
    lines = []
    tried = summary.completed + len(summary.failures)
    if summary.path:
        lines.append(f"wrote {summary.completed} demos to {summary.path} (+ {summary.path.with_suffix('.json').name})")
    else:
        lines.append("no demos completed; no output written")
    if tried:
        lines.append(f"{tried} episodes tried, {len(summary.failures)} failed "
                     f"({summary.completed / tried:.0%} kept), {summary.wall_time:.1f} s")
    reasons = Counter(f["reason"].split(":")[0] if f["reason"].startswith("error") else f["reason"]
                      for f in summary.failures)
    if reasons:
        lines.append("failure reasons: " + ", ".join(f"{r} x{c}" for r, c in reasons.most_common()))
    if summary.skipped_questions:
        lines.append(f"{len(summary.skipped_questions)} questions got no demo after --max-attempts seeds: "
                     f"{summary.skipped_questions[:20]}{' ...' if len(summary.skipped_questions) > 20 else ''}")
    if summary.interrupted:
        lines.append(f"interrupted by {summary.interrupted}: kept the {summary.completed} finished demos "
                     f"of {summary.requested} requested")
    for err in summary.errors:
        lines.append(f"error: {err}")
    return "\n".join(lines)
