"""Shared fixtures. Question data: the real GSM8K / MMLU-Pro files when ``RSB_DATA_DIR`` names them (CI
sets it to the shared copies), else the small fixtures written for the tests, so that no test that
only needs *some* questions skips on a machine without the datasets."""
from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from net_helpers import silent_proxy_server

FIXTURE_DATA = Path(__file__).resolve().parent / "fixtures" / "semantic_data"


# Seconds each of the longest test files took in one whole `make test` run (2 cores, the sum of its
# tests' setup, call and teardown).
# `make test` hands whole files to its workers in collection order (xdist --dist loadfile
# --no-loadscope-reorder): the long ones go first, so none starts last and runs alone at the end.
# Only the order depends on these numbers; a file not listed keeps its place after them.
LONGEST_FILES = {
    "export/test_dataset_build.py": 268, "acceptance/test_faults.py": 239, "audit/test_audit.py": 207,
    "integrations/test_lerobot_env.py": 206, "commands/test_eval_cli.py": 201, "motionplan/test_generate.py": 168,
    "commands/test_bad_input.py": 129, "export/test_lerobot_export.py": 127, "semantic/test_options.py": 98,
    "tasks/test_perturb.py": 90, "parallel/test_ray_executor.py": 85, "baselines/test_diffusion_policy.py": 73,
    "sim/test_render_engine.py": 73, "motionplan/test_expert.py": 70, "acceptance/test_light_imports.py": 52,
    "tasks/test_tasks.py": 46, "vector/test_vector_env.py": 45, "reporting/test_html_report.py": 41,
}


def pytest_collection_modifyitems(config, items) -> None:
    """The longest files first (LONGEST_FILES), each file's tests in their own order."""
    def seconds(item) -> int:
        return LONGEST_FILES.get(item.nodeid.split("::", 1)[0].removeprefix("tests/"), 0)

    items.sort(key=lambda item: -seconds(item))  # stable: the rest keep their order


def pytest_configure(config) -> None:
    """Tests run as from a terminal: a run started in a script's background (``make test &``)
    inherits SIGINT ignored, and so would every command a test starts; its Ctrl-C tests would then
    pass without the command ever being interrupted. (Runs in each xdist worker too.)"""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


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
