"""Train a (language-conditioned) diffusion policy on RSB demonstrations.

    python -m rsb_maniskill.baselines.diffusion_policy.train --demos FILE.h5 [--demos ...] --out DIR \
        [--obs state|rgb] [--no-language] [--total-iters N]

A language policy trains on every training-template wording of each demo's instruction, one drawn
per window (``--no-paraphrase``: the recorded wording only). Rerunning the same command resumes
from ``DIR/checkpoints/last.pt`` (model, EMA, optimizer, LR schedule, step and every RNG), so an
interrupted run ends where an uninterrupted one would.
"""
from __future__ import annotations

import argparse
import json
import random
import signal
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from rsb_maniskill.baselines.diffusion_policy import checkpoint
from rsb_maniskill.baselines.diffusion_policy.text import require_extra

# Arguments that define the model and its data: a resumed run must not change them.
FIXED_ON_RESUME = ("obs", "no_language", "no_paraphrase", "prediction", "obs_horizon", "pred_horizon",
                   "act_horizon", "unet_dims", "image_size", "batch_size", "lr", "lr_schedule", "seed", "demos",
                   "max_episodes")


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m rsb_maniskill.baselines.diffusion_policy.train",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--demos", action="append", required=True, help="trajectory .h5 (its .json beside it); repeatable")
    p.add_argument("--out", required=True, help="run directory (checkpoints/, log.jsonl)")
    p.add_argument("--obs", default="state", choices=["state", "rgb"], help="observation variant (default state)")
    p.add_argument("--no-language", action="store_true", help="ignore the instruction (ManiSkill's baseline)")
    p.add_argument("--no-paraphrase", action="store_true",
                   help="train on each demo's recorded wording only, not on all training templates' wordings")
    p.add_argument("--total-iters", type=int, default=30_000)
    p.add_argument("--batch-size", type=int, default=256)
    p.add_argument("--lr", type=float, default=1e-4)
    p.add_argument("--lr-schedule", default="cosine", help="diffusers schedule name: cosine, constant, ...")
    p.add_argument("--warmup", type=int, default=500, help="LR warm-up iterations")
    p.add_argument("--unet-dims", type=int, nargs="+", default=[64, 128, 256])
    p.add_argument("--prediction", default="epsilon", choices=["epsilon", "sample"],
                   help="U-Net target: the noise (ManiSkill's choice) or the clean action chunk")
    p.add_argument("--obs-horizon", type=int, default=2)
    p.add_argument("--pred-horizon", type=int, default=16)
    p.add_argument("--act-horizon", type=int, default=8)
    p.add_argument("--image-size", type=int, default=64, help="rgb: cameras resized to this square side")
    p.add_argument("--max-episodes", type=int, default=None, help="use only the first N demos")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--save-every", type=int, default=2000, help="checkpoint period in iterations")
    p.add_argument("--keep-every", type=int, default=10_000, help="keep a step_<N>.pt every N iterations")
    p.add_argument("--stop-after", type=int, default=None,
                   help="stop (with a checkpoint) after N iterations of this run")
    p.add_argument("--max-minutes", type=float, default=None, help="stop (with a checkpoint) after this wall time")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    if args.obs_horizon + args.act_horizon - 1 > args.pred_horizon:
        p.error("need obs_horizon + act_horizon - 1 <= pred_horizon")
    if args.pred_horizon % 2 ** (len(args.unet_dims) - 1):
        p.error(f"--pred-horizon must be divisible by {2 ** (len(args.unet_dims) - 1)} for {len(args.unet_dims)} "
                "U-Net levels")
    return args


def _rng_state(gen: torch.Generator) -> dict:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate(),
            "sampler": gen.get_state()}


def _set_rng_state(state: dict, gen: torch.Generator) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    gen.set_state(state["sampler"])


