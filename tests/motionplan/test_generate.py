"""`rsb generate` / `rsb merge` / `rsb replay`: demonstration datasets from the scripted expert.

Core tests (not slow) use the real motion-planning expert on RSB-Math-4 (no external data) and
take about a minute together; the slow ones add multi-process runs, control-mode and
observation conversion, shards, videos and the everyday-objects suites.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.motionplan import ExpertResult, ScriptedExpert
from rsb_maniskill.motionplan.config import output_path
from rsb_maniskill.motionplan.dataset import annotate_episodes, check_pair
from rsb_maniskill.motionplan.generate import GenerateConfig, GenerateError, generate
from rsb_maniskill.motionplan.replay import carry_metadata
from rsb_maniskill.motionplan.shards import WorkPlan, plan_work

ENV_ID = "RSB-Math-4"
REPO = Path(__file__).resolve().parents[2]
TESTS = Path(__file__).resolve().parent


class FlakyExpert:
    """Real expert, except on odd seeds below 500 (RSB-Math-4's pool size): there a stand-in
    idles 3 steps and reports a failure, so the discard / retry paths run deterministically."""

    def __init__(self, env):
        self.env = env

    def run(self):
        base = self.env.unwrapped
        seed = int(base._episode_seed[0])
        if seed % 2 == 0 or seed >= 500:
            return ScriptedExpert(self.env).run()
        hold = base.agent.rest_action()
        for _ in range(3):
            self.env.step(hold)
        return ExpertResult(False, "stand_in_failure", 3, 0.0, 0.0, "left")


class OverclaimingExpert:
    """Claims success after three idle steps: the env's own verdict must overrule it."""

    def __init__(self, env):
        self.env = env

    def run(self):
        hold = self.env.unwrapped.agent.rest_action()
        for _ in range(3):
            self.env.step(hold)
        return ExpertResult(True, "", 3, 0.0, 0.0, "left")


def _cfg(tmp_path, **kw) -> GenerateConfig:
    kw.setdefault("num", 2)
    return GenerateConfig(env_id=ENV_ID, out=str(tmp_path / "demos"), progress=False, **kw)


def _env(extra: dict | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), str(REPO), os.environ.get("PYTHONPATH", "")]))
    env.update(extra or {})
    return env


def _rsb(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", *args], capture_output=True, text=True,
                          env=_env(), cwd=REPO, timeout=kw.get("timeout", 300))


def _all_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*")) if root.exists() else []


def _check_dataset(h5_path: Path) -> dict:
    """Asserts the pair is a valid ManiSkill trajectory file; returns its json."""
    data = json.loads(h5_path.with_suffix(".json").read_text())
    with h5py.File(h5_path, "r") as f:
        assert sorted(f.keys()) == sorted(f"traj_{i}" for i in range(len(data["episodes"])))
        for ep in data["episodes"]:
            g = f[f"traj_{ep['episode_id']}"]
            actions = g["actions"][:]
            assert actions.ndim == 2 and actions.shape[1] == 14
            assert actions.shape[0] == ep["elapsed_steps"]
            assert "env_states" in g and "actors" in g["env_states"] and "articulations" in g["env_states"]
            assert g["env_states/task"].shape[0] == actions.shape[0] + 1
            assert bool(g["success"][-1])
    return data


