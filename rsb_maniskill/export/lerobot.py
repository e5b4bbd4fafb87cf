"""RSB demonstrations as a LeRobot dataset (format v3.0), written with pyarrow and OpenCV.

Layout (what ``lerobot.datasets.LeRobotDataset`` reads): ``meta/info.json``, ``meta/stats.json``,
``meta/tasks.parquet`` (one row per distinct instruction, the task string as pandas index),
``meta/episodes/chunk-000/file-000.parquet`` (one row per episode: tasks, length, frame range, video
files and timestamps, per-episode statistics, and the RSB metadata as ``rsb/*`` columns),
``data/chunk-000/file-000.parquet`` (one row per frame) and ``videos/<camera>/chunk-CCC/file-FFF.mp4``
(one file per episode and camera, MPEG-4 from OpenCV).

An :class:`Episode` holds camera frames (``export/render_demos.py`` renders them from the recorded
env states of ``rsb generate``'s state-only demos), ``observation.state`` and ``action`` in the
Aloha 14-number layout (``to_aloha14``) and the episode's instruction as its task. Feature keys
follow a naming (``export/naming.py``). No simulator here, and LeRobot's own package is not
imported either: its pins (torch, numpy 2) clash with the project's.

:func:`write_dataset` writes one dataset from an iterable of episodes in this process (videos are
encoded on a thread while the next episode renders). ``rsb export lerobot`` (``export/build.py``:
``export_lerobot``) splits the demos into shards, writes each with :func:`write_dataset` in worker
processes (``rsb_maniskill.parallel.pool``) and merges them (``export/merge.py``); ``rsb dataset build``
does the same with the expert's demos made in the same workers.
"""
from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from rsb_maniskill.export.naming import DEFAULT_NAMING, NAMINGS, video_key
from rsb_maniskill.robot import ALOHA14_NAMES, CAMERAS

CODEBASE_VERSION = "v3.0"
ROBOT_TYPE = "aloha"
ALOHA14_DIM = len(ALOHA14_NAMES)  # observation.state and action
CHUNKS_SIZE = 1000  # files per chunk directory, LeRobot's default
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
IMAGE_STATS_FRAMES = 20  # frames per episode sampled for image statistics ...
IMAGE_STATS_STEP = 4  # ... every 4th pixel each way (LeRobot also samples and downsamples)
VIDEO_FOURCC, VIDEO_CODEC = "mp4v", "mpeg4"
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
DATA_FILE = DATA_PATH.format(chunk_index=0, file_index=0)  # a dataset written here has one data file
EPISODES_FILE = "meta/episodes/chunk-000/file-000.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
INFO_FILE, STATS_FILE, TASKS_FILE = "meta/info.json", "meta/stats.json", "meta/tasks.parquet"


class ExportError(RuntimeError):
    """A demo file cannot be exported, or the output directory is not usable."""


@dataclass
class Episode:
    """One exported episode: Aloha-layout state and action, camera frames, task, RSB metadata."""

    state: np.ndarray  # (T, 14) float32, Aloha-14
    action: np.ndarray  # (T, 14) float32, Aloha-14
    frames: dict[str, np.ndarray]  # camera -> (T, H, W, 3) uint8
    task: str
    meta: dict[str, Any] = field(default_factory=dict)


# ------------------------------------------------------------------ statistics (LeRobot's keys)


def vector_stats(x: np.ndarray) -> dict[str, np.ndarray]:
    """min / max / mean / std / count / quantiles of (T, D) values, per dimension."""
    x = np.asarray(x, dtype=np.float64).reshape(len(x), -1)
    out = dict(min=x.min(0), max=x.max(0), mean=x.mean(0), std=x.std(0), count=np.array([len(x)]))
    out.update({f"q{int(round(q * 100)):02d}": np.quantile(x, q, axis=0) for q in QUANTILES})
    return out


def image_stats(frames: np.ndarray) -> dict[str, np.ndarray]:
    """Per-channel statistics of (T, H, W, 3) uint8 frames scaled to [0, 1], shaped (3, 1, 1) as
    LeRobot stores them; a spread-out sample of frames and pixels stands for the episode."""
    idx = np.linspace(0, len(frames) - 1, min(len(frames), IMAGE_STATS_FRAMES)).round().astype(int)
    px = frames[idx, ::IMAGE_STATS_STEP, ::IMAGE_STATS_STEP].reshape(-1, 3).astype(np.float64) / 255.0
    s = vector_stats(px)
    s = {k: (v if k == "count" else v.reshape(3, 1, 1)) for k, v in s.items()}
    s["count"] = np.array([len(frames)])
    return s


