"""The episode loops: a policy on a list of seeds of one suite, each finished episode handed to ``write``.

The loops know the env only through the RSB task contract (no task import here):
``env.unwrapped.get_language_instruction()``, ``env.unwrapped.episode_specs``, optionally
``env.unwrapped.episode_spec(seed)`` (an episode's semantics without a reset), and the latched
grasp / placement flags in ``info`` (torch or numpy, leading env dim).

:func:`episode_loop` drives one env, :func:`batched_loop` ``num_envs`` parallel envs; both read
what to run from one :class:`EpisodeSettings` and give the same records, episode for episode.
Resuming, the records file and the progress bar belong to the driver (``jobs.py``), which also
runs these loops in worker processes.
"""
from __future__ import annotations

import os
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from rsb_maniskill import compat
from rsb_maniskill.batch import env_row, first_value, single_env_obs
from rsb_maniskill.env_ids import TASK_MAX_EPISODE_STEPS
from rsb_maniskill.evaluation.positions import left_ranks
from rsb_maniskill.evaluation.protocol import (
    SHUFFLE_SEED,
    Episode,
    ShuffledDonors,
    ablate,
    episode_of,
    mode_episodes,
    scene_variants,
    variant_fields,
    variant_reset,
)
from rsb_maniskill.evaluation.records import COUNTERFACTUAL, EVAL_INSTRUCTION_MODES, build_record, perturb_fields
from rsb_maniskill.evaluation.statements import EpisodeText
from rsb_maniskill.evaluation.store import safe_name
from rsb_maniskill.parallel.pool import watched
from rsb_maniskill.perturb import label as perturb_label
from rsb_maniskill.perturb import parse_perturb
from rsb_maniskill.policies.errors import PolicyError, blame_policy, episode_where, policy_call_label
from rsb_maniskill.policies.interface import (
    PerEnvPolicies,
    as_chunk,
    as_chunks,
    env_action_space,
    is_batched,
    obs_rows,
    reset_policies,
    reset_policy,
    split_output,
    split_outputs,
)

DEFAULT_MAX_STEPS = TASK_MAX_EPISODE_STEPS  # the tasks' own limit


@dataclass(frozen=True, kw_only=True)
class EpisodeSettings:
    """What to run and how to record it: the one argument of the loops besides env, policy and seeds.

    ``seeds`` is the whole evaluation: it fixes the shuffled-mode donors and which episodes (the
    first ``num_videos``) are filmed, whichever process runs which of them.
    """

    suite_id: str
    seeds: tuple[int, ...] | range  # a range (rsb eval's) is kept as it is: lazy
    label: str  # the records' ``policy`` field and the table row
    instruction_mode: str = "normal"  # normal, blank ("" for the policy), shuffled (another episode's), counterfactual
    # counterfactual mode: K variants of each scene (default min(N, 4)); episodes() are (seed, variant)
    variants: int | None = None
    max_steps: int = DEFAULT_MAX_STEPS  # cap on env steps, on top of the env's own time limit
    video_dir: str | None = None  # an mp4 of each of the first num_videos seeds, from env.render()
    num_videos: int = 0
    keep_spec: bool = True  # the full EpisodeSpec in each record ("episode")
    shuffle_seed: int = SHUFFLE_SEED
    reset_options: Mapping[str, Any] | None = None
    # seed -> instruction, to find shuffled donors without a reset; in-process runs only (a callable
    # does not travel to worker processes). Default: the task's episode_spec(seed), else a reset.
    instruction_lookup: Callable[[int], str] | None = None
    # Render the cameras at every step, as a plain env.step does; by default they are rendered only
    # when the policy asks for a chunk (same records, less time). For benchmarks and checks.
    render_every_step: bool = False
    # Robustness axes of the env, {axis: level} (rsb_maniskill.perturb); records carry them.
    perturb: Mapping[str, int] | None = None
    # Seconds one policy call (factory, reset, act) may take before its worker process is killed and
    # the run ends with a PolicyError (None or 0: no limit). Enforced where the loop runs in a
    # ProcessPool worker (rsb eval always runs it there), not in this process.
    policy_timeout: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.seeds, range):  # a range stays one: -n costs no memory
            object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))
        object.__setattr__(self, "perturb", parse_perturb(self.perturb) or None)
        if self.instruction_mode not in EVAL_INSTRUCTION_MODES:
            raise ValueError(f"instruction_mode must be one of {EVAL_INSTRUCTION_MODES}, "
                             f"got {self.instruction_mode!r}")
        if self.instruction_mode == COUNTERFACTUAL:
            object.__setattr__(self, "variants", scene_variants(self.suite_id, self.variants))
        elif self.variants is not None:
            raise ValueError("variants are counterfactual mode's (instruction_mode='counterfactual')")
        if not isinstance(self.seeds, range) and len(set(self.seeds)) != len(self.seeds):
            raise ValueError("seeds contain duplicates")
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")

    def episodes(self) -> Sequence[Episode]:
        """What the loops run: the seeds, or in counterfactual mode each seed's variants, (seed, k)."""
        return mode_episodes(self.seeds, self.instruction_mode, self.variants)


