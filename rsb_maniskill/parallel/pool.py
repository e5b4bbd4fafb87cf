"""Running a job's tasks in this process or in worker processes, how many, and stopping them cleanly.

Demonstration generation, evaluation and dataset builds split their work into tasks (a worker's
seeds), run ``target(task, emit)`` for each, and handle every ``emit(message)`` in this process,
which alone writes the output files. An :class:`Executor` hides where the tasks run:

- :class:`InProcess` runs them one after the other here; exceptions and Ctrl-C reach the caller
  as they are.
- :class:`ProcessPool` runs each task in a spawned worker process. A worker's exception comes back
  as :attr:`TaskOutcome.error` (with its traceback), a worker that dies without a word as an error
  naming how (its exit code, or the signal that killed it). On SIGINT / SIGTERM it asks the workers
  to stop (SIGTERM: each raises :class:`Interrupted` between two critical sections), keeps handling
  their messages until they are done, and reports which signal it got. Given GPUs, it deals its
  workers over them. Used in a ``with`` block its workers outlive :meth:`ProcessPool.run`: a job of
  several parts (``rsb eval``'s suites) pays the workers' start-up (imports: seconds each) once.
- ``RayExecutor`` (:mod:`rsb_maniskill.parallel.ray_pool`, the ``ray`` extra) runs one Ray task per
  task, on a Ray cluster or on a local one it starts.

:class:`InterruptGuard` turns SIGINT / SIGTERM into :class:`Interrupted`, never inside a
``critical()`` block (writing an episode or a record), so a stopped run never leaves half of one,
and never inside a ``__del__`` (where Python would print it and drop it): held back, sent again.

How many workers, and on which GPUs (``--num-procs auto``): :mod:`rsb_maniskill.parallel.plan`.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Protocol, Sequence

from rsb_maniskill.parallel.threads import cpu_share, thread_env

Emit = Callable[[Any], None]
Target = Callable[[Any, Emit], Any]



class Interrupted(KeyboardInterrupt):
    """SIGINT / SIGTERM received; carries the signal number."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


RESEND_S = 0.05  # how soon a signal held back in a finalizer is sent again
# How long workers may take to stop after Ctrl-C / SIGTERM before they are killed: a worker stops
# between two critical sections (a record or an episode is written whole), so a well-behaved one is
# out in a second or two; one blocked in a call that ignores signals (a policy in native code) is
# killed, its finished records already sent. Ctrl-C stops any run within ~10 s, whatever it runs.
STOP_GRACE_S = 5.0
EXIT_WAIT_S = 10.0  # how long finished workers may take to exit (all together) before they are killed


def _in_finalizer(frame: Any) -> bool:
    """Whether ``frame`` runs inside a ``__del__``, where a raised exception is printed and lost."""
    while frame is not None:
        if frame.f_code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


_GUARDS: list["InterruptGuard"] = []  # the guards active in this process, innermost last


def from_a_signal(err: BaseException) -> bool:
    """Whether a KeyboardInterrupt may stand for a signal (Ctrl-C, SIGTERM) rather than be raised by
    code (a policy's ``raise KeyboardInterrupt``): under an :class:`InterruptGuard` a signal raises
    :class:`Interrupted`, so a plain KeyboardInterrupt there, with no signal received, is code's;
    without a guard any KeyboardInterrupt may be Python's own Ctrl-C."""
    if isinstance(err, Interrupted) or not _GUARDS:
        return True
    return _GUARDS[-1].received is not None


