"""The noise-prediction network: a 1-D conditional U-Net over action chunks (Chi et al., the
shape of ManiSkill's ``examples/baselines/diffusion_policy``), FiLM-conditioned on one global
vector = diffusion-step embedding + observation features + (optionally) the instruction embedding.

The instruction also FiLM-gates the observation encoder's hidden layer (as RT-1 gates its image
encoder): choosing the named block means taking *its* pose out of the state, a product of text and
observation that the U-Net's FiLM layers (linear in the conditioning) can only form indirectly.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import torch
import torch.nn as nn


@dataclass
class ModelConfig:
    """Everything needed to rebuild the network; stored in every checkpoint."""

    act_dim: int
    obs_dim: int  # state vector (state variant) or proprioception (rgb variant)
    obs_mode: str = "state"  # "state" or "rgb"
    obs_horizon: int = 2
    pred_horizon: int = 16
    act_horizon: int = 8
    language: bool = True
    text_dim: int = 384  # all-MiniLM-L6-v2
    text_feat: int = 64  # the instruction's share of the global conditioning
    obs_feat: int = 256  # hidden width and output of the observation encoder
    unet_dims: list[int] = field(default_factory=lambda: [64, 128, 256])
    step_embed_dim: int = 64
    n_groups: int = 8
    kernel_size: int = 5
    num_cameras: int = 0  # rgb: cameras stacked along channels
    image_size: int = 64  # rgb: square side the images are resized to
    image_feat: int = 128
    num_train_steps: int = 100  # DDPM steps
    prediction: str = "epsilon"  # what the U-Net predicts: the noise (ManiSkill) or the clean chunk ("sample")

    def to_dict(self) -> dict:
        return asdict(self)


class SinusoidalPosEmb(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.dim = dim

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        half = self.dim // 2
        freq = torch.exp(torch.arange(half, device=t.device) * (-math.log(10000) / (half - 1)))
        arg = t.float()[:, None] * freq[None]
        return torch.cat([arg.sin(), arg.cos()], dim=-1)


def conv_block(c_in: int, c_out: int, k: int, groups: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv1d(c_in, c_out, k, padding=k // 2), nn.GroupNorm(groups, c_out), nn.Mish())


class FiLMResBlock(nn.Module):
    """Two conv blocks; the conditioning predicts a per-channel scale and bias between them."""

    def __init__(self, c_in: int, c_out: int, cond_dim: int, k: int, groups: int):
        super().__init__()
        self.conv1 = conv_block(c_in, c_out, k, groups)
        self.conv2 = conv_block(c_out, c_out, k, groups)
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, 2 * c_out))
        self.skip = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        scale, bias = self.film(cond)[..., None].chunk(2, dim=1)
        h = self.conv2(scale * self.conv1(x) + bias)
        return h + self.skip(x)


class ConditionalUnet1D(nn.Module):
    """Noise prediction over a (B, T, act_dim) chunk given the diffusion step and a global condition."""

    def __init__(self, act_dim: int, cond_dim: int, dims: list[int], step_dim: int, k: int, groups: int):
        super().__init__()
        self.step_encoder = nn.Sequential(SinusoidalPosEmb(step_dim), nn.Linear(step_dim, 4 * step_dim), nn.Mish(),
                                          nn.Linear(4 * step_dim, step_dim))
        c = step_dim + cond_dim
        chans = [act_dim, *dims]
        pairs = list(zip(chans[:-1], chans[1:]))
        self.down = nn.ModuleList()
        for i, (a, b) in enumerate(pairs):
            last = i == len(pairs) - 1
            self.down.append(nn.ModuleList([FiLMResBlock(a, b, c, k, groups), FiLMResBlock(b, b, c, k, groups),
                                            nn.Identity() if last else nn.Conv1d(b, b, 3, 2, 1)]))
        self.mid = nn.ModuleList([FiLMResBlock(dims[-1], dims[-1], c, k, groups) for _ in range(2)])
        self.up = nn.ModuleList()
        for a, b in reversed(pairs[1:]):  # back up to the full chunk length
            self.up.append(nn.ModuleList([FiLMResBlock(2 * b, a, c, k, groups), FiLMResBlock(a, a, c, k, groups),
                                          nn.ConvTranspose1d(a, a, 4, 2, 1)]))
        self.final = nn.Sequential(conv_block(dims[0], dims[0], k, groups), nn.Conv1d(dims[0], act_dim, 1))

    def forward(self, sample: torch.Tensor, t: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        x = sample.moveaxis(-1, -2)  # (B, C, T)
        t = t.expand(x.shape[0]) if t.ndim else t[None].expand(x.shape[0])
        g = torch.cat([self.step_encoder(t), cond], dim=-1)
        skips = []
        for res1, res2, down in self.down:
            x = res2(res1(x, g), g)
            skips.append(x)
            x = down(x)
        for res in self.mid:
            x = res(x, g)
        for res1, res2, up in self.up:
            x = up(res2(res1(torch.cat([x, skips.pop()], dim=1), g), g))
        return self.final(x).moveaxis(-1, -2)


class ImageEncoder(nn.Module):
    """A plain conv net over the cameras stacked along channels (rgb variant)."""

    def __init__(self, in_channels: int, out_dim: int):
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(in_channels, 32, 3, 2, 1), nn.ReLU(), nn.Conv2d(32, 64, 3, 2, 1), nn.ReLU(),
            nn.Conv2d(64, 64, 3, 2, 1), nn.ReLU(), nn.Conv2d(64, 64, 3, 2, 1), nn.ReLU(),
            nn.AdaptiveAvgPool2d(2), nn.Flatten(), nn.Linear(256, out_dim), nn.ReLU())

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.net(images)


class ObsEncoder(nn.Module):
    """Observation history -> features through one hidden layer that the instruction (if any) scales
    and shifts per unit; the gate starts at identity."""

    def __init__(self, in_dim: int, width: int, text_dim: int | None):
        super().__init__()
        self.inp = nn.Sequential(nn.Linear(in_dim, width), nn.Mish())
        self.out = nn.Sequential(nn.Linear(width, width), nn.Mish(), nn.Linear(width, width))
        self.gate = None
        if text_dim:
            self.gate = nn.Sequential(nn.Linear(text_dim, width), nn.Mish(), nn.Linear(width, 2 * width))
            nn.init.zeros_(self.gate[-1].weight)
            nn.init.zeros_(self.gate[-1].bias)

    def forward(self, obs: torch.Tensor, text: torch.Tensor | None) -> torch.Tensor:
        h = self.inp(obs)
        if self.gate is not None:
            scale, bias = self.gate(text).chunk(2, dim=-1)
            h = h * (1 + scale) + bias
        return self.out(h)


class DiffusionPolicyNet(nn.Module):
    """Observation (+ instruction) encoders and the U-Net; the diffusion schedule lives outside."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        per_step = cfg.obs_dim
        if cfg.obs_mode == "rgb":
            self.image_encoder = ImageEncoder(3 * cfg.num_cameras, cfg.image_feat)
            per_step += cfg.image_feat
        cond = cfg.obs_horizon * per_step + cfg.obs_feat
        self.obs_encoder = ObsEncoder(cfg.obs_horizon * per_step, cfg.obs_feat, cfg.text_dim if cfg.language else None)
        if cfg.language:
            self.text_proj = nn.Sequential(nn.Linear(cfg.text_dim, 128), nn.Mish(), nn.Linear(128, cfg.text_feat))
            cond += cfg.text_feat
        self.unet = ConditionalUnet1D(cfg.act_dim, cond, cfg.unet_dims, cfg.step_embed_dim, cfg.kernel_size,
                                      cfg.n_groups)

    def condition(self, obs: torch.Tensor, text: torch.Tensor | None = None,
                  images: torch.Tensor | None = None) -> torch.Tensor:
        """Global conditioning from (B, obs_horizon, obs_dim) normalised obs, (B, obs_horizon, C, H, W)
        float images in [0, 1] (rgb) and the (B, text_dim) instruction embedding (language)."""
        feats = [obs]
        if self.cfg.obs_mode == "rgb":
            b, h = images.shape[:2]
            feats.append(self.image_encoder(images.flatten(0, 1)).view(b, h, -1))
        flat = torch.cat(feats, dim=-1).flatten(1)
        parts = [flat, self.obs_encoder(flat, text if self.cfg.language else None)]
        if self.cfg.language:
            parts.append(self.text_proj(text))
        return torch.cat(parts, dim=-1)

    def forward(self, noisy: torch.Tensor, t: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        return self.unet(noisy, t, cond)


def make_scheduler(cfg: ModelConfig, kind: str = "ddpm"):
    """DDPM for training (and slow sampling) or DDIM (few-step sampling) from ``diffusers``,
    with ManiSkill's settings: squared-cosine betas, clipped samples (and its epsilon prediction by default)."""
    from diffusers import DDIMScheduler, DDPMScheduler

    kwargs = dict(num_train_timesteps=cfg.num_train_steps, beta_schedule="squaredcos_cap_v2", clip_sample=True,
                  prediction_type=cfg.prediction)
    if kind == "ddpm":
        return DDPMScheduler(**kwargs)
    if kind == "ddim":
        return DDIMScheduler(**kwargs)
    raise ValueError(f"unknown scheduler {kind!r}: use 'ddpm' or 'ddim'")