def default_instruction_lookup(env: Any, reset_options: Mapping[str, Any] | None = None) -> Callable[[int], str]:
    """seed -> instruction: from the task's ``episode_spec(seed)`` if it has one, else by a reset."""
    base = env.unwrapped
    if callable(getattr(base, "episode_spec", None)):
        return lambda seed: base.episode_spec(seed).instruction

    def by_reset(seed: int) -> str:
        env.reset(seed=seed, options=reset_options)
        return base.get_language_instruction()[0]

    return by_reset


class _Episodes:
    """What both loops set up from the settings: the instruction ablation, the filmed seeds, the
    action dimension, and the record of a finished episode."""

    def __init__(self, env: Any, settings: EpisodeSettings, *, resets_allowed: bool) -> None:
        self.settings = settings
        self.action_dim = int(env_action_space(env).shape[-1])
        # what the task says an episode is (per-category tables); tasks without it give no categories
        self.categorize = getattr(env.unwrapped, "episode_categories", None)
        self.filmed = set(settings.seeds[:settings.num_videos]) if settings.video_dir is not None else set()
        self.donors = None
        if settings.instruction_mode == "shuffled":
            lookup = settings.instruction_lookup
            if lookup is None:
                if not resets_allowed and not callable(getattr(env.unwrapped, "episode_spec", None)):
                    raise ValueError("shuffled mode on parallel envs needs the task's episode_spec(seed)")
                lookup = default_instruction_lookup(env, settings.reset_options)
            self.donors = ShuffledDonors(settings.seeds, lookup, settings.shuffle_seed)

    def donor(self, seed: int, own: str | None = None) -> tuple[int, str] | None:
        """Shuffled mode: (donor seed, its instruction); ``own`` defaults to the looked-up text.

        Call it before the episode's own reset: a reset-based lookup resets the env on other seeds.
        """
        if self.donors is None:
            return None
        return self.donors(seed, self.donors.text(seed) if own is None else own)

    def instruction(self, own: str, donor: tuple[int, str] | None) -> tuple[str, dict[str, Any]]:
        """The text the policy is given, and the record's ablation fields."""
        return ablate(own, self.settings.instruction_mode, donor)

    def record(self, *, seed: int, spec: Any, given: str, info: Mapping[str, Any], steps: int,
               extra: dict[str, Any], frames: list | None, said: EpisodeText) -> dict[str, Any]:
        """The record of a finished episode (with what the policy said, if it talked); writes its
        video first when it was filmed. ``extra`` holds a counterfactual variant's fields."""
        s = self.settings
        extra.update(said.fields(spec))
        if s.perturb:
            extra.update(perturb_fields(s.perturb))
        if frames is not None:
            # The policy label leads the name: rows of one results directory share videos/.
            name = f"{safe_name(s.label)}_{s.suite_id}_{s.instruction_mode}_seed{seed}"
            if "variant" in extra:
                name += f"_v{extra['variant']}"
            if s.perturb:
                name += "_" + safe_name(perturb_label(s.perturb))
            extra["video"] = write_video(frames, s.video_dir, name).name
        if s.keep_spec and hasattr(spec, "to_dict"):
            extra["episode"] = spec.to_dict()
        return build_record(suite_id=s.suite_id, seed=seed, spec=spec, instruction=given,
                            instruction_mode=s.instruction_mode, info=info, steps=steps, policy=s.label, extra=extra,
                            categories=self.categorize(spec) if self.categorize is not None else None,
                            left_rank=left_ranks(spec) if hasattr(spec, "candidates") else None)


