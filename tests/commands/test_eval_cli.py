"""`rsb eval` end to end, in physics: oracle and blind baselines, resume after a kill, videos,
errors that leave results untouched, and the remote client serving the oracle. The kill / resume,
video and paper-objects runs are slow (20-70 s each); the resume logic itself is tested without
physics in evaluation/test_records.py and evaluation/test_runner.py."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import pytest

import rsb_maniskill  # noqa: F401  (registers the suites)
from rsb_maniskill.cli import main
from rsb_maniskill.evaluation import EVAL_ENV_KWARGS, eval_seeds, run_episodes
from rsb_maniskill.evaluation.store import read_records
from rsb_maniskill.policies.reference import ExpertPolicy, blind_target
from rsb_maniskill.reporting.summary import results_from_records, summary_dict

SUITE = "RSB-Math-4"


def rsb_eval(*args: str) -> int:
    return main(["eval", *args, "-q"])


def summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


@pytest.mark.slow
def test_oracle_and_blind_on_100_episodes(tmp_path):
    """The issue's acceptance check: oracle TSR >= 98 %, blind nSG within 0.1 of 0 (RSB-Math-4)."""
    out = tmp_path / "res"
    assert rsb_eval("oracle", "--suites", SUITE, "-n", "100", "--out", str(out), "--num-procs", "2") == 0
    assert rsb_eval("blind", "--suites", SUITE, "-n", "100", "--out", str(out), "--num-procs", "2") == 0
    rows = summary(out)["rows"]
    oracle, blind = rows["oracle"]["suites"][SUITE], rows["blind"]["suites"][SUITE]
    assert oracle["n_episodes"] == blind["n_episodes"] == 100
    assert oracle["tsr"]["value"] >= 0.98
    assert blind["gsr"]["value"] >= 0.95  # the expert grasps whatever it is sent to
    assert abs(blind["nsg"]["value"]) <= 0.1
    records = read_records(out / "episodes.jsonl")
    assert sorted(r["seed"] for r in records if r["policy"] == "oracle") == eval_seeds(SUITE, 100)
    # blind went for its own draw, not the answer: its first grasp is that block
    for r in records:
        if r["policy"] == "blind" and r["grasped_any"]:
            assert r["first_grasped"] == blind_target(r["seed"], 4)
    assert (out / "summary_oracle.png").stat().st_size > 0 and (out / "summary.csv").exists()


# kill -9 (and SIGINT), then the same command: tests/acceptance/test_faults.py


