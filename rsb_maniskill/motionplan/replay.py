"""ManiSkill's ``replay_trajectory`` with the RSB environments registered.

``python -m mani_skill.trajectory.replay_trajectory`` only imports ManiSkill's own tasks, so an
``RSB-*`` env id fails with NameNotFound. This entry imports ``rsb_maniskill`` first, in this
process and in every worker process replay starts (``-n K`` on the CPU backend), then runs
ManiSkill's replay with exactly its arguments::

    rsb replay --traj-path demos/RSB-Math-4/motionplanning/train.state.pd_joint_pos.physx_cpu.h5 \\
        -o rgb -c pd_joint_delta_pos --save-traj
    python -m rsb_maniskill.replay --traj-path ... (same arguments)

It lives beside ``dataset.py`` (the trajectory files it reads and annotates) and ``cli.py``.
"""
from __future__ import annotations

import json
import multiprocessing
import sys
from pathlib import Path

from rsb_maniskill.env_ids import CPU_SIM_BACKEND
from rsb_maniskill.motionplan.dataset import DatasetError, check_pair, json_path_of, load_json, write_json_atomic
from rsb_maniskill.robot import CONTROL_MODE


def _register_envs() -> None:
    import rsb_maniskill  # noqa: F401  (registers the RSB-* envs and the aloha_agilex robot)


class _RegisteringMultiprocessing:
    """Stands in for the ``multiprocessing`` module inside replay_trajectory: its pools import
    rsb_maniskill in each (spawned) worker before any replay task arrives."""

    def __getattr__(self, name):
        return getattr(multiprocessing, name)

    @staticmethod
    def Pool(processes=None, *args, **kwargs):  # noqa: N802  (mirrors multiprocessing.Pool)
        return multiprocessing.get_context("spawn").Pool(processes, _register_envs, *args, **kwargs)


def replayed_path(args) -> Path:
    """Where ManiSkill's replay writes with ``--save-traj``: next to the source, named
    ``<stem before the first dot>.<obs_mode>.<control_mode>.<sim_backend>.h5``."""
    src = Path(args.traj_path)
    env_kwargs = json.loads(src.with_suffix(".json").read_text())["env_info"]["env_kwargs"]
    obs = args.obs_mode or env_kwargs.get("obs_mode") or "none"
    control = args.target_control_mode or env_kwargs.get("control_mode") or CONTROL_MODE
    backend = args.sim_backend or env_kwargs.get("sim_backend") or CPU_SIM_BACKEND
    if backend == "auto":
        backend = CPU_SIM_BACKEND
    return src.with_name(f"{src.name.split('.')[0]}.{obs}.{control}.{backend}.h5")


def carry_metadata(src_h5: str | Path, out_h5: str | Path) -> int:
    """Copies the RSB episode metadata (instruction, options, ...) and the top-level ``rsb``
    block from the source json into a replayed json, which ManiSkill writes without them.

    Replay keeps the source order and may drop failed episodes, so episodes are paired in
    order by ``episode_seed``. Returns the number of episodes annotated."""
    src = load_json(json_path_of(src_h5))
    out_json = json_path_of(out_h5)
    out = load_json(out_json)
    ms_keys = {"episode_id", "episode_seed", "control_mode", "elapsed_steps", "reset_kwargs", "success", "fail"}
    i, done = 0, 0
    for ep in out["episodes"]:
        while i < len(src["episodes"]) and src["episodes"][i]["episode_seed"] != ep["episode_seed"]:
            i += 1
        if i == len(src["episodes"]):
            break
        ep.update({k: v for k, v in src["episodes"][i].items() if k not in ms_keys})
        i, done = i + 1, done + 1
    for key in ("rsb", "rsb_merged_from", "source_type", "source_desc"):
        if key in src:
            out.setdefault(key, src[key])
    out["rsb_replayed_from"] = Path(src_h5).name
    write_json_atomic(out_json, out)
    return done


def main(argv: list[str] | None = None) -> int:
    """Runs ManiSkill's replay on ``argv`` (default: ``sys.argv[1:]``); returns the exit status.

    With ``--save-traj`` the replayed json also gets the RSB metadata of its source."""
    _register_envs()
    from mani_skill.trajectory import replay_trajectory as rt

    rt.mp = _RegisteringMultiprocessing()
    args = rt.parse_args(list(sys.argv[1:] if argv is None else argv))
    try:
        check_pair(args.traj_path)  # a missing, damaged or truncated pair: one line naming the file
    except DatasetError as err:
        print(f"rsb replay: error: {err}", file=sys.stderr)
        return 2
    out = replayed_path(args) if args.save_traj else None
    if out is not None and out.resolve() == Path(args.traj_path).resolve():
        # ManiSkill would open its output with "w" before noticing, truncating the source.
        print(f"rsb replay: error: --save-traj would write over the source {out}: replaying with the same "
              "obs mode, control mode and backend. Change -o / -c, or copy the file to another name first.",
              file=sys.stderr)
        return 2
    rt.main(args)
    if out is not None and out.exists() and out.with_suffix(".json").exists():
        n = carry_metadata(args.traj_path, out)
        print(f"{out}: RSB metadata carried over for {n} episodes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