class Observations:
    """Render on demand: steps the env without rendering its cameras, renders them when asked.

    A chunked policy reads observations only when it asks for a new chunk, so the cameras (most of
    a visual step's cost on the CPU renderer) are rendered only then: :meth:`step` computes state
    and ``info`` (the metrics) at every step, :meth:`current` the full observation of the last step,
    once. ManiSkill has no switch for this; the env computes its observation for ``obs_mode``, so
    the step runs under ``state_dict`` and :meth:`current` calls ``get_obs(info)`` under the real
    mode: the same observation the step would have returned (rendering changes no physics).
    Envs without visual observations, or without ManiSkill's ``get_obs``, are stepped as they are.
    """

    SKIP_MODE = "state_dict"

    def __init__(self, env: Any, every_step: bool = False) -> None:
        self.env, self.base = env, env.unwrapped
        self.mode = getattr(self.base, "obs_mode", None)
        self.lazy = (not every_step and isinstance(self.mode, str)
                     and self.mode not in ("none", "state", "state_dict")
                     and callable(getattr(self.base, "get_obs", None)))
        self.renders = 0  # camera renders done by current(): one per chunk asked for
        self.obs: Any = None
        self.info: Any = None
        self.stale = False

    def reset(self, **kwargs: Any) -> tuple[Any, Any]:
        self.obs, self.info = self.env.reset(**kwargs)
        self.stale = False
        return self.obs, self.info

    def step(self, action: Any) -> tuple[Any, Any, Any, Any]:
        """``env.step(action)`` without its observation: (reward, terminated, truncated, info)."""
        if self.lazy:
            # a vector of CPU envs (rsb_maniskill.vector) has its own switch; a ManiSkill env, its obs mode
            own = getattr(self.base, "skip_observations", None)
            with own() if callable(own) else compat.obs_mode(self.base, self.SKIP_MODE):
                out = self.env.step(action)
        else:
            out = self.env.step(action)
        self.obs, self.info, self.stale = out[0], out[4], self.lazy
        return out[1:]

    def current(self) -> Any:
        """The observation of the last reset or step, rendered now if the step skipped it."""
        if self.stale:
            self.obs = self.base.get_obs(self.info)
            self.stale = False
            self.renders += 1
        return self.obs


def _render(env: Any) -> np.ndarray:
    """``env.render()`` of every env as a (B, H, W, 3) numpy array."""
    img = env.render()
    img = img.detach().cpu().numpy() if hasattr(img, "detach") else np.asarray(img)
    return img if img.ndim == 4 else img[None]


def write_video(frames: Sequence[np.ndarray], video_dir: str | os.PathLike, name: str) -> Path:
    """mp4 at the control rate (real time), with ManiSkill's writer."""
    from mani_skill.utils.visualization.misc import images_to_video

    from rsb_maniskill.env_ids import CONTROL_FREQ

    images_to_video(list(frames), str(video_dir), name, fps=CONTROL_FREQ, verbose=False)
    return Path(video_dir) / f"{name}.mp4"


