"""The executors shared by generation and evaluation, and the interrupt guard (no simulator)."""
from __future__ import annotations

import os
import signal
import time

import pytest

from rsb_maniskill.workers import InProcess, Interrupted, InterruptGuard, ProcessPool, deal


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
        emit(("started", task))
        try:
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


def test_deal_is_round_robin():
    assert deal([1, 2, 3, 4, 5], 2) == [[1, 3, 5], [2, 4]]
    assert deal([1, 2], 4) == [[1], [2]]
    assert deal([1, 2, 3], 1) == [[1, 2, 3]]
    assert deal([], 3) == [[]]
