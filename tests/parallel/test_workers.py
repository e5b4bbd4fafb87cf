"""The executors shared by generation and evaluation, the interrupt guard, and the choice of how
many workers (``--num-procs auto``) with faked CPU and GPU counts (no simulator)."""
from __future__ import annotations

import argparse
import os
import signal
import stat
import sys
import time

import pytest

from rsb_maniskill.parallel import plan as workers_plan
from rsb_maniskill.parallel import threads
from rsb_maniskill.parallel.plan import add_worker_args, plan_workers, resolve_workers
from rsb_maniskill.parallel.pool import InProcess, Interrupted, InterruptGuard, ProcessPool, deal


# Targets run in spawned processes: module-level, so they pickle by name.
def count(task, emit):
    name, n = task
    for i in range(n):
        emit((name, i))
    return f"{name} done"


def fail_on_b(task, emit):
    if task == "b":
        raise ValueError("bad task b")
    emit(task)
    return task


def die_hard(task, emit):
    if task == "dead":
        os._exit(3)
    return task


def signal_turned_into_a_type_error(task, emit):
    """What pybind11 did in SAPIEN's Pose(): the Interrupted its argument conversion met came out
    as its own TypeError."""
    try:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)
    except Interrupted:
        raise TypeError("__init__(): incompatible constructor arguments") from None
    return "no signal"


def cuda_visible_devices(task, emit):
    return os.environ.get("CUDA_VISIBLE_DEVICES")


def wait_for_stop(task, emit):
    """Emits once, then works until a signal stops it (Interrupted from the worker's guard)."""
    emit(("started", task))
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        time.sleep(0.01)
    return "never stopped"


def finish_up_on_stop(task, emit):
    """Like the generation worker: its own guard turns the signal into a clean, partial result."""
    with InterruptGuard():
        try:  # the emit too: the parent may signal as soon as the message is in the pipe
            emit(("started", task))
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                time.sleep(0.01)
        except Interrupted as err:
            return f"{task} saved its part after {signal.Signals(err.signum).name}"
    return "never stopped"


def test_in_process_runs_in_order_and_lets_errors_through():
    seen = []
    outcome = InProcess().run(count, [("a", 2), ("b", 1)], seen.append)
    assert seen == [("a", 0), ("a", 1), ("b", 0)]
    assert [t.result for t in outcome.tasks] == ["a done", "b done"] and outcome.interrupted is None
    with pytest.raises(ValueError, match="bad task b"):
        InProcess().run(fail_on_b, ["a", "b"], seen.append)


def test_process_pool_delivers_every_message_in_order_per_task():
    seen = []
    outcome = ProcessPool().run(count, [("a", 30), ("b", 20), ("c", 1)], seen.append)
    assert [t.result for t in outcome.tasks] == ["a done", "b done", "c done"]
    assert not outcome.errors and outcome.interrupted is None
    for name, n in (("a", 30), ("b", 20), ("c", 1)):
        assert [i for m, i in seen if m == name] == list(range(n))


def test_process_pool_reports_a_failed_and_a_dead_worker():
    seen = []
    outcome = ProcessPool().run(fail_on_b, ["a", "b", "c"], seen.append)
    assert sorted(seen) == ["a", "c"] and [t.result for t in outcome.tasks] == ["a", None, "c"]
    assert list(outcome.errors) == [1]
    assert "ValueError('bad task b')" in outcome.errors[1] and "Traceback" in outcome.errors[1]

    outcome = ProcessPool(poll_s=0.1).run(die_hard, ["ok", "dead"], seen.append)
    assert outcome.tasks[0].result == "ok"
    assert outcome.errors == {1: "exited with code 3"}


class _Exited:
    """A worker process as the parent sees it: already gone with ``code``, or alive until killed."""

    def __init__(self, code: int | None) -> None:
        self.exitcode = code

    def is_alive(self) -> bool:
        return self.exitcode is None

    def kill(self) -> None:
        self.exitcode = -signal.SIGKILL

    def join(self, timeout: float | None = None) -> None:
        pass


