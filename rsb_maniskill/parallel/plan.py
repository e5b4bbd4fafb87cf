"""How many workers a run starts, and on which GPUs: ``--num-procs auto``, the default of ``rsb eval``,
``rsb generate`` and ``rsb dataset build``.

:func:`plan_workers` decides, a pure function of the usable CPUs, the NVIDIA GPUs, whether the
obs mode renders and the job's size; :func:`resolve_workers` counts them on this machine (or the
Ray cluster), applies the plan to the executor and prints it in one line; :func:`add_worker_args`
is the command-line side (``--num-procs auto|N``, ``--executor``, ``--address``). Measured
reasons for the numbers: docs/gpu.md, docs/scale.md.
"""
from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

from rsb_maniskill.debug import plural
from rsb_maniskill.parallel.pool import Executor, ProcessPool
from rsb_maniskill.parallel.threads import usable_cpus

if TYPE_CHECKING:
    from rsb_maniskill.parallel.ray_pool import RayExecutor

EXECUTORS = ("local", "ray")  # --executor: local processes, or Ray tasks (the ray extra)
AUTO = "auto"  # --num-procs auto: the worker count from the machine (plan_workers)
# Rendering with CPU physics saturates one NVIDIA GPU at 4-8 processes: on an H100 (2026-11-25)
# 1 / 4 / 8 / 16 processes rendered 161 / 425-442 / 402-536 / 342 rgb steps/s in all (docs/gpu.md).
# 8 keeps the GPU busy while the others do CPU work between renders (a policy, the expert, video
# encoding); 16 only queue on the driver.
RENDER_PROCS_PER_GPU = 8
# A spawned worker costs seconds to start (imports, its env; 5-10 s on 2 cores) that a few episodes
# don't repay: auto starts one per so many episodes at most. A state episode is ~0.5 s, a rendered
# one several seconds (benchmarks/auto_workers.py, docs/scale.md).
MIN_STATE_EPISODES_PER_WORKER = 16
MIN_RENDERED_EPISODES_PER_WORKER = 4
NO_RENDER_OBS_MODES = ("none", "state", "state_dict")  # ManiSkill obs modes that read no camera
# --num-envs auto: K CPU envs a process, every camera of the K rendered in one call (rsb_maniskill.vector).
# On an H100 (16 cores, 2026-11-26) with rendering every step, 16 processes x K = 4 / 8 / 16 ran 3,210 /
# 2,236 / 2,369 rgb env-steps/s, against 253-425 for one env a process: the CPU physics is then the
# bound, so one process a CPU and K = 4 (docs/gpu.md). Without an NVIDIA GPU (lavapipe) or without
# cameras there is nothing to batch: K = 1.
RENDER_ENVS_PER_PROC = 4


def obs_mode_renders(obs_mode: str) -> bool:
    """Whether envs with this ManiSkill obs mode render cameras (rgb, depth, sensor_data, ...)."""
    return obs_mode not in NO_RENDER_OBS_MODES


def visible_gpus(count: int, cuda_visible_devices: str | None) -> list[str]:
    """The ``count`` GPUs of the machine as a process with this ``CUDA_VISIBLE_DEVICES`` sees them,
    named as that variable names them (its entries, else ``0 .. count-1``). Like CUDA, stops at
    the first entry that names no GPU (``-1``, an index out of range)."""
    if count < 1:
        return []
    if cuda_visible_devices is None:
        return [str(i) for i in range(count)]
    out = []
    for entry in (e.strip() for e in cuda_visible_devices.split(",")):
        if not ((entry.isdigit() and int(entry) < count) or entry.startswith(("GPU-", "MIG-"))):
            break
        out.append(entry)
    return out


def nvidia_gpus() -> list[str]:
    """The NVIDIA GPUs this process may use (:func:`visible_gpus`); ``[]`` without an NVIDIA driver.
    Asks ``nvidia-smi -L``: no torch import and no CUDA context in the main process."""
    smi = shutil.which("nvidia-smi")
    if smi is None:
        return []
    try:
        listing = subprocess.run([smi, "-L"], capture_output=True, text=True, timeout=20).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    count = sum(line.startswith("GPU ") for line in listing.splitlines())
    return visible_gpus(count, os.environ.get("CUDA_VISIBLE_DEVICES"))


