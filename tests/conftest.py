"""Shared fixtures. Question data: the real GSM8K / MMLU-Pro files when ``RSB_DATA_DIR`` names them (CI
sets it to the shared copies), else the small fixtures written for the tests, so that no test that
only needs *some* questions skips on a machine without the datasets."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from net_helpers import silent_proxy_server

FIXTURE_DATA = Path(__file__).resolve().parent / "fixtures" / "semantic_data"


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