def aggregate_stats(per_episode: Sequence[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Dataset statistics from episode ones: exact min, max, mean and std (pooled variance),
    count-weighted quantiles (the approximation LeRobot itself makes)."""
    w = np.array([float(s["count"][0]) for s in per_episode])
    wn = (w / w.sum()).reshape(-1, *([1] * per_episode[0]["mean"].ndim))
    means = np.stack([s["mean"] for s in per_episode])
    mean = (wn * means).sum(0)
    var = (wn * (np.stack([s["std"] for s in per_episode]) ** 2 + (means - mean) ** 2)).sum(0)
    out = dict(min=np.min([s["min"] for s in per_episode], 0), max=np.max([s["max"] for s in per_episode], 0),
               mean=mean, std=np.sqrt(var), count=np.array([int(w.sum())]))
    for q in QUANTILES:
        k = f"q{int(round(q * 100)):02d}"
        out[k] = (wn * np.stack([s[k] for s in per_episode])).sum(0)
    return out


def jsonable_stats(stats: dict[str, dict[str, np.ndarray]]) -> dict:
    return {f: {k: np.asarray(v).tolist() for k, v in s.items()} for f, s in stats.items()}


# ------------------------------------------------------------------ writing


def _write_video(path: Path, frames: np.ndarray, fps: int) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*VIDEO_FOURCC), float(fps), (w, h))
    if not writer.isOpened():
        raise ExportError(f"OpenCV cannot write {path} ({VIDEO_FOURCC})")
    for frame in frames:
        writer.write(np.ascontiguousarray(frame[..., ::-1]))
    writer.release()


def _hf_metadata(features: dict) -> bytes:
    """The ``huggingface`` schema metadata of the data parquet (what ``datasets`` writes)."""
    hf = {}
    for name, ft in features.items():
        if ft["dtype"] == "video":
            continue
        value = {"dtype": ft["dtype"], "_type": "Value"}
        hf[name] = value if list(ft["shape"]) == [1] else {"feature": value, "length": ft["shape"][0], "_type": "List"}
    return json.dumps({"info": {"features": hf}}).encode()


def _features(cameras: Sequence[str], shapes: dict[str, tuple[int, int]], fps: int, naming: str) -> dict:
    feats: dict[str, Any] = {
        "observation.state": {"dtype": "float32", "shape": [ALOHA14_DIM], "names": list(ALOHA14_NAMES)},
        "action": {"dtype": "float32", "shape": [ALOHA14_DIM], "names": list(ALOHA14_NAMES)},
    }
    for c in cameras:
        h, w = shapes[c]
        feats[video_key(c, naming)] = {"dtype": "video", "shape": [h, w, 3], "names": ["height", "width", "channels"],
                               "info": {"video.height": h, "video.width": w, "video.codec": VIDEO_CODEC,
                                        "video.pix_fmt": "yuv420p", "video.fps": fps, "video.channels": 3,
                                        "has_audio": False, "is_depth_map": False}}
    for name, dtype in (("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
                        ("index", "int64"), ("task_index", "int64")):
        feats[name] = {"dtype": dtype, "shape": [1], "names": None}
    return feats


def tasks_table(tasks: dict[str, int]):
    """``meta/tasks.parquet``: column task_index, index "task" (pandas metadata, as LeRobot reads it)."""
    import pyarrow as pa

    names = sorted(tasks, key=tasks.get)
    table = pa.table({"task_index": pa.array([tasks[t] for t in names], pa.int64()),
                      "task": pa.array(names, pa.string())})
    pandas_md = {"index_columns": ["task"],
                 "column_indexes": [{"name": None, "field_name": None, "pandas_type": "unicode",
                                     "numpy_type": "object", "metadata": {"encoding": "UTF-8"}}],
                 "columns": [{"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
                              "numpy_type": "int64", "metadata": None},
                             {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object",
                              "metadata": None}],
                 "attributes": {}, "creator": {"library": "pyarrow", "version": pa.__version__}}
    return table.replace_schema_metadata({"pandas": json.dumps(pandas_md)})


def check_out(out: Path, overwrite: bool) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not overwrite:
        raise ExportError(f"{out} exists and is not empty; choose another --out or pass --overwrite")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ExportError(f"cannot create {out.parent}: {err}") from None


def _frame_table(ep: Episode, episode_index: int, first_index: int, task_index: int, fps: int):
    """The episode's rows of the data parquet, and the columns its statistics are taken over."""
    import pyarrow as pa

    n = len(ep.action)
    frame_index = np.arange(n)
    cols = {"observation.state": ep.state, "action": ep.action, "timestamp": (frame_index / fps).astype(np.float32),
            "frame_index": frame_index, "episode_index": np.full(n, episode_index),
            "index": first_index + frame_index, "task_index": np.full(n, task_index)}
    table = pa.table({
        "observation.state": pa.FixedSizeListArray.from_arrays(pa.array(ep.state.ravel(), pa.float32()), ALOHA14_DIM),
        "action": pa.FixedSizeListArray.from_arrays(pa.array(ep.action.ravel(), pa.float32()), ALOHA14_DIM),
        "timestamp": pa.array(cols["timestamp"], pa.float32()),
        **{k: pa.array(cols[k], pa.int64()) for k in ("frame_index", "episode_index", "index", "task_index")},
    })
    return table, cols


def _video_columns(episode_index: int, frames: int, cameras: Sequence[str], fps: int,
                   naming: str) -> dict[str, Any]:
    """The episode row's video columns: one mp4 per camera, in the chunk and file of the episode."""
    chunk, file = divmod(episode_index, CHUNKS_SIZE)
    row: dict[str, Any] = {}
    for c in cameras:
        key = video_key(c, naming)
        row.update({f"videos/{key}/chunk_index": chunk, f"videos/{key}/file_index": file,
                    f"videos/{key}/from_timestamp": 0.0, f"videos/{key}/to_timestamp": frames / fps})
    return row


def _write_videos(root: Path, ep: Episode, episode_index: int, cameras: Sequence[str], fps: int,
                  naming: str) -> None:
    """One mp4 per camera, at the path :func:`_video_columns` names."""
    chunk, file = divmod(episode_index, CHUNKS_SIZE)
    for c in cameras:
        key = video_key(c, naming)
        _write_video(root / VIDEO_PATH.format(video_key=key, chunk_index=chunk, file_index=file), ep.frames[c], fps)


def _write_meta(root: Path, episodes: list[dict], tasks: dict[str, int], stats: list[dict], features: dict,
                fps: int, frames: int) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    (root / EPISODES_FILE).parent.mkdir(parents=True)
    pq.write_table(pa.Table.from_pylist(episodes), root / EPISODES_FILE)
    pq.write_table(tasks_table(tasks), root / TASKS_FILE)
    agg = {f: aggregate_stats([s[f] for s in stats]) for f in stats[0]}
    (root / STATS_FILE).write_text(json.dumps(jsonable_stats(agg), indent=1))
    info = {"codebase_version": CODEBASE_VERSION, "fps": fps, "features": features, "total_episodes": len(episodes),
            "total_frames": frames, "total_tasks": len(tasks), "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": 100, "video_files_size_in_mb": 200,
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH,
            "robot_type": ROBOT_TYPE, "splits": {"train": f"0:{len(episodes)}"}}
    (root / INFO_FILE).write_text(json.dumps(info, indent=4))


def check_fps(fps: int | None) -> tuple[int, int]:
    """``(fps, stride)`` for a requested frame rate (default: every control step)."""
    from rsb_maniskill.env_ids import CONTROL_FREQ  # what every RSB demo runs at

    fps = CONTROL_FREQ if fps is None else int(fps)
    if fps < 1 or CONTROL_FREQ % fps:
        raise ExportError(f"--fps must divide the demos' control frequency ({CONTROL_FREQ} Hz), got {fps}")
    return fps, CONTROL_FREQ // fps


def check_cameras(cameras: Sequence[str], naming: str) -> tuple[str, ...]:
    bad = [c for c in cameras if c not in CAMERAS]
    if bad or not cameras:
        raise ExportError(f"unknown camera(s) {', '.join(bad) or '(none given)'}; valid: {', '.join(CAMERAS)}")
    if naming not in NAMINGS:
        raise ExportError(f"unknown naming {naming!r}; valid: {', '.join(NAMINGS)}")
    return tuple(cameras)


class _VideoWriter:
    """Encodes an episode's videos on one thread while the caller renders the next episode; at most
    one episode waits, so memory stays at two episodes' frames."""

    def __init__(self) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rsb-video")
        self._pending = None

    def submit(self, fn: Any, *args: Any) -> None:
        self.wait()
        self._pending = self._pool.submit(fn, *args)

    def wait(self) -> None:
        if self._pending is not None:
            pending, self._pending = self._pending, None
            pending.result()  # re-raises an encoding error here

    def close(self) -> None:
        try:
            self.wait()
        finally:
            self._pool.shutdown(wait=True)


def write_dataset(episodes: Iterable[Episode], out: str | os.PathLike, *, fps: int, cameras: Sequence[str],
                  naming: str = DEFAULT_NAMING, on_episode: Any = None) -> dict[str, Any]:
    """Writes ``episodes`` (frames already at ``fps``) as one LeRobot v3.0 dataset at ``out``, in this
    process; ``on_episode(frames)`` after each. Built under a temporary name beside ``out`` and
    renamed at the end, so an interrupted or failed write leaves nothing at ``out``."""
    import pyarrow.parquet as pq

    out = Path(out)
    tmp = out.parent / f".{out.name}.tmp{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tasks: dict[str, int] = {}
    rows: list[dict[str, Any]] = []
    stats: list[dict[str, dict[str, np.ndarray]]] = []
    shapes: dict[str, tuple[int, int]] = {}
    features: dict = {}
    writer = None
    videos = _VideoWriter()
    index = 0
    try:
        (tmp / DATA_FILE).parent.mkdir(parents=True)
        for ep in episodes:
            e, n = len(rows), len(ep.action)
            if not shapes:
                shapes = {c: ep.frames[c].shape[1:3] for c in cameras}
                features = _features(cameras, shapes, fps, naming)
            bad = [c for c in cameras if ep.frames[c].shape[1:3] != shapes[c]]
            if bad:
                raise ExportError(f"{ep.meta.get('source_file', 'a demo')}: camera {bad[0]} is "
                                  f"{ep.frames[bad[0]].shape[1:3]} here, {shapes[bad[0]]} before; export demos "
                                  "of one camera size together")
            table, cols = _frame_table(ep, e, index, tasks.setdefault(ep.task, len(tasks)), fps)
            if writer is None:
                writer = pq.ParquetWriter(tmp / DATA_FILE, table.schema.with_metadata(
                    {"huggingface": _hf_metadata(features)}))
            writer.write_table(table.replace_schema_metadata(writer.schema.metadata))
            ep_stats = {k: vector_stats(v) for k, v in cols.items()}
            ep_stats.update({video_key(c, naming): image_stats(ep.frames[c]) for c in cameras})
            row: dict[str, Any] = {"episode_index": e, "tasks": [ep.task], "length": n, "data/chunk_index": 0,
                                   "data/file_index": 0, "dataset_from_index": index, "dataset_to_index": index + n}
            row.update(_video_columns(e, n, cameras, fps, naming))
            videos.submit(_write_videos, tmp, ep, e, cameras, fps, naming)
            row.update({"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0})
            row.update({f"stats/{f}/{k}": np.asarray(v).tolist() for f, st in ep_stats.items() for k, v in st.items()})
            row.update({f"rsb/{k}": v for k, v in ep.meta.items()})
            rows.append(row)
            stats.append(ep_stats)
            index += n
            if on_episode is not None:
                on_episode(n)
        videos.close()
        if writer is None:
            raise ExportError("the demo files hold no episodes")
        writer.close()
        writer = None
        _write_meta(tmp, rows, tasks, stats, features, fps, index)
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        if writer is not None:
            writer.close()
        videos.close()
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {"out": str(out), "episodes": len(rows), "frames": index, "tasks": len(tasks), "fps": fps,
            "cameras": [video_key(c, naming) for c in cameras]}
