"""The CPUs this process may use, and each local process's share of them for its thread pools (torch's
intra-op pool, OpenMP, BLAS).

Each of these pools starts a thread a core in every process, so N worker processes on C cores would
run N x C threads spinning at their barriers for cores the other workers hold. Every worker
:class:`~rsb_maniskill.parallel.pool.ProcessPool` starts gets ``max(1, cores // workers)`` through
the variables below, set in its environment before its interpreter starts (torch, numpy's BLAS and
OpenMP read them as they load). A user's ``OMP_NUM_THREADS`` wins (MKL and OpenBLAS fall back to
it), as does any one of them set alone. Ray sets its workers' ``OMP_NUM_THREADS`` itself (their CPUs).
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Mapping

# OpenMP (torch's intra-op pool, libgomp), then the BLAS libraries numpy or torch may be built on
THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
CGROUP_ROOT = Path("/sys/fs/cgroup")


def cgroup_cpu_quota(root: Path = CGROUP_ROOT) -> float | None:
    """CPUs' worth of time a cgroup quota allows this process (a container's ``--cpus``; v2
    ``cpu.max`` or v1 ``cpu.cfs_quota_us``), None without a quota."""
    try:
        if (root / "cpu.max").is_file():
            quota, period = (root / "cpu.max").read_text().split()[:2]
            return None if quota == "max" else int(quota) / int(period)
        v1 = root / "cpu"
        if (v1 / "cpu.cfs_quota_us").is_file():
            quota = int((v1 / "cpu.cfs_quota_us").read_text())
            return None if quota < 0 else quota / int((v1 / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        pass
    return None


def usable_cpus(cgroup_root: Path = CGROUP_ROOT) -> int:
    """The CPUs this process may use: its affinity (the cpuset a container or a job scheduler
    gave it), capped by a cgroup CPU quota; not ``os.cpu_count()``, the whole machine's."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    quota = cgroup_cpu_quota(cgroup_root)
    return max(1, min(cpus, math.ceil(quota))) if quota else cpus


def cpu_share(processes: int, cpus: int | None = None) -> int:
    """Threads a process when ``processes`` local processes share ``cpus`` (None: the CPUs this
    process may use, its affinity capped by a cgroup quota, as ``--num-procs auto`` counts them)."""
    if cpus is None:
        cpus = usable_cpus()
    return max(1, cpus // max(1, processes))


def thread_env(threads: int, environ: Mapping[str, str] = os.environ) -> dict[str, str]:
    """The variables to add to a process's environment so that its pools run ``threads`` threads:
    none if the user set ``OMP_NUM_THREADS``, else those of :data:`THREAD_VARS` not set."""
    if "OMP_NUM_THREADS" in environ:
        return {}
    return {name: str(threads) for name in THREAD_VARS if name not in environ}
