"""``rsb dataset build`` and ``rsb export lerobot``: LeRobot datasets in shards, in parallel, resumable.

A build is cut into shards by arithmetic, never by timing: each suite's question range in chunks of
``shard_size`` questions (``rsb export lerobot``: each demo file's episodes in chunks). Workers
(``rsb_maniskill.workers``: this process, spawned processes, or Ray tasks) take the shards dealt
to them, and for each one run the scripted expert on its questions (``rsb generate``'s code, into a
temporary demo file), render the kept demos' camera frames from their recorded states and write
the shard as a small LeRobot dataset (``write_dataset``), renamed into ``<work>/shards/`` only when
whole. A shard is therefore there completely or not at all: a run stopped in any way (Ctrl-C,
SIGTERM, kill -9) loses only the shards in flight, and a rerun of the same command skips the
finished ones. When every shard of a suite is there, they are merged (``export/merge.py``) into
``OUT/<suite>`` with its dataset card. The shard list, hence every episode, does not depend on the
number of workers. Local worker processes share the CPUs for software rendering: each caps
lavapipe's raster threads to its share (``LP_NUM_THREADS``, unless the user set it).

Layout: ``OUT/<suite>/`` (the dataset, ready for ``huggingface-cli upload``) and
``OUT/.work/<suite>/`` (``settings.json`` and ``shards/shard-NNNNN``; safe to delete after the build).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Sequence

from rsb_maniskill.export.lerobot import DEFAULT_CAMERAS, ExportError
from rsb_maniskill.export.naming import DEFAULT_NAMING

WORK_DIR = ".work"
SETTINGS_FILE = "settings.json"
BUILD_META = "meta/rsb_build.json"  # the settings a dataset was built with, inside the dataset
PROVENANCE = ("code_commit", "skipped_questions")  # also in BUILD_META; they decide no episode or file
EXPORT_META = "meta/rsb_export.json"  # what an exported dataset's demos are (benchmark version, ...)
SHARD_META = "meta/rsb_shard.json"
DEFAULT_SHARD_SIZE = 25  # questions a shard: a kill loses at most this many demos per worker


@dataclass(frozen=True)
class ExportShard:
    """Episodes of one demo file (``rsb export lerobot``)."""

    demo: str
    episode_ids: tuple[int, ...]

    @property
    def size(self) -> int:
        return len(self.episode_ids)


@dataclass(frozen=True)
class SuiteShard:
    """Questions ``start .. stop-1`` of a suite's split (``rsb dataset build``): one demo each."""

    env_id: str
    start: int
    stop: int

    @property
    def size(self) -> int:
        return self.stop - self.start


@dataclass
class BuildConfig:
    """What ``rsb dataset build`` is asked for (see ``rsb dataset build --help``)."""

    suites: Sequence[str] = ("paper",)
    out: str = "datasets"
    targets: str = "blocks"
    split: str = "train"
    questions: str = "all"
    cameras: Sequence[str] = ("head", "left_wrist", "right_wrist")
    fps: int | None = None
    naming: str = "rsb"
    num_procs: int = 1
    shard_size: int = DEFAULT_SHARD_SIZE
    data_dir: str | None = None
    max_attempts: int = 20
    progress: bool = True
    env_kwargs: dict = field(default_factory=dict)  # e.g. camera_size=(w, h)


# ------------------------------------------------------------------ shards on disk


def shard_dir(work: Path, k: int) -> Path:
    return work / "shards" / f"shard-{k:05d}"


def done_shards(work: Path, count: int) -> set[int]:
    """Indices of the shards already written whole (a shard directory appears by rename only)."""
    return {k for k in range(count) if (shard_dir(work, k) / SHARD_META).is_file()}


def _clean_temps(work: Path) -> None:
    """Removes temporary shard directories left by runs that were killed."""
    tmp = work / "tmp"
    if tmp.is_dir():
        for d in tmp.iterdir():
            pid = d.name.rsplit(".", 1)[-1]
            if not (pid.isdigit() and _alive(int(pid))):
                shutil.rmtree(d, ignore_errors=True)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except OSError:
        return False
    return True


def _publish(tmp: Path, final: Path) -> None:
    """Renames a whole shard into place; a shard another process finished first wins."""
    final.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.replace(tmp, final)
    except OSError:
        if not (final / SHARD_META).is_file():
            raise