def test_a_death_in_a_watched_block_is_not_taken_for_a_hang():
    """os._exit in a policy call, and the process's exit (slow on a loaded machine) outlasts the
    call's limit before the parent sees the sentinel: a death in that call, with its exit code."""
    label = argparse.Namespace(value=b"act")
    long_ago = time.monotonic() - 10
    done = {}
    ProcessPool._check_watches([_Exited(3), _Exited(None)], done, [[long_ago, 2.0], [long_ago, 2.0]], [label, label])
    assert done[0].error == "exited with code 3" and done[0].exit_code == 3 and done[0].timed_out is None
    assert done[0].stuck == "act"
    assert done[1].error == "killed: act did not return within 2 s" and done[1].timed_out == 2.0


def test_a_signal_stops_the_workers_and_keeps_what_they_sent():
    """SIGTERM to this process (here: sent by itself once both workers run) reaches each worker."""
    for target, expect in ((wait_for_stop, None), (finish_up_on_stop, "saved its part after SIGTERM")):
        started = []

        def on_message(msg):
            started.append(msg)
            if len(started) == 2:
                os.kill(os.getpid(), signal.SIGTERM)  # deferred to the end of this message's handling

        previous = signal.getsignal(signal.SIGTERM)
        t0 = time.monotonic()
        outcome = ProcessPool().run(target, ["x", "y"], on_message)
        assert time.monotonic() - t0 < 30
        assert signal.getsignal(signal.SIGTERM) is previous  # the guard put the handler back
        assert outcome.interrupted == signal.SIGTERM and sorted(started) == [("started", "x"), ("started", "y")]
        for t in outcome.tasks:
            if expect is None:
                assert t.interrupted == signal.SIGTERM and t.result is None and t.error is None
            else:
                assert t.result.endswith(expect) and t.interrupted is None


def test_interrupt_guard_defers_signals_in_critical_blocks():
    with InterruptGuard() as guard:
        done = []
        with pytest.raises(Interrupted) as err:
            with guard.critical():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
                done.append("the write finished")
        assert done == ["the write finished"] and err.value.signum == signal.SIGINT
        assert isinstance(err.value, KeyboardInterrupt)
    with InterruptGuard() as guard:
        guard.disarm()
        os.kill(os.getpid(), signal.SIGTERM)  # only recorded: we are already shutting down
        time.sleep(0.05)
        assert guard.received == signal.SIGTERM


def test_an_error_native_code_raised_in_place_of_a_signal_is_the_signal():
    outcome = ProcessPool().run(signal_turned_into_a_type_error, ["t"], lambda m: None)
    assert outcome.tasks[0].interrupted == signal.SIGTERM and outcome.tasks[0].error is None
    with InterruptGuard() as guard:
        assert guard.signal_behind(TypeError("x")) is None  # no signal: an error is an error
        assert guard.signal_behind(Interrupted(signal.SIGINT)) == signal.SIGINT
        with pytest.raises(TypeError):
            signal_turned_into_a_type_error("t", None)
        assert guard.signal_behind(TypeError("x")) == signal.SIGTERM


class _SignalledWhileCollected:
    """Gets a signal while Python runs its finalizer, as SAPIEN's Scene.__del__ did under Ctrl-C."""

    def __del__(self) -> None:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the handler runs here, inside __del__


def test_interrupt_guard_holds_a_signal_got_in_a_finalizer_until_it_returns(monkeypatch):
    """Raised inside __del__, Interrupted would be printed ("Exception ignored") and lost."""
    unraisable = []
    monkeypatch.setattr(sys, "unraisablehook", unraisable.append)
    after = []
    with InterruptGuard() as guard:
        with pytest.raises(Interrupted) as err:
            obj = _SignalledWhileCollected()
            del obj
            after.append("the finalizer returned")
            time.sleep(5.0)  # the signal, sent again, ends this
        assert after == ["the finalizer returned"] and err.value.signum == signal.SIGINT
        assert guard.received == signal.SIGINT
    assert unraisable == []
    with InterruptGuard() as guard:  # held, then a write's end raises it: it is not raised twice
        with pytest.raises(Interrupted):
            obj = _SignalledWhileCollected()
            del obj
            with guard.critical():
                pass
        time.sleep(0.15)
    assert unraisable == []


def test_deal_is_round_robin():
    assert deal([1, 2, 3, 4, 5], 2) == [[1, 3, 5], [2, 4]]
    assert deal([1, 2], 4) == [[1], [2]]
    assert deal([1, 2, 3], 1) == [[1, 2, 3]]
    assert deal([], 3) == [[]]


