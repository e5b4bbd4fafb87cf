"""`rsb dataset build`: expert + rendering in shards, identical whatever the number of workers,
resumable after kill -9, one dataset per suite with its card, bad input refused before any write."""
from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import yaml

from rsb_maniskill.cli import main
from rsb_maniskill.export.build import WORK_DIR, BuildConfig, build_datasets
from rsb_maniskill.version import BENCHMARK_VERSION

from lerobot_venv import _lerobot_python, fingerprint, read_data

SUITE = "RSB-Math-4"
STRAY = re.compile(r"\.tmp|\.partial|\.part\d|write-probe")  # what a half-done write is named
SMALL = {"camera_size": (64, 48)}  # the pipeline is the same at 320x240, only slower


def build(out: Path, num_procs: int, shard_size: int = 2, questions: str = "0:4", **kw) -> list[dict]:
    """What RUN's script below builds, in this process (a rerun that is not about the process reuses
    the simulator this process has loaded)."""
    cfg = BuildConfig(suites=[SUITE], out=str(out), questions=questions, shard_size=shard_size, num_procs=num_procs,
                      progress=False, env_kwargs=dict(SMALL), **kw)
    return build_datasets(cfg)


def tree(root: Path) -> dict[str, str]:
    """Every file under ``root``, by its bytes (relative path -> sha256)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def one_proc(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("one")
    summaries = build(out, 1)
    assert summaries[0]["episodes"] == 4 and not summaries[0]["already_built"]
    return out / SUITE


@pytest.fixture(scope="module")
def one_shard(tmp_path_factory) -> Path:
    """The same four questions in one shard of four (``one_proc``: two shards of two)."""
    out = tmp_path_factory.mktemp("one_shard")
    build(out, 1, shard_size=4)
    return out / SUITE


def test_two_workers_build_the_same_dataset(one_proc, tmp_path):
    build(tmp_path, 2)
    assert fingerprint(tmp_path / SUITE) == fingerprint(one_proc)
    # a rerun finds the dataset built with the same settings and does nothing
    again = build(tmp_path, 2)
    assert again[0]["already_built"] and again[1]["rendered_frames"] == 0


def test_shard_size_changes_no_byte(one_proc, one_shard):
    """One shard of the four questions (seed 3 played after seeds 0-2 in one env) and two shards of
    two (each in a new env): the same dataset, every file under its root byte for byte: frames and
    videos, how the frames are filed, the per-episode statistics of the renumbered columns, the
    dataset statistics built from them, the build settings and the card."""
    files = tree(one_shard)
    assert files == tree(one_proc)
    assert len([f for f in files if f.startswith("videos/")]) == 12 and "meta/stats.json" in files
    assert {"README.md", "meta/rsb_build.json", "meta/info.json", "data/chunk-000/file-000.parquet"} <= set(files)
    # the renumbered columns' statistics are of the merged dataset's values, not of a shard's
    data = read_data(one_proc)
    for e in pq.read_table(one_proc / "meta/episodes/chunk-000/file-000.parquet").to_pylist():
        rows = range(e["dataset_from_index"], e["dataset_to_index"])
        assert e["stats/episode_index/min"] == e["stats/episode_index/max"] == [e["episode_index"]]
        assert e["stats/index/min"] == [rows[0]] and e["stats/index/max"] == [rows[-1]]
        assert e["stats/task_index/mean"] == [data["task_index"][rows[0]]]
        assert "rsb/source_episode_id" not in e and "rsb/source_file" not in e  # a build's demos are temporary
    stats = json.loads((one_proc / "meta/stats.json").read_text())
    assert stats["episode_index"]["max"] == [3] and stats["episode_index"]["count"] == [len(data["index"])]


def test_dataset_contents_and_card(one_proc):
    info = json.loads((one_proc / "meta/info.json").read_text())
    data = read_data(one_proc)
    eps = pq.read_table(one_proc / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert info["total_episodes"] == 4 == len(eps) and info["total_frames"] == len(data["index"])
    assert data["index"] == list(range(len(data["index"])))  # renumbered across the two shards
    assert sorted(set(data["episode_index"])) == [0, 1, 2, 3]
    assert [e["rsb/seed"] for e in eps] == [0, 1, 2, 3]  # question q is seed q (Math-4's pool is larger)
    for e in eps:  # the CoT target of a policy that talks, through the merge of the shards
        assert isinstance(e["rsb/options"], list) and all(isinstance(o, str) for o in e["rsb/options"])
        assert e["rsb/correct_option"] == e["rsb/options"]["ABCD".index(e["rsb/correct_letter"])]
        assert f"Option {e['rsb/correct_letter']} is" in e["rsb/rationale"]
    assert len(sorted((one_proc / "data").glob("chunk-000/file-*.parquet"))) == 1  # whole episodes, not shards
    for e in eps:  # each episode's frames point at its own task and its own video
        rows = range(e["dataset_from_index"], e["dataset_to_index"])
        assert {data["episode_index"][r] for r in rows} == {e["episode_index"]}
        assert (one_proc / f"videos/observation.images.cam_high/chunk-000/file-{e['episode_index']:03d}.mp4").is_file()
    card = (one_proc / "README.md").read_text()
    header = yaml.safe_load(card.split("---")[1])
    assert header["license"] == "mit" and header["task_categories"] == ["robotics"] and "LeRobot" in header["tags"]
    assert header["configs"][0]["data_files"] == "data/*/*.parquet"
    # the features, in the hub's form: parquet columns under dataset_info, the mp4 streams beside them
    columns = {f["name"]: f for f in header["dataset_info"]["features"]}
    videos = {f["name"]: f for f in header["video_features"]}
    assert set(columns) | set(videos) == set(info["features"]) and not set(columns) & set(videos)
    for name, ft in info["features"].items():
        if ft["dtype"] == "video":
            assert videos[name]["dtype"] == "video" and videos[name]["shape"] == ft["shape"] == [48, 64, 3]
        elif ft["shape"] == [1]:
            assert columns[name] == {"name": name, "dtype": ft["dtype"]}
        else:
            assert columns[name] == {"name": name, "list": ft["dtype"], "length": ft["shape"][0]}
    schema = pq.read_schema(one_proc / "data/chunk-000/file-000.parquet")
    assert list(columns) == [n for n in schema.names if n in columns] and set(columns) == set(schema.names)
    assert columns["observation.state"] == {"name": "observation.state", "list": "float32", "length": 14}
    from huggingface_hub import DatasetCard  # the hub's client reads the same header

    assert DatasetCard(card).data.to_dict()["dataset_info"]["features"] == header["dataset_info"]["features"]
    assert "it is not on PyPI" in card and "bash scripts/setup.sh" in card and "pip install rsb_maniskill" not in card
    for needle in ("RSB-Math-4, train split", "0:4 of a pool of 500", "rsb dataset build --suites RSB-Math-4",
                   "lerobot-train --dataset.repo_id=", "openpi", '"observation.images.cam_high"'):
        assert needle in card, needle
    built = json.loads((one_proc / "meta/rsb_build.json").read_text())
    assert built["questions"] == "0:4" and built["cameras"] == ["head", "left_wrist", "right_wrist"]
    assert built["benchmark_version"] == BENCHMARK_VERSION and "code_commit" in built
    assert built["skipped_questions"] == []
    assert f"| benchmark version | RSB-MS {BENCHMARK_VERSION} " in card


@pytest.mark.parametrize("skipped, line", [
    ([], "| questions without a demo | 0 (up to 20 seeds were tried per question) |"),
    ([3, 17], "| questions without a demo | 2: the expert failed on all 20 seeds tried for each (questions 3, 17) |"),
])
def test_card_says_why_a_question_has_no_demo(tmp_path, skipped, line):
    from rsb_maniskill.export.card import dataset_card

    (tmp_path / "meta").mkdir()
    (tmp_path / "meta/info.json").write_text(json.dumps({
        "codebase_version": "v3.0", "total_episodes": 2, "total_frames": 9, "fps": 25,
        "features": {"action": {"dtype": "float32", "shape": [14]}}}))
    card = dataset_card(tmp_path, {"env_id": "RSB-Math-4", "split": "train", "questions": "0:4", "pool_size": 500,
                                   "max_attempts": 20, "skipped_questions": skipped, "rsb_version": "0.2.0",
                                   "benchmark_version": BENCHMARK_VERSION, "fps": 25, "cameras": ["head"],
                                   "naming": "rsb"})
    assert line in card and "the expert failed on 20 seeds" not in card


RUN = """
import sys
from rsb_maniskill.export.build import BuildConfig, build_datasets
if __name__ == "__main__":
    build_datasets(BuildConfig(suites=["{suite}"], out=sys.argv[1], questions="{questions}", shard_size=2,
                               num_procs={procs}, progress=False, env_kwargs={{"camera_size": (64, 48)}}))
