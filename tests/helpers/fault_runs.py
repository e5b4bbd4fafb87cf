"""What the fault-injection tests share (tests/acceptance/test_faults*.py): running ``rsb`` as a user
runs it (``python -m rsb_maniskill.cli`` in a subprocess), stopping it, and reading what it left: records,
demos, stray half-written files; the reference demos of the cheapest generate run (each file's module fixture)."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import h5py
import numpy as np

REPO = Path(__file__).resolve().parents[2]
TESTS = REPO / "tests" / "helpers"  # the helper modules policies are named from (bad_policies)
SUITE = "RSB-Math-4"
EVAL = ["--suites", SUITE, "-o", "state", "-q"]
DEMO_DIR = Path(SUITE) / "motionplanning"
DEMO_FILE = DEMO_DIR / "train.state.pd_joint_pos.physx_cpu.h5"
STAMP = re.compile(r"\d{4}-\d{2}-\d{2}([T ]\d{2}:\d{2}(:\d{2})?Z?( UTC)?)?")
STRAY = re.compile(r"\.tmp|\.partial|\.part\d|write-probe")  # what a half-done write is named


def _env(**extra: str) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), str(REPO), os.environ.get("PYTHONPATH", "")]))
    env.pop("RSB_DEBUG", None)
    env.update(extra)
    return env


def rsb(*args: str, timeout: float = 300, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "rsb_maniskill.cli", *args], capture_output=True, text=True,
                          env=_env(**env), cwd=REPO, timeout=timeout)


def start(*args: str, **env: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "rsb_maniskill.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=_env(**env), cwd=REPO)


def wait_until(ready: Callable[[], bool], proc: subprocess.Popen, timeout: float = 240) -> bool:
    """Polls ``ready`` while ``proc`` runs; True when it came true before the process ended."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if ready():
                return True
        except OSError:  # a temp file or folder the command is writing vanished under the walk: not yet
            pass
        time.sleep(0.05)
    return False


def stop(proc: subprocess.Popen, sig: int) -> tuple[int, str]:
    """Sends ``sig`` (if the process still runs); its exit code and output."""
    if proc.poll() is None:
        proc.send_signal(sig)
    out, err = proc.communicate(timeout=240)
    return proc.returncode, out + err


def error_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if ": error:" in line]


def stray_files(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if STRAY.search(p.name))


def lines(path: Path) -> int:
    return sum(1 for _ in path.open()) if path.exists() else 0


def records(out: Path) -> list[dict]:
    """The records, in seed order, without what differs from run to run (timings)."""
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines() if line.strip()]
    for r in rows:
        r.pop("wall_s", None)
    return sorted(rows, key=lambda r: (r["suite_id"], r["instruction_mode"], r["seed"]))


def tree(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` by content, time stamps masked."""
    return {str(p.relative_to(root)): STAMP.sub("<stamp>", p.read_text(errors="replace")).encode()
            if p.suffix in (".html", ".md", ".json", ".csv", ".jsonl") else p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}



def _demos(h5_path: Path) -> tuple[list[dict], dict[str, np.ndarray]]:
    """The json episodes (without the expert's timings) and every h5 dataset by path."""
    data = json.loads(h5_path.with_suffix(".json").read_text())
    episodes = [{k: v for k, v in ep.items() if k != "expert"} for ep in data["episodes"]]
    arrays: dict[str, np.ndarray] = {}
    with h5py.File(h5_path) as f:
        f.visititems(lambda name, obj: arrays.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return episodes, arrays


GENERATE = ["generate", SUITE, "-n", "2", "-q"]


def reference_demos(tmp_path_factory) -> Path:
    """The demos of the cheapest uninterrupted generate run (GENERATE), to compare a rerun with."""
    out = tmp_path_factory.mktemp("gen")
    res = rsb(*GENERATE, "--out", str(out))
    assert res.returncode == 0, res.stderr[-2000:]
    return out / DEMO_FILE


def _resume_dir(out: Path) -> Path:
    return out / DEMO_DIR / ".train.state.pd_joint_pos.physx_cpu.partial"


def _pair(path: Path, seeds: list[int]) -> Path:
    """A minimal ManiSkill trajectory pair of one env."""
    with h5py.File(path, "w") as f:
        for i, _ in enumerate(seeds):
            f.create_dataset(f"traj_{i}/actions", data=np.zeros((2, 14), dtype=np.float32))
    env_info = {"env_id": SUITE, "env_kwargs": {"obs_mode": "state"}}
    path.with_suffix(".json").write_text(json.dumps({"env_info": env_info, "episodes": [
        {"episode_id": i, "episode_seed": s} for i, s in enumerate(seeds)]}))
    return path


def workers_of(pid: int) -> list[int]:
    """Child processes of ``pid`` that are multiprocessing workers."""
    found = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        for child in (task / "children").read_text().split():
            cmd = Path(f"/proc/{child}/cmdline").read_bytes() if Path(f"/proc/{child}/cmdline").exists() else b""
            if b"spawn_main" in cmd:
                found.append(int(child))
    return found


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] != "Z"
    except (FileNotFoundError, IndexError):
        return False
