"""Running a job's tasks in this process or in worker processes, and stopping them cleanly.

Demonstration generation and evaluation both split their work into tasks (a worker's seeds),
run ``target(task, emit)`` for each, and handle every ``emit(message)`` in this process, which
alone writes the output files. An :class:`Executor` hides where the tasks run:

- :class:`InProcess` runs them one after the other here; exceptions and Ctrl-C reach the caller
  as they are.
- :class:`ProcessPool` runs one spawned process per task. A worker's exception comes back as
  :attr:`TaskOutcome.error` (with its traceback), a worker that dies without a word as an error
  naming its exit code. On SIGINT / SIGTERM it asks the workers to stop (SIGTERM: each raises
  :class:`Interrupted` between two critical sections), keeps handling their messages until they
  are done, and reports which signal it got.

- :class:`RayExecutor` runs one Ray task per task, on a Ray cluster (``address``) or on a local
  one it starts; messages come back through a Ray queue, and a signal cancels the tasks.

:class:`InterruptGuard` turns SIGINT / SIGTERM into :class:`Interrupted`, never inside a
``critical()`` block (writing an episode or a record), so a stopped run never leaves half of one.
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
    """

    def __init__(self, grace_s: float = 120.0, poll_s: float = 0.5) -> None:
        self.grace_s = grace_s
        self.poll_s = poll_s

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
                for p in procs:
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


RAY_HINT = "the Ray executor needs `pip install 'rsb_maniskill[ray]'` (ray on every machine of the cluster)"


