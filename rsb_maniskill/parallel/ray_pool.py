"""The Ray executor: a job's tasks as Ray tasks, on a Ray cluster or on a local one it starts.

The optional half of :mod:`rsb_maniskill.parallel.pool` (the ``ray`` extra: ``pip install
'rsb_maniskill[ray]'``): it runs the same ``target(task, emit)`` as the local executors, so
generation, evaluation and dataset builds run on a cluster unchanged. Messages come back through a
Ray queue and reach ``on_message`` in the driver, which alone writes the output files; a signal in
the driver cancels the tasks.
"""
from __future__ import annotations

import os
import signal
import socket
import time
import traceback
from typing import Any, Sequence

from rsb_maniskill.parallel.pool import (
    STOP_GRACE_S,
    Emit,
    Interrupted,
    InterruptGuard,
    RunOutcome,
    Target,
    TaskOutcome,
)

RAY_HINT = "the Ray executor needs `pip install 'rsb_maniskill[ray]'` (ray on every machine of the cluster)"
CONNECT_TIMEOUT_S = 10.0  # a cluster's head answers in milliseconds; Ray itself retries for minutes
START_HINT = "start one (ray start --head on its head machine) or leave --address out for a local cluster"


def check_address(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """Raise ValueError, in seconds, where nothing listens at ``--address HOST:PORT``.

    ``ray.init`` retries an unreachable head for minutes, printing its logs; a TCP connect tells a
    typo apart at once. ``auto`` is left to Ray, which fails at once without a cluster here."""
    if address == "auto":
        return
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ValueError(f"--address {address!r}: not a Ray cluster address; use HOST:PORT (e.g. 10.0.0.1:6379), "
                         "ray://HOST:PORT or auto")
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as err:
        why = "no answer in %g s" % timeout_s if isinstance(err, TimeoutError) else (err.strerror or str(err))
        raise ValueError(f"--address {address}: no Ray cluster answers there ({why.lower()}); {START_HINT}") from err


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
                 gpus_per_task: float = 0, grace_s: float = STOP_GRACE_S, poll_s: float = 0.2) -> None:
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
                try:
                    ray.init(address=self.address, **common)
                except ConnectionError as err:  # --address auto with no cluster on this machine
                    said = str(err).split(". ")[0].rstrip(".")  # Ray's first sentence: what it did not find
                    raise ValueError(f"--address {self.address}: {said}; {START_HINT}") from err
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
                        if deadline is not None and (time.monotonic() > deadline or guard.count > 1):
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
