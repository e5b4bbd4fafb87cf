"""``rsb eval --policy-process shared``: one policy server process for every worker.

The policy is built once, in a server process of its own (``server.py``, batching); each worker
builds the ``remote`` policy pointed at it over loopback instead of its own copy. The server stops
with the run (and by itself if the run dies: ``--parent-pid``); a worker that dies only frees its
rows. A policy call that outlasts the run's ``--policy-timeout`` fails in the server, as it would
in a worker.

Threads: the server's pools take one worker's share of the cores (``cores // workers``, as each
worker's: :mod:`rsb_maniskill.parallel.threads`), not every core. With no wait its forward passes
overlap the other workers' physics, and a pool with more threads than free cores stalls at its
barriers (on a busy machine a forward pass then takes a scheduler tick or more, many times its cost).
With the default wait the workers it answers are mostly idle while it computes, so a larger pool
would gain at most those cores on the forward pass alone.

``auto`` shares only where it is meant to pay: a policy that declares a model (``heavy``) computed on
a GPU (``gpu``, ``registry.py``) on a machine with CUDA, with more than one worker. On the CPU a copy
a worker was faster than one shared, each process's threads its share of the cores: the copies
compute at once on their own cores, while the server computes a batch on one share with the workers
waiting, each call paying the round trip (and, with the default wait, the wait for the last worker)
(``benchmarks/policy_server.py``, recorded in ``benchmarks/results/policy_server.json``).
"""
from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import threading
from typing import Any, Callable, Mapping

from rsb_maniskill.parallel.threads import cpu_share, thread_env
from rsb_maniskill.policies.errors import PolicyError
from rsb_maniskill.policies.registry import is_heavy, policy_spec, runs_on_gpu
from rsb_maniskill.policies.remote.batching import DEFAULT_MAX_BATCH, DEFAULT_MAX_WAIT_MS

POLICY_PROCESSES = ("auto", "shared", "worker")
LOOPBACK = "127.0.0.1"
STOP_WAIT_S = 10.0  # how long a stopped server may take to print its batch sizes before it is killed
CHECK_WAIT_S = 2.0  # after workers failed: how long the server may take to be seen gone
REPLY_GRACE_S = 5.0  # a worker waits this much past the policy timeout: the server's error line comes first
MEASURED = "benchmarks/results/policy_server.json"  # where the CPU rule comes from


def cuda_available() -> bool:
    """Whether this machine has a CUDA device torch can use (torch imported only when asked)."""
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency
        return False
    return bool(torch.cuda.is_available())


def choose(mode: str, spec: str, num_procs: int, local: bool = True, cuda: bool | None = None) -> tuple[str, str]:
    """``(shared | worker, why)`` for ``--policy-process mode``; ValueError (one line) for a policy
    ``shared`` cannot serve. ``cuda``: whether a GPU is there (None: asked of torch, when it matters)."""
    if mode not in POLICY_PROCESSES:
        raise ValueError(f"--policy-process must be one of {', '.join(POLICY_PROCESSES)}, got {mode!r}")
    if mode == "worker":
        return "worker", "--policy-process worker"
    reads_sim = policy_spec(spec).needs_env
    if mode == "shared":
        if reads_sim:
            raise ValueError(f"--policy-process shared: policy {spec!r} is built with each worker's env (it reads "
                             "the simulator), so it cannot be served; use --policy-process worker")
        if not local:
            raise ValueError("--policy-process shared serves the policy over loopback to local workers; with "
                             "--executor ray use --policy-process worker (or serve it yourself: rsb serve, then "
                             "rsb eval remote)")
        return "shared", "--policy-process shared"
    if reads_sim:
        return "worker", f"{spec} is built with each worker's env"
    if not local:
        return "worker", "Ray workers are not on this machine's loopback"
    if not is_heavy(spec):
        return "worker", f"{spec} declares no model to share (heavy)"
    if num_procs <= 1:
        return "worker", "one worker: one copy either way"
    if not runs_on_gpu(spec):
        return "worker", (f"{spec}'s model runs on the CPU (it declares no gpu), where a copy a worker was faster than "
                          f"one shared ({MEASURED}); --policy-process shared loads it once anyway")
    if not (cuda_available() if cuda is None else cuda):
        return "worker", (f"{spec}'s model runs on a GPU and this machine has none (CUDA): on the CPU a copy a worker "
                          f"was faster ({MEASURED})")
    return "shared", f"{spec}'s model runs on the GPU: loaded once and batched for the {num_procs} workers"


