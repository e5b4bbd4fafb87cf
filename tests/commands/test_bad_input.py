"""Every mistake a clear line, nothing locked: each command fed bad input exits 2 (usage) or 1
(runtime) with one line naming what is wrong and how to fix it, no traceback, and the results
folder it was pointed at byte for byte as it was.

The tables walk the commands' bad inputs: ``USAGE`` (caught before any env is built: no physics),
``DAMAGED`` (a results folder edited or damaged by hand), ``POLICIES`` (a user policy that
misbehaves: one env, one episode), and every option of every command that takes a number or a
choice, fed a word it cannot take (so a new flag gets the same treatment). Runs whose subject is what
the user reads run rsb eval's worker tasks in this process (``eval_workers_here``); a policy's error
from a real worker process: test_a_worker_sends_the_policy_error_back_whole...
"""
from __future__ import annotations

import argparse
import json
import pickle
import shutil
import socket
from pathlib import Path

import h5py
import numpy as np
import pytest
from eval_here import workers_here

from rsb_maniskill.cli import build_parser, main

from bad_policies import OUTPUTS

SUITE = "RSB-Math-4"
RUN = ["--suites", SUITE, "-q"]  # every rsb eval below: one suite, no progress bars


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder``, by its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def one_error_line(err: str) -> str:
    """The one error line of a command's stderr (progress lines and ManiSkill's warnings aside)."""
    lines = [line for line in err.splitlines() if ": error: " in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def rsb(capsys, argv: list[str]) -> tuple[int, str]:
    """``rsb ARGV`` in this process: (exit status, stderr)."""
    capsys.readouterr()
    code = main(argv)
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    """The folder of a finished `rsb eval` (random, one episode of 3 steps): what the errors must leave alone."""
    out = tmp_path_factory.mktemp("bad_input") / "results"
    with workers_here():
        assert main(["eval", "random", "-n", "1", "--max-steps", "3", "--out", str(out), *RUN]) == 0
    assert (out / "run.json").is_file() and (out / "summary.md").is_file()
    return out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# rsb eval: (arguments, exit status, what the line says). All fail before an env is built.
USAGE = [
    (["eval", "oracle", "-o", "bogus"], 2, "-o bogus: not an obs mode; use one of state"),
    (["eval", "oracle", "-c", "bogus"], 2, "-c bogus: not a controller of the robot aloha_agilex; use one of "
                                           "pd_joint_pos"),
    (["eval", "oracle", "-e", "foo=1"], 2, "--env-arg foo: RSB-Math-4 takes no keyword 'foo'; it takes color_map"),
    (["eval", "oracle", "-e", "camera_size=abc"], 2, "camera_size takes tuple[int, int] | None; VALUE is read as "
                                                     "JSON, e.g. -e camera_size=[224,224]"),
    (["eval", "oracle", "-e", "camera_size=[224]"], 2, "camera_size takes tuple[int, int] | None"),
    (["eval", "oracle", "-e", "num_envs=0"], 2, "--env-arg cannot set num_envs: use --num-envs"),
    (["eval", "oracle", "-e", "sim_backend=physx_cuda"], 2, "--env-arg cannot set sim_backend: use -b / --sim-backend"),
    (["eval", "oracle", "--num-envs", "0"], 2, "--num-envs must be >= 1, got 0"),
    (["eval", "oracle", "-b", "physx_cuda", "--num-envs", "auto"], 2, "with -b physx_cuda give --num-envs K"),
    (["eval", "oracle", "-e", "obs_mode=rgb"], 2, "--env-arg cannot set obs_mode: use -o / --obs-mode"),
    (["eval", "oracle", "-e", "targets=objects"], 2, "--env-arg cannot set targets: the suite id fixes it"),
    (["eval", "oracle", "-e", "split=train"], 2, "--env-arg cannot set split: the protocol fixes split=test"),
    (["eval", "oracle", "-e", "color_map=bogus"], 2, "RSB-Math-4: unknown color_map 'bogus'; valid: fixed, shuffle"),
    (["eval", "oracle", "-a", "foo=1"], 2, "policy 'oracle': got an unexpected keyword argument 'foo' "
                                           "(its arguments: none); give the factory's arguments with -a KEY=VALUE"),
    (["eval", "random", "-a", "foo=1"], 2, "(its arguments: chunk_size, seed)"),
    (["eval", "bad_policies:needs_checkpoint"], 2, "policy 'bad_policies:needs_checkpoint': missing a required "
                                                   "argument: 'checkpoint' (its arguments: checkpoint, replan_every)"),
    (["eval", "no_such_module:make"], 2, "cannot import module 'no_such_module'"),
    (["eval", "oracle", "-a", "oops"], 2, "--policy-arg 'oops' must look like KEY=VALUE"),
    (["eval", "oracle", "--suites", ""], 2, "--suites '' names no suite; give a suite id (e.g. RSB-Math-4)"),
    (["eval", "oracle", "--suites", "RSB-Nope-4"], 2, "unknown suite 'RSB-Nope-4'"),
    (["eval", "oracle", "-n", "0"], 2, "--num-episodes must be >= 1, got 0"),
    (["eval", "oracle", "-n", "abc"], 2, "argument -n/--num-episodes: invalid int value: 'abc' (see rsb eval --help)"),
    (["eval", "remote", "-a", "prot=1"], 2, "-a prot: not an option of the remote policy"),
    (["eval", "remote", "-a", "port={port}", "-a", "connect_timeout=1"], 2,
     "no policy server at ws://127.0.0.1:{port} after 1 s"),
    (["eval", "random", "-n", "2", "--max-steps", "6"], 2, "max_steps: 3 before, 6 now"),  # a resume, other settings
    (["backbone", "arithmetic", "-e", "foo=1"], 2, "--env-arg foo: RSB-Math-4 takes no keyword 'foo'"),
    (["backbone", "arithmetic", "-e", "obs_mode=rgb"], 2, "cannot set obs_mode: rsb backbone builds its env"),
]


@pytest.mark.parametrize("argv, status, message", USAGE, ids=[" ".join(c[0][:4]) for c in USAGE])
def test_usage_errors_are_one_line_and_write_nothing(argv, status, message, results, capsys):
    port = str(free_port())
    argv = [a.replace("{port}", port) for a in argv]
    before = snapshot(results)
    code, err = rsb(capsys, [*argv, "--out", str(results), *([] if "--suites" in argv else RUN[:2]), "-q"])
    line = one_error_line(err)
    assert code == status and message.replace("{port}", port) in line, line
    assert line.startswith(f"rsb {argv[0]}: error: ")
    assert snapshot(results) == before


@pytest.mark.usefixtures("eval_workers_here")
def test_a_typo_locks_nothing(results, capsys, tmp_path):
    """The issue's first item: a typo fails before run.json is written, so the corrected command runs
    in the same folder; and a run.json row of a run that recorded nothing (one killed before its
    first episode) is replaced with a note, not a refusal."""
    out = tmp_path / "fresh"
    code, err = rsb(capsys, ["eval", "oracle", "-o", "bogus", "-n", "1", "--out", str(out), *RUN])
    assert code == 2 and "-o bogus" in one_error_line(err)
    assert not out.exists() or snapshot(out) == {}
    shutil.copytree(results, out)
    manifest = json.loads((out / "run.json").read_text())
    manifest["runs"]["blind"] = {**manifest["runs"]["random"], "policy": "blind", "obs_mode": "rgb"}
    (out / "run.json").write_text(json.dumps(manifest))  # as a crashed first run of blind left it
    code, err = rsb(capsys, ["eval", "blind", "-n", "1", "--max-steps", "3", "--out", str(out), *RUN])
    assert code == 0, err
    assert "'blind' was started with other settings and recorded nothing; replaced (obs_mode: 'rgb' before, " \
           "'state' now)" in err
    assert json.loads((out / "run.json").read_text())["runs"]["blind"]["obs_mode"] == "state"


# A results folder damaged by hand: (file, its new text, what the line says), for rsb eval and rsb report.
DAMAGED = [
    ("run.json", "{\"runs\": ", "run.json: not valid JSON (line 1, column 10: Expecting value); restore it, or "
                                "delete it and the next run writes it anew"),
    ("run.json", "[1, 2]", "run.json: not the settings file of rsb eval"),
    ("episodes.jsonl", "{first}\nnot json at all\n{first}\n", "episodes.jsonl:2: not a JSON object record ('not json "
                                                              "at all'): the file was edited or damaged; fix or delete "
                                                              "that line (the other records are kept) and rerun"),
    ("episodes.jsonl", "{first}\n{}\n", "episodes.jsonl:2: not an episode record: it has none of their fields "
                                          "(suite_id, seed, question_id, ...)"),
    ("episodes.jsonl", "{first}\n{\"seed\": 1}\n", "episodes.jsonl:2: episode record lacks fields: suite_id, "
                                                   "question_id"),
]


@pytest.mark.parametrize("command", ["eval", "report"])
@pytest.mark.parametrize("name, text, message", DAMAGED, ids=[f"{d[0]}-{i}" for i, d in enumerate(DAMAGED)])
def test_damaged_files_name_the_file_and_line(command, name, text, message, results, tmp_path, capsys):
    out = tmp_path / "damaged"
    shutil.copytree(results, out)
    first = (out / "episodes.jsonl").read_text().splitlines()[0]
    (out / name).write_text(text.replace("{first}", first))
    before = snapshot(out)
    argv = ["eval", "random", "-n", "1", "--max-steps", "3", "--out", str(out), *RUN] if command == "eval" \
        else ["report", str(out)]
    code, err = rsb(capsys, argv)
    line = one_error_line(err)
    assert code == 2 and f"{out / name}" in line and message.split(": ", 1)[1] in line, line
    assert line.count(str(out)) == 1  # the path once
    assert snapshot(out) == before


def test_report_rewrites_every_summary_from_the_same_records(results, tmp_path, capsys):
    """rsb report writes summary.*, results.json and report.html in one pass: they agree."""
    out = tmp_path / "rep"
    shutil.copytree(results, out)
    (out / "summary.json").write_text("{}")  # stale
    assert main(["report", str(out)]) == 0
    summary, doc = json.loads((out / "summary.json").read_text()), json.loads((out / "results.json").read_text())
    assert summary["rows"]["random"]["suites"][SUITE]["n_episodes"] == doc["rows"][0]["suites"][SUITE]["n"] == 1


def test_compare_says_nsg_as_the_tables_do(results, tmp_path, capsys):
    other = tmp_path / "other"  # a run compared with itself is refused (test_faults): its copy stands in
    shutil.copytree(results, other)
    assert main(["report", "--compare", str(results), str(other)]) == 0
    out = capsys.readouterr().out
    assert "| nSG |" in out and "NSG" not in out


@pytest.mark.usefixtures("eval_workers_here")
def test_more_records_than_asked_is_said(results, tmp_path, capsys):
    """-n 1 on a folder holding 2 episodes of the row: the summary covers both, and a line says so."""
    out = tmp_path / "more"
    shutil.copytree(results, out)
    assert main(["eval", "random", "-n", "2", "--max-steps", "3", "--out", str(out), *RUN]) == 0
    code, err = rsb(capsys, ["eval", "random", "-n", "1", "--max-steps", "3", "--out", str(out), *RUN])
    assert code == 0
    assert (f"rsb eval: note: the summary covers every record in {out}: 2 episodes of 'random' on these suites, "
            "1 more than this run's -n 1") in err
    assert json.loads((out / "summary.json").read_text())["rows"]["random"]["suites"][SUITE]["n_episodes"] == 2


# A user policy that misbehaves (tests/helpers/bad_policies.py): one env is built, the first act fails.
POLICIES = [(["bad_policies:returns", "-a", f"what={what}"], phrase) for what, (_, phrase) in OUTPUTS.items()] + [
    (["bad_policies:RaisesInAct"], "act raised RuntimeError: the model is not loaded"),
    (["bad_policies:RaisesInReset"], "reset raised KeyError: 'wrist_camera'"),
]


@pytest.mark.parametrize("policy, phrase", POLICIES, ids=[" ".join(p[0]) for p in POLICIES])
@pytest.mark.usefixtures("eval_workers_here")  # the way back from a worker: the next test
def test_a_misbehaving_policy_is_one_line_naming_it_and_the_episode(policy, phrase, results, capsys):
    before = snapshot(results)
    code, err = rsb(capsys, ["eval", *policy, "-o", "state", "-n", "2", "--max-steps", "5", "--out", str(results),
                             *RUN])
    line = one_error_line(err)
    assert code == 1, err
    assert line.startswith(f"rsb eval: error: policy '{policy[0]}' on RSB-Math-4 seed 10000000 (normal instruction): "
                           f"{phrase}"), line
    assert line.endswith("fix it and rerun the same command: finished episodes are kept (rsb --debug eval ... "
                         "shows the traceback)")
    assert "runner.py" not in err and "jobs.py" not in err  # none of the harness's frames
    assert snapshot(results) == before  # its run.json row is taken back: it recorded nothing


def test_a_worker_sends_the_policy_error_back_whole_and_debug_shows_the_traceback(results, capsys):
    """--num-procs 2: both workers fail, the command prints the error once; --debug adds the
    policy's traceback (from the worker process) before the same line."""
    before = snapshot(results)
    argv = ["eval", "bad_policies:RaisesInAct", "-o", "state", "-n", "2", "--max-steps", "5", "--num-procs", "2",
            "--out", str(results), *RUN]
    code, err = rsb(capsys, argv)
    assert code == 1 and "act raised RuntimeError: the model is not loaded" in one_error_line(err)
    code, err = rsb(capsys, ["--debug", *argv])
    assert code == 1 and err.count("rsb eval: error: ") == 1
    trace = err.split("rsb eval: error: ")[0]
    assert "Traceback" in trace and "bad_policies.py" in trace and "RuntimeError: the model is not loaded" in trace
    assert snapshot(results) == before


def test_an_env_that_cannot_be_built_is_one_line(results, capsys):
    """What the checks cannot know (a render device that does not exist) fails in the worker: one
    line naming the env's settings, exit 1, and the run's run.json row taken back."""
    before = snapshot(results)
    code, err = rsb(capsys, ["eval", "random", "-o", "rgb", "-e", "render_backend=bogus", "--name", "rb", "-n", "1",
                             "--out", str(results), *RUN])
    line = one_error_line(err)
    assert code == 1 and ("rsb eval: error: cannot build the env RSB-Math-4 (obs_mode='rgb', "
                          "render_backend='bogus'): RuntimeError: ") in line, line
    assert snapshot(results) == before


def _demo_pair(folder: Path, name: str) -> Path:
    """A small trajectory pair (X.h5 + X.json) as rsb generate writes them."""
    h5 = folder / f"{name}.h5"
    with h5py.File(h5, "w") as f:
        f.create_group("traj_0")["actions"] = np.zeros((400, 14))
    h5.with_suffix(".json").write_text(json.dumps({"env_info": {"env_id": SUITE, "env_kwargs": {}},
                                                   "episodes": [{"episode_id": 0, "episode_seed": 0}]}))
    return h5


def test_damaged_demo_files_are_named(tmp_path, capsys):
    """A truncated .h5 and a damaged .json, for rsb export lerobot, rsb merge and rsb replay."""
    good = _demo_pair(tmp_path, "good")
    cut = _demo_pair(tmp_path, "cut")
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    bad = _demo_pair(tmp_path, "bad")
    bad.with_suffix(".json").write_text('{"env_info": ')
    before = snapshot(tmp_path)
    for damaged, phrase in ((cut, f"{cut}: not a readable HDF5 file ("), (bad, f"{bad.with_suffix('.json')}: not "
                                                                               "valid JSON (")):
        for argv in (["export", "lerobot", str(damaged), "--out", str(tmp_path / "ds")],
                     ["merge", str(good), str(damaged), "--out", str(tmp_path / "merged.h5")],
                     ["replay", "--traj-path", str(damaged)]):
            code, err = rsb(capsys, argv)
            line = one_error_line(err)
            assert code == 2 and phrase in line and "restore it or make it again (rsb generate)" in line, line
    assert snapshot(tmp_path) == before


OTHERS = [
    (["questions", SUITE, "-n", "-1"], 2, "rsb questions: error: -n must be >= 1, got -1"),
    (["questions"], 2, "rsb questions: error: name at least one SUITE"),
    (["questions", ""], 2, "rsb questions: error: SUITE '' names no suite"),
    (["audit", SUITE, "--out", "/proc/rsb-audit"], 2, "rsb audit: error: cannot write to --out /proc/rsb-audit"),
    (["dataset", "build", "--suites", "", "--out", "{tmp}/ds"], 2, "rsb dataset build: error: --suites '' names no "
                                                                   "suite"),
    (["generate", SUITE, "-n", "-1", "--out", "{tmp}/demos"], 2, "rsb generate: error: -n must be >= 1, got -1"),
]


@pytest.mark.parametrize("argv, status, message", OTHERS, ids=[" ".join(c[0][:3]) for c in OTHERS])
def test_other_commands_bad_input(argv, status, message, tmp_path, capsys):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    code, err = rsb(capsys, argv)
    assert code == status and message in one_error_line(err), err
    assert list(tmp_path.iterdir()) == []


def test_help_texts_say_percent_once(capsys):
    """argparse formats an option's help with %, not a description: "%%" there shows as is."""
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    for command, sub in commands.items():
        out = sub.format_help()
        assert "%%" not in out, command
        if command in ("audit", "report", "leaderboard"):
            assert "95 %" in out, command


def _options() -> list[tuple[list[str], str, str]]:
    """(command path, option, a value it cannot take) for every option of every command that takes
    a number or one of fixed choices."""
    out = []

    def walk(parser: argparse.ArgumentParser, path: list[str]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    if sub.prefix_chars == "-":  # rsb replay hands everything to ManiSkill's parser
                        walk(sub, [*path, name])
            elif action.option_strings and action.nargs != 0:
                if action.type in (int, float):
                    out.append((path, action.option_strings[-1], "many"))
                elif action.choices is not None:
                    out.append((path, action.option_strings[-1], "no-such-choice"))

    walk(build_parser(), [])
    return out


OPTIONS = _options()


def test_the_walk_finds_the_options():
    found = {(" ".join(path), option) for path, option, _ in OPTIONS}
    assert {("eval", "--num-episodes"), ("eval", "--instruction"), ("dataset build", "--shard-size"),
            ("audit", "--num-episodes"), ("questions", "--num-episodes")} <= found


@pytest.mark.parametrize("path, option, value", OPTIONS, ids=[f"{' '.join(p)} {o}" for p, o, _ in OPTIONS])
def test_every_option_refuses_a_word_it_cannot_take(path, option, value, capsys):
    code, err = rsb(capsys, [*path, option, value])
    line = one_error_line(err)
    assert code == 2 and option in line and "invalid" in line, line
    assert line.endswith(f"(see rsb {' '.join(path)} --help)".replace("rsb  ", "rsb ")), line


@pytest.mark.usefixtures("eval_workers_here")
def test_a_summary_written_at_an_interruption_says_it_is_partial(tmp_path, capsys, monkeypatch):
    """Ctrl-C in the second of three episodes: summary.md / .json and report.html say "partial:
    interrupted, 1 of 3 episodes"; the resumed run's summary no longer does."""
    monkeypatch.setenv("RSB_TEST_INTERRUPT_MARKER", str(tmp_path / "interrupted-once"))
    out = tmp_path / "cut"
    argv = ["eval", "bad_policies:InterruptsOnce", "-o", "state", "-n", "3", "--max-steps", "5", "--out", str(out),
            *RUN]
    assert main(argv) == 130
    mark = "partial: interrupted, 1 of 3 episodes"
    assert json.loads((out / "summary.json").read_text())["partial"] == mark
    assert (out / "summary.md").read_text().startswith(f"**{mark}**")
    assert mark in (out / "report.html").read_text()
    assert main(argv) == 0
    assert "partial" not in json.loads((out / "summary.json").read_text())
    assert "partial" not in (out / "summary.md").read_text() and mark not in (out / "report.html").read_text()


def test_the_errors_pickle_whole():
    """What a worker process sends back is the error itself: message, policy, episode and traceback."""
    from rsb_maniskill.evaluation.jobs import JobError
    from rsb_maniskill.policies.errors import PolicyError

    err = PolicyError("act returned None", policy="p", where="RSB-Math-4 seed 7 (normal instruction)", detail="tb")
    back = pickle.loads(pickle.dumps(err))
    assert isinstance(back, ValueError) and str(back) == str(err) == ("policy 'p' on RSB-Math-4 seed 7 (normal "
                                                                      "instruction): act returned None")
    assert back.detail == "tb"
    job = pickle.loads(pickle.dumps(JobError("worker 0: exited with code -9", detail="how")))
    assert str(job) == "worker 0: exited with code -9" and job.detail == "how"


def test_a_batched_policy_is_blamed_for_its_wave():
    """The parallel-env loop names the policy and the env's seed of the call that went wrong."""
    from rsb_maniskill.evaluation.runner import EpisodeSettings, batched_loop
    from rsb_maniskill.policies.errors import PolicyError

    from fake_envs import SEEDS, FakeBatchedEnv, ScriptedPolicy

    class Nan(ScriptedPolicy):
        def act(self, obs):
            return np.full((3, 14), np.nan)

    settings = EpisodeSettings(suite_id=SUITE, seeds=SEEDS, label="nan-policy")
    with pytest.raises(PolicyError) as caught:
        batched_loop(FakeBatchedEnv(2), [Nan(), Nan()], settings, SEEDS, list().append)
    # one act-only policy per env: the user's act, on its env's seed (not act_batch on the wave)
    assert str(caught.value).startswith(f"policy 'nan-policy' on {SUITE} seed {SEEDS[0]} (normal "
                                        "instruction): act returned NaN or inf actions (42 of 42 numbers")


def test_the_obs_modes_checked_without_the_simulator_are_every_suites():
    """`rsb eval` passes the obs modes that read no camera without loading the task class (its own
    process stays light): every suite's task class must take them."""
    from rsb_maniskill.commands.eval_args import _task_class
    from rsb_maniskill.env_ids import ENVS
    from rsb_maniskill.parallel.plan import NO_RENDER_OBS_MODES

    for suite in ENVS:
        assert set(NO_RENDER_OBS_MODES) <= set(_task_class(suite).SUPPORTED_OBS_MODES), suite
