"""GPU physics without surprises: the PhysX GPU library is found, fetched with timeouts, or named
in a clear error; `rsb doctor` reports what the machine can do. Runs on CPU machines: the
library's download is pointed at 127.0.0.1 servers, never at the internet."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import requests

from rsb_maniskill import network
from rsb_maniskill.cli import main
from rsb_maniskill.sim import physx_gpu
from rsb_maniskill.version import benchmark_label

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def home(tmp_path, monkeypatch):
    """A home without the library; no offline switch; no proxy unless a test sets one."""
    monkeypatch.setenv("HOME", str(tmp_path))
    proxies = ("HTTPS_PROXY", "https_proxy", "HTTP_PROXY", "http_proxy", "NO_PROXY", "no_proxy")
    for var in (*network.OFFLINE_VARS, *proxies):
        monkeypatch.delenv(var, raising=False)
    assert not physx_gpu.library_path().exists()
    return tmp_path


def _assert_clear(err: Exception | str, home: Path) -> None:
    msg = str(err)
    lib = home / ".sapien" / "physx" / physx_gpu.physx_version() / "libPhysXGpu_64.so"
    assert str(lib) in msg and physx_gpu.library_url() in msg and str(lib.parent) in msg
    assert physx_gpu.SETUP_COMMAND in msg and "rsb doctor" in msg


@pytest.mark.parametrize("var", network.OFFLINE_VARS)
def test_offline_switch_gives_the_clear_error_without_network(home, var, monkeypatch):
    monkeypatch.setenv(var, "1")
    monkeypatch.setattr(requests, "get", lambda *a, **k: pytest.fail("no network call when offline"))
    with pytest.raises(physx_gpu.PhysXGpuLibraryMissing) as err:
        physx_gpu.check_for_sim_backend("physx_cuda", 1)
    _assert_clear(err.value, home)


@pytest.mark.timeout(60)
def test_dropped_packets_give_the_clear_error_within_seconds(home, silent_proxy, monkeypatch):
    monkeypatch.setenv(physx_gpu.READ_TIMEOUT_VAR, "2")
    t0 = time.monotonic()
    with pytest.raises(physx_gpu.PhysXGpuLibraryMissing) as err:
        physx_gpu.fetch()
    assert time.monotonic() - t0 < 30  # not SAPIEN's timeout-less hang
    _assert_clear(err.value, home)
    assert "Timeout" in str(err.value)


def test_refused_connection_gives_the_clear_error(home, monkeypatch):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    monkeypatch.setenv("HTTPS_PROXY", f"http://127.0.0.1:{port}")
    with pytest.raises(physx_gpu.PhysXGpuLibraryMissing) as err:
        physx_gpu.fetch(timeout=5)
    _assert_clear(err.value, home)


def test_present_library_makes_no_network_call(home, monkeypatch):
    lib = physx_gpu.library_path()
    lib.parent.mkdir(parents=True)
    lib.write_bytes(b"\x7fELF stand-in")

    def no_network(*args, **kwargs):
        raise AssertionError("network used although the library is present")
    monkeypatch.setattr(requests, "get", no_network)
    monkeypatch.setattr(socket.socket, "connect", no_network)
    assert physx_gpu.fetch() == lib
    physx_gpu.check_for_sim_backend("physx_cuda", 16)  # returns: SAPIEN will load the file itself


def test_gpu_env_fails_clearly_before_sapien_downloads(home, monkeypatch):
    """gym.make on physx_cuda with the library missing and offline: our error, not requests'."""
    import gymnasium as gym

    import rsb_maniskill  # noqa: F401

    monkeypatch.setenv("RSB_OFFLINE", "1")
    with pytest.raises(physx_gpu.PhysXGpuLibraryMissing) as err:
        gym.make("RSB-Math-4", num_envs=4, sim_backend="physx_cuda", obs_mode="state")
    _assert_clear(err.value, home)


# ---------------------------------------------------------------- when GPU physics can run: one rule


