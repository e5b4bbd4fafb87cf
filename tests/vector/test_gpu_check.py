"""benchmarks/gpu_check.py on a machine without CUDA: it refuses at once, saying why and how to run it;
its workers start their timed part together at a barrier; the ceiling stage runs with a stand-in group."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "gpu_check.py"


@pytest.fixture(scope="module")
def gpu_check():
    sys.path.insert(0, str(SCRIPT.parent))
    spec = importlib.util.spec_from_file_location("gpu_check", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["gpu_check"] = module  # the spawned workers import it by name
    spec.loader.exec_module(module)
    return module


def test_without_cuda_it_stops_at_once_and_says_why(gpu_check, monkeypatch, capsys):
    monkeypatch.setattr(gpu_check, "no_cuda_reason", lambda: "torch sees no CUDA device")
    monkeypatch.setattr(gpu_check, "gpu_tests", lambda dry: pytest.fail("a stage ran"))
    assert gpu_check.main([]) == 2
    err = capsys.readouterr().err
    assert "no GPU figures here: torch sees no CUDA device" in err and "python benchmarks/gpu_check.py" in err


def test_workers_start_together_at_the_barrier(gpu_check, tmp_path):
    res, wall = gpu_check._pool_run(gpu_check._barrier_probe, 2, (1.0, str(tmp_path / "slow")))
    ready = max(r[2] for r in res)  # the slow worker's
    assert ready - min(r[2] for r in res) > 0.5  # one was slow indeed
    assert all(t0 >= ready - 0.01 for t0, _, _ in res)  # no one started before it was ready
    assert wall >= 0


@pytest.mark.slow
def test_ceiling_stage_with_a_stand_in_group(gpu_check):
    rate = gpu_check.ceiling(1, 2, 2, [32, 24], dry=True)
    assert rate > 0