def _check_settings(work: Path, dataset: Path | None, settings: dict) -> bool:
    """True when ``dataset`` is already built with ``settings``; raises when ``work`` or ``dataset``
    hold a build of other settings (nothing is touched then)."""
    def differs(path: Path) -> str | None:
        if not path.is_file():
            return None
        old = json.loads(path.read_text())
        diff = sorted(k for k in (set(old) | set(settings)) - set(PROVENANCE) if old.get(k) != settings.get(k))
        return ", ".join(f"{k}={old.get(k)!r} there, {settings.get(k)!r} now" for k in diff) or None

    for path, holder in ((work / SETTINGS_FILE, work), *(((dataset / BUILD_META, dataset),) if dataset else ())):
        d = differs(path)
        if d:
            raise ExportError(f"{holder} holds a build of other settings ({d}); use another --out or delete it")
    if dataset is None:
        return False
    if dataset.exists() and not (dataset / BUILD_META).is_file():
        raise ExportError(f"{dataset} exists and is not an `rsb dataset build` output; use another --out")
    return (dataset / BUILD_META).is_file()


# ------------------------------------------------------------------ worker side


def _write_shard(work: Path, settings: dict, k: int, shard: ExportShard | SuiteShard, emit: Any) -> None:
    """Makes shard ``k`` of ``work`` whole under a temporary name, then renames it into place."""
    from rsb_maniskill.export.lerobot import check_fps, render_episodes, write_dataset
    from rsb_maniskill.workers import Interrupted

    final = shard_dir(work, k)
    if (final / SHARD_META).is_file():
        emit({"type": "shard", "expected": shard.size, "episodes": 0, "skipped": True})
        return
    tmp = work / "tmp" / f"shard-{k:05d}.{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)  # (exist_ok on the shared parents: workers create them at once)
    fps, stride = check_fps(settings["fps"])
    meta: dict[str, Any] = {"shard": k, **asdict(shard)}
    try:
        if isinstance(shard, SuiteShard):
            demo, extra = _generate(shard, settings, tmp / "demos")
            meta.update(extra)
            ids = None
        else:
            demo, ids = Path(shard.demo), shard.episode_ids
        episodes = 0
        if demo is not None:
            out = write_dataset(render_episodes(demo, settings["cameras"], stride, ids), tmp / "dataset", fps=fps,
                                cameras=settings["cameras"], naming=settings["naming"],
                                on_episode=lambda n: emit({"type": "episode", "frames": n}))
            episodes = out["episodes"]
        else:
            (tmp / "dataset" / "meta").mkdir(parents=True)
        meta["episodes"] = episodes
        (tmp / "dataset" / SHARD_META).write_text(json.dumps(meta, indent=1))
        _publish(tmp / "dataset", final)
        emit({"type": "shard", "expected": shard.size, "episodes": episodes, "skipped": False})
    except KeyboardInterrupt as err:
        raise Interrupted(getattr(err, "signum", signal.SIGINT)) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _generate(shard: SuiteShard, settings: dict, out: Path) -> tuple[Path | None, dict]:
    """The expert's demos of the shard's questions (state only: frames are rendered afterwards)."""
    from rsb_maniskill.motionplan.generate import GenerateConfig, generate
    from rsb_maniskill.workers import InProcess, Interrupted

    env_kwargs = dict(settings.get("env_kwargs") or {})
    if settings.get("data_dir"):
        env_kwargs["data_dir"] = settings["data_dir"]
    cfg = GenerateConfig(env_id=shard.env_id, out=str(out), split=settings["split"],
                         questions=f"{shard.start}:{shard.stop}", progress=False, overwrite=True,
                         max_attempts=settings["max_attempts"], env_kwargs=env_kwargs)
    summary = generate(cfg, executor=InProcess())
    if summary.interrupted:
        raise Interrupted(signal.Signals[summary.interrupted])
    if summary.errors:
        raise ExportError(f"{shard.env_id} questions {shard.start}:{shard.stop}: {summary.errors[0]}")
    return summary.path, {"skipped_questions": summary.skipped_questions, "failures": summary.failures}


def software_rendering() -> bool:
    """True when this process renders with Mesa's lavapipe (the Vulkan driver `_render` picked)."""
    from rsb_maniskill._render import select_vulkan_driver

    icd = select_vulkan_driver() or ""
    return os.path.basename(icd).startswith("lvp")


def limit_lavapipe_threads(threads: int | None) -> bool:
    """Caps lavapipe's rasterizer threads in this process (Mesa's ``LP_NUM_THREADS``); True if set.

    lavapipe starts one raster thread per CPU in every process, so N worker processes on N cores
    would run N x N threads fighting for the cores; each worker takes its share instead. Must run
    before this process's first Vulkan instance (lavapipe reads the variable then); left alone when
    the user has set it, and on GPU drivers."""
    if not threads or "LP_NUM_THREADS" in os.environ or not software_rendering():
        return False
    os.environ["LP_NUM_THREADS"] = str(threads)
    return True