class RayExecutor:
    """One Ray task per task, on the cluster at ``address`` or, without one, a local cluster.

    The local cluster (``num_cpus`` CPUs, bound to 127.0.0.1, no dashboard) is started on first
    use and shut down by :meth:`close` (or at the end of a ``with`` block); a cluster that was
    already connected is left as it is. Each task asks for ``cpus_per_task`` CPUs and
    ``gpus_per_task`` GPUs and is never retried (its messages would repeat). ``emit`` puts
    messages on a Ray queue that :meth:`run` drains here, so each reaches ``on_message`` in this
    process, in the order its task sent them. On SIGINT / SIGTERM the tasks are cancelled (a
    KeyboardInterrupt in each, which their own guards defer past critical blocks), their last
    messages are still handled, and tasks not done ``grace_s`` later are killed.
    ``target`` and the tasks must be picklable and importable on every machine (install
    rsb_maniskill there); files a task writes are on its machine (use a shared filesystem).
    """

    def __init__(self, address: str | None = None, num_cpus: int = 2, cpus_per_task: float = 1,
                 gpus_per_task: float = 0, grace_s: float = 120.0, poll_s: float = 0.2) -> None:
        self.address = address
        self.num_cpus = num_cpus
        self.cpus_per_task = cpus_per_task
        self.gpus_per_task = gpus_per_task
        self.grace_s = grace_s
        self.poll_s = poll_s
        self._started = False

    @staticmethod
    def _ray() -> Any:
        try:
            import ray
        except ImportError as err:
            raise ImportError(RAY_HINT) from err
        return ray

    def start(self) -> Any:
        """Connect to the cluster (or start the local one) unless this process already is; returns ray."""
        import logging

        ray = self._ray()
        if not ray.is_initialized():
            # workers import the code the driver runs: pass on its import path and data directory
            env_vars = {k: os.environ[k] for k in ("PYTHONPATH", "RSB_DATA_DIR") if k in os.environ}
            common = dict(include_dashboard=False, logging_level=logging.WARNING, log_to_driver=True,
                          runtime_env={"env_vars": env_vars} if env_vars else None)
            if self.address:
                ray.init(address=self.address, **common)
            else:
                ray.init(num_cpus=self.num_cpus, _node_ip_address="127.0.0.1", **common)
            self._started = True
        return ray

    def workers(self) -> int:
        """How many tasks the cluster runs at once (its CPUs, or GPUs, over what a task asks)."""
        res = self.start().cluster_resources()
        if self.gpus_per_task:
            return max(1, int(res.get("GPU", 0) // self.gpus_per_task))
        return max(1, int(res.get("CPU", 1) // self.cpus_per_task))

    def close(self) -> None:
        """Shut the local cluster down (a cluster this executor did not connect to is left alone)."""
        if self._started:
            self._ray().shutdown()
            self._started = False

    def __enter__(self) -> "RayExecutor":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def run(self, target: Target, tasks: Sequence[Any], on_message: Emit) -> RunOutcome:
        ray = self.start()
        from ray.util.queue import Queue

        q = Queue(actor_options={"num_cpus": 0})
        remote = ray.remote(num_cpus=self.cpus_per_task, num_gpus=self.gpus_per_task, max_retries=0)(_ray_task)
        refs = [remote.remote(target, task, i, q) for i, task in enumerate(tasks)]
        index = {ref: i for i, ref in enumerate(refs)}
        done: dict[int, TaskOutcome] = {}
        with InterruptGuard() as guard:
            try:
                deadline = None
                while len(done) < len(refs):
                    try:
                        pending = [r for r in refs if index[r] not in done]
                        ready, _ = ray.wait(pending, num_returns=len(pending), timeout=self.poll_s)
                        # a task's messages are queued before it returns: drain, then mark it done
                        self._drain(q, on_message, guard)
                        for ref in ready:
                            done[index[ref]] = self._outcome(ray, ref, index[ref])
                        if deadline is not None and time.monotonic() > deadline:
                            for ref in pending:
                                ray.cancel(ref, force=True)
                            deadline = None
                    except Interrupted:
                        guard.disarm()
                        for ref in refs:
                            if index[ref] not in done:
                                ray.cancel(ref)
                        deadline = time.monotonic() + self.grace_s
            finally:
                guard.disarm()
                for ref in refs:
                    if index[ref] not in done:  # leaving early (an error here): stop it
                        ray.cancel(ref, force=True)
                ray.kill(q.actor)
        return RunOutcome([done[i] for i in range(len(refs))], interrupted=guard.received)

    @staticmethod
    def _drain(q: Any, on_message: Emit, guard: InterruptGuard) -> None:
        while True:
            batch = q.get_nowait_batch(q.qsize())
            if not batch:
                return
            for message in batch:
                with guard.critical():  # a record or an episode is written whole
                    on_message(message)

    @staticmethod
    def _outcome(ray: Any, ref: Any, i: int) -> TaskOutcome:
        from ray.exceptions import TaskCancelledError

        try:
            return ray.get(ref)
        except TaskCancelledError:
            return TaskOutcome(i, interrupted=signal.SIGINT)
        except Exception as err:  # noqa: BLE001  (a task that died: its machine, its process)
            return TaskOutcome(i, error=f"{type(err).__name__}: {err}")


def _ray_task(target: Target, task: Any, index: int, q: Any) -> TaskOutcome:
    """Ray task entry: runs ``target``; its exception or interruption comes back in the outcome."""
    try:
        return TaskOutcome(index, result=target(task, q.put))
    except KeyboardInterrupt as err:  # Interrupted, or Ray's cancellation
        return TaskOutcome(index, interrupted=getattr(err, "signum", signal.SIGINT))
    except BaseException as err:  # noqa: BLE001  (reported to the driver, with the traceback)
        return TaskOutcome(index, error=f"{err!r}\n{traceback.format_exc()}")


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


EXECUTORS = ("local", "ray")


def add_executor_args(parser: Any) -> None:
    """``--executor`` and ``--address``, the same for ``rsb generate`` and ``rsb eval``."""
    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help="where workers run: local processes (default) or Ray tasks (pip install "
                             "'rsb_maniskill[ray]'); with ray, --num-procs defaults to the cluster's CPUs")
    parser.add_argument("--address", default=None,
                        help="Ray cluster to join (e.g. 10.0.0.1:6379 or auto); without it Ray starts a "
                             "local cluster for this run")


def executor_from_args(executor: str, address: str | None, gpus_per_task: float = 0) -> RayExecutor | None:
    """The executor the flags name: None for local (the caller picks InProcess or ProcessPool).

    Raises ValueError on ``--address`` without ``--executor ray`` and ImportError without Ray."""
    if executor == "local":
        if address:
            raise ValueError("--address names a Ray cluster: add --executor ray")
        return None
    RayExecutor._ray()  # fail now, with the install hint, not after the first suite
    return RayExecutor(address=address, gpus_per_task=gpus_per_task)
