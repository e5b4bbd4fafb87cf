"""The shards of ``rsb dataset build`` and ``rsb export lerobot``: what one is, where it lives on
disk, and the worker that makes it (``export/build.py`` plans the shards and deals them out).

A worker takes the shards dealt to it and, for each one, runs the scripted expert on its questions
(``rsb generate``'s code, into a temporary demo file) or takes its demo file's episodes, renders
the demos' camera frames from their recorded states (``export/render_demos.py``) and writes the
shard as a small LeRobot dataset (``write_dataset``) under a temporary name, renamed into
``<work>/shards/`` only when whole: a shard is there completely or not at all.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from rsb_maniskill.export.lerobot import ExportError, check_fps, write_dataset
from rsb_maniskill.export.render_demos import render_episodes
from rsb_maniskill.sim.render import limit_lavapipe_threads

SHARD_META = "meta/rsb_shard.json"


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


# ------------------------------------------------------------------ shards on disk


def shard_dir(work: Path, k: int) -> Path:
    return work / "shards" / f"shard-{k:05d}"


def done_shards(work: Path, count: int) -> set[int]:
    """Indices of the shards already written whole (a shard directory appears by rename only)."""
    return {k for k in range(count) if (shard_dir(work, k) / SHARD_META).is_file()}


def clean_temps(work: Path) -> None:
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


# ------------------------------------------------------------------ worker side


def _write_shard(work: Path, settings: dict, k: int, shard: ExportShard | SuiteShard, emit: Any) -> None:
    """Makes shard ``k`` of ``work`` whole under a temporary name, then renames it into place."""
    from rsb_maniskill.parallel.pool import Interrupted

    final = shard_dir(work, k)
    if (final / SHARD_META).is_file():
        emit({"type": "shard", "expected": shard.size, "episodes": 0, "skipped": True})
        return
    tmp = work / "tmp" / f"shard-{k:05d}.{os.getpid()}"
    try:  # from before the folder exists: a signal at any point leaves nothing half-written
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)  # (exist_ok on the shared parents: workers create them at once)
        fps, stride = check_fps(settings["fps"])
        meta: dict[str, Any] = {"shard": k, **asdict(shard)}
        if isinstance(shard, SuiteShard):
            demo, extra = _generate(shard, settings, tmp / "demos")
            meta.update(extra)
            ids = None
        else:
            demo, ids = Path(shard.demo), shard.episode_ids
        episodes = 0
        if demo is not None:
            rendered = render_episodes(demo, settings["cameras"], stride, ids, source=isinstance(shard, ExportShard))
            out = write_dataset(rendered, tmp / "dataset", fps=fps,
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
    from rsb_maniskill.parallel.pool import InProcess, Interrupted

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


def run_worker(task: dict, emit: Any) -> int:
    """Executor target: the shards dealt to one worker (of any suites), one after the other."""
    limit_lavapipe_threads(task.get("lp_threads"))  # before the first render env of this process
    for work, settings, k, shard in task["items"]:
        _write_shard(Path(work), settings, k, shard, emit)
    return len(task["items"])