@dataclass(frozen=True)
class WorkerPlan:
    """How many workers a run starts and where they render; ``why`` says what decided it."""

    num_procs: int
    executor: str = "local"
    gpus: int = 0  # local: the NVIDIA GPUs the workers are dealt to, round-robin, one GPU each
    gpus_per_task: float = 0.0  # ray: the share of a GPU each task asks for (Ray places the tasks)
    why: str = ""

    def line(self) -> str:
        """The one line a run prints, e.g. ``workers: 2 processes (auto: 2 usable CPUs, no NVIDIA GPU)``."""
        n = self.num_procs
        one, many = ("Ray task", "Ray tasks") if self.executor == "ray" else ("process", "processes")
        where = ""
        if self.gpus_per_task:
            where = f", {self.gpus_per_task:g} GPU each"
        elif self.gpus > 1 and n > 1:
            where = f" dealt round-robin over {self.gpus} GPUs"
        return f"workers: {n} {one if n == 1 else many}{where} ({self.why})"


def plan_num_envs(gpus: int, renders: bool, requested: int | None = None) -> tuple[int, str]:
    """``--num-envs auto|K`` on the CPU backend: (K, why). K envs a process render all their cameras
    in one call where an NVIDIA GPU renders (:data:`RENDER_ENVS_PER_PROC`); with lavapipe, or with no
    camera to render, batching gains nothing: one env a process."""
    if requested is not None:
        return requested, f"--num-envs {requested}"
    if not renders:
        return 1, "auto: no camera to render, one env a process"
    if not gpus:
        return 1, "auto: rendering on the CPU (lavapipe), batching gains nothing; one env a process"
    return RENDER_ENVS_PER_PROC, (f"auto: {plural(gpus, 'NVIDIA GPU')} render the cameras of {RENDER_ENVS_PER_PROC} "
                                  "envs a process in one call (H100: 16 processes x 4 envs, 3,210 rgb env-steps/s)")


def _started(n: int, why: str, requested: int | None, episodes: int | None) -> tuple[int, str]:
    """An explicit ``--num-procs N`` over more workers than episodes: the workers that start (one an
    episode at most; the seeds are dealt one a worker), said so, not the N asked for."""
    if requested is not None and episodes is not None and max(1, episodes) < n:
        return max(1, episodes), f"{why}; {plural(episodes, 'episode')}: one worker each at most"
    return n, why


