"""Trajectory files as ManiSkill writes them (``X.h5`` + ``X.json``): temp names, atomic
finalisation, checks and merging of parts / shards into one dataset.

A dataset is a pair: the .h5 holds groups ``traj_<episode_id>`` (actions, env_states, obs, ...)
and the .json holds ``env_info`` plus one ``episodes`` entry per group. Both are written under
temporary names in the destination directory and renamed at the end (json first, h5 last), so
a finished ``X.h5`` always has its ``X.json`` and a failed run leaves no half-written pair.
"""
from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import h5py

from rsb_maniskill.outdirs import probe_writable

TMP_TAG = ".tmp"
MAX_OPEN_INPUTS = 64  # a merge keeps at most this many input files open


class DatasetError(RuntimeError):
    """A trajectory file pair is missing, inconsistent or cannot be written."""


class NoSpaceError(DatasetError):
    """The device an output is written to is full (or the user's quota is): what is finished is kept."""


def is_no_space(err: BaseException) -> bool:
    """Whether ``err`` is a full disk: an OSError ENOSPC / EDQUOT, or libhdf5's write failure saying so."""
    if isinstance(err, NoSpaceError) or isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(err)
    return f"errno = {errno.ENOSPC}," in text or "No space left on device" in text or "Disk quota exceeded" in text


def no_space(path: str | os.PathLike, then: str = "") -> NoSpaceError:
    """The one-line error of a full disk under ``path``, with what to do (``then``: what is kept)."""
    try:
        free = f" ({shutil.disk_usage(path).free / 2**20:.1f} MiB free)"
    except OSError:
        free = ""
    return NoSpaceError(f"no space left on the device of {path}{free}: free some space or choose another --out"
                        + (f"; {then}" if then else ""))


def check_free_space(directory: str | os.PathLike, needed: int, then: str = "") -> None:
    """NoSpaceError before a write of ``needed`` bytes into ``directory`` that cannot fit."""
    try:
        free = shutil.disk_usage(directory).free
    except OSError:
        return
    if free < needed:
        raise no_space(directory, then)


def json_path_of(h5_path: str | os.PathLike) -> Path:
    """ManiSkill's rule: the metadata lives next to the .h5 with the suffix swapped."""
    p = Path(h5_path)
    if p.suffix != ".h5":
        raise DatasetError(f"{p}: trajectory files must end in .h5")
    return p.with_suffix(".json")


def temp_h5_path(final_h5: str | os.PathLike, tag: str = "") -> Path:
    """Hidden temp name in the same directory (same file system, so rename is atomic)."""
    p = Path(final_h5)
    return p.with_name(f".{p.stem}{TMP_TAG}{os.getpid()}{tag}.h5")


RESUME_SETTINGS = "settings.json"  # in a resume folder: what the interrupted run was asked for
RESUME_LOCK = "lock"  # in a resume folder: held (flock) by the run writing into it
DEMO_PREFIX = "demo"  # a kept demo in a resume folder: demo<seed>.h5 + .json, one episode each


def resume_dir_of(final_h5: str | os.PathLike) -> Path:
    """The hidden folder where a run toward ``final_h5`` keeps each finished demo as it ends
    (``.<stem>.partial``): what an interrupted run leaves, and what the same command resumes from."""
    p = Path(final_h5)
    return p.with_name(f".{p.stem}.partial")


def demo_path(resume_dir: str | os.PathLike, seed: int) -> Path:
    return Path(resume_dir) / f"{DEMO_PREFIX}{int(seed):010d}.h5"


def resume_demos(resume_dir: str | os.PathLike) -> dict[int, Path]:
    """The finished demos of a resume folder, by seed, after removing what a killed run left half
    written (temp files, a json without its h5). A demo pair is renamed into place whole (json
    first, h5 last), so an h5 there always has its json."""
    d = Path(resume_dir)
    demos: dict[int, Path] = {}
    for p in sorted(d.iterdir()) if d.is_dir() else []:
        name = p.name
        if name in (RESUME_SETTINGS, RESUME_LOCK):
            continue
        if name.startswith(DEMO_PREFIX) and name.endswith(".h5") and json_path_of(p).exists():
            try:
                demos[int(name[len(DEMO_PREFIX):-3])] = p
                continue
            except ValueError:
                pass
        if name.startswith(DEMO_PREFIX) and name.endswith(".json") and p.with_suffix(".h5").exists():
            continue
        if p.is_file() or p.is_symlink():
            p.unlink()
    return demos