class InterruptGuard:
    """Turns SIGINT / SIGTERM into :class:`Interrupted`, deferred to the end of ``critical()`` blocks.

    Use it as a context manager in the main thread; the previous handlers come back on exit.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: int | None = None
        self.count = 0  # signals received: a second one while stopping means "stop now"
        self.armed = True
        self._depth = 0
        self._resend: threading.Timer | None = None  # a signal held back in a finalizer, sent again
        self._old: dict = {}

    def __enter__(self) -> "InterruptGuard":
        for s in self.SIGNALS:
            self._old[s] = signal.signal(s, self._handler)
        _GUARDS.append(self)
        return self

    def __exit__(self, *exc: object) -> None:
        self._cancel_resend()
        for s, h in self._old.items():
            signal.signal(s, h)
        if self in _GUARDS:
            _GUARDS.remove(self)

    def disarm(self) -> None:
        """Stop raising: later signals are only recorded (we are already shutting down)."""
        self.armed = False
        self._cancel_resend()

    def _handler(self, signum: int, frame: Any) -> None:
        if self._resend is None:
            self.count += 1
        if self.received is not None and self._resend is None:
            return
        self.received = signum
        self._cancel_resend()
        if self.armed and self._depth == 0:
            if _in_finalizer(frame):
                # Python prints an exception raised in a __del__ (SAPIEN's Scene has one) and drops
                # it: hold the signal back and send it again once the finalizer has returned.
                self._resend = threading.Timer(RESEND_S, os.kill, (os.getpid(), signum))
                self._resend.daemon = True
                self._resend.start()
                return
            raise Interrupted(signum)

    def signal_behind(self, err: BaseException) -> int | None:
        """The signal ``err`` stands for: an :class:`Interrupted`'s, or one received before any other
        exception. Native code may raise its own error in place of the one a signal handler raised
        inside it: pybind11 (SAPIEN) turns it into "incompatible constructor arguments"."""
        return err.signum if isinstance(err, Interrupted) else self.received

    def _cancel_resend(self) -> None:
        if self._resend is not None:
            self._resend.cancel()
            self._resend = None

    @contextmanager
    def critical(self) -> Iterator[None]:
        """A block a signal must not cut short; a signal received inside raises at its end."""
        self._depth += 1
        try:
            yield
        finally:
            self._depth -= 1
        if self.armed and self._depth == 0 and self.received is not None:
            self._cancel_resend()
            raise Interrupted(self.received)


@dataclass
class TaskOutcome:
    """What became of one task: its return value, or why there is none."""

    index: int
    result: Any = None
    error: str | None = None  # the worker's exception and traceback, or how it died ("exited with code -9")
    interrupted: int | None = None  # the signal that stopped the worker, if one did
    stuck: str | None = None  # the watched block (see :func:`watched`) it died or was killed in
    timed_out: float | None = None  # the limit that block outlasted (it was killed), if it did
    exit_code: int | None = None  # the exit code of a worker that died without an outcome


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


@dataclass
class _Worker:
    """A spawned worker process as its pool holds it: the pipes it is sent tasks on and sends its
    messages on, and the (since, limit) and label of the block it is in (see :func:`watched`)."""

    proc: Any
    tasks: Any  # this process's sending end: (target, task, index), or None to stop
    messages: Any  # this process's reading end: ("msg", message) ..., then ("done", TaskOutcome)
    watch: Any
    label: Any


class ProcessPool:
    """Runs each task in a spawned worker process (spawned: SAPIEN and torch state must not be forked),
    task k in worker k.

    ``target`` and the tasks must be picklable (a module-level function and plain data).
    ``grace_s``: how long stopping workers may take after a signal before they are killed (a
    second signal kills them at once).
    ``devices``: GPUs as ``CUDA_VISIBLE_DEVICES`` names them; worker k starts with
    ``CUDA_VISIBLE_DEVICES=devices[k % len(devices)]``, so it renders (and runs CUDA) on that one
    GPU: set in its environment before its interpreter starts, hence before the simulator loads.
    Each worker's thread pools (torch, OpenMP, BLAS) take its share of the cores, ``cores // workers``
    of the run that starts it (:mod:`rsb_maniskill.parallel.threads`; a user's ``OMP_NUM_THREADS`` wins).

    Alone, :meth:`run` starts its workers and stops them before it returns. In a ``with`` block they
    live until the block ends: each :meth:`run` hands its tasks to the workers already started
    (starting more only where it has more tasks), so their start-up (the interpreter, the imports)
    is paid once. A worker whose task did not end cleanly (it failed, died, was killed or
    interrupted) is stopped and a later run starts a fresh one in its place.

    Each worker writes to its own pipe, synchronously (a message sent is in the pipe, even if the
    worker then dies at once), and the parent waits on the pipes and on the processes' sentinels
    together: a dead worker is noticed as it dies. Workers die with this process (Linux:
    ``PR_SET_PDEATHSIG``; elsewhere a parent-pid watch). A block of the worker run under
    :func:`watched` that outlasts its limit gets the worker killed, and the outcome's ``stuck``
    names the block; a worker that dies inside one (``os._exit`` in a policy) names it too.
    """

    def __init__(self, grace_s: float = STOP_GRACE_S, poll_s: float = 0.5, devices: Sequence[str] = ()) -> None:
        self.grace_s = grace_s
        self.poll_s = poll_s
        self.devices = tuple(devices)
        self._workers: dict[int, _Worker] = {}
        self._kept = False  # in a with block: workers outlive run()

    def __enter__(self) -> "ProcessPool":
        self._kept = True
        return self

    def __exit__(self, *exc: object) -> None:
        self._kept = False
        self.close()

    def device_of(self, index: int) -> str | None:
        """The ``CUDA_VISIBLE_DEVICES`` of worker ``index`` (None: inherited as it is)."""
        return self.devices[index % len(self.devices)] if self.devices else None

    @property
    def started(self) -> int:
        """Worker processes running now (between two runs of a ``with`` block: the ones kept)."""
        return sum(w.proc.is_alive() for w in self._workers.values())

    def _worker(self, index: int, threads: int) -> _Worker:
        """Worker ``index``: the one kept from an earlier run if it still lives, else a new one whose
        thread pools run ``threads`` threads."""
        import multiprocessing as mp

        kept = self._workers.get(index)
        if kept is not None and kept.proc.is_alive():
            return kept
        if kept is not None:
            self._stop([self._workers.pop(index)])
        ctx = mp.get_context("spawn")
        task_r, task_w = ctx.Pipe(duplex=False)
        msg_r, msg_w = ctx.Pipe(duplex=False)
        watch = ctx.Array("d", 2, lock=False)  # (since, limit) of the watched block, 0: none
        label = ctx.Array("c", _LABEL_BYTES, lock=False)
        proc = ctx.Process(target=_worker_main, args=(task_r, msg_w, watch, label, os.getpid()), daemon=True)
        with _environ(CUDA_VISIBLE_DEVICES=self.device_of(index), **thread_env(threads)):  # the child inherits them
            proc.start()
        task_r.close()  # the child holds these ends
        msg_w.close()
        self._workers[index] = worker = _Worker(proc, task_w, msg_r, watch, label)
        return worker

    def run(self, target: Target, tasks: Sequence[Any], on_message: Emit) -> RunOutcome:
        from multiprocessing.connection import wait

        workers: list[_Worker] = []
        done: dict[int, TaskOutcome] = {}
        with InterruptGuard() as guard:
            try:
                share = cpu_share(len(tasks))  # the cores each worker's thread pools may take
                for k, task in enumerate(tasks):
                    workers.append(self._worker(k, share))
                    try:
                        workers[k].tasks.send((target, task, k))
                    except OSError:  # it died since it was kept: noticed below as dead
                        pass
                procs = [w.proc for w in workers]
                readers = {i: w.messages for i, w in enumerate(workers)}
                deadline = None
                while len(done) < len(procs):
                    try:
                        live = {readers[i]: i for i in readers if i not in done}
                        sentinels = {procs[i].sentinel: i for i in range(len(procs)) if i not in done}
                        ready = wait([*live, *sentinels], timeout=self.poll_s)
                        for conn in [c for c in ready if c in live]:
                            i = live[conn]
                            try:
                                kind, payload = conn.recv()
                            except (EOFError, OSError):
                                del readers[i]
                                continue
                            if kind == "done":
                                done[i] = payload
                            else:
                                with guard.critical():  # a record or an episode is written whole
                                    on_message(payload)
                        for s in [s for s in ready if s in sentinels]:
                            i = sentinels[s]
                            if i not in done and not (i in readers and readers[i].poll()):
                                done[i] = self._died(i, procs[i], workers[i].watch, workers[i].label)
                        self._check_watches(procs, done, [w.watch for w in workers], [w.label for w in workers])
                        if deadline is not None and (time.monotonic() > deadline or guard.count > 1):
                            self._kill(procs, done, "killed: did not stop in time after the interruption")
                    except Interrupted:
                        guard.disarm()
                        for k, p in enumerate(procs):
                            if k not in done and p.is_alive():
                                os.kill(p.pid, signal.SIGTERM)
                        deadline = time.monotonic() + self.grace_s
                        if any(k not in done for k in range(len(procs))):
                            print(f"stopping the workers (killed in {self.grace_s:g} s; Ctrl-C again: now)",
                                  file=sys.stderr, flush=True)
            finally:
                guard.disarm()
                for k, w in enumerate(workers):
                    if k not in done and w.proc.is_alive():  # leaving early (an error here): stop it
                        w.proc.terminate()
                clean = self._kept and guard.received is None
                unfit = [k for k, w in enumerate(workers) if not (clean and k in done and done[k].error is None
                                                                   and done[k].interrupted is None)]
                self._stop([self._workers.pop(k) for k in unfit if k in self._workers])
                if not self._kept:
                    self.close()
        return RunOutcome([done[i] for i in range(len(workers))], interrupted=guard.received)

    def close(self) -> None:
        """Stop every worker (each finishes what it is doing; one that does not exit is killed)."""
        workers, self._workers = list(self._workers.values()), {}
        self._stop(workers)

    @staticmethod
    def _stop(workers: list[_Worker]) -> None:
        for w in workers:
            try:
                w.tasks.send(None)  # no more tasks: its loop ends
            except OSError:
                pass
        exit_by = time.monotonic() + EXIT_WAIT_S  # one wait for all: a worker whose exit hangs
        for w in workers:                         # (a policy's thread) costs it once, not once each
            w.proc.join(timeout=max(0.0, exit_by - time.monotonic()))
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join(timeout=10)
            w.tasks.close()
            w.messages.close()

    @staticmethod
    def _died(index: int, proc: Any, watch: Any, label: Any) -> TaskOutcome:
        proc.join(timeout=5)
        code = proc.exitcode
        if watch[0]:  # it died inside a watched block: that block ended the process
            return TaskOutcome(index, error=exit_text(code), stuck=label.value.decode(errors="replace"),
                               exit_code=code)
        return TaskOutcome(index, error=exit_text(code), exit_code=code)

    @staticmethod
    def _check_watches(procs: list, done: dict[int, TaskOutcome], watches: list, labels: list) -> None:
        now = time.monotonic()
        for k, p in enumerate(procs):
            since, limit = watches[k][0], watches[k][1]
            if k not in done and since and limit and now - since > limit:
                what = labels[k].value.decode(errors="replace")
                if p.is_alive():
                    p.kill()
                    p.join(timeout=10)
                if p.exitcode is not None and p.exitcode != -signal.SIGKILL:
                    # it ended by itself (os._exit in the block) and its exit, slow under load, outlasted
                    # the limit: a death in the block, not a hang (a process already exiting keeps its code)
                    done[k] = ProcessPool._died(k, p, watches[k], labels[k])
                    continue
                done[k] = TaskOutcome(k, error=f"killed: {what} did not return within {limit:g} s",
                                      stuck=what, timed_out=limit)

    @staticmethod
    def _kill(procs: list, done: dict[int, TaskOutcome], why: str) -> None:
        for k, p in enumerate(procs):
            if k not in done:
                if p.is_alive():
                    p.kill()
                done[k] = TaskOutcome(k, error=why)


# Why a signal may have ended a worker, said beside its name (SIGKILL: nothing in the process could
# have said anything: the kernel's out-of-memory killer, or a user's or a scheduler's kill -9).
SIGNAL_CAUSES = {
    signal.SIGKILL: "likely out of memory, or killed by the user",
    signal.SIGSEGV: "a crash in native code",
    signal.SIGBUS: "a crash in native code",
    signal.SIGABRT: "aborted, often by native code",
}


def exit_text(code: int | None) -> str:
    """How a process that ended without an outcome ended: ``"exited with code 3"``, or for a
    negative code ``"killed by SIGKILL (likely out of memory, or killed by the user)"``."""
    if code is None or code >= 0:
        return f"exited with code {code}"
    try:
        sig = signal.Signals(-code)
    except ValueError:
        return f"killed by signal {-code}"
    cause = SIGNAL_CAUSES.get(sig)
    return f"killed by {sig.name}" + (f" ({cause})" if cause else "")


_LABEL_BYTES = 512
_WATCH: tuple[Any, Any] | None = None  # in a worker: its (since, limit) array and label, shared with the parent


@contextmanager
def watched(label: str, limit_s: float | None) -> Iterator[None]:
    """A block the parent watches: in a :class:`ProcessPool` worker, the parent kills the worker
    if the block runs longer than ``limit_s`` (None or 0: no limit, but a death inside it is still
    named ``label``). Elsewhere (this process) it does nothing."""
    if _WATCH is None:
        yield
        return
    times, text = _WATCH
    text.value = label.encode()[:_LABEL_BYTES - 1]
    times[1] = float(limit_s or 0)
    times[0] = time.monotonic()  # CLOCK_MONOTONIC: the same clock in every process of the machine
    try:
        yield
    finally:
        times[0] = 0.0


def die_with_parent(parent_pid: int) -> None:
    """This process is killed when ``parent_pid`` dies (even by kill -9): ``PR_SET_PDEATHSIG`` on
    Linux, else a thread that watches the parent's pid."""
    import threading

    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(1, signal.SIGKILL, 0, 0, 0) == 0:  # PR_SET_PDEATHSIG = 1
                if os.getppid() != parent_pid:  # the parent died before the call
                    os._exit(1)
                return
        except (OSError, AttributeError):
            pass

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="parent-watch").start()


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


