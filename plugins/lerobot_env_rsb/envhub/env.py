"""RSB on LeRobot's EnvHub: ``make_env("<user>/<repo>@<rev>:env.py", n_envs, trust_remote_code=True)``.

Upload this file to a hub repository (or load it from a local path). It needs ``rsb_maniskill``
installed; the suite and settings come from environment variables so the file stays generic:
``RSB_TASK`` (default ``RSB-Math-4``; ids, comma lists, ``paper``), ``RSB_NAMING`` (``rsb`` or
``robotwin``), ``RSB_INSTRUCTION_MODE``, ``RSB_RECORDS_DIR``, ``RSB_CAMERA_SIZE`` (``WxH``, default
the cameras' ``rsb_maniskill.robot.CAMERA_SIZE``).
"""
from __future__ import annotations

import os


def make_env(n_envs: int = 1, use_async_envs: bool = False, cfg=None):
    from rsb_maniskill.integrations.lerobot_env import create_rsb_envs
    from rsb_maniskill.robot import CAMERA_SIZE

    if cfg is not None and getattr(cfg, "type", None) == "rsb":  # an RSBEnvConfig: take its settings
        return cfg.create_envs(n_envs, use_async_envs)
    w, h = (int(v) for v in os.environ.get("RSB_CAMERA_SIZE", "{}x{}".format(*CAMERA_SIZE)).split("x"))
    return create_rsb_envs(os.environ.get("RSB_TASK", "RSB-Math-4"), n_envs, use_async_envs,
                           naming=os.environ.get("RSB_NAMING", "rsb"),
                           instruction_mode=os.environ.get("RSB_INSTRUCTION_MODE", "normal"),
                           records_dir=os.environ.get("RSB_RECORDS_DIR", "outputs/rsb_eval"), camera_size=(w, h))
