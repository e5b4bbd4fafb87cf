"""Offline in seconds: without the question data and without network, every command that reads
question data gives the one-line message that says how to provide it, not minutes of hub retries.

No network here even on a machine that has one: a proxy on 127.0.0.1 accepts connections and never
answers (``silent_proxy``), as for the PhysX GPU library's download (tests/sim/test_gpu_setup.py).
``benchmarks/offline_latency.py`` measures the seconds per command."""
from __future__ import annotations

import subprocess
import sys
import time

import pytest

from rsb_maniskill import network

from net_helpers import COMMANDS, no_data_env


@pytest.mark.parametrize("name", COMMANDS)
def test_no_data_and_no_network_gives_the_message_within_seconds(name, tmp_path, silent_proxy):
    args = [a.format(tmp=tmp_path) for a in COMMANDS[name]]
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", *args], capture_output=True, text=True,
                          env=no_data_env(tmp_path), timeout=120)
    elapsed = time.monotonic() - t0
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out
    lines = [ln for ln in out.splitlines() if "rsb data download" in ln]
    assert lines, out
    # one line: what, how to fix, why: the client's own timeout error ("unreachable (ReadTimeout)"),
    # or the probe's deadline when that error comes later on a loaded machine ("no answer ... within")
    deadline = f"no answer from https://huggingface.co within {network.PROBE_TIMEOUT:g} s"
    why = "unreachable" in lines[0] or deadline in lines[0]
    assert "$RSB_DATA_DIR" in lines[0] and why, lines[0]
    assert elapsed < 30, f"{name}: {elapsed:.1f} s (the hub's retries took minutes)"


def test_the_probe_gives_up_at_its_deadline(silent_proxy, monkeypatch):
    monkeypatch.setattr(network, "_PROBED", {})
    for var in network.OFFLINE_VARS:  # CI may run with the hub offline: the probe itself is under test
        monkeypatch.delenv(var, raising=False)
    t0 = time.monotonic()
    why = network.unreachable("https://huggingface.co", timeout=1.0)
    assert why and "huggingface.co" in why and time.monotonic() - t0 < 5
    assert network.unreachable("https://huggingface.co", timeout=1.0) == why  # asked once a process


def test_the_offline_switch_asks_nobody(monkeypatch):
    import requests

    monkeypatch.setenv("RSB_OFFLINE", "1")
    monkeypatch.setattr(requests, "head", lambda *a, **k: pytest.fail("no network call when offline"))
    assert "offline" in network.unreachable("https://huggingface.co")