def lavapipe_share(workers: int) -> int:
    """Raster threads per worker when ``workers`` local processes share this machine's CPUs."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cpus = os.cpu_count() or 1
    return max(1, cpus // max(1, workers))


def run_worker(task: dict, emit: Any) -> int:
    """Executor target: the shards dealt to one worker (of any suites), one after the other."""
    limit_lavapipe_threads(task.get("lp_threads"))  # before the first render env of this process
    for work, settings, k, shard in task["items"]:
        _write_shard(Path(work), settings, k, shard, emit)
    return len(task["items"])


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
    from rsb_maniskill.workers import InProcess, InterruptGuard, ProcessPool, deal

    bar = _Progress(sum(s.size for *_, s in shards), progress)
    # one task per worker, its shards dealt round-robin (they may span suites)
    tasks = [{"items": [(str(w), settings, k, s) for w, settings, k, s in part]} for part in deal(shards, num_procs)]
    if len(tasks) > 1 and executor is None:  # local worker processes: each its share of the cores
        for t in tasks:
            t["lp_threads"] = lavapipe_share(len(tasks))
    try:
        chosen = executor or (InProcess() if len(tasks) <= 1 else ProcessPool())
        if not tasks:
            outcome = None
        elif isinstance(chosen, InProcess) and threading.current_thread() is threading.main_thread():
            with InterruptGuard():  # SIGTERM stops a one-process build as Ctrl-C does
                outcome = chosen.run(run_worker, tasks, bar)
        else:  # ProcessPool and Ray handle SIGINT / SIGTERM themselves
            outcome = chosen.run(run_worker, tasks, bar)
    except KeyboardInterrupt:  # in this process (InProcess): the shard in flight was dropped whole
        return [], True, bar
    finally:
        bar.close()
    if outcome is None:
        return [], False, bar
    interrupted = bool(outcome.interrupted or any(t.interrupted for t in outcome.tasks))
    return [t.error for t in outcome.tasks if t.error], interrupted, bar


def export_lerobot(demos: Sequence[str | os.PathLike], out: str | os.PathLike, *, fps: int | None = None,
                   cameras: Sequence[str] = DEFAULT_CAMERAS, naming: str = DEFAULT_NAMING, overwrite: bool = False,
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
    paths = [Path(p) for p in demos]
    for p in paths:
        if p.suffix != ".h5" or not p.is_file() or not p.with_suffix(".json").is_file():
            raise ExportError(f"{p}: not a trajectory file pair (X.h5 with X.json beside it)")
    check_out(out, overwrite)
    ids, versions = [], {}
    for p in paths:
        data = json.loads(p.with_suffix(".json").read_text())
        ids.append((p, [int(e["episode_id"]) for e in data["episodes"]]))
        versions.setdefault((data.get("rsb") or {}).get("benchmark_version") or UNVERSIONED, p)
    if len(versions) > 1:
        (va, pa), (vb, pb) = sorted(versions.items())[:2]
        raise ExportError(f"{pa} holds demos of {benchmark_label(va)}, {pb} of {benchmark_label(vb)}: one dataset "
                          "holds the episodes of one benchmark version")
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

    work = out.parent / f".{out.name}.work"
    if overwrite and (work / SETTINGS_FILE).is_file() and json.loads((work / SETTINGS_FILE).read_text()) != settings:
        shutil.rmtree(work)
    _check_settings(work, None, settings)
    work.mkdir(parents=True, exist_ok=True)
    (work / SETTINGS_FILE).write_text(json.dumps(settings, indent=1))
    _clean_temps(work)
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
    from rsb_maniskill.objects.family import DEFAULT_TARGETS, join_env_id, split_env_id, target_names
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
        _clean_temps(work)
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
            public = {k: v for k, v in settings.items() if k != "data_dir"}
            skipped = sorted(q for m in metas for q in m.get("skipped_questions", []))
            full = [shard_dir(work, k) for k, m in enumerate(metas) if m["episodes"]]
            meta = {**public, "code_commit": code_commit(), "skipped_questions": skipped}
            info = merge_datasets(full, dataset, extra_files={BUILD_META: json.dumps(meta, indent=1)})
            card = dataset_card(dataset, meta)
            (dataset / "README.md").write_text(card)
        info = json.loads((dataset / "meta/info.json").read_text())
        summaries.append({"env_id": env_id, "out": str(dataset), "episodes": info["total_episodes"],
                          "frames": info["total_frames"], "already_built": complete})
    summaries.append({"wall_s": time.perf_counter() - t0, "rendered_frames": bar.frames,
                      "rendered_episodes": bar.episodes})
    return summaries