def _workers(pid: int) -> set[int]:
    """Spawned worker processes of ``pid`` (not multiprocessing's resource tracker)."""
    out = set()
    for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
        cmdline = Path(f"/proc/{c}/cmdline").read_bytes()
        if b"spawn_main" in cmdline and b"resource_tracker" not in cmdline:
            out.add(int(c))
    return out


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="reads child processes from /proc (Linux)")
def test_sigterm_stops_workers_and_keeps_finished_episodes(tmp_path):
    out = tmp_path / "res"
    cmd = [sys.executable, "-m", "rsb_maniskill.cli", "eval", "blind", "--suites", SUITE, "-n", "12",
           "--num-procs", "2", "--out", str(out), "-q"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    records = out / "episodes.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if records.exists() and records.read_text().count("\n") >= 2:
            break
        time.sleep(0.05)
    workers = _workers(proc.pid)
    assert proc.poll() is None and len(workers) >= 2
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "Rerun the same command to resume" in err
    time.sleep(0.5)
    assert not [w for w in workers if Path(f"/proc/{w}").exists()], "worker processes outlived the run"
    partial = summary(out)["partial"]  # the finished episodes are summarised, and marked as part of the run
    assert partial == f"partial: interrupted, {len(read_records(records))} of 12 episodes"
    assert (out / "summary.md").read_text().startswith(f"**{partial}**")
    assert partial in (out / "report.html").read_text()
    assert rsb_eval("blind", "--suites", SUITE, "-n", "12", "--num-procs", "2", "--out", str(out)) == 0
    assert sorted(r["seed"] for r in read_records(records)) == eval_seeds(SUITE, 12)
    assert "partial" not in summary(out)


@pytest.mark.slow
@pytest.mark.usefixtures("eval_workers_here")
def test_videos_of_the_first_episodes(tmp_path):
    out = tmp_path / "res"
    assert rsb_eval("oracle", "--suites", "RSB-Math-10", "-n", "2", "--videos", "1", "--out", str(out)) == 0
    videos = sorted((out / "videos").glob("*.mp4"))
    assert [v.name for v in videos] == [f"oracle_RSB-Math-10_normal_seed{eval_seeds('RSB-Math-10', 1)[0]}.mp4"]
    import imageio.v3 as iio

    frames = iio.imread(videos[0])
    rec = read_records(out / "episodes.jsonl")[0]
    assert len(frames) == rec["steps"] + 1 and frames.std() > 5  # one frame per step, not blank
    assert rec["video"] == videos[0].name


@pytest.mark.usefixtures("eval_workers_here")
def test_errors_leave_results_untouched(tmp_path, capsys):
    out = tmp_path / "res"
    assert rsb_eval("random", "--suites", SUITE, "-n", "1", "--max-steps", "5", "--out", str(out)) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    capsys.readouterr()

    cases = [
        (["random", "--suites", "RSB-Nope-4"], "unknown suite 'RSB-Nope-4'"),
        (["no_such_module:make"], "cannot import module 'no_such_module'"),
        (["rsb_maniskill.policies.interface:nothing"], "has no attribute 'nothing'"),
        (["random", "--suites", "RSB-HardMath-4", "--data-dir", str(tmp_path / "none")], "GSM8K not found"),
        (["random", "--suites", SUITE, "-n", "0"], "--num-episodes must be >= 1"),
        (["random", "--suites", SUITE, "-e", "split=train"], "cannot set split"),
        (["random", "--suites", SUITE, "-a", "oops"], "must look like KEY=VALUE"),
        # resuming with other settings would mix two protocols in one table
        (["random", "--suites", SUITE, "-n", "2", "--max-steps", "6"], "max_steps: 5 before, 6 now"),
    ]
    for args, message in cases:
        assert rsb_eval(*args, "--out", str(out)) == 2, args
        err = capsys.readouterr().err
        assert message in err, (args, err)
    after = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert after == before

    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert rsb_eval("random", "--suites", SUITE, "--out", str(blocker / "sub")) == 2
    assert "cannot write to results directory" in capsys.readouterr().err


def test_oracle_served_over_websocket_loopback(tmp_path):
    """RemotePolicy -> PolicyServer -> oracle: the wire protocol carries a real policy to success."""
    from rsb_maniskill.policies.remote.client import RemotePolicy
    from rsb_maniskill.policies.remote.server import PolicyServer

    env = gym.make(SUITE, obs_mode="state", render_backend="none", **EVAL_ENV_KWARGS)
    seeds = eval_seeds(SUITE, 3)

    class Oracle(ExpertPolicy):
        def fork(self) -> ExpertPolicy:  # the server's policy for the env it serves: the one env here
            return ExpertPolicy(env)

    try:
        # The server thread runs the oracle on the same env the runner steps; the runner waits for
        # each reply, so the two never touch the env at once.
        with PolicyServer(Oracle(env), host="127.0.0.1", port=0) as server:
            with RemotePolicy("127.0.0.1", server.port, mark_episode_start=True, connect_timeout=10,
                              request_timeout=60, name="remote-oracle") as client:
                records = run_episodes(env, client, SUITE, seeds, tmp_path / "e.jsonl", progress=False)
    finally:
        env.close()
    assert [r["seed"] for r in records] == seeds
    assert all(r["success"] and r["policy"] == "remote-oracle" for r in records)


@pytest.mark.usefixtures("eval_workers_here")
def test_shuffled_and_blank_modes_on_the_real_task(tmp_path):
    """Donor instructions come from the task's episode_spec(seed), without resetting the env."""
    out = tmp_path / "res"
    assert rsb_eval("random", "--suites", SUITE, "-n", "3", "--max-steps", "2", "--instruction", "blank",
                    "shuffled", "--out", str(out)) == 0
    records = read_records(out / "episodes.jsonl")
    env = gym.make(SUITE, obs_mode="state", render_backend="none", **EVAL_ENV_KWARGS)
    own = {s: env.unwrapped.episode_spec(s).instruction for s in eval_seeds(SUITE, 3)}
    env.close()
    blank = [r for r in records if r["instruction_mode"] == "blank"]
    shuffled = [r for r in records if r["instruction_mode"] == "shuffled"]
    assert len(blank) == len(shuffled) == 3
    assert all(r["instruction"] == "" and r["original_instruction"] == own[r["seed"]] for r in blank)
    for r in shuffled:
        assert r["donor_seed"] != r["seed"] and r["instruction"] == own[r["donor_seed"]]
        assert r["original_instruction"] == own[r["seed"]]
    rows = summary(out)["rows"]
    assert set(rows) == {"random (blank)", "random (shuffled)"}
    assert summary_dict(results_from_records(records))["rows"].keys() == rows.keys()


@pytest.mark.slow
@pytest.mark.usefixtures("eval_workers_here")
def test_paper_objects_prints_the_beyond_blocks_table(tmp_path, capsys, question_data):
    """`--suites paper-objects`: the six paper suites with everyday objects, and the appendix's
    Scene | GSR | TSR table with its Avg row."""
    out = tmp_path / "res"
    assert main(["eval", "oracle", "--suites", "paper-objects", "-n", "1", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Beyond Blocks: oracle" in text
    table = text.split("Beyond Blocks: oracle", 1)[1]
    for suite in ("RSB-Math-4", "RSB-HardMath-10", "RSB-General-10"):
        assert f"| {suite} | 100.0 | 100.0 |" in table
    assert "| **Avg** | **100.0** | **100.0** |" in table
    suites = summary(out)["rows"]["oracle"]["suites"]
    assert sorted(suites) == sorted(s + "-Objects" for s in ("RSB-Math-4", "RSB-Math-10", "RSB-HardMath-4",
                                                               "RSB-HardMath-10", "RSB-General-4", "RSB-General-10"))
    assert all(s["n_choices"] in (4, 10) for s in suites.values())
