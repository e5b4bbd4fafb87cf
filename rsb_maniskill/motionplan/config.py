"""What ``rsb generate`` is asked for, and the names and env settings that follow from it."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from rsb_maniskill.env_ids import CPU_SIM_BACKEND
from rsb_maniskill.robot import CONTROL_MODE

SIM_BACKEND = CPU_SIM_BACKEND  # demos run one env a process on the CPU
DEFAULT_EXPERT = "rsb_maniskill.motionplan:ScriptedExpert"
SOURCE_DESC = ("RSB scripted motion-planning expert (mplib): grasps the correct block with the arm "
               "on its side and places it in the answer zone; only successful episodes are kept")


class GenerateError(RuntimeError):
    """A bad request (suite, split, output path, shard) detected before anything is written."""


@dataclass
class GenerateConfig:
    """What ``rsb generate`` was asked for (see ``rsb generate --help``)."""

    env_id: str
    out: str = "demos"
    split: str = "train"
    num: int | None = None
    questions: str | None = None  # None: seed mode; "all" or "START:STOP"
    seed_start: int = 0
    obs_mode: str = "state"
    save_video: bool = False
    num_procs: int = 1
    shard: tuple[int, int] = (0, 1)
    overwrite: bool = False
    max_attempts: int = 20
    traj_name: str | None = None
    expert: str = DEFAULT_EXPERT
    env_kwargs: dict = field(default_factory=dict)  # extra env kwargs: instructions, color_map, data_dir
    progress: bool = True
    verbose: bool = False


def output_path(cfg: GenerateConfig) -> Path:
    """``<out>/<ENV_ID>/motionplanning/<name>.<obs_mode>.pd_joint_pos.physx_cpu.h5``.

    ``name`` is ``--traj-name`` or the split, plus ``-shard<i>of<n>`` for a shard. ManiSkill's
    replay keeps the part before the first dot and appends the new modes, so a replayed file
    lands next to it as ``<name>.<obs>.<control>.physx_cpu.h5``."""
    name = cfg.traj_name or cfg.split
    if "." in name or "/" in name:
        raise GenerateError(f"bad --traj-name {name!r}: no dots or slashes (replay splits names on '.')")
    i, n = cfg.shard
    if n > 1:
        name += f"-shard{i}of{n}"
    return Path(cfg.out) / cfg.env_id / "motionplanning" / f"{name}.{cfg.obs_mode}.{CONTROL_MODE}.{SIM_BACKEND}.h5"


def make_env_kwargs(cfg: GenerateConfig) -> dict:
    """Kwargs for ``gym.make``; RecordEpisode stores them in the json so replay rebuilds the env."""
    kwargs = dict(obs_mode=cfg.obs_mode, control_mode=CONTROL_MODE, sim_backend=SIM_BACKEND, split=cfg.split)
    kwargs.update(cfg.env_kwargs)
    if cfg.save_video:
        kwargs["render_mode"] = "rgb_array"  # videos come from the human render camera
    return kwargs
