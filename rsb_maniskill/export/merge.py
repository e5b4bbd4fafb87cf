"""Merging LeRobot v3.0 datasets written by separate workers (or machines) into one.

Each shard is a complete dataset (``write_dataset``). The merge renumbers episodes, frames and
tasks, gives each shard's data parquet its own ``data/chunk-CCC/file-FFF.parquet`` (LeRobot's
chunked layout: ``CHUNKS_SIZE`` files a chunk), moves every episode video to the chunk and file of
its new episode index (hard links: no copy, and the shards stay intact), and recomputes the
dataset statistics from the per-episode ones. It writes under a temporary name beside ``out`` and
renames at the end, so an interrupted merge leaves the shards as they were and nothing at ``out``.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from rsb_maniskill.export.lerobot import (
    CHUNKS_SIZE,
    DATA_FILE,
    DATA_PATH,
    EPISODES_FILE,
    INFO_FILE,
    STATS_FILE,
    TASKS_FILE,
    VIDEO_PATH,
    ExportError,
    aggregate_stats,
    jsonable_stats,
    tasks_table,
)


def _link(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:  # another filesystem, or no hard links there
        shutil.copy2(src, dst)


def _episode_stats(row: dict[str, Any], features: Sequence[str]) -> dict[str, dict[str, np.ndarray]]:
    """The per-episode statistics stored in an episodes-table row, as arrays."""
    out: dict[str, dict[str, np.ndarray]] = {f: {} for f in features}
    for key, value in row.items():
        if key.startswith("stats/"):
            feature, stat = key[len("stats/"):].rsplit("/", 1)
            if feature in out:
                out[feature][stat] = np.asarray(value, dtype=np.float64)
    return out


def video_keys(info: dict) -> list[str]:
    return [k for k, ft in info["features"].items() if ft["dtype"] == "video"]


def merge_datasets(shards: Sequence[str | os.PathLike], out: str | os.PathLike,
                   extra_files: dict[str, str] | None = None) -> dict[str, Any]:
    """Merges the v3.0 datasets ``shards`` (in this order) into one at ``out`` (replaced if it exists);
    ``extra_files`` (relative path -> text) are written into it too (a dataset card)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    shards = [Path(s) for s in shards]
    if not shards:
        raise ExportError("nothing to merge: no shard holds an episode")
    out = Path(out)
    tmp = out.parent / f".{out.name}.merge{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    info0 = json.loads((shards[0] / INFO_FILE).read_text())
    keys = video_keys(info0)
    stat_features = [k for k, ft in info0["features"].items() if k not in ("index",)]
    tasks: dict[str, int] = {}
    rows: list[dict[str, Any]] = []
    stats: list[dict[str, dict[str, np.ndarray]]] = []
    frames = 0
    try:
        for k, shard in enumerate(shards):
            info = json.loads((shard / INFO_FILE).read_text())
            if info["features"] != info0["features"] or info["fps"] != info0["fps"]:
                raise ExportError(f"{shard}: its features or fps differ from {shards[0]}'s; merge shards of one build")
            local_tasks = pq.read_table(shard / TASKS_FILE).to_pydict()
            task_map = {i: tasks.setdefault(t, len(tasks))
                        for i, t in zip(local_tasks["task_index"], local_tasks["task"])}
            data = pq.read_table(shard / DATA_FILE)
            e0 = len(rows)
            columns = {
                "episode_index": pa.array(np.asarray(data["episode_index"]) + e0, pa.int64()),
                "index": pa.array(np.asarray(data["index"]) + frames, pa.int64()),
                "task_index": pa.array([task_map[t] for t in data["task_index"].to_pylist()], pa.int64()),
            }
            for name, col in columns.items():
                data = data.set_column(data.schema.get_field_index(name), name, col)
            chunk, file = divmod(k, CHUNKS_SIZE)
            data_path = tmp / DATA_PATH.format(chunk_index=chunk, file_index=file)
            data_path.parent.mkdir(parents=True, exist_ok=True)
            pq.write_table(data, data_path)
            for row in pq.read_table(shard / EPISODES_FILE).to_pylist():
                e = row["episode_index"] + e0
                row.update({"episode_index": e, "data/chunk_index": chunk, "data/file_index": file,
                            "dataset_from_index": row["dataset_from_index"] + frames,
                            "dataset_to_index": row["dataset_to_index"] + frames})
                new_chunk, new_file = divmod(e, CHUNKS_SIZE)
                for key in keys:
                    src = shard / VIDEO_PATH.format(video_key=key, chunk_index=row[f"videos/{key}/chunk_index"],
                                                    file_index=row[f"videos/{key}/file_index"])
                    _link(src, tmp / VIDEO_PATH.format(video_key=key, chunk_index=new_chunk, file_index=new_file))
                    row[f"videos/{key}/chunk_index"], row[f"videos/{key}/file_index"] = new_chunk, new_file
                rows.append(row)
                stats.append(_episode_stats(row, stat_features))
            frames += data.num_rows
        (tmp / EPISODES_FILE).parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.Table.from_pylist(rows), tmp / EPISODES_FILE)
        pq.write_table(tasks_table(tasks), tmp / TASKS_FILE)
        features = [f for f in stat_features if all(stats_[f] for stats_ in stats)]
        agg = {f: aggregate_stats([s[f] for s in stats]) for f in features}
        (tmp / STATS_FILE).write_text(json.dumps(jsonable_stats(agg), indent=1))
        info = dict(info0, total_episodes=len(rows), total_frames=frames, total_tasks=len(tasks),
                    data_path=DATA_PATH, splits={"train": f"0:{len(rows)}"})
        (tmp / INFO_FILE).write_text(json.dumps(info, indent=4))
        for rel, text in (extra_files or {}).items():
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp / rel).write_text(text)
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {"out": str(out), "episodes": len(rows), "frames": frames, "tasks": len(tasks), "fps": info0["fps"],
            "cameras": keys}
