"""The Ray executor: same records and episodes as the local executor, on a local Ray cluster
(started on 127.0.0.1 with 2 CPUs by the module fixture, shut down at its end)."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import ray

from rsb_maniskill.evaluation import eval_seeds  # noqa: E402
from rsb_maniskill.evaluation.jobs import EvalJob, run_job  # noqa: E402
from rsb_maniskill.evaluation.store import read_records  # noqa: E402
from rsb_maniskill.parallel.pool import ProcessPool  # noqa: E402
from rsb_maniskill.parallel.ray_pool import RayExecutor  # noqa: E402

pytestmark = pytest.mark.timeout(600)
TESTS = Path(__file__).parent
SUITE = "RSB-Math-4"


def emit_then_maybe_fail(task, emit):
    """Executor target: emits ``n`` numbered messages, then fails when asked to."""
    name, n, fail = task
    for k in range(n):
        emit((name, k))
    if fail:
        raise ValueError(f"{name} failed on purpose")
    return name.upper()


@pytest.fixture(scope="module")
def executor():
    # the workers import this module's targets: tests/ goes on their path (Ray passes PYTHONPATH on)
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(TESTS), *sys.path) if p)
    try:
        with RayExecutor(num_cpus=2) as ex:
            yield ex
    finally:
        if old is None:
            os.environ.pop("PYTHONPATH")
        else:
            os.environ["PYTHONPATH"] = old
    assert not ray.is_initialized()  # the local cluster is gone


def test_messages_results_and_errors_come_back_like_the_process_pools(executor):
    tasks = [("a", 5, False), ("b", 3, True), ("c", 0, False)]
    runs = {}
    for name, ex in (("pool", ProcessPool()), ("ray", executor)):
        messages = []
        runs[name] = (ex.run(emit_then_maybe_fail, tasks, messages.append), messages)
    (pool, pool_msgs), (ray_out, ray_msgs) = runs["pool"], runs["ray"]
    assert [t.result for t in ray_out.tasks] == [t.result for t in pool.tasks] == ["A", None, "C"]
    assert set(ray_out.errors) == set(pool.errors) == {1} and "failed on purpose" in ray_out.errors[1]
    assert sorted(ray_msgs) == sorted(pool_msgs)
    for name in "ab":  # each task's messages in the order it sent them
        assert [k for n, k in ray_msgs if n == name] == sorted(k for n, k in ray_msgs if n == name)
    assert ray_out.interrupted is None
    assert executor.workers() == 2


def _strip(records):
    return sorted(({k: v for k, v in r.items() if k != "wall_s"} for r in records), key=lambda r: r["seed"])


@pytest.mark.slow
def test_eval_records_equal_local_and_resume(executor, tmp_path):
    # the random policy: its draws follow each episode's seed, so records compare exactly, and no
    # motion plan is paid for (what is compared is where the episodes ran, not what they did)
    job = EvalJob(suite_id=SUITE, seeds=tuple(eval_seeds(SUITE, 6)), policy="random", label="random",
                  obs_mode="state", max_steps=60)
    # the local records in this process (that a pool of workers records the same is
    # tests/vector/test_vector_env.py's test_rsb_eval_k_envs_in_each_of_p_workers_gives_the_one_env_records)
    local = run_job(job, tmp_path / "local.jsonl", num_procs=1, progress=False)
    # a run that stopped after 2 episodes, resumed on Ray: each seed once, the same records
    first = EvalJob(**{**job.__dict__, "seeds": job.seeds[:2]})
    run_job(first, tmp_path / "ray.jsonl", num_procs=2, progress=False, executor=executor)
    on_ray = run_job(job, tmp_path / "ray.jsonl", num_procs=2, progress=False, executor=executor)
    assert _strip(on_ray) == _strip(local)
    assert sorted(r["seed"] for r in read_records(tmp_path / "ray.jsonl")) == list(job.seeds)


@pytest.mark.slow
def test_generate_same_episodes_as_local(executor, tmp_path):
    from rsb_maniskill.motionplan.generate import GenerateConfig, generate

    def make(out, ex, num_procs):
        cfg = GenerateConfig(env_id=SUITE, out=str(out), num=3, num_procs=num_procs, progress=False)
        summary = generate(cfg, ex)
        assert summary.completed == 3 and not summary.errors, summary
        return summary.path

    # local: in this process (two local processes make the same demos as one:
    # tests/motionplan/test_generate.py's test_two_processes_make_the_same_dataset_as_one)
    local, on_ray = make(tmp_path / "local", None, 1), make(tmp_path / "ray", executor, 2)
    eps = [json.loads(p.with_suffix(".json").read_text())["episodes"] for p in (local, on_ray)]
    assert [e["episode_seed"] for e in eps[0]] == [e["episode_seed"] for e in eps[1]]
    assert [e["instruction"] for e in eps[0]] == [e["instruction"] for e in eps[1]]
    with h5py.File(local) as a, h5py.File(on_ray) as b:
        assert sorted(a) == sorted(b)
        for key in a:
            assert np.array_equal(a[key]["actions"][:], b[key]["actions"][:])


def test_cli_eval_and_generate_on_ray(executor, tmp_path, capsys):
    from rsb_maniskill.cli import main

    out = tmp_path / "res"
    assert main(["eval", "random", "--suites", SUITE, "-n", "3", "--max-steps", "30", "--out", str(out), "-q",
                 "--executor", "ray"]) == 0
    assert sorted(r["seed"] for r in read_records(out / "episodes.jsonl")) == eval_seeds(SUITE, 3)
    capsys.readouterr()
    assert main(["generate", SUITE, "-n", "2", "--out", str(tmp_path / "demos"), "-q", "--executor", "ray"]) == 0
    printed = capsys.readouterr()
    assert "2" in printed.out
    # auto counts the cluster's CPUs (2), then gives each task at least 16 state episodes
    assert "workers: 1 Ray task (auto: Ray cluster of 2 CPUs, no camera to render; 2 episodes" in printed.err
    assert main(["generate", SUITE, "-n", "2", "--out", str(tmp_path / "two"), "-q", "--executor", "ray",
                 "--num-procs", "2"]) == 0
    assert "workers: 2 Ray tasks (--num-procs 2)" in capsys.readouterr().err
    assert ray.is_initialized()  # the cluster the fixture started is left alone


def test_address_needs_the_ray_executor(tmp_path, capsys):
    from rsb_maniskill.cli import main

    assert main(["eval", "blind", "--suites", SUITE, "-n", "1", "--out", str(tmp_path), "--address", "auto"]) == 2
    assert "--executor ray" in capsys.readouterr().err


def _closed_port() -> int:
    import socket

    with socket.socket() as s:  # bound and closed again: nothing listens there
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("command", [["eval", "blind", "--suites", SUITE, "-n", "1", "-q"],
                                     ["generate", SUITE, "-n", "1", "-q"], ["dataset", "build", "--suites", SUITE]])
def test_an_address_where_no_cluster_answers_is_one_line_in_seconds(command, tmp_path, capsys):
    """Ray retries an unreachable head for minutes; a TCP connect fails in a second, and nothing is written."""
    import time

    from rsb_maniskill.cli import main

    port = _closed_port()
    for address, said in ((f"127.0.0.1:{port}", f"--address 127.0.0.1:{port}: no Ray cluster answers there ("),
                          ("10.0.0.1", "--address '10.0.0.1': not a Ray cluster address; use HOST:PORT")):
        start = time.monotonic()
        code = main([*command, "--out", str(tmp_path / "out"), "--executor", "ray", "--address", address])
        err = capsys.readouterr().err
        assert code == 2 and time.monotonic() - start < 30, err
        lines = [line for line in err.splitlines() if ": error: " in line]
        assert len(lines) == 1 and said in lines[0] and "Traceback" not in err, err
        assert "leave --address out for a local cluster" in lines[0] or "HOST:PORT" in lines[0]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_sigterm_stops_a_ray_run_and_keeps_finished_episodes(tmp_path):
    """SIGTERM to `rsb eval --executor ray`: tasks cancelled, exit 130, whole records, resumable."""
    import signal
    import subprocess
    import time

    out = tmp_path / "res"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    cmd = [sys.executable, "-m", "rsb_maniskill.cli", "eval", "blind", "--suites", SUITE, "-n", "16",
           "--num-procs", "2", "--out", str(out), "-q", "--executor", "ray"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    records = out / "episodes.jsonl"
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and proc.poll() is None:
        if records.exists() and records.read_text().count("\n") >= 2:
            break
        time.sleep(0.1)
    assert proc.poll() is None, "the run ended before it could be stopped"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Rerun the same command to resume" in err
    kept = read_records(records)  # every line a whole record
    assert 2 <= len(kept) < 16 and len({r["seed"] for r in kept}) == len(kept)