@pytest.fixture
def cuda(monkeypatch):
    """A (faked) CUDA machine; the network probe forgets earlier verdicts."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda *a: "NVIDIA H100 80GB HBM3 (faked)")
    monkeypatch.setattr(network, "_PROBED", {})


def _forbid_network(monkeypatch) -> None:
    def no_network(*args, **kwargs):
        raise AssertionError("network used")
    monkeypatch.setattr(requests, "head", no_network)
    monkeypatch.setattr(requests, "get", no_network)
    monkeypatch.setattr(socket.socket, "connect", no_network)


def test_gpu_physics_needs_cuda(home, monkeypatch):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    _forbid_network(monkeypatch)
    assert "needs a CUDA device" in physx_gpu.gpu_physics_unavailable()


def test_gpu_physics_runs_where_the_library_is(home, cuda, monkeypatch):
    lib = physx_gpu.library_path()
    lib.parent.mkdir(parents=True)
    lib.write_bytes(b"")  # present is enough: SAPIEN loads it
    monkeypatch.setenv("RSB_OFFLINE", "1")  # offline changes nothing then
    _forbid_network(monkeypatch)
    assert physx_gpu.gpu_physics_unavailable() is None
    assert physx_gpu.gpu_physics_unavailable(probe_network=False) is None


@pytest.mark.parametrize("var", network.OFFLINE_VARS)
def test_gpu_physics_offline_without_the_library_names_it_and_the_fix(home, cuda, var, monkeypatch):
    monkeypatch.setenv(var, "1")
    _forbid_network(monkeypatch)
    reason = physx_gpu.gpu_physics_unavailable()
    _assert_clear(reason, home)
    assert "offline" in reason and var in reason


@pytest.mark.timeout(60)
def test_gpu_physics_online_but_unreachable_names_it_within_seconds(home, cuda, silent_proxy):
    t0 = time.monotonic()
    reason = physx_gpu.gpu_physics_unavailable()
    assert time.monotonic() - t0 < network.PROBE_TIMEOUT + 5
    _assert_clear(reason, home)
    assert "Timeout" in reason or "no answer" in reason  # requests' timeout or the probe's deadline


def test_gpu_physics_refused_connection_names_it(home, cuda, monkeypatch):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    monkeypatch.setenv("HTTPS_PROXY", f"http://127.0.0.1:{port}")
    reason = physx_gpu.gpu_physics_unavailable()
    _assert_clear(reason, home)
    assert "unreachable" in reason


def test_gpu_physics_online_fetches_at_first_use(home, cuda, monkeypatch):
    """GitHub answers: the library is fetched at the first GPU env, as before; only `rsb doctor`,
    which never uses the network, calls the missing library a reason."""
    monkeypatch.setattr(network, "unreachable", lambda url, timeout=network.PROBE_TIMEOUT: None)
    assert physx_gpu.gpu_physics_unavailable() is None
    reason = physx_gpu.gpu_physics_unavailable(probe_network=False)
    assert "not installed yet" in reason and physx_gpu.SETUP_COMMAND in reason
    assert str(physx_gpu.library_path()) in reason


def test_gpu_tests_skip_by_the_rule_with_its_reason(home, cuda, monkeypatch, request):
    monkeypatch.setenv("RSB_OFFLINE", "1")
    with pytest.raises(pytest.skip.Exception) as skip:
        request.getfixturevalue("gpu_physics")
    assert str(skip.value) == physx_gpu.gpu_physics_unavailable()
    _assert_clear(str(skip.value), home)


def test_gpu_tests_run_where_the_library_is(home, cuda, request):
    lib = physx_gpu.library_path()
    lib.parent.mkdir(parents=True)
    lib.write_bytes(b"")
    assert request.getfixturevalue("gpu_physics") is None  # no skip


def test_doctor_reports_the_same_rule(home, cuda, monkeypatch):
    from rsb_maniskill.commands.doctor import check_gpu

    monkeypatch.setenv("RSB_OFFLINE", "1")
    _forbid_network(monkeypatch)
    checks = {c.name: c for c in check_gpu()}
    assert checks["GPU physics"].status == "warn"
    assert checks["GPU physics"].detail == physx_gpu.gpu_physics_unavailable()
    assert checks["PhysX GPU library"].detail == f"missing ({physx_gpu.library_path()})"
    assert checks["--num-procs auto"].detail.startswith("cameras: workers: ")
    from rsb_maniskill.sim.camera_group import group_rendering_unavailable

    why_not = group_rendering_unavailable()  # the rule the vector env's renderer="auto" picks by
    assert "envs a process" in checks["--num-envs auto"].detail
    assert ("available" if why_not is None else why_not) in checks["--num-envs auto"].detail
    lib = physx_gpu.library_path()
    lib.parent.mkdir(parents=True)
    lib.write_bytes(b"")
    checks = {c.name: c for c in check_gpu()}
    assert checks["GPU physics"].status == "ok" and checks["PhysX GPU library"].detail == str(lib)


@pytest.mark.parametrize("backend, n, gpu", [("auto", 1, False), ("auto", 8, True), ("physx_cpu", 1, False),
                                              ("physx_cuda", 1, True), ("physx_cuda:1", 4, True), ("gpu", 2, True),
                                              ("cpu", 1, False)])
def test_uses_gpu_physics_like_maniskill(backend, n, gpu):
    assert physx_gpu.uses_gpu_physics(backend, n) is gpu


def test_module_entry_point_reports_the_error(home):
    env = {"HOME": str(home), "RSB_OFFLINE": "1", "PATH": "/usr/bin:/bin", "PYTHONPATH": str(REPO)}
    out = subprocess.run([sys.executable, "-m", "rsb_maniskill.sim.physx_gpu"], capture_output=True, text=True, env=env)
    assert out.returncode == 1 and "libPhysXGpu_64.so" in out.stderr


def test_doctor_reports_every_area(capsys, monkeypatch, home):
    monkeypatch.setenv("RSB_OFFLINE", "1")
    rc = main(["doctor", "--json"])
    report = json.loads(capsys.readouterr().out)
    areas = {c["area"] for c in report["checks"]}
    assert {"python", "packages", "render", "gpu", "data", "episodes", "optional"} <= areas
    by_name = {c["name"]: c for c in report["checks"]}
    assert {"mani-skill", "mplib", "numpy", "sapien", "torch"} <= set(by_name)  # the pins of pyproject.toml
    assert by_name["numpy"]["status"] == "ok" and "<2" in by_name["numpy"]["detail"]
    assert by_name[benchmark_label()]["status"] == "ok" and "8 suites" in by_name[benchmark_label()]["detail"]
    assert by_name["one-frame render"]["status"] == "ok"  # lavapipe or a GPU: the tests render elsewhere too
    assert "libPhysXGpu_64.so" in by_name["PhysX GPU library"]["detail"]
    assert report["demo_can_run"] is True and rc == 0


def test_doctor_exit_1_when_the_renderer_is_missing(capsys, monkeypatch):
    monkeypatch.setenv("VK_ICD_FILENAMES", "/nonexistent/no_icd.json")
    rc = main(["doctor"])
    out = capsys.readouterr().out
    assert rc == 1 and "`make demo` cannot run here" in out and "lavapipe" in out


def test_rsb_eval_num_envs_reports_the_missing_library_up_front(home, monkeypatch, capsys, tmp_path):
    """`rsb eval -b physx_cuda --num-envs B` on a (faked) CUDA machine without the library: exit 2 with the
    clear error before any env or worker starts."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setenv("RSB_OFFLINE", "1")
    rc = main(["eval", "random", "--suites", "RSB-Math-4", "-n", "2", "-b", "physx_cuda", "--num-envs", "2",
               "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and "rsb eval: error: GPU physics" in err and "libPhysXGpu_64.so" in err
    assert not list((tmp_path / "out").glob("*/episodes.jsonl"))
