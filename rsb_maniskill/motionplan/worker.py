"""One generation worker: the expert over its share of seeds, successful episodes recorded to a part file.

The part is ManiSkill's RecordEpisode pair (``.h5`` + ``.json``); once it is closed, each kept
episode's json entry gets its semantics (``EpisodeSpec.to_dict()``), question index, expert timings
and video through :func:`~rsb_maniskill.motionplan.dataset.annotate_episodes`, a plain rewrite of
the finished json. A signal stops the worker between episodes (never while one is being written)
and still leaves a valid part.
"""
from __future__ import annotations

import os
import signal
import traceback
from pathlib import Path
from typing import Any, Callable

from mani_skill.utils.wrappers.record import RecordEpisode

from rsb_maniskill.batch import first_value
from rsb_maniskill.motionplan import dataset
from rsb_maniskill.motionplan.config import SOURCE_DESC, GenerateConfig, GenerateError, make_env_kwargs
from rsb_maniskill.motionplan.shards import WorkPlan, seed_schedule
from rsb_maniskill.parallel.pool import Interrupted, InterruptGuard
from rsb_maniskill.resolve import resolve


class DemoRecorder(RecordEpisode):
    """ManiSkill's recorder that also keeps the last ``info``: the env's own verdict on the episode.

    Its trajectory file lives in memory: each kept demo is copied out whole (:func:`save_demo`) and
    dropped, so none of the recorder's own h5 writes can meet a full disk (libhdf5 then printed
    dozens of tracebacks and crashed the process)."""

    last_info: dict = {}  # replaced at every reset and step

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        import h5py

        super().__init__(*args, clean_on_close=False, **kwargs)
        on_disk = Path(self._h5_file.filename)
        self._h5_file.close()
        on_disk.unlink(missing_ok=True)
        self._h5_file = h5py.File(on_disk.name, "w", driver="core", backing_store=False)

    def drop_last(self) -> None:
        """Forget the episode just flushed (saved elsewhere): memory holds one demo at a time."""
        entry = self._json_data["episodes"].pop()
        del self._h5_file[f"traj_{entry['episode_id']}"]

    def reset(self, *args: Any, **kwargs: Any):
        obs, self.last_info = super().reset(*args, **kwargs)
        return obs, self.last_info

    def step(self, action: Any):
        out = super().step(action)
        self.last_info = out[-1]
        return out

    @property
    def env_success(self) -> bool:
        return bool(first_value(self.last_info.get("success", False)))


def load_expert(path: str) -> Callable:
    """``"module:attr"`` -> the expert class (``attr(env).run() -> ExpertResult``)."""
    try:
        return resolve(path, "expert")
    except (ValueError, ImportError, AttributeError, TypeError) as err:
        raise GenerateError(f"cannot load expert {path!r}: {err}") from err


def worker_summary(worker: int, part: str | Path, **fields: Any) -> dict:
    """What a worker reports to the parent (also for a worker that failed before starting)."""
    summary = dict(worker=worker, part=str(part), kept=0, failures=[], skipped_questions=[], interrupted=None,
                   error=None, plan_time=0.0, sim_time=0.0, kept_steps=0)
    summary.update(fields)
    return summary


def run_worker(cfg: GenerateConfig, plan: WorkPlan, part_h5: str | Path, video_dir: str | Path | None,
               report: Callable[[dict], None], *, resume_dir: str | Path | None = None,
               done: set[int] = frozenset()) -> dict:
    """Generates this worker's share: each kept demo saved whole into ``resume_dir`` as it ends
    (default: ``part_h5``'s folder); the seeds in ``done`` are demos kept before, counted, not run.
    ``part_h5`` is the recorder's scratch file."""
    import gymnasium as gym

    import rsb_maniskill  # noqa: F401  (registers the RSB envs)
    from rsb_maniskill.env_ids import CONTROL_FREQ

    part_h5 = Path(part_h5)
    resume = Path(resume_dir) if resume_dir is not None else part_h5.parent
    expert_cls = load_expert(cfg.expert)
    summary = worker_summary(plan.worker, part_h5)
    meta: dict[int, dict] = {}  # seed -> what the part's json entry gets once it is closed
    with InterruptGuard() as guard:
        env = DemoRecorder(gym.make(cfg.env_id, **make_env_kwargs(cfg)), output_dir=str(part_h5.parent),
                           trajectory_name=part_h5.stem, save_video=cfg.save_video, save_on_reset=False,
                           record_reward=True, video_fps=CONTROL_FREQ, source_type="motionplanning",
                           source_desc=SOURCE_DESC)
        try:
            _run_share(cfg, plan, env, expert_cls, guard, summary, meta, video_dir, report, resume, done)
        except (Interrupted, Exception) as err:
            guard.disarm()
            signum = guard.signal_behind(err)
            if signum is not None:
                summary["interrupted"] = signal.Signals(signum).name
            else:
                summary["error"] = f"worker {plan.worker}: {err}"
                summary["resumable"] = isinstance(err, dataset.NoSpaceError)  # its demos so far are kept
                if not isinstance(err, RuntimeError):
                    summary["error"] += "\n" + traceback.format_exc()
        finally:
            guard.disarm()
            env.close()  # closes the scratch pair (the demos are saved already)
    return summary


