"""The diffusion-policy baseline end to end on a handful of real demos: training writes a
checkpoint `rsb eval` runs, resume continues exactly where an uninterrupted run would be, a
policy overfit to one demo reproduces its first action chunk, the text encoder loads offline."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from rsb_maniskill.baselines.diffusion_policy import checkpoint
from rsb_maniskill.baselines.diffusion_policy.data import load_demos
from rsb_maniskill.baselines.diffusion_policy.policy import DiffusionPolicy
from rsb_maniskill.baselines.diffusion_policy.text import require_extra

require_extra()  # set-up installs the 'baselines' extra: a missing one is a failure, not a skip
from rsb_maniskill.baselines.diffusion_policy.train import main as train_main  # noqa: E402
from rsb_maniskill.motionplan.config import GenerateConfig  # noqa: E402
from rsb_maniskill.motionplan.generate import generate  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
SUITE = "RSB-Direct-4"  # the instruction names the block: no question data needed
TINY = ["--unet-dims", "16", "32", "--batch-size", "16", "--threads", "1", "-q"]


@pytest.fixture(scope="module")
def demos(tmp_path_factory) -> Path:
    """Three expert demos as `rsb generate` writes them."""
    tmp = tmp_path_factory.mktemp("dp")
    summary = generate(GenerateConfig(env_id=SUITE, out=str(tmp / "demos"), num=3, progress=False))
    assert summary.path is not None and summary.completed == 3
    return Path(summary.path)


def _train(demos: Path, out: Path, *extra: str) -> Path:
    return train_main(["--demos", str(demos), "--out", str(out), *TINY, *extra])


def test_text_encoder_loads_offline():
    code = ("from rsb_maniskill.baselines.diffusion_policy.text import TextEncoder\n"
            "import numpy as np, json\n"
            "enc = TextEncoder()\n"
            "red, blue = 'Move the red block into the gray zone.', 'Move the blue block into the gray zone.'\n"
            "e = enc.encode([red, blue])\n"
            "again = enc(red)\n"
            "print(json.dumps([list(e.shape), float(np.linalg.norm(e[0])), float(e[0] @ e[1]),\n"
            "                  bool((again == e[0]).all()), len(enc.cache)]))")
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1", "HF_HOME": "/nonexistent-hf-home",
           "PYTHONPATH": str(REPO)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    shape, norm, cos, cached, n_cached = json.loads(out.stdout.strip().splitlines()[-1])
    assert shape == [2, 384]
    assert abs(norm - 1) < 1e-4
    assert cos < 0.99  # the colour word changes the embedding
    assert cached and n_cached == 2


@pytest.mark.slow
def test_instruction_gate_selects_the_named_slot():
    """The language-gated observation encoder learns to copy out the pose in the slot the
    instruction names (the operation Direct-4 needs), from its own weights, in a few hundred steps."""
    from rsb_maniskill.baselines.diffusion_policy.model import ObsEncoder

    torch.manual_seed(0)
    slots, dim, n = 4, 3, 512
    texts = torch.randn(slots, 384)  # one "instruction" embedding per slot
    enc = ObsEncoder(slots * dim, 64, text_dim=384)
    head = torch.nn.Linear(64, dim)
    opt = torch.optim.Adam([*enc.parameters(), *head.parameters()], lr=3e-3)
    obs, which = torch.randn(n, slots, dim), torch.randint(slots, (n,))
    target = obs[torch.arange(n), which]
    for _ in range(600):
        loss = torch.nn.functional.mse_loss(head(enc(obs.flatten(1), texts[which])), target)
        opt.zero_grad()
        loss.backward()
        opt.step()
    test_obs, test_which = torch.randn(256, slots, dim), torch.randint(slots, (256,))
    with torch.no_grad():
        err = head(enc(test_obs.flatten(1), texts[test_which])) - test_obs[torch.arange(256), test_which]
    assert err.pow(2).mean() < 0.1  # the pose has unit variance: guessing the slot mean scores ~1.0


def test_demo_windows_carry_instruction_and_actions(demos):
    ds = load_demos([demos])
    meta = json.loads(demos.with_suffix(".json").read_text())
    assert [e.instruction for e in ds.episodes] == [ep["instruction"] for ep in meta["episodes"]]
    assert ds.control_mode == "pd_joint_pos"
    assert all(len(e.obs) == len(e.actions) + 1 and e.actions.shape[1] == 14 for e in ds.episodes)
    with pytest.raises(ValueError, match="--obs"):
        load_demos([demos], obs="depth")


def test_training_draws_each_windows_wording_from_its_own_episode(demos, tmp_path):
    """The demos' instructions come with their paraphrases (20 training templates, recorded first); a
    batch takes a random one of the window's own episode (the recorded one without a generator); an
    entry the templates cannot reproduce trains on its recorded wording, with a warning."""
    from rsb_maniskill.baselines.diffusion_policy.data import Normalizer, WindowSampler
    from rsb_maniskill.semantic.templates import SEEN_DIRECT

    ds = load_demos([demos])
    for e in ds.episodes:
        assert e.paraphrases[0] == e.instruction and len(set(e.paraphrases)) == len(SEEN_DIRECT)
    # fake embeddings that say whose they are: 100 * episode + wording
    emb = [np.full((len(e.paraphrases), 384), 100.0 * i) + np.arange(len(e.paraphrases))[:, None]
           for i, e in enumerate(ds.episodes)]
    windows = WindowSampler(ds, Normalizer.fit(ds.episodes), emb, 2, 16)
    idx = torch.arange(len(windows))
    ep = windows.ep_idx[idx].float()
    assert torch.equal(windows.batch(idx)["text"][:, 0], 100 * ep)  # recorded wording
    drawn = windows.batch(idx, torch.Generator().manual_seed(0))["text"][:, 0]
    assert torch.equal(torch.div(drawn, 100, rounding_mode="floor"), ep)  # always its own episode's
    assert len(set((drawn % 100).tolist())) > 15  # and many of its wordings

    meta = json.loads(demos.with_suffix(".json").read_text())
    meta["episodes"][1]["instruction"] += " Quickly."  # no template renders this
    copy = tmp_path / demos.name
    copy.write_bytes(demos.read_bytes())
    copy.with_suffix(".json").write_text(json.dumps(meta))
    with pytest.warns(UserWarning, match="recorded wording only"):
        changed = load_demos([copy])
    assert changed.episodes[1].paraphrases == (meta["episodes"][1]["instruction"],)
    assert changed.episodes[0].paraphrases == ds.episodes[0].paraphrases


def test_tiny_run_checkpoint_runs_in_rsb_eval(demos, tmp_path):
    from rsb_maniskill.cli import main as rsb_main

    ckpt = _train(demos, tmp_path / "run", "--total-iters", "4", "--save-every", "2")
    state = checkpoint.load(ckpt)
    assert state["step"] == 4 and state["meta"]["num_episodes"] == 3 and state["config"]["language"]
    assert (tmp_path / "run" / "checkpoints" / "step_4.pt").is_file()
    out = tmp_path / "eval"
    rc = rsb_main(["eval", "rsb_maniskill.baselines.diffusion_policy:make_policy",
                   "-a", f"checkpoint={tmp_path / 'run'}", "-a", "inference_steps=2", "-o", "state",
                   "--suites", SUITE, "-n", "1", "--max-steps", "20", "--name", "dp-tiny", "--out", str(out), "-q"])
    assert rc == 0
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert len(records) == 1
    assert records[0]["policy"] == "dp-tiny" and records[0]["steps"] == 20


def test_policy_executes_chunks_with_consecutive_history(demos, tmp_path):
    """7 actions, then the 8th alone, then a new inference on the frames just before and after it."""
    ckpt = _train(demos, tmp_path / "run", "--total-iters", "1", "--no-language")
    policy = DiffusionPolicy(str(ckpt), inference_steps=2)
    assert policy.text is None
    ep = load_demos([demos]).episodes[0]
    policy.reset("ignored", ep.obs[0])
    first = policy.act(ep.obs[0])
    assert first.shape == (7, 14)
    assert policy.act(ep.obs[7]).shape == (1, 14)
    policy.act(ep.obs[8])
    assert [h[0][0] for h in policy.history] == [ep.obs[7][0], ep.obs[8][0]]
    with pytest.raises(ValueError, match="-o state"):
        policy.act({"sensor_data": {}})
    with pytest.raises(ValueError, match=f"trained on {ep.obs.shape[1]}-d state observations, the env gives 81"):
        policy.act(ep.obs[9][:81])  # a state vector of another size (e.g. recorded by an older version)


def test_resume_restores_optimizer_step_and_rng(demos, tmp_path):
    """Interrupted after 3 of 6 iterations and rerun: the same weights, optimizer and step as one go
    (with language, so the wordings drawn after the restart are those of one go, too)."""
    whole = checkpoint.load(_train(demos, tmp_path / "whole", "--total-iters", "6"))
    _train(demos, tmp_path / "split", "--total-iters", "6", "--stop-after", "3")
    half = checkpoint.load(tmp_path / "split")
    assert half["step"] == 3
    resumed = checkpoint.load(_train(demos, tmp_path / "split", "--total-iters", "6"))
    assert resumed["step"] == 6
    assert resumed["lr_scheduler"]["last_epoch"] == whole["lr_scheduler"]["last_epoch"] == 6
    for name, w in whole["model"].items():
        assert torch.equal(w, resumed["model"][name]), name
    for name, w in whole["ema_model"].items():
        assert torch.equal(w, resumed["ema_model"][name]), name
    opt_w, opt_r = whole["optimizer"]["state"], resumed["optimizer"]["state"]
    assert opt_w.keys() == opt_r.keys()
    for k in opt_w:
        assert torch.equal(opt_w[k]["exp_avg"], opt_r[k]["exp_avg"]) and torch.equal(opt_w[k]["step"], opt_r[k]["step"])
    with pytest.raises(SystemExit, match="--lr"):
        _train(demos, tmp_path / "split", "--total-iters", "8", "--lr", "0.01")
    with pytest.raises(SystemExit, match="--no-paraphrase"):
        _train(demos, tmp_path / "split", "--total-iters", "8", "--no-paraphrase")


@pytest.mark.slow
def test_overfit_one_demo_reproduces_first_chunk(demos, tmp_path):
    ckpt = _train(demos, tmp_path / "run", "--total-iters", "300", "--max-episodes", "1", "--lr", "1e-3",
                  "--warmup", "20", "--batch-size", "32", "--lr-schedule", "constant_with_warmup",
                  "--unet-dims", "32", "64", "--prediction", "sample")
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert log[-1]["loss"] < 0.1 * log[0]["loss"], log  # the loss really falls
    ep = load_demos([demos], max_episodes=1).episodes[0]
    meta = json.loads(demos.with_suffix(".json").read_text())["episodes"][0]
    policy = DiffusionPolicy(str(ckpt), scheduler="ddpm")
    policy.reset(meta["instruction"], ep.obs[0])
    chunk = policy.act(ep.obs[0])
    norm = policy.norm
    target = norm.norm_actions(ep.actions[: len(chunk)])  # in [-1, 1] units
    err = np.abs(norm.norm_actions(chunk) - target)
    later = np.abs(norm.norm_actions(ep.actions[40: 40 + len(chunk)]) - target)  # how far another chunk lies
    print("first-chunk error per joint", err.max(axis=0).round(3), "mean", err.mean(), "vs", later.mean())
    assert err.mean() < 0.1 and err.mean() < 0.25 * later.mean() and err.max() < 0.75, err.max(axis=0)


@pytest.mark.slow
def test_rgb_variant_trains_and_runs_in_rsb_eval(tmp_path):
    """One camera demo (head and wrist cameras, rendered on CPU at 64x48: the policy sees 32x32), a few
    iterations, one short episode."""
    from rsb_maniskill.cli import main as rsb_main

    summary = generate(GenerateConfig(env_id=SUITE, out=str(tmp_path / "demos"), num=1, obs_mode="rgb", progress=False,
                                      env_kwargs={"camera_size": (64, 48)}))
    assert summary.completed == 1
    with pytest.raises(Exception, match="--obs state needs 'state'"):
        load_demos([summary.path], obs="state")
    ckpt = _train(Path(summary.path), tmp_path / "run", "--obs", "rgb", "--image-size", "32", "--total-iters", "3")
    state = checkpoint.load(ckpt)
    assert state["meta"]["cameras"] == ["head_camera", "left_wrist_camera", "right_wrist_camera"]
    assert state["config"]["obs_mode"] == "rgb" and state["config"]["num_cameras"] == 3
    rc = rsb_main(["eval", "rsb_maniskill.baselines.diffusion_policy:make_policy", "-a", f"checkpoint={ckpt}",
                   "-a", "inference_steps=2", "-o", "rgb", "-e", "camera_size=[64,48]", "--suites", SUITE, "-n", "1",
                   "--max-steps", "10", "--name", "dp-rgb", "--out", str(tmp_path / "eval"), "-q"])
    assert rc == 0
    records = [json.loads(line) for line in (tmp_path / "eval" / "episodes.jsonl").read_text().splitlines()]
    assert len(records) == 1 and records[0]["steps"] == 10
