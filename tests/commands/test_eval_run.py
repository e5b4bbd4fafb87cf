"""`rsb eval` as one run: workers started once for every suite x instruction mode (the records those of
a fresh start a suite), the throughput line on the command's own clock for K = 1 and 4, --num-envs
capped at a worker's episodes, --max-batch / --max-wait-ms, and -q."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rsb_maniskill.cli import main
from rsb_maniskill.evaluation.protocol import eval_seed_range
from rsb_maniskill.evaluation.store import SETTINGS_FIELD, read_records

REPO = Path(__file__).resolve().parents[2]
HELPERS = REPO / "tests" / "helpers"
SUITES = ["RSB-Math-4", "RSB-Math-10"]
SMALL = ["-o", "state", "--max-steps", "4"]


def _env(**extra: str) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(HELPERS), str(REPO), os.environ.get("PYTHONPATH", "")]),
                **extra)


def _comparable(records: list[dict]) -> list[dict]:
    """Records without what differs from run to run (timings) or from path to path (the settings stamp)."""
    drop = {"wall_s", SETTINGS_FIELD}
    return sorted(({k: v for k, v in r.items() if k not in drop} for r in records),
                  key=lambda r: (r["suite_id"], r["instruction_mode"], r["seed"]))


def test_one_start_a_run_gives_the_records_of_a_start_a_suite(tmp_path, monkeypatch):
    """Two suites x two instruction modes on two workers: the workers start once (every policy build of
    the run in the same two processes), and the records are those of each suite and mode run on its own,
    env and policy built afresh (the path before one start a run), episode for episode."""
    from rsb_maniskill.evaluation.jobs import EvalJob, run_job

    monkeypatch.syspath_prepend(str(HELPERS))
    log, out = tmp_path / "builds.log", tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", "eval", "counted_policies:make_counted",
                          "-a", f"log={log}", "--suites", *SUITES, "-n", "3", *SMALL, "--instruction", "normal",
                          "shuffled", "--num-procs", "2", "--policy-process", "worker", "--out", str(out), "-q"],
                         env=_env(), capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    builds = log.read_text().split()
    assert len(builds) == 2 * 2 * 2 and len(set(builds)) == 2  # 4 jobs x 2 workers, in 2 processes
    assert res.stdout.strip().splitlines()[-1].startswith("throughput: start-up ")

    reference = tmp_path / "reference.jsonl"  # each job on its own, in this process
    for suite in SUITES:
        for mode in ("normal", "shuffled"):
            run_job(EvalJob(suite_id=suite, seeds=eval_seed_range(suite, 3), policy="counted_policies:make_counted",
                            label="counted_policies:make_counted", policy_kwargs={"log": str(tmp_path / "x.log")},
                            instruction_mode=mode, obs_mode="state", max_steps=4), reference, progress=False)
    assert _comparable(read_records(out / "episodes.jsonl")) == _comparable(read_records(reference))
    assert len(read_records(reference)) == 12


def _watch_records(cmd: list[str], records: Path) -> tuple[subprocess.CompletedProcess, list[float]]:
    """Runs ``cmd``; the time (this process's clock) at which each line of ``records`` appeared."""
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen: list[float] = []
    while proc.poll() is None:
        try:
            n = records.read_bytes().count(b"\n")
        except FileNotFoundError:
            n = 0
        now = time.monotonic()
        seen += [now] * (n - len(seen))
        time.sleep(0.005)
    out, err = proc.communicate()
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err), seen


@pytest.mark.parametrize("k", [1, 4])
def test_the_throughput_line_agrees_with_env_steps_over_the_steady_wall_time(k, tmp_path):
    """The line's env-steps/s against one computed here: every episode's steps over the time from the
    first episode's start (the moment its record appeared here, less its own wall_s: for K = 4 its
    wave's) to the moment the last record appeared. Agreement within 10 %, whatever the machine's speed
    (before, K = 4 records carried no wall_s and the line took the first wave for start-up)."""
    out = tmp_path / "run"
    n = 8 if k == 1 else 16
    res, seen = _watch_records([sys.executable, "-m", "rsb_maniskill.cli", "eval", "random", "--suites", "RSB-Math-4",
                                "-o", "state", "--max-steps", "150", "-n", str(n), "--num-envs", str(k),
                                "--num-procs", "1", "--out", str(out), "-q"], out / "episodes.jsonl")
    assert res.returncode == 0, res.stderr[-2000:]
    line = res.stdout.strip().splitlines()[-1]
    said = re.match(r"throughput: start-up ([\d.]+) s, then ([\d,]+) env-steps/s \(([\d,]+) env-steps, (\d+) "
                    r"episodes in ([\d.]+) s\)", line)
    assert said, line
    records = [json.loads(x) for x in (out / "episodes.jsonl").read_text().splitlines()]
    steps = [int(r["steps"]) for r in records]
    assert int(said.group(3).replace(",", "")) == sum(steps) and int(said.group(4)) == n == len(seen)
    measured = sum(steps) / (seen[-1] - (seen[0] - float(records[0]["wall_s"])))
    line_rate = float(said.group(2).replace(",", ""))
    print(f"K = {k}: the line {line_rate:,.0f}, measured here {measured:,.0f} env-steps/s")
    assert abs(line_rate / measured - 1) < 0.10, (line, measured)
    assert float(said.group(1)) > 0  # start-up (the worker, its imports, env and policy) is not steady time