def existing_outputs(h5_path: str | os.PathLike) -> list[Path]:
    """The files of the pair that already exist."""
    h5 = Path(h5_path)
    return [p for p in (h5, json_path_of(h5)) if p.exists()]


def check_writable_dir(directory: Path) -> list[Path]:
    """Creates ``directory`` (and parents) and checks a file can be written there.

    Returns the directories it created, so that a failing run can remove them again."""
    created = []
    missing = []
    d = directory.absolute()
    while not d.exists():
        missing.append(d)
        d = d.parent
    try:
        for d in reversed(missing):
            d.mkdir()
            created.append(d)
        probe_writable(directory)
    except OSError as err:
        remove_empty_dirs(created)
        raise DatasetError(f"cannot write to output directory {directory}: {err.strerror or err}. "
                           "Choose a writable --out or fix its permissions.") from err
    return created


def remove_empty_dirs(dirs: Iterable[Path]) -> None:
    """Removes directories this run created, deepest first, if they stayed empty."""
    for d in sorted(dirs, key=lambda p: len(p.parts), reverse=True):
        try:
            d.rmdir()
        except OSError:
            pass


def remove_pair(h5_path: str | os.PathLike) -> None:
    """Deletes an .h5/.json pair (missing files are fine)."""
    for p in (Path(h5_path), json_path_of(h5_path)):
        try:
            p.unlink()
        except FileNotFoundError:
            pass


def finalize_pair(tmp_h5: str | os.PathLike, final_h5: str | os.PathLike) -> Path:
    """Renames a finished temp pair onto its final name (json first, h5 last). A pair it replaces
    loses its h5 first: a reader never sees the new json beside the old h5 (counts that disagree),
    only a json whose h5 is not there yet."""
    Path(final_h5).unlink(missing_ok=True)
    os.replace(json_path_of(tmp_h5), json_path_of(final_h5))
    os.replace(tmp_h5, final_h5)
    return Path(final_h5)


def load_json(path: str | os.PathLike) -> dict:
    """A trajectory json; DatasetError naming the file when it is not JSON."""
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DatasetError(f"{path}: not valid JSON ({err}): a damaged trajectory file; restore it or make it "
                           "again (rsb generate)") from None


def dump_json(path: str | os.PathLike, data: dict) -> None:
    """ManiSkill's encoder (numpy scalars and arrays) and layout (indent 2)."""
    from mani_skill.utils.io_utils import dump_json as ms_dump_json

    ms_dump_json(path, data, indent=2)


