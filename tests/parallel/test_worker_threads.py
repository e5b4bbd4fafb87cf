"""Each local worker's thread pools (torch, OpenMP, BLAS) take its share of the cores, as does the shared
policy server's, and a user's OMP_NUM_THREADS wins: seen from inside the processes."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from rsb_maniskill.parallel.pool import ProcessPool
from rsb_maniskill.parallel.threads import THREAD_VARS, cpu_share, thread_env, usable_cpus

REPO = Path(__file__).resolve().parents[2]
HELPERS = REPO / "tests" / "helpers"


def _env_without_threads(**extra: str) -> dict[str, str]:
    """This environment without any thread variable (tests/conftest.py sets OMP_NUM_THREADS), helpers importable."""
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS}
    env["PYTHONPATH"] = os.pathsep.join([str(HELPERS), str(REPO), os.environ.get("PYTHONPATH", "")])
    return {**env, **extra}


def _reports(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_the_share_and_who_wins():
    assert cpu_share(2, cpus=8) == 4 and cpu_share(3, cpus=8) == 2
    assert cpu_share(16, cpus=2) == 1 and cpu_share(0, cpus=2) == 2  # never 0 threads; 0 processes: one
    assert cpu_share(1) == usable_cpus()
    assert thread_env(3, {}) == {name: "3" for name in THREAD_VARS}
    assert thread_env(3, {"OMP_NUM_THREADS": "5"}) == {}  # the user's OMP_NUM_THREADS: MKL and OpenBLAS follow it
    assert thread_env(3, {"MKL_NUM_THREADS": "5"}) == {"OMP_NUM_THREADS": "3", "OPENBLAS_NUM_THREADS": "3"}


def test_eval_workers_and_the_shared_server_take_a_workers_share(tmp_path):
    """`rsb eval` on two workers: each builds its policy with torch and the variables at cores // 2; with
    --policy-process shared the one process that builds it (the server) has that share too."""
    share = max(1, usable_cpus() // 2)
    for mode, builders in (("worker", 2), ("shared", 1)):
        report = tmp_path / f"{mode}.jsonl"
        res = subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", "eval", "thread_report:make_reporting",
                              "-a", f"log={tmp_path / 'builds.log'}", "-a", f"report={report}", "--suites",
                              "RSB-Direct-4", "-n", "2", "-o", "state", "--max-steps", "2", "--num-procs", "2",
                              "--policy-process", mode, "--out", str(tmp_path / mode), "-q"],
                             env=_env_without_threads(), capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, res.stderr[-2000:]
        lines = _reports(report)
        assert len({line["pid"] for line in lines}) == builders, lines
        for line in lines:
            assert line["torch_threads"] == share, (mode, line)
            assert line["env"] == {name: str(share) for name in THREAD_VARS}, (mode, line)


def test_a_users_omp_num_threads_wins_in_the_workers(monkeypatch):
    monkeypatch.syspath_prepend(str(HELPERS))
    from thread_report import pool_task

    for name in THREAD_VARS:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # one worker's share would be every core
    outcome = ProcessPool().run(pool_task, [0], lambda message: None)
    assert not outcome.errors, outcome.errors
    assert outcome.tasks[0].result == {"torch_threads": 1, "env": {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": None,
                                                                   "OPENBLAS_NUM_THREADS": None}}
    monkeypatch.delenv("OMP_NUM_THREADS")
    outcome = ProcessPool().run(pool_task, [0, 1, 2], lambda message: None)  # three workers: a third of the cores each
    share = str(max(1, usable_cpus() // 3))
    assert [t.result["env"] for t in outcome.tasks] == [{name: share for name in THREAD_VARS}] * 3
    assert "OMP_NUM_THREADS" not in os.environ  # set for the workers only