def test_num_envs_is_capped_at_the_episodes_a_worker_runs(tmp_path):
    """--num-envs 1000 for 2 episodes on one worker: 2 envs are built, said so, and the run ends."""
    res = subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", "eval", "random", "--suites", "RSB-Math-4",
                          "-n", "2", *SMALL, "--num-envs", "1000", "--num-procs", "1", "--out", str(tmp_path / "r")],
                         env=_env(), capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "envs: 2 a process (--num-envs 1000: no more than the 2 episodes a worker runs)" in res.stderr
    assert len(read_records(tmp_path / "r" / "episodes.jsonl")) == 2


@pytest.mark.parametrize("flag, value, said", [
    ("--max-batch", "0", "--max-batch must be a whole number of rows >= 1, got 0"),
    ("--max-batch", "-3", "--max-batch must be a whole number of rows >= 1, got -3"),
    ("--max-wait-ms", "-1", "--max-wait-ms must be from 0 to"),
    ("--max-wait-ms", "inf", "got inf"),
    ("--max-wait-ms", "nan", "got nan"),
    ("--max-wait-ms", "1e308", "got 1e+308"),
])
def test_bad_batching_flags_are_usage_errors(flag, value, said, tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["eval", "random", "--suites", "RSB-Math-4", "-n", "1", *SMALL, flag, value, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("rsb eval: error: ") and said in err, err
    assert not out.exists()


def test_the_batching_flags_reach_the_shared_server(tmp_path, capsys, monkeypatch):
    from rsb_maniskill.policies.errors import PolicyError
    from rsb_maniskill.policies.remote import shared

    got = {}

    class Server:
        def __init__(self, spec, policy_kwargs, **kwargs):
            got.update(kwargs)
            raise PolicyError("stand-in server: not started", policy=spec)

    monkeypatch.setattr(shared, "SharedServer", Server)
    monkeypatch.syspath_prepend(str(HELPERS))
    assert main(["eval", "counted_policies:make_counted", "-a", f"log={tmp_path / 'builds.log'}", "--suites",
                 "RSB-Math-4", "-n", "2", *SMALL, "--num-procs", "2",
                 "--policy-process", "shared", "--max-batch", "3", "--max-wait-ms", "0", "--out",
                 str(tmp_path / "r"), "-q"]) == 1
    assert (got["max_batch"], got["max_wait_ms"]) == (3, 0.0)
    assert "stand-in server" in capsys.readouterr().err


def test_quiet_is_errors_only_and_normal_output_has_no_logging_lines(tmp_path):
    """-q: nothing on stderr for a run that goes well; without it, what the run chose and the progress,
    never a library's logging line (``INFO:name:...``)."""
    runs = {}
    for flags in ([], ["-q"]):
        runs[bool(flags)] = subprocess.run(
            [sys.executable, "-m", "rsb_maniskill.cli", "eval", "random", "--suites", "RSB-Math-4", "-n", "2", *SMALL,
             "--num-procs", "2", "--out", str(tmp_path / f"r{len(flags)}"), *flags],
            env=_env(), capture_output=True, text=True, timeout=300)
    for res in runs.values():
        assert res.returncode == 0, res.stderr[-2000:]
        assert not re.search(r"(?m)^(INFO|WARNING|DEBUG):", res.stderr), res.stderr[-2000:]
        assert res.stdout.strip().splitlines()[-1].startswith("throughput: ")
    assert runs[True].stderr == ""
    assert "workers: 2 processes (--num-procs 2)" in runs[False].stderr and "ep/s" in runs[False].stderr


def test_an_error_line_keeps_the_cause_of_a_traceback():
    """A message carrying a traceback (a server's, a worker's) reads as its cause, whole, in one line."""
    from rsb_maniskill.policies.errors import one_line

    served = ("error in policy server:\nTraceback (most recent call last):\n  File \"model.py\", line 3, in act\n"
              "    raise ValueError(\"bad image size: 224 x 224 expected\")\nValueError: bad image size: 224 x 224 "
              "expected")
    assert one_line(served) == "error in policy server: ValueError: bad image size: 224 x 224 expected"
    assert one_line("first\nsecond") == "first ..." and one_line("  one  ") == "one" and one_line("") == ""
