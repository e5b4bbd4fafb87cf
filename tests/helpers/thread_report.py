"""A policy whose factory reports the thread pools of the process that builds it (a worker, or the
shared server): one JSON line a build, appended to ``log``. Importable by workers and by a server
process with tests/helpers/ on PYTHONPATH."""
from __future__ import annotations

import json
import os

from counted_policies import CountedPolicy

THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def make_reporting(log: str, report: str) -> CountedPolicy:
    """``report``: where the line goes; ``log``: the counted policy's build log."""
    import torch

    line = {"pid": os.getpid(), "torch_threads": torch.get_num_threads(),
            "env": {name: os.environ.get(name) for name in THREAD_VARS}}
    with open(report, "a") as f:
        f.write(json.dumps(line) + "\n")
    return CountedPolicy(log)


def pool_task(task: object, emit) -> dict:
    """A :class:`~rsb_maniskill.parallel.pool.ProcessPool` target: the worker's variables and torch threads."""
    import torch

    return {"torch_threads": torch.get_num_threads(), "env": {name: os.environ.get(name) for name in THREAD_VARS}}
