"""Running a job's tasks in this process or in worker processes, how many, and stopping them cleanly.

Demonstration generation, evaluation and dataset builds split their work into tasks (a worker's
seeds), run ``target(task, emit)`` for each, and handle every ``emit(message)`` in this process,
which alone writes the output files. An :class:`Executor` hides where the tasks run:

- :class:`InProcess` runs them one after the other here; exceptions and Ctrl-C reach the caller
  as they are.
- :class:`ProcessPool` runs one spawned process per task. A worker's exception comes back as
  :attr:`TaskOutcome.error` (with its traceback), a worker that dies without a word as an error
  naming its exit code. On SIGINT / SIGTERM it asks the workers to stop (SIGTERM: each raises
  :class:`Interrupted` between two critical sections), keeps handling their messages until they
  are done, and reports which signal it got. Given GPUs, it deals its workers over them.
- ``RayExecutor`` (:mod:`rsb_maniskill.parallel.ray_pool`, the ``ray`` extra) runs one Ray task per
  task, on a Ray cluster or on a local one it starts.

:class:`InterruptGuard` turns SIGINT / SIGTERM into :class:`Interrupted`, never inside a
``critical()`` block (writing an episode or a record), so a stopped run never leaves half of one.

How many workers, and on which GPUs (``--num-procs auto``): :mod:`rsb_maniskill.parallel.plan`.
"""
from __future__ import annotations

import os
import queue as queue_module
import signal
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Protocol, Sequence

Emit = Callable[[Any], None]
Target = Callable[[Any, Emit], Any]



class Interrupted(KeyboardInterrupt):
    """SIGINT / SIGTERM received; carries the signal number."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


class InterruptGuard:
    """Turns SIGINT / SIGTERM into :class:`Interrupted`, deferred to the end of ``critical()`` blocks.

    Use it as a context manager in the main thread; the previous handlers come back on exit.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: int | None = None
        self.armed = True
        self._depth = 0
        self._old: dict = {}

    def __enter__(self) -> "InterruptGuard":
        for s in self.SIGNALS:
            self._old[s] = signal.signal(s, self._handler)
        return self

    def __exit__(self, *exc: object) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)

    def disarm(self) -> None:
        """Stop raising: later signals are only recorded (we are already shutting down)."""
        self.armed = False

    def _handler(self, signum: int, frame: Any) -> None:
        if self.received is not None:
            return
        self.received = signum
        if self.armed and self._depth == 0:
            raise Interrupted(signum)

    @contextmanager
    def critical(self) -> Iterator[None]:
        """A block a signal must not cut short; a signal received inside raises at its end."""
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
        if self.armed and self._depth == 0 and self.received is not None:
            raise Interrupted(self.received)


@dataclass
class TaskOutcome:
    """What became of one task: its return value, or why there is none."""

    index: int
    result: Any = None
    error: str | None = None  # the worker's exception and traceback, or how it died ("exited with code -9")
    interrupted: int | None = None  # the signal that stopped the worker, if one did


@dataclass
class RunOutcome:
    """One :class:`TaskOutcome` per task, in task order, and the signal that stopped the run."""

    tasks: list[TaskOutcome]
    interrupted: int | None = None  # the signal this process received, if one did

    @property
    def errors(self) -> dict[int, str]:
        return {t.index: t.error for t in self.tasks if t.error}


class Executor(Protocol):
    """Runs ``target(task, emit)`` for every task; each ``emit(message)`` reaches ``on_message`` here."""

    def run(self, target: Target, tasks: Sequence[Any], on_message: Emit) -> RunOutcome:
        """Messages of one task arrive in the order it emitted them."""


class InProcess:
    """Runs the tasks here, one after the other. Exceptions (Ctrl-C included) propagate."""

    def run(self, target: Target, tasks: Sequence[Any], on_message: Emit) -> RunOutcome:
        return RunOutcome([TaskOutcome(i, result=target(task, on_message)) for i, task in enumerate(tasks)])


