"""``rsb dataset build`` and ``rsb export lerobot``: LeRobot datasets in shards, in parallel, resumable.

A build is cut into shards by arithmetic, never by timing: each suite's question range in chunks of
``shard_size`` questions (``rsb export lerobot``: each demo file's episodes in chunks). Workers
(``rsb_maniskill.parallel.pool``: this process, spawned processes, or Ray tasks) take the shards dealt
to them, and for each one (``export/shards.py``) run the scripted expert on its questions (``rsb
generate``'s code, into a temporary demo file), render the kept demos' camera frames from their
recorded states and write the shard as a small LeRobot dataset (``write_dataset``), renamed into
``<work>/shards/`` only when whole. A shard is therefore there completely or not at all: a run
stopped in any way (Ctrl-C, SIGTERM, kill -9) loses only the shards in flight, and a rerun of the
same command skips the finished ones. When every shard of a suite is there, they are merged
(``export/merge.py``) into ``OUT/<suite>`` with its dataset card. The shard list, hence every
episode, does not depend on the number of workers. Local worker processes share the CPUs for
software rendering: each caps lavapipe's raster threads to its share (``LP_NUM_THREADS``, unless
the user set it; ``sim/render.py``).

Layout: ``OUT/<suite>/`` (the dataset, ready for ``huggingface-cli upload``) and
``OUT/.work/<suite>/`` (``settings.json`` and ``shards/shard-NNNNN``; safe to delete after the build).
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from rsb_maniskill.export.lerobot import INFO_FILE, ExportError
from rsb_maniskill.export.naming import DEFAULT_NAMING
from rsb_maniskill.export.shards import (
    SHARD_META,
    ExportShard,
    SuiteShard,
    clean_temps,
    done_shards,
    run_worker,
    shard_dir,
)
from rsb_maniskill.objects.family import DEFAULT_TARGETS
from rsb_maniskill.outdirs import writable_dir
from rsb_maniskill.robot import CAMERAS
from rsb_maniskill.sim.render import lavapipe_share

WORK_DIR = ".work"
SETTINGS_FILE = "settings.json"
BUILD_META = "meta/rsb_build.json"  # the settings a dataset was built with, inside the dataset
PROVENANCE = ("code_commit", "skipped_questions")  # also in BUILD_META; they decide no episode or file
# How the work is cut: a resumed build must keep it (the finished shards are reused), but it decides
# no episode and no byte of the dataset (export/merge.py), so BUILD_META does not hold it.
WORK_ONLY = ("shard_size",)
EXPORT_META = "meta/rsb_export.json"  # what an exported dataset's demos are (benchmark version, ...)
DEFAULT_SHARD_SIZE = 25  # questions a shard: a kill loses at most this many demos per worker


@dataclass
class BuildConfig:
    """What ``rsb dataset build`` is asked for (see ``rsb dataset build --help``)."""

    suites: Sequence[str] = ("paper",)
    out: str = "datasets"
    targets: str = DEFAULT_TARGETS
    split: str = "train"
    questions: str = "all"
    cameras: Sequence[str] = CAMERAS
    fps: int | None = None
    naming: str = DEFAULT_NAMING
    num_procs: int = 1
    shard_size: int = DEFAULT_SHARD_SIZE
    data_dir: str | None = None
    max_attempts: int = 20
    progress: bool = True
    env_kwargs: dict = field(default_factory=dict)  # e.g. camera_size=(w, h)


def _check_settings(work: Path, dataset: Path | None, settings: dict) -> bool:
    """True when ``dataset`` is already built with ``settings``; raises when ``work`` or ``dataset``
    hold a build of other settings (nothing is touched then). A dataset built with another shard
    size is the same dataset (``WORK_ONLY``)."""
    def differs(path: Path, ignored: tuple[str, ...]) -> str | None:
        if not path.is_file():
            return None
        old = json.loads(path.read_text())
        diff = sorted(k for k in (set(old) | set(settings)) - set(ignored) if old.get(k) != settings.get(k))
        return ", ".join(f"{k}={old.get(k)!r} there, {settings.get(k)!r} now" for k in diff) or None

    checks = [(work / SETTINGS_FILE, work, PROVENANCE)]
    if dataset is not None:
        if dataset.exists() and not (dataset / BUILD_META).is_file():
            raise ExportError(f"{dataset} exists and is not an `rsb dataset build` output; use another --out")
        checks.insert(0, (dataset / BUILD_META, dataset, PROVENANCE + WORK_ONLY))
    for path, holder, ignored in checks:
        d = differs(path, ignored)
        if d:
            raise ExportError(f"{holder} holds a build of other settings ({d}); use another --out or delete it")
        if holder == dataset and path.is_file():
            return True  # built: the work directory's shards no longer matter
    return False


# ------------------------------------------------------------------ driver side


class _Progress:
    """One bar for the whole job: episodes (a shard's failed questions count as done), frames, ETA."""

    def __init__(self, total: int, enabled: bool):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc="dataset", unit="ep", disable=not enabled, dynamic_ncols=True,
                        file=sys.stderr)
        self.frames = self.episodes = self.shards = 0
        self.t0 = time.perf_counter()

    def __call__(self, msg: dict) -> None:
        if msg.get("type") == "episode":
            self.episodes += 1
            self.frames += msg["frames"]
            self.bar.update(1)
        elif msg.get("type") == "shard":
            self.shards += 1
            self.bar.update(msg["expected"] - msg["episodes"])  # questions without a demo, or already there
        fps = self.frames / max(time.perf_counter() - self.t0, 1e-9)
        self.bar.set_postfix(frames=self.frames, fps=f"{fps:.1f}", refresh=False)

    def close(self) -> None:
        self.bar.close()