def _run_share(cfg: GenerateConfig, plan: WorkPlan, env: DemoRecorder, expert_cls: Callable,
               guard: InterruptGuard, summary: dict, meta: dict[int, dict], video_dir: str | Path | None,
               report: Callable[[dict], None], resume: Path, done: set[int]) -> None:
    schedule = seed_schedule(plan, cfg.max_attempts)
    consecutive_failures, pending_question, kept = 0, None, None
    while summary["kept"] < plan.wanted:
        try:
            seed, q = schedule.send(kept) if kept is not None else next(schedule)
        except StopIteration:
            break
        if pending_question is not None and q != pending_question:
            summary["skipped_questions"].append(pending_question)  # attempts exhausted
        pending_question = q
        if seed in done:  # kept by an interrupted run of this request
            kept, pending_question, consecutive_failures = True, None, 0
            summary["kept"] += 1
            report(dict(type="episode", worker=plan.worker, seed=seed, question_index=seed % plan.pool_size,
                        kept=True, reason="", resumed=True))
            continue
        env.reset(seed=seed)
        spec = env.unwrapped.episode_specs[0]
        result, kept, reason = _attempt(env, expert_cls)
        msg = dict(type="episode", worker=plan.worker, seed=seed, question_index=seed % plan.pool_size,
                   kept=kept, reason="" if kept else reason,
                   steps=getattr(result, "steps", 0), plan_time=getattr(result, "plan_time", 0.0),
                   sim_time=getattr(result, "sim_time", 0.0), arm=getattr(result, "arm", ""))
        with guard.critical():
            if kept:
                try:
                    env.flush_trajectory()
                    meta[seed] = _episode_meta(cfg, spec, msg, env, video_dir)
                    save_demo(env, seed, meta[seed], resume)
                except (OSError, RuntimeError) as err:
                    if dataset.is_no_space(err):
                        raise dataset.no_space(resume) from None
                    raise
                env.drop_last()
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
    if pending_question is not None and summary["kept"] < plan.wanted:
        summary["skipped_questions"].append(pending_question)


def save_demo(env: DemoRecorder, seed: int, fields: dict, resume: Path) -> Path:
    """The episode just flushed to the recorder's file, copied whole as its own one-episode pair
    ``demo<seed>.h5/.json`` (with its RSB ``fields`` in the json entry), renamed into place json
    first, h5 last: it survives any later kill of this process."""
    import h5py

    h5 = env._h5_file
    h5.flush()
    entry = dict(env._json_data["episodes"][-1])
    final = dataset.demo_path(resume, seed)
    tmp = final.with_name(f".{final.stem}{dataset.TMP_TAG}{os.getpid()}.h5")
    try:
        with h5py.File(tmp, "w") as out:
            h5.copy(h5[f"traj_{entry['episode_id']}"], out, "traj_0")
        data = {k: v for k, v in env._json_data.items() if k != "episodes"}
        data["episodes"] = [{**entry, "episode_id": 0, **fields}]
        dataset.dump_json(dataset.json_path_of(tmp), data)
        return dataset.finalize_pair(tmp, final)
    except BaseException:
        dataset.remove_pair(tmp)
        raise


def _attempt(env: DemoRecorder, expert_cls: Callable) -> tuple[Any, bool, str]:
    """Runs the expert on the episode just reset: (its result, kept, why not)."""
    try:
        result = expert_cls(env).run()
    except Exception as err:  # a planner crash costs one seed, not the run
        return None, False, f"error:{type(err).__name__}: {err}"
    reason = result.reason or ("" if env.env_success else "env_not_successful")
    return result, bool(result.success and env.env_success), reason


def _episode_meta(cfg: GenerateConfig, spec: Any, msg: dict, env: DemoRecorder,
                  video_dir: str | Path | None) -> dict:
    """The json fields of a kept episode; writes its video first when asked for one."""
    entry = dict(spec.to_dict())
    entry["question_index"] = msg["question_index"]
    entry["expert"] = dict(arm=msg["arm"], steps=msg["steps"], plan_time=round(msg["plan_time"], 4),
                           sim_time=round(msg["sim_time"], 4))
    if cfg.save_video:
        from mani_skill.utils.visualization.misc import images_to_video

        from rsb_maniskill.env_ids import CONTROL_FREQ

        name = f"seed{msg['seed']:06d}"
        images_to_video(env.render_images, str(video_dir), video_name=name, fps=CONTROL_FREQ, verbose=False)
        entry["video"] = os.path.relpath(Path(video_dir) / f"{name}.mp4", Path(cfg.out))
        env.flush_video(save=False)
    return entry