def _worker_main(tasks: Any, conn: Any, watch: Any, label: Any, parent_pid: int) -> None:
    """Process entry: runs the tasks it is sent, one after the other, until it is sent None (or its
    parent is gone); each task's outcome is always sent back."""
    global _WATCH
    die_with_parent(parent_pid)
    _WATCH = (watch, label)
    while True:
        try:
            job = tasks.recv()
        except (EOFError, OSError, KeyboardInterrupt):  # the parent closed the pipe; a Ctrl-C between tasks
            job = None
        if job is None:
            conn.close()
            return
        _run_task(*job, conn, watch)


def _run_task(target: Target, task: Any, index: int, conn: Any, watch: Any) -> None:
    """One task under a guard: its messages, then its outcome, sent on ``conn``."""
    with InterruptGuard() as guard:
        def emit(message: Any) -> None:
            with guard.critical():
                conn.send(("msg", message))

        try:
            outcome = TaskOutcome(index, result=target(task, emit))
        except BaseException as err:  # noqa: BLE001  (reported to the parent, with the traceback)
            signum = guard.signal_behind(err)
            if signum is not None:
                outcome = TaskOutcome(index, interrupted=signum)
            else:
                outcome = TaskOutcome(index, error=f"{err!r}\n{traceback.format_exc()}")
        guard.disarm()
        watch[0] = 0.0
        conn.send(("done", outcome))


def deal(items: Sequence[Any], parts: int) -> list[list[Any]]:
    """Round-robin split of ``items`` into at most ``parts`` non-empty lists (item k to list k % n);
    a ``range`` splits into ranges (nothing listed)."""
    n = max(1, min(parts, len(items)))
    return [items[k::n] if isinstance(items, range) else list(items[k::n]) for k in range(n)]
