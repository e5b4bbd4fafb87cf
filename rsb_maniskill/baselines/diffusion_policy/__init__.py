"""A diffusion-policy baseline that can read the instruction (needs the ``baselines`` extra).

In the shape of ManiSkill's ``examples/baselines/diffusion_policy``: a 1-D conditional U-Net
over action chunks (observation horizon 2, prediction horizon 16, action horizon 8) with
``diffusers``' DDPM / DDIM schedules; the instruction's frozen all-MiniLM-L6-v2 embedding joins
the FiLM conditioning (``--no-language`` drops it). Modules: ``model`` (network, schedules),
``text`` (instruction encoder), ``data`` (demo files -> windows), ``train`` (the training CLI),
``checkpoint``, ``policy`` (the ``rsb eval`` policy).
"""
from __future__ import annotations


def make_policy(checkpoint: str, **kwargs):
    """``rsb eval rsb_maniskill.baselines.diffusion_policy:make_policy -a checkpoint=DIR``."""
    from rsb_maniskill.baselines.diffusion_policy.policy import make_policy as _make

    return _make(checkpoint, **kwargs)


make_policy.heavy = True  # a loaded checkpoint; it computes on the CPU (no `gpu`), so `auto` keeps a copy a worker
