"""Shared fixtures. Question data: the real GSM8K / MMLU-Pro files when ``RSB_DATA_DIR`` names them (CI
sets it to the shared copies), else the small fixtures written for the tests, so that no test that
only needs *some* questions skips on a machine without the datasets."""
from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from net_helpers import silent_proxy_server

FIXTURE_DATA = Path(__file__).resolve().parent / "fixtures" / "semantic_data"


DURATIONS = Path(__file__).resolve().parent / "durations.json"


def _file_seconds() -> dict[str, float]:
    """Seconds each test file cost in one whole-suite run (tests/durations.json, written by
    scripts/test_durations.py from a run's --junitxml or --durations 0 output); {} without the file."""
    try:
        return dict(json.loads(DURATIONS.read_text(encoding="utf-8"))["files"])
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def pytest_collection_modifyitems(config, items) -> None:
    """The costliest files first, each file's tests in their own order. `make test` hands whole files
    to its workers in collection order (xdist --dist loadfile --no-loadscope-reorder): the long ones go
    first, so none starts last and runs alone at the end. Only the order depends on the measured
    seconds; a file the durations file does not know keeps its place after them."""
    seconds = _file_seconds()
    items.sort(key=lambda item: -seconds.get(item.nodeid.split("::", 1)[0], 0))  # stable: the rest keep order


_STARTED = time.monotonic()
_LOAD_AT_START = os.getloadavg()[0]


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    """The guard on the suite's cost: its wall time, the cores and workers it ran on and the machine's
    load (README's test command says what to expect on 2 cores; tests/durations.json, what each file costs)."""
    if hasattr(config, "workerinput"):  # an xdist worker: the controller reports
        return
    cores = len(os.sched_getaffinity(0))
    workers = len(getattr(config.option, "tx", None) or []) or 1
    seconds = time.monotonic() - _STARTED
    wall = f"{seconds / 60:.1f} min" if seconds >= 60 else f"{seconds:.0f} s"
    terminalreporter.write_line(
        f"rsb: suite wall time {wall} on {cores} cores, {workers} worker{'s' * (workers > 1)} "
        f"(1-min load {_LOAD_AT_START:.1f} at start, {os.getloadavg()[0]:.1f} at end)")


def pytest_configure(config) -> None:
    """Tests run as from a terminal: a run started in a script's background (``make test &``)
    inherits SIGINT ignored, and so would every command a test starts; its Ctrl-C tests would then
    pass without the command ever being interrupted. (Runs in each xdist worker too.)"""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    _share_the_cores(config)


def _share_the_cores(config) -> None:
    """OpenMP and BLAS thread pools (torch, scikit-learn, numpy) of the cores' share of each test
    worker: `make test` runs a worker a core plus one, and a pool of a thread a core in each spins at
    its barriers for the threads the other workers hold (the audit tests took twice the CPU time with
    two threads a worker on two cores as with one). Set here, in the controller before its workers
    start, so that they and every command a test starts inherit it; a user's OMP_NUM_THREADS wins. The
    rule is the one `rsb`'s own worker processes follow (rsb_maniskill.parallel.threads)."""
    if hasattr(config, "workerinput"):
        return
    from rsb_maniskill.parallel.threads import cpu_share, thread_env

    workers = len(getattr(config.option, "tx", None) or []) or 1
    os.environ.update(thread_env(cpu_share(workers)))


@pytest.fixture
def eval_workers_here():
    """``rsb eval`` called in this process runs its worker tasks here too, not in a spawned worker
    that imports ManiSkill anew (tests/helpers/eval_here.py: where the processes stay tested)."""
    from eval_here import workers_here

    with workers_here():
        yield


@pytest.fixture
def question_data(monkeypatch) -> Path:
    """The data directory in use; sets ``RSB_DATA_DIR`` (also for subprocesses) when unset."""
    if os.environ.get("RSB_DATA_DIR"):
        return Path(os.environ["RSB_DATA_DIR"])
    monkeypatch.setenv("RSB_DATA_DIR", str(FIXTURE_DATA))
    return FIXTURE_DATA


@pytest.fixture
def no_data_dir(monkeypatch):
    """No ``RSB_DATA_DIR`` and no cached pools, before and after: each test names its data itself
    (a module that needs this marks itself ``pytestmark = pytest.mark.usefixtures("no_data_dir")``)."""
    from rsb_maniskill.semantic import clear_cache

    monkeypatch.delenv("RSB_DATA_DIR", raising=False)
    clear_cache()
    yield
    clear_cache()


@pytest.fixture
def no_data(tmp_path, monkeypatch) -> Path:
    """No question data at hand: an empty data folder, and no network (what a report on a laptop
    without the datasets sees)."""
    empty = tmp_path / "no-data"
    empty.mkdir()
    monkeypatch.setenv("RSB_DATA_DIR", str(empty))
    monkeypatch.setenv("RSB_OFFLINE", "1")
    return empty


@pytest.fixture
def silent_proxy(monkeypatch):
    """No network, also on a machine that has one: HTTPS_PROXY (subprocesses inherit it) is a proxy
    on 127.0.0.1 that accepts connections and never answers (a firewall that drops)."""
    with silent_proxy_server() as url:
        monkeypatch.setenv("HTTPS_PROXY", url)
        monkeypatch.setenv("https_proxy", url)
        yield url


@pytest.fixture
def gpu_physics() -> None:
    """Skips a test that needs GPU physics where this machine can't run it (no CUDA device, or no
    PhysX GPU library and no way to fetch it), with the reason and the fix ``rsb doctor`` prints.
    Use as ``@pytest.mark.usefixtures("gpu_physics")``."""
    from rsb_maniskill.sim.physx_gpu import gpu_physics_unavailable

    reason = gpu_physics_unavailable()
    if reason:
        pytest.skip(reason)