class SharedServer:
    """A policy server process on a free loopback port; ``client_kwargs`` are the ``remote`` policy's
    arguments that reach it. ``max_batch`` / ``max_wait_ms``: ``rsb serve``'s; ``policy_timeout``: the
    run's (a call past it fails its rows); ``quiet``: the server prints errors only (``rsb eval -q``);
    ``workers``: the local workers it serves (its thread pools take one worker's share of the cores).
    It inherits ``rsb --debug`` (``RSB_DEBUG``). A context manager: stopped (SIGTERM, then killed) on exit."""

    def __init__(self, spec: str, policy_kwargs: Mapping[str, Any], *, max_batch: int = DEFAULT_MAX_BATCH,
                 max_wait_ms: float = DEFAULT_MAX_WAIT_MS, start_timeout: float | None = None,
                 policy_timeout: float | None = None, quiet: bool = False, workers: int = 1,
                 log: Callable[[str], None] | None = None) -> None:
        self.spec = spec
        self.policy_timeout = policy_timeout
        self.log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        cmd = [sys.executable, "-m", "rsb_maniskill.policies.remote.server", spec, "--host", LOOPBACK, "--port", "0",
               "--max-batch", str(max_batch), "--max-wait-ms", str(max_wait_ms), "--parent-pid", str(os.getpid()),
               "--policy-timeout", str(policy_timeout or 0)]
        if quiet:
            cmd.append("--quiet")
        for key, value in policy_kwargs.items():
            cmd += ["-a", f"{key}={json.dumps(value)}"]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))  # the specs this run resolves
        env.update(thread_env(cpu_share(workers), env))  # a worker's share (see the module's docstring)
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, env=env, text=True)
        self.port = self._read_port(start_timeout)

    def _read_port(self, timeout: float | None) -> int:
        from rsb_maniskill.policies.remote.server import READY

        lines: queue.Queue[str | None] = queue.Queue()

        def pump() -> None:  # the server's stdout: its ready line, then whatever it prints
            assert self.proc.stdout is not None
            for line in self.proc.stdout:
                lines.put(line)
            lines.put(None)

        threading.Thread(target=pump, name="rsb-shared-server-stdout", daemon=True).start()
        while True:
            try:
                line = lines.get(timeout=timeout)
            except queue.Empty:
                self.stop()
                raise PolicyError(f"the shared policy server built no policy within {timeout:g} s "
                                  "(--policy-timeout)", policy=self.spec) from None
            if line is None:
                code = self.proc.wait()
                raise PolicyError(f"the shared policy server exited (code {code}) before serving: its error is "
                                  "above", policy=self.spec)
            if line.startswith(READY):
                return int(line.rsplit(":", 1)[1])
            print(line, end="")  # the policy's own prints while it loads

    def client_kwargs(self) -> dict[str, Any]:
        """The ``remote`` policy's arguments: this server, episode starts marked (rows reset on them); a
        reply waited for a little past the policy timeout, so that the server's error line comes first."""
        return {"host": LOOPBACK, "port": self.port, "mark_episode_start": True, "connect_timeout": 60.0,
                "request_timeout": None if self.policy_timeout is None else self.policy_timeout + REPLY_GRACE_S}

    def dead(self) -> str | None:
        """None while serving; else one line saying it stopped."""
        code = self.proc.poll()
        return None if code is None else f"the shared policy server (pid {self.proc.pid}) stopped with exit code {code}"

    def check(self) -> None:
        """Raise a PolicyError naming the server when it is gone (called when workers failed). A server
        that answers its health check is serving: the workers' error was the policy's, said at once; one
        that does not (killed: it closed their connections as it exited) is given a moment to be reaped."""
        if self.proc.poll() is None and self._healthy():
            return
        try:
            self.proc.wait(timeout=CHECK_WAIT_S)
        except subprocess.TimeoutExpired:
            return
        line = self.dead()
        if line:
            raise PolicyError(f"{line}; the workers lost their policy", policy=self.spec)

    def _healthy(self) -> bool:
        """``GET /healthz`` answers 200 (the server's handshake check, before any policy call)."""
        import http.client

        conn = http.client.HTTPConnection(LOOPBACK, self.port, timeout=1.0)
        try:
            conn.request("GET", "/healthz")
            return conn.getresponse().status == 200
        except (OSError, http.client.HTTPException):
            return False
        finally:
            conn.close()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def __enter__(self) -> "SharedServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
