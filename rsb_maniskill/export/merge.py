"""Merging LeRobot v3.0 datasets written by separate workers (or machines) into one.

Each shard is a complete dataset (``write_dataset``). The merge renumbers episodes, frames and
tasks, and files the frames anew: consecutive episodes fill ``data/chunk-CCC/file-FFF.parquet``
(LeRobot's chunked layout: ``CHUNKS_SIZE`` files a chunk) up to ``DATA_FILE_FRAMES`` frames a file,
whatever shard they came from. It moves every episode video to the chunk and file of its new
episode index (hard links: no copy, and the shards stay intact), gives the renumbered columns
(episode, frame and task index) their per-episode statistics of the new values, as LeRobot's own
aggregation does, and computes the dataset statistics from the per-episode ones. So the merged
dataset is the same, file for file and byte for byte, however the episodes were cut into shards.
It writes under a temporary name beside ``out`` and renames at the end, so an interrupted merge
leaves the shards as they were and nothing at ``out``.
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
    vector_stats,
)

# Frames a merged data file holds at most (whole episodes; about 75 MB of state and action at 148
# bytes a frame, under LeRobot's 100 MB data files); fixed, so the files do not depend on the shards.
DATA_FILE_FRAMES = 500_000
RENUMBERED = ("episode_index", "index", "task_index")  # the columns a merge renumbers


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


def _renumbered_stats(episode: int, first: int, length: int, task: int) -> dict[str, dict[str, np.ndarray]]:
    """The per-episode statistics of the renumbered columns, of their new values: what writing the
    whole dataset at once would have computed (``lerobot._frame_table``'s columns), exactly.
    LeRobot's aggregation shifts the old ones by the offsets, which rounds a mean differently."""
    return {"episode_index": vector_stats(np.full(length, episode)), "index": vector_stats(first + np.arange(length)),
            "task_index": vector_stats(np.full(length, task))}


class _DataFiles:
    """Writes the merged frames into data files of whole episodes, ``DATA_FILE_FRAMES`` at most each."""

    def __init__(self, root: Path) -> None:
        self.root, self.pending, self.frames, self.file = root, [], 0, 0

    def add(self, table: Any) -> tuple[int, int]:
        """Files one episode's rows; returns the (chunk, file) index of the data file it went to."""
        if self.pending and self.frames + table.num_rows > DATA_FILE_FRAMES:
            self.flush()
        self.pending.append(table)
        self.frames += table.num_rows
        return divmod(self.file, CHUNKS_SIZE)

    def flush(self) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        if not self.pending:
            return
        chunk, file = divmod(self.file, CHUNKS_SIZE)
        path = self.root / DATA_PATH.format(chunk_index=chunk, file_index=file)
        path.parent.mkdir(parents=True, exist_ok=True)
        # one contiguous table: the bytes depend on the rows only, not on how the shards cut them
        pq.write_table(pa.concat_tables(self.pending).combine_chunks(), path)
        self.pending, self.frames, self.file = [], 0, self.file + 1


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
    data_files = _DataFiles(tmp)
    try:
        for shard in shards:
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
            for row in pq.read_table(shard / EPISODES_FILE).to_pylist():
                e, first, n = row["episode_index"] + e0, row["dataset_from_index"], row["length"]
                chunk, file = data_files.add(data.slice(first, n))
                row.update({"episode_index": e, "data/chunk_index": chunk, "data/file_index": file,
                            "dataset_from_index": first + frames, "dataset_to_index": row["dataset_to_index"] + frames})
                renumbered = _renumbered_stats(e, first + frames, n, tasks[row["tasks"][0]])
                row.update({f"stats/{f}/{stat}": np.asarray(v).tolist() for f, st in renumbered.items()
                            for stat, v in st.items() if f"stats/{f}/{stat}" in row})
                new_chunk, new_file = divmod(e, CHUNKS_SIZE)
                for key in keys:
                    src = shard / VIDEO_PATH.format(video_key=key, chunk_index=row[f"videos/{key}/chunk_index"],
                                                    file_index=row[f"videos/{key}/file_index"])
                    _link(src, tmp / VIDEO_PATH.format(video_key=key, chunk_index=new_chunk, file_index=new_file))
                    row[f"videos/{key}/chunk_index"], row[f"videos/{key}/file_index"] = new_chunk, new_file
                rows.append(row)
                stats.append(_episode_stats(row, stat_features))
            frames += data.num_rows
        data_files.flush()
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