def _run(shards: list[tuple[Path, dict, int, Any]], num_procs: int, executor: Any,
         progress: bool) -> tuple[list[str], bool, "_Progress"]:
    """Deals ``(work, settings, k, shard)`` items to workers and runs them; returns the workers'
    errors, whether a signal stopped the run, and the progress counters."""
    from rsb_maniskill.parallel.pool import InProcess, InterruptGuard, ProcessPool, deal

    bar = _Progress(sum(s.size for *_, s in shards), progress)
    # one task per worker, its shards dealt round-robin (they may span suites)
    tasks = [{"items": [(str(w), settings, k, s) for w, settings, k, s in part]} for part in deal(shards, num_procs)]
    if 0 < len(tasks) < num_procs:
        # the plan's line said the workers asked for; fewer start where there are fewer shards
        print(f"workers: {len(tasks)} started, one a shard ({len(shards)} shards for --num-procs {num_procs})",
              file=sys.stderr, flush=True)
    if len(tasks) > 1 and executor is None:  # local worker processes: each its share of the cores
        for t in tasks:
            t["lp_threads"] = lavapipe_share(len(tasks))
    try:
        chosen = executor or (InProcess() if len(tasks) <= 1 else ProcessPool())
        if not tasks:
            outcome = None
        elif isinstance(chosen, InProcess) and threading.current_thread() is threading.main_thread():
            with InterruptGuard() as guard:  # SIGTERM stops a one-process build as Ctrl-C does
                try:
                    outcome = chosen.run(run_worker, tasks, bar)
                except Exception as err:  # native code's own error in place of the signal's
                    if guard.signal_behind(err) is None:
                        raise
                    return [], True, bar
        else:  # ProcessPool and Ray handle SIGINT / SIGTERM themselves
            outcome = chosen.run(run_worker, tasks, bar)
    except KeyboardInterrupt:  # in this process (InProcess): the shard in flight was dropped whole
        return [], True, bar
    finally:
        bar.close()
        for work in {w for w, *_ in shards}:  # a worker stopped (or killed after the grace) mid-shard
            clean_temps(work)                  # leaves its folder; every worker has ended here
    if outcome is None:
        return [], False, bar
    interrupted = bool(outcome.interrupted or any(t.interrupted for t in outcome.tasks))
    return [t.error for t in outcome.tasks if t.error], interrupted, bar