class ProcessPool:
    """One spawned process per task (spawned: SAPIEN and torch state must not be forked).

    ``target`` and the tasks must be picklable (a module-level function and plain data).
    ``grace_s``: how long stopping workers may take after a signal before they are killed.
    ``devices``: GPUs as ``CUDA_VISIBLE_DEVICES`` names them; worker k starts with
    ``CUDA_VISIBLE_DEVICES=devices[k % len(devices)]``, so it renders (and runs CUDA) on that one
    GPU: set in its environment before its interpreter starts, hence before the simulator loads.
    """

    def __init__(self, grace_s: float = 120.0, poll_s: float = 0.5, devices: Sequence[str] = ()) -> None:
        self.grace_s = grace_s
        self.poll_s = poll_s
        self.devices = tuple(devices)

    def device_of(self, index: int) -> str | None:
        """The ``CUDA_VISIBLE_DEVICES`` of worker ``index`` (None: inherited as it is)."""
        return self.devices[index % len(self.devices)] if self.devices else None

    def run(self, target: Target, tasks: Sequence[Any], on_message: Emit) -> RunOutcome:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        q = ctx.Queue()
        procs = [ctx.Process(target=_worker_main, args=(target, task, i, q), daemon=True)
                 for i, task in enumerate(tasks)]
        done: dict[int, TaskOutcome] = {}
        silent_polls = [0] * len(procs)
        with InterruptGuard() as guard:
            try:
                for k, p in enumerate(procs):
                    with _environ(CUDA_VISIBLE_DEVICES=self.device_of(k)):  # the child inherits it
                        p.start()
                deadline = None
                while len(done) < len(procs):
                    try:
                        try:
                            kind, i, payload = q.get(timeout=self.poll_s)
                        except queue_module.Empty:
                            self._check_dead(procs, done, silent_polls)
                            if deadline is not None and time.monotonic() > deadline:
                                self._kill(procs, done, "killed: did not stop in time after the interruption")
                            continue
                        if kind == "done":
                            done[i] = payload
                        else:
                            with guard.critical():  # a record or an episode is written whole
                                on_message(payload)
                    except Interrupted:
                        guard.disarm()
                        for k, p in enumerate(procs):
                            if k not in done and p.is_alive():
                                os.kill(p.pid, signal.SIGTERM)
                        deadline = time.monotonic() + self.grace_s
            finally:
                guard.disarm()
                for k, p in enumerate(procs):
                    if k not in done and p.is_alive():  # leaving early (an error here): stop it
                        p.terminate()
                    p.join(timeout=10)
                    if p.is_alive():
                        p.kill()
                        p.join(timeout=10)
        return RunOutcome([done[i] for i in range(len(procs))], interrupted=guard.received)

    def _check_dead(self, procs: list, done: dict[int, TaskOutcome], silent_polls: list[int]) -> None:
        # A finished worker's last messages may still be in the pipe: give them a few polls.
        for k, p in enumerate(procs):
            if k not in done and p.exitcode is not None:
                silent_polls[k] += 1
                if silent_polls[k] > 4:
                    done[k] = TaskOutcome(k, error=f"exited with code {p.exitcode}")

    @staticmethod
    def _kill(procs: list, done: dict[int, TaskOutcome], why: str) -> None:
        for k, p in enumerate(procs):
            if k not in done:
                if p.is_alive():
                    p.kill()
                done[k] = TaskOutcome(k, error=why)


@contextmanager
def _environ(**values: str | None) -> Iterator[None]:
    """Sets environment variables (None: leaves one as it is) for the block, then restores them."""
    old = {k: os.environ.get(k) for k, v in values.items() if v is not None}
    os.environ.update({k: v for k, v in values.items() if v is not None})
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _worker_main(target: Target, task: Any, index: int, q: Any) -> None:
    """Process entry: runs ``target`` under a guard and always posts its outcome."""
    with InterruptGuard() as guard:
        def emit(message: Any) -> None:
            with guard.critical():
                q.put(("msg", index, message))

        try:
            outcome = TaskOutcome(index, result=target(task, emit))
        except Interrupted as err:
            outcome = TaskOutcome(index, interrupted=err.signum)
        except BaseException as err:  # noqa: BLE001  (reported to the parent, with the traceback)
            outcome = TaskOutcome(index, error=f"{err!r}\n{traceback.format_exc()}")
        guard.disarm()
        q.put(("done", index, outcome))


def deal(items: Sequence[Any], parts: int) -> list[list[Any]]:
    """Round-robin split of ``items`` into at most ``parts`` non-empty lists (item k to list k % n)."""
    n = max(1, min(parts, len(items)))
    return [list(items[k::n]) for k in range(n)]
