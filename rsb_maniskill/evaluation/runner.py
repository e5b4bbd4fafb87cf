"""Run a policy on a list of episode seeds of one suite, one env, recording each episode as it ends.

The runner knows the env only through the RSB task contract (no task import here):
``env.unwrapped.get_language_instruction()``, ``env.unwrapped.episode_specs`` and the latched
grasp / placement flags in ``info`` (torch or numpy, leading env dim). It resumes by skipping the
seeds already in the records file, so an interrupted run loses at most the episode in flight.
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .policy import as_chunk, policy_name
from .protocol import SHUFFLE_SEED, apply_instruction_mode, derangement
from .records import INSTRUCTION_MODES, RecordWriter, completed_seeds, read_records

# info flags copied into every record, and extra ones kept when the env provides them.
RECORD_FLAGS = ("grasped_any", "grasped_correct", "placed_correct", "placed_wrong", "success")
EXTRA_FLAGS = ("grasped_wrong", "fail")
DEFAULT_MAX_STEPS = 300  # the tasks' max_episode_steps (12 s at 25 Hz)


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
        instruction_lookup: seed -> instruction, to find shuffled donors without resetting the env
            on the donor's seed (the default).
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
        try:
            _run(env, policy, suite_id, seeds, todo, out_path, instruction_mode, max_steps, progress, label,
                 reset_options, instruction_lookup, shuffle_seed, keep_spec, len(seeds) - len(todo))
        finally:
            if own_env:
                env.close()
    return [r for r in read_records(out_path)
            if r.get("suite_id") == suite_id and r.get("instruction_mode") == instruction_mode
            and r.get("policy") == label]


def _run(env: Any, policy: Any, suite_id: str, seeds: Sequence[int], todo: Sequence[int], out_path: Path,
         instruction_mode: str, max_steps: int, progress: bool, label: str, reset_options: dict | None,
         instruction_lookup: Callable[[int], str] | None, shuffle_seed: int, keep_spec: bool, n_done: int) -> None:
    base = env.unwrapped
    action_dim = _action_dim(env)
    batched_actions = len(env.action_space.shape) == 2

    def instruction_of(seed: int) -> str:
        env.reset(seed=seed, options=reset_options)
        return base.get_language_instruction()[0]

    donors = None
    if instruction_mode == "shuffled":
        donors = _Donors(seeds, instruction_lookup or instruction_of, shuffle_seed)

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(seeds), initial=n_done, desc=f"{label} {suite_id} [{instruction_mode}]", unit="ep")
    try:
        _loop(env, base, policy, suite_id, todo, out_path, instruction_mode, max_steps, label, reset_options,
              donors, keep_spec, action_dim, batched_actions, bar)
    finally:
        if bar is not None:
            bar.close()


def _loop(env: Any, base: Any, policy: Any, suite_id: str, todo: Sequence[int], out_path: Path,
          instruction_mode: str, max_steps: int, label: str, reset_options: dict | None, donors: _Donors | None,
          keep_spec: bool, action_dim: int, batched_actions: bool, bar: Any) -> None:
    n_grasp = n_success = 0
    with RecordWriter(out_path) as writer:
        for i, seed in enumerate(todo, start=1):
            t0 = time.monotonic()
            extra: dict[str, Any] = {}
            donor_text = None
            if donors is not None:
                # Before this episode's own reset: the default lookup resets the env on other seeds.
                extra["donor_seed"], donor_text = donors(seed, donors.text(seed))
            obs, info = env.reset(seed=seed, options=reset_options)
            instructions = base.get_language_instruction()
            if len(instructions) != 1:
                raise ValueError(f"run_episodes drives one env, this one has {len(instructions)}")
            instruction = instructions[0]
            spec = base.episode_specs[0]
            given = apply_instruction_mode(instruction, instruction_mode, donor_text)
            if instruction_mode != "normal":
                extra["original_instruction"] = instruction

            policy.reset(given, single_env_obs(obs))
            steps, finished = 0, False
            while not finished and steps < max_steps:
                chunk = as_chunk(policy.act(single_env_obs(obs)), action_dim)
                for action in chunk:
                    a = action[None] if batched_actions else action
                    obs, _, terminated, truncated, info = env.step(a)
                    steps += 1
                    finished = bool(_first(terminated)) or bool(_first(truncated))
                    if finished or steps >= max_steps:
                        break
            extra["wall_s"] = round(time.monotonic() - t0, 3)
            if keep_spec and hasattr(spec, "to_dict"):
                extra["episode"] = spec.to_dict()
            record = build_record(suite_id=suite_id, seed=seed, spec=spec, instruction=given,
                                  instruction_mode=instruction_mode, info=info, steps=steps, policy=label,
                                  extra=extra)
            writer.write(record)
            n_grasp += record["grasped_any"] or record["success"]
            n_success += record["success"]
            if bar is not None:
                bar.update(1)
                bar.set_postfix(GSR=f"{n_grasp / i:.0%}", TSR=f"{n_success / i:.0%}", refresh=False)
