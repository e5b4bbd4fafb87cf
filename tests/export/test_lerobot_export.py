"""`rsb export lerobot`: the v3.0 layout, frames equal to what the env renders, bad input, and
LeRobot's own loader on the result (in a separate virtual environment: its pins clash with ours)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.export.build import export_lerobot
from rsb_maniskill.export.lerobot import ExportError
from rsb_maniskill.motionplan.generate import GenerateConfig, generate
from rsb_maniskill.version import BENCHMARK_VERSION

from lerobot_venv import _lerobot_python, fingerprint, read_data


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("demos")
    summary = generate(GenerateConfig(env_id="RSB-Math-4", out=str(out), num=2, progress=False))
    assert summary.completed == 2
    return summary.path


@pytest.fixture(scope="module")
def exported(demos, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("lerobot") / "rsb-math-4"
    export_lerobot([demos], out, progress=False)
    return out


@pytest.fixture(scope="module")
def robotwin(demos, tmp_path_factory) -> Path:
    """`rsb export lerobot --naming robotwin` (5 fps: fewer frames to render, the same keys), rendered in
    this process (its simulator is loaded; the worker processes' export is the parallel test's)."""
    out = tmp_path_factory.mktemp("robotwin") / "rsb-math-4-robotwin"
    assert main(["export", "lerobot", str(demos), "--out", str(out), "--naming", "robotwin", "--fps", "5",
                 "--num-procs", "1"]) == 0
    return out


@pytest.fixture(scope="module")
def head_frames(demos) -> list[np.ndarray]:
    """The head camera at every step of each demo, rendered here from its recorded states (once: the
    video and LeRobot checks below compare frames of it)."""
    from rsb_maniskill.export.render_demos import render_episodes

    return [ep.frames["head"] for ep in render_episodes(demos, ("head",), 1)]


def test_demos_rendered_together_on_a_vector_env_give_the_same_frames(demos):
    """`render_episodes(num_envs=2)` (both demos set and rendered together, as on a GPU machine) gives
    the episodes, states and frames of one env rendering them in turn."""
    from rsb_maniskill.export.render_demos import close_render_env, render_episodes

    try:
        one = list(render_episodes(demos, ("head", "left_wrist"), 25, num_envs=1))
        two = list(render_episodes(demos, ("head", "left_wrist"), 25, num_envs=2))
    finally:
        close_render_env()
    assert len(one) == len(two) == 2
    for a, b in zip(one, two):
        assert a.meta == b.meta and a.task == b.task
        np.testing.assert_array_equal(a.state, b.state)
        np.testing.assert_array_equal(a.action, b.action)
        for c in ("head", "left_wrist"):
            assert a.frames[c].shape == b.frames[c].shape and a.frames[c].any()
            np.testing.assert_array_equal(a.frames[c], b.frames[c])


def test_v3_layout_and_contents(demos, exported):
    src = json.loads(demos.with_suffix(".json").read_text())
    info = json.loads((exported / "meta/info.json").read_text())
    n_frames = sum(e["elapsed_steps"] for e in src["episodes"])
    assert info["codebase_version"] == "v3.0" and info["fps"] == 25 and info["robot_type"] == "aloha"
    assert info["total_episodes"] == 2 and info["total_frames"] == n_frames
    keys = ["observation.images.cam_high", "observation.images.cam_left_wrist", "observation.images.cam_right_wrist"]
    assert all(info["features"][k]["dtype"] == "video" for k in keys)
    assert info["features"]["observation.state"]["shape"] == [14]
    data = read_data(exported)
    assert len(data["index"]) == n_frames and data["index"] == list(range(n_frames))
    tasks = pq.read_table(exported / "meta/tasks.parquet").to_pydict()
    instructions = [e["instruction"] for e in src["episodes"]]
    assert sorted(tasks["task"]) == sorted(set(instructions))
    eps = pq.read_table(exported / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    for ep, s in zip(eps, src["episodes"]):
        assert ep["tasks"] == [s["instruction"]] and ep["length"] == s["elapsed_steps"]
        assert ep["rsb/correct_letter"] == s["correct_letter"] and ep["rsb/seed"] == s["episode_seed"]
        assert ep["rsb/suite_id"] == "RSB-Math-4" and ep["rsb/split"] == "train"
        # a CoT target: the rationale, ending on the correct option, and that option's text
        assert ep["rsb/options"] == s["options"] and all(isinstance(o, str) for o in ep["rsb/options"])
        assert ep["rsb/rationale"] == s["rationale"] and ep["rsb/correct_option"] in ep["rsb/options"]
        assert ep["rsb/correct_option"] == ep["rsb/options"]["ABCD".index(s["correct_letter"])]
        # every frame of the episode points at its task
        rows = range(ep["dataset_from_index"], ep["dataset_to_index"])
        assert {data["task_index"][r] for r in rows} == {tasks["task_index"][tasks["task"].index(s["instruction"])]}
    # Aloha layout: action = to_aloha14 of the recorded pd_joint_pos action, grippers in [0, 1]
    import h5py

    from rsb_maniskill.agents.aloha import to_aloha14
    with h5py.File(demos) as f:
        np.testing.assert_allclose(np.asarray(data["action"][:5]), to_aloha14(f["traj_0/actions"][:5]), atol=1e-6)
    state = np.asarray(data["observation.state"])
    assert state[:, [6, 13]].min() >= 0 and state[:, [6, 13]].max() <= 1
    stats = json.loads((exported / "meta/stats.json").read_text())
    assert stats["action"]["count"] == [n_frames] and np.asarray(stats[keys[0]]["mean"]).shape == (3, 1, 1)


def test_video_frames_are_the_rendered_frames(demos, exported, head_frames):
    cap = cv2.VideoCapture(str(exported / "videos/observation.images.cam_high/chunk-000/file-001.mp4"))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame[..., ::-1])
    src = json.loads(demos.with_suffix(".json").read_text())
    assert len(frames) == src["episodes"][1]["elapsed_steps"]
    t = 40
    err = np.abs(frames[t].astype(int) - head_frames[1][t].astype(int)).mean()
    assert err < 6, err  # MPEG-4 is lossy; a wrong frame or camera differs by tens


def test_fps_subsamples_and_bad_input_keeps_existing_files(demos, tmp_path):
    out = tmp_path / "five"
    summary = export_lerobot([demos], out, fps=5, cameras=["head"], progress=False)
    src = json.loads(demos.with_suffix(".json").read_text())
    assert summary["frames"] == sum(-(-e["elapsed_steps"] // 5) for e in src["episodes"])
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    for kwargs, msg in ((dict(fps=7, overwrite=True), "must divide"), (dict(cameras=["top"]), "unknown camera"),
                        ({}, "not empty")):
        with pytest.raises(ExportError, match=msg):
            export_lerobot([demos], out, progress=False, **kwargs)
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before  # nothing written over
    assert not list(tmp_path.glob(".five.tmp*"))
    with pytest.raises(ExportError, match="not a trajectory file pair"):
        export_lerobot([tmp_path / "missing.h5"], tmp_path / "x", progress=False)
    assert main(["export", "lerobot", str(tmp_path / "missing.h5"), "--out", str(tmp_path / "y")]) == 2


def test_the_dataset_names_its_benchmark_version_and_takes_one(demos, exported, tmp_path):
    src = json.loads(demos.with_suffix(".json").read_text())
    assert src["rsb"]["benchmark_version"] == BENCHMARK_VERSION and "code_commit" in src["rsb"]
    meta = json.loads((exported / "meta/rsb_export.json").read_text())
    assert meta["benchmark_version"] == BENCHMARK_VERSION and meta["rsb_version"] and meta["naming"] == "rsb"
    old = tmp_path / "old.h5"  # the same demos, as written before benchmark versions
    shutil.copy(demos, old)
    del src["rsb"]["benchmark_version"]
    old.with_suffix(".json").write_text(json.dumps(src))
    with pytest.raises(ExportError, match=f"of RSB-MS {BENCHMARK_VERSION}, .* of unversioned: one dataset"):
        export_lerobot([demos, old], tmp_path / "mixed", progress=False)
    assert not (tmp_path / "mixed").exists()


@pytest.fixture(scope="module")
def lerobot_reads(exported, robotwin, head_frames, tmp_path_factory) -> dict[str, dict]:
    """What LeRobot's own loader (in its venv) reads of the default and the RoboTwin-named export, both
    in one process (one LeRobot import)."""
    py = _lerobot_python()
    frame = tmp_path_factory.mktemp("frame") / "frame.npy"
    np.save(frame, head_frames[0][30])
    code = textwrap.dedent(f"""
        import json, numpy as np
        from lerobot.datasets.lerobot_dataset import LeRobotDataset
        ds = LeRobotDataset("local/rsb-math-4", root={str(exported)!r})
        item = ds[30]  # episode 0, frame 30
        img = (item["observation.images.cam_high"].numpy().transpose(1, 2, 0) * 255).round()
        eps = ds.meta.episodes
        rsb = dict(frames=len(ds), episodes=ds.num_episodes, task=item["task"],
                   tasks=sorted(ds.meta.tasks.index), letter=eps[0]["rsb/correct_letter"],
                   options=eps[0]["rsb/options"], rationale=eps[0]["rsb/rationale"],
                   correct_option=eps[0]["rsb/correct_option"],
                   err=float(np.abs(img - np.load({str(frame)!r})).mean()), keys=sorted(item))
        ds = LeRobotDataset("local/rsb-math-4-robotwin", root={str(robotwin)!r})
        item = ds[3]
        robotwin = dict(frames=len(ds), cameras=sorted(ds.meta.camera_keys),
                        shape=list(item["observation.images.head_camera"].shape))
        print(json.dumps(dict(rsb=rsb, robotwin=robotwin)))
    """)
    res = subprocess.run([str(py), "-c", code], capture_output=True, text=True, timeout=600,
                         env={**os.environ, "HF_HUB_OFFLINE": "1", "PYTHONPATH": ""})
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_lerobot_loads_the_export(demos, lerobot_reads):
    got = lerobot_reads["rsb"]
    src = json.loads(demos.with_suffix(".json").read_text())
    assert got["frames"] == sum(e["elapsed_steps"] for e in src["episodes"]) and got["episodes"] == 2
    assert got["task"] == src["episodes"][0]["instruction"]
    assert got["tasks"] == sorted({e["instruction"] for e in src["episodes"]})
    assert got["letter"] == src["episodes"][0]["correct_letter"]
    assert got["options"] == src["episodes"][0]["options"]  # a list of strings, as LeRobot reads it
    assert got["rationale"] == src["episodes"][0]["rationale"] and got["correct_option"] in got["options"]
    assert got["err"] < 6, got["err"]
    assert {"observation.state", "action", "observation.images.cam_left_wrist", "task_index"} <= set(got["keys"])


def test_parallel_export_is_the_same_dataset(demos, robotwin, tmp_path):
    """Two worker processes, one shard each, merged: the same files as the export in this process (the
    RoboTwin one at 5 fps: the workers render a fifth of the frames; the merge is the same)."""
    export_lerobot([demos], tmp_path / "par", fps=5, naming="robotwin", progress=False, num_procs=2, shard_size=1)
    assert fingerprint(tmp_path / "par") == fingerprint(robotwin)
    assert not (tmp_path / ".par.work").exists()  # the shards go once merged


def test_robotwin_naming_writes_robotwin_camera_keys(demos, robotwin):
    from rsb_maniskill.export.naming import CAMERA_KEYS

    info = json.loads((robotwin / "meta/info.json").read_text())
    cams = {k for k, ft in info["features"].items() if ft["dtype"] == "video"}
    assert cams == {"observation.images.head_camera", "observation.images.left_camera",
                    "observation.images.right_camera"}
    assert cams == {f"observation.images.{k}" for k in CAMERA_KEYS["robotwin"].values()}
    assert all(info["features"][k]["shape"] == [240, 320, 3] for k in cams)
    # state and action keep the Aloha-14 layout, as LeRobot's RoboTwin env gives agent_pos and takes actions
    assert info["features"]["observation.state"]["shape"] == info["features"]["action"]["shape"] == [14]
    for k in cams:
        assert len(list((robotwin / "videos" / k).glob("chunk-000/file-*.mp4"))) == 2
    assert not list(robotwin.rglob("*cam_high*"))
    src = json.loads(demos.with_suffix(".json").read_text())
    assert info["total_frames"] == sum(-(-e["elapsed_steps"] // 5) for e in src["episodes"]) and info["fps"] == 5


@pytest.mark.slow
def test_lerobot_loads_the_robotwin_export(robotwin, lerobot_reads):
    got = lerobot_reads["robotwin"]
    assert got["cameras"] == ["observation.images.head_camera", "observation.images.left_camera",
                              "observation.images.right_camera"]
    assert got["shape"] == [3, 240, 320]
    assert got["frames"] == json.loads((robotwin / "meta/info.json").read_text())["total_frames"]
