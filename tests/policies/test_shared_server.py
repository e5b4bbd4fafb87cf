"""`rsb eval --policy-process shared|worker` in physics: the model loaded once for every worker
(counted: the test policy's factory appends a line per build), the records of the per-worker run, and
the shared server's faults: killed mid-run (the run stops in one line, records kept, the rerun
resumes) and Ctrl-C (the server stops with the run). The server binds 127.0.0.1 and stops with its run."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("websockets")

SUITE = "RSB-Math-4"
HELPERS = Path(__file__).parents[1] / "helpers"
SERVER_MODULE = "rsb_maniskill.policies.remote.server"


def _records(out: Path) -> list[dict]:
    path = out / "episodes.jsonl"
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _comparable(records: list[dict]) -> list[dict]:
    return sorted(({k: v for k, v in r.items() if k not in ("wall_s", "settings_id")} for r in records),
                  key=lambda r: r["seed"])


def _loads(log: Path) -> int:
    return log.read_text().count("\n") if log.exists() else 0


def _eval_cmd(out: Path, log: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "rsb_maniskill.cli", "eval", "counted_policies:make_counted", "-a", f"log={log}",
            "--suites", SUITE, "-o", "state", "--max-steps", "4", "--out", str(out), "-q", *extra]


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(HELPERS), *sys.path]))


def _server_pid(parent: int) -> int | None:
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            cmd = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == parent and SERVER_MODULE in cmd:
            return int(stat.parent.name)
    return None


def test_shared_loads_the_model_once_and_gives_the_per_worker_records(tmp_path, question_data):
    log = tmp_path / "loads.log"
    runs = {}
    for mode in ("worker", "shared"):
        out = tmp_path / mode
        done = subprocess.run(_eval_cmd(out, log, "-n", "4", "--num-procs", "4", "--policy-process", mode),
                              env=_env(), capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        runs[mode] = (_loads(log), done.stderr)
    assert runs["worker"][0] == 4  # one model a worker
    assert runs["shared"][0] == 4 + 1  # shared: loaded once more, for all four workers
    assert "batches formed" not in runs["shared"][1]  # -q: the server prints errors only
    assert _comparable(_records(tmp_path / "shared")) == _comparable(_records(tmp_path / "worker"))
    assert len(_records(tmp_path / "shared")) == 4


def _start_and_wait_for_a_record(cmd: list[str], out: Path, tmp_path: Path, name: str):
    err = open(tmp_path / f"{name}.err", "w")
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
    deadline = time.monotonic() + 240
    before = len(_records(out))
    while len(_records(out)) <= before and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    return proc, err


def test_server_killed_or_ctrl_c_stops_the_run_and_the_rerun_resumes(tmp_path, question_data):
    out, log = tmp_path / "run", tmp_path / "loads.log"
    cmd = _eval_cmd(out, log, "-n", "8", "--num-procs", "2", "--policy-process", "shared", "-a", "delay_s=0.4")
    # 1. the server killed mid-run: the workers stop, one line says why, the finished episodes stay
    proc, err = _start_and_wait_for_a_record(cmd, out, tmp_path, "killed")
    try:
        server = _server_pid(proc.pid)
        assert server is not None, "no shared server process under rsb eval"
        os.kill(server, signal.SIGKILL)
        assert proc.wait(timeout=120) == 1
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        err.close()
    text = (tmp_path / "killed.err").read_text()
    errors = [line for line in text.splitlines() if line.startswith("rsb eval: error")]
    assert len(errors) == 1 and "shared policy server" in errors[0] and "stopped" in errors[0], text[-2000:]
    kept = len(_records(out))
    assert 1 <= kept < 8
    # 2. Ctrl-C: the run ends as interrupted (130) and its server with it
    proc, err = _start_and_wait_for_a_record(cmd, out, tmp_path, "ctrl_c")
    try:
        server = _server_pid(proc.pid)
        os.kill(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=120) == 130
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        err.close()
    assert server is not None and not Path(f"/proc/{server}").exists() or \
        "Z" in Path(f"/proc/{server}/stat").read_text().rsplit(")", 1)[1].split()[0]
    # 3. the rerun resumes: every episode once
    done = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    seeds = [r["seed"] for r in _records(out)]
    assert len(seeds) == 8 and len(set(seeds)) == 8