def test_process_pool_deals_its_workers_over_the_gpus(monkeypatch):
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0,1,2,3")
    outcome = ProcessPool(devices=("2", "GPU-abc")).run(cuda_visible_devices, [None] * 3, print)
    assert [t.result for t in outcome.tasks] == ["2", "GPU-abc", "2"]
    assert os.environ["CUDA_VISIBLE_DEVICES"] == "0,1,2,3"  # this process keeps its own
    assert ProcessPool().run(cuda_visible_devices, [None], print).tasks[0].result == "0,1,2,3"


# ---------------------------------------------------------------- how many workers


@pytest.mark.parametrize("cpus, gpus, renders, executor, n, gpus_dealt, share", [
    (2, 0, False, "local", 2, 0, 0),      # state: one a CPU
    (2, 0, True, "local", 2, 0, 0),       # lavapipe renders on the CPUs: one a CPU
    (16, 0, False, "local", 16, 0, 0),
    (16, 1, False, "local", 16, 0, 0),    # no camera: the GPU does not count
    (16, 1, True, "local", 8, 1, 0),      # one GPU saturates at 4-8 rendering processes
    (16, 2, True, "local", 16, 2, 0),     # dealt over both
    (32, 2, True, "local", 16, 2, 0),
    (3, 2, True, "local", 3, 2, 0),       # fewer CPUs than 8 a GPU
    (1, 0, True, "local", 1, 0, 0),
    (0, 0, False, "local", 1, 0, 0),      # never fewer than one
    (64, 0, False, "ray", 64, 0, 0),      # the cluster's CPUs
    (64, 2, False, "ray", 64, 0, 0),      # state tasks ask for no GPU
    (64, 2, True, "ray", 16, 0, 0.125),   # 8 a GPU, an eighth of a GPU each
    (6, 2, True, "ray", 6, 0, 0.3333),    # all 6 at once, 3 a GPU
    (64, 0, True, "ray", 64, 0, 0),       # a CPU-only cluster renders with lavapipe: no GPU asked
])
def test_auto_plan(cpus, gpus, renders, executor, n, gpus_dealt, share):
    plan = plan_workers(cpus, gpus, renders, executor)
    assert (plan.num_procs, plan.gpus, plan.gpus_per_task) == (n, gpus_dealt, share)
    assert plan.line().startswith(f"workers: {n} ") and "(auto: " in plan.line()


def test_an_explicit_count_wins_and_the_gpus_are_still_shared():
    assert plan_workers(2, 0, False, requested=5).num_procs == 5
    plan = plan_workers(16, 2, True, requested=24)
    assert (plan.num_procs, plan.gpus) == (24, 2) and "--num-procs 24" in plan.line()
    plan = plan_workers(64, 2, True, "ray", requested=32)
    assert (plan.num_procs, plan.gpus_per_task) == (32, 0.0625)  # all 32 at once, 16 a GPU
    assert plan_workers(64, 2, True, "ray", requested=1).gpus_per_task == 1.0


def test_batched_gpu_envs_get_one_worker_or_one_ray_task_a_gpu():
    assert plan_workers(16, 1, True, num_envs=8).num_procs == 1
    plan = plan_workers(64, 4, False, "ray", num_envs=8)
    assert (plan.num_procs, plan.gpus_per_task) == (4, 1.0) and "4 GPUs" in plan.line()


def test_a_small_job_gets_fewer_workers_than_cpus():
    """A worker costs seconds to start: auto gives each at least 16 state (4 rendered) episodes."""
    assert plan_workers(16, 0, False, episodes=100).num_procs == 7
    assert plan_workers(16, 0, False, episodes=16).num_procs == 1
    assert plan_workers(16, 0, False, episodes=0).num_procs == 1  # a resumed job with nothing left
    assert plan_workers(2, 0, False, episodes=1000).num_procs == 2
    assert plan_workers(16, 2, True, episodes=6).num_procs == 2  # 4 rendered episodes a worker
    assert plan_workers(16, 0, False, episodes=4, requested=4).num_procs == 4  # an explicit count still wins
    assert "; 16 episodes, at least 16 a worker" in plan_workers(16, 0, False, episodes=16).line()
    assert plan_workers(64, 2, True, "ray", episodes=8).gpus_per_task == 1.0  # 2 tasks, a GPU each