def plan_workers(cpus: int, gpus: int, renders: bool, executor: str = "local", *,
                 requested: int | None = None, num_envs: int = 1, episodes: int | None = None,
                 gpu_physics: bool = True) -> WorkerPlan:
    """The workers of a run, from ``cpus`` usable CPUs and ``gpus`` NVIDIA GPUs (of this machine,
    or with ``executor="ray"`` of the cluster), whether its obs mode ``renders`` and, when known,
    how many ``episodes`` a job has. Pure: the caller counts (:func:`resolve_workers`).

    - ``requested`` (an explicit ``--num-procs N``) wins; the GPUs are still shared out.
    - ``num_envs > 1`` (batched envs on GPU physics): one process, or on Ray one task per GPU.
    - ``num_envs > 1`` on CPU physics (``gpu_physics=False``, a vector env a worker): one worker per
      CPU, with no cap per GPU (one render call a batch leaves the CPU physics as the bound); a small
      job gets one worker per ``num_envs`` episodes at most.
    - rendering on NVIDIA GPUs: one worker per CPU, at most :data:`RENDER_PROCS_PER_GPU` per GPU
      (the GPU, not the cores, is the limit); locally dealt round-robin over the GPUs, on Ray each
      task asks for its share of a GPU, so that Ray spreads them over the GPUs and nodes.
    - otherwise (state observations, or rendering on the CPU with lavapipe): one worker per CPU.
      The main process is not given a CPU of its own: it mostly waits for the workers' messages
      (``benchmarks/auto_workers.py`` measures its CPU time).
    - a small job gets fewer: one worker per :data:`MIN_STATE_EPISODES_PER_WORKER` episodes
      (:data:`MIN_RENDERED_EPISODES_PER_WORKER` rendered ones) at most.
    """
    cpus, gpus = max(1, cpus), max(0, gpus)
    ray = executor == "ray"
    where = f"Ray cluster of {plural(cpus, 'CPU')}" if ray else plural(cpus, "usable CPU")
    if renders or (ray and num_envs > 1):
        where += ", " + (plural(gpus, "GPU") if ray else
                         plural(gpus, "NVIDIA GPU") if gpus else "no NVIDIA GPU")
    if num_envs > 1 and not gpu_physics:  # K CPU envs a worker, rendered in one call
        n = requested or cpus
        why = (f"--num-procs {requested}" if requested else f"auto: {where}, {num_envs} envs a process "
               "rendered in one call: the CPU physics is the bound")
        if requested is None and episodes is not None and -(-max(1, episodes) // num_envs) < n:
            n = -(-max(1, episodes) // num_envs)
            why += f"; {plural(episodes, 'episode')}, at least {num_envs} a worker"
        n, why = _started(n, why, requested, episodes)
        if not (renders and gpus):
            return WorkerPlan(n, executor, why=why)
        if ray:
            return WorkerPlan(n, executor, gpus_per_task=math.floor(min(1.0, gpus / n) * 1e4) / 1e4, why=why)
        return WorkerPlan(n, executor, gpus=gpus, why=why)
    if num_envs > 1:  # GPU physics: one batched worker drives a whole GPU
        if ray:
            return WorkerPlan(requested or max(1, gpus), executor, gpus_per_task=1.0,
                              why=f"--num-envs {num_envs}: one task a GPU; {where}")
        return WorkerPlan(requested or 1, executor, why=f"--num-envs {num_envs}: one process drives the GPU envs")
    if requested is not None:
        n, why = requested, f"--num-procs {requested}" + (f"; {where}" if renders and gpus else "")
    elif not renders:
        n, why = cpus, f"auto: {where}, no camera to render"
    elif not gpus:
        n, why = cpus, f"auto: {where}, rendering on the CPU"
    else:
        n = min(cpus, RENDER_PROCS_PER_GPU * gpus)
        why = f"auto: {where}, at most {RENDER_PROCS_PER_GPU} rendering workers a GPU"
    per = MIN_RENDERED_EPISODES_PER_WORKER if renders else MIN_STATE_EPISODES_PER_WORKER
    if requested is None and episodes is not None and -(-max(1, episodes) // per) < n:
        n = -(-max(1, episodes) // per)
        why += f"; {plural(episodes, 'episode')}, at least {per} a worker"
    n, why = _started(n, why, requested, episodes)
    if not (renders and gpus):
        return WorkerPlan(n, executor, why=why)
    if ray:  # a share that lets all n run at once, rounded down to Ray's resource precision
        return WorkerPlan(n, executor, gpus_per_task=math.floor(min(1.0, gpus / n) * 1e4) / 1e4, why=why)
    return WorkerPlan(n, executor, gpus=gpus, why=why)


def resolve_num_envs(requested: int | None, renders: bool, log: Callable[[str], None] | None = None) -> int:
    """``--num-envs auto|K`` on the CPU backend: :func:`plan_num_envs` on this machine's NVIDIA GPUs;
    prints the choice and why in one line (``log``, default stderr) when it was auto."""
    k, why = plan_num_envs(len(nvidia_gpus()) if renders and requested is None else 0, renders, requested)
    if requested is None:
        (log or _stderr)(f"envs: {k} a process ({why})")
    return k


def resolve_workers(requested: int | None, executor: RayExecutor | None, renders: bool, *, num_envs: int = 1,
                    episodes: int | None = None, log: Callable[[str], None] | None = None,
                    gpu_physics: bool = True) -> tuple[Executor | None, int]:
    """The executor and worker count of a run: ``--num-procs`` (``requested``; None is auto) and
    :func:`plan_workers` on this machine's usable CPUs and NVIDIA GPUs, or on the Ray cluster's.
    Prints the plan in one line (``log``, default stderr).

    Returns ``(executor, num_procs)``: the Ray executor given, set to ask for the plan's GPU share a
    task; locally a :class:`ProcessPool` dealing the workers over the GPUs when they render on
    several, else None (the caller's usual choice of :class:`InProcess` or :class:`ProcessPool`)."""
    if executor is not None:
        res = executor.start().cluster_resources()
        plan = plan_workers(int(res.get("CPU", 1) // executor.cpus_per_task), int(res.get("GPU", 0)), renders,
                            "ray", requested=requested, num_envs=num_envs, episodes=episodes, gpu_physics=gpu_physics)
        executor.gpus_per_task = plan.gpus_per_task
    else:
        gpus = nvidia_gpus() if renders and (num_envs == 1 or not gpu_physics) else []
        plan = plan_workers(usable_cpus(), len(gpus), renders, requested=requested, num_envs=num_envs,
                            episodes=episodes, gpu_physics=gpu_physics)
        if plan.gpus > 1 and plan.num_procs > 1:
            executor = ProcessPool(devices=gpus)
    (log or _stderr)(plan.line())
    return executor, plan.num_procs


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


# ------------------------------------------------------------------ command-line flags


def parse_num_procs(text: str) -> int | None:
    """A ``--num-procs`` value: ``auto`` (None, decided by :func:`plan_workers`) or a count >= 1."""
    if text.strip().lower() == AUTO:
        return None
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise ValueError(f"must be {AUTO} or a whole number of workers >= 1, got {text!r}")
    return n


class _NumProcs(argparse.Action):
    """``--num-procs auto|N``; a bad value is one line and exit status 2 (no usage dump)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        try:
            setattr(namespace, self.dest, parse_num_procs(values))
        except ValueError as err:
            parser.exit(2, f"{parser.prog}: error: {option_string} {err}\n")


def add_worker_args(parser: Any) -> None:
    """``--num-procs auto|N``, ``--executor`` and ``--address``: how many workers, and where. The
    command reads them back with ``resolve_workers(args.num_procs, executor_from_args(...), renders)``."""
    parser.add_argument("--num-procs", action=_NumProcs, default=None, metavar="auto|N",
                        help="worker processes, or Ray tasks. auto (default): one per usable CPU, at most "
                             f"{RENDER_PROCS_PER_GPU} per NVIDIA GPU when cameras render (dealt over the GPUs; "
                             "with Ray, each task asks for its share of a GPU); the run prints its choice. "
                             "N: exactly N")
    add_executor_args(parser)


def add_executor_args(parser: Any) -> None:
    """``--executor`` and ``--address``, the same for every command that runs workers."""
    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help="where workers run: local processes (default) or Ray tasks (pip install "
                             "'rsb_maniskill[ray]'); with ray, --num-procs auto counts the cluster's CPUs and GPUs")
    parser.add_argument("--address", default=None,
                        help="Ray cluster to join (e.g. 10.0.0.1:6379 or auto); without it Ray starts a "
                             "local cluster for this run")


def executor_from_args(executor: str, address: str | None, gpus_per_task: float = 0) -> RayExecutor | None:
    """The executor the flags name: None for local (the caller picks InProcess or ProcessPool).

    Raises ValueError on ``--address`` without ``--executor ray`` or where no cluster answers, and
    ImportError without Ray."""
    if executor == "local":
        if address:
            raise ValueError("--address names a Ray cluster: add --executor ray")
        return None
    from rsb_maniskill.parallel.ray_pool import RayExecutor, check_address  # the optional half: only when asked for

    RayExecutor._ray()  # fail now, with the install hint, not after the first suite
    executor = RayExecutor(address=address, gpus_per_task=gpus_per_task)
    if address:  # join the cluster now: a wrong address fails in seconds, before anything is written
        check_address(address)
        executor.start()
    return executor