def write_json_atomic(path: str | os.PathLike, data: dict) -> None:
    """Rewrites a json file through a temp name in its directory, so readers never see half of it."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}.json")
    dump_json(tmp, data)
    os.replace(tmp, path)


def annotate_episodes(h5_path: str | os.PathLike, fields_by_seed: Mapping[int, Mapping]) -> int:
    """Adds fields to the json entries of a finished trajectory pair, matched by ``episode_seed``.

    The way RSB metadata (instruction, options, ...) joins ManiSkill's own episode fields: after
    the recorder has closed the pair, never inside it. Returns the number of entries annotated."""
    jp = json_path_of(h5_path)
    data = load_json(jp)
    n = 0
    for ep in data["episodes"]:
        fields = fields_by_seed.get(ep["episode_seed"])
        if fields:
            ep.update(fields)
            n += 1
    write_json_atomic(jp, data)
    return n


def check_pair(h5_path: str | os.PathLike) -> dict:
    """Opens a trajectory pair and checks h5 groups and json episodes agree; returns the json."""
    h5_path = Path(h5_path)
    jp = json_path_of(h5_path)
    if not h5_path.exists() or not jp.exists():
        raise DatasetError(f"{h5_path}: need both {h5_path.name} and {jp.name}")
    data = load_json(jp)
    if "episodes" not in data or "env_info" not in data:
        raise DatasetError(f"{jp}: not a ManiSkill trajectory json (no 'env_info' / 'episodes')")
    try:
        with h5py.File(h5_path, "r") as f:
            groups = set(f.keys())
    except OSError as err:
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise DatasetError(f"{h5_path}: not a readable HDF5 file ({reason}): truncated or damaged; restore it or "
                           "make it again (rsb generate)") from None
    wanted = {f"traj_{ep['episode_id']}" for ep in data["episodes"]}
    if groups != wanted or len(wanted) != len(data["episodes"]):
        raise DatasetError(f"{h5_path}: h5 groups and json episodes disagree "
                           f"({len(groups)} groups, {len(data['episodes'])} episodes)")
    return data


def _env_signature(env_info: dict | None) -> tuple:
    if env_info is None:
        return (None, None)
    kwargs = {k: v for k, v in (env_info.get("env_kwargs") or {}).items() if k != "render_mode"}
    return env_info.get("env_id"), json.dumps(kwargs, sort_keys=True)


def _remove_stale_merges(output: Path) -> None:
    """The temp pair of a merge into ``output`` killed before its rename (kill -9): removed once its
    process is gone (its pid is in the name), so a rerun leaves no stray file."""
    for stale in output.parent.glob(f".{output.stem}{TMP_TAG}*.merge.*"):
        pid = stale.name[len(f".{output.stem}{TMP_TAG}"):].split(".")[0]
        try:
            os.kill(int(pid), 0)
        except (ValueError, ProcessLookupError):
            stale.unlink(missing_ok=True)
        except PermissionError:  # another user's live process
            pass


def merge_pairs(inputs: Sequence[str | os.PathLike], output: str | os.PathLike, *,
                overwrite: bool = False, sort_key: Callable[[dict], object] | None = None,
                header: dict | None = None) -> int:
    """Merges trajectory pairs into ``output`` (.h5 + .json), renumbering ``traj_<i>``.

    All inputs must come from the same env id and env kwargs (else replay could not rebuild
    one env for all of them). Top-level json keys come from the first input, updated with
    ``header``; ``sort_key`` orders the merged episodes (default: input order). The output is
    written under a temp name and renamed at the end. Returns the number of episodes."""
    output = Path(output)
    if not inputs:
        raise DatasetError("nothing to merge: no input files")
    json_path_of(output)
    seen: dict[Path, str] = {}
    for path in inputs:
        real = Path(path).resolve()
        if real in seen:
            raise DatasetError(f"{path} is given twice (also as {seen[real]}): its episodes would be duplicated; "
                               "name each input once")
        seen[real] = str(path)
    if output.resolve() in seen:
        raise DatasetError(f"--out {output} is one of the inputs: merging a file into itself would duplicate its "
                           "episodes; write to a new path")
    if existing_outputs(output) and not overwrite:
        raise DatasetError(f"{output} exists; pass --overwrite to replace it")
    sources = []  # (input path, episode entry)
    first = None
    for path in inputs:
        data = check_pair(path)
        if first is None:
            first = data
        elif _env_signature(data["env_info"]) != _env_signature(first["env_info"]):
            raise DatasetError(f"{path}: env_info differs from {inputs[0]} "
                               f"({_env_signature(data['env_info'])} vs {_env_signature(first['env_info'])}); "
                               "only datasets of the same env and env kwargs can be merged")
        sources.extend((Path(path), ep) for ep in data["episodes"])
    by_seed: dict[object, Path] = {}
    for path, ep in sources:
        seed = ep.get("episode_seed")
        if seed is not None and by_seed.setdefault(seed, path) != path:
            raise DatasetError(f"episode seed {seed} is in both {by_seed[seed]} and {path}: the same demo twice "
                               "(a file copied, a shard merged twice); merge each demo once")
    if sort_key is not None:
        sources.sort(key=lambda s: sort_key(s[1]))
    merged = {k: v for k, v in first.items() if k != "episodes"}
    merged.update(header or {})
    merged["episodes"] = []
    check_writable_dir(output.parent)  # a read-only or full folder: one line naming it, before the copy
    _remove_stale_merges(output)
    size = sum(Path(p).stat().st_size + json_path_of(p).stat().st_size for p in dict.fromkeys(map(str, inputs)))
    check_free_space(output.parent, size + 2**20)  # libhdf5 meeting a full disk may crash the process
    tmp = temp_h5_path(output, ".merge")
    handles: dict[Path, h5py.File] = {}
    try:
        with h5py.File(tmp, "w") as out:
            for new_id, (path, ep) in enumerate(sources):
                if path not in handles and len(handles) >= MAX_OPEN_INPUTS:  # many one-demo files: few open
                    handles.pop(next(iter(handles))).close()
                src = handles.get(path) or handles.setdefault(path, h5py.File(path, "r"))
                src.copy(src[f"traj_{ep['episode_id']}"], out, f"traj_{new_id}")
                merged["episodes"].append({**ep, "episode_id": new_id})
        dump_json(json_path_of(tmp), merged)
        finalize_pair(tmp, output)
    except BaseException:
        remove_pair(tmp)
        raise
    finally:
        for f in handles.values():
            f.close()
    return len(merged["episodes"])
