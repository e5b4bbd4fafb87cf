"""A ProcessPool in a ``with`` block keeps its workers from one run to the next (a run of several
jobs starts them once); a worker whose task did not end cleanly is replaced; how a dead worker is named."""
from __future__ import annotations

import os
import signal
import time

import pytest

from rsb_maniskill.parallel.pool import (
    Interrupted,
    InterruptGuard,
    ProcessPool,
    exit_text,
    from_a_signal,
)


# Targets run in spawned processes: module-level, so they pickle by name.
def pid(task, emit):
    emit(task)
    return os.getpid()


def pid_or_fail(task, emit):
    if task == "fail":
        raise ValueError("bad task")
    if task == "exit":
        os._exit(3)
    if task == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
        time.sleep(30)
    return os.getpid()


def _gone(pids, timeout=15.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not [p for p in pids if os.path.exists(f"/proc/{p}") and
                open(f"/proc/{p}/stat").read().split(") ")[1][0] != "Z"]:
            return True
        time.sleep(0.05)
    return False


def test_workers_outlive_a_run_in_a_with_block_and_stop_at_its_end():
    seen = []
    with ProcessPool() as pool:
        first = pool.run(pid, ["a", "b"], seen.append)
        assert pool.started == 2
        second = pool.run(pid, ["c", "d", "e"], seen.append)  # one more task: one more worker
        third = pool.run(pid, ["f"], seen.append)
    pids = [t.result for t in first.tasks]
    assert [t.result for t in second.tasks][:2] == pids and third.tasks[0].result == pids[0]
    assert second.tasks[2].result not in pids
    assert sorted(seen) == list("abcdef")
    assert pool.started == 0 and _gone(pids + [second.tasks[2].result])


def test_alone_a_run_stops_its_workers():
    pool = ProcessPool()
    outcome = pool.run(pid, ["a"], lambda m: None)
    assert pool.started == 0 and _gone([outcome.tasks[0].result])


def test_a_worker_whose_task_failed_or_died_is_replaced_the_others_kept():
    with ProcessPool(poll_s=0.1) as pool:
        first = pool.run(pid_or_fail, ["ok", "fail", "exit"], lambda m: None)
        assert "ValueError('bad task')" in first.tasks[1].error and first.tasks[2].error == "exited with code 3"
        assert pool.started == 1
        again = pool.run(pid_or_fail, ["ok", "ok", "ok"], lambda m: None)
    assert again.tasks[0].result == first.tasks[0].result  # kept
    assert all(isinstance(t.result, int) for t in again.tasks) and len({t.result for t in again.tasks}) == 3


def test_a_worker_killed_by_sigkill_is_named_so_with_the_likely_cause():
    outcome = ProcessPool(poll_s=0.1).run(pid_or_fail, ["kill"], lambda m: None)
    assert outcome.tasks[0].exit_code == -signal.SIGKILL
    assert outcome.tasks[0].error == "killed by SIGKILL (likely out of memory, or killed by the user)"
    assert exit_text(-signal.SIGSEGV) == "killed by SIGSEGV (a crash in native code)"
    assert exit_text(-signal.SIGHUP) == "killed by SIGHUP" and exit_text(0) == "exited with code 0"


def wait_then_pid(task, emit):
    emit(("started", task))
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        time.sleep(0.01)
    return os.getpid()


def test_after_a_signal_the_next_run_starts_fresh_workers():
    """An interrupted run's workers may hold a signal: they are stopped, not handed the next task."""
    started = []

    def on_message(msg):
        started.append(msg)
        if len(started) == 2:
            os.kill(os.getpid(), signal.SIGTERM)  # deferred to the end of this message's handling

    with ProcessPool() as pool:
        t0 = time.monotonic()
        outcome = pool.run(wait_then_pid, ["x", "y"], on_message)
        assert time.monotonic() - t0 < 30 and outcome.interrupted == signal.SIGTERM
        assert pool.started == 0
        assert [t.result for t in pool.run(pid, ["z"], lambda m: None).tasks][0] > 0


def test_a_keyboard_interrupt_under_a_guard_without_a_signal_is_codes():
    assert from_a_signal(KeyboardInterrupt())  # no guard: it may be Python's own Ctrl-C
    with InterruptGuard():
        assert not from_a_signal(KeyboardInterrupt())  # raised by code: no signal came
        assert from_a_signal(Interrupted(signal.SIGINT))
        with pytest.raises(Interrupted):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)
        assert from_a_signal(KeyboardInterrupt())  # a signal came: it may stand for it
    assert from_a_signal(KeyboardInterrupt())