def test_the_plan_line_says_what_and_why():
    assert plan_workers(2, 0, True).line() == "workers: 2 processes (auto: 2 usable CPUs, no NVIDIA GPU, rendering " \
                                              "on the CPU)"
    assert plan_workers(1, 0, False).line() == "workers: 1 process (auto: 1 usable CPU, no camera to render)"
    assert "dealt round-robin over 2 GPUs" in plan_workers(16, 2, True).line()
    assert "16 Ray tasks, 0.125 GPU each" in plan_workers(64, 2, True, "ray").line()


def test_usable_cpus_is_the_affinity_capped_by_a_cgroup_quota(monkeypatch, tmp_path):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 3, 5})
    monkeypatch.setattr(os, "cpu_count", lambda: 64)
    assert threads.usable_cpus(tmp_path) == 3  # the affinity, not the machine's 64
    (tmp_path / "cpu.max").write_text("max 100000\n")
    assert threads.usable_cpus(tmp_path) == 3
    (tmp_path / "cpu.max").write_text("150000 100000\n")  # docker --cpus 1.5
    assert threads.usable_cpus(tmp_path) == 2
    (tmp_path / "cpu.max").unlink()
    (tmp_path / "cpu").mkdir()
    (tmp_path / "cpu" / "cpu.cfs_quota_us").write_text("100000\n")  # cgroup v1, one CPU
    (tmp_path / "cpu" / "cpu.cfs_period_us").write_text("100000\n")
    assert threads.usable_cpus(tmp_path) == 1
    (tmp_path / "cpu" / "cpu.cfs_quota_us").write_text("-1\n")
    assert threads.usable_cpus(tmp_path) == 3


@pytest.mark.parametrize("count, visible, expect", [
    (0, None, []), (2, None, ["0", "1"]), (4, "2,3", ["2", "3"]), (4, "1,-1,2", ["1"]), (2, "", []),
    (2, "5", []), (2, "GPU-1a2b, GPU-3c4d", ["GPU-1a2b", "GPU-3c4d"]), (0, "0,1", []),
])
def test_visible_gpus_follow_cuda_visible_devices(count, visible, expect):
    assert workers_plan.visible_gpus(count, visible) == expect


def test_nvidia_gpus_asks_nvidia_smi(monkeypatch, tmp_path):
    smi = tmp_path / "nvidia-smi"
    smi.write_text("#!/bin/sh\necho 'GPU 0: NVIDIA H100 80GB HBM3 (UUID: GPU-a)'\n"
                   "echo 'GPU 1: NVIDIA H100 80GB HBM3 (UUID: GPU-b)'\n")
    smi.chmod(smi.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES", raising=False)
    assert workers_plan.nvidia_gpus() == ["0", "1"]
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "1")
    assert workers_plan.nvidia_gpus() == ["1"]
    monkeypatch.setenv("PATH", str(tmp_path / "nothing-here"))
    assert workers_plan.nvidia_gpus() == []


def _fake_machine(monkeypatch, cpus: int, gpus: list[str]) -> None:
    monkeypatch.setattr(workers_plan, "usable_cpus", lambda: cpus)
    monkeypatch.setattr(workers_plan, "nvidia_gpus", lambda: gpus)


def test_resolve_deals_rendering_workers_over_several_gpus(monkeypatch):
    lines = []
    _fake_machine(monkeypatch, 16, ["1", "3"])
    executor, n = resolve_workers(None, None, renders=True, log=lines.append)
    assert n == 16 and isinstance(executor, ProcessPool) and executor.devices == ("1", "3")
    assert lines == ["workers: 16 processes dealt round-robin over 2 GPUs (auto: 16 usable CPUs, 2 NVIDIA GPUs, "
                     "at most 8 rendering workers a GPU)"]
    assert resolve_workers(None, None, renders=False, log=lines.append) == (None, 16)
    assert resolve_workers(3, None, renders=True, log=lines.append)[1] == 3
    _fake_machine(monkeypatch, 16, ["0"])
    assert resolve_workers(None, None, renders=True, log=lines.append) == (None, 8)  # one GPU: nothing to deal


