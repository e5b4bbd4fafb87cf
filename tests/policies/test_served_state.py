"""Every env's episode state is its own, whichever process runs the policy: the diffusion-policy
baseline (a tiny checkpoint, wrapped in a recorder: a single-env policy served as one copy an env)
and a stateful batched stand-in (served by ``reset_envs`` / ``act_batch`` over slots) hand out the
same action chunks, seed for seed and call for call, under ``rsb eval --policy-process worker``,
``shared`` and ``auto``, with ``--num-envs 1`` and ``4``. Each policy writes every chunk it returns
to a log (``tests/helpers/served_policies.py``), in the workers or in the shared server alike. The
runs' normal output (no ``-q``) holds no library log line and no traceback."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("websockets")

from served_policies import read_chunks  # noqa: E402

SUITE = "RSB-Direct-4"  # the instruction names the block: no question data needed
HELPERS = Path(__file__).parents[1] / "helpers"
OBS_DIM, ACTION_DIM = 117, 14  # the suite's state observation and joint actions
# (mode, K): the per-worker run with one env a worker is the reference; the shared server gets the rows
# of two workers, one at a time (K = 1) or four a request (K = 4); auto decides for itself and says why
# (on a machine without CUDA: a copy a worker, here with K = 4 envs each)
RUNS = (("worker", 1), ("shared", 1), ("shared", 4), ("auto", 4))
LOG_LINE = re.compile(r"^(DEBUG|INFO|WARNING|ERROR|CRITICAL):")  # logging's default format


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(HELPERS), *sys.path]))


def _tiny_checkpoint(out: Path) -> Path:
    """A diffusion-policy checkpoint with random weights (no training: what is compared is how the
    served copies act, not how well), saved as training saves one."""
    import torch

    from rsb_maniskill.baselines.diffusion_policy import checkpoint
    from rsb_maniskill.baselines.diffusion_policy.data import Normalizer
    from rsb_maniskill.baselines.diffusion_policy.model import DiffusionPolicyNet, ModelConfig

    torch.manual_seed(0)
    cfg = ModelConfig(act_dim=ACTION_DIM, obs_dim=OBS_DIM, language=False, unet_dims=[16, 32], obs_feat=32,
                      step_embed_dim=16, num_train_steps=20)
    net = DiffusionPolicyNet(cfg)
    norm = Normalizer(np.full(ACTION_DIM, -0.5, np.float32), np.full(ACTION_DIM, 0.5, np.float32),
                      np.zeros(OBS_DIM, np.float32), np.ones(OBS_DIM, np.float32))
    state = {"config": cfg.to_dict(), "norm": norm.state_dict(), "model": net.state_dict(),
             "ema_model": net.state_dict(), "step": 0, "meta": {"cameras": [], "control_mode": "pd_joint_pos"}}
    return checkpoint.save(out, state, step=0, keep_step_file=False)


def _run_all(tmp_path: Path, factory: str, *args: str) -> dict[tuple[str, int], tuple[dict, list[dict], str]]:
    """Each run of RUNS: its chunks ``(seed, call) -> chunk``, its records and its stderr."""
    got = {}
    for mode, k in RUNS:
        out, log = tmp_path / f"{mode}-{k}", tmp_path / f"{mode}-{k}.chunks"
        cmd = [sys.executable, "-m", "rsb_maniskill.cli", "eval", factory, "-a", f"log={log}", *args,
               "--suites", SUITE, "-o", "state", "--max-steps", "10", "-n", "8", "--num-procs", "2",
               "--num-envs", str(k), "--policy-process", mode, "--out", str(out)]
        done = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
        got[(mode, k)] = (read_chunks(log), records, done.stdout + done.stderr)
    return got


def _same_everywhere(got: dict) -> None:
    chunks, records, _ = got[("worker", 1)]
    assert len({seed for seed, _ in chunks}) == 8 and len(chunks) >= 8 * 3  # every episode, several calls each
    # what the episode was: all but its wall time and the digest of the run's settings (which name the policy process)
    strip = lambda rs: sorted(({k: v for k, v in r.items() if k not in ("wall_s", "settings_id")} for r in rs),  # noqa: E731
                              key=lambda r: r["seed"])
    for run, (other, other_records, _) in got.items():
        assert other.keys() == chunks.keys(), run
        differ = [key for key in chunks if other[key] != chunks[key]]
        assert not differ, f"{run}: {len(differ)} of {len(chunks)} chunks differ from the per-worker run's"
        assert strip(other_records) == strip(records), run
    _, _, said = got[("auto", 4)]
    assert "policy process: worker" in said or "policy process: shared" in said  # auto says what it chose, and why
    for run, (_, _, output) in got.items():  # a run's normal output (no -q): no library's log line, no traceback
        noise = [line for line in output.splitlines() if LOG_LINE.match(line) or "websockets" in line
                 or "Traceback" in line]
        assert not noise, f"{run}: {noise}"


def test_diffusion_baseline_acts_the_same_served_or_per_worker(tmp_path):
    pytest.importorskip("diffusers")
    ckpt = _tiny_checkpoint(tmp_path / "dp")
    got = _run_all(tmp_path, "served_policies:make_recording_diffusion", "-a", f"checkpoint={ckpt}")
    _same_everywhere(got)
    for k in (1, 4):
        assert "each env its own (a copy of the policy as built" in got[("shared", k)][2]  # as the server said


def test_stateful_batched_policy_acts_the_same_served_or_per_worker(tmp_path):
    got = _run_all(tmp_path, "served_policies:make_stateful")
    _same_everywhere(got)
    assert "reset_envs" in got[("shared", 4)][2]