def episode_loop(env: Any, policy: Any, settings: EpisodeSettings, todo: Sequence[int],
                 write: Callable[[dict], None]) -> None:
    """Run the episodes ``todo`` (a subset of ``settings.seeds``) on one env; ``write`` each record as it ends."""
    base = env.unwrapped
    episodes = _Episodes(env, settings, resets_allowed=True)
    batched_actions = len(env.action_space.shape) == 2
    observations = Observations(env, settings.render_every_step)

    for item in todo:
        t0 = time.monotonic()
        seed, variant = episode_of(item)
        donor = episodes.donor(seed)
        obs, info = observations.reset(seed=seed, options=variant_reset(settings.reset_options, [variant]))
        instructions = base.get_language_instruction()
        if len(instructions) != 1:
            raise ValueError(f"episode_loop drives one env, this one has {len(instructions)}; "
                             "use batched_loop for parallel envs")
        spec = base.episode_specs[0]
        given, extra = episodes.instruction(instructions[0], donor)
        if variant is not None:
            extra.update(variant_fields(env))
        frames = [_render(env)[0]] if seed in episodes.filmed else None

        with _blamed(settings, "reset", [seed]):
            reset_policy(policy, given, single_env_obs(obs), seed)
        steps, finished, said = 0, False, EpisodeText()
        while not finished and steps < settings.max_steps:
            current = single_env_obs(observations.current())
            with _blamed(settings, "act", [seed]):
                actions, text = split_output(policy.act(current))
                chunk = as_chunk(actions, episodes.action_dim)
            said.add(text)
            for action in chunk:
                a = action[None] if batched_actions else action
                _, terminated, truncated, info = observations.step(a)
                steps += 1
                if frames is not None:
                    frames.append(_render(env)[0])
                finished = bool(first_value(terminated)) or bool(first_value(truncated))
                if finished or steps >= settings.max_steps:
                    break
        extra["wall_s"] = round(time.monotonic() - t0, 3)
        write(episodes.record(seed=seed, spec=spec, given=given, info=info, steps=steps, extra=extra, frames=frames,
                              said=said))


@contextmanager
def _blamed(settings: EpisodeSettings, call: str, seeds: Sequence[int]) -> Iterator[None]:
    """The policy's ``call`` on ``seeds``: what goes wrong in it is a PolicyError naming the episode;
    in a worker process, a call that outlasts ``settings.policy_timeout`` or ends the process is too."""
    where = episode_where(settings.suite_id, seeds, settings.instruction_mode)
    with watched(policy_call_label(call, where), settings.policy_timeout), \
            blame_policy(call, policy=settings.label, where=where):
        try:
            yield
        except PolicyError as err:  # one env's call of PerEnvPolicies: its seed
            row = getattr(err, "row", None)
            if err.where is None and row is not None and row < len(seeds):
                err.where = episode_where(settings.suite_id, [seeds[row]], settings.instruction_mode)
            raise


def _row_info(info: Mapping[str, Any], i: int) -> dict[str, Any]:
    return {k: env_row(v, i) for k, v in info.items() if hasattr(v, "__len__") or hasattr(v, "detach")}