def export_lerobot(demos: Sequence[str | os.PathLike], out: str | os.PathLike, *, fps: int | None = None,
                   cameras: Sequence[str] = CAMERAS, naming: str = DEFAULT_NAMING, overwrite: bool = False,
                   progress: bool = True, num_procs: int = 1, executor: Any = None,
                   shard_size: int | None = None) -> dict[str, Any]:
    """Writes the episodes of ``demos`` (``rsb generate`` files, merged or converted ones too) as
    one LeRobot v3.0 dataset under ``out``; returns a summary.

    The episodes are cut into shards of ``shard_size`` (default: a few per worker), rendered by
    ``num_procs`` worker processes (or ``executor``, e.g. Ray), each shard written whole under
    ``.<out>.work/`` beside ``out``, then merged into ``out``. A rerun after an interruption keeps
    the finished shards; nothing is written at ``out`` until the merge is complete. Demos of two
    benchmark versions do not go into one dataset; ``meta/rsb_export.json`` names the version."""
    try:
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        raise ExportError("writing parquet needs pyarrow: pip install 'rsb_maniskill[export]'") from None
    from rsb_maniskill.export.lerobot import check_cameras, check_fps, check_out
    from rsb_maniskill.version import UNVERSIONED, benchmark_label, code_commit, package_version

    out = Path(out)
    cameras = check_cameras(cameras, naming)
    fps, _ = check_fps(fps)
    from rsb_maniskill.motionplan.dataset import DatasetError, check_pair

    paths = [Path(p) for p in demos]
    ids, versions = [], {}
    for p in paths:
        if p.suffix != ".h5" or not p.is_file() or not p.with_suffix(".json").is_file():
            raise ExportError(f"{p}: not a trajectory file pair (X.h5 with X.json beside it)")
        try:
            data = check_pair(p)  # both files readable, and they agree (errors name the file)
        except DatasetError as err:
            raise ExportError(str(err)) from None
        ids.append((p, [int(e["episode_id"]) for e in data["episodes"]]))
        versions.setdefault((data.get("rsb") or {}).get("benchmark_version") or UNVERSIONED, p)
    if len(versions) > 1:
        (va, pa), (vb, pb) = sorted(versions.items())[:2]
        raise ExportError(f"{pa} holds demos of {benchmark_label(va)}, {pb} of {benchmark_label(vb)}: one dataset "
                          "holds the episodes of one benchmark version")
    check_out(out, overwrite)
    total = sum(len(i) for _, i in ids)
    if total == 0:
        raise ExportError("the demo files hold no episodes")
    if num_procs < 1:
        raise ExportError(f"--num-procs must be >= 1, got {num_procs}")
    size = shard_size or max(1, min(50, -(-total // (4 * num_procs))))
    shards = [ExportShard(str(p), tuple(i[k:k + size])) for p, i in ids for k in range(0, len(i), size)]
    settings = {"demos": [str(p.resolve()) for p in paths], "fps": fps, "cameras": list(cameras), "naming": naming,
                "shard_size": size}
    meta = {"benchmark_version": next(iter(versions)), "rsb_version": package_version(),
            "code_commit": code_commit(), **settings}
    return run_export_shards(shards, out, settings, num_procs=num_procs, executor=executor, progress=progress,
                             overwrite=overwrite, meta=meta)


def run_export_shards(shards: list[ExportShard], out: Path, settings: dict, *, num_procs: int, executor: Any,
                      progress: bool, overwrite: bool, meta: dict) -> dict[str, Any]:
    """``rsb export lerobot``: render the shards in workers, then merge them into ``out`` (with
    ``meta`` as ``meta/rsb_export.json``)."""
    from rsb_maniskill.export.merge import merge_datasets

    try:  # a read-only or missing-permission --out: named by the user's path, not the work folder beside it
        writable_dir(out.parent)
    except OSError as err:
        raise ExportError(f"cannot write to --out {out}: {err.strerror or err}; choose a writable --out") from None
    work = out.parent / f".{out.name}.work"
    if overwrite and (work / SETTINGS_FILE).is_file() and json.loads((work / SETTINGS_FILE).read_text()) != settings:
        shutil.rmtree(work)
    _check_settings(work, None, settings)
    work.mkdir(parents=True, exist_ok=True)
    (work / SETTINGS_FILE).write_text(json.dumps(settings, indent=1))
    clean_temps(work)
    done = done_shards(work, len(shards))
    todo = [(work, settings, k, s) for k, s in enumerate(shards) if k not in done]
    errors, interrupted, _ = _run(todo, min(num_procs, max(1, len(todo))), executor, progress)
    if interrupted:
        raise KeyboardInterrupt(f"interrupted: {len(done_shards(work, len(shards)))} of {len(shards)} shards "
                                "written; rerun the same command to continue")
    if errors:
        raise ExportError(f"a worker failed (finished shards are kept; rerun to continue): {errors[0]}")
    full = [shard_dir(work, k) for k in range(len(shards))
            if json.loads((shard_dir(work, k) / SHARD_META).read_text())["episodes"]]
    summary = merge_datasets(full, out, extra_files={EXPORT_META: json.dumps(meta, indent=1)})
    shutil.rmtree(work, ignore_errors=True)
    return summary


def _suite_plan(cfg: BuildConfig) -> list[tuple[str, int, int, int]]:
    """(env id, first question, stop, pool size) per suite, all checked before anything is written."""
    from rsb_maniskill.env_ids import resolve_env_ids
    from rsb_maniskill.motionplan.config import GenerateError
    from rsb_maniskill.motionplan.shards import question_list
    from rsb_maniskill.objects.family import join_env_id, split_env_id, target_names
    from rsb_maniskill.semantic import EpisodeSampler, SemanticError

    if cfg.targets not in target_names():
        raise ExportError(f"unknown --targets {cfg.targets!r}; valid: {', '.join(target_names())}")
    if cfg.shard_size < 1 or cfg.num_procs < 1:
        raise ExportError(f"--shard-size and --num-procs must be >= 1, got {cfg.shard_size} and {cfg.num_procs}")
    try:
        env_ids = resolve_env_ids(list(cfg.suites))
    except ValueError as err:
        raise ExportError(str(err)) from None
    plan = []
    for eid in env_ids:
        suite_id, targets = split_env_id(eid)
        if cfg.targets != DEFAULT_TARGETS:  # --targets other than the default: every suite with that family
            eid, targets = join_env_id(suite_id, cfg.targets), cfg.targets
        try:
            pool = EpisodeSampler(suite_id, split=cfg.split, targets=targets, data_dir=cfg.data_dir).num_questions
            qs = question_list(cfg.questions, pool, None)
        except (ValueError, SemanticError, GenerateError) as err:
            raise ExportError(f"{eid}: {err}") from None
        if qs != list(range(qs[0], qs[-1] + 1)):
            raise ExportError(f"--questions must be 'all' or START:STOP, got {cfg.questions!r}")
        plan.append((eid, qs[0], qs[-1] + 1, pool))
    return list(dict.fromkeys(plan))


def build_settings(cfg: BuildConfig, env_id: str, start: int, stop: int, pool: int) -> dict[str, Any]:
    """What decides a suite's episodes and files: a rerun must ask for the same to resume."""
    from rsb_maniskill.export.lerobot import check_cameras, check_fps
    from rsb_maniskill.version import BENCHMARK_VERSION, package_version

    return {"benchmark_version": BENCHMARK_VERSION, "rsb_version": package_version(), "env_id": env_id,
            "split": cfg.split,
            "questions": f"{start}:{stop}", "pool_size": pool, "cameras": list(check_cameras(cfg.cameras, cfg.naming)),
            "fps": check_fps(cfg.fps)[0], "naming": cfg.naming, "shard_size": cfg.shard_size,
            "max_attempts": cfg.max_attempts, "env_kwargs": {k: list(v) if isinstance(v, tuple) else v
                                                             for k, v in cfg.env_kwargs.items()},
            "data_dir": cfg.data_dir}


def build_datasets(cfg: BuildConfig, executor: Any = None) -> list[dict[str, Any]]:
    """Runs the whole build (see the module doc); returns one summary per suite. Raises
    ``KeyboardInterrupt`` (finished shards kept) when stopped, ``ExportError`` on bad input."""
    from rsb_maniskill.export.card import dataset_card
    from rsb_maniskill.export.merge import merge_datasets
    from rsb_maniskill.version import code_commit

    out = Path(cfg.out)
    suites = []
    for env_id, start, stop, pool in _suite_plan(cfg):
        settings = build_settings(cfg, env_id, start, stop, pool)
        work, dataset = out / WORK_DIR / env_id, out / env_id
        complete = _check_settings(work, dataset, {k: v for k, v in settings.items() if k != "data_dir"})
        shards = [SuiteShard(env_id, a, min(a + cfg.shard_size, stop)) for a in range(start, stop, cfg.shard_size)]
        suites.append((env_id, settings, work, dataset, shards, complete))
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ExportError(f"cannot create --out {out}: {err}") from None
    todo = []
    for env_id, settings, work, dataset, shards, complete in suites:
        if complete:
            continue
        work.mkdir(parents=True, exist_ok=True)
        (work / SETTINGS_FILE).write_text(json.dumps({k: v for k, v in settings.items() if k != "data_dir"}, indent=1))
        clean_temps(work)
        done = done_shards(work, len(shards))
        todo += [(work, settings, k, s) for k, s in enumerate(shards) if k not in done]
    t0 = time.perf_counter()
    errors, interrupted, bar = _run(todo, min(cfg.num_procs, max(1, len(todo))), executor, cfg.progress)
    if interrupted:
        total = sum(len(s[4]) for s in suites)
        have = sum(len(done_shards(s[2], len(s[4]))) for s in suites)
        raise KeyboardInterrupt(f"interrupted: {have} of {total} shards written under {out / WORK_DIR}; rerun the "
                                "same command to continue")
    if errors:
        raise ExportError(f"a worker failed (finished shards are kept; rerun to continue): {errors[0]}")
    summaries = []
    for env_id, settings, work, dataset, shards, complete in suites:
        if not complete:
            metas = [json.loads((shard_dir(work, k) / SHARD_META).read_text()) for k in range(len(shards))]
            public = {k: v for k, v in settings.items() if k != "data_dir" and k not in WORK_ONLY}
            skipped = sorted(q for m in metas for q in m.get("skipped_questions", []))
            full = [shard_dir(work, k) for k, m in enumerate(metas) if m["episodes"]]
            meta = {**public, "code_commit": code_commit(), "skipped_questions": skipped}
            info = merge_datasets(full, dataset, extra_files={BUILD_META: json.dumps(meta, indent=1)})
            card = dataset_card(dataset, meta)
            (dataset / "README.md").write_text(card)
        info = json.loads((dataset / INFO_FILE).read_text())
        summaries.append({"env_id": env_id, "out": str(dataset), "episodes": info["total_episodes"],
                          "frames": info["total_frames"], "already_built": complete})
    summaries.append({"wall_s": time.perf_counter() - t0, "rendered_frames": bar.frames,
                      "rendered_episodes": bar.episodes})
    return summaries