def _arrays(group: h5py.Group) -> dict[str, np.ndarray]:
    """Every dataset under an h5 group (an episode: actions, env states, observations, ...) by path."""
    out: dict[str, np.ndarray] = {}
    group.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three demos from seeds 0.. with the real expert (shared by the checks below). Their cameras are
    64x48 (env kwargs the file records, so every replay to rgb below renders that: the same code as
    at 320x240, a twentieth of the pixels)."""
    tmp = tmp_path_factory.mktemp("gen")
    summary = generate(_cfg(tmp, num=3, env_kwargs={"camera_size": (64, 48)}))
    assert summary.path is not None and summary.completed == 3, summary
    return summary


# ---------------------------------------------------------------------------- pure logic
def _seeds(plan: WorkPlan, stop: int) -> range:
    return range(plan.first_seed, stop, plan.stride)


@pytest.mark.parametrize("num, shards, procs", [(10, 1, 1), (10, 3, 2), (7, 4, 3), (5, 2, 4)])
def test_seed_shards_partition_seed_space(tmp_path, num, shards, procs):
    owner = {}
    total = 0
    for i in range(shards):
        plans = plan_work(_cfg(tmp_path, num=num, shard=(i, shards), num_procs=procs, seed_start=100), 500)
        assert plans == plan_work(_cfg(tmp_path, num=num, shard=(i, shards), num_procs=procs, seed_start=100), 500)
        total += sum(p.quota for p in plans)
        for p in plans:
            for s in _seeds(p, 400):  # far enough to cover many retries
                assert s not in owner, f"seed {s} in two workers"
                assert (s - 100) % shards == i
                owner[s] = (i, p.worker)
    assert total == num
    assert set(owner) == set(range(100, 400))  # every seed has exactly one owner


def test_question_shards_partition_questions(tmp_path):
    seen = []
    for i in range(3):
        for p in plan_work(_cfg(tmp_path, num=None, questions="all", shard=(i, 3), num_procs=2), 50):
            assert all(q % 3 == i for q in p.questions)
            seen += p.questions
    assert sorted(seen) == list(range(50))
    plans = plan_work(_cfg(tmp_path, num=None, questions="10:20", num_procs=1), 50)
    assert plans[0].questions == list(range(10, 20))
    assert plan_work(_cfg(tmp_path, num=4, questions="all"), 50)[0].questions == [0, 1, 2, 3]


def test_output_name_follows_maniskill_layout(tmp_path):
    path = output_path(_cfg(tmp_path, shard=(2, 5)))
    assert path.relative_to(tmp_path / "demos").as_posix() == \
        f"{ENV_ID}/motionplanning/train-shard2of5.state.pd_joint_pos.physx_cpu.h5"


def test_unknown_suite_and_unwritable_dir_leave_no_files(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["generate", "RSB-Nope-4", "-n", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "unknown suite 'RSB-Nope-4'" in err and "RSB-Math-4" in err
    assert not out.exists()
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    assert main(["generate", ENV_ID, "-n", "2", "--out", str(blocker / "demos")]) == 2
    assert "cannot write to output directory" in capsys.readouterr().err
    assert _all_files(tmp_path) == [blocker]
    with pytest.raises(GenerateError, match="split"):
        generate(_cfg(tmp_path, split="validation"))
    with pytest.raises(GenerateError, match="--questions"):
        generate(_cfg(tmp_path, questions="5:2"))
    assert _all_files(tmp_path) == [blocker]


def _tiny_pair(path: Path, n: int) -> Path:
    with h5py.File(path, "w") as f:
        for i in range(n):
            f.create_dataset(f"traj_{i}/actions", data=np.zeros((2, 14), dtype=np.float32))
    path.with_suffix(".json").write_text(json.dumps({"env_info": {"env_id": ENV_ID}, "episodes": [
        {"episode_id": i, "episode_seed": i} for i in range(n)]}))
    return path


def test_a_replaced_pair_never_shows_counts_that_disagree(tmp_path, monkeypatch):
    """Between the renames of a new pair onto an old one a reader sees the old pair, or the new json
    with no h5 yet: never the new json (3 episodes) beside the old h5 (2 groups)."""
    from rsb_maniskill.motionplan import dataset

    final = _tiny_pair(tmp_path / "final.h5", 2)
    tmp = _tiny_pair(tmp_path / ".final.tmp1.h5", 3)
    seen = []
    real_replace = os.replace

    def replace(src, dst):
        real_replace(src, dst)
        try:
            seen.append(len(check_pair(final)["episodes"]))
        except dataset.DatasetError as err:
            seen.append(str(err).split(": ", 1)[1][:9])  # "need both"
    monkeypatch.setattr(dataset.os, "replace", replace)
    dataset.finalize_pair(tmp, final)
    assert seen == ["need both", 3]


def test_annotate_episodes_joins_by_seed_after_the_pair_is_written(tmp_path):
    """The public path for RSB metadata: a rewrite of the finished json, matched by episode_seed."""
    h5 = tmp_path / "part.h5"
    with h5py.File(h5, "w") as f:
        for i in range(3):
            f.create_group(f"traj_{i}")
    episodes = [dict(episode_id=i, episode_seed=s, elapsed_steps=10 + i) for i, s in enumerate((4, 7, 9))]
    h5.with_suffix(".json").write_text(json.dumps(dict(env_info={"env_id": ENV_ID}, episodes=episodes)))
    assert annotate_episodes(h5, {7: {"instruction": "pick B", "question_index": 7}, 5: {"instruction": "x"}}) == 1
    data = check_pair(h5)
    assert data["episodes"][1] == dict(episode_id=1, episode_seed=7, elapsed_steps=11, instruction="pick B",
                                       question_index=7)
    assert data["episodes"][0] == episodes[0] and data["episodes"][2] == episodes[2]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["part.h5", "part.json"]  # no temp file left


# ---------------------------------------------------------------------------- generation
def test_the_envs_verdict_overrules_the_expert(tmp_path):
    summary = generate(_cfg(tmp_path, num=1, max_attempts=2, expert="test_generate:OverclaimingExpert"))
    assert summary.path is None and summary.completed == 0
    assert [(f["seed"], f["reason"]) for f in summary.failures] == [(0, "env_not_successful"),
                                                                     (1, "env_not_successful")]
    assert "failed on 2 seeds in a row" in summary.errors[0] and summary.exit_code == 1
    assert _all_files(tmp_path) == []  # nothing kept: no file, no directory



def test_generated_dataset_is_valid_and_self_describing(dataset):
    data = _check_dataset(dataset.path)
    env_info = data["env_info"]
    assert env_info["env_id"] == f"rsb_maniskill:{ENV_ID}"  # gymnasium imports the pack to find it
    assert env_info["env_kwargs"]["split"] == "train"
    assert env_info["env_kwargs"]["control_mode"] == "pd_joint_pos"
    assert env_info["env_kwargs"]["obs_mode"] == "state" and env_info["env_kwargs"]["camera_size"] == [64, 48]
    assert data["source_type"] == "motionplanning"
    assert [ep["episode_seed"] for ep in data["episodes"]] == sorted(ep["episode_seed"] for ep in data["episodes"])
    for ep in data["episodes"]:
        assert ep["success"] is True and ep["control_mode"] == "pd_joint_pos"
        assert ep["reset_kwargs"]["seed"] == ep["episode_seed"]
        for key in ("instruction", "question_id", "options", "correct_letter", "block_of_option", "rationale"):
            assert key in ep, key
        assert ep["correct_letter"] in ep["letters"]
        assert ep["question_index"] == ep["episode_seed"] % data["rsb"]["pool_size"]
        assert ep["expert"]["steps"] == ep["elapsed_steps"]
    rsb = data["rsb"]
    assert rsb["requested"] == rsb["completed"] == 3 and rsb["complete"] and rsb["interrupted"] is None
    assert [p.name for p in dataset.path.parent.iterdir() if p.name.startswith(".")] == []


def test_failed_episodes_are_discarded_and_logged(tmp_path):
    summary = generate(_cfg(tmp_path, num=2, expert="test_generate:FlakyExpert"))
    data = _check_dataset(summary.path)
    assert [ep["episode_seed"] for ep in data["episodes"]] == [0, 2]
    assert data["rsb"]["failures"] == [dict(seed=1, question_index=1, reason="stand_in_failure", steps=3)]


def test_questions_mode_retries_seed_plus_pool_size(tmp_path):
    # question 1 fails on seed 1 (odd), then succeeds with seed 1 + 500 (same question).
    summary = generate(_cfg(tmp_path, num=None, questions="0:3", expert="test_generate:FlakyExpert"))
    data = _check_dataset(summary.path)
    assert [(ep["question_index"], ep["episode_seed"]) for ep in data["episodes"]] == [(0, 0), (1, 501), (2, 2)]
    assert [ep["question_id"] for ep in data["episodes"]] == [0, 1, 2]
    assert [f["seed"] for f in data["rsb"]["failures"]] == [1]
    assert data["rsb"]["skipped_questions"] == []
    # with one attempt per question, question 1 gets no demo and is listed as skipped
    summary = generate(_cfg(tmp_path / "one", num=None, questions="0:3", max_attempts=1,
                            expert="test_generate:FlakyExpert"))
    data = _check_dataset(summary.path)
    assert [ep["question_index"] for ep in data["episodes"]] == [0, 2]
    assert data["rsb"]["skipped_questions"] == [1] and summary.exit_code == 0


def test_existing_output_needs_overwrite(tmp_path, dataset):
    cfg = _cfg(tmp_path, num=1)
    first = generate(cfg)
    before = first.path.read_bytes()
    again = generate(cfg)  # the same request again: done already, nothing run, nothing written
    assert again.already and again.completed == 1 and again.exit_code == 0 and first.path.read_bytes() == before
    cfg.seed_start = 5  # another request onto the same file
    with pytest.raises(GenerateError, match="--overwrite"):
        generate(cfg)
    assert first.path.read_bytes() == before
    cfg.overwrite = True
    second = generate(cfg)
    data = _check_dataset(second.path)
    assert [ep["episode_seed"] for ep in data["episodes"]] == [5]
    names = sorted(p.name for p in second.path.parent.iterdir())
    assert names == [second.path.name, second.path.with_suffix(".json").name]


def _sigterm_after_first_episode(tmp_path: Path, procs: int) -> tuple[int, Path, str]:
    out = tmp_path / "demos"
    cmd = [sys.executable, "-m", "rsb_maniskill.cli", "generate", ENV_ID, "-n", "200", "--out", str(out),
           "--num-procs", str(procs), "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                            cwd=REPO)
    directory = out / ENV_ID / "motionplanning"
    deadline = time.monotonic() + 240
    resume = directory / ".train.state.pd_joint_pos.physx_cpu.partial"
    while time.monotonic() < deadline and proc.poll() is None:
        parts = list(resume.glob("demo*.h5")) if resume.exists() else []
        if parts:  # each kept demo is saved whole as it ends
            break
        time.sleep(0.2)
    assert proc.poll() is None, proc.communicate()
    assert parts, "no episode finished in time"
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=180)
    return proc.returncode, directory / "train.state.pd_joint_pos.physx_cpu.h5", stdout + stderr


def _check_kept(path: Path, log: str) -> list[Path]:
    """After a signal: no output file that looks finished; each finished demo kept whole in the
    resume folder, and the run says where and how to continue. Returns the kept demos."""
    assert not path.exists() and not path.with_suffix(".json").exists()
    resume = path.parent / f".{path.stem}.partial"
    demos = sorted(resume.glob("demo*.h5"))
    assert 1 <= len(demos) < 200
    for demo in demos:
        assert len(_check_dataset(demo)["episodes"]) == 1
    assert sorted(p.name for p in resume.iterdir()) == sorted(
        ["lock", "settings.json", *(d.name for d in demos), *(d.with_suffix(".json").name for d in demos)])
    assert f"kept the {len(demos)} finished demos of 200 requested in {resume}" in log
    assert "rerun the same command to continue" in log
    return demos


def test_sigterm_keeps_the_finished_demos_for_the_same_command(tmp_path):
    rc, path, log = _sigterm_after_first_episode(tmp_path, procs=1)
    assert rc == 128 + signal.SIGTERM, log
    _check_kept(path, log)


def test_replay_actions_reproduce_success(dataset, tmp_path):
    src = tmp_path / "copy.h5"  # replay writes <stem>.<obs>.<control>.<backend>.h5 next to it
    src.write_bytes(dataset.path.read_bytes())
    src.with_suffix(".json").write_bytes(dataset.path.with_suffix(".json").read_bytes())
    res = subprocess.run([sys.executable, "-m", "rsb_maniskill.replay", "--traj-path", str(src), "--save-traj"],
                         capture_output=True, text=True, env=_env(), cwd=REPO, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "Replayed 3 episodes, 3/3=100.00% demos saved" in res.stdout
    out = tmp_path / "copy.state.pd_joint_pos.physx_cpu.h5"
    assert out.exists()
    data = json.loads(out.with_suffix(".json").read_text())
    assert all(ep["success"] for ep in data["episodes"]) and "instruction" in data["episodes"][0]


# ---------------------------------------------------------------------------- slow
def _replay(src: Path, *args: str) -> subprocess.CompletedProcess:
    return _rsb("replay", "--traj-path", str(src), *args, timeout=600)


@pytest.mark.slow
def test_replay_converts_to_delta_joint_control(dataset):
    res = _replay(dataset.path, "-c", "pd_joint_delta_pos", "--save-traj")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "3/3=100.00% demos saved" in res.stdout
    out = dataset.path.with_name("train.state.pd_joint_delta_pos.physx_cpu.h5")
    data = json.loads(out.with_suffix(".json").read_text())
    assert data["env_info"]["env_kwargs"]["control_mode"] == "pd_joint_delta_pos"
    src = json.loads(dataset.path.with_suffix(".json").read_text())
    assert [ep["instruction"] for ep in data["episodes"]] == [ep["instruction"] for ep in src["episodes"]]
    with h5py.File(out) as f:
        a = f["traj_0/actions"][:]
        assert a.shape[1] == 14 and np.abs(a).max() <= 1.0 + 1e-6


@pytest.mark.slow
def test_replay_to_rgb_observations(dataset):
    res = _replay(dataset.path, "-o", "rgb", "--save-traj", "--count", "1")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "1/1=100.00% demos saved" in res.stdout
    out = dataset.path.with_name("train.rgb.pd_joint_pos.physx_cpu.h5")
    with h5py.File(out) as f:
        cams = f["traj_0/obs/sensor_data"]
        assert len(cams) >= 1
        for cam in cams.values():
            rgb = cam["rgb"]
            assert rgb.dtype == np.uint8 and rgb.shape[0] == f["traj_0/actions"].shape[0] + 1
            assert rgb.shape[1:] == (48, 64, 3)  # the recorded env kwargs reach the replay's env


@pytest.mark.slow
def test_maniskills_own_replay_tool_as_is(dataset, tmp_path):
    """`python -m mani_skill.trajectory.replay_trajectory`, nothing imported by hand: the file names
    its env "rsb_maniskill:RSB-Math-4", so gymnasium imports the pack in each process (2 workers,
    an episode each), converting control and obs modes; its output replays again with the same tool."""
    src = tmp_path / "demo.h5"
    src.write_bytes(dataset.path.read_bytes())
    src.with_suffix(".json").write_bytes(dataset.path.with_suffix(".json").read_bytes())
    assert json.loads(src.with_suffix(".json").read_text())["env_info"]["env_id"] == "rsb_maniskill:RSB-Math-4"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}

    def maniskill_replay(path: Path, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "mani_skill.trajectory.replay_trajectory", "--traj-path",
                               str(path), *args], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)

    res = maniskill_replay(src, "-n", "2", "--count", "2", "-c", "pd_joint_delta_pos", "-o", "rgb", "--save-traj")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "Replayed 2 episodes, 2/2=100.00% demos saved" in res.stdout
    out = tmp_path / "demo.rgb.pd_joint_delta_pos.physx_cpu.h5"
    data = json.loads(out.with_suffix(".json").read_text())
    assert data["env_info"]["env_id"] == "rsb_maniskill:RSB-Math-4"
    assert data["env_info"]["env_kwargs"]["control_mode"] == "pd_joint_delta_pos"
    with h5py.File(out) as f:
        assert f["traj_0/obs/sensor_data/head_camera/rgb"].shape[-1] == 3
    # ManiSkill writes its own episode fields only; the RSB ones come back from the source
    assert "instruction" not in data["episodes"][0]
    assert carry_metadata(src, out) == 2
    source = json.loads(src.with_suffix(".json").read_text())
    restored = json.loads(out.with_suffix(".json").read_text())
    assert [e["instruction"] for e in restored["episodes"]] == [e["instruction"] for e in source["episodes"][:2]]
    again = maniskill_replay(out, "-o", "state", "--count", "1", "--save-traj")
    assert again.returncode == 0 and "1/1=100.00% demos saved" in again.stdout, again.stderr[-3000:]


@pytest.mark.slow
def test_two_processes_make_the_same_dataset_as_one(tmp_path):
    one = generate(_cfg(tmp_path / "one", num=4))
    two = generate(_cfg(tmp_path / "two", num=4, num_procs=2))
    d1, d2 = _check_dataset(one.path), _check_dataset(two.path)
    assert d2["rsb"]["num_procs"] == 2
    # every seed succeeds here, so both runs keep seeds 0..3 in seed order
    assert [e["episode_seed"] for e in d1["episodes"]] == [e["episode_seed"] for e in d2["episodes"]]
    # same episodes (question, options, binding, layout) ...
    meta = ("instruction", "options", "correct_letter", "block_of_option")
    assert [[e[k] for k in meta] for e in d1["episodes"]] == [[e[k] for k in meta] for e in d2["episodes"]]
    # ... and the same demos, bit for bit, though seed 3 follows seeds 0-2 in one process and seed 1
    # in the other (every reset builds a fresh PhysX scene: before, 118 steps here and 119 there)
    with h5py.File(one.path) as f1, h5py.File(two.path) as f2:
        for i in range(4):
            a1, a2 = _arrays(f1[f"traj_{i}"]), _arrays(f2[f"traj_{i}"])
            assert a1.keys() == a2.keys() and {"actions", "env_states/articulations/aloha_agilex"} <= a1.keys()
            assert [k for k in a1 if not np.array_equal(a1[k], a2[k])] == [], i


@pytest.mark.slow
def test_sigterm_with_worker_processes(tmp_path):
    rc, path, log = _sigterm_after_first_episode(tmp_path, procs=2)
    assert rc == 128 + signal.SIGTERM, log
    _check_kept(path, log)


@pytest.mark.slow
def test_shards_merge_into_one_dataset(tmp_path, capsys):
    """The commands in this process (the processes' own signals and exits are the SIGTERM tests')."""
    paths = []
    for i in range(2):
        assert main(["generate", ENV_ID, "--questions", "0:4", "--shard", f"{i}/2", "--out", str(tmp_path), "-q",
                     "--num-procs", "1"]) == 0, capsys.readouterr().err[-3000:]
        paths.append(tmp_path / ENV_ID / "motionplanning" / f"train-shard{i}of2.state.pd_joint_pos.physx_cpu.h5")
    assert main(["merge", *map(str, paths), "--out", str(tmp_path / "all.h5"), "--sort-by-seed"]) == 0
    data = _check_dataset(tmp_path / "all.h5")
    assert [ep["question_index"] for ep in data["episodes"]] == [0, 1, 2, 3]
    assert data["rsb"]["shards"] == ["0/2", "1/2"] and data["rsb"]["completed"] == 4
    capsys.readouterr()
    assert main(["merge", *map(str, paths), "--out", str(tmp_path / "all.h5")]) == 2
    assert "--overwrite" in capsys.readouterr().err


@pytest.mark.slow
def test_save_video_writes_one_mp4_per_demo(tmp_path):
    summary = generate(_cfg(tmp_path, num=1, save_video=True))
    data = _check_dataset(summary.path)
    video = tmp_path / "demos" / data["episodes"][0]["video"]
    assert video.exists() and video.stat().st_size > 1000


@pytest.mark.slow
def test_objects_demos_replay_with_maniskills_tool_in_delta_joint_control(tmp_path):
    """Everyday objects: generated demos replay with ManiSkill's replay tool (fresh process,
    nothing imported by hand) converted to pd_joint_delta_pos, every demo still a success."""
    summary = generate(GenerateConfig(env_id="RSB-Direct-4-Objects", out=str(tmp_path / "demos"), progress=False,
                                      num=2))
    assert summary.completed == 2, summary
    data = _check_dataset(summary.path)
    assert data["env_info"]["env_id"] == "rsb_maniskill:RSB-Direct-4-Objects"
    assert all(":" in c and not c.startswith("block") for e in data["episodes"] for c in e["candidates"])
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    res = subprocess.run([sys.executable, "-m", "mani_skill.trajectory.replay_trajectory", "--traj-path",
                          str(summary.path), "-c", "pd_joint_delta_pos", "-o", "state", "--save-traj"],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "Replayed 2 episodes, 2/2=100.00% demos saved" in res.stdout


def test_merged_demos_keep_one_benchmark_version():
    from rsb_maniskill.motionplan.summary import combine_rsb_blocks

    block = {"requested": 2, "completed": 2, "complete": True, "benchmark_version": "1.1", "shard": "0/2"}
    assert combine_rsb_blocks([block, {**block, "shard": "1/2"}])["benchmark_version"] == "1.1"
    with pytest.raises(ValueError, match="cannot merge demos of RSB-MS 1.1 and unversioned"):
        combine_rsb_blocks([block, {k: v for k, v in block.items() if k != "benchmark_version"}])