def batched_loop(env: Any, policy: Any, settings: EpisodeSettings, todo: Sequence[int],
                 write: Callable[[dict], None]) -> None:
    """Episodes in waves of ``num_envs``: env i of a wave runs one seed.

    ``policy`` is a :class:`~rsb_maniskill.policies.interface.BatchedPolicy` (one ``act_batch`` call
    per step for every env that needs a chunk), or a list of single-env policies, one per env.
    All envs of a wave are reset together with their seeds (a list); each env's record is taken at
    the step it terminates or truncates, and it then holds its last action until the wave ends
    (a vector of CPU envs, ``rsb_maniskill.vector``, stops stepping it: ``env.unwrapped.hold(i)``). The
    last wave is padded with repeats of its last seed whose outcome is discarded. Records equal
    those of :func:`episode_loop`, episode for episode, but for ``wall_s`` (here: from the wave's
    reset to the episode's end).
    """
    import torch

    base = env.unwrapped
    b = base.num_envs
    episodes = _Episodes(env, settings, resets_allowed=False)
    resets, acts = "reset_batch", "act_batch"  # the calls an error or a hang names: the ones the user wrote
    if not is_batched(policy):
        if len(policy) != b:
            raise ValueError(f"need one policy per env: {b} envs, {len(policy)} policies")
        policy, resets, acts = PerEnvPolicies(policy, episodes.action_dim), "reset", "act"
    observations = Observations(env, settings.render_every_step)
    hold = getattr(base, "hold", None)

    for start in range(0, len(todo), b):
        wave_items = [episode_of(e) for e in todo[start:start + b]]
        n = len(wave_items)
        items = wave_items + [wave_items[-1]] * (b - n)  # the last wave padded with repeats
        wave = [seed for seed, _ in wave_items]
        t0 = time.monotonic()  # an episode's wall_s: from its wave's reset to its own end
        obs, info = observations.reset(seed=[seed for seed, _ in items],
                                       options=variant_reset(settings.reset_options, [k for _, k in items]))
        specs = list(base.episode_specs)
        instructions = base.get_language_instruction()
        given, extras = [], []
        for i, seed in enumerate(wave):
            text, extra = episodes.instruction(instructions[i], episodes.donor(seed, instructions[i]))
            if items[i][1] is not None:
                extra.update(variant_fields(env, i))
            given.append(text)
            extras.append(extra)
        with _blamed(settings, resets, wave):
            reset_policies(policy, given, obs_rows(obs, range(n)), wave)
        frames = {i: [] for i, s in enumerate(wave) if s in episodes.filmed}
        _collect_frames(env, frames)
        pending: list[list[np.ndarray]] = [[] for _ in range(b)]
        said = [EpisodeText() for _ in range(b)]
        last = np.zeros((b, episodes.action_dim), dtype=np.float32)
        steps = [0] * b
        active = [i < n for i in range(b)]
        if callable(hold):
            for i in range(n, b):  # the padding of the last wave
                hold(i)
        while any(active):
            need = [i for i in range(b) if active[i] and not pending[i]]
            if need:  # one call for all envs whose chunk ran out (in step when chunks are of equal length)
                current = obs_rows(observations.current(), need)
                with _blamed(settings, acts, [wave[i] for i in need]):
                    actions, texts = split_outputs(policy.act_batch(current, need), len(need))
                    chunks = as_chunks(actions, len(need), episodes.action_dim)
                for i, chunk, text in zip(need, chunks, texts):
                    pending[i] = list(chunk)
                    said[i].add(text)
            for i in range(b):
                if active[i]:
                    last[i] = pending[i].pop(0)
            action = torch.as_tensor(last, device=base.device)
            _, terminated, truncated, info = observations.step(action)
            _collect_frames(env, frames, active)
            ended = _flags(terminated) | _flags(truncated)  # one host copy a step, not two an env
            for i in range(n):
                if not active[i]:
                    continue
                steps[i] += 1
                if ended[i] or steps[i] >= settings.max_steps:
                    active[i] = False
                    if callable(hold):  # a vector of CPU envs stops stepping it (no physics for nothing)
                        hold(i)
                    extras[i]["wall_s"] = round(time.monotonic() - t0, 3)
                    write(episodes.record(seed=wave[i], spec=specs[i], given=given[i], info=_row_info(info, i),
                                          steps=steps[i], extra=extras[i], frames=frames.pop(i, None), said=said[i]))


def _flags(x: Any) -> np.ndarray:
    """A batched flag (torch or numpy, leading env dim) as a numpy bool row per env."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=bool).reshape(-1)


def _collect_frames(env: Any, frames: dict[int, list], active: Sequence[bool] | None = None) -> None:
    if not frames:
        return
    img = _render(env)
    for i, f in frames.items():
        if active is None or active[i]:
            f.append(img[i])