def train(args: argparse.Namespace) -> Path:
    """Runs (or resumes) training; returns the path of the last checkpoint."""
    require_extra()
    from diffusers.optimization import get_scheduler
    from diffusers.training_utils import EMAModel
    from tqdm import tqdm

    from rsb_maniskill.baselines.diffusion_policy.data import Normalizer, WindowSampler, load_demos
    from rsb_maniskill.baselines.diffusion_policy.model import DiffusionPolicyNet, ModelConfig, make_scheduler

    if args.threads:
        torch.set_num_threads(args.threads)
    out = Path(args.out)
    last = checkpoint.checkpoint_dir(out) / checkpoint.LAST
    resumed = checkpoint.load(last) if last.is_file() else None
    if resumed is not None:
        old = resumed["args"]
        changed = [k for k in FIXED_ON_RESUME if old.get(k) != getattr(args, k)]
        if changed:
            was = ", ".join("--" + k.replace("_", "-") + f" {old.get(k)}" for k in changed)
            raise SystemExit(f"{last} was trained with other settings ({was}): pass them again to resume, "
                             "or choose another --out")
    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    gen = torch.Generator().manual_seed(args.seed)

    demos = load_demos(args.demos, obs=args.obs, image_size=args.image_size, max_episodes=args.max_episodes)
    norm = Normalizer.fit(demos.episodes) if resumed is None else Normalizer.from_state_dict(resumed["norm"])
    text_emb = None
    if not args.no_language:
        from rsb_maniskill.baselines.diffusion_policy.text import TextEncoder

        wordings = [(e.instruction,) if args.no_paraphrase else e.paraphrases or (e.instruction,)
                    for e in demos.episodes]
        flat = TextEncoder().encode([t for w in wordings for t in w])
        text_emb = np.split(flat, np.cumsum([len(w) for w in wordings])[:-1])
    windows = WindowSampler(demos, norm, text_emb, args.obs_horizon, args.pred_horizon)
    cfg = ModelConfig(act_dim=demos.episodes[0].actions.shape[1], obs_dim=demos.episodes[0].obs.shape[1],
                      obs_mode=args.obs, obs_horizon=args.obs_horizon, pred_horizon=args.pred_horizon,
                      act_horizon=args.act_horizon, language=not args.no_language, unet_dims=list(args.unet_dims),
                      num_cameras=len(demos.cameras), image_size=args.image_size, prediction=args.prediction)
    net = DiffusionPolicyNet(cfg)
    ema = EMAModel(net.parameters(), power=0.75)
    opt = torch.optim.AdamW(net.parameters(), lr=args.lr, betas=(0.95, 0.999), weight_decay=1e-6)
    lr_sched = get_scheduler(args.lr_schedule, optimizer=opt, num_warmup_steps=args.warmup,
                             num_training_steps=args.total_iters)
    noise_sched = make_scheduler(cfg, "ddpm")
    step, train_s = 0, 0.0
    if resumed is not None:
        net.load_state_dict(resumed["model"])
        ema.load_state_dict(resumed["ema"])
        opt.load_state_dict(resumed["optimizer"])
        lr_sched.load_state_dict(resumed["lr_scheduler"])
        step, train_s = resumed["step"], resumed["train_s"]
        _set_rng_state(resumed["rng"], gen)
    meta = {"control_mode": demos.control_mode, "env_id": demos.env_id, "cameras": demos.cameras,
            "demos": [str(p) for p in args.demos], "num_episodes": len(demos.episodes), "num_windows": len(windows)}
    (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    n_params = sum(p.numel() for p in net.parameters())

    def snapshot() -> dict:
        ema.store(net.parameters())
        ema.copy_to(net.parameters())
        ema_weights = {k: v.clone() for k, v in net.state_dict().items()}
        ema.restore(net.parameters())
        return {"config": cfg.to_dict(), "norm": norm.state_dict(), "model": net.state_dict(), "ema": ema.state_dict(),
                "ema_model": ema_weights, "optimizer": opt.state_dict(), "lr_scheduler": lr_sched.state_dict(),
                "step": step, "train_s": train_s, "rng": _rng_state(gen), "args": vars(args), "meta": meta}

    stop_step = args.total_iters if args.stop_after is None else min(args.total_iters, step + args.stop_after)
    deadline = None if args.max_minutes is None else time.monotonic() + 60 * args.max_minutes
    interrupted = []
    old_term = signal.signal(signal.SIGTERM, lambda *_: interrupted.append("SIGTERM"))
    bar = tqdm(total=args.total_iters, initial=step, disable=args.quiet, desc=f"train {out.name}", dynamic_ncols=True)
    if step == 0:
        print(f"{len(demos.episodes)} demos, {len(windows)} windows, {n_params / 1e6:.2f}M parameters, "
              f"language={'on' if cfg.language else 'off'}", file=sys.stderr)
    log = open(out / "log.jsonl", "a")
    net.train()
    t0, losses = time.monotonic(), []
    try:
        while step < stop_step and not interrupted and (deadline is None or time.monotonic() < deadline):
            idx = torch.randint(len(windows), (args.batch_size,), generator=gen)
            batch = windows.batch(idx, gen)
            actions = batch["actions"]
            noise = torch.randn(actions.shape, generator=gen)
            t = torch.randint(0, cfg.num_train_steps, (actions.shape[0],), generator=gen)
            noisy = noise_sched.add_noise(actions, noise, t)
            cond = net.condition(batch["obs"], batch.get("text"), batch.get("images"))
            loss = F.mse_loss(net(noisy, t, cond), noise if cfg.prediction == "epsilon" else actions)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            lr_sched.step()
            ema.step(net.parameters())
            step += 1
            losses.append(loss.item())
            bar.update(1)
            if step % 50 == 0 or step == stop_step:
                bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}")
            if step % 100 == 0 or step == stop_step:
                now = time.monotonic()
                log.write(json.dumps({"step": step, "loss": float(np.mean(losses[-100:])),
                                      "lr": lr_sched.get_last_lr()[0], "train_s": round(train_s + now - t0, 2)}) + "\n")
                log.flush()
            if step % args.save_every == 0 and step < stop_step:
                train_s += time.monotonic() - t0
                t0 = time.monotonic()
                checkpoint.save(out, snapshot(), step, keep_step_file=step % args.keep_every == 0)
    except KeyboardInterrupt:
        interrupted.append("SIGINT")
    finally:
        train_s += time.monotonic() - t0
        bar.close()
        log.close()
        signal.signal(signal.SIGTERM, old_term)
    path = checkpoint.save(out, snapshot(), step, keep_step_file=True)
    state = "interrupted" if interrupted else ("done" if step >= args.total_iters else "stopped")
    print(f"{state} at step {step}/{args.total_iters} ({train_s:.0f} s of training in all); checkpoint {path}",
          file=sys.stderr)
    if interrupted:
        raise SystemExit(130)
    return path


def main(argv: Sequence[str] | None = None) -> Path:
    return train(parse_args(argv))


if __name__ == "__main__":
    main()
