"""RSB on LeRobot's EnvHub: ``make_env("<user>/<repo>@<rev>:env.py", n_envs, trust_remote_code=True)``.

Upload this file to a hub repository (or load it from a local path). It needs ``rsb_maniskill``
and its LeRobot plugin ``lerobot_env_rsb`` installed (``pip install . ./plugins/lerobot_env_rsb``
from a checkout). The settings are those of ``--env.type=rsb`` (:class:`RSBEnvConfig`, whose
defaults hold), taken from a ``cfg`` of that type or from environment variables so the file
stays generic: ``RSB_TASK`` (ids, comma lists, ``paper``), ``RSB_NAMING`` (``rsb`` or
``robotwin``), ``RSB_INSTRUCTION_MODE``, ``RSB_RECORDS_DIR``, ``RSB_CAMERA_SIZE`` (``WxH``).
"""
from __future__ import annotations

import os

ENV_VARS = {"RSB_TASK": "task", "RSB_NAMING": "naming", "RSB_INSTRUCTION_MODE": "instruction_mode",
            "RSB_RECORDS_DIR": "records_dir"}  # environment variable -> RSBEnvConfig field


def make_env(n_envs: int = 1, use_async_envs: bool = False, cfg=None):
    from lerobot_env_rsb import RSBEnvConfig
    from rsb_maniskill.integrations.lerobot_env import create_rsb_envs

    if isinstance(cfg, RSBEnvConfig):  # --env.type=rsb: take its settings
        return cfg.create_envs(n_envs, use_async_envs)
    settings = {field: os.environ[var] for var, field in ENV_VARS.items() if var in os.environ}
    if "RSB_CAMERA_SIZE" in os.environ:
        settings["camera_width"], settings["camera_height"] = (
            int(v) for v in os.environ["RSB_CAMERA_SIZE"].split("x"))
    cfg = RSBEnvConfig(**settings)
    return create_rsb_envs(cfg.task, n_envs, use_async_envs, **cfg.gym_kwargs)
