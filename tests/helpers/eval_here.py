"""``rsb eval``'s worker tasks run in the test's own process, for the tests of what a run writes and
says (records, summaries, resumes, one-line errors) rather than of its processes. Each ``rsb eval``
otherwise spawns a worker that imports ManiSkill and torch anew (3-4 CPU-s a run, more than a short
run's episodes); here the test process imports them once. The same jobs run (``run_shard`` on the
same shards, one after the other), on :class:`~rsb_maniskill.parallel.pool.InProcess`.

What only real workers show stays tested with them: signals, kill -9, exit codes, a policy's
``os._exit`` or hang (tests/acceptance/test_faults*.py), an error crossing the pipe
(test_bad_input.py's worker case), workers started once a run (tests/commands/test_eval_run.py) and
tests/parallel/. Use the ``eval_workers_here`` fixture (tests/conftest.py), or :func:`workers_here`
around a module fixture's run."""
from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import pytest


@contextmanager
def workers_here() -> Iterator[None]:
    """Within the block, the ProcessPool ``rsb eval`` opens is this process (it imports the class
    when it runs, so the patched one)."""
    from rsb_maniskill.parallel import pool

    class Here(pool.InProcess):
        """InProcess as ``rsb eval`` holds its pool: in a ``with`` block."""

        def __enter__(self) -> "Here":
            return self

        def __exit__(self, *exc: object) -> None:
            return None

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(pool, "ProcessPool", Here)
        yield