"""


def run_script(questions: str = "0:4", procs: int = 1) -> str:
    return RUN.format(suite=SUITE, questions=questions, procs=procs)


def wait_for(path: Path, proc: subprocess.Popen, timeout: float = 300) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)


def test_kill_9_then_rerun_resumes_without_duplicates(one_proc, tmp_path):
    script = tmp_path / "run.py"
    script.write_text(run_script())
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, str(script), str(out)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    first = out / WORK_DIR / SUITE / "shards" / "shard-00000" / "meta" / "rsb_shard.json"
    deadline = time.monotonic() + 300
    while not first.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)  # mid-way through the second shard
    proc.wait()
    assert first.exists() and not (out / SUITE).exists()
    assert not (out / WORK_DIR / SUITE / "shards" / "shard-00001").exists()
    assert not build(out, 1)[0]["already_built"]  # the same build, rerun (here: the kill was the process's)
    assert fingerprint(out / SUITE) == fingerprint(one_proc)
    assert not list((out / WORK_DIR / SUITE / "tmp").glob("*"))  # the killed run's partial shard is gone
    assert [p.name for p in (out / SUITE).rglob("*") if STRAY.search(p.name)] == []  # nor a half-done write


def test_sigint_stops_keeping_finished_shards(tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-c", textwrap.dedent(run_script()), str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = out / WORK_DIR / SUITE / "shards" / "shard-00000" / "meta" / "rsb_shard.json"
    deadline = time.monotonic() + 300
    while not first.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode != 0 and "rerun the same command to continue" in err
    assert first.exists() and not (out / SUITE).exists()


@pytest.mark.parametrize("procs", [1, 2])
def test_sigterm_stops_keeping_finished_shards_and_rerun_completes(procs, tmp_path):
    """SIGTERM (what a scheduler or `timeout` sends) mid-build, in this process or to a pool's parent:
    the process exits, finished shards stay, nothing half-written is left, and a rerun completes
    with every question once."""
    script = tmp_path / "run.py"
    script.write_text(run_script("0:6", procs))  # 3 shards: one worker always has one left to do
    out = tmp_path / "out"
    work = out / WORK_DIR / SUITE
    proc = subprocess.Popen([sys.executable, str(script), str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    wait_for(work / "shards" / "shard-00000" / "meta" / "rsb_shard.json", proc)
    assert proc.poll() is None, proc.communicate()[1][-2000:]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode != 0 and "rerun the same command to continue" in err, err[-2000:]
    assert not (out / SUITE).exists()  # never a merged dataset of part of the shards
    kept = sorted(d.name for d in (work / "shards").iterdir())
    assert "shard-00000" in kept and len(kept) < 3
    assert all((work / "shards" / d / "meta" / "rsb_shard.json").is_file() for d in kept)  # whole or absent
    assert not list((work / "tmp").glob("*"))  # the shard in flight was dropped, not left half-written
    inode = {d: (work / "shards" / d / "meta" / "rsb_shard.json").stat().st_ino for d in kept}
    build(out, procs, questions="0:6")  # the script's build, rerun in this process (its workers: processes)
    data = read_data(out / SUITE)
    eps = pq.read_table(out / SUITE / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [e["rsb/seed"] for e in eps] == [0, 1, 2, 3, 4, 5]  # each question once, in order
    assert sorted(set(data["episode_index"])) == list(range(6)) and data["index"] == list(range(len(data["index"])))
    assert json.loads((out / SUITE / "meta/info.json").read_text())["total_episodes"] == 6
    # the finished shards were reused, not made again (a remade shard is a new directory)
    assert all((work / "shards" / d / "meta" / "rsb_shard.json").stat().st_ino == inode[d] for d in kept)


@pytest.mark.parametrize("argv, message", [
    (["--suites", "RSB-Nope-4"], "unknown suite 'RSB-Nope-4'"),
    (["--suites", "RSB-Math-4", "--questions", "490:600"], "the pool has questions 0..499"),
    (["--suites", "RSB-Math-4", "--fps", "7"], "--fps must divide"),
    (["--suites", "RSB-Math-4", "--cameras", "head,top"], "unknown camera(s) top"),
])
def test_bad_input_is_one_line_and_writes_nothing(argv, message, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["dataset", "build", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    errors = [line for line in err.splitlines() if ": error: " in line]  # beside it, at most the worker count
    assert len(errors) == 1 and message in errors[0] and "Traceback" not in err
    assert not out.exists()


def test_other_settings_are_refused_and_nothing_is_lost(one_proc, tmp_path, capsys):
    before = fingerprint(one_proc)
    out = str(one_proc.parent)
    assert main(["dataset", "build", "--suites", SUITE, "--questions", "0:4", "--fps", "5", "--out", out]) == 2
    err = capsys.readouterr().err
    assert "holds a build of other settings" in err and "fps=25 there, 5 now" in err
    assert fingerprint(one_proc) == before


def test_missing_question_data_offline(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("RSB_DATA_DIR", str(tmp_path / "empty"))
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    (tmp_path / "empty").mkdir()
    assert main(["dataset", "build", "--suites", "RSB-HardMath-4", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "rsb data download" in err and not (tmp_path / "out").exists()


@pytest.fixture(scope="module")
def lerobot_reads(one_proc, one_shard) -> dict[str, dict]:
    """What LeRobot's own loader (in its venv) reads of each dataset, both in one process (one LeRobot
    import): dataset name -> the figures below."""
    py = _lerobot_python()
    code = textwrap.dedent(f"""
        import json
        import pyarrow.parquet as pq, yaml
        from datasets import Features
        from lerobot.datasets.lerobot_dataset import LeRobotDataset
        got = {{}}
        for name, root in {{"one_proc": {str(one_proc)!r}, "one_shard": {str(one_shard)!r}}}.items():
            ds = LeRobotDataset("local/rsb-math-4", root=root)
            last = ds[len(ds) - 1]
            # the card's dataset_info.features, read by `datasets` (what the hub runs), is the data files' schema
            header = yaml.safe_load(open(root + "/README.md").read().split("---")[1])
            card = Features._from_yaml_list(header["dataset_info"]["features"])
            files = Features.from_arrow_schema(pq.read_schema(root + "/data/chunk-000/file-000.parquet"))
            got[name] = dict(frames=len(ds), episodes=ds.num_episodes, last_ep=int(last["episode_index"]),
                             last_index=int(last["index"]), shape=list(last["observation.images.cam_high"].shape),
                             task=last["task"], card_features=card == files)
        print(json.dumps(got))
    """)
    res = subprocess.run([str(py), "-c", code], capture_output=True, text=True, timeout=600,
                         env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.parametrize("dataset", ["one_proc", "one_shard"])
def test_lerobot_loads_the_merged_dataset(dataset, lerobot_reads, request):
    one_proc = request.getfixturevalue(dataset)  # two shards merged, or one
    got = lerobot_reads[dataset]
    data = read_data(one_proc)
    assert got["frames"] == len(data["index"]) and got["episodes"] == 4 and got["last_ep"] == 3
    assert got["last_index"] == len(data["index"]) - 1 and got["shape"] == [3, 48, 64]
    eps = pq.read_table(one_proc / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert got["task"] == eps[3]["tasks"][0]
    assert got["card_features"]


def test_workers_get_one_task_each_whatever_the_suites():
    """--num-procs N starts N workers: shards of several suites are dealt to them, not one per suite."""
    from rsb_maniskill.export.build import _run
    from rsb_maniskill.export.shards import SuiteShard
    from rsb_maniskill.parallel.pool import RunOutcome

    class Recorder:
        def run(self, target, tasks, on_message):
            self.tasks = tasks
            return RunOutcome([])

    items = [(Path(f"/w/{s}"), {"env_id": s}, k, SuiteShard(s, 2 * k, 2 * k + 2))
             for s in ("RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4") for k in range(3)]
    rec = Recorder()
    errors, interrupted, _ = _run(items, 2, rec, progress=False)
    assert errors == [] and not interrupted and len(rec.tasks) == 2
    dealt = [item for t in rec.tasks for item in t["items"]]
    assert sorted((w, k) for w, _, k, _ in dealt) == sorted((str(w), k) for w, _, k, _ in items)
    assert all(len({w for w, *_ in t["items"]}) == 3 for t in rec.tasks)  # each worker spans the suites


def test_workers_share_lavapipe_threads_unless_told(monkeypatch):
    """Each local worker caps lavapipe's raster threads to its share of the CPUs (software rendering
    only; a user's LP_NUM_THREADS wins)."""
    from rsb_maniskill.parallel import threads
    from rsb_maniskill.sim import render

    monkeypatch.delenv("LP_NUM_THREADS", raising=False)
    monkeypatch.setattr(threads, "usable_cpus", lambda: 6)  # the CPUs --num-procs auto counts
    assert render.lavapipe_share(2) == 3 and render.lavapipe_share(4) == 1 and render.lavapipe_share(24) == 1
    monkeypatch.setattr(render, "software_rendering", lambda: False)
    assert not render.limit_lavapipe_threads(1) and "LP_NUM_THREADS" not in os.environ  # a GPU driver: left alone
    monkeypatch.setattr(render, "software_rendering", lambda: True)
    assert not render.limit_lavapipe_threads(None) and "LP_NUM_THREADS" not in os.environ  # one worker: all threads
    assert render.limit_lavapipe_threads(1) and os.environ["LP_NUM_THREADS"] == "1"
    monkeypatch.setenv("LP_NUM_THREADS", "3")
    assert not render.limit_lavapipe_threads(1) and os.environ["LP_NUM_THREADS"] == "3"
    monkeypatch.undo()
    monkeypatch.setenv("VK_ICD_FILENAMES", "/usr/share/vulkan/icd.d/lvp_icd.x86_64.json")
    assert render.software_rendering()
    monkeypatch.setenv("VK_ICD_FILENAMES", "/usr/share/vulkan/icd.d/nvidia_icd.json")
    assert not render.software_rendering()
