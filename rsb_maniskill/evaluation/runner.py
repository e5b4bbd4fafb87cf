"""Run a policy on a list of episode seeds of one suite, one env, recording each episode as it ends.

The runner knows the env only through the RSB task contract (no task import here):
``env.unwrapped.get_language_instruction()``, ``env.unwrapped.episode_specs``, optionally
``env.unwrapped.episode_spec(seed)`` (an episode's semantics without a reset), and the latched
grasp / placement flags in ``info`` (torch or numpy, leading env dim). It resumes by skipping the
seeds already in the records file, so an interrupted run loses at most the episode in flight.

:func:`episode_loop` is the loop itself; it hands each record to a ``write`` callable, so worker
processes (``jobs.py``) can send their records to the one process that owns the file.
"""
from __future__ import annotations

import os
import re
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from rsb_maniskill.registration import TASK_MAX_EPISODE_STEPS

from .policy import as_chunk, policy_name
from .protocol import SHUFFLE_SEED, apply_instruction_mode, derangement
from .records import INSTRUCTION_MODES, RecordWriter, completed_seeds, read_records

# info flags copied into every record, and extra ones kept when the env provides them.
RECORD_FLAGS = ("grasped_any", "grasped_correct", "placed_correct", "placed_wrong", "success")
EXTRA_FLAGS = ("grasped_wrong", "fail")
DEFAULT_MAX_STEPS = TASK_MAX_EPISODE_STEPS  # the tasks' own limit
VIDEO_FPS = 25  # the control rate: videos play in real time


def _first(x: Any) -> Any:
    """Python scalar of env 0 from a tensor / array / scalar."""
    if hasattr(x, "detach"):  # torch, without importing it
        x = x.detach().cpu().numpy()
    a = np.asarray(x)
    return a.reshape(-1)[0].item() if a.size else None


def single_env_obs(obs: Any) -> Any:
    """Nested obs of a one-env batch as numpy with the leading env dim removed."""
    if isinstance(obs, Mapping):
        return {k: single_env_obs(v) for k, v in obs.items()}
    if hasattr(obs, "detach"):
        obs = obs.detach().cpu().numpy()
    if isinstance(obs, np.ndarray) and obs.ndim >= 1:
        return obs[0]
    return obs


def info_flag(info: Mapping[str, Any], key: str, default: Any = False) -> Any:
    return _first(info[key]) if key in info else default