def test_resolve_prints_on_stderr(monkeypatch, capsys):
    _fake_machine(monkeypatch, 2, [])
    assert resolve_workers(None, None, renders=True) == (None, 2)
    out = capsys.readouterr()
    assert out.err == "workers: 2 processes (auto: 2 usable CPUs, no NVIDIA GPU, rendering on the CPU)\n"
    assert out.out == ""


class FakeRay:
    """What resolve_workers asks of a RayExecutor: the cluster's resources."""

    cpus_per_task = 1
    gpus_per_task = 0.0

    def __init__(self, resources):
        self.resources = resources

    def start(self):
        return self

    def cluster_resources(self):
        return self.resources


def test_resolve_on_ray_counts_the_cluster_and_asks_a_gpu_share():
    ray = FakeRay({"CPU": 48.0, "GPU": 3.0, "memory": 1e11})
    lines = []
    assert resolve_workers(None, ray, renders=True, log=lines.append) == (ray, 24)
    assert ray.gpus_per_task == 0.125 and lines[0].startswith("workers: 24 Ray tasks, 0.125 GPU each")
    assert resolve_workers(None, ray, renders=False, log=lines.append) == (ray, 48) and ray.gpus_per_task == 0
    cpu_only = FakeRay({"CPU": 8.0})
    assert resolve_workers(None, cpu_only, renders=True, log=lines.append) == (cpu_only, 8)
    assert cpu_only.gpus_per_task == 0  # a GPU ask would never be scheduled there


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rsb generate")
    add_worker_args(p)
    return p


def test_num_procs_is_auto_by_default_and_a_number_wins():
    assert _parser().parse_args([]).num_procs is None
    assert _parser().parse_args(["--num-procs", "auto"]).num_procs is None
    assert _parser().parse_args(["--num-procs", "3"]).num_procs == 3
    args = _parser().parse_args(["--executor", "ray", "--address", "auto"])
    assert (args.executor, args.address) == ("ray", "auto")


@pytest.mark.parametrize("bad", ["0", "-2", "abc", "1.5"])
def test_a_bad_num_procs_is_one_line_and_exit_2(bad, capsys):
    with pytest.raises(SystemExit) as stop:
        _parser().parse_args(["--num-procs", bad])
    err = capsys.readouterr().err
    assert stop.value.code == 2
    assert err == f"rsb generate: error: --num-procs must be auto or a whole number of workers >= 1, got {bad!r}\n"


@pytest.mark.parametrize("bad", ["0", "abc"])
def test_rsb_generate_rejects_a_bad_num_procs(bad, capsys, tmp_path):
    from rsb_maniskill.cli import main

    assert main(["generate", "RSB-Math-4", "-n", "1", "--num-procs", bad, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--num-procs must be auto" in err and not list(tmp_path.iterdir())


def test_rsb_generate_prints_its_choice(capsys, tmp_path):
    from rsb_maniskill.cli import main

    assert main(["generate", "RSB-Math-4", "-n", "1", "--out", str(tmp_path), "-q"]) == 0
    err = capsys.readouterr().err
    assert f"workers: 1 process (auto: {workers_plan.usable_cpus()} usable CPU" in err
    assert "no camera to render; 1 episode, at least 16 a worker)" in err


def test_address_auto_without_a_cluster_is_one_line(tmp_path):
    """`--address auto` where this machine runs no cluster: Ray's own error, as one line, before anything
    is written. (Not beside the Ray executor's tests: Ray's auto joins any cluster it sees running here,
    the one their fixture starts included.)"""
    import subprocess
    import sys

    import psutil

    if any(p.info["name"] == "gcs_server" for p in psutil.process_iter(["name"])):
        pytest.skip("a Ray cluster runs on this machine: --address auto joins it")

    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    env.update(PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    out = tmp_path / "res"
    proc = subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", "eval", "blind", "--suites", "RSB-Math-4",
                           "-n", "1", "--out", str(out), "-q", "--executor", "ray", "--address", "auto"],
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("rsb eval: error: --address auto: Could not find any "
                                                           "running Ray instance; start one"), proc.stderr
    assert "Traceback" not in proc.stderr and not out.exists()