def build_record(
    *,
    suite_id: str,
    seed: int,
    spec: Any,
    instruction: str,
    instruction_mode: str,
    info: Mapping[str, Any],
    steps: int,
    policy: str,
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The episode record (``records.RECORD_FIELDS``) from the episode spec and the last ``info``."""
    record: dict[str, Any] = {
        "suite_id": suite_id,
        "seed": int(seed),
        "question_id": int(spec.question_id),
        "instruction": instruction,
        "instruction_mode": instruction_mode,
        "target_block": int(spec.target_block),
        "correct_letter": str(spec.correct_letter),
        "first_grasped": int(info_flag(info, "first_grasped", -1)),
        **{k: bool(info_flag(info, k)) for k in RECORD_FLAGS},
        "steps": int(steps),
        "policy": policy,
    }
    record.update({k: bool(info_flag(info, k)) for k in EXTRA_FLAGS if k in info})
    if extra:
        record.update(extra)
    return record


class _Donors:
    """Shuffled mode: episode ``seeds[i]`` is told the instruction of ``seeds[donor[i]]``.

    Same rule as ``protocol.shuffled_instruction`` on the whole seed list (so resumed and
    uninterrupted runs agree), with the instructions looked up lazily, one donor at a time.
    """

    def __init__(self, seeds: Sequence[int], lookup: Callable[[int], str], shuffle_seed: int) -> None:
        self.seeds = list(seeds)
        self.index = {s: i for i, s in enumerate(self.seeds)}
        self.donor = derangement(len(self.seeds), shuffle_seed)
        self.lookup = lookup
        self.cache: dict[int, str] = {}

    def text(self, seed: int) -> str:
        if seed not in self.cache:
            self.cache[seed] = self.lookup(seed)
        return self.cache[seed]

    def __call__(self, seed: int, own: str) -> tuple[int, str]:
        j = self.donor[self.index[seed]]
        for _ in range(len(self.seeds) - 1):
            if self.text(self.seeds[j]) != own:
                break
            j = self.donor[j]
        return self.seeds[j], self.text(self.seeds[j])


def _action_dim(env: Any) -> int:
    space = getattr(env.unwrapped, "single_action_space", None) or env.action_space
    return int(space.shape[-1])


def default_instruction_lookup(env: Any, reset_options: dict | None = None) -> Callable[[int], str]:
    """seed -> instruction: from the task's ``episode_spec(seed)`` if it has one, else by a reset."""
    base = env.unwrapped
    if callable(getattr(base, "episode_spec", None)):
        return lambda seed: base.episode_spec(seed).instruction

    def by_reset(seed: int) -> str:
        env.reset(seed=seed, options=reset_options)
        return base.get_language_instruction()[0]

    return by_reset


def run_episodes(
    env_factory: Callable[[], Any] | Any,
    policy: Any,
    suite_id: str,
    seeds: Sequence[int],
    out_path: str | os.PathLike,
    instruction_mode: str = "normal",
    max_steps: int = DEFAULT_MAX_STEPS,
    progress: bool = True,
    *,
    policy_label: str | None = None,
    reset_options: dict | None = None,
    instruction_lookup: Callable[[int], str] | None = None,
    shuffle_seed: int = SHUFFLE_SEED,
    keep_spec: bool = True,
    video_dir: str | os.PathLike | None = None,
    num_videos: int = 0,
) -> list[dict]:
    """Evaluate ``policy`` on ``seeds`` of ``suite_id``, appending one record per episode to ``out_path``.

    Args:
        env_factory: zero-argument callable making a one-env RSB env of ``suite_id`` (evaluation
            split), or an env. It is only built when seeds remain, and closed if built here.
        policy: a :class:`~rsb_maniskill.evaluation.policy.Policy`.
        seeds: the full seed list of this evaluation (``protocol.eval_seeds``); seeds already
            recorded for this policy / suite / mode in ``out_path`` are skipped.
        instruction_mode: ``normal``, ``blank`` ("" for the policy) or ``shuffled`` (another
            episode's instruction, fixed pairing over ``seeds``).
        max_steps: cap on env steps, on top of the env's own time limit.
        instruction_lookup: seed -> instruction, to find shuffled donors (default:
            :func:`default_instruction_lookup`).
        video_dir, num_videos: an mp4 of each of the first ``num_videos`` seeds of ``seeds``, from
            ``env.render()`` (make the env with ``render_mode="rgb_array"``).
    Returns:
        Every record of this (policy, suite, mode) in ``out_path``, old and new, in file order.
    """
    if instruction_mode not in INSTRUCTION_MODES:
        raise ValueError(f"instruction_mode must be one of {INSTRUCTION_MODES}, got {instruction_mode!r}")
    if len(set(seeds)) != len(seeds):
        raise ValueError("seeds contain duplicates")
    label = policy_label or policy_name(policy)
    out_path = Path(out_path)
    done = completed_seeds(out_path, suite_id, instruction_mode, label)
    todo = [s for s in seeds if s not in done]

    if todo:
        own_env = not hasattr(env_factory, "step")
        env = env_factory() if own_env else env_factory
        bar = ProgressBar(label, suite_id, instruction_mode, len(seeds), len(seeds) - len(todo), progress)
        try:
            with RecordWriter(out_path) as writer:
                def write(record: dict) -> None:
                    writer.write(record)
                    bar.add(record)

                episode_loop(env, policy, suite_id, seeds, todo, write, instruction_mode=instruction_mode,
                             max_steps=max_steps, label=label, reset_options=reset_options,
                             instruction_lookup=instruction_lookup, shuffle_seed=shuffle_seed,
                             keep_spec=keep_spec, video_dir=video_dir, num_videos=num_videos)
        finally:
            bar.close()
            if own_env:
                env.close()
    return [r for r in read_records(out_path)
            if r.get("suite_id") == suite_id and r.get("instruction_mode") == instruction_mode
            and r.get("policy") == label]


class ProgressBar:
    """tqdm bar over a suite's episodes with the running GSR / TSR; a no-op when disabled."""

    def __init__(self, label: str, suite_id: str, mode: str, total: int, initial: int, enabled: bool) -> None:
        self.bar = None
        self.n = self.grasped = self.success = 0
        if enabled:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, initial=initial, desc=f"{label} {suite_id} [{mode}]", unit="ep")

    def add(self, record: Mapping[str, Any]) -> None:
        self.n += 1
        self.grasped += bool(record["grasped_any"] or record["success"])
        self.success += bool(record["success"])
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(GSR=f"{self.grasped / self.n:.0%}", TSR=f"{self.success / self.n:.0%}", refresh=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _render(env: Any) -> np.ndarray:
    """``env.render()`` of every env as a (B, H, W, 3) numpy array."""
    img = env.render()
    img = img.detach().cpu().numpy() if hasattr(img, "detach") else np.asarray(img)
    return img if img.ndim == 4 else img[None]


def write_video(frames: Sequence[np.ndarray], video_dir: str | os.PathLike, name: str) -> Path:
    """mp4 at the control rate, with ManiSkill's writer."""
    from mani_skill.utils.visualization.misc import images_to_video

    images_to_video(list(frames), str(video_dir), name, fps=VIDEO_FPS, verbose=False)
    return Path(video_dir) / f"{name}.mp4"


def _finish_record(*, suite_id: str, seed: int, spec: Any, given: str, instruction_mode: str, info: Mapping[str, Any],
                   steps: int, label: str, extra: dict[str, Any], frames: list | None, video_dir: Any,
                   keep_spec: bool) -> dict[str, Any]:
    """The record of a finished episode; writes its video first when it was filmed."""
    if frames is not None:
        # The policy label leads the name: rows of one results directory share videos/.
        name = f"{re.sub(r'[^A-Za-z0-9_.-]+', '_', label)}_{suite_id}_{instruction_mode}_seed{seed}"
        extra["video"] = write_video(frames, video_dir, name).name
    if keep_spec and hasattr(spec, "to_dict"):
        extra["episode"] = spec.to_dict()
    return build_record(suite_id=suite_id, seed=seed, spec=spec, instruction=given,
                        instruction_mode=instruction_mode, info=info, steps=steps, policy=label, extra=extra)


def episode_loop(
    env: Any,
    policy: Any,
    suite_id: str,
    seeds: Sequence[int],
    todo: Sequence[int],
    write: Callable[[dict], None],
    *,
    instruction_mode: str = "normal",
    max_steps: int = DEFAULT_MAX_STEPS,
    label: str,
    reset_options: dict | None = None,
    instruction_lookup: Callable[[int], str] | None = None,
    shuffle_seed: int = SHUFFLE_SEED,
    keep_spec: bool = True,
    video_dir: str | os.PathLike | None = None,
    num_videos: int = 0,
) -> None:
    """Run the episodes ``todo`` (a subset of ``seeds``) and ``write`` each record as it ends.

    ``seeds`` is the whole evaluation: it fixes the shuffled-mode donors and which episodes
    (the first ``num_videos``) get a video, whichever process runs them.
    """
    base = env.unwrapped
    action_dim = _action_dim(env)
    batched_actions = len(env.action_space.shape) == 2
    donors = None
    if instruction_mode == "shuffled":
        donors = _Donors(seeds, instruction_lookup or default_instruction_lookup(env, reset_options), shuffle_seed)
    filmed = set(seeds[:num_videos]) if video_dir is not None else set()

    for seed in todo:
        t0 = time.monotonic()
        extra: dict[str, Any] = {}
        donor_text = None
        if donors is not None:
            # Before this episode's own reset: a reset-based lookup resets the env on other seeds.
            extra["donor_seed"], donor_text = donors(seed, donors.text(seed))
        obs, info = env.reset(seed=seed, options=reset_options)
        instructions = base.get_language_instruction()
        if len(instructions) != 1:
            raise ValueError(f"episode_loop drives one env, this one has {len(instructions)}; "
                             "use batched_loop for parallel envs")
        instruction = instructions[0]
        spec = base.episode_specs[0]
        given = apply_instruction_mode(instruction, instruction_mode, donor_text)
        if instruction_mode != "normal":
            extra["original_instruction"] = instruction
        frames = [_render(env)[0]] if seed in filmed else None

        policy.reset(given, single_env_obs(obs))
        steps, finished = 0, False
        while not finished and steps < max_steps:
            chunk = as_chunk(policy.act(single_env_obs(obs)), action_dim)
            for action in chunk:
                a = action[None] if batched_actions else action
                obs, _, terminated, truncated, info = env.step(a)
                steps += 1
                if frames is not None:
                    frames.append(_render(env)[0])
                finished = bool(_first(terminated)) or bool(_first(truncated))
                if finished or steps >= max_steps:
                    break
        extra["wall_s"] = round(time.monotonic() - t0, 3)
        write(_finish_record(suite_id=suite_id, seed=seed, spec=spec, given=given, instruction_mode=instruction_mode,
                             info=info, steps=steps, label=label, extra=extra, frames=frames, video_dir=video_dir,
                             keep_spec=keep_spec))


def _env_row(x: Any, i: int) -> Any:
    """Row ``i`` of a batched (nested) obs, as numpy."""
    if isinstance(x, Mapping):
        return {k: _env_row(v, i) for k, v in x.items()}
    if hasattr(x, "detach"):
        return x[i].detach().cpu().numpy()
    return np.asarray(x)[i]


def _row_info(info: Mapping[str, Any], i: int) -> dict[str, Any]:
    return {k: _env_row(v, i) for k, v in info.items() if hasattr(v, "__len__") or hasattr(v, "detach")}


def batched_loop(
    env: Any,
    policies: Sequence[Any],
    suite_id: str,
    seeds: Sequence[int],
    todo: Sequence[int],
    write: Callable[[dict], None],
    *,
    instruction_mode: str = "normal",
    max_steps: int = DEFAULT_MAX_STEPS,
    label: str,
    shuffle_seed: int = SHUFFLE_SEED,
    keep_spec: bool = True,
    video_dir: str | os.PathLike | None = None,
    num_videos: int = 0,
) -> None:
    """Episodes in waves of ``num_envs``: env i of a wave runs one seed with ``policies[i]``.

    All envs of a wave are reset together with their seeds (a list); each env's record is taken at
    the step it terminates or truncates, and it then holds its last action until the wave ends. The
    last wave is padded with repeats of its last seed whose outcome is discarded. Records equal
    those of :func:`~rsb_maniskill.evaluation.runner.episode_loop`, episode for episode.
    """
    import torch

    base = env.unwrapped
    b = base.num_envs
    if len(policies) != b:
        raise ValueError(f"need one policy per env: {b} envs, {len(policies)} policies")
    space = getattr(base, "single_action_space", None) or env.action_space
    action_dim = int(space.shape[-1])
    donors = None
    if instruction_mode == "shuffled":
        if not callable(getattr(base, "episode_spec", None)):
            raise ValueError("shuffled mode on parallel envs needs the task's episode_spec(seed)")
        donors = _Donors(seeds, default_instruction_lookup(env), shuffle_seed)
    filmed = set(seeds[:num_videos]) if video_dir is not None else set()

    for start in range(0, len(todo), b):
        wave = list(todo[start:start + b])
        n = len(wave)
        obs, info = env.reset(seed=wave + [wave[-1]] * (b - n))
        specs = list(base.episode_specs)
        instructions = base.get_language_instruction()
        given, extras = [], []
        for i, seed in enumerate(wave):
            extra: dict[str, Any] = {}
            donor_text = None
            if donors is not None:
                extra["donor_seed"], donor_text = donors(seed, instructions[i])
            if instruction_mode != "normal":
                extra["original_instruction"] = instructions[i]
            given.append(apply_instruction_mode(instructions[i], instruction_mode, donor_text))
            extras.append(extra)
            policies[i].reset(given[i], _env_row(obs, i))
        frames = {i: [] for i, s in enumerate(wave) if s in filmed}
        _collect_frames(env, frames)
        pending: list[list[np.ndarray]] = [[] for _ in range(b)]
        last = np.zeros((b, action_dim), dtype=np.float32)
        steps = [0] * b
        active = [i < n for i in range(b)]
        while any(active):
            for i in range(b):
                if active[i] and not pending[i]:
                    pending[i] = list(as_chunk(policies[i].act(_env_row(obs, i)), action_dim))
                if active[i]:
                    last[i] = pending[i].pop(0)
            action = torch.as_tensor(last, device=base.device)
            obs, _, terminated, truncated, info = env.step(action)
            _collect_frames(env, frames, active)
            for i in range(n):
                if not active[i]:
                    continue
                steps[i] += 1
                done = bool(_first(terminated[i:i + 1])) or bool(_first(truncated[i:i + 1])) or steps[i] >= max_steps
                if done:
                    active[i] = False
                    write(_finish_record(suite_id=suite_id, seed=wave[i], spec=specs[i], given=given[i],
                                         instruction_mode=instruction_mode, info=_row_info(info, i),
                                         steps=steps[i], label=label,
                                         extra=extras[i], frames=frames.pop(i, None), video_dir=video_dir,
                                         keep_spec=keep_spec))


def _collect_frames(env: Any, frames: dict[int, list], active: Sequence[bool] | None = None) -> None:
    if not frames:
        return
    img = _render(env)
    for i, f in frames.items():
        if active is None or active[i]:
            f.append(img[i])
